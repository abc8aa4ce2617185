"""Each security rule of docs/web.md, one test (or a few) each: binding and the token, Host and
Origin checks, upload size limits, zip-slip and the other zip rules, names and frame ids,
uploaded files stored under generated names and never executed, the API's refusal of command
line systems, and checkpoints loaded with ``torch.load(weights_only=True)``."""

from __future__ import annotations

import io
import os
import stat
import subprocess
import sys
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from lidarfuzz.web import Limits
from lidarfuzz.web.security import is_loopback
from tests.web.conftest import TURN, register

TOKEN = "s3cret-token"
BAD_LABEL = "Car 0.00 0 1.5 100 100 200 200 1.5 1.6\n"  # 10 fields, KITTI has 15


def kitti_zip(world: Path, *, prefix: str = "sim/", replace: dict[str, str] | None = None,
              extra: dict[str, bytes] | None = None) -> bytes:
    """The world as a zip in KITTI layout (inside a folder ``prefix``), with some files replaced."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for path in sorted(world.rglob("*")):
            if path.is_file() and path.parts[len(world.parts)] in ("velodyne", "label_2", "calib"):
                name = path.relative_to(world).as_posix()
                data = (replace or {}).get(name)
                archive.writestr(prefix + name, data if data is not None else path.read_bytes())
        for name, data in (extra or {}).items():
            archive.writestr(prefix + name, data)
    return buffer.getvalue()


def zip_of(members: dict[str, bytes], links: tuple[str, ...] = ()) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
        for name in links:
            info = zipfile.ZipInfo(name)
            info.create_system = 3
            info.external_attr = (stat.S_IFLNK | 0o777) << 16
            archive.writestr(info, "/etc/passwd")
    return buffer.getvalue()


def upload(client: TestClient, name: str, files: list[tuple[str, bytes]]) -> Any:
    return client.post("/api/datasets/upload", data={"name": name},
                       files=[("files", (filename, data)) for filename, data in files])


def uploads(tmp_path: Path) -> list[Path]:
    folder = tmp_path / "ws" / "uploads"
    return sorted(folder.rglob("*")) if folder.exists() else []


# -- binding and the token ----------------------------------------------------------------------
@pytest.mark.parametrize(("host", "loopback"), [("127.0.0.1", True), ("localhost", True), ("::1", True),
                                                ("[::1]", True), ("127.0.0.2", True), ("0.0.0.0", False),
                                                ("192.168.1.5", False), ("example.com", False), ("::", False)])
def test_only_loopback_hosts_count_as_local(host: str, loopback: bool) -> None:
    assert is_loopback(host) is loopback


def test_serve_refuses_another_host_without_a_token(tmp_path: Path) -> None:
    code = "import sys; from lidarfuzz.cli.app import main; sys.argv = ['lidarfuzz', *sys.argv[1:]]; main()"
    env = {k: v for k, v in os.environ.items() if k != "LIDARFUZZ_TOKEN"}
    result = subprocess.run([sys.executable, "-c", code, "serve", "--host", "0.0.0.0", "--workspace",
                             str(tmp_path / "ws")], capture_output=True, text=True, timeout=120, env=env)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "--host 0.0.0.0" in lines[0] and "--token" in lines[0]
    assert not (tmp_path / "ws").exists()  # refused before anything was opened


def test_serve_binds_another_host_with_a_token(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import uvicorn

    from lidarfuzz.cli.app import app

    started: list[dict[str, Any]] = []
    monkeypatch.setattr(uvicorn, "run", lambda application, **options: started.append({"app": application,
                                                                                        **options}))
    monkeypatch.setenv("LIDARFUZZ_TOKEN", TOKEN)
    result = CliRunner().invoke(app, ["serve", "--host", "0.0.0.0", "--port", "8123", "--workspace",
                                      str(tmp_path / "ws")])
    assert result.exit_code == 0, result.output
    assert started[0]["host"] == "0.0.0.0" and started[0]["port"] == 8123
    assert started[0]["app"].state.web.token == TOKEN
    result = CliRunner().invoke(app, ["serve", "--workspace", str(tmp_path / "ws")], env={"LIDARFUZZ_TOKEN": ""})
    assert result.exit_code == 0 and started[1]["host"] == "127.0.0.1"
    assert started[1]["app"].state.web.token is None


@pytest.fixture
def guarded(make_client: Callable[..., TestClient], tmp_path: Path, world: Path) -> TestClient:
    register(tmp_path / "ws", world)
    return make_client(token=TOKEN)


def _api_calls(client: TestClient) -> Iterator[tuple[str, str]]:
    """Every API operation of the OpenAPI schema, with its path parameters filled in."""
    paths = client.get("/openapi.json").json()["paths"]
    for path, operations in paths.items():
        assert path.startswith("/api/")
        filled = path.replace("{task_id}", "1").replace("{finding_id}", "1").replace("{name}", "world").replace(
            "{frame_id}", "000000")
        for method in operations:
            yield method.upper(), filled


def test_every_api_call_needs_the_token(guarded: TestClient) -> None:
    calls = list(_api_calls(guarded))
    assert len(calls) >= 30
    for method, path in calls:
        missing = guarded.request(method, path)
        assert missing.status_code == 401, (method, path, missing.status_code)
        assert missing.headers["www-authenticate"] == "Bearer"
        wrong = guarded.request(method, path, headers={"Authorization": "Bearer not-it"})
        assert wrong.status_code == 401, (method, path)
        assert guarded.request(method, path, params={"token": "not-it"}).status_code == 401
    assert guarded.get("/api/tasks").json() == {"detail": guarded.get("/api/tasks").json()["detail"]}


def test_the_right_token_in_the_header_or_the_query(guarded: TestClient) -> None:
    assert guarded.get("/api/health", headers={"Authorization": f"Bearer {TOKEN}"}).json()["token_required"] is True
    assert guarded.get("/api/datasets", params={"token": TOKEN}).status_code == 200
    auth = {"Authorization": f"Bearer {TOKEN}"}
    task = guarded.post("/api/tasks", json={"dataset": "world", "sut": "classic", "operators": TURN}, headers=auth)
    assert task.status_code == 201
    stream = guarded.get(f"/api/tasks/{task.json()['id']}/events", params={"token": TOKEN})
    assert stream.status_code == 200 and "event: end" in stream.text
    # the page, its files and the docs need no token (the page asks for it)
    assert guarded.get("/docs").status_code == 200 and guarded.get("/").status_code in (200, 503)


def test_without_a_token_only_requests_to_loopback_names_are_answered(make_client: Callable[..., TestClient]) -> None:
    rebound = make_client(base_url="http://attacker.example:8000")
    reply = rebound.get("/api/health")
    assert reply.status_code == 403 and "127.0.0.1" in reply.json()["detail"]
    assert rebound.get("/").status_code == 403
    for base in ("http://localhost:8000", "http://[::1]:8000", "http://127.0.0.1"):
        assert make_client(base_url=base).get("/api/health").status_code == 200


def test_with_a_token_other_host_names_are_answered(make_client: Callable[..., TestClient]) -> None:
    remote = make_client(base_url="http://lidar-lab.example:8000", token=TOKEN)
    auth = {"Authorization": f"Bearer {TOKEN}"}
    assert remote.get("/api/health", headers=auth).status_code == 200
    # behind a reverse proxy the Origin differs from the Host; the token is what protects writes
    proxied = remote.post("/api/models", json={"name": "c", "spec": "classic"},
                          headers={**auth, "Origin": "https://lab.example"})
    assert proxied.status_code == 201
    assert remote.post("/api/models", json={"name": "d", "spec": "classic"},
                       headers={"Origin": "https://lab.example"}).status_code == 401


def test_cross_site_writes_are_refused(client: TestClient) -> None:
    body = {"name": "other", "spec": "classic"}
    refused = client.post("/api/models", json=body, headers={"Origin": "http://evil.example"})
    assert refused.status_code == 403 and "cross-site" in refused.json()["detail"]
    assert client.delete("/api/models/classic", headers={"Origin": "https://evil.example"}).status_code == 403
    assert [m["name"] for m in client.get("/api/models").json()["items"]] == ["classic"]
    assert client.post("/api/models", json=body, headers={"Origin": "http://127.0.0.1"}).status_code == 201
    assert client.get("/api/models", headers={"Origin": "http://evil.example"}).status_code == 200  # reads: CORS


# -- request sizes ----------------------------------------------------------------------------
def test_an_upload_over_the_limit_is_refused_by_its_content_length(make_client: Callable[..., TestClient],
                                                                    tmp_path: Path) -> None:
    client = make_client(limits=Limits(max_upload=10_000))
    reply = upload(client, "big", [("frames.zip", b"x" * 20_000)])
    assert reply.status_code == 413 and "10,000 bytes" in reply.json()["detail"]
    assert uploads(tmp_path) == []
    reply = client.post("/api/models/upload", data={"name": "m"}, files={"file": ("m.onnx", b"x" * 20_000)})
    assert reply.status_code == 413


def test_an_upload_over_the_limit_is_refused_while_it_streams(make_client: Callable[..., TestClient],
                                                               tmp_path: Path) -> None:
    """No Content-Length (chunked): the body is counted as it arrives."""
    client = make_client(limits=Limits(max_upload=10_000))
    boundary = "lidarfuzz-boundary"

    def body() -> Iterator[bytes]:
        yield (f"--{boundary}\r\nContent-Disposition: form-data; name=\"name\"\r\n\r\nbig\r\n"
               f"--{boundary}\r\nContent-Disposition: form-data; name=\"files\"; filename=\"a.bin\"\r\n"
               f"Content-Type: application/octet-stream\r\n\r\n").encode()
        for _ in range(40):
            yield b"\0" * 1000
        yield f"\r\n--{boundary}--\r\n".encode()

    reply = client.post("/api/datasets/upload", content=body(),
                        headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})
    assert reply.status_code == 413
    assert uploads(tmp_path) == [] and client.get("/api/datasets").json()["items"] == []


def test_other_requests_have_a_small_limit(client: TestClient) -> None:
    huge = {"dataset": "world", "sut": "classic", "operators": TURN, "name": "x" * (2 << 20)}
    assert client.post("/api/tasks", json=huge).status_code == 413


# -- zips -------------------------------------------------------------------------------------
@pytest.mark.parametrize(("members", "links", "named", "why"), [
    ({"sim/velodyne/000000.bin": b"", "../../evil.txt": b"pwned"}, (), "../../evil.txt", "zip-slip"),
    ({"sim/a/../../../evil.txt": b"pwned"}, (), "sim/a/../../../evil.txt", "zip-slip"),
    ({"/etc/cron.d/evil": b"pwned"}, (), "/etc/cron.d/evil", "absolute"),
    ({"C:/evil.txt": b"pwned"}, (), "C:/evil.txt", "absolute"),
    ({"sim/velodyne/000000.bin": b""}, ("sim/label_2",), "sim/label_2", "symbolic link"),
])
def test_a_zip_that_escapes_its_folder_is_refused_naming_the_member(
        client: TestClient, tmp_path: Path, members: dict[str, bytes], links: tuple[str, ...], named: str,
        why: str) -> None:
    reply = upload(client, "evil", [("data.zip", zip_of(members, links))])
    assert reply.status_code == 400, reply.text
    detail = reply.json()["detail"]
    assert detail.startswith(named) and why in detail and "nothing was extracted" in detail
    assert uploads(tmp_path) == []
    assert not (tmp_path / "evil.txt").exists() and not (tmp_path / "ws" / "evil.txt").exists()


def test_a_zip_with_too_many_members_is_refused(make_client: Callable[..., TestClient], tmp_path: Path) -> None:
    client = make_client(limits=Limits(max_members=3))
    reply = upload(client, "many", [("data.zip", zip_of({f"velodyne/{i:06d}.bin": b"" for i in range(5)}))])
    assert reply.status_code == 400 and reply.json()["detail"].startswith("velodyne/000003.bin")
    assert "more than the limit of 3" in reply.json()["detail"] and uploads(tmp_path) == []


def test_a_zip_that_unpacks_too_large_is_refused(make_client: Callable[..., TestClient], tmp_path: Path) -> None:
    client = make_client(limits=Limits(max_unzipped=50_000))
    bomb = zip_of({"velodyne/000000.bin": b"\0" * 32_000, "velodyne/000001.bin": b"\0" * 32_000})
    assert len(bomb) < 50_000
    reply = upload(client, "bomb", [("data.zip", bomb)])
    assert reply.status_code == 400 and reply.json()["detail"].startswith("velodyne/000001.bin")
    assert "unpacks to more than" in reply.json()["detail"] and uploads(tmp_path) == []


def test_a_kitti_zip_is_extracted_under_a_generated_folder(client: TestClient, tmp_path: Path,
                                                           world: Path) -> None:
    odd = {"notes/read me;rm -rf ~.txt": b"hello", ".hidden": b"x", "__MACOSX/._000000.bin": b"x"}
    reply = upload(client, "mine", [("my data.zip", kitti_zip(world, extra=odd))])
    assert reply.status_code == 201, reply.text
    row = reply.json()
    assert row["frame_count"] == 2 and row["format"] == "kitti" and row["uploaded"] is True
    root = Path(row["path"])
    generated = root.relative_to((tmp_path / "ws" / "uploads").resolve()).parts[0]
    assert len(generated) == 32 and int(generated, 16) >= 0  # a uuid, not a user's name
    assert (root / "velodyne" / "000001.bin").read_bytes() == (world / "velodyne" / "000001.bin").read_bytes()
    assert (root / "notes" / "read_me_rm_-rf__.txt").read_bytes() == b"hello"
    assert not (root / ".hidden").exists() and not (root / "__MACOSX").exists()
    for path in uploads(tmp_path):  # nothing uploaded is made executable
        assert path.is_dir() or not path.stat().st_mode & (stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    assert client.delete("/api/datasets/mine").status_code == 204
    assert uploads(tmp_path) == []


def test_a_kitti_zip_with_a_malformed_label_line_is_a_422_naming_file_and_line(client: TestClient, tmp_path: Path,
                                                                              world: Path) -> None:
    labels = (world / "label_2" / "000001.txt").read_text(encoding="utf-8").splitlines(keepends=True)
    broken = "".join([*labels[:1], BAD_LABEL, *labels[1:]])
    calib = "P0: 1 0 0\n"  # a calibration without its keys
    reply = upload(client, "broken", [("data.zip", kitti_zip(world, replace={"label_2/000001.txt": broken,
                                                                               "calib/000000.txt": calib}))])
    assert reply.status_code == 422, reply.text
    body = reply.json()
    lines = body["detail"].splitlines()
    assert any(line.startswith("label_2/000001.txt:2: ") for line in lines), lines
    assert any(line.startswith("calib/000000.txt") for line in lines), lines
    assert {(p["file"], p["line"]) for p in body["problems"]} >= {("label_2/000001.txt", 2)}
    assert str(tmp_path) not in body["detail"]  # paths relative to the upload, not the server's
    assert uploads(tmp_path) == [] and [d["name"] for d in client.get("/api/datasets").json()["items"]] == ["world"]


def test_frames_with_label_and_calib_files(client: TestClient, world: Path) -> None:
    def files(kind: str, suffix: str) -> list[tuple[str, bytes]]:
        return [(f"{frame}.{suffix}", (world / kind / f"{frame}.{suffix}").read_bytes())
                for frame in ("000000", "000001")]

    frames, labels, calibs = files("velodyne", "bin"), files("label_2", "txt"), files("calib", "txt")
    # label and calibration files share the frame's name: they are told apart by their content
    reply = upload(client, "loose", frames + labels + calibs)
    assert reply.status_code == 201, reply.text
    root = Path(reply.json()["path"])
    assert reply.json()["frame_count"] == 2
    assert sorted(p.relative_to(root).as_posix() for p in root.rglob("*.txt")) == [
        "calib/000000.txt", "calib/000001.txt", "label_2/000000.txt", "label_2/000001.txt"]
    reply = upload(client, "uncalibrated", frames + labels)
    assert reply.status_code == 422 and "no calib/ folder" in reply.json()["detail"]
    broken = [labels[0], ("000001.txt", labels[1][1] + BAD_LABEL.encode())]
    reply = upload(client, "broken", frames + broken + calibs)
    assert reply.status_code == 422
    line = len(labels[1][1].decode().splitlines()) + 1
    assert f"label_2/000001.txt:{line}: " in reply.json()["detail"]


def test_a_log_upload_is_stored_under_a_generated_name(client: TestClient, tmp_path: Path, world: Path) -> None:
    from lidarfuzz.io.logs import write_log
    from lidarfuzz.io.open import open_dataset

    dataset = open_dataset(world)
    log = write_log(tmp_path / "drive.mcap", [dataset.load(f) for f in dataset.frame_ids()])
    reply = upload(client, "drive", [("../../drive.mcap", log.read_bytes())])
    assert reply.status_code == 201, reply.text
    stored = Path(reply.json()["path"])
    assert stored.name == "log.mcap" and reply.json()["frame_count"] == 2
    assert stored.parent.parent == (tmp_path / "ws" / "uploads").resolve()


def test_unsupported_files_are_refused_and_not_kept(client: TestClient, tmp_path: Path) -> None:
    reply = upload(client, "script", [("run.sh", b"#!/bin/sh\nrm -rf ~\n")])
    assert reply.status_code == 422 and "run.sh: unsupported file type" in reply.json()["detail"]
    assert uploads(tmp_path) == []


# -- names and frame ids ------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["../../etc", "a/b", "..", ".hidden", "a\\b", "", "x" * 101, "name with space"])
def test_names_that_are_not_plain_are_refused(client: TestClient, tmp_path: Path, name: str) -> None:
    reply = upload(client, name, [("data.zip", zip_of({"velodyne/000000.bin": b""}))])
    assert reply.status_code == 400 and "name" in reply.json()["detail"]
    assert client.post("/api/models", json={"name": name, "spec": "classic"}).status_code == 400
    assert client.post("/api/datasets/generate", json={"name": name}).status_code == 400
    assert uploads(tmp_path) == []


@pytest.mark.parametrize("frame_id", ["..", "..%2F..%2Fetc%2Fpasswd", "000000..", "%2e%2e", "a%5C..%5Cb",
                                      ".000000"])
def test_frame_ids_that_are_paths_are_refused(client: TestClient, frame_id: str) -> None:
    reply = client.get(f"/api/datasets/world/frames/{frame_id}")
    if frame_id == "..":  # the client resolved ".." itself: the data set's own page, no frame
        assert reply.status_code == 200 and reply.json()["name"] == "world" and "frame_ids" not in reply.json()
        return
    assert reply.status_code in (400, 404, 405), reply.text
    if reply.status_code == 400:
        assert "frame_id" in reply.json()["detail"]


# -- systems under test ---------------------------------------------------------------------------
@pytest.mark.parametrize(("spec", "options"), [
    ("subprocess:python detector.py {points} {output}", {}),
    ("worker:./serve_detections", {}),
    ("  subprocess:rm -rf /", {}),
    ("os:system", {}),
    ("subprocess_tools.evil:run", {}),
    ("onnx:/etc/passwd", {}),
    ("open3d:/root/model.pth", {}),
    ("classic", {"post": "os:system"}),
    ("pillars", {"weights": "/etc/shadow"}),
])
def test_specs_that_run_or_read_server_things_are_refused(client: TestClient, spec: str,
                                                          options: dict[str, Any]) -> None:
    reply = client.post("/api/models", json={"name": "evil", "spec": spec, "options": options})
    assert reply.status_code == 403, reply.text
    assert [m["name"] for m in client.get("/api/models").json()["items"]] == ["classic"]


def test_a_subprocess_sut_is_refused_in_a_campaign_too(client: TestClient) -> None:
    reply = client.post("/api/tasks", json={"dataset": "world", "sut": "subprocess:sh -c 'touch /tmp/x'",
                                            "operators": TURN})
    assert reply.status_code == 403 and "CLI" in reply.json()["detail"]
    assert client.get("/api/tasks").json()["total"] == 0


def test_a_subprocess_sut_registered_from_the_cli_is_listed_and_usable(client: TestClient, tmp_path: Path) -> None:
    """Only registration is refused: a command-line system the CLI recorded shows in the list."""
    from lidarfuzz.store import Store
    from lidarfuzz.store.inventory import add_model

    store = Store(tmp_path / "ws")
    add_model(store, "external", f"subprocess:{sys.executable} -c pass {{points}} {{output}}")
    store.close()
    kinds = {m["name"]: m["kind"] for m in client.get("/api/models").json()["items"]}
    assert kinds == {"classic": "builtin", "external": "subprocess"}


def test_an_open3d_config_file_is_refused(client: TestClient, tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    path = tmp_path / "pp.pth"
    torch.save({"w": torch.zeros(1)}, path)
    reply = client.post("/api/models/upload", data={"name": "pp", "options": '{"config": "/tmp/evil.yml"}'},
                        files={"file": ("pp.pth", path.read_bytes())})
    assert reply.status_code == 403


class _Payload:
    """Unpickling this (without weights_only) would create the marker file."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, tuple[str, str]]:
        return open, (str(self.marker), "w")


def test_a_checkpoint_with_code_is_never_run(client: TestClient, tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    marker = tmp_path / "pwned"
    path = tmp_path / "evil.pth"
    torch.save({"model_state_dict": {"w": torch.zeros(1)}, "extra": _Payload(marker)}, path)
    reply = client.post("/api/models/upload", data={"name": "evil"}, files={"file": ("evil.pth", path.read_bytes())})
    assert reply.status_code == 422, reply.text
    assert "weights_only=True" in reply.json()["detail"] and reply.json()["detail"].startswith("evil.pth")
    assert not marker.exists()
    assert uploads(tmp_path) == [] and len(client.get("/api/models").json()["items"]) == 1


def test_the_report_runs_in_an_opaque_origin(finished: tuple[TestClient, int]) -> None:
    """Task names and messages are escaped by the report's templates; opened in its own tab, the
    page is also sandboxed (no access to the app's origin, where the token is kept)."""
    client, task_id = finished
    reply = client.get(f"/api/tasks/{task_id}/report")
    policy = reply.headers["content-security-policy"]
    assert policy.startswith("sandbox") and "allow-same-origin" not in policy


def test_responses_send_no_referrer_and_no_sniffing(guarded: TestClient) -> None:
    for reply in (guarded.get("/api/health", params={"token": TOKEN}), guarded.get("/"), guarded.get("/api/tasks")):
        assert reply.headers["referrer-policy"] == "no-referrer"  # ?token= never leaks in a Referer
        assert reply.headers["x-content-type-options"] == "nosniff"
