"""``lidarfuzz suts``, ``detect`` and ``relations`` as a user runs them."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.io.kitti import read_label_file
from lidarfuzz.scene.calib import KittiCalibration

runner = CliRunner()
DETECTOR = "tests.suts.detectors:centroid_detector?input=points"


def test_detect_writes_kitti_detection_files_and_refuses_to_overwrite(kitti_log: Path, tmp_path: Path) -> None:
    out = tmp_path / "dets"
    result = runner.invoke(app, ["detect", DETECTOR, str(kitti_log), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "3/3 frame(s)" in result.output
    files = sorted(out.glob("*.txt"))
    assert [f.stem for f in files] == ["000000", "000001", "000002"]
    calib = KittiCalibration.from_file(kitti_log / "calib" / "000000.txt")
    boxes = read_label_file(files[0], calib)
    assert len(boxes) <= 1 and (len(boxes) == 0 or boxes.is_detection)
    again = runner.invoke(app, ["detect", DETECTOR, str(kitti_log), "--out", str(out)])
    assert again.exit_code == 2 and "exists" in again.output and "--overwrite" in again.output
    assert runner.invoke(app, ["detect", DETECTOR, str(kitti_log), "--out", str(out), "--overwrite"]).exit_code == 0


def test_detect_lists_failures_and_goes_on(kitti_log: Path, tmp_path: Path) -> None:
    # flaky raises on ids ending in 1 and hangs on ids ending in 2: isolated, the hang is cut off
    args = ["detect", "tests.suts.detectors:flaky", str(kitti_log), "--out", str(tmp_path), "--isolate"]
    args += ["--timeout", "2"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "1/3 frame(s)" in result.output
    assert "crash" in result.output and "segmentation" in result.output and "timeout" in result.output
    assert [f.stem for f in tmp_path.glob("*.txt")] == ["000000"]


def test_suts_and_relations_listings() -> None:
    suts = runner.invoke(app, ["suts"])
    assert suts.exit_code == 0 and "subprocess:" in suts.output
    relations = runner.invoke(app, ["relations"])
    assert relations.exit_code == 0
    for name in ("preservation", "equivariance", "invariance", "deeptest_tolerance", "gt_recall"):
        assert name in relations.output
    one = runner.invoke(app, ["relations", "preservation"])
    assert one.exit_code == 0 and "min_iou" in one.output
    assert runner.invoke(app, ["relations", "nope"]).exit_code != 0


def test_detect_leaves_out_boxes_outside_the_camera_view_unless_asked(kitti_log: Path, tmp_path: Path) -> None:
    # a detector answering one box behind the sensor and one ahead
    spec = "tests.suts.detectors:behind_and_ahead"
    args = ["detect", spec, str(kitti_log), "--out", str(tmp_path / "a"), "--limit", "1"]
    assert runner.invoke(app, args).exit_code == 0
    assert len((tmp_path / "a" / "000000.txt").read_text().splitlines()) == 1
    args = ["detect", spec, str(kitti_log), "--out", str(tmp_path / "b"), "--limit", "1", "--all"]
    assert runner.invoke(app, args).exit_code == 0
    assert len((tmp_path / "b" / "000000.txt").read_text().splitlines()) == 2
