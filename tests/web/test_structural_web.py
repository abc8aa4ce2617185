"""A structural task in the web app: created through the API on a registered log, run by the app's
worker, its tables and views served as a page the task page embeds."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from fastapi.testclient import TestClient

from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.store import Store
from lidarfuzz.store.inventory import add_dataset
from tests.campaign.test_structural import write_log
from tests.web.conftest import TURN, register, wait_for

PROCESS = "lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process"


def test_a_structural_task_through_the_api(make_client: Callable[..., TestClient], tmp_path: Path) -> None:
    workspace = tmp_path / "ws"
    store = Store(workspace)
    add_dataset(store, "drive", write_log(tmp_path / "drive"))
    store.close()
    client = make_client(workspace)
    campaign = {"kind": "structural", "dataset": "drive", "sut": "controller", "coverage": {"targets": [PROCESS]},
                "segments": 2, "heuristics": ["greedy_edges"], "strategies": ["HGT"]}
    missing = client.post("/api/tasks", json={**campaign, "logs": ["nowhere"]})
    assert missing.status_code == 422 and "field 'logs.0': no data set named 'nowhere'" in missing.text
    reply = client.post("/api/tasks", json=campaign)
    assert reply.status_code == 201, reply.text
    task_id = reply.json()["id"]
    task = wait_for(client, task_id)
    # one field-test log, its greedy_edges base and the HGT log made from it: three units
    assert task["status"] == "done" and task["kind"] == "structural" and (task["done"], task["total"]) == (3, 3)
    page = client.get(f"/api/tasks/{task_id}/structural")
    assert page.status_code == 200 and page.headers["content-security-policy"].startswith("sandbox")
    assert f"all-nodes of {PROCESS}" in page.text and "greedy_edges agg HGT" in page.text
    assert 'class="lf-cov-source"' in page.text and "lf-cov-compare" in page.text


def test_the_structural_page_of_another_kind_of_task_is_a_conflict(make_client: Callable[..., TestClient],
                                                                   tmp_path: Path, world: Path) -> None:
    register(tmp_path / "ws", world)
    store = Store(tmp_path / "ws")
    task_id = create_task(store, parse_campaign({"dataset": "world", "sut": "classic", "operators": TURN}))
    store.close()
    reply = make_client().get(f"/api/tasks/{task_id}/structural")
    assert reply.status_code == 409 and "not a structural task" in reply.text
