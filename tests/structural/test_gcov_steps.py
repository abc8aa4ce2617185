"""Per-step code coverage of a compiled sequence system (examples/suts/c_controller/controller.c):
the program dumps its gcov counts before answering, GcovRecorder reads each step's own."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.structural.gcov import GcovRecorder
from lidarfuzz.structural.log_coverage import frame_coverage
from lidarfuzz.structural.requirements import Requirement
from lidarfuzz.suts.sequence import WorkerSequence
from tests.requirements import missing

pytestmark = pytest.mark.gcov

SOURCE = Path(__file__).resolve().parents[2] / "examples" / "suts" / "c_controller"
TEXT = (SOURCE / "controller.c").read_text().splitlines()
STEP = "controller.c:step"


def line_of(marker: str) -> int:
    """The 1-based line of the source holding ``marker`` (so the test follows edits of the file)."""
    return next(i for i, text in enumerate(TEXT, 1) if marker in text)


@pytest.fixture(scope="module")
def build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    compiler = shutil.which("gcc")
    if compiler is None or shutil.which("gcov") is None:
        missing("gcc or gcov not found", "the Debian package gcc")
    if importlib.util.find_spec("gcovr") is None:
        missing("gcovr not installed", "the gcov extra: pip install 'lidarfuzz[gcov]'")
    out = tmp_path_factory.mktemp("c_controller")
    subprocess.run([compiler, "--coverage", "-O0", "-DLIDARFUZZ_GCOV", "-o", str(out / "controller"),
                    str(SOURCE / "controller.c"), "-lm"], check=True, cwd=out)
    return out


def road(wall_at: float | None = None) -> Scene:
    """A flat road 1.73 m below the sensor; optionally a wall across the lane ``wall_at`` m ahead."""
    x, y = np.meshgrid(np.arange(2.0, 40.0, 0.5), np.arange(-6.0, 6.0, 0.5))
    points = [np.c_[x.ravel(), y.ravel(), np.full(x.size, -1.73)]]
    if wall_at is not None:
        wy, wz = np.meshgrid(np.arange(-2.0, 2.0, 0.1), np.arange(-1.5, 0.0, 0.1))
        points.append(np.c_[np.full(wy.size, wall_at), wy.ravel(), wz.ravel()])
    xyz = np.concatenate(points)
    return Scene(PointCloud(np.c_[xyz, np.zeros(len(xyz))].astype(np.float32)))


def test_each_step_covers_its_own_branches(build: Path) -> None:
    system = WorkerSequence(str(build / "controller"), timeout=30)
    try:
        recorder = GcovRecorder(system, build, SOURCE, ["controller.c:step"])
        replay = frame_coverage([road(), road(wall_at=5.0), road()], system.step, recorder, reset=system.reset)
    finally:
        system.close()
    emergency = Requirement(STEP, "node", line_of("/* EMERGENCY */"))
    slow_enter = Requirement(STEP, "node", line_of("state = SLOW;"))
    # frame 0: an empty road at 8 m/s, stopping distance 8²/6 + 2 = 12.7 m: no emergency, stays cruising
    # frame 1: a wall 5 m ahead, inside 12.7 m: the emergency stop
    # frame 2: the wall gone, in STOP: counting clear frames (1 of 3), no emergency
    assert not replay.failures
    assert [o.emergency_stop for o in replay.outputs] == [False, True, False]
    assert emergency not in replay.covered[0] and emergency in replay.covered[1] and emergency not in replay.covered[2]
    assert slow_enter not in replay.covered[0]
    assert all(r.function == STEP for step in replay.covered for r in step)  # only the target's
    assert replay.covered[0] and replay.covered[0] != replay.covered[1]  # each step's counts alone, not summed
    assert replay.covered[0] <= recorder.requirements()


def test_a_program_that_does_not_dump_is_named(build: Path, tmp_path: Path) -> None:
    script = tmp_path / "silent.py"  # speaks the protocol, never writes gcov data
    script.write_text("import sys, json\nfor line in sys.stdin:\n    if not line.strip(): break\n"
                      "    r = json.loads(line)\n"
                      "    print(json.dumps({'ok': True, 'id': r['id']} if r.get('reset') else "
                      "{'steering': 0.0, 'speed': 1.0, 'id': r['id']}), flush=True)\n")
    system = WorkerSequence(f"python3 {script}", timeout=30)
    try:
        recorder = GcovRecorder(system, build, SOURCE)
        with pytest.raises(LidarfuzzError, match="wrote no gcov data for this step"):
            recorder.record(system.step, road())
    finally:
        system.close()
    with pytest.raises(LidarfuzzError, match=r"no function of nosuch\.c"):
        GcovRecorder(system, build, SOURCE, ["nosuch.c"])


def test_logs_select_reads_a_compiled_programs_gcov_data(build: Path, kitti_log: Path) -> None:
    import json

    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app

    result = CliRunner().invoke(app, ["logs", "select", str(kitti_log), "--sut", f"worker:{build / 'controller'}",
                                      "--gcov", str(build), "--source-root", str(SOURCE), "--target", "controller.c",
                                      "--size", "1", "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert 0 < summary["log_nodes"] < 1 and 0 < summary["log_edges"] < 1  # main, step, ... partly run
    refused = CliRunner().invoke(app, ["logs", "select", str(kitti_log), "--sut", "controller", "--gcov", str(build),
                                       "--target", "controller.c"])
    assert refused.exit_code != 0 and "--gcov measures a compiled worker: program" in str(refused.exception)


def test_a_structural_campaign_on_a_compiled_program(build: Path, kitti_log: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app

    result = CliRunner().invoke(app, [
        "run", "--kind", "structural", "--dataset", str(kitti_log), "--sut", f"worker:{build / 'controller'}",
        "--gcov", str(build), "--source-root", str(SOURCE), "--target", "controller.c:step",
        "--heuristic", "greedy_edges", "--strategy", "HGT", "--segments", "1", "--workspace", str(tmp_path / "ws")],
        env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    # the field-test log's 3 frames ran step(): its all-nodes row is above 0 and below 100
    assert "controller.c:step" in result.output
    row = next(line for line in result.output.splitlines() if "average" in line)
    ft = float(row.split("│")[2])
    assert 0 < ft < 100
