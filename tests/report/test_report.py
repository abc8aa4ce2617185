"""The campaign report: HTML contents, offline-ness, exports, gates and JUnit XML, unfinished
tasks and a data set that moved."""

from __future__ import annotations

import csv
import json
import re
import threading
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.results import summarise
from lidarfuzz.campaign.runner import ProgressEvent, run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.report import Gate, junit_xml, parse_gate, render_html, write_report
from lidarfuzz.report.bev import load_pair
from lidarfuzz.report.charts import charts
from lidarfuzz.report.gates import check_gate, evaluate
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.store import Finding, Store
from lidarfuzz.store.contracts import TaskSummary

OPERATORS = [{"name": "rotate_z", "severities": [3]}, {"name": "uniform_noise_addition", "severities": [2, 4]}]
IMAGES = 2
PNG = "data:image/png;base64,"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> tuple[Store, int, Path]:
    root = tmp_path_factory.mktemp("report")
    data = root / "data"
    generate_dataset(data, GenerationConfig(frames=4, seed=0, sensor="HDL-64E"), workers=1, overwrite=True)
    store = Store(root / "ws")
    # a bug-zoo system (its ROI is not turned with the scene), so that the report has findings to show: the
    # correct pipeline raises none on these harmless mutants
    task_id = create_task(store, parse_campaign({"dataset": str(data), "sut": "classic-bug-roi-cache",
                                                 "operators": OPERATORS}))
    run_task(store, task_id, executor=InlineExecutor())
    return store, task_id, data


@pytest.fixture(scope="module")
def report(campaign: tuple[Store, int, Path], tmp_path_factory: pytest.TempPathFactory) -> Any:
    store, task_id, _ = campaign
    return write_report(store, task_id, tmp_path_factory.mktemp("out"), images=IMAGES)


@pytest.fixture(scope="module")
def summary(campaign: tuple[Store, int, Path]) -> TaskSummary:
    store, task_id, _ = campaign
    return summarise(store, task_id)


class Tables(HTMLParser):
    """The cell texts of every table, grouped by the nearest enclosing element with data-difficulty."""

    def __init__(self) -> None:
        super().__init__()
        self.tables: dict[tuple[str, str], list[list[str]]] = {}
        self.key: tuple[str, str] | None = None
        self.row: list[str] | None = None
        self.cell: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        found = dict(attrs)
        if tag == "div" and "data-difficulty" in found:
            self.key = (str(found["data-difficulty"]), str(found["data-points"]))
            self.tables[self.key] = []
        elif tag == "tr" and self.key is not None:
            self.row = []
        elif tag == "td" and self.row is not None:
            self.cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag == "td" and self.row is not None and self.cell is not None:
            self.row.append(" ".join("".join(self.cell).split()))
            self.cell = None
        elif tag == "tr" and self.row is not None and self.key is not None:
            self.tables[self.key].append(self.row)
            self.row = None
        elif tag == "table":
            self.key = None

    def handle_data(self, data: str) -> None:
        if self.cell is not None:
            self.cell.append(data)


def ap_rows(html: str, difficulty: str, points: str) -> dict[tuple[str, str], list[str]]:
    """(subtask label, boxes) → the class cells' leading value, from the rendered AP table."""
    parser = Tables()
    parser.feed(html)
    rows: dict[tuple[str, str], list[str]] = {}
    label = ""
    for row in parser.tables[(difficulty, points)]:
        if len(row) <= 2:  # the header (no td), or a subtask without figures: its label and a note
            continue
        if len(row) == 6:  # the first row of a subtask carries its label
            label, row = row[0], row[1:]
        rows[(label, row[0])] = [cell.split()[0] for cell in row[1:]]
    return rows


def test_html_shows_the_summary_ap_figures(report: Any, summary: TaskSummary) -> None:
    html = report.html.read_text()
    mutated = next(s for s in summary.subtasks[1:] if s.ap is not None)
    assert mutated.ap is not None
    for difficulty, points in (("moderate", "R40"), ("hard", "R11")):
        rows = ap_rows(html, difficulty, points)
        for metric, name in (("bbox", "bbox"), ("bev", "BEV"), ("3d", "3D")):
            expected = [f"{mutated.ap.ap[metric][cls][difficulty][points]:.1f}" for cls in summary.classes]
            expected.append(f"{mutated.ap.map[metric][difficulty][points]:.1f}")
            assert rows[(mutated.label, name)] == expected
    # only the default table (moderate, R40) shows without JavaScript
    assert len(re.findall(r'class="ap-table[^"]*" data-difficulty="\w+" data-points="R\d\d">', html)) == 1
    assert 'data-difficulty="moderate" data-points="R40">' in html


def test_html_is_self_contained(report: Any, summary: TaskSummary) -> None:
    html = report.html.read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", html, re.IGNORECASE)
    assert not re.search(r"url\(\s*['\"]?(https?:)?//", html)
    assert "<link" not in html and "@import" not in html
    pictures = min(IMAGES, len(summary.findings.top))
    assert pictures > 0, "the fixture campaign should have findings"
    assert html.count(PNG) == len(charts(summary)) + pictures == 3 + pictures
    for section in ("ap", "charts", "robustness", "violations", "failures", "findings"):
        assert f'id="{section}"' in html
    for finding in summary.findings.top:
        assert f"lidarfuzz replay {finding.id}" in html
    assert f"lidarfuzz report {summary.task.id}" in html


def test_exports_match_the_summary(report: Any, summary: TaskSummary) -> None:
    written = json.loads(report.json.read_text())
    assert written == summary.dump()
    assert TaskSummary.model_validate(written).dump() == written  # reads back

    def rows(path: Path) -> list[dict[str, str]]:
        with path.open(newline="") as handle:
            return list(csv.DictReader(handle))

    evaluated = [s.ap for s in summary.subtasks if s.ap is not None]
    metrics = len(evaluated[0].ap)
    assert len(rows(report.ap_csv)) == len(evaluated) * metrics * (len(summary.classes) + 1) * 3 * 2
    assert len(rows(report.delta_ap_csv)) == len(summary.delta_ap) > 0
    expected = sum(len(s.violations_total) + len(s.violations) + len(s.violations_per_object)
                   for s in summary.subtasks[1:])
    assert len(rows(report.violations_csv)) == expected
    findings = rows(report.findings_csv)
    assert len(findings) == summary.findings.total
    assert {f["kind"] for f in findings} == set(summary.findings.by_kind)
    some = next(r for r in rows(report.ap_csv) if r["class"] == "mAP" and r["metric"] == "3d")
    entry = next(s for s in summary.subtasks if s.label == some["label"])
    assert entry.ap is not None
    assert float(some["ap"]) == pytest.approx(entry.ap.map["3d"][some["difficulty"]][some["points"]])


@pytest.mark.parametrize(("rule", "fields"), [
    ("ap_drop:3d:Car:fog@3>10", {"kind": "ap_drop", "metric": "3d", "cls": "Car", "subtask": "fog@3",
                                 "difficulty": "moderate", "threshold": 10.0}),
    ("ap_drop:BEV:map:*:hard > 2.5", {"metric": "bev", "cls": "mAP", "subtask": "*", "difficulty": "hard",
                                      "threshold": 2.5}),
    ("violations:preservation>0", {"kind": "violations", "relation": "preservation", "subtask": "*",
                                   "threshold": 0.0}),
    ("violation_rate:preservation:fog>5%", {"kind": "violation_rate", "subtask": "fog", "threshold": 0.05}),
    ("violation_rate:*>0.2", {"relation": "*", "threshold": 0.2}),
    ("failures>0", {"kind": "failures", "failure_kind": "*"}),
    ("failures:timeout>2", {"failure_kind": "timeout", "threshold": 2.0}),
])
def test_parse_good_gates(rule: str, fields: dict[str, Any]) -> None:
    gate = parse_gate(rule)
    assert {k: getattr(gate, k) for k in fields} == fields


@pytest.mark.parametrize(("rule", "why"), [
    ("ap_drop:3d:Car:fog@3", "expected RULE>THRESHOLD"),
    ("ap_drop:3d:Car:fog@3>=10", "only '>'"),
    ("ap_drop:4d:Car:fog@3>10", "unknown metric '4d'"),
    ("ap_drop:3d:Truck:fog@3>10", "unknown class 'Truck'"),
    ("ap_drop:3d:Car>10", "METRIC:CLASS:SUBTASK"),
    ("ap_drop:3d:Car:fog@3:medium>10", "unknown difficulty"),
    ("violations:preservation>0.5", "whole number"),
    ("violation_rate:preservation>2", "[0, 1]"),
    ("failures:segfault>0", "unknown failure kind"),
    ("recall:Car>3", "unknown gate kind"),
    ("failures>many", "not a number"),
    ("failures>-1", "negative"),
])
def test_parse_bad_gates_names_the_rule(rule: str, why: str) -> None:
    with pytest.raises(LidarfuzzError) as caught:
        parse_gate(rule)
    assert repr(rule) in str(caught.value)
    assert why in str(caught.value)


def hand_made(drop: float) -> TaskSummary:
    """A summary with one subtask whose Car 3D AP (moderate) drops by ``drop`` points."""
    return TaskSummary.model_validate({
        "task": {"id": 7, "name": "", "status": "done", "done": 2, "total": 2,
                 "dataset": {"name": "d", "path": "/d", "format": "kitti"},
                 "model": {"name": "classic", "spec": "classic", "fingerprint": "f"}, "seed": 0},
        "classes": ["Car", "Pedestrian", "Cyclist"],
        "subtasks": [{"id": 1, "label": "original", "operator": "original", "severity": 0},
                     {"id": 2, "label": "fog@3", "operator": "fog", "severity": 3,
                      "violations_total": [{"relation": "preservation", "checked": 10, "violated": 3, "rate": 0.3}]}],
        "delta_ap": [{"label": "fog@3", "operator": "fog", "severity": 3, "metric": "3d", "class": "Car",
                      "difficulty": "moderate", "clean": 50.0, "corrupted": 50.0 - drop, "delta": -drop}],
        "violations": {"relation": [{"relation": "preservation", "checked": 10, "violated": 3, "rate": 0.3}]},
        "findings": {"by_kind": {"preservation": 3, "crash": 1}},
    })


def test_gate_evaluation() -> None:
    assert check_gate(hand_made(12.0), "ap_drop:3d:Car:fog@3>10").status == "failed"
    assert check_gate(hand_made(8.0), "ap_drop:3d:Car:fog@3>10").status == "passed"
    assert check_gate(hand_made(12.0), "ap_drop:3d:Car:*>10").status == "failed"
    assert check_gate(hand_made(12.0), "ap_drop:3d:Car:fog>10").status == "failed"  # an operator: all severities
    assert check_gate(hand_made(12.0), "ap_drop:3d:Car:fog@3:hard>10").status == "error"  # no such figure
    missing = check_gate(hand_made(12.0), "ap_drop:3d:Car:rain@3>10")
    assert missing.status == "error" and "rain@3" in missing.message
    assert check_gate(hand_made(0), "violations:preservation>2").status == "failed"
    assert check_gate(hand_made(0), "violations:preservation>3").status == "passed"
    assert check_gate(hand_made(0), "violation_rate:preservation>25%").status == "failed"
    assert check_gate(hand_made(0), "violation_rate:preservation:fog@3>0.3").status == "passed"
    assert check_gate(hand_made(0), "violations:equivariance>0").status == "error"
    assert check_gate(hand_made(0), "failures>0").status == "failed"
    assert check_gate(hand_made(0), "failures:timeout>0").status == "passed"
    failed = check_gate(hand_made(12.0), "ap_drop:3d:Car:fog@3>10")
    assert "fog@3" in failed.rows[0] and "12.0" in failed.rows[0]


def test_junit_xml_counts() -> None:
    gates = ["ap_drop:3d:Car:fog@3>10", "violations:preservation>5", "failures>0", "violations:nothing>0"]
    root = ET.fromstring(junit_xml(hand_made(12.0), gates))
    cases = root.findall("./testsuite/testcase")
    assert [c.get("name") for c in cases] == ["task finished", *gates]
    assert root.get("tests") == "5" and root.get("failures") == "2" and root.get("errors") == "1"
    failed = {c.get("name"): c.find("failure") for c in cases if c.find("failure") is not None}
    assert set(failed) == {"ap_drop:3d:Car:fog@3>10", "failures>0"}
    assert "fog@3" in (failed["ap_drop:3d:Car:fog@3>10"].text or "")
    # no gates: the task check, "no SUT failures", then informational cases that always pass
    root = ET.fromstring(junit_xml(hand_made(12.0)))
    names = [c.get("name") for c in root.iter("testcase")]
    assert names == ["task finished", "failures>0", "ap fog@3", "relation preservation"]
    assert root.get("failures") == "1"  # the crash


def test_report_gates_on_a_real_task(campaign: tuple[Store, int, Path], summary: TaskSummary,
                                     tmp_path: Path) -> None:
    store, task_id, _ = campaign
    files = write_report(store, task_id, tmp_path, gates=["violations:*>1000000", Gate("failures>0", "failures", 0)],
                         images=0)
    assert files.passed and not files.failed
    root = ET.parse(files.junit).getroot()
    assert root.get("tests") == "3" and root.get("failures") == "0" and root.get("errors") == "0"
    assert files.html.read_text().count(PNG) == len(charts(summary))
    default = [r for r in evaluate(summary) if r.informational]
    assert len(default) == len(summary.subtasks) - 1 + len(summary.violations.relation)
    with pytest.raises(LidarfuzzError, match="ap_drop:3d"):
        write_report(store, task_id, tmp_path / "never", gates=["ap_drop:3d>1"])
    assert not (tmp_path / "never").exists()


def test_pictures_mark_what_the_finding_is_about(campaign: tuple[Store, int, Path], summary: TaskSummary) -> None:
    store, _, _ = campaign
    finding_id = summary.findings.top[0].id
    pair = load_pair(store, finding_id)
    with store.session() as s:
        violations = s.get(Finding, finding_id).detail["violations"]
    assert set(pair.lost_source) == {v["source_index"] for v in violations if v["source_index"] >= 0}
    assert set(pair.spurious) == {v["follow_index"] for v in violations if v["follow_index"] >= 0}
    assert pair.mutant is not None and pair.follow_detections is not None


def test_report_when_the_data_set_moved(campaign: tuple[Store, int, Path], summary: TaskSummary,
                                        tmp_path: Path) -> None:
    store, task_id, data = campaign
    moved = data.with_name("moved")
    data.rename(moved)
    try:
        files = write_report(store, task_id, tmp_path, images=IMAGES)
    finally:
        moved.rename(data)
    html = files.html.read_text()
    assert html.count(PNG) == len(charts(summary))  # charts, no pictures
    assert html.count("No picture: frame") == min(IMAGES, len(summary.findings.top))
    assert "was the data set moved?" in html


def test_report_of_an_unfinished_task(campaign: tuple[Store, int, Path], tmp_path: Path) -> None:
    store, _, data = campaign
    task_id = create_task(store, parse_campaign({"dataset": str(data), "sut": "classic", "operators": OPERATORS}))
    stop = threading.Event()

    def progress(event: ProgressEvent) -> None:
        if event.task_done >= 6:  # the originals and part of the first mutation
            stop.set()

    run_task(store, task_id, executor=InlineExecutor(), progress=progress, stop=stop)
    files = write_report(store, task_id, tmp_path, images=1)
    summary = TaskSummary.model_validate(json.loads(files.json.read_text()))
    assert summary.task.status == "cancelled"
    assert any(s.ap is None for s in summary.subtasks)
    html = files.html.read_text()
    assert "This task is unfinished" in html and "not evaluated yet" in html
    assert not files.passed
    assert [r.name for r in files.failed] == ["task finished"]


def test_render_html_without_labels(summary: TaskSummary) -> None:
    unlabelled = json.loads(json.dumps(summary.dump()))  # as read back from report.json
    for entry in unlabelled["subtasks"]:
        entry["ap"] = None
    unlabelled["delta_ap"], unlabelled["robustness"] = [], {}
    html = render_html(TaskSummary.model_validate(unlabelled))
    pending = re.findall(r'class="pending"[^>]*>no AP: the data set has no labels<', html)
    assert len(pending) == 6 * len(summary.subtasks)  # in each difficulty × interpolation table
    assert "No robustness figures" in html
    assert html.count(PNG) == 1  # only the violation chart has something to draw


def test_report_of_a_system_that_crashes(campaign: tuple[Store, int, Path], tmp_path: Path) -> None:
    store, _, data = campaign
    task_id = create_task(store, parse_campaign({"dataset": str(data), "sut": "tests.campaign.systems:RaisesOnFrame",
                                                 "operators": [{"name": "rotate_z", "severities": [3]}]}))
    run_task(store, task_id, executor=InlineExecutor())
    files = write_report(store, task_id, tmp_path, images=12)
    summary = TaskSummary.model_validate(json.loads(files.json.read_text()))
    crashes = summary.findings.by_kind["crash"]
    assert crashes == 2  # the original and its mutant
    assert not files.passed and [r.name for r in files.failed] == ["failures>0"]
    html = files.html.read_text()
    assert re.search(rf'<td class="left">crash</td><td class="bad">{crashes}</td>', html)
    # failures come first among the findings, and have pictures too
    top = summary.findings.top
    assert [f.kind for f in top[:crashes]] == ["crash"] * crashes
    assert html.count(PNG) == len(charts(summary)) + min(12, len(top))
    pair = load_pair(store, top[0].id)
    assert (pair.mutant is None) == (top[0].operator == "original")
    assert pair.follow_detections is None


def test_html_shows_the_ap_sample_warnings(summary: TaskSummary) -> None:
    """The campaign's few objects per class are named above the AP tables, and only then."""
    assert summary.ap_warnings, "the fixture's small campaign has fewer than 41 objects of some class"
    html = render_html(summary)
    assert 'id="ap-warnings"' in html and "too few objects to score" in html
    quiet = summary.model_copy(update={"ap_warnings": []})
    assert 'id="ap-warnings"' not in render_html(quiet)
