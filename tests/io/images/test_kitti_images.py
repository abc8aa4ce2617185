"""KITTI's image_2/ beside the LiDAR frames: ids, P2 intrinsics, depth_2, steering.csv, poses."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.dataset import Log
from lidarfuzz.io.images import KittiImages, open_image_dataset
from tests.io.images.util import PIXELS, write_png

# A hand-written calib: fx=700, fy=710, cx=600, cy=180; P2 carries a baseline term (-0.06 m × fx = -42)
P2 = "700 0 600 -42 0 710 180 0 0 0 1 0"
CALIB = f"""P0: 700 0 600 0 0 710 180 0 0 0 1 0
P1: 700 0 600 -380 0 710 180 0 0 0 1 0
P2: {P2}
P3: 700 0 600 -420 0 710 180 0 0 0 1 0
R0_rect: 1 0 0 0 1 0 0 0 1
Tr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0
Tr_imu_to_velo: 1 0 0 0 0 1 0 0 0 0 1 0
"""


def kitti(root: Path, ids: tuple[str, ...] = ("000000", "000001")) -> Path:
    for i, frame in enumerate(ids):
        write_png(root / "image_2" / f"{frame}.png", PIXELS if i == 0 else PIXELS[:, ::-1].copy())
        (root / "velodyne").mkdir(parents=True, exist_ok=True)
        np.zeros((4, 4), np.float32).tofile(root / "velodyne" / f"{frame}.bin")
        (root / "calib").mkdir(exist_ok=True)
        (root / "calib" / f"{frame}.txt").write_text(CALIB)
    return root


def test_frames_match_the_lidar_frames_and_intrinsics_are_p2s_left_3x3(tmp_path):
    ds = open_image_dataset(kitti(tmp_path))
    assert isinstance(ds, KittiImages) and not isinstance(ds, Log) and ds.format == "kitti"
    assert list(ds.frame_ids()) == ["000000", "000001"] == sorted(p.stem for p in (tmp_path / "velodyne").iterdir())
    sample = ds["000000"]
    assert np.array_equal(sample.image, PIXELS)
    assert sample.intrinsics.tolist() == [[700, 0, 600], [0, 710, 180], [0, 0, 1]]
    assert sample.steering is None and sample.depth is None
    assert ds.problems() == []
    assert ds.image_sizes() == {(2, 3): 2}


def test_image_3_uses_p3(tmp_path):
    root = kitti(tmp_path)
    write_png(root / "image_3" / "000000.png")
    ds = open_image_dataset(root, camera="image_3")
    assert list(ds.frame_ids()) == ["000000"]
    assert ds[0].intrinsics[0].tolist() == [700, 0, 600]
    assert any("LiDAR frame(s) without an image in image_3/" in p.message for p in ds.problems())


def test_depth_and_steering_as_gen_camera_writes_them(tmp_path):
    root = kitti(tmp_path)
    (root / "depth_2").mkdir()
    raw = np.array([[2560, 0, 256], [512, 1, 0]], dtype=np.uint16)  # metres × 256
    assert cv2.imwrite(str(root / "depth_2" / "000000.png"), raw)
    (root / "steering.csv").write_text("frame_id,steering,speed\n000000,0.0873,7.5\n000001,-0.02,7.25\n")
    ds = open_image_dataset(root)
    sample = ds["000000"]
    # 2560 / 256 = 10 m, 256 / 256 = 1 m, 512 / 256 = 2 m, 1 / 256 m; 0 = nothing hit → inf
    assert sample.depth.tolist() == [[10.0, np.inf, 1.0], [2.0, 1 / 256, np.inf]]
    assert sample.steering == 0.0873 and sample.metadata["speed"] == 7.5 and sample.metadata["steering_row"] == 2
    assert ds["000001"].steering == -0.02 and ds["000001"].depth is None
    assert [p.message for p in ds.problems()] == ["1 frame(s) without a depth map, e.g. 000001"]


def test_bad_steering_rows_name_the_line_and_column(tmp_path):
    root = kitti(tmp_path)
    (root / "steering.csv").write_text("frame_id,steering,speed\n000000,left,7.5\n000001,0.1,nan\n")
    with pytest.raises(DataFormatError, match=r"steering\.csv:2: field 'steering': 'left' is not a number "
                                              r"\(and 1 more problem"):
        open_image_dataset(root)
    problems = open_image_dataset(root, strict=False).problems()
    assert [(p.line, p.message) for p in problems] == [
        (2, "field 'steering': 'left' is not a number"),
        (3, "field 'speed': 'nan' is not a finite number"),
    ]
    (root / "steering.csv").write_text("frame,angle\n000000,0.1\n")
    with pytest.raises(DataFormatError, match=r"steering\.csv:1: field 'frame_id': no column 'frame_id'"):
        open_image_dataset(root)


def test_depth_map_of_another_size_is_refused(tmp_path):
    root = kitti(tmp_path)
    (root / "depth_2").mkdir()
    cv2.imwrite(str(root / "depth_2" / "000000.png"), np.ones((3, 3), np.uint16))
    with pytest.raises(DataFormatError, match=r"depth_2/000000\.png: the depth map is 3×3 but the image is 3×2"):
        open_image_dataset(root)["000000"]


def test_timestamps_make_a_log_and_poses_place_the_camera(tmp_path):
    root = kitti(tmp_path)
    (root / "timestamps.txt").write_text("000000 0.2\n000001 0.1\n")
    (root / "poses.txt").write_text("000000 1 0 0 5 0 1 0 0 0 0 1 0\n000001 1 0 0 0 0 1 0 0 0 0 1 0\n")
    ds = open_image_dataset(root)
    assert isinstance(ds, Log) and list(ds.frame_ids()) == ["000001", "000000"]
    assert ds.timestamps().tolist() == [0.1, 0.2]
    pose = ds["000000"].pose
    # P2 = K [I | t] with K t = (-42, 0, 0) → t = (-0.06, 0, 0): camera 2 sits at x_rect = +0.06 m.
    # rect → LiDAR (Tr_velo_to_cam's inverse): x_velo = z_rect, y_velo = -x_rect, z_velo = -y_rect, so the
    # camera is at LiDAR (0, -0.06, 0) and its optical axis (z) is LiDAR +x; the LiDAR pose adds x = 5.
    assert np.allclose(pose[:3, 3], [5.0, -0.06, 0.0])
    assert np.allclose(pose[:3, 2], [1, 0, 0]) and np.allclose(pose[:3, 0], [0, -1, 0])
    assert np.array_equal(ds.poses()[1], pose)  # the log's poses are the samples' ones, in time order


def test_not_a_kitti_camera_folder(tmp_path):
    with pytest.raises(DataFormatError, match="not an image data set: no image_2/ folder"):
        open_image_dataset(tmp_path)
    with pytest.raises(DataFormatError, match="no image_3/ folder here or under training/"):
        KittiImages(kitti(tmp_path), camera="image_3")
