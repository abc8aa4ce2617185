"""lidarfuzz's own errors are never shown as the system's: a relation that raises on every mutant
(here gt_recall, broken on purpose) is counted as a tool error, makes no finding, and the findings
other relations made on the same mutants are drawn with the system's detections and a note that the
error was lidarfuzz's — not "the system failed here"."""

from __future__ import annotations

from html import unescape
from typing import Any

import pytest

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.results import summarise
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.oracles.relations.detection import GroundTruthRecall
from lidarfuzz.report.bev import load_pair
from lidarfuzz.report.html import render_html
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.store import Finding, Store


def _broken(self: Any, pair: Any) -> Any:
    raise IndexError("index 0 is out of bounds for axis 0 with size 0")


@pytest.fixture(scope="module")
def broken_task(tmp_path_factory: pytest.TempPathFactory) -> tuple[Store, int]:
    root = tmp_path_factory.mktemp("tool-errors")
    generate_dataset(root / "data", GenerationConfig(frames=2, seed=0), workers=1, overwrite=True)
    store = Store(root / "ws")
    # the scene turned: a bug-zoo pipeline whose ROI does not turn with it breaks equivariance (findings);
    # gt_recall runs on the same mutants and raises on each
    task_id = create_task(store, parse_campaign({
        "dataset": str(root / "data"), "sut": "classic-bug-roi-cache", "relations": ["equivariance", "gt_recall"],
        "operators": [{"name": "rotate_z", "severities": [3]}]}))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(GroundTruthRecall, "__call__", _broken)
        run_task(store, task_id, executor=InlineExecutor())
    return store, task_id


def test_a_raising_relation_is_a_tool_error_not_a_system_failure(broken_task: tuple[Store, int]) -> None:
    store, task_id = broken_task
    summary = summarise(store, task_id)
    mutated = summary.subtasks[1]
    assert mutated.tool_errors == {"oracle_error": 2}  # both frames' mutants
    assert mutated.failures == 0 and summary.findings.by_kind.get("oracle_error", 0) == 0
    html = unescape(render_html(summary))
    assert "lidarfuzz's own errors, not the system's: 2 frames where a relation failed" in html
    assert "The system never crashed, timed out or returned invalid output." in html


def test_a_finding_on_a_mutant_with_a_tool_error_draws_the_systems_output(broken_task: tuple[Store, int]) -> None:
    store, task_id = broken_task
    with store.session() as s:
        ids = [f.id for f in s.query(Finding).filter(Finding.task_id == task_id, Finding.kind == "equivariance")]
    assert ids, "the turned scene should break the bug-zoo pipeline's equivariance"
    pair = load_pair(store, ids[0])
    assert pair.follow_detections is not None  # the system answered: it did not fail
    assert pair.tool_error.startswith("relation gt_recall: IndexError")
