"""The task lifecycle the web app depends on: a task that was running when the server stopped is
picked up by the next server, always (also when that one starts while the old one is still shutting
down, the race a restart soon after Ctrl-C hits); a server's stop ends a run as pending in one step;
a user's stop stays a cancel; the snapshot says when the system under test is loading."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from lidarfuzz.campaign.lifecycle import INTERRUPTED_NOTE, STOPPED_NOTE
from lidarfuzz.store import Store
from lidarfuzz.store.models import Status, Task
from lidarfuzz.web.events import progress_snapshot
from lidarfuzz.web.workers import TaskWorkers
from tests.web.conftest import TURN, register, wait_for


def campaign(**extra: object) -> dict[str, object]:
    return {"dataset": "world", "sut": "classic", "operators": TURN, **extra}


def set_state(workspace: Path, task_id: int, status: Status, *, worker: str = "", error: str = "") -> None:
    """What another process leaves in the store: the task's status, its worker, a fresh heartbeat."""
    store = Store(workspace)
    with store.session() as s:
        task = s.get(Task, task_id)
        assert task is not None
        task.status, task.worker, task.error, task.heartbeat_at = status, worker, error, datetime.now(UTC)
    store.close()


@pytest.fixture
def sleeper() -> Iterator[subprocess.Popen[bytes]]:
    """A live process of this host standing for the old server (killed by the test, or at the end)."""
    process = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    yield process
    if process.poll() is None:
        process.kill()
    process.wait()


def held_by_a_live_process(make_client: Callable[..., TestClient], workspace: Path, world: Path,
                           holder: subprocess.Popen[bytes]) -> tuple[TestClient, int]:
    """A task created by a server that stopped, marked running in ``holder`` (a live process, as the
    old server shutting down is), and a new server started meanwhile: its client and the task."""
    register(workspace, world)
    first = make_client(workers=0)
    task_id = first.post("/api/tasks", json=campaign()).json()["id"]
    first.__exit__(None, None, None)
    set_state(workspace, task_id, Status.RUNNING, worker=f"{socket.gethostname()}:{holder.pid}")
    return make_client(), task_id


def test_a_restart_while_the_old_server_shuts_down_still_runs_the_task(
        make_client: Callable[..., TestClient], tmp_path: Path, world: Path,
        sleeper: subprocess.Popen[bytes]) -> None:
    # the reproduction: the new server starts while the old one (a live process) still holds the
    # task as running; the old one then ends the run as pending with STOPPED_NOTE. Before the fix
    # the new server looked only at its start and the task stayed pending until the next restart.
    workspace = tmp_path / "ws"
    second, task_id = held_by_a_live_process(make_client, workspace, world, sleeper)
    detail = second.get(f"/api/tasks/{task_id}").json()
    assert (detail["status"], detail["queued"]) == ("running", False)  # alive elsewhere: not taken
    set_state(workspace, task_id, Status.PENDING, error=STOPPED_NOTE)  # the old server's last write
    assert wait_for(second, task_id, timeout=30)["status"] == "done"


def test_a_restart_while_the_old_server_dies_with_the_task_running_still_runs_it(
        make_client: Callable[..., TestClient], tmp_path: Path, world: Path,
        sleeper: subprocess.Popen[bytes]) -> None:
    # the other ending of the race: the old server is killed (a second Ctrl-C) with the task marked
    # running and a fresh heartbeat; its process is gone, so the task is an orphan
    second, task_id = held_by_a_live_process(make_client, tmp_path / "ws", world, sleeper)
    assert second.get(f"/api/tasks/{task_id}").json()["queued"] is False
    sleeper.kill()
    sleeper.wait()
    assert wait_for(second, task_id, timeout=30)["status"] == "done"


def test_the_sweep_takes_orphans_only(tmp_path: Path, world: Path, sleeper: subprocess.Popen[bytes]) -> None:
    workspace = tmp_path / "ws"
    register(workspace, world)
    store = Store(workspace)
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task

    ids = [create_task(store, parse_campaign({**campaign(), "seed": seed, "dataset": "world"})) for seed in range(7)]
    store.close()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    host = socket.gethostname()
    set_state(workspace, ids[0], Status.PENDING, error=STOPPED_NOTE)  # a server's stop: orphan
    set_state(workspace, ids[1], Status.PENDING, error=INTERRUPTED_NOTE)  # Ctrl-C of a CLI run: orphan
    set_state(workspace, ids[2], Status.RUNNING, worker=f"{host}:{dead.stdout.strip()}")  # process gone: orphan
    set_state(workspace, ids[3], Status.RUNNING, worker=f"{host}:{sleeper.pid}")  # alive: not
    set_state(workspace, ids[4], Status.CANCELLED)  # a user's stop: not
    set_state(workspace, ids[5], Status.FAILED, error="ValueError: x")  # failed: resumed by hand only
    # ids[6]: pending as created: taken when a server starts (start()), not by the sweep
    store = Store(workspace)
    try:
        workers = TaskWorkers(store, threads=0)
        assert workers.sweep() == ids[:3]
        assert workers.sweep() == []  # queued already: once
    finally:
        store.close()


def test_a_server_stop_ends_the_run_as_pending_and_a_user_stop_as_cancelled(
        make_client: Callable[..., TestClient], tmp_path: Path, world: Path) -> None:
    workspace = tmp_path / "ws"
    register(workspace, world)
    many = [{"name": "rotate_z", "severities": [1, 2, 3, 4, 5]}, {"name": "fog", "severities": [1, 2, 3, 4, 5]}]
    client = make_client()
    stopped = client.post("/api/tasks", json=campaign(operators=many)).json()["id"]
    wait_for(client, stopped, ("running",))
    assert client.post(f"/api/tasks/{stopped}/stop").json()["status"] == "cancelled"
    detail = wait_for(client, stopped, ("cancelled",))
    assert detail["error"] == ""
    client.__exit__(None, None, None)
    store = Store(workspace)
    with store.session() as s:
        task = s.get(Task, stopped)
        assert task is not None and (task.status, task.error) == (Status.CANCELLED, "")
    store.close()


def test_the_snapshot_says_loading_until_a_unit_is_done(tmp_path: Path, world: Path) -> None:
    workspace = tmp_path / "ws"
    register(workspace, world)
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task

    store = Store(workspace)
    try:
        task_id = create_task(store, parse_campaign(campaign()))
        snapshot = progress_snapshot(store, task_id)
        assert snapshot is not None and snapshot["loading"] is False  # pending: nothing loads
        set_state(workspace, task_id, Status.RUNNING, worker=f"{socket.gethostname()}:{os.getpid()}")
        snapshot = progress_snapshot(store, task_id)
        assert snapshot is not None and snapshot["loading"] is True  # running, no unit done
        with store.session() as s:
            task = s.get(Task, task_id)
            assert task is not None
            task.done = 3  # a resumed task: units of an earlier run
        snapshot = progress_snapshot(store, task_id)
        assert snapshot is not None and snapshot["loading"] is False
        snapshot = progress_snapshot(store, task_id, loading=lambda tid: tid == task_id)  # the workers know better
        assert snapshot is not None and snapshot["loading"] is True
    finally:
        store.close()


def test_every_subtask_of_a_done_task_has_its_start_and_finish(make_client: Callable[..., TestClient],
                                                                 tmp_path: Path, world: Path) -> None:
    register(tmp_path / "ws", world)
    client = make_client()
    task_id = client.post("/api/tasks", json=campaign()).json()["id"]
    task = wait_for(client, task_id)
    assert task["status"] == "done"
    for sub in task["subtasks"]:  # the originals and rotate_z@3: set once each, start before finish
        started, finished = (datetime.fromisoformat(sub[k]) for k in ("started_at", "finished_at"))
        assert started <= finished, sub["label"]
    # a later run does not move a start: resuming a done task changes nothing
    client.post(f"/api/tasks/{task_id}/resume")
    again = client.get(f"/api/tasks/{task_id}").json()
    assert [s["started_at"] for s in again["subtasks"]] == [s["started_at"] for s in task["subtasks"]]


def test_the_api_refuses_a_share_above_one_at_its_field(make_client: Callable[..., TestClient], tmp_path: Path,
                                                         world: Path) -> None:
    register(tmp_path / "ws", world)
    client = make_client(workers=0)
    body = campaign(operators=[{"name": "rotate_z", "severities": [3]},
                               {"name": "uniform_point_deletion", "config": {"ratio_range": [0.5, 1.2]}}])
    reply = client.post("/api/tasks", json=body)
    # by hand: the second entry's ratio_range high end, a share of points, is above 1
    assert reply.status_code == 422
    assert reply.json()["detail"] == ("request body: field 'operators.1.config.ratio_range.1': uniform_point_deletion: "
                                      "Input should be less than or equal to 1")
    twice = client.post("/api/tasks", json=campaign(operators=[{"name": "fog", "severities": [1, 3]},
                                                              {"name": "fog", "severities": [3]}]))
    assert twice.status_code == 422 and "field 'operators.1': fog at severity 3 is in entry 0" in twice.json()["detail"]
    assert client.get("/api/tasks").json()["total"] == 0  # nothing created


def test_the_server_says_what_a_stop_or_resume_did_and_what_can_be_resumed(finished: tuple[TestClient, int]) -> None:
    """A done task cannot be resumed (the page shows no Resume button: ``resumable`` is the server's
    word) and both actions on it are refused with a sentence the page shows as it is."""
    client, task_id = finished
    assert client.get(f"/api/tasks/{task_id}").json()["resumable"] is False
    resumed = client.post(f"/api/tasks/{task_id}/resume").json()
    assert resumed == {"id": task_id, "status": "done", "refused": True,
                       "message": f"Resume refused: task #{task_id} it is done, nothing is left to run."}
    stopped = client.post(f"/api/tasks/{task_id}/stop").json()
    assert stopped["refused"] is True and stopped["message"] == f"Task #{task_id} is done: there is nothing to stop."
