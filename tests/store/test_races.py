"""Races on one store: processes creating and migrating a brand-new workspace at once, and two
runners resuming one task at once.

Expected values, worked out by hand:

* 3 processes each create one campaign on the same new workspace: 3 tasks, ids 1..3, each
  process's name stored once (before the migration lock, all but the first died on "table
  already exists" and their campaigns were lost; then on the data set's name, registered by both).
* The task here has 1 + 2 subtasks (originals, gaussian_noise_addition@2, rotate_z@3) × 2
  frames = 6 units. Two runners at once: the claim lets one run them (6 units), the other is
  refused naming the first's pid (or, waiting, finds the task done and runs 0): 6 units in all,
  none run twice; 6 stored results.
"""

from __future__ import annotations

import multiprocessing
import os
import socket
import subprocess
import sys
import threading
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import func, insert, select

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.store import FrameResult, Status, Store
from lidarfuzz.store.claims import claim_task, holder
from lidarfuzz.store.errors import TaskClaimedError
from lidarfuzz.store.models import TaskClaim

ROOT = Path(__file__).resolve().parents[2]
UNITS = 6  # (originals + 2 operator settings) × 2 frames


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("world") / "sim"
    generate_dataset(root, GenerationConfig(frames=2, seed=0), workers=1, overwrite=True)
    return root


@pytest.fixture(params=["sqlite", "postgresql"])
def target(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    if request.param == "sqlite":
        return str(tmp_path / "ws")
    url: str = request.getfixturevalue("fresh_postgres_url")
    return url


def campaign(world: Path, name: str, sut: str = "classic", **extra: Any) -> Any:
    return parse_campaign({"name": name, "dataset": str(world), "sut": sut, **extra,
                           "operators": [{"name": "gaussian_noise_addition", "severities": [2]},
                                         {"name": "rotate_z", "severities": [3]}]})


def _create(target: str, world: str, name: str, loaded: Any, go: Any) -> None:
    """One process: loaded, wait for the common start, open the (new) store, create a campaign."""
    loaded.release()
    go.wait(60)
    create_task(Store(target), campaign(Path(world), name))


def test_processes_creating_one_new_workspace_at_once_keep_every_campaign(target: str, world: Path) -> None:
    context = multiprocessing.get_context("fork")  # separate processes, as separate commands are (forked: cheap)
    loaded, go = context.Semaphore(0), context.Event()
    names = [f"campaign-{i}" for i in range(3)]
    processes = [context.Process(target=_create, args=(target, str(world), name, loaded, go)) for name in names]
    for process in processes:
        process.start()
    for _ in processes:
        assert loaded.acquire(timeout=60)
    go.set()  # every interpreter has imported lidarfuzz: all open the new store at once
    for process in processes:
        process.join(120)
    assert [p.exitcode for p in processes] == [0] * len(names)
    store = Store(target)
    with store.session() as s:
        from lidarfuzz.store.models import Task

        stored = s.execute(select(Task.id, Task.name).order_by(Task.id)).all()
    assert sorted(name for _, name in stored) == names
    assert [task_id for task_id, _ in stored] == [1, 2, 3]


def _run(target: str, task_id: int, wait: bool, loaded: Any, go: Any, results: Any) -> None:
    """A second runner: loaded, it starts on ``go`` (the first holds the claim); reports its units or
    its refusal."""
    store = Store(target)
    loaded.set()
    go.wait(60)
    try:
        outcome = run_task(store, task_id, executor=InlineExecutor(), wait=wait)
        results.put(("ran", outcome.stats.units, outcome.status.value))
    except TaskClaimedError as exc:
        results.put(("refused", exc.pid, str(exc)))


@pytest.mark.parametrize("wait", [pytest.param(False, id="refuses"),
                                  # resume --wait is also tested through the CLI below, on SQLite
                                  pytest.param(True, id="waits", marks=pytest.mark.slow)])
def test_two_runners_of_one_task_run_each_unit_once(target: str, world: Path, wait: bool) -> None:
    store = Store(target)
    task_id = create_task(store, campaign(world, "slow", sut="tests.campaign.systems:SlowClassic"),
                          sut_options={"delay": 0.3})
    store.engine.dispose()  # no connection of this process's pool is shared with the child
    context = multiprocessing.get_context("fork")
    loaded, go, results = context.Event(), context.Event(), context.Queue()
    second = context.Process(target=_run, args=(target, task_id, wait, loaded, go, results))
    second.start()
    assert loaded.wait(60)
    first: dict[str, Any] = {}

    def run_first() -> None:
        first["outcome"] = run_task(store, task_id, executor=InlineExecutor())

    runner = threading.Thread(target=run_first)
    runner.start()
    deadline = time.monotonic() + 60
    while holder(store, task_id) is None and time.monotonic() < deadline:
        time.sleep(0.02)
    go.set()  # the first holds the claim (for 6 × 0.3 s at least): the second tries now, mid-run
    runner.join(120)
    second.join(120)
    verdict = results.get(timeout=10)
    assert first["outcome"].status == Status.DONE and first["outcome"].stats.units == UNITS
    if wait:
        assert verdict == ("ran", 0, "done")  # it waited, then found nothing left to run
    else:
        assert verdict[0] == "refused" and verdict[1] == os.getpid()
        assert f"process {os.getpid()} on {socket.gethostname()}" in verdict[2]
    task = get_task(store, task_id)
    assert task.status == Status.DONE and task.done == task.total == UNITS
    with store.session() as s:
        assert s.scalar(select(func.count()).select_from(FrameResult)) == UNITS
    assert holder(store, task_id) is None  # released at the end


def _claim(store: Store, task_id: int, host: str, pid: int, age: float) -> None:
    moment = datetime.now(UTC) - timedelta(seconds=age)
    with store.session() as s:
        s.execute(insert(TaskClaim).values(task_id=task_id, token="theirs", host=host, pid=pid, claimed_at=moment,
                                           renewed_at=moment))


def test_a_dead_runners_claim_is_taken_over(target: str, world: Path) -> None:
    store = Store(target)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True,
                          check=True)
    gone = int(dead.stdout)  # a pid of this host whose process has exited
    ids = [create_task(store, campaign(world, f"t{i}")) for i in range(3)]
    _claim(store, ids[0], socket.gethostname(), gone, age=1.0)  # crashed a second ago: taken at once
    _claim(store, ids[1], "elsewhere", 1, age=60.0)  # another host, silent for a minute: taken
    _claim(store, ids[2], "elsewhere", 1, age=1.0)  # another host, renewed a second ago: alive
    for task_id in ids[:2]:
        with claim_task(store, task_id) as token:
            claim = holder(store, task_id)
            assert claim is not None and claim.token == token and claim.pid == os.getpid()
        assert holder(store, task_id) is None
    with pytest.raises(TaskClaimedError, match=r"task 3 is being run by process 1 on elsewhere since"), \
            claim_task(store, ids[2]):
        pass
    with claim_task(store, ids[2], take_over=True):  # resume --force
        assert holder(store, ids[2]).pid == os.getpid()  # type: ignore[union-attr]


def test_a_claim_is_renewed_while_held(tmp_path: Path, world: Path) -> None:
    store = Store(tmp_path / "ws")
    task_id = create_task(store, campaign(world, "t"))
    with claim_task(store, task_id, renew_every=0.05):
        first = holder(store, task_id)
        time.sleep(0.5)
        later = holder(store, task_id)
    assert first is not None and later is not None and later.renewed_at > first.renewed_at


def test_resume_refuses_in_one_line_naming_the_runner_or_waits(tmp_path: Path, world: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    from lidarfuzz.cli.app import main

    ws = tmp_path / "ws"
    store = Store(ws)
    task_id = create_task(store, campaign(world, "t"))
    argv = ["lidarfuzz", "resume", str(task_id), "--inline", "--workspace", str(ws)]
    release = threading.Event()

    def hold() -> None:
        with claim_task(store, task_id):
            release.wait(30)

    holding = threading.Thread(target=hold)
    holding.start()
    while holder(store, task_id) is None:
        time.sleep(0.01)
    try:
        with pytest.raises(SystemExit) as refused:
            sys.argv = argv
            main()
        assert refused.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1  # one line
        assert f"task {task_id} is being run by process {os.getpid()} on {socket.gethostname()} since" in err
        assert "--wait" in err
        threading.Timer(1.0, release.set).start()  # the other runner ends in a second
        with pytest.raises(SystemExit) as waited:
            sys.argv = [*argv, "--wait"]
            main()
        assert waited.value.code == 0
        assert "waiting for it" in " ".join(capsys.readouterr().out.split())  # (the console wraps at 80)
    finally:
        release.set()
        holding.join()
    assert get_task(store, task_id).status == Status.DONE
