"""Code coverage of a Python worker program (lidarfuzz.structural.worker_coverage): the same
per-frame requirements as the same controller measured in process."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.scene.scene import Scene
from lidarfuzz.structural.log_coverage import frame_coverage
from lidarfuzz.structural.python_coverage import CoverageRecorder
from lidarfuzz.structural.requirements import Requirement
from lidarfuzz.structural.worker_coverage import WorkerRecorder, covered_from, wrap_command
from lidarfuzz.suts.controller import ObstacleAvoidance
from lidarfuzz.suts.sequence import WorkerSequence

ROOT = Path(__file__).resolve().parents[2]
PROGRAM = ROOT / "examples" / "suts" / "sequence_worker.py"
TARGETS = ["lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process", "lidarfuzz.suts.controller.vfh"]


def test_a_worker_program_covers_per_frame_what_the_same_code_covers_in_process(sample_scenes: list[Scene]) -> None:
    controller = ObstacleAvoidance()
    here = frame_coverage(sample_scenes, controller.step, CoverageRecorder(TARGETS), reset=controller.reset)
    system = WorkerSequence(wrap_command(f"python3 {PROGRAM}", TARGETS), timeout=120)
    try:
        there = frame_coverage(sample_scenes, system.step, WorkerRecorder(system, TARGETS), reset=system.reset)
        again = frame_coverage(sample_scenes, system.step, WorkerRecorder(system, TARGETS), reset=system.reset)
    finally:
        system.close()
    assert all(here.covered) and not here.failures and not there.failures
    assert there.covered == here.covered  # frame by frame, the same requirements
    assert again.covered == here.covered  # the program's state was reset: the second log the same
    assert [o.speed for o in there.outputs] == [o.speed for o in here.outputs]


def test_the_covered_field_is_read_strictly() -> None:
    assert covered_from({"speed": 1.0}) == frozenset()  # an unwrapped worker: nothing measured
    assert covered_from({"covered": [["m:f", "edge", -3, 4]]}) == {Requirement("m:f", "edge", -3, 4)}
    with pytest.raises(LidarfuzzError, match="'covered' must hold"):
        covered_from({"covered": [["m:f", "arc", 1, 2]]})


def test_only_python_programs_are_wrapped() -> None:
    assert wrap_command("python3 -m my.worker --x 1", ["m"]).endswith("-- -m my.worker --x 1")
    assert wrap_command("prog.py", ["m"]).startswith(sys.executable)
    with pytest.raises(LidarfuzzError, match="only a Python program"):
        wrap_command("./detector --serve", ["m"])


def test_logs_select_measures_a_worker_program_as_it_measures_the_controller_in_process(kitti_log: Path,
                                                                                        tmp_path: Path) -> None:
    import json

    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app

    def select(sut: str, out: Path) -> dict[str, object]:
        result = CliRunner().invoke(app, ["logs", "select", str(kitti_log), "--sut", sut, "--target", TARGETS[0],
                                          "--size", "1", "--out", str(out), "--json"])
        assert result.exit_code == 0, result.output
        return json.loads(result.output)  # the summary record

    here = select("controller", tmp_path / "a")
    there = select(f"worker:python3 {PROGRAM}", tmp_path / "b")
    assert here == there and float(here["nodes"]) > 0.3  # process() on 3 frames: the same share either way
    assert 0 < float(here["base_nodes"]) <= 1  # type: ignore[arg-type]
