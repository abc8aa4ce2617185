"""The web API against the real engine: tasks (created, run by the workers, watched, stopped,
resumed, deleted, resumed after a restart), reports and exports, findings, binary frames,
data sets (generated, uploaded, deleted), models, the catalogue and the offline docs."""

from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.report.bev import load_pair
from lidarfuzz.store import Status, Store, Task
from lidarfuzz.web.frames import ONLY_MUTANT, ONLY_ORIGINAL, SAME, decode
from tests.web.conftest import TURN, register, wait_for

MANY = [{"name": "gaussian_noise_addition", "severities": [1, 2, 3, 4, 5]},
        {"name": "uniform_point_deletion", "severities": [1, 2, 3, 4, 5]},
        {"name": "intensity_scaling", "severities": [1, 2, 3, 4, 5]}]


def campaign(**extra: Any) -> dict[str, Any]:
    return {"dataset": "world", "sut": "classic", "operators": TURN, **extra}


def events(text: str) -> list[tuple[str, dict[str, Any]]]:
    """The (event, data) pairs of an event stream."""
    out = []
    for block in text.split("\n\n"):
        fields = dict(line.split(": ", 1) for line in block.splitlines() if ": " in line and not line.startswith(":"))
        if "event" in fields:
            out.append((fields["event"], json.loads(fields["data"])))
    return out


# -- health, docs, front end ------------------------------------------------------------------
def test_health_names_version_workspace_and_token(client: TestClient, tmp_path: Path) -> None:
    health = client.get("/api/health").json()
    assert health["workspace"] == str(tmp_path / "ws") and health["token_required"] is False
    assert health["version"] and health["workers"] == 1


def test_openapi_docs_load_nothing_from_the_network(client: TestClient) -> None:
    page = client.get("/docs")
    assert page.status_code == 200
    assert "/static/vendor/swagger-ui/swagger-ui-bundle.js" in page.text
    assert "/static/vendor/swagger-ui/swagger-ui.css" in page.text
    assert "http://" not in page.text and "https://" not in page.text  # no CDN
    for asset in ("swagger-ui-bundle.js", "swagger-ui.css"):  # bundled by the front end's build
        assert client.get(f"/static/vendor/swagger-ui/{asset}").status_code == 200
    assert client.get("/redoc").status_code == 404
    paths = client.get("/openapi.json").json()["paths"]
    for path in ("/api/tasks", "/api/tasks/{task_id}/events", "/api/findings/{finding_id}/frames",
                 "/api/datasets/upload", "/api/models/upload", "/api/operators/{name}/preview.png"):
        assert path in paths


def test_the_front_end_is_served_at_the_root_or_a_503_says_it_is_not_built(
        client: TestClient, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    import lidarfuzz.web.app as web_app

    monkeypatch.setattr(web_app, "STATIC", tmp_path / "no-static")
    page = client.get("/")
    assert page.status_code == 503 and "front end is not built" in page.text
    built = tmp_path / "static"
    built.mkdir()
    (built / "index.html").write_text("<!doctype html><title>lidarfuzz</title>", encoding="utf-8")
    monkeypatch.setattr(web_app, "STATIC", built)
    page = client.get("/")
    assert page.status_code == 200 and "<title>lidarfuzz</title>" in page.text


# -- tasks ------------------------------------------------------------------------------------
def test_a_task_is_created_run_by_the_workers_and_listed(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    listing = client.get("/api/tasks").json()
    assert listing["total"] >= 1
    row = next(item for item in listing["items"] if item["id"] == task_id)
    assert row["status"] == "done" and row["done"] == row["total"] == 4  # 2 frames: originals + 1 subtask
    assert (row["dataset"], row["model"], row["operator_count"], row["kind"]) == ("world", "classic", 1, "mutation")
    assert row["finished_at"].endswith("+00:00")
    detail = client.get(f"/api/tasks/{task_id}").json()
    assert [s["label"] for s in detail["subtasks"]] == ["original", "rotate_z@3"]
    assert all(s["status"] == "done" and s["done"] == s["total"] == 2 for s in detail["subtasks"])
    assert set(detail["subtasks"][1]["ap_moderate"]) == {"bbox", "bev", "3d", "aos"}
    assert "mAP" in detail["subtasks"][1]["ap_moderate"]["3d"]
    assert detail["summary"]["task"]["id"] == task_id and detail["running"] is None
    assert client.get("/api/tasks", params={"status": "pending"}).json()["items"] == []
    assert client.get("/api/tasks/999").status_code == 404


def test_a_task_runs_on_a_process_pool(make_client: Callable[..., TestClient], tmp_path: Path, world: Path) -> None:
    """What `lidarfuzz serve` does by default: run_task with its pool of worker processes."""
    register(tmp_path / "ws", world)
    client = make_client(inline=False, processes=1)
    task_id = client.post("/api/tasks", json=campaign()).json()["id"]
    task = wait_for(client, task_id, timeout=120)
    assert task["status"] == "done" and task["done"] == 4, task
    assert task["worker"].endswith(f":{os.getpid()}")  # claimed by this server's process
    assert client.get(f"/api/tasks/{task_id}/findings").json()["total"] > 0


def test_the_app_on_a_postgresql_store(make_client: Callable[..., TestClient], fresh_postgres_url: str,
                                      tmp_path: Path, world: Path) -> None:
    """A database URL as the workspace: the same engine; uploads, reports and caches go to ``files``."""
    client = make_client(fresh_postgres_url, files=tmp_path / "files")
    zipped = io.BytesIO()
    with zipfile.ZipFile(zipped, "w") as archive:
        for path in sorted(world.rglob("*")):
            if path.is_file():
                archive.write(path, path.relative_to(world).as_posix())
    reply = client.post("/api/datasets/upload", data={"name": "world"}, files={"files": ("w.zip", zipped.getvalue())})
    assert reply.status_code == 201, reply.text
    assert Path(reply.json()["path"]).is_relative_to((tmp_path / "files" / "uploads").resolve())
    assert client.post("/api/models", json={"name": "classic", "spec": "classic-bug-roi-cache"}).status_code == 201
    task_id = client.post("/api/tasks", json=campaign()).json()["id"]
    with client.stream("GET", f"/api/tasks/{task_id}/events") as stream:
        assert events("".join(stream.iter_text()))[-1][1]["status"] == "done"
    assert client.get(f"/api/tasks/{task_id}/findings").json()["total"] > 0
    assert client.get(f"/api/tasks/{task_id}/junit.xml").status_code == 200
    assert (tmp_path / "files" / "reports" / f"task-{task_id}" / "junit.xml").is_file()


def test_task_list_pages_newest_first(make_client: Callable[..., TestClient], tmp_path: Path, world: Path) -> None:
    register(tmp_path / "ws", world)
    client = make_client(workers=0)
    ids = [client.post("/api/tasks", json=campaign(seed=seed)).json()["id"] for seed in range(3)]
    page = client.get("/api/tasks", params={"limit": 2, "offset": 1}).json()
    assert page["total"] == 3 and [t["id"] for t in page["items"]] == [ids[1], ids[0]]
    assert [t["status"] for t in page["items"]] == ["pending", "pending"]
    assert client.get("/api/tasks", params={"status": "running"}).json()["total"] == 0
    assert client.get("/api/tasks", params={"status": "bogus"}).status_code == 422


@pytest.mark.parametrize(("body", "named"), [
    ({"dataset": "world", "sut": "classic", "operators": [{"name": "fog", "severities": [9]}]},
     "operators.0.severities"),
    ({"dataset": "world", "sut": "classic", "operators": [{"name": "no_such_operator"}]}, "operators.0.name"),
    ({"dataset": "world", "sut": "classic"}, "operators"),
    ({"dataset": "world", "sut": "classic", "operators": TURN, "speed": "fast"}, "speed"),
    ({"dataset": "nowhere", "sut": "classic", "operators": TURN}, "dataset"),
    ({"dataset": "world", "sut": "no_such_sut", "operators": TURN}, "no_such_sut"),
])
def test_a_bad_campaign_is_a_422_naming_the_key(client: TestClient, body: dict[str, Any], named: str) -> None:
    reply = client.post("/api/tasks", json=body)
    assert reply.status_code == 422, reply.text
    assert named in reply.json()["detail"]
    assert client.get("/api/tasks").json()["total"] == 0


def test_a_campaign_must_be_an_object(client: TestClient) -> None:
    assert client.post("/api/tasks", json=["dataset", "world"]).status_code == 422


def test_events_stream_progress_then_end(client: TestClient) -> None:
    task_id = client.post("/api/tasks", json=campaign()).json()["id"]
    with client.stream("GET", f"/api/tasks/{task_id}/events") as stream:
        assert stream.headers["content-type"].startswith("text/event-stream")
        seen = events("".join(stream.iter_text()))
    names = [name for name, _ in seen]
    assert names[0] == "progress" and names[-1] == "end" and names.count("end") == 1
    assert names[:-1] == ["progress"] * (len(names) - 1)
    last = seen[-1][1]
    assert last["status"] == "done" and last["done"] == last["total"] == 4
    assert [s["label"] for s in last["subtasks"]] == ["original", "rotate_z@3"]
    counts = [data["done"] for _, data in seen]
    assert counts == sorted(counts)  # counters only grow
    assert client.get("/api/tasks/12345/events").status_code == 404


def test_events_follow_a_task_another_process_runs(make_client: Callable[..., TestClient], tmp_path: Path,
                                                   world: Path) -> None:
    """The stream polls the store: it sees a task the CLI runs (here: run_task in another thread,
    as `lidarfuzz resume` would), and two browsers see the same."""
    register(tmp_path / "ws", world)
    client = make_client(workers=0)
    task_id = client.post("/api/tasks", json=campaign(operators=MANY[:1])).json()["id"]
    store = Store(tmp_path / "ws")
    runner = threading.Thread(target=run_task, args=(store, task_id), kwargs={"executor": InlineExecutor()})
    texts: list[str] = []

    def watch() -> None:
        with client.stream("GET", f"/api/tasks/{task_id}/events") as stream:
            texts.append("".join(stream.iter_text()))

    watchers = [threading.Thread(target=watch) for _ in range(2)]
    for thread in [*watchers, runner]:
        thread.start()
    for thread in [runner, *watchers]:
        thread.join(60)
    assert len(texts) == 2
    for text in texts:
        seen = events(text)
        assert seen[-1][0] == "end" and seen[-1][1]["status"] == "done" and seen[-1][1]["done"] == 12
        assert any(data["status"] == "running" or data["done"] < 12 for _, data in seen[:-1])
    store.close()


def test_stop_resume_and_delete(client: TestClient, tmp_path: Path) -> None:
    task_id = client.post("/api/tasks", json=campaign(operators=MANY)).json()["id"]
    wait_for(client, task_id, ("running",))
    reply = client.post(f"/api/tasks/{task_id}/stop")
    assert reply.status_code == 200 and reply.json() == {
        "id": task_id, "status": "cancelled", "refused": False,
        "message": f"Task #{task_id} stopped: what is done is kept; Resume goes on from there."}
    stopped = wait_for(client, task_id)
    assert stopped["status"] == "cancelled" and stopped["done"] < stopped["total"] == 32
    resumed = client.post(f"/api/tasks/{task_id}/resume").json()
    assert resumed["status"] == "pending" and not resumed["refused"]
    done = wait_for(client, task_id)
    assert done["status"] == "done" and done["done"] == 32
    client.get(f"/api/tasks/{task_id}/report.json")
    assert (tmp_path / "ws" / "reports" / f"task-{task_id}" / "report.json").is_file()
    assert client.delete(f"/api/tasks/{task_id}").status_code == 204
    assert client.get(f"/api/tasks/{task_id}").status_code == 404
    assert not (tmp_path / "ws" / "reports" / f"task-{task_id}").exists()
    assert client.post(f"/api/tasks/{task_id}/stop").status_code == 404


def test_deleting_a_running_task_stops_it_first(client: TestClient) -> None:
    task_id = client.post("/api/tasks", json=campaign(operators=MANY)).json()["id"]
    wait_for(client, task_id, ("running",))
    assert client.delete(f"/api/tasks/{task_id}").status_code == 204
    assert client.get(f"/api/tasks/{task_id}").status_code == 404
    assert client.get("/api/tasks").json()["total"] == 0


def test_a_restart_resumes_unfinished_tasks(make_client: Callable[..., TestClient], tmp_path: Path,
                                            world: Path) -> None:
    register(tmp_path / "ws", world)
    first = make_client(workers=0)  # queues, never runs
    pending = first.post("/api/tasks", json=campaign()).json()["id"]
    crashed = first.post("/api/tasks", json=campaign(seed=1)).json()["id"]
    assert first.get(f"/api/tasks/{pending}").json()["status"] == "pending"
    first.__exit__(None, None, None)
    # a task whose process died while it ran: "running", fresh heartbeat, but the pid is gone
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    store = Store(tmp_path / "ws")
    with store.session() as s:
        task = s.get(Task, crashed)
        assert task is not None
        task.status, task.worker = Status.RUNNING, f"{os.uname().nodename}:{dead.stdout.strip()}"
        task.heartbeat_at = datetime.now(UTC)
    store.close()
    second = make_client()
    assert wait_for(second, pending)["status"] == "done"
    assert wait_for(second, crashed)["status"] == "done"


def test_stopping_the_server_puts_a_running_task_back_to_pending(make_client: Callable[..., TestClient],
                                                                  tmp_path: Path, world: Path) -> None:
    register(tmp_path / "ws", world)
    first = make_client()
    task_id = first.post("/api/tasks", json=campaign(operators=MANY)).json()["id"]
    wait_for(first, task_id, ("running",))
    first.__exit__(None, None, None)
    store = Store(tmp_path / "ws")
    with store.session() as s:
        task = s.get(Task, task_id)
        assert task is not None and task.status == Status.PENDING and "server stopped" in task.error
    store.close()
    second = make_client()
    done = wait_for(second, task_id)
    assert done["status"] == "done" and done["done"] == 32


# -- reports ----------------------------------------------------------------------------------
def test_the_report_is_written_on_demand_and_cached(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    page = client.get(f"/api/tasks/{task_id}/report")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "rotate_z" in page.text and "data:image/png;base64" in page.text
    workspace = Path(client.get("/api/health").json()["workspace"])
    html = workspace / "reports" / f"task-{task_id}" / "report.html"
    written = html.stat().st_mtime_ns
    assert client.get(f"/api/tasks/{task_id}/report").text == page.text
    assert html.stat().st_mtime_ns == written  # served from the cache


def test_the_exports(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    summary = client.get(f"/api/tasks/{task_id}/report.json")
    assert summary.status_code == 200 and summary.json()["task"]["id"] == task_id
    assert f"task-{task_id}-report.json" in summary.headers["content-disposition"]
    ap = list(csv.DictReader(io.StringIO(client.get(f"/api/tasks/{task_id}/ap.csv").text)))
    assert {row["label"] for row in ap} == {"original", "rotate_z@3"}
    violations = list(csv.DictReader(io.StringIO(client.get(f"/api/tasks/{task_id}/violations.csv").text)))
    assert {"relation", "rate"} <= set(violations[0])
    findings = list(csv.DictReader(io.StringIO(client.get(f"/api/tasks/{task_id}/findings.csv").text)))
    assert len(findings) == client.get(f"/api/tasks/{task_id}/findings").json()["total"] > 0
    assert client.get(f"/api/tasks/{task_id}/delta_ap.csv").status_code == 200
    junit = ET.fromstring(client.get(f"/api/tasks/{task_id}/junit.xml").content)
    assert junit.tag == "testsuites" and any(c.get("name") == "task finished" for c in junit.iter("testcase"))
    assert client.get("/api/tasks/999/ap.csv").status_code == 404


def test_exports_are_written_again_when_the_task_changes(make_client: Callable[..., TestClient], tmp_path: Path,
                                                         world: Path) -> None:
    register(tmp_path / "ws", world)
    client = make_client(workers=0)
    task_id = client.post("/api/tasks", json=campaign()).json()["id"]
    before = client.get(f"/api/tasks/{task_id}/report.json").json()
    assert before["task"]["status"] == "pending"
    store = Store(tmp_path / "ws")
    run_task(store, task_id, executor=InlineExecutor())  # as `lidarfuzz resume` would, outside the server
    store.close()
    after = client.get(f"/api/tasks/{task_id}/report.json").json()
    assert after["task"]["status"] == "done"


# -- findings ---------------------------------------------------------------------------------
def test_findings_are_filtered_and_paged(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    everything = client.get(f"/api/tasks/{task_id}/findings").json()
    assert everything["total"] == len(everything["items"]) > 0
    facets = everything["facets"]
    assert facets["operator"] == ["rotate_z"] and "equivariance" in facets["relation"]
    for relation in facets["relation"]:
        some = client.get(f"/api/tasks/{task_id}/findings", params={"relation": relation}).json()
        assert some["total"] == sum(f["relation"] == relation for f in everything["items"])
        assert all(f["relation"] == relation for f in some["items"])
    cls = facets["class"][0]
    by_class = client.get(f"/api/tasks/{task_id}/findings", params={"cls": cls}).json()
    assert by_class["total"] == sum(f["class"] == cls for f in everything["items"])
    assert client.get(f"/api/tasks/{task_id}/findings", params={"operator": "fog"}).json()["total"] == 0
    page = client.get(f"/api/tasks/{task_id}/findings", params={"limit": 1, "offset": 1}).json()
    assert [f["id"] for f in page["items"]] == [everything["items"][1]["id"]]
    first = everything["items"][0]
    assert first["label"] == "rotate_z@3" and first["frame_id"] in ("000000", "000001")
    assert client.get("/api/tasks/999/findings").status_code == 404


def test_a_finding_with_its_replay_record(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    finding_id = client.get(f"/api/tasks/{task_id}/findings").json()["items"][0]["id"]
    finding = client.get(f"/api/findings/{finding_id}").json()
    assert finding["task_id"] == task_id and finding["replay_command"] == f"lidarfuzz replay {finding_id}"
    assert finding["replay"]["operator"]["name"] == "rotate_z" and finding["replay"]["params"]
    assert finding["detail"]["violations"]
    assert client.get("/api/findings/99999").status_code == 404


# -- binary frames ----------------------------------------------------------------------------
def _key_set(points: np.ndarray) -> set[bytes]:
    xyz = np.ascontiguousarray(points[:, :3], dtype=np.float32)
    return {row.tobytes() for row in xyz}


def test_a_findings_frames_decode_to_the_rebuilt_pair(finished: tuple[TestClient, int]) -> None:
    client, task_id = finished
    workspace = Path(client.get("/api/health").json()["workspace"])
    findings = client.get(f"/api/tasks/{task_id}/findings", params={"relation": "equivariance"}).json()["items"]
    finding_id = findings[0]["id"]
    reply = client.get(f"/api/findings/{finding_id}/frames")
    assert reply.status_code == 200 and reply.headers["content-type"] == "application/octet-stream"
    header, clouds = decode(reply.content)
    length = int.from_bytes(reply.content[4:8], "little")
    assert (8 + length) % 4 == 0
    store = Store(workspace)
    pair = load_pair(store, finding_id)
    store.close()
    assert pair.mutant is not None
    original, mutant = clouds["original"], clouds["mutant"]
    assert [c["name"] for c in header["clouds"]] == ["original", "mutant"]
    # a rotation is geometric: after ``change``, ``aligned_change`` (tests/web/test_frames_payload.py)
    assert header["clouds"][0]["channels"] == [*pair.source.points.channels, "change", "aligned_change"]
    width = len(pair.source.points.channels)
    assert original.shape == (len(pair.source.points), width + 2)
    assert mutant.shape[0] == len(pair.mutant.points)
    np.testing.assert_array_equal(original[:, :width], pair.source.points.data)
    np.testing.assert_array_equal(mutant[:, :width], pair.mutant.points.data)
    # the change flags, against sets of exact x, y, z bytes
    in_mutant, in_original = _key_set(pair.mutant.points.data), _key_set(pair.source.points.data)
    expected_original = [SAME if k in in_mutant else ONLY_ORIGINAL for k in map(bytes, np.ascontiguousarray(
        pair.source.points.data[:, :3]).view(np.dtype((np.void, 12))).ravel())]
    expected_mutant = [SAME if k in in_original else ONLY_MUTANT for k in map(bytes, np.ascontiguousarray(
        pair.mutant.points.data[:, :3]).view(np.dtype((np.void, 12))).ravel())]
    np.testing.assert_array_equal(original[:, width], expected_original)
    np.testing.assert_array_equal(mutant[:, width], expected_mutant)
    # a rotation keeps every point and moves it: as many points, and (off the axis) none where it was
    assert len(pair.mutant.points) == len(pair.source.points)
    assert int(np.sum(mutant[:, width] == ONLY_MUTANT)) > 0.99 * len(pair.mutant.points)
    # boxes and highlights
    boxes = header["boxes"]
    geometric = int(np.sum(pair.source.boxes.has_geometry))
    assert len(boxes["original"]["gt"]) == len(boxes["original"]["gt_labels"]) == geometric
    assert len(boxes["original"]["detections"]) == len(pair.source_detections)
    assert pair.follow_detections is not None
    assert len(boxes["mutant"]["detections"]) == len(boxes["mutant"]["scores"]) == len(pair.follow_detections)
    assert all(len(row) == 7 for row in boxes["original"]["gt"] + boxes["mutant"]["detections"])
    assert boxes["original"]["lost"] == sorted(pair.lost_source) and boxes["original"]["lost"]
    assert header["finding"]["id"] == finding_id and header["finding"]["has_mutant"] is True
    assert client.get("/api/findings/99999/frames").status_code == 404


def test_change_flags_match_points_bit_for_bit() -> None:
    from lidarfuzz.web.frames import change_flags

    original = np.array([[0, 0, 0, 1], [1, 2, 3, 0], [1, 2, 3, 0.5], [5, 5, 5, 0]], np.float32)
    mutant = np.array([[1, 2, 3, 9], [5, 5, 5.0001, 0], [7, 7, 7, 0]], np.float32)  # intensity does not count
    before, after = change_flags(original, mutant)
    assert before.tolist() == [ONLY_ORIGINAL, SAME, SAME, ONLY_ORIGINAL]
    assert after.tolist() == [SAME, ONLY_MUTANT, ONLY_MUTANT]
    empty = np.zeros((0, 4), np.float32)
    assert change_flags(empty, mutant)[1].tolist() == [ONLY_MUTANT] * 3
    assert change_flags(original, empty)[0].tolist() == [ONLY_ORIGINAL] * 4


def test_boxes_without_geometry_are_left_out_and_highlights_renumbered() -> None:
    from lidarfuzz.scene.boxes import Boxes3D
    from lidarfuzz.web.frames import Cloud, encode, frame_boxes

    nan = float("nan")
    gt = Boxes3D.create([[1, 0, 0], [nan, nan, nan], [9, 0, 0]], [[4, 2, 1.5]] * 3, [0, 0, 0.5],
                        ["Car", "DontCare", "Pedestrian"])
    detections = Boxes3D.create([[9, 0, 0]], [[0.8, 0.6, 1.7]], [0.5], ["Pedestrian"], scores=[0.9])
    boxes = frame_boxes(gt, detections, missing=[2], lost=[0])
    assert boxes["gt_labels"] == ["Car", "Pedestrian"] and boxes["missing"] == [1] and boxes["lost"] == [0]
    assert boxes["scores"] == [0.9] and boxes["failed"] is False
    assert frame_boxes(gt, None)["failed"] is True and frame_boxes(gt, None)["detections"] == []
    header, clouds = decode(encode([Cloud("frame", np.zeros((0, 4), np.float32), ("x", "y", "z", "intensity")),
                                    Cloud("more", np.ones((3, 5), np.float32), ("x", "y", "z", "intensity", "ring"))],
                                   {"frame": boxes}))
    assert clouds["frame"].shape == (0, 4) and clouds["more"].tolist() == [[1.0] * 5] * 3
    assert header["clouds"][1]["offset"] == 0 and header["boxes"]["frame"]["missing"] == [1]


def test_a_data_set_frame_as_binary(client: TestClient, world: Path) -> None:
    from lidarfuzz.io.open import open_dataset

    listing = client.get("/api/datasets/world/frames").json()
    # independent frames: no order, so no timestamps (a log's: tests/web/test_browser_viewer.py)
    assert listing == {"name": "world", "modality": "lidar", "total": 2, "frame_ids": ["000000", "000001"],
                       "order": None, "timestamps": None}
    assert client.get("/api/datasets/world/frames", params={"offset": 1, "limit": 5}).json()["frame_ids"] == [
        "000001"]
    reply = client.get("/api/datasets/world/frames/000001")
    header, clouds = decode(reply.content)
    scene = open_dataset(world).load("000001")
    assert header["frame_id"] == "000001" and header["dataset"] == "world"
    assert header["clouds"][0]["channels"] == list(scene.points.channels)
    np.testing.assert_array_equal(clouds["frame"], scene.points.data)
    assert header["boxes"]["frame"]["gt_labels"] == [str(v) for v in scene.boxes.labels[scene.boxes.has_geometry]]
    assert client.get("/api/datasets/world/frames/000009").status_code == 404
    assert client.get("/api/datasets/nothing/frames/000000").status_code == 404


# -- data sets --------------------------------------------------------------------------------
def test_generate_a_data_set_with_the_simulator(make_client: Callable[..., TestClient], tmp_path: Path) -> None:
    client = make_client(processes=1)
    reply = client.post("/api/datasets/generate", json={"name": "tiny", "frames": 1, "seed": 3, "sensor": "VLP-16"})
    assert reply.status_code == 202 and reply.json()["status"] == "generating"
    assert client.post("/api/datasets/generate", json={"name": "tiny", "frames": 1}).status_code == 409
    deadline = time.monotonic() + 60
    while True:
        items = client.get("/api/datasets").json()["items"]
        if (items and items[0]["status"] != "generating") or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert items[0]["status"] == "ready" and items[0]["frame_count"] == 1 and items[0]["format"] == "kitti"
    path = Path(items[0]["path"])
    assert (path / "velodyne" / "000000.bin").is_file() and path.parent == tmp_path / "ws" / "uploads"
    assert client.delete("/api/datasets/tiny").status_code == 204
    assert not path.exists() and client.get("/api/datasets").json()["items"] == []


def test_generate_a_drive_log_for_structural_tasks(make_client: Callable[..., TestClient]) -> None:
    client = make_client(processes=1)
    body = {"name": "drive", "frames": 4, "seed": 1, "sensor": "VLP-16", "scenes": "drive"}
    assert client.post("/api/datasets/generate", json=body).status_code == 202
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        items = client.get("/api/datasets").json()["items"]
        if items[0]["status"] != "generating":
            break
        time.sleep(0.1)
    assert items[0]["status"] == "ready" and "a drive log" in items[0]["notes"]
    path = Path(items[0]["path"])
    assert len((path / "timestamps.txt").read_text().splitlines()) == 4 and (path / "ego.txt").is_file()
    logs = client.get("/api/datasets/logs").json()["items"]
    assert [row["name"] for row in logs] == ["drive"]  # a log: structural tasks may replay it


@pytest.mark.parametrize(("body", "field"), [({"name": "x", "frames": 0}, "frames"),
                                             ({"name": "x", "kind": "rural"}, "kind"),
                                             ({"name": "x", "scenes": "random"}, "scenes"),
                                             ({"name": "x", "sensor": "/etc/passwd"}, "sensor")])
def test_a_bad_generation_request_is_refused(client: TestClient, body: dict[str, Any], field: str) -> None:
    reply = client.post("/api/datasets/generate", json=body)
    assert reply.status_code == 422 and field in reply.text


def test_forgetting_a_data_set(client: TestClient, world: Path) -> None:
    task_id = client.post("/api/tasks", json=campaign()).json()["id"]
    wait_for(client, task_id)
    reply = client.delete("/api/datasets/world")
    assert reply.status_code == 409 and "used by 1 task" in reply.json()["detail"]
    client.delete(f"/api/tasks/{task_id}")
    assert client.delete("/api/datasets/world").status_code == 204
    assert (world / "velodyne" / "000000.bin").is_file()  # not an upload: its files stay
    assert client.delete("/api/datasets/world").status_code == 404


# -- models -----------------------------------------------------------------------------------
def test_register_list_and_remove_models(client: TestClient) -> None:
    reply = client.post("/api/models", json={"name": "strict", "spec": "classic", "options": {"min_points": 8}})
    assert reply.status_code == 201, reply.text
    model = reply.json()
    assert model["kind"] == "builtin" and len(model["fingerprint"]) == 16 and model["options"] == {"min_points": 8}
    plugin = client.post("/api/models", json={"name": "same", "spec": "lidarfuzz.suts.classic:ClassicPipeline"})
    assert plugin.status_code == 201 and plugin.json()["kind"] == "plugin"
    names = [m["name"] for m in client.get("/api/models").json()["items"]]
    assert names == ["classic", "same", "strict"]
    assert client.post("/api/models", json={"name": "strict", "spec": "classic"}).status_code == 409
    bad = client.post("/api/models", json={"name": "typo", "spec": "clasic"})
    assert bad.status_code == 422 and "clasic" in bad.json()["detail"]
    bad_option = client.post("/api/models", json={"name": "opt", "spec": "classic", "options": {"nope": 1}})
    assert bad_option.status_code == 422 and "nope" in bad_option.json()["detail"]
    assert client.delete("/api/models/strict").status_code == 204
    assert client.delete("/api/models/strict").status_code == 404
    task_id = client.post("/api/tasks", json=campaign()).json()["id"]
    wait_for(client, task_id)
    assert client.delete("/api/models/classic").status_code == 409


def _tiny_onnx(path: Path) -> Path:
    """An ONNX graph that outputs no boxes (enough for ONNX Runtime to open it)."""
    import onnx
    from onnx import TensorProto, helper

    points = helper.make_tensor_value_info("points", TensorProto.FLOAT, [None, 4])
    boxes = helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [None, 9])
    shape = helper.make_tensor("shape", TensorProto.INT64, [2], [0, 9])
    graph = helper.make_graph([helper.make_node("ConstantOfShape", ["shape"], ["boxes"])], "empty", [points],
                              [boxes], initializer=[shape])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    onnx.save(model, path)
    return path


def test_upload_an_onnx_model(client: TestClient, tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    model = _tiny_onnx(tmp_path / "detector.onnx")
    reply = client.post("/api/models/upload", data={"name": "net", "options": json.dumps({"class_names": ["Car"]})},
                        files={"file": ("detector.onnx", model.read_bytes())})
    assert reply.status_code == 201, reply.text
    row = reply.json()
    assert row["kind"] == "onnx" and row["options"] == {"class_names": ["Car"]}
    stored = Path(row["spec"].removeprefix("onnx:"))
    assert stored.name == "model.onnx" and stored.parent.parent == (tmp_path / "ws" / "uploads").resolve()
    assert client.delete("/api/models/net").status_code == 204
    assert not stored.parent.exists()


def test_a_file_that_is_not_an_onnx_model_is_a_422(client: TestClient, tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    reply = client.post("/api/models/upload", data={"name": "junk"}, files={"file": ("junk.onnx", b"not a graph")})
    assert reply.status_code == 422 and "ONNX Runtime cannot load" in reply.json()["detail"]
    assert client.get("/api/models").json()["items"][0]["name"] == "classic"
    assert not any((tmp_path / "ws" / "uploads").iterdir())


def test_upload_an_open3d_checkpoint(client: TestClient, tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    path = tmp_path / "pointpillars.pth"
    torch.save({"model_state_dict": {"layer.weight": torch.zeros(2, 2)}}, path)
    reply = client.post("/api/models/upload", data={"name": "pp", "options": '{"config": "pointpillars_kitti"}'},
                        files={"file": ("pointpillars.pth", path.read_bytes())})
    assert reply.status_code == 201, reply.text
    assert reply.json()["kind"] == "open3d" and reply.json()["spec"].endswith("/checkpoint.pth")


def test_a_model_upload_needs_a_known_kind_and_allowed_options(client: TestClient) -> None:
    reply = client.post("/api/models/upload", data={"name": "x"}, files={"file": ("run.sh", b"#!/bin/sh\n")})
    assert reply.status_code == 422 and "kind" in reply.json()["detail"]
    reply = client.post("/api/models/upload", data={"name": "x", "options": '{"post": "os:system"}'},
                        files={"file": ("m.onnx", b"x")})
    assert reply.status_code == 422 and "options.post" in reply.json()["detail"]
    reply = client.post("/api/models/upload", data={"name": "x", "options": "[1, 2]"}, files={"file": ("m.onnx", b"x")})
    assert reply.status_code == 422


# -- catalogue --------------------------------------------------------------------------------
def test_the_operator_catalogue(client: TestClient) -> None:
    from lidarfuzz.operators import available

    families = client.get("/api/operators").json()["families"]
    operators = {op["name"]: op for family in families for op in family["operators"]}
    assert set(operators) == {name for name, cls in available().items() if cls.modality == "lidar"}
    camera = client.get("/api/operators", params={"modality": "camera"}).json()["families"]
    assert {op["name"] for family in camera for op in family["operators"]} >= {"image_fog", "image_blur"}
    assert all(op["modality"] == "camera" for family in camera for op in family["operators"])
    assert client.get("/api/operators", params={"modality": "radar"}).status_code == 422
    reply = client.get("/api/operators/image_fog/preview.png")
    assert reply.status_code == 422 and "camera operator" in reply.json()["detail"]
    assert all(op["family"] == family["family"] for family in families for op in family["operators"])
    fog = operators["fog"]
    assert fog["relation"] == "degrading" and fog["description"] and fog["severities"] == [1, 2, 3, 4, 5]
    assert fog["params_schema"]["type"] == "object" and fog["params_schema"]["properties"]
    assert all(len(row["values"]) == 6 for row in fog["severity_table"])
    assert set(fog["severity_configs"]) == {"1", "2", "3", "4", "5"}
    assert operators["gaussian_noise_addition"]["aliases"] == ["NNA"]


def test_an_operator_preview_is_drawn_once_and_cached(client: TestClient, tmp_path: Path) -> None:
    reply = client.get("/api/operators/NNA/preview.png", params={"severity": 5})
    assert reply.status_code == 200 and reply.content.startswith(b"\x89PNG")
    cached = list((tmp_path / "ws" / "cache" / "web" / "previews").glob("gaussian_noise_addition-s5-*.png"))
    assert len(cached) == 1 and cached[0].read_bytes() == reply.content
    assert client.get("/api/operators/gaussian_noise_addition/preview.png?severity=5").content == reply.content
    assert client.get("/api/operators/no_such/preview.png").status_code == 404
    assert client.get("/api/operators/fog/preview.png?severity=9").status_code == 422


def test_relations_and_suts(client: TestClient) -> None:
    relations = {r["name"]: r for r in client.get("/api/relations").json()["items"]}
    assert relations["preservation"]["applies_to"] == ["invariant"]
    assert "min_iou" in relations["equivariance"]["params_schema"]["properties"]
    suts = {s["name"] for s in client.get("/api/suts").json()["items"]}
    assert {"classic", "pillars"} <= suts
