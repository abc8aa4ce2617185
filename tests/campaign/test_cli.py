"""The campaign commands as a user runs them: run, list, status, report (with gates), replay,
cancel, resume, delete, and the errors a user meets."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.io.open import open_dataset

runner = CliRunner()


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory, world: Path) -> Path:
    ws = tmp_path_factory.mktemp("cli") / "ws"
    mutants = ws.parent / "mutants"
    result = runner.invoke(app, ["run", "--dataset", str(world), "--sut", "classic", "--op", "rotate_z@1",
                                 "--op", "fog@3", "--inline", "--save-mutants", str(mutants),
                                 "--workspace", str(ws)], env={"COLUMNS": "160"})
    assert result.exit_code == 0, result.output
    return ws


def test_run_prints_the_tables_and_writes_the_report(workspace: Path) -> None:
    report = workspace / "reports" / "task-1"
    assert {p.name for p in report.iterdir()} >= {"report.html", "report.json", "junit.xml", "ap.csv"}


def test_mutants_are_saved_as_kitti_with_their_labels_moved(workspace: Path, world: Path) -> None:
    rotated = open_dataset(workspace.parent / "mutants" / "rotate_z@1")
    original = open_dataset(world)
    assert list(rotated.frame_ids()) == list(original.frame_ids())
    a, b = original.load("000000"), rotated.load("000000")
    assert len(a.boxes) == len(b.boxes) and not b.boxes.allclose(a.boxes)  # moved with their objects


def test_list_status_and_report_with_gates(workspace: Path, world: Path, tmp_path: Path) -> None:
    listed = runner.invoke(app, ["list", "--workspace", str(workspace)], env={"COLUMNS": "160"})
    assert listed.exit_code == 0 and "done" in listed.output
    status = runner.invoke(app, ["status", "1", "--workspace", str(workspace)], env={"COLUMNS": "160"})
    assert status.exit_code == 0 and "rotate_z@1" in status.output and "fog@3" in status.output
    ok = runner.invoke(app, ["report", "1", "--quiet", "--gate", "failures>0", "--workspace", str(workspace)])
    assert ok.exit_code == 0, ok.output
    # a failing gate: a system that raises on frame 000001 crashes once per subtask (the original and
    # fog@1), so "failures>0" fails; the correct pipeline above breaks no relation on this small world
    other = ["--workspace", str(tmp_path / "ws")]
    crashed = runner.invoke(app, ["run", "--dataset", str(world), "--sut", "tests.campaign.systems:RaisesOnFrame",
                                  "--op", "fog@1", "--inline", *other], env={"COLUMNS": "160"})
    assert "system failures: {'crash': 2}" in crashed.output, crashed.output
    failing = runner.invoke(app, ["report", "1", "--quiet", "--gate", "failures>0", *other])
    assert failing.exit_code == 1 and "gates failed" in failing.output
    bad = runner.invoke(app, ["report", "1", "--gate", "ap_drop:3d>1", "--workspace", str(workspace)])
    assert isinstance(bad.exception, LidarfuzzError) and "ap_drop:3d>1" in str(bad.exception)


def test_replay_of_a_finding(world: Path, tmp_path: Path) -> None:
    from sqlalchemy import select

    from lidarfuzz.store import Finding, Store

    # the yaw-wrap variant (deterministic, stateless) breaks equivariance under a large turn; the
    # correct pipeline above breaks nothing, so there would be nothing to replay
    ws = tmp_path / "ws"
    created = runner.invoke(app, ["run", "--dataset", str(world), "--sut", "classic-bug-yaw-wrap", "--op",
                                  "rotate_z@5", "--trials", "3", "--inline", "--workspace", str(ws)])
    assert created.exit_code == 0, created.output
    with Store(ws).session() as s:
        finding = s.scalar(select(Finding.id).order_by(Finding.id))
    assert finding is not None, "yaw-wrap under rotate_z@5 should break equivariance on some of 9 mutants"
    result = runner.invoke(app, ["replay", str(finding), "--workspace", str(ws)], env={"COLUMNS": "160"})
    assert result.exit_code == 0, result.output
    # the variant is deterministic and unchanged: same system, same outputs, same verdict
    assert "system: the same" in result.output and "not reproduced" not in result.output
    assert "reproduced in" in result.output and "non-deterministic" not in result.output


def test_detached_task_is_cancelled_resumed_and_deleted(workspace: Path, world: Path) -> None:
    ws = ["--workspace", str(workspace)]
    created = runner.invoke(app, ["run", "--dataset", str(world), "--sut", "classic", "--op", "fog@1", "--detach", *ws])
    assert created.exit_code == 0 and "created task 2" in created.output
    assert "cancelled" in runner.invoke(app, ["cancel", "2", *ws]).output
    resumed = runner.invoke(app, ["resume", "2", "--inline", *ws], env={"COLUMNS": "160"})
    assert resumed.exit_code == 0, resumed.output
    assert "done" in runner.invoke(app, ["status", "2", *ws]).output
    assert runner.invoke(app, ["delete", "2", *ws]).exit_code == 0
    gone = runner.invoke(app, ["status", "2", *ws])
    assert isinstance(gone.exception, LidarfuzzError) and "no task 2" in str(gone.exception)


def test_user_errors_name_what_is_wrong(tmp_path: Path, world: Path) -> None:
    ws = ["--workspace", str(tmp_path / "ws")]
    missing = runner.invoke(app, ["run", "--dataset", str(world), *ws])
    assert isinstance(missing.exception, LidarfuzzError) and "--sut" in str(missing.exception)
    nowhere = runner.invoke(app, ["run", "--dataset", str(tmp_path / "nope"), "--sut", "classic", "--op", "fog", *ws])
    assert isinstance(nowhere.exception, LidarfuzzError) and "nope" in str(nowhere.exception)
    bad_op = runner.invoke(app, ["run", "--dataset", str(world), "--sut", "classic", "--op", "fgo", *ws])
    assert isinstance(bad_op.exception, LidarfuzzError) and "fgo" in str(bad_op.exception)
    campaign = tmp_path / "c.yaml"
    campaign.write_text(f"dataset: {world}\nsut: classic\noperators:\n  - name: fog\n    severities: [7]\n")
    bad_file = runner.invoke(app, ["run", str(campaign), *ws])
    assert isinstance(bad_file.exception, LidarfuzzError)
    assert "c.yaml" in str(bad_file.exception) and "operators.0.severities" in str(bad_file.exception)
