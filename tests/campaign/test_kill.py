"""kill -9 in the middle of a campaign, then ``lidarfuzz resume``: nothing lost, nothing counted twice.

The whole process group is killed (the CLI and its worker pool), as a power cut would; the
store (SQLite in WAL mode, or PostgreSQL) must hold whole results with counters that agree,
and the resumed task must end with exactly the results of an uninterrupted run.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from sqlalchemy import func, select

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.store import FrameResult, Status, Store, Subtask

ROOT = Path(__file__).resolve().parents[2]
CLI = "from lidarfuzz.cli.app import main; main()"
OPS = ["--op", "gaussian_noise_addition@2,5", "--op", "rotate_z@3"]


def outputs(store: Store, task_id: int) -> dict[tuple[str, int, str, int], bytes | None]:
    with store.session() as s:
        rows = s.execute(select(Subtask.name, Subtask.severity, FrameResult.frame_id, FrameResult.trial,
                                FrameResult.boxes).join(Subtask).where(Subtask.task_id == task_id))
        return {(a, b, c, d): e for a, b, c, d, e in rows}


def cli(cwd: Path, *args: str, **kwargs: object) -> subprocess.Popen[str]:
    """The CLI in ``cwd`` (reports of a database-URL workspace go to ./lidarfuzz-reports), with the
    test systems importable."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return subprocess.Popen([sys.executable, "-c", CLI, *args], cwd=cwd, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, env={**os.environ, "COLUMNS": "120", "PYTHONPATH": path},
                            **kwargs)


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_kill_9_then_resume(backend: str, tmp_path: Path, world: Path, request: pytest.FixtureRequest) -> None:
    workspace = str(tmp_path / "ws") if backend == "sqlite" else request.getfixturevalue("fresh_postgres_url")
    run = cli(tmp_path, "run", "--dataset", str(world), "--sut", "tests.campaign.systems:SlowClassic",
              "--option", "delay=0.15", *OPS, "--workers", "2", "--workspace", workspace, start_new_session=True)
    store = Store(workspace)
    deadline = time.monotonic() + 120
    done = 0
    while time.monotonic() < deadline and run.poll() is None:
        try:
            with store.session() as s:
                done = s.scalar(select(func.count()).select_from(FrameResult)) or 0
        except Exception:  # the schema may not exist yet
            done = 0
        if done >= 5:
            break
        time.sleep(0.02)
    assert run.poll() is None, f"the run ended before it could be killed:\n{run.communicate()[0]}"
    os.killpg(run.pid, signal.SIGKILL)
    run.wait()

    task = get_task(store, 1)
    assert task.status == Status.RUNNING and 5 <= task.done < task.total  # died mid-way, its counters whole
    with store.session() as s:
        stored = s.scalar(select(func.count()).select_from(FrameResult))
    assert stored == task.done == sum(sub.done for sub in task.subtasks)

    resumed = cli(tmp_path, "resume", "1", "--force", "--workers", "2", "--workspace", workspace)
    log = resumed.communicate(timeout=300)[0]
    assert resumed.returncode == 0, log
    task = get_task(store, 1)
    assert task.status == Status.DONE and task.done == task.total == 12
    with store.session() as s:
        assert s.scalar(select(func.count()).select_from(FrameResult)) == 12

    reference = Store(tmp_path / "reference")
    ref_id = create_task(reference, parse_campaign({
        "dataset": str(world), "sut": "classic",
        "operators": [{"name": "gaussian_noise_addition", "severities": [2, 5]},
                      {"name": "rotate_z", "severities": [3]}]}))
    run_task(reference, ref_id, executor=InlineExecutor())
    assert outputs(store, 1) == outputs(reference, ref_id)  # the slowed classic pipeline finds the same
