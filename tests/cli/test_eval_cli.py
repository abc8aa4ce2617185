"""``lidarfuzz eval GT_DIR DT_DIR`` on label and detection folders written by hand."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.oracles.kitti_eval import evaluate_kitti
from lidarfuzz.oracles.kitti_files import load_kitti_eval_frames
from tests.oracles.test_kitti_files import car_line, write_set

runner = CliRunner()


def lidarfuzz(*args: str) -> subprocess.CompletedProcess[str]:
    """Run the real entry point, as a user would."""
    return subprocess.run(
        [sys.executable, "-c", "from lidarfuzz.cli.app import main; main()", *args],
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_perfect_detections_print_the_devkit_table_and_the_summary(tmp_path: Path) -> None:
    _, dets = write_set(tmp_path / "kitti" / "training", frames=6, cars=7)
    result = runner.invoke(app, ["eval", str(tmp_path / "kitti"), str(dets), "--classes", "Car"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    # 42 GT cars, all found: R40 and R11 both 100 on every metric and difficulty
    start = lines.index("Car AP_R40@0.70, 0.70, 0.70:")
    assert lines[start + 2] == "bev  AP:100.0000, 100.0000, 100.0000"
    assert "Car AP@0.70, 0.70, 0.70:" in lines and "Pedestrian AP@" not in result.output
    assert "AP|R40, moderate" in result.output and "mAP" in result.output
    assert "default KITTI-like calibration" in result.output  # no calib/ next to label_2
    assert "no detection file" not in result.output


def test_loose_overlaps_and_class_list(tmp_path: Path) -> None:
    labels, dets = write_set(tmp_path, frames=2, cars=3)
    result = runner.invoke(app, ["eval", str(labels), str(dets), "--overlaps", "loose", "--classes", "Car,Cyclist"])
    assert result.exit_code == 0, result.output
    assert "Car AP@0.70, 0.50, 0.50:" in result.output and "Cyclist AP@0.50, 0.25, 0.25:" in result.output
    for bad in (["--overlaps", "tight"], ["--classes", "Car,Truck"], ["--classes", ","]):
        refused = runner.invoke(app, ["eval", str(labels), str(dets), *bad])
        assert refused.exit_code == 2, refused.output


def test_json_holds_every_ap_and_the_map(tmp_path: Path) -> None:
    _, dets = write_set(tmp_path, frames=3, cars=4)
    (dets / "000000.txt").write_text(car_line(-4.0, 10.0, score=0.9, with_2d=False) + "\n")  # 3 misses
    out = tmp_path / "ap.json"
    result = runner.invoke(app, ["eval", str(tmp_path), str(dets), "--json", str(out)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text())
    expected = evaluate_kitti(load_kitti_eval_frames(tmp_path, dets).frames)
    assert data["ap"] == json.loads(expected.to_json())["ap"]
    assert data["map_moderate_R40"]["3d"] == pytest.approx(expected.mean_ap("3d", "moderate"))
    assert data["map"]["bev"]["moderate"]["R40"] == pytest.approx(expected.mean_ap("bev", "moderate"))
    assert 0 < data["ap"]["3d"]["Car"]["moderate"]["R40"] < 100
    assert data["inputs"]["frames"] == 3 and data["inputs"]["missing_detections"] == []


def test_missing_detection_files_warn_with_the_count(tmp_path: Path) -> None:
    _, dets = write_set(tmp_path, frames=4, cars=2)
    (dets / "000001.txt").unlink()
    (dets / "000003.txt").unlink()
    result = runner.invoke(app, ["eval", str(tmp_path), str(dets)])
    assert result.exit_code == 0, result.output
    assert "2 of 4 ground-truth frame(s) have no detection file" in result.output
    assert "e.g. 000001" in result.output


def test_bad_detection_line_is_one_clear_error_naming_file_and_line(tmp_path: Path) -> None:
    _, dets = write_set(tmp_path, frames=2, cars=2)
    (dets / "000001.txt").write_text(car_line(0, 10, score=0.5) + "\nCar 0 0 0 1 2 3\n")
    result = lidarfuzz("eval", str(tmp_path), str(dets))
    assert result.returncode == 2, result.stderr
    assert f"{dets / '000001.txt'}:2: expected 15 fields (16 with a score), found 7" in result.stderr
    assert "Traceback" not in result.stderr


def test_stray_detection_file_is_an_error_naming_it(tmp_path: Path) -> None:
    _, dets = write_set(tmp_path, frames=2, cars=2)
    (dets / "000042.txt").write_text(car_line(0, 10, score=0.5) + "\n")
    result = lidarfuzz("eval", str(tmp_path), str(dets))
    assert result.returncode == 2
    assert "000042.txt: detection file without a ground-truth frame" in result.stderr
