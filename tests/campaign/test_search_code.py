"""Searches guided by code coverage (code_nodes, code_edges) on Python systems with no network:
the classic pipeline's bug-zoo dense-cell variant and a small system whose rare branch crashes."""

from __future__ import annotations

import inspect
import multiprocessing
import shutil
import threading
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select
from typer.testing import CliRunner

from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task, list_tasks
from lidarfuzz.cli.app import app
from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.kitti import open_kitti
from lidarfuzz.store.errors import ConflictError
from lidarfuzz.store.models import Finding, FrameResult, Status
from lidarfuzz.store.store import Store
from lidarfuzz.structural.python_coverage import CoverageRecorder
from lidarfuzz.suts.bugzoo import DenseCloudCell

DENSE = "lidarfuzz.suts.bugzoo:DenseCloudCell"
CRASH = "tests.campaign.code_systems:CrowdedCrash"
# outside_roi_scatter adds up to 10,000 points: the world's frames (110-112k points) cross 115k with it
POOL = [{"name": "outside_roi_scatter"}, {"name": "intensity_scaling"}, {"name": "gaussian_noise_addition"}]


def _spec(world: Path, sut: str, target: str, budget: int = 8, **search: Any) -> Any:
    return parse_campaign({"dataset": str(world), "sut": sut, "kind": "fuzz", "operators": POOL, "seed": 0,
                           "frames": 2, "search": {"budget": budget, "guide": "code", "targets": [target],
                                                   "batch": 2, **search}})


def _rows(store: Store, task_id: int) -> list[tuple[Any, ...]]:
    task = get_task(store, task_id)
    with store.session() as s:
        rows = s.execute(select(FrameResult.frame_id, FrameResult.trial, FrameResult.params, FrameResult.failure)
                         .where(FrameResult.subtask_id.in_([sub.id for sub in task.subtasks]))
                         .order_by(FrameResult.id)).all()
    return [tuple(r) for r in rows]


def test_code_guided_fuzz_reaches_the_dense_branch(world: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    task_id = create_task(store, _spec(world, "classic-bug-dense-cell", DENSE))
    assert run_task(store, task_id).status == Status.DONE
    rows = _rows(store, task_id)
    seeds = [params for _, _, params, _ in rows if params.get("role") == "seed"]
    tests = [params for _, _, params, _ in rows if params.get("role") == "test"]
    # By hand, DenseCloudCell's code: points_xyzi is one block (1 node; entry->block, block->exit: 2 edges);
    # cluster has the `if not self._dense` block, the `return super().cluster` block and the dense block
    # (3 nodes; entry->if, if->super, if->dense, super->exit, dense->exit: 5 edges): 4 nodes, 7 edges.
    # The world's frames (110-112k points) take every block but the dense one: 3 nodes, 5 edges.
    assert seeds[-1]["coverage"] == {"code_nodes": 3 / 4, "code_edges": 5 / 7}
    assert len(tests) == 8
    accepted = [t for t in tests if t["accepted"]]
    # the first test over 115k points adds the dense block and its two edges, and nothing after it can
    assert [t["gains"] for t in accepted] == [{"code_nodes": 1, "code_edges": 2}]
    assert accepted[0]["coverage"] == {"code_nodes": 1.0, "code_edges": 1.0}
    adding = {"outside_roi_scatter", "gaussian_noise_addition"}  # the pool's operators that add points
    assert adding & {step["operator"] for step in accepted[0]["params"]["steps"]}
    summary = get_task(store, task_id).summary
    assert summary is not None and summary.search is not None
    assert summary.search.coverage == {"code_nodes": 1.0, "code_edges": 1.0}

    # the accepted test, replayed under the recorder: the new arcs are the dense branch's
    from lidarfuzz.operators.registry import from_spec

    test = next(r for r in rows if r[2].get("accepted") and r[2].get("role") == "test")
    chain = from_spec(test[2]["operator"])
    scene = open_kitti(world).load(test[0])
    mutant = chain.apply(scene, chain.parse_params(test[2]["params"]))
    assert len(mutant.points) > 115_000 >= len(scene.points)
    recorder = CoverageRecorder([DENSE])
    system = DenseCloudCell()
    _, before = recorder.record(system.detect, scene)
    _, after = recorder.record(system.detect, mutant)
    lines, first = inspect.getsourcelines(DenseCloudCell.cluster)
    branch = first + next(i for i, text in enumerate(lines) if "if not self._dense" in text)
    dense = first + next(i for i, text in enumerate(lines) if "from lidarfuzz.suts.classic.cluster" in text)
    labels = {r.label().rpartition(":")[2] for r in after - before}
    assert labels == {str(dense), f"{branch}->{dense}", f"{dense}->exit"}


def test_code_guided_search_finds_the_crash_behind_a_rare_branch(world: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    task_id = create_task(store, _spec(world, "tests.campaign.code_systems:CrowdedCrash", CRASH, budget=6))
    assert run_task(store, task_id).status == Status.DONE
    with store.session() as s:
        crashes = s.execute(select(Finding.message, FrameResult.params).join(
            FrameResult, Finding.frame_result_id == FrameResult.id).where(Finding.task_id == task_id,
                                                                          Finding.kind == "crash")).all()
    assert crashes, "reaching the rare branch runs into its bug"
    message, params = crashes[0]
    assert message.startswith("ZeroDivisionError")
    # the first crash is the first test to reach the branch: detect's `return self.crowded` block and
    # crowded's block are new (2 nodes), and so are the edges into them (if -> return, entry -> crowded)
    assert params["accepted"] and params["gains"]["code_nodes"] == 2 and params["gains"]["code_edges"] >= 2


def test_code_guided_search_resumes_exactly(world: Path, tmp_path: Path) -> None:
    whole = Store(tmp_path / "whole")
    whole_id = create_task(whole, _spec(world, CRASH, CRASH))
    run_task(whole, whole_id)
    store = Store(tmp_path / "parts")
    task_id = create_task(store, _spec(world, CRASH, CRASH))
    stop, seen = threading.Event(), []

    def progress(event: Any) -> None:
        seen.append(event)
        if len(seen) == 2:  # the seeds, then one batch
            stop.set()

    assert run_task(store, task_id, progress=progress, stop=stop).status == Status.CANCELLED
    assert run_task(store, task_id).status == Status.DONE
    assert _rows(store, task_id) == _rows(whole, whole_id)


def _run_in_child(folder: str, task_id: int) -> None:
    store = Store(folder)
    run_task(store, task_id)
    store.close()


@pytest.mark.slow
def test_code_guided_search_in_a_spawned_process_gives_the_same_tests(world: Path, tmp_path: Path) -> None:
    here = Store(tmp_path / "here")
    here_id = create_task(here, _spec(world, CRASH, CRASH))
    run_task(here, here_id)
    there = Store(tmp_path / "there")
    there_id = create_task(there, _spec(world, CRASH, CRASH))
    there.close()
    child = multiprocessing.get_context("spawn").Process(target=_run_in_child, args=(str(tmp_path / "there"),
                                                                                   there_id))
    child.start()
    child.join(120)
    assert child.exitcode == 0
    there = Store(tmp_path / "there")
    assert _rows(there, there_id) == _rows(here, here_id)


def test_code_guided_search_errors(world: Path, tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match="targets: code criteria need the code to cover"):
        parse_campaign({"dataset": str(world), "sut": "classic", "kind": "fuzz", "search": {"guide": "code"}})
    with pytest.raises(DataFormatError, match="cannot be mixed"):
        parse_campaign({"dataset": str(world), "sut": "classic", "kind": "fuzz",
                        "search": {"criteria": ["code_edges", "nc"], "guide": "code_edges", "targets": [DENSE]}})
    store = Store(tmp_path / "ws")
    with pytest.raises(ConflictError, match=r"targets: code target 'lidarfuzz\.suts\.bugzoo:Nothing'"):
        create_task(store, _spec(world, "classic", "lidarfuzz.suts.bugzoo:Nothing"))
    assert list_tasks(store) == []


def test_cli_runs_a_code_guided_search_on_the_classic_pipeline(world: Path, tmp_path: Path) -> None:
    runner = CliRunner()
    ws = ["--workspace", str(tmp_path / "ws")]
    result = runner.invoke(app, ["run", *ws, "--dataset", str(world), "--sut", "classic-bug-dense-cell", "--kind",
                                 "fuzz", "--budget", "4", "--frames", "1", "--guide", "code", "--target", DENSE,
                                 "--op", "outside_roi_scatter", "--search", "batch=2", "--inline"])
    assert result.exit_code == 0, result.output
    assert "fuzz search: code coverage" in result.output
    assert "CODE_EDGES" in result.output
    shutil.rmtree(tmp_path / "ws")
