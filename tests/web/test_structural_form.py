"""What the New task form needs to create a structural task: the registered sequence systems with
the code targets it proposes, the heuristics and strategies to choose from, which registered data
sets are logs, and a refusal naming the field when a structural task is given a data set without
order."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from fastapi.testclient import TestClient

from lidarfuzz.store import Store
from lidarfuzz.store.inventory import add_dataset
from tests.campaign.test_structural import write_log

# the controller's methods in the roles of the paper's process() and calculate() (docs/structural.md)
PROCESS = "lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process"
CALCULATE = "lidarfuzz.suts.controller.vfh:VFH.calculate"


def test_the_sequence_systems_and_what_a_structural_task_can_choose(make_client: Callable[..., TestClient]) -> None:
    reply = make_client().get("/api/sequence-systems")
    assert reply.status_code == 200
    body = reply.json()
    systems = {item["name"]: item for item in body["items"]}
    # pyproject's lidarfuzz.sequence_suts: the controller and its three bug-zoo variants
    assert {"controller", "controller-bug-linear-stop", "controller-bug-sticky-block",
            "controller-bug-left-sector"} <= set(systems)
    assert systems["controller"]["targets"] == [PROCESS, CALCULATE]
    assert systems["controller"]["description"].startswith("Obstacle avoidance")
    assert systems["controller-bug-linear-stop"]["targets"] == [PROCESS, CALCULATE]  # a subclass: the same methods
    assert "classic" not in systems  # a per-frame detector is not a sequence system
    assert [h["name"] for h in body["heuristics"]] == ["greedy_edges", "greedy_nodes", "budget", "decision_change",
                                                       "random"]
    assert [s["name"] for s in body["strategies"]] == ["HGT", "AVG"]
    assert body["segments"] == 5


def test_which_data_sets_are_logs(make_client: Callable[..., TestClient], tmp_path: Path) -> None:
    workspace = tmp_path / "ws"
    store = Store(workspace)
    add_dataset(store, "drive", write_log(tmp_path / "drive", frames=4))
    add_dataset(store, "frames", write_log(tmp_path / "frames", frames=3, stamps=False))  # no timestamps.txt
    store.close()
    reply = make_client(workspace).get("/api/datasets/logs")
    assert reply.status_code == 200
    body = reply.json()
    assert body["items"] == [{"name": "drive", "frame_count": 4, "order": "timestamps", "format": "kitti"}]
    assert [r["name"] for r in body["refused"]] == ["frames"]
    assert body["refused"][0]["reason"].startswith("not a log: a KITTI-layout folder without timestamps.txt")


def test_a_structural_task_on_a_data_set_without_order_is_refused_naming_the_field(
        make_client: Callable[..., TestClient], tmp_path: Path) -> None:
    workspace = tmp_path / "ws"
    store = Store(workspace)
    add_dataset(store, "drive", write_log(tmp_path / "drive", frames=4))
    add_dataset(store, "frames", write_log(tmp_path / "frames", frames=3, stamps=False))
    store.close()
    client = make_client(workspace)
    campaign = {"kind": "structural", "sut": "controller", "coverage": {"targets": [PROCESS]}}
    first = client.post("/api/tasks", json={**campaign, "dataset": "frames"})
    assert first.status_code == 422
    assert first.json()["detail"].startswith("request body: field 'dataset': data set 'frames': not a log")
    further = client.post("/api/tasks", json={**campaign, "dataset": "drive", "logs": ["frames"]})
    assert further.status_code == 422 and "field 'logs.0': data set 'frames': not a log" in further.text
    detector = client.post("/api/tasks", json={**campaign, "dataset": "drive", "sut": "classic"})
    detail = detector.json()["detail"]
    assert detector.status_code == 422 and detail.startswith("sut: unknown sequence system 'classic'"), detail
    assert client.get("/api/tasks").json()["total"] == 0  # nothing was created
