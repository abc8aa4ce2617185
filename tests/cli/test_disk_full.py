"""A disk that fills during ``lidarfuzz run`` and ``lidarfuzz report``: one line naming what was
being written and what to do, exit code 1, the store consistent (what was committed kept), no
partial file at a final name; once there is room, ``resume`` / ``report`` end exactly as a run
that never failed.

The disk is filled by :mod:`tests.cli.faults` (the database capped at a page count: SQLite's own
"database or disk is full"; files given a byte budget: ``OSError(ENOSPC)`` from ``write``).

Expected values, by hand: the schema alone takes more than 8 pages (13 tables and their
indexes, a page each at least), so a store capped at 8 fills while it is created; originals +
rotate_z@3 + gaussian_noise_addition@2 on 2 frames = 6 units; the page cap leaves a quarter of
the room the run's results and summary take (most of it is the summary, at the end), so the run
fails after some results and before the last; report.html alone is tens of kilobytes, so a
budget of 1 byte fails on the first file and 20,000 bytes fails mid-way (on a file before or at
report.html); a report has 8 files (report.html and .json, 5 CSV files, junit.xml).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import func, select, text

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.store import FrameResult, Status, Store, Subtask
from tests.cli.faults import run_commands

OPS = ["--op", "rotate_z@3", "--op", "gaussian_noise_addition@2"]
UNITS = 6


def outputs(store: Store, task_id: int) -> dict[tuple[str, int, str, int], bytes | None]:
    with store.session() as s:
        rows = s.execute(select(Subtask.name, Subtask.severity, FrameResult.frame_id, FrameResult.trial,
                                FrameResult.boxes).join(Subtask).where(Subtask.task_id == task_id))
        return {(a, b, c, d): e for a, b, c, d, e in rows}


def pages(store: Store) -> int:
    with store.engine.connect() as connection:
        return int(connection.execute(text("PRAGMA page_count")).scalar_one())


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A data set, and an uninterrupted run of the campaign on it (its results and the store's
    size in pages before and after the run)."""
    root = tmp_path_factory.mktemp("diskfull")
    world = root / "world"
    generate_dataset(world, GenerationConfig(frames=2, seed=0), workers=1, overwrite=True)
    store = Store(root / "reference")
    task = create_task(store, parse_campaign({"dataset": str(world), "sut": "classic", "operators": [
        {"name": "rotate_z", "severities": [3]}, {"name": "gaussian_noise_addition", "severities": [2]}]}))
    before = pages(store)
    run_task(store, task, executor=InlineExecutor())
    after = pages(store)
    store.close()
    return {"world": world, "outputs": outputs(Store(root / "reference"), task), "before": before, "after": after,
            "workspace": root / "reference"}


def one_line(result: dict[str, Any]) -> str:
    err: str = result["err"]
    assert result["code"] == 1, result
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    return err


def test_run_on_a_full_disk_says_so_in_one_line_and_resume_completes_identically(
        reference: dict[str, Any], tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    cap = reference["before"] + (reference["after"] - reference["before"]) // 4  # room for a few results
    run_args = ["run", "--dataset", str(reference["world"]), "--sut", "classic", *OPS, "--inline",
                "--workspace", str(ws)]
    tiny, full = run_commands([({"store_pages": 8}, run_args), ({"store_pages": cap}, run_args)])
    # full while the new store's schema was created: nothing of it is left half-made (the next run works)
    assert one_line(tiny) == (f"error: cannot write {ws.resolve() / 'lidarfuzz.db'}: the disk is full; free space "
                              f"on that disk (or write elsewhere), then run the command again\n")
    err = one_line(full)
    assert err == (f"error: cannot write {ws.resolve() / 'lidarfuzz.db'}: the disk is full; free space on that "
                   f"disk (or write elsewhere), then run the command again; what is stored is kept: lidarfuzz "
                   f"resume 1 finishes the task\n")
    store = Store(ws)
    task = get_task(store, 1)
    with store.session() as s:
        stored = s.scalar(select(func.count()).select_from(FrameResult))
    assert task.status == Status.FAILED and 0 < task.done == stored < UNITS  # counters agree with what is stored
    assert not (ws / "reports").exists()

    resumed, = run_commands([({}, ["resume", "1", "--inline", "--workspace", str(ws)])])
    assert resumed["code"] == 0, resumed
    task = get_task(store, 1)
    assert task.status == Status.DONE and task.done == task.total == UNITS
    assert outputs(store, 1) == reference["outputs"]
    assert (ws / "reports" / "task-1" / "report.html").is_file()


def test_report_on_a_full_disk_leaves_no_partial_file(reference: dict[str, Any], tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    shutil.copytree(reference["workspace"], ws)  # a done task
    first, old = tmp_path / "first", tmp_path / "old"
    base = ["--workspace", str(ws), "--quiet"]
    whole, = run_commands([({}, ["report", "1", "--out", str(old), *base])])
    assert whole["code"] == 0, whole
    earlier = {p.name: p.read_bytes() for p in old.iterdir()}
    empty, middle = run_commands([
        ({"write_bytes": 1}, ["report", "1", "--out", str(first), *base]),  # nothing fits
        ({"write_bytes": 20_000}, ["report", "1", "--out", str(old), *base]),  # some files fit, over a report
    ])
    for failed, folder in ((empty, first), (middle, old)):
        err = one_line(failed)
        assert err.startswith(f"error: cannot write {folder}") and "the disk is full" in err
        assert err.endswith("nothing half-written is left; lidarfuzz report 1 writes it again (--out - prints "
                            "report.html)\n")
    assert list(first.iterdir()) == []  # no file, whole or partial, and no staging folder left
    assert {p.name: p.read_bytes() for p in old.iterdir()} == earlier  # the earlier report, whole
    assert "report.html" in earlier and len(earlier) >= 8  # (with room, the same command wrote every file)
