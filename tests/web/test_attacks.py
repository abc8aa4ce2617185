"""The attacks of issue 23 on the web server, one test each, with the requests an attacker sends:
each asserts the answer and that nothing in the workspace changed (no data set, model, upload or
task state). ``benchmarks/web_attacks.py`` runs more variants against a real ``lidarfuzz serve``.

1. a write from another page: ``Origin: null`` (a sandboxed frame), no Origin, another site's;
2. zip bombs: ratio, overlapping members, many small members, a lying header, deep or long paths,
   links, encrypted members;
3. the token in the start-up banner and in access logs (``?token=``);
4. a loopback address other than 127.0.0.1 without a token (the server answered 403 to everything);
5. ids out of range (a 500 from SQLite's driver);
6. control characters in names and notes, stored and printed raw by ``datasets list``;
7. a reader that aborts (the corrupt LAZ of the issue) or hangs while an upload is inspected.
"""

from __future__ import annotations

import io
import logging
import stat
import struct
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store import Store
from lidarfuzz.store.inventory import add_dataset, list_datasets, list_models
from lidarfuzz.web import Limits, create_app
from lidarfuzz.web.inspection import UploadInspector
from lidarfuzz.web.security import is_loopback_host
from tests.web import crashing_reader
from tests.web.conftest import BASE, TURN, register

TOKEN = "s3cret-token-value"


def uploads(workspace: Path) -> list[Path]:
    folder = workspace / "uploads"
    return sorted(folder.rglob("*")) if folder.exists() else []


def frames_of(world: Path) -> list[tuple[str, tuple[str, bytes]]]:
    """The world's two scans with their labels, as an upload's files."""
    return [("files", (path.name, path.read_bytes()))
            for folder in ("velodyne", "label_2") for path in sorted((world / folder).iterdir())]


@pytest.fixture
def bare(tmp_path: Path, world: Path) -> Iterator[TestClient]:
    """A tokenless app that queues tasks without running them, and a client that adds no Origin of its own."""
    register(tmp_path / "ws", world)
    with TestClient(create_app(tmp_path / "ws", workers=0, inline=True), base_url=BASE) as client:
        yield client


def state(client: TestClient, workspace: Path) -> dict[str, Any]:
    """What an attack could change: data sets (with notes), models, tasks (with status), uploads."""
    datasets = {d["name"]: d["notes"] for d in client.get("/api/datasets").json()["items"]}
    models = sorted(m["name"] for m in client.get("/api/models").json()["items"])
    tasks = {t["id"]: t["status"] for t in client.get("/api/tasks").json()["items"]}
    return {"datasets": datasets, "models": models, "tasks": tasks, "uploads": uploads(workspace)}


# -- 1. writes from another page --------------------------------------------------------------
CROSS_SITE = {
    "null (sandboxed iframe)": {"Origin": "null"},
    "missing": {},
    "another site": {"Origin": "http://evil.example"},
    "another port": {"Origin": "http://127.0.0.1:9999"},
    "Sec-Fetch-Site cross-site": {"Origin": BASE, "Sec-Fetch-Site": "cross-site"},
}


@pytest.mark.parametrize("headers", CROSS_SITE.values(), ids=CROSS_SITE.keys())
def test_writes_without_the_servers_own_origin_are_refused(bare: TestClient, tmp_path: Path, world: Path,
                                                          headers: dict[str, str]) -> None:
    own = {"Origin": BASE, "Sec-Fetch-Site": "same-origin"}  # what Chromium sends from the app's page
    task = bare.post("/api/tasks", json={"dataset": "world", "sut": "classic", "operators": TURN}, headers=own)
    assert task.status_code == 201, task.text
    task_id = task.json()["id"]
    before = state(bare, tmp_path / "ws")
    attacks = [
        bare.post("/api/datasets/upload", data={"name": "pwned"}, files=frames_of(world), headers=headers),
        bare.post(f"/api/tasks/{task_id}/stop", headers=headers),
        bare.post(f"/api/tasks/{task_id}/resume", headers=headers),
        bare.delete(f"/api/tasks/{task_id}", headers=headers),
        bare.patch("/api/datasets/world", json={"notes": "pwned"}, headers=headers),
        bare.post("/api/models", json={"name": "pwned", "spec": "classic"}, headers=headers),
        bare.delete("/api/models/classic", headers=headers),
    ]
    for reply in attacks:
        assert reply.status_code == 403, (reply.request.url, reply.text)
        assert "cross-site requests are refused" in reply.json()["detail"]
    assert state(bare, tmp_path / "ws") == before
    # the app's own page still writes
    assert bare.patch("/api/datasets/world", json={"notes": "mine"}, headers=own).status_code == 200


def test_with_a_token_a_write_needs_the_token_whatever_its_origin(make_client: Callable[..., TestClient],
                                                                  tmp_path: Path, world: Path) -> None:
    register(tmp_path / "ws", world)
    client = make_client(token=TOKEN)
    refused = client.patch("/api/datasets/world", json={"notes": "pwned"}, headers={"Origin": "null"})
    assert refused.status_code == 401
    assert client.get("/api/datasets/world", params={"token": TOKEN}).json()["notes"] == ""
    # a script (no Origin) or a reverse proxy (another Origin) with the token is the user
    for origin in ({}, {"Origin": "null"}, {"Origin": "https://lab.example"}):
        reply = client.patch("/api/datasets/world", json={"notes": "mine"},
                             headers={"Authorization": f"Bearer {TOKEN}", **origin})
        assert reply.status_code == 200, reply.text


# -- 2. zip bombs -----------------------------------------------------------------------------
def _zip(members: dict[str, bytes], method: int = zipfile.ZIP_DEFLATED) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", method) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return buffer.getvalue()


def _patch_central(data: bytes, index: int, **fields: int) -> bytes:
    """Rewrite fields of the ``index``-th central directory record (the zip format's offsets:
    flags 8, file size 24, local header offset 42)."""
    offsets = {"flags": (8, "<H"), "file_size": (24, "<I"), "header_offset": (42, "<I")}
    out = bytearray(data)
    at = -1
    for _ in range(index + 1):
        at = out.index(b"PK\x01\x02", at + 1)
    for name, value in fields.items():
        offset, fmt = offsets[name]
        struct.pack_into(fmt, out, at + offset, value)
    return bytes(out)


def _link_zip() -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        info = zipfile.ZipInfo("velodyne/000000.bin")
        info.create_system = 3
        info.external_attr = (stat.S_IFLNK | 0o777) << 16
        archive.writestr(info, "/etc/passwd")
    return buffer.getvalue()


ZEROS = b"\0" * (8 << 20)
BOMBS: dict[str, tuple[Callable[[], bytes], str]] = {
    # 8 MiB of zeros deflate to about 8 KiB: a ratio near 1,000, over 100, and past the 1 MiB grace
    "ratio 1000": (lambda: _zip({"velodyne/000000.bin": ZEROS}), "more than 100 times its compressed size"),
    # the second member's header points into the first's data: one kernel unpacked twice
    "overlapping members": (lambda: _patch_central(_zip({"velodyne/000000.bin": ZEROS[:1 << 20],
                                                          "velodyne/000001.bin": ZEROS[:1 << 20]}), 1,
                                                    header_offset=0), "overlap"),
    # 300 members of 64 KiB zeros, each under the grace: 18.75 MiB from a zip of about 60 KB (< 100 x)
    "many small members": (lambda: _zip({f"velodyne/{i:06d}.bin": ZEROS[:64 << 10] for i in range(300)}),
                           "more than 100 times its size"),
    # declares 1,000 bytes but inflates to 1 MiB: extraction stops at the declared size (bad CRC)
    "lying header": (lambda: _patch_central(_zip({"velodyne/000000.bin": ZEROS[:1 << 20]}), 0, file_size=1000),
                     "cannot extract"),
    "33 folders deep": (lambda: _zip({"/".join(["d"] * 33) + "/000000.bin": b"x"}), "33 folders deep"),
    "a 300-character name": (lambda: _zip({"velodyne/" + "a" * 300 + ".bin": b"x"}), "longer than"),
    "a symbolic link": (_link_zip, "symbolic link"),
    "an encrypted member": (lambda: _patch_central(_zip({"velodyne/000000.bin": b"x" * 100}), 0, flags=1),
                            "encrypted"),
}


@pytest.mark.parametrize("bomb", BOMBS.values(), ids=BOMBS.keys())
def test_zip_bombs_and_hostile_members_are_refused_leaving_nothing(
        make_client: Callable[..., TestClient], tmp_path: Path, bomb: tuple[Callable[[], bytes], str]) -> None:
    build, why = bomb
    client = make_client()
    reply = client.post("/api/datasets/upload", data={"name": "bomb"}, files=[("files", ("data.zip", build()))])
    assert reply.status_code == 400, reply.text
    assert why in reply.json()["detail"]
    assert uploads(tmp_path / "ws") == [] and client.get("/api/datasets").json()["items"] == []


def test_the_bytes_written_are_counted_not_the_declared_sizes(tmp_path: Path) -> None:
    """A member whose header under-declares its size writes no more than it declared."""
    from fastapi import HTTPException

    from lidarfuzz.web.security import extract_zip

    archive = tmp_path / "lie.zip"
    archive.write_bytes(_patch_central(_zip({"a.bin": ZEROS[:1 << 20]}), 0, file_size=1000))
    dest = tmp_path / "out"
    dest.mkdir()
    with pytest.raises(HTTPException) as refused:
        extract_zip(archive, dest, Limits())
    assert refused.value.status_code == 400
    assert (dest / "a.bin").stat().st_size <= 1000  # never the 1 MiB the data inflates to


# -- 3. the token in the banner and in logs ---------------------------------------------------
def test_the_token_is_never_printed_at_start(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import uvicorn

    from lidarfuzz.cli.app import app

    monkeypatch.setattr(uvicorn, "run", lambda application, **options: None)
    monkeypatch.setenv("LIDARFUZZ_TOKEN", TOKEN)
    quiet = CliRunner().invoke(app, ["serve", "--host", "0.0.0.0", "--workspace", str(tmp_path / "ws")])
    assert quiet.exit_code == 0, quiet.output
    assert TOKEN not in quiet.output and "--print-token" in quiet.output and "?token=TOKEN" in quiet.output
    asked = CliRunner().invoke(app, ["serve", "--print-token", "--workspace", str(tmp_path / "ws")])
    assert asked.exit_code == 0 and f"?token={TOKEN}" in asked.output


def test_the_token_in_a_query_is_redacted_from_access_logs(make_client: Callable[..., TestClient],
                                                           caplog: pytest.LogCaptureFixture) -> None:
    make_client(token=TOKEN)  # started: the app installed its redaction
    caplog.set_level(logging.INFO, logger="uvicorn.access")
    caplog.set_level(logging.INFO, logger="uvicorn.error")
    # the record uvicorn's access log writes for an event stream opened with ?token=
    logging.getLogger("uvicorn.access").info('%s - "%s %s HTTP/%s" %d', "127.0.0.1:51000", "GET",
                                             f"/api/tasks/1/events?token={TOKEN}&x=1", "1.1", 200)
    logging.getLogger("uvicorn.error").info("opened /?token=%s", TOKEN)
    assert TOKEN not in caplog.text
    assert "/api/tasks/1/events?token=[redacted]&x=1" in caplog.text and "/?token=[redacted]" in caplog.text


# -- 4. binding -------------------------------------------------------------------------------
@pytest.mark.parametrize(("host", "local"), [("127.0.0.2:8000", True), ("127.255.255.254", True),
                                             ("[::1]:8000", True), ("localhost:8000", True),
                                             ("127.0.0.1.evil.example", False), ("localhost.evil.example", False),
                                             ("10.0.0.1:8000", False), ("", False)])
def test_a_request_host_is_local_only_as_localhost_or_a_loopback_address(host: str, local: bool) -> None:
    assert is_loopback_host(host) is local


def test_serving_on_another_loopback_address_without_a_token_works(tmp_path: Path, world: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    import uvicorn

    from lidarfuzz.cli.app import app

    register(tmp_path / "ws", world)
    started: list[Any] = []
    monkeypatch.setattr(uvicorn, "run", lambda application, **options: started.append((application, options)))
    monkeypatch.delenv("LIDARFUZZ_TOKEN", raising=False)
    result = CliRunner().invoke(app, ["serve", "--host", "127.0.0.2", "--port", "8123",
                                      "--workspace", str(tmp_path / "ws")])
    assert result.exit_code == 0, result.output
    application, options = started[0]
    assert options["host"] == "127.0.0.2"
    base = "http://127.0.0.2:8123"
    with TestClient(application, base_url=base) as client:  # the requests a browser there sends
        assert client.get("/api/health").status_code == 200
        reply = client.patch("/api/datasets/world", json={"notes": "n"}, headers={"Origin": base})
        assert reply.status_code == 200, reply.text
        assert client.get("/api/health", headers={"Host": "rebound.example:8123"}).status_code == 403


@pytest.mark.parametrize(("arguments", "named"), [(["--print-token"], "--print-token"),
                                                  (["--token", "a b c d e f"], "--token"),
                                                  (["--token", "short"], "--token"),
                                                  (["--host", "0.0.0.0"], "--host 0.0.0.0")])
def test_a_configuration_that_cannot_work_is_refused_at_start(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              arguments: list[str], named: str) -> None:
    import uvicorn

    from lidarfuzz.cli.app import app

    started: list[Any] = []
    monkeypatch.setattr(uvicorn, "run", lambda application, **options: started.append(options))
    monkeypatch.delenv("LIDARFUZZ_TOKEN", raising=False)
    result = CliRunner().invoke(app, ["serve", *arguments, "--workspace", str(tmp_path / "ws")])
    assert isinstance(result.exception, LidarfuzzError), result.output
    message = str(result.exception)
    assert message.startswith(named) and "\n" not in message
    assert started == [] and not (tmp_path / "ws").exists()


# -- 5. ids out of range ----------------------------------------------------------------------
#: 2^31 is one past PostgreSQL's INTEGER, 2^63 one past SQLite's, 10^30 past both; -1 and 0 are no ids
OUT_OF_RANGE = [2**31, 2**63, 10**30, -1, 0]


def test_ids_out_of_range_are_a_422_on_every_route(client: TestClient, tmp_path: Path) -> None:
    before = state(client, tmp_path / "ws")
    paths = client.get("/openapi.json").json()["paths"]
    tried = 0
    for template, operations in paths.items():
        if not any(f"{{{p}}}" in template for p in ("task_id", "finding_id", "pair_id")):
            continue
        for value in OUT_OF_RANGE:
            path = template.replace("{name}", "world").replace("{frame_id}", "000000")
            for parameter in ("task_id", "finding_id", "pair_id"):
                path = path.replace(f"{{{parameter}}}", str(value))
            for method in operations:
                body = {"rater": "ana", "verdict": "same"} if method == "put" else {}
                reply = client.request(method.upper(), path, json=body if method in ("put", "patch") else None)
                assert reply.status_code == 422, (method, path, reply.status_code, reply.text)
                assert "detail" in reply.json()
                tried += 1
    assert tried >= 5 * 25  # every route with an id, each value
    queries = [("/api/tasks/1/findings", {"subtask": 10**30}), ("/api/tasks/1/findings", {"severity": 10**30}),
               ("/api/tasks", {"offset": 2**63}),
               ("/api/tasks/1/ratings/pairs", {"seed": -1}), ("/api/tasks/1/ratings/pairs", {"seed": 2**64}),
               ("/api/compare", {"tasks": f"1,{10**30}"}), ("/api/datasets/world/frames", {"offset": 10**30}),
               ("/api/datasets/world/frames", {"limit": -1}), ("/api/compare", {"tasks": "1,\u00b2"}),
               ("/api/compare", {"tasks": "1," + "9" * 5000}), ("/api/tasks/" + "9" * 5000, {})]
    for path, params in queries:
        reply = client.get(path, params=params)
        assert reply.status_code == 422, (path, params, reply.text)
    assert state(client, tmp_path / "ws") == before


# -- 6. control characters in names -----------------------------------------------------------
CONTROL = {"ESC (C0)": "\x1b]0;pwned\x07", "BEL": "\x07", "CR": "a\rb", "DEL": "\x7f", "NEL (C1)": "\x85",
           "CSI (C1)": "\x9b2J", "right-to-left override": "\u202e", "zero-width space": "\u200b",
           "line separator": "\u2028"}


@pytest.mark.parametrize("text", CONTROL.values(), ids=CONTROL.keys())
def test_names_with_control_characters_are_refused_in_the_store(tmp_path: Path, world: Path, text: str) -> None:
    store = Store(tmp_path / "ws")
    with pytest.raises(LidarfuzzError) as refused:
        add_dataset(store, f"evil{text}x", world)
    message = str(refused.value)
    assert message.startswith("name: ") and "control character" in message
    assert not any(ord(c) < 32 or 127 <= ord(c) < 160 or c in "\u202e\u200b\u2028" for c in message)
    assert list_datasets(store) == []


@pytest.mark.parametrize(("name", "why"), [("a/b", "path separator"), ("a\\b", "path separator"),
                                           (".hidden", "starts with a dot"), (" x", "space"), ("", "empty"),
                                           ("x" * 101, "at most 100")])
def test_other_unsafe_names_are_refused_in_the_store(tmp_path: Path, world: Path, name: str, why: str) -> None:
    store = Store(tmp_path / "ws")
    with pytest.raises(LidarfuzzError, match=why):
        add_dataset(store, name, world)
    assert list_models(store) == [] and list_datasets(store) == []


def test_names_stored_before_are_printed_escaped(tmp_path: Path, world: Path) -> None:
    from sqlalchemy import update

    from lidarfuzz.cli.app import app
    from lidarfuzz.store.models import Dataset

    store = Store(tmp_path / "ws")
    add_dataset(store, "world", world)
    with store.session() as s:  # as an older version stored it
        s.execute(update(Dataset).values(name="evil\x1b]0;pwned\x07", notes="\x1b[2Jgone\u202e"))
    store.close()
    for extra in ([], ["--plain"]):
        result = CliRunner().invoke(app, ["datasets", "list", "--workspace", str(tmp_path / "ws"), *extra])
        assert result.exit_code == 0, result.output
        assert "\x1b" not in result.output and "\x07" not in result.output and "\u202e" not in result.output
        assert "evil\\x1b]0;pwned\\x07" in result.output and "\\x1b[2Jgone\\u202e" in result.output


def test_uploaded_file_names_and_notes_with_control_characters(make_client: Callable[..., TestClient],
                                                               tmp_path: Path, world: Path) -> None:
    client = make_client()
    # a raw multipart body: the file name carries ESC and BEL as bytes (httpx would escape some)
    boundary = "attack"
    scan = (world / "velodyne" / "000000.bin").read_bytes()
    body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"name\"\r\n\r\nscan\r\n"
            f"--{boundary}\r\nContent-Disposition: form-data; name=\"files\"; "
            f"filename=\"x\x1b]0;pwned\x07.bin\"\r\nContent-Type: application/octet-stream\r\n\r\n").encode() \
        + scan + f"\r\n--{boundary}--\r\n".encode()
    reply = client.post("/api/datasets/upload", content=body,
                        headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})
    assert reply.status_code == 201, reply.text
    assert reply.json()["notes"] == "uploaded: x\\x1b]0;pwned\\x07.bin"  # escaped, as printable() writes them
    refused = client.patch("/api/datasets/scan", json={"notes": "\x1b[2J"})
    assert refused.status_code == 422 and refused.json()["detail"].startswith("notes: ")
    assert client.get("/api/datasets/scan").json()["notes"] == "uploaded: x\\x1b]0;pwned\\x07.bin"


# -- 7. a reader that aborts or hangs while an upload is inspected -----------------------------
@pytest.mark.parametrize(("work", "seconds", "said"), [(crashing_reader.abort, 60.0, "SIGABRT"),
                                                       (crashing_reader.hang, 2.0, "longer than the limit of 2 s")])
def test_a_reader_that_aborts_or_hangs_cannot_take_the_server_down(
        make_client: Callable[..., TestClient], tmp_path: Path, world: Path, monkeypatch: pytest.MonkeyPatch,
        work: Callable[..., Any], seconds: float, said: str) -> None:
    from lidarfuzz.web.routes import datasets

    broken = UploadInspector(seconds=seconds, work=work)
    monkeypatch.setattr(datasets, "inspector", lambda memory, limit: broken)
    client = make_client()
    try:
        reply = client.post("/api/datasets/upload", data={"name": "corrupt"}, files=frames_of(world))
        assert reply.status_code == 422, reply.text
        assert said in reply.json()["detail"] and "nothing was recorded" in reply.json()["detail"]
        assert client.get("/api/health").status_code == 200  # the server is still up
        assert uploads(tmp_path / "ws") == [] and client.get("/api/datasets").json()["items"] == []
        assert broken.started == 1 and broken._process is None  # the worker is gone; the next upload starts one
    finally:
        broken.close()
