"""The structural task kind on a six-frame log and a system counted by hand
(:mod:`tests.campaign.structural_system`): numbers, store records, resume, determinism, refusals.

The log: six frames 0.1 s apart, every point at most 1 m high. ``Gate.step`` (4 nodes, 6 edges)
then always takes the ``else`` branch: nodes 29, 33, 34 and edges entry->29, 29->33, 33->34,
34->exit — 3/4 nodes (75 %), 4/6 edges (66.7 %). Segments of 2 frames: three segments covering
the same; greedy_edges takes the first (ties go to the earliest), so the base log L' is frames 0-1
(75 %, 66.7 %). HGT inserts each frame raised by 10 m after it: those frames take the ``if``
branch (node 31, edges 29->31, 31->34), so L'' covers all (100 %), COV_Ag = 1/4 nodes, 2/6 edges.
AVG's averages stay low: nothing new.

Safety (the system reports a box whose near face is 2.5 m ahead; speed +1 a frame, 0 on a high
frame; stopping distance v²/8 + 2): the FT log's speeds 1..6 give 5 consecutive pairs, and the
speed-ups from v = 3, 4, 5 (stopping 3.125, 4, 5.125 m > 2.5 m) are violations; v = 1, 2 (2.125,
2.5 m: not nearer) hold. L' (speeds 1, 2): 1 pair, holds. HGT (1, 0, 1, 0): 3 pairs, none a
speed-up from a speed whose stopping distance exceeds 2.5 m. AVG (1, 2, 3): 2 pairs, hold.
Checked 5 + 1 + 3 + 2 = 11, violated 3.
"""

from __future__ import annotations

import re
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from sqlalchemy import func, select

from lidarfuzz.campaign.results import summarise
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.kitti import KittiWriter
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.store.models import CoverageRecord, Finding, FrameResult, Log, LogKind, Status
from lidarfuzz.store.models import Segment as SegmentRow
from lidarfuzz.store.store import Store

SYSTEM = "tests.campaign.structural_system:Gate"
TARGET = "tests.campaign.structural_system:Gate.step"


def write_log(root: Path, frames: int = 6, stamps: bool = True) -> Path:
    with KittiWriter(root) as writer:
        for i in range(frames):
            points = np.array([[5.0 + i, 0.0, 0.0, 1.0], [6.0, 1.0, 0.5, 1.0], [7.0, -1.0, 1.0, 1.0]], np.float32)
            writer.add(Scene(PointCloud(points), frame_id=f"{i:06d}", timestamp=0.1 * i if stamps else None))
    return root


@pytest.fixture
def drive(tmp_path: Path) -> Path:
    return write_log(tmp_path / "drive")


def campaign(log: Path, **more: Any) -> Any:
    values: dict[str, Any] = {"kind": "structural", "dataset": str(log), "sut": SYSTEM,
                              "coverage": {"targets": [TARGET]}, "segments": 2, "heuristics": ["greedy_edges"],
                              "strategies": ["HGT", "AVG"], **more}
    return parse_campaign(values)


def run(store: Store, spec: Any, **options: Any) -> tuple[int, Any]:
    task_id = create_task(store, spec)
    outcome = run_task(store, task_id, **options)
    return task_id, outcome


def test_the_tables_aggregated_coverage_and_relations_worked_by_hand(drive: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    task_id, outcome = run(store, campaign(drive))
    assert outcome.status == Status.DONE
    figures = summarise(store, task_id).kind_summary
    assert figures["functions"] == [TARGET]
    nodes = next(t for t in figures["tables"] if t["function"] == TARGET and t["criterion"] == "node")
    edges = next(t for t in figures["tables"] if t["function"] == TARGET and t["criterion"] == "edge")
    assert nodes["columns"] == ["FT log", "greedy_edges base", "greedy_edges agg HGT", "greedy_edges agg AVG"]
    assert nodes["total"] == 4 and edges["total"] == 6
    assert nodes["rows"] == [{"log": "drive", "values": [0.75, 0.75, 1.0, 0.75]}]
    assert edges["rows"][0]["values"] == pytest.approx([4 / 6, 4 / 6, 1.0, 4 / 6])
    assert nodes["average"] == [0.75, 0.75, 1.0, 0.75]
    hgt = {r["criterion"]: r for r in figures["aggregated"] if r["strategy"] == "HGT"}
    assert (hgt["node"]["new"], hgt["node"]["aggregated"]) == (1, 0.25)
    assert (hgt["edge"]["new"], hgt["edge"]["aggregated"]) == (2, pytest.approx(2 / 6))
    assert all(r["new"] == 0 for r in figures["aggregated"] if r["strategy"] == "AVG")
    [reduction] = figures["reduction"]
    assert (reduction["segments"], reduction["frames"], reduction["log_segments"], reduction["log_frames"]) == \
        (1, 2, 3, 6)
    assert figures["relations"]["safety"] == {"checked": 11, "violated": 3}
    assert figures["findings"] == {"safety": 3}
    with store.session() as s:
        steps = sorted(f.detail["step"] for f in s.scalars(select(Finding).where(Finding.task_id == task_id)))
        finding = s.scalars(select(Finding).where(Finding.task_id == task_id).order_by(Finding.id)).first()
        assert finding is not None
        assert finding.detail["decision_before"]["speed"] == 3.0 and finding.detail["decision_after"]["speed"] == 4.0
        assert finding.detail["frame_id"] == "000003" and finding.replay.relation["name"] == "safety"
    assert steps == [3, 4, 5]


def test_the_meta_model_holds_every_log_segment_and_coverage_record(drive: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    task_id, _ = run(store, campaign(drive))
    with store.session() as s:
        logs = {row.name: row for row in s.scalars(select(Log))}
        ft = logs[f"task-{task_id}/0:drive"]
        assert ft.kind == LogKind.FIELD_TEST and ft.frame_count == 6
        base = logs[f"task-{task_id}/0:drive/greedy_edges"]
        hgt = logs[f"task-{task_id}/0:drive/greedy_edges+HGT"]
        avg = logs[f"task-{task_id}/0:drive/greedy_edges+AVG"]
        assert (base.parent_id, base.heuristic, base.strategy, base.frame_count) == (ft.id, "greedy_edges", "none", 2)
        assert (hgt.parent_id, hgt.strategy, hgt.frame_count) == (ft.id, "HGT", 4)  # 2k frames
        assert (avg.parent_id, avg.strategy, avg.frame_count) == (ft.id, "AVG", 3)  # 2k - 1
        assert s.scalar(select(func.count()).select_from(SegmentRow)) == 3
        # FT: 2 criteria × (the log + 3 segments); each generated log: 2 criteria
        assert s.scalar(select(func.count()).select_from(CoverageRecord)) == 8 + 3 * 2
        record = s.scalar(select(CoverageRecord).where(CoverageRecord.log_id == hgt.id,
                                                       CoverageRecord.criterion == "edge"))
        assert record is not None and (record.covered_count, record.total_count) == (6, 6)
        assert record.fingerprint == s.scalar(select(CoverageRecord.fingerprint).limit(1))


def _counts(store: Store) -> tuple[int, ...]:
    with store.session() as s:
        return tuple(int(s.scalar(select(func.count()).select_from(table)) or 0)
                     for table in (Log, SegmentRow, CoverageRecord, FrameResult, Finding))


def _figures(store: Store, task_id: int) -> dict[str, Any]:
    figures = summarise(store, task_id).kind_summary
    return {key: figures[key] for key in ("tables", "aggregated", "reduction", "relations", "findings")}


def test_a_resumed_task_redoes_no_unit_and_records_nothing_twice(drive: Path, tmp_path: Path) -> None:
    whole = Store(tmp_path / "whole")
    whole_id, _ = run(whole, campaign(drive))
    store = Store(tmp_path / "ws")
    task_id = create_task(store, campaign(drive))
    stop = threading.Event()
    units: list[str] = []

    def after_unit(event: Any) -> None:
        units.append(event.label)
        if len(units) == 2:
            stop.set()  # as lidarfuzz cancel would: the run stops before its third unit

    first = run_task(store, task_id, progress=after_unit, stop=stop)
    assert first.status == Status.CANCELLED and units == ["original", "base:greedy_edges"]
    again: list[str] = []
    second = run_task(store, task_id, progress=lambda e: again.append(e.label))
    assert second.status == Status.DONE and again == ["greedy_edges+HGT", "greedy_edges+AVG"]
    assert _counts(store) == _counts(whole) == (4, 3, 14, 4, 3)
    assert _figures(store, task_id) == _figures(whole, whole_id)
    assert run_task(store, task_id).status == Status.DONE and _counts(store) == (4, 3, 14, 4, 3)


def test_the_same_seed_gives_the_same_results(drive: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    spec = campaign(drive, heuristics=["random", "decision_change"], seed=7)
    first, _ = run(store, spec)
    second, _ = run(store, spec)
    assert _figures(store, first) == _figures(store, second)


@pytest.mark.parametrize(("change", "message"), [
    ({"coverage": {"targets": ["tests.campaign.structural_system:Gate.nothing"]}}, "coverage.targets: "),
    ({"coverage": {}}, "coverage.targets: name the code to cover"),
    ({"heuristics": ["best"]}, "heuristics: unknown heuristic 'best'"),
    ({"strategies": ["XYZ"]}, "strategies"),
    ({"relations": ["preservation"]}, "relations: 'preservation' judges detections"),
    ({"sut": "classic"}, "sut: unknown sequence system 'classic'"),
])
def test_bad_campaigns_are_refused_in_one_line_naming_the_field(drive: Path, tmp_path: Path,
                                                                 change: dict[str, Any], message: str) -> None:
    store = Store(tmp_path / "ws")
    with pytest.raises((LidarfuzzError, ValueError)) as caught:
        create_task(store, campaign(drive, **change))
    text = str(caught.value)
    assert message in text and "\n" not in text.strip(), text


def test_a_log_without_order_is_refused_naming_it(tmp_path: Path) -> None:
    unordered = write_log(tmp_path / "plain", stamps=False)
    with pytest.raises(DataFormatError, match="no frame order"):
        create_task(Store(tmp_path / "ws"), campaign(unordered))


def test_several_field_test_logs_are_rows_of_the_table(drive: Path, tmp_path: Path) -> None:
    other = write_log(tmp_path / "second", frames=4)
    store = Store(tmp_path / "ws")
    task_id, _ = run(store, campaign(drive, dataset=[str(drive), str(other)], strategies=["HGT"]))
    nodes = next(t for t in summarise(store, task_id).kind_summary["tables"]
                 if t["function"] == TARGET and t["criterion"] == "node")
    # the second log (4 frames, 2 segments) covers what the first does: 3/4; its HGT log all 4
    assert nodes["rows"] == [{"log": "drive", "values": [0.75, 0.75, 1.0]},
                             {"log": "second", "values": [0.75, 0.75, 1.0]}]


def test_a_worker_program_is_measured_through_its_answers(drive: Path, tmp_path: Path) -> None:
    # the same system as a program of its own: the same coverage, hence the same tables
    worker = Path(__file__).with_name("structural_worker.py")
    store = Store(tmp_path / "ws")
    task_id, outcome = run(store, campaign(drive, sut=f"worker:python3 {worker}", strategies=["HGT"]))
    assert outcome.status == Status.DONE
    nodes = next(t for t in summarise(store, task_id).kind_summary["tables"]
                 if t["function"] == TARGET and t["criterion"] == "node")
    assert nodes["rows"] == [{"log": "drive", "values": [0.75, 0.75, 1.0]}]


def test_the_run_command_with_flags_and_with_a_campaign_file(drive: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app

    runner = CliRunner()
    ws = tmp_path / "ws"
    flags = ["run", "--kind", "structural", "--dataset", str(drive), "--sut", SYSTEM, "--target", TARGET,
             "--heuristic", "greedy_edges", "--strategy", "HGT", "--segments", "2", "--workspace", str(ws)]
    done = runner.invoke(app, flags, env={"COLUMNS": "200"})
    assert done.exit_code == 0, done.output
    # the all-nodes row: FT log 75, base 75, aggregated with HGT 100
    assert "greedy_edges agg HGT" in done.output and re.search(r"drive\s*│\s*75\.0\s*│\s*75\.0\s*│\s*100\.0\s*│",
                                                                done.output)
    assert "safety 3/9 violated" in done.output  # checked: FT 5, base 1, HGT 3 (no AVG log here)
    report = (ws / "reports" / "task-1" / "report.html").read_text()
    # a log campaign's report: its section first, no AP table, charts or robustness (a log has no AP)
    assert 'id="structural"' in report and 'id="ap"' not in report and 'id="robustness"' not in report
    assert report.index('id="structural"') < report.index('id="violations"')
    file = tmp_path / "campaign.yaml"
    file.write_text(f"kind: structural\ndataset: [{drive}]\nsut: {SYSTEM}\ncoverage: {{targets: [{TARGET}]}}\n"
                    "segments: 2\nheuristics: [greedy_edges]\nstrategies: [AVG]\n", encoding="utf-8")
    again = runner.invoke(app, ["run", str(file), "--workspace", str(ws)], env={"COLUMNS": "200"})
    assert again.exit_code == 0, again.output
    assert "greedy_edges agg AVG" in again.output
    missing = runner.invoke(app, [*flags[:7], *flags[9:]])  # no --target
    assert isinstance(missing.exception, LidarfuzzError) and str(missing.exception).startswith("--target:")
    wrong = runner.invoke(app, ["run", "--dataset", str(drive), "--sut", "classic", "--op", "fog", "--strategy",
                                "HGT", "--workspace", str(ws)])
    assert isinstance(wrong.exception, LidarfuzzError) and "--kind structural" in str(wrong.exception)


def test_a_log_that_covers_nothing_gives_empty_base_logs_not_a_failure(drive: Path, tmp_path: Path) -> None:
    # Gate.reset runs before a log, never inside a step: every step covers none of its requirements,
    # so each heuristic selects no segment, and the base and generated logs are empty (0 %)
    store = Store(tmp_path / "ws")
    reset = "tests.campaign.structural_system:Gate.reset"
    task_id, outcome = run(store, campaign(drive, coverage={"targets": [reset]}))
    assert outcome.status == Status.DONE
    figures = summarise(store, task_id).kind_summary
    nodes = next(t for t in figures["tables"] if t["function"] and t["criterion"] == "node")
    assert nodes["rows"][0]["values"] == [0.0, 0.0, 0.0, 0.0]
    assert [r["frames"] for r in figures["reduction"]] == [0]


@pytest.mark.slow
def test_the_controller_on_a_simulated_drive_log_twice_with_the_same_seed(tmp_path: Path) -> None:
    # 30 VLP-16 frames of a simulated drive, the controller's two main methods: the same records twice,
    # and tables of the paper's form whose aggregated columns never fall below their base
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset

    log = tmp_path / "drive"
    generate_dataset(log, GenerationConfig(frames=30, seed=1, drive=True, sensor="VLP-16"), workers=1)
    targets = ["lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process",
               "lidarfuzz.suts.controller.vfh:VFH.calculate"]
    spec = parse_campaign({"kind": "structural", "dataset": str(log), "sut": "controller",
                           "coverage": {"targets": targets}, "heuristics": ["greedy_edges", "decision_change"],
                           "strategies": ["HGT", "AVG"], "seed": 3})
    store = Store(tmp_path / "ws")
    first, outcome = run(store, spec)
    second, _ = run(store, spec)
    assert outcome.status == Status.DONE
    assert _figures(store, first) == _figures(store, second)
    figures = summarise(store, first).kind_summary
    assert figures["functions"] == sorted(targets)
    for table in figures["tables"]:
        [row] = table["rows"]
        base, *aggregated = row["values"][1:4]
        assert all(value >= base for value in aggregated), table  # L' ∪ L'' covers at least what L' does
    assert figures["relations"]["safety"]["checked"] > 0


def test_a_finding_of_a_log_is_not_replayed_alone(drive: Path, tmp_path: Path) -> None:
    from lidarfuzz.campaign.replay import ReplayError, replay_finding

    store = Store(tmp_path / "ws")
    task_id, _ = run(store, campaign(drive))
    with store.session() as s:
        finding_id = s.scalar(select(Finding.id).where(Finding.task_id == task_id).limit(1))
    assert finding_id is not None
    with pytest.raises(ReplayError, match=r"is a step of a log .* replay the log in order: lidarfuzz logs select"):
        replay_finding(store, finding_id)
