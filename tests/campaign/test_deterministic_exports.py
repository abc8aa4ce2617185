"""Identical runs give identical exports: the same campaign run inline (one unit after another) and on
two worker processes whose results come back in a shuffled order writes byte-identical CSV files
(findings with their ids and replay commands, AP, ΔAP, violations) and the same JSON summary but for
the run's own record (times, seconds, cache hits).

Before, findings were numbered in the order units finished (findings.csv and its replay commands
changed from run to run) and AP was summed over frames in that order (AOS differed in the last digit).
"""

from __future__ import annotations

import json
import random
from collections.abc import Iterable, Iterator
from pathlib import Path

import pytest

from lidarfuzz.campaign.executor import InlineExecutor, ProcessExecutor
from lidarfuzz.campaign.results import evaluate_subtask, summarise
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.campaign.work import UnitResult, WorkUnit
from lidarfuzz.report.exports import finding_rows, without_run_record, write_csvs, write_json
from lidarfuzz.store import FrameResult, Status, Store, Subtask

OPERATORS = [{"name": "rotate_z", "severities": [3]}, {"name": "uniform_point_deletion", "severities": [4]}]
#: The classic pipeline raising on frame 000001 (a crash finding on each of its units), so that the
#: findings' numbering is put to the test (a stateless system: the bug zoo's ROI cache keeps state
#: between frames, so its answers depend on which frames each process saw before).
BUGGY = "tests.campaign.systems:RaisesOnFrame"


class ShuffledPool(ProcessExecutor):
    """Two worker processes; each batch of results handed back in a seeded random order (the order
    units finish in is the scheduler's: this makes it as unlike the units' order as it gets)."""

    def __init__(self, seed: int) -> None:
        super().__init__(2)
        self.rng = random.Random(seed)

    def run(self, units: Iterable[WorkUnit]) -> Iterator[UnitResult]:
        results = list(super().run(units))
        self.rng.shuffle(results)
        yield from results


def exports(store: Store, task_id: int, out: Path) -> dict[str, bytes]:
    out.mkdir()
    summary = summarise(store, task_id)
    write_csvs(summary, out, finding_rows(store, task_id))
    write_json(summary, out / "report.json")
    files = {path.name: path.read_bytes() for path in sorted(out.iterdir())}
    files["report.json"] = json.dumps(without_run_record(json.loads(files["report.json"]))).encode()
    return files


@pytest.mark.slow
def test_inline_and_a_shuffled_pool_write_byte_identical_exports(tmp_path: Path, world: Path) -> None:
    spec = {"dataset": str(world), "sut": BUGGY, "operators": OPERATORS, "trials": 2}
    made = {}
    for name, executor in (("inline", InlineExecutor()), ("pool", ShuffledPool(seed=7))):
        store = Store(tmp_path / name)
        task_id = create_task(store, parse_campaign(spec))
        assert run_task(store, task_id, executor=executor).status == Status.DONE
        made[name] = exports(store, task_id, tmp_path / f"{name}-out")
    assert sorted(made["inline"]) == ["ap.csv", "delta_ap.csv", "findings.csv", "report.json", "violations.csv"]
    findings = made["inline"]["findings.csv"].decode().splitlines()
    assert len(findings) > 1, "the campaign should find something, or the ids are not put to the test"
    for name, content in made["inline"].items():
        assert made["pool"][name] == content, name


def test_a_subtask_s_figures_do_not_depend_on_the_order_of_its_rows(tmp_path: Path, world: Path) -> None:
    """AP (AOS included) and violation counts from a subtask's rows are the same, bit for bit, in
    any order the store returns them (before, frames were summed in the order results arrived)."""
    store = Store(tmp_path / "ws")
    spec = {"dataset": str(world), "sut": "classic", "operators": OPERATORS[:1], "trials": 2}
    task_id = create_task(store, parse_campaign(spec))
    assert run_task(store, task_id, executor=InlineExecutor()).status == Status.DONE
    from sqlalchemy import select

    from lidarfuzz.io.open import open_dataset
    from lidarfuzz.operators.registry import from_spec

    dataset = open_dataset(str(world))
    with store.session() as s:
        sub = s.scalars(select(Subtask).where(Subtask.task_id == task_id, Subtask.name == "rotate_z")).one()
        rows = list(s.execute(select(FrameResult.frame_id, FrameResult.detections, FrameResult.ground_truth,
                                     FrameResult.failure, FrameResult.relations, FrameResult.seconds,
                                     FrameResult.cached, FrameResult.params).where(FrameResult.subtask_id == sub.id)
                              .order_by(FrameResult.frame_id, FrameResult.trial)))
        operator = from_spec(sub.operator)
    assert len(rows) == 6  # 3 frames × 2 trials

    def figures(order: list[object]) -> str:
        result = evaluate_subtask(order, lambda f: dataset.load_calib(f), operator=operator)
        return json.dumps(result.model_dump(mode="json", exclude={"sut_seconds", "cached"}), sort_keys=True)

    expected = figures(rows)
    # the trials of one frame keep their order (the store's query orders by frame and trial)
    by_frame = [rows[i:i + 2] for i in range(0, 6, 2)]
    for permutation in ([2, 0, 1], [1, 2, 0], [2, 1, 0]):
        assert figures([row for i in permutation for row in by_frame[i]]) == expected
