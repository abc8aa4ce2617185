"""Loading KITTI label and detection folders for the evaluation, on files written by hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.oracles.kitti_eval import evaluate_kitti, get_thresholds
from lidarfuzz.oracles.kitti_files import find_label_dir, load_kitti_eval_frames
from lidarfuzz.scene.calib import KittiCalibration

CALIB = KittiCalibration.default()
CAR_HWL = (1.5, 1.6, 3.9)


def car_line(x: float, z: float, ry: float = 0.0, score: float | None = None, with_2d: bool = True) -> str:
    """A KITTI label line for a car standing on the road (camera y 1.65) at camera (x, z).

    Ground truth gets the projected 2D box and alpha, as the KITTI annotations have them;
    ``with_2d=False`` writes the ``-1`` / ``-10`` placeholders a LiDAR-only detector writes.
    """
    h, w, length = CAR_HWL
    loc = (x, 1.65, z)
    if with_2d:
        lidar = CALIB.boxes_from_camera([loc], [CAR_HWL], [ry])
        box = CALIB.boxes_to_image(lidar)[0]
        alpha = float(CALIB.alpha(lidar)[0])
        two_d = f"{alpha:.6f} {box[0]:.2f} {box[1]:.2f} {box[2]:.2f} {box[3]:.2f}"
    else:
        two_d = "-10 -1 -1 -1 -1"
    line = f"Car 0.00 0 {two_d} {h} {w} {length} {x} 1.65 {z} {ry}"
    return line + (f" {score}" if score is not None else "")


DONTCARE = "DontCare -1 -1 -10 800.00 160.00 830.00 180.00 -1 -1 -1 -1000 -1000 -1000 -10"


def write_set(root: Path, frames: int = 6, cars: int = 7, detections: bool = True) -> tuple[Path, Path]:
    """``root/label_2`` with ``frames × cars`` fully visible cars (plus a DontCare line per frame),
    and ``root/dets`` with each car detected exactly, distinct scores, no 2D box."""
    labels, dets = root / "label_2", root / "dets"
    labels.mkdir(parents=True)
    dets.mkdir()
    score = 0.99
    for f in range(frames):
        gt_lines, dt_lines = [], []
        for c in range(cars):
            x, z = 4.0 * (c % 3) - 4.0, 10.0 + 2.0 * c  # all within 25 m: taller than 40 px
            gt_lines.append(car_line(x, z, ry=0.1 * c))
            dt_lines.append(car_line(x, z, ry=0.1 * c, score=round(score, 4), with_2d=False))
            score -= 0.01
        (labels / f"{f:06d}.txt").write_text("\n".join([*gt_lines, DONTCARE]) + "\n")
        if detections:
            (dets / f"{f:06d}.txt").write_text("\n".join(dt_lines) + "\n")
    return labels, dets


def test_label_folder_found_in_each_kitti_layout(tmp_path: Path) -> None:
    labels, _ = write_set(tmp_path / "kitti" / "training", frames=1, cars=1)
    assert find_label_dir(labels) == labels
    assert find_label_dir(tmp_path / "kitti" / "training") == labels
    assert find_label_dir(tmp_path / "kitti") == labels
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFormatError, match="no label files here"):
        find_label_dir(tmp_path / "empty")
    with pytest.raises(DataFormatError, match="no such folder"):
        find_label_dir(tmp_path / "nowhere")


def test_dontcare_and_scores_are_read_and_2d_boxes_left_for_projection(tmp_path: Path) -> None:
    labels, dets = write_set(tmp_path, frames=2, cars=3)
    loaded = load_kitti_eval_frames(tmp_path, dets)
    assert loaded.frame_ids == ["000000", "000001"] and loaded.label_dir == labels
    gt, dt = loaded.frames[0].gt, loaded.frames[0].detections
    assert gt.labels.tolist() == ["Car", "Car", "Car", "DontCare"]
    assert not gt.has_geometry[3] and np.allclose(gt.bbox2d[3], [800, 160, 830, 180])
    assert np.allclose(dt.scores, [0.99, 0.98, 0.97])
    assert np.all(np.isnan(dt.bbox2d)) and np.all(np.isnan(dt.alpha))
    assert np.allclose(dt.as_array(), gt.as_array()[:3], atol=1e-9)


def test_calibration_next_to_the_labels_or_the_default_with_a_note(tmp_path: Path) -> None:
    labels, dets = write_set(tmp_path, frames=2, cars=1)
    loaded = load_kitti_eval_frames(labels, dets)
    assert loaded.calib_dir is None and "default" in loaded.notes[0]
    assert all(f.calib == KittiCalibration.default() for f in loaded.frames)
    centre_default_rig = loaded.frames[0].gt.centers[0]

    further = CALIB.Tr_velo_to_cam.copy()
    further[2, 3] += 1.0
    shifted = KittiCalibration.from_mapping({"P2": CALIB.P2, "R0_rect": CALIB.R0_rect, "Tr_velo_to_cam": further})
    (tmp_path / "calib").mkdir()
    for frame_id in ("000000", "000001"):
        (tmp_path / "calib" / f"{frame_id}.txt").write_text(shifted.to_text())
    # an image_2 PNG sets the image size (only its header is read)
    (tmp_path / "image_2").mkdir()
    header = b"\x89PNG\r\n\x1a\n" + b"\0\0\0\rIHDR" + (1224).to_bytes(4, "big") + (370).to_bytes(4, "big")
    (tmp_path / "image_2" / "000001.png").write_bytes(header)
    loaded = load_kitti_eval_frames(labels, dets)
    assert loaded.calib_dir == tmp_path / "calib" and not loaded.notes
    assert np.allclose(loaded.frames[0].calib.Tr_velo_to_cam, shifted.Tr_velo_to_cam)
    assert loaded.frames[0].calib.image_shape == (375, 1242) and loaded.frames[1].calib.image_shape == (370, 1224)
    # boxes are placed through the frame's calibration: camera z is 1 m further, so LiDAR x is 1 m less
    assert np.allclose(loaded.frames[0].gt.centers[0] - centre_default_rig, [-1.0, 0.0, 0.0])

    (tmp_path / "calib" / "000001.txt").unlink()
    with pytest.raises(DataFormatError, match=r"calib[/\\]000001.txt: no calibration file"):
        load_kitti_eval_frames(labels, dets)
    with pytest.raises(DataFormatError, match="no such calibration folder"):
        load_kitti_eval_frames(labels, dets, tmp_path / "missing")


def test_missing_detection_file_is_an_empty_frame(tmp_path: Path) -> None:
    _, dets = write_set(tmp_path, frames=3, cars=2)
    (dets / "000001.txt").unlink()
    (dets / "000002.txt").write_text("")
    loaded = load_kitti_eval_frames(tmp_path, dets)
    assert loaded.missing_detections == ["000001"]
    assert len(loaded.frames[1].detections) == 0 and len(loaded.frames[2].detections) == 0
    assert len(loaded.frames[1].gt) == 3


def test_stray_detection_file_is_an_error_naming_it(tmp_path: Path) -> None:
    _, dets = write_set(tmp_path, frames=2, cars=1)
    (dets / "000007.txt").write_text(car_line(0, 10, score=0.5) + "\n")
    with pytest.raises(DataFormatError, match=r"000007.txt: detection file without a ground-truth frame"):
        load_kitti_eval_frames(tmp_path, dets)


@pytest.mark.parametrize(
    ("line", "field"),
    [
        ("Car 0.00 0 -10 -1 -1 -1 -1 1.5 1.6 3.9 0 1.65", None),
        ("Car 0.00 0 -10 -1 -1 -1 -1 1.5 1.6 3.9 0 1.65 oops 0 0.5", "z"),
        ("Tractor 0.00 0 -10 -1 -1 -1 -1 1.5 1.6 3.9 0 1.65 10 0 0.5", "type"),
    ],
)
def test_bad_detection_line_names_file_line_and_field(tmp_path: Path, line: str, field: str | None) -> None:
    _, dets = write_set(tmp_path, frames=2, cars=1)
    (dets / "000001.txt").write_text(car_line(0, 10, score=0.5) + "\n\n" + line + "\n")
    with pytest.raises(DataFormatError) as caught:
        load_kitti_eval_frames(tmp_path, dets)
    assert caught.value.path == dets / "000001.txt" and caught.value.line == 3 and caught.value.field == field


def test_detections_without_scores_are_refused(tmp_path: Path) -> None:
    labels, _ = write_set(tmp_path, frames=2, cars=1)
    with pytest.raises(DataFormatError, match="detections need a score") as caught:
        load_kitti_eval_frames(tmp_path, labels)
    assert caught.value.field == "score"


@pytest.mark.parametrize(("frames", "cars"), [(6, 7), (2, 5), (1, 1)])
def test_perfect_detections_score_what_the_devkit_sampling_allows(tmp_path: Path, frames: int, cars: int) -> None:
    write_set(tmp_path, frames=frames, cars=cars)
    loaded = load_kitti_eval_frames(tmp_path, tmp_path / "dets")
    result = evaluate_kitti(loaded.frames, classes=("Car",))
    # every GT found, no FP: precision is 1 at each of the thresholds get_thresholds picks, 0 after
    num_gt = frames * cars
    filled = len(get_thresholds(np.linspace(1, 0.5, num_gt), num_gt))
    assert filled == min(num_gt, 41)
    for metric in ("bbox", "bev", "3d", "aos"):
        for difficulty in ("easy", "moderate", "hard"):
            assert result.get(metric, "Car", difficulty, "R40") == pytest.approx((filled - 1) / 40 * 100)
            assert result.get(metric, "Car", difficulty, "R11") == pytest.approx(len(range(0, filled, 4)) / 11 * 100)


def test_an_empty_detection_folder_is_an_error_not_a_zero(tmp_path: Path) -> None:
    labels = tmp_path / "label_2"
    labels.mkdir()
    (labels / "000000.txt").write_text("DontCare -1 -1 -10 1 2 3 4 -1 -1 -1 -1000 -1000 -1000 -10\n")
    empty = tmp_path / "dets"
    empty.mkdir()
    with pytest.raises(DataFormatError, match="no detection files"):
        load_kitti_eval_frames(labels, empty)
