"""Multi-system campaigns: a campaign naming a reference system creates and runs a reference task
on the same mutants, and the task's report (``report --baseline`` too) compares the two."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.cli.app import app
from lidarfuzz.errors import DataFormatError
from lidarfuzz.report import write_report
from lidarfuzz.store import Store

runner = CliRunner()
OPERATORS = [{"name": "rotate_z", "severities": [3]}]


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory, world: Path) -> Path:
    """Task 1: the ROI-cache variant (rotate_z reveals it), task 2 its reference classic, run first;
    task 3: classic with no reference."""
    ws = tmp_path_factory.mktemp("reference") / "ws"
    store = Store(ws)
    main = create_task(store, parse_campaign({"dataset": str(world), "sut": "classic-bug-roi-cache",
                                              "reference": "classic", "operators": OPERATORS, "trials": 2}))
    for task in [*get_task(store, main).options.references, main]:
        run_task(store, task, executor=InlineExecutor())
    run_task(store, create_task(store, parse_campaign({"dataset": str(world), "sut": "classic",
                                                       "operators": OPERATORS, "trials": 2})),
             executor=InlineExecutor())
    store.close()
    return ws


@pytest.fixture(scope="module")
def store(workspace: Path):
    opened = Store(workspace)
    yield opened
    opened.close()


def test_the_campaign_links_its_reference_task(store: Store) -> None:
    main, reference = get_task(store, 1), get_task(store, 2)
    assert main.options.references == [2] and reference.options.reference_of == 1
    assert get_task(store, 3).options.references == [] and get_task(store, 3).options.reference_of is None
    assert (main.model.name, reference.model.name) == ("classic-bug-roi-cache", "classic")
    assert reference.options.frame_ids == main.options.frame_ids and reference.seed == main.seed
    assert [(s.name, s.severity, s.operator_key, s.op_index) for s in reference.subtasks] == [
        (s.name, s.severity, s.operator_key, s.op_index) for s in main.subtasks]


def test_the_report_sets_the_reference_beside_the_system(store: Store, tmp_path: Path) -> None:
    files = write_report(store, 1, tmp_path / "report", images=0)
    html = files.html.read_text(encoding="utf-8")
    assert 'id="comparison-2"' in html and "one-sided Fisher exact test" in html and "Tarone" in html
    saved = json.loads((tmp_path / "report" / "comparison-2.json").read_text(encoding="utf-8"))
    assert files.comparisons == (tmp_path / "report" / "comparison-2.json",)
    # equivariance under rotate_z: 6/6 against 0/6, any class and Car
    assert {(r["label"], r["relation"]) for r in saved["rows"] if r["significant"]} == {("rotate_z@3", "equivariance")}
    # a task without references has no comparison section
    plain = write_report(store, 3, tmp_path / "plain", images=0)
    assert "comparison-" not in plain.html.read_text(encoding="utf-8") and plain.comparisons == ()


def test_report_with_a_baseline_prints_the_comparison(workspace: Path, tmp_path: Path) -> None:
    result = runner.invoke(app, ["report", "3", "--baseline", "1", "--out", str(tmp_path / "r"),
                                 "--workspace", str(workspace)], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    # classic (A) against the variant (B): classic is never significantly above
    assert "significantly above B: 0 row(s)" in result.output
    saved = json.loads((tmp_path / "r" / "comparison-1.json").read_text(encoding="utf-8"))
    # every disagreement is the variant's: at least equivariance on all 6 rotated frames
    assert saved["disagreements_by_side"]["A"] == 0 and saved["disagreements_by_side"]["B"] >= 6
    assert f"A only 0, B only {saved['disagreements_by_side']['B']})" in " ".join(result.output.split())


def test_run_with_a_reference_creates_both_tasks(world: Path, tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    result = runner.invoke(app, ["run", "--dataset", str(world), "--sut", "classic", "--op", "rotate_z@1",
                                 "--reference", "classic-bug-roi-cache", "--detach", "--workspace", str(ws)],
                           env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "its reference: lidarfuzz resume 2" in result.output
    opened = Store(ws)
    try:
        assert get_task(opened, 1).options.references == [2]
        assert get_task(opened, 2).model.name == "classic-bug-roi-cache"
    finally:
        opened.close()


def test_an_empty_reference_is_refused_naming_the_field(world: Path) -> None:
    with pytest.raises(DataFormatError, match=r"reference.*entry 1 is empty"):
        parse_campaign({"dataset": str(world), "sut": "classic", "operators": OPERATORS,
                        "reference": ["classic", " "]})
