"""``lidarfuzz eval`` option mistakes: one line naming the option and the values it takes, exit code 2,
no usage box (issue 23); class names in any case, as the devkit matches them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from tests.oracles.test_kitti_files import write_set

runner = CliRunner()


def test_bad_classes_and_overlaps_are_one_line(tmp_path: Path) -> None:
    labels, dets = write_set(tmp_path, frames=1, cars=1)
    cases = [
        (["--classes", "Car,Truck"], "error: --classes: 'Truck' is not a class; choose among Car, Pedestrian, "
                                     "Cyclist (comma-separated, any case)"),
        (["--classes", "Bus,tram"], "error: --classes: 'Bus', 'tram' are not classes; choose among"),
        (["--classes", " , "], "error: --classes: no class given; choose among Car, Pedestrian, Cyclist"),
        (["--overlaps", "tight"], "error: --overlaps: 'tight' is not one of official, loose"),
    ]
    for args, message in cases:
        result = runner.invoke(app, ["eval", str(labels), str(dets), *args])
        assert result.exit_code == 2, result.output
        assert result.output.startswith(message) and result.output.count("\n") == 1, result.output
    # the real entry point, as a user sees it: one line on stderr, nothing on stdout
    shown = subprocess.run([sys.executable, "-c", "from lidarfuzz.cli.app import main; main()", "eval",
                            str(labels), str(dets), "--overlaps", "tight"], capture_output=True, text=True, timeout=120)
    assert shown.returncode == 2 and shown.stdout == ""
    assert shown.stderr == "error: --overlaps: 'tight' is not one of official, loose\n"


def test_classes_are_taken_in_any_case(tmp_path: Path) -> None:
    # 6 cars found exactly: the table is the devkit's, headed by the class in KITTI's spelling, once
    labels, dets = write_set(tmp_path, frames=2, cars=3)
    result = runner.invoke(app, ["eval", str(labels), str(dets), "--classes", "car,CAR, Pedestrian"])
    assert result.exit_code == 0, result.output
    assert result.output.count("Car AP@0.70, 0.70, 0.70:") == 1 and "Pedestrian AP@0.50, 0.50, 0.50:" in result.output
