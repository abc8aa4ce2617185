"""A data set file deleted mid-run: the units that cannot read their frame are data faults — never a
failure of the system under test, never a finding, left out of AP — and ``resume``, once the file is
back, runs only them again and ends with exactly the results of an undisturbed run.

The expected figures come from that undisturbed run of the same campaign (same data, seed and
system): whatever the classic pipeline finds, a disturbed-then-resumed run must find the same.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import pytest
from sqlalchemy import func, select

from lidarfuzz.campaign import executor
from lidarfuzz.campaign.executor import InlineExecutor, _run, _start
from lidarfuzz.campaign.results import summarise
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.campaign.work import DATA_FAULT, UnitResult, WorkContext, WorkUnit
from lidarfuzz.report.gates import check_gate
from lidarfuzz.store import Finding, FrameResult, Status, Store, Subtask

OPERATORS = [{"name": "gaussian_noise_addition", "severities": [2]}, {"name": "rotate_z", "severities": [3]}]


def campaign(data: Path) -> object:
    return parse_campaign({"dataset": str(data), "sut": "classic", "operators": OPERATORS})


def move_away(victim: Path) -> None:
    victim.rename(victim.with_name(victim.name + ".away"))


def truncate(victim: Path) -> None:
    victim.write_bytes(b"\0" * 5)  # not a whole number of float32 (x, y, z, intensity) points


class DeletingExecutor(InlineExecutor):
    """Runs units inline and spoils ``victim`` (``spoil``: moved away by default) once the first
    result is out — mid-run, after the runner and the worker opened the data set, before the worker
    read the victim's frame (the first result is frame 000000's original)."""

    def __init__(self, victim: Path, spoil: Callable[[Path], None] = move_away) -> None:
        super().__init__()
        self.victim, self.spoil = victim, spoil

    def run(self, units: Iterable[WorkUnit]) -> Iterator[UnitResult]:
        for count, result in enumerate(super().run(units), start=1):
            if count == 1 and self.victim.exists():
                self.spoil(self.victim)
            yield result


def results(store: Store, task_id: int) -> dict[tuple[str, int, str, int], tuple[object, ...]]:
    """What the task found on every unit (not when or how fast)."""
    with store.session() as s:
        rows = s.execute(select(Subtask.name, Subtask.severity, FrameResult.frame_id, FrameResult.trial,
                                FrameResult.boxes, FrameResult.gt_boxes, FrameResult.failure, FrameResult.params)
                         .join(Subtask).where(Subtask.task_id == task_id))
        return {(a, b, c, d): (e, f, g, h) for a, b, c, d, e, f, g, h in rows}


def findings(store: Store, task_id: int) -> list[tuple[str, str, str]]:
    with store.session() as s:
        return sorted((a, b, c) for a, b, c in s.execute(select(Finding.kind, Finding.cls, Finding.message).where(
            Finding.task_id == task_id)))


@pytest.fixture(scope="module")
def undisturbed(tmp_path_factory: pytest.TempPathFactory, world: Path) -> tuple[Store, int]:
    store = Store(tmp_path_factory.mktemp("undisturbed"))
    task_id = create_task(store, campaign(world))
    assert run_task(store, task_id, executor=InlineExecutor()).status == Status.DONE
    return store, task_id


def test_a_deleted_frame_is_a_data_fault_and_resume_repairs_it(tmp_path: Path, world: Path,
                                                                undisturbed: tuple[Store, int]) -> None:
    data = tmp_path / "data"
    shutil.copytree(world, data)
    victim = data / "velodyne" / "000002.bin"
    store = Store(tmp_path / "ws")
    task_id = create_task(store, campaign(data))

    outcome = run_task(store, task_id, executor=DeletingExecutor(victim))
    assert outcome.status == Status.FAILED
    task = get_task(store, task_id)
    # frame 000002 under the original and both mutants: 3 units (its mutants wait for its original)
    assert task.done == task.total == 9
    assert task.error.startswith("data faults: 3 units could not read their frames (frame 000002: ")
    assert "000002.bin" in task.error
    with store.session() as s:
        faults = [r for r in s.scalars(select(FrameResult)) if r.failure is not None]
        assert [(r.frame_id, r.failure.kind) for r in faults] == [("000002", DATA_FAULT)] * 3
        assert s.scalar(select(func.count()).select_from(Finding).where(Finding.kind.in_(
            ("crash", "timeout", "invalid_output")))) == 0  # nothing blamed on the system
    summary = summarise(store, task_id)
    assert [entry.tool_errors.get(DATA_FAULT, 0) for entry in summary.subtasks] == [1, 1, 1]
    assert [entry.failures for entry in summary.subtasks] == [0, 0, 0]
    assert all(entry.ap is not None for entry in summary.subtasks)  # AP over the two frames read
    gated = [check_gate(summary, rule) for rule in ("failures>0", "failures:data_error>2")]
    assert [r.status for r in gated] == ["passed", "failed"]  # the system never failed; 3 faults > 2

    victim.with_name(victim.name + ".away").rename(victim)
    resumed = run_task(store, task_id, executor=InlineExecutor())
    assert resumed.status == Status.DONE and resumed.stats.units == 3  # only the faulted units ran again
    task = get_task(store, task_id)
    assert task.done == task.total == 9 and task.error == ""
    assert all(sub.status == Status.DONE and sub.done == sub.total for sub in task.subtasks)

    ref_store, ref_id = undisturbed
    assert results(store, task_id) == results(ref_store, ref_id)
    assert findings(store, task_id) == findings(ref_store, ref_id)
    mine, ref = summarise(store, task_id), summarise(ref_store, ref_id)
    assert mine.findings.total == ref.findings.total
    assert [e.ap for e in mine.subtasks] == [e.ap for e in ref.subtasks]  # AP to the last digit
    assert [e.tool_errors for e in mine.subtasks] == [{}, {}, {}]


def test_resume_with_the_frame_still_unreadable_keeps_the_fault(tmp_path: Path, world: Path) -> None:
    data = tmp_path / "data"
    shutil.copytree(world, data)
    victim = data / "velodyne" / "000001.bin"
    store = Store(tmp_path / "ws")
    task_id = create_task(store, campaign(data))
    assert run_task(store, task_id, executor=DeletingExecutor(victim, truncate)).status == Status.FAILED
    # the file is still broken: the three units fault again, replaced in place (no unit counted twice)
    again = run_task(store, task_id, executor=InlineExecutor())
    assert again.status == Status.FAILED and again.stats.units == 3
    with store.session() as s:
        assert s.scalar(select(func.count()).select_from(FrameResult)) == 9
        messages = [r.failure.message for r in s.scalars(select(FrameResult)) if r.failure is not None]
    assert len(messages) == 3 and all("000001.bin" in m and m.startswith("frame 000001: ") for m in messages)
    assert get_task(store, task_id).done == 9


def test_a_pool_worker_that_cannot_open_the_data_set_answers_data_faults(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    # a worker process started after the data set lost a file: before, its initializer raised, the
    # pool broke, and every unit it was given was recorded as a crash of the system under test
    for name in ("_WORKER", "_WORKER_ERROR"):  # the pool process's globals, here in the test's process
        monkeypatch.setattr(executor, name, None)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.setenv(var, os.environ.get(var, "1"))
    context = WorkContext(str(tmp_path / "gone"), "classic", {}, "")
    _start(context)
    result = _run(WorkUnit(1, "000004"))
    assert result.failure is not None and result.failure.kind == DATA_FAULT
    assert result.failure.message.startswith("frame 000004: ") and "gone" in result.failure.message


def test_the_command_line_says_a_run_with_data_faults_did_not_finish(tmp_path: Path, world: Path) -> None:
    # a frame unreadable from the start (5 bytes: no whole point): its 3 units (the original and two
    # operators) are data faults; `run` still prints and reports what ran, then fails (exit 1) naming
    # the faults, and the report says they are not the system's
    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app

    data = tmp_path / "data"
    shutil.copytree(world, data)
    truncate(data / "velodyne" / "000001.bin")
    ws = tmp_path / "ws"
    ops = [arg for op in OPERATORS for arg in ("--op", f"{op['name']}@{op['severities'][0]}")]
    result = CliRunner().invoke(app, ["run", "--dataset", str(data), "--sut", "classic", *ops, "--inline",
                                      "--workspace", str(ws)], env={"COLUMNS": "200"})
    assert result.exit_code == 1, result.output
    assert "error: task 1:" in result.output and "data fault" in result.output
    html = (ws / "reports" / "task-1" / "report.html").read_text(encoding="utf-8")
    assert "Data faults, not the system's" in html and "3 unit(s)" in html
    assert "Not the system&#39;s either: 3 units whose frame could not be read" in html
    assert "lidarfuzz resume 1</code> runs what is missing" in html
