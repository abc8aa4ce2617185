import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.kitti import parse_labels
from lidarfuzz.scene import KittiCalibration
from tests.conftest import KITTI_000000_CALIB, KITTI_000000_LABEL


@pytest.fixture(scope="module")
def calib() -> KittiCalibration:
    return KittiCalibration.parse(KITTI_000000_CALIB, "calib/000000.txt")


def test_parse_reads_every_matrix(calib):
    assert calib.P2[0, 0] == 721.5377 and calib.P2[0, 3] == 44.85728
    assert calib.R0_rect.shape == (3, 3) and calib.Tr_imu_to_velo is not None
    assert KittiCalibration.parse(calib.to_text()) == calib  # exact text round trip


def test_default_rig_hand_worked():
    calib = KittiCalibration.default()
    # A LiDAR point 10 m ahead, 1 m left, on the sensor's height: camera x = -y, y = -z - 0.08, z = x - 0.27.
    np.testing.assert_allclose(calib.lidar_to_rect([[10.0, 1.0, 0.0]]), [[-1.0, -0.08, 9.73]])
    uv, depth = calib.rect_to_image([[-1.0, -0.08, 9.73]])
    fx, cx, cy = 721.5377, 609.5593, 172.854
    np.testing.assert_allclose(uv, [[(fx * -1.0 + cx * 9.73 + fx * 0.06) / 9.73, (fx * -0.08 + cy * 9.73) / 9.73]])
    assert depth[0] == pytest.approx(9.73)


def test_label_geometry_hand_worked(calib):
    # KITTI 000000: a pedestrian, bottom centre (1.84, 1.47, 8.41) in the camera frame, h w l = 1.89 0.48 1.20.
    boxes = parse_labels(KITTI_000000_LABEL, calib)
    x, y, z, length, width, height, yaw = boxes.as_array()[0]
    assert (length, width, height) == (1.20, 0.48, 1.89)
    # LiDAR centre: the bottom centre lifted by h/2 along LiDAR z.
    bottom = calib.rect_to_lidar([[1.84, 1.47, 8.41]])[0]
    np.testing.assert_allclose([x, y, z], bottom + np.array([0, 0, 1.89 / 2]), atol=1e-12)
    assert x == pytest.approx(8.68, abs=0.05) and y == pytest.approx(-1.85, abs=0.05)
    assert yaw == pytest.approx(-0.01 - np.pi / 2)
    # Devkit alpha = -arctan2(-y, x) + ry reproduces the annotated -0.20.
    assert calib.alpha(boxes.as_array())[0] == pytest.approx(-0.20, abs=0.01)
    # The 2D box is the extent of the 8 corners built in the camera frame, as the devkit does:
    h, w, length, ry = 1.89, 0.48, 1.20, 0.01
    xc = np.array([length, length, -length, -length] * 2) / 2
    yc = np.array([0, 0, 0, 0, -h, -h, -h, -h])
    zc = np.array([w, -w, -w, w, w, -w, -w, w]) / 2
    rot = np.array([[np.cos(ry), 0, np.sin(ry)], [0, 1, 0], [-np.sin(ry), 0, np.cos(ry)]])
    corners = (rot @ np.stack([xc, yc, zc])).T + np.array([1.84, 1.47, 8.41])
    projected = np.c_[corners, np.ones(8)] @ calib.P2.T
    uv = projected[:, :2] / projected[:, 2:]
    expected = [uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max()]
    np.testing.assert_allclose(calib.boxes_to_image(boxes.as_array())[0], expected, atol=1e-6)


@settings(max_examples=80, deadline=None)
@given(
    st.floats(-70, 70), st.floats(-40, 40), st.floats(-3, 2), st.floats(0.2, 15), st.floats(0.2, 4),
    st.floats(0.2, 4), st.floats(-np.pi, np.pi),
)
def test_lidar_camera_round_trip_keeps_all_seven_numbers(x, y, z, length, width, height, yaw):
    calib = KittiCalibration.parse(KITTI_000000_CALIB)
    box = np.array([[x, y, z, length, width, height, yaw]])
    loc, dims, ry = calib.boxes_to_camera(box)
    back = calib.boxes_from_camera(loc, dims, ry)
    np.testing.assert_allclose(back[:, :6], box[:, :6], atol=1e-5)
    assert abs((back[0, 6] - yaw + np.pi) % (2 * np.pi) - np.pi) < 1e-5


def test_image_round_trip(calib):
    points = np.random.default_rng(1).uniform([2, -20, -3], [70, 20, 2], (200, 3))
    uv, depth = calib.lidar_to_image(points)
    np.testing.assert_allclose(calib.image_to_lidar(uv, depth), points, atol=1e-9)


def test_2d_box_is_clipped_to_the_image():
    calib = KittiCalibration.default()
    box2d = calib.boxes_to_image([[5.0, 6.0, -1.0, 4.0, 1.8, 1.5, 0.0]])[0]  # partly left of the image
    assert box2d[0] == 0.0 and 0 < box2d[2] <= 1241 and 0 <= box2d[1] < box2d[3] <= 374


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("P2: 1 2 3\nR0_rect: 1 0 0 0 1 0 0 0 1\nTr_velo_to_cam: 0 0 0 0 0 0 0 0 0 0 0 0\n",
         r":1: field 'P2': expected 12"),
        ("P2: 1 2 3 4 5 6 7 8 9 10 11 12\nTr_velo_to_cam: 0 0 0 0 0 0 0 0 0 0 0 0\n", "missing key R0_rect"),
        ("P2: 1 2 3 4 5 6 7 8 9 1O 11 12\n", r":1: field 'P2': value '1O' is not a number"),
        ("P2: 1 2 3 4 5 6 7 8 9 10 11 12\nP2: 1 2 3 4 5 6 7 8 9 10 11 12\n", "key appears twice"),
    ],
)
def test_bad_calib_files_name_file_line_and_key(text, match):
    with pytest.raises(DataFormatError, match=match) as info:
        KittiCalibration.parse(text, "calib/000123.txt")
    assert str(info.value).startswith("calib/000123.txt")


def test_tracking_spellings_are_accepted(calib):
    text = KITTI_000000_CALIB.replace("R0_rect:", "R_rect").replace("Tr_velo_to_cam:", "Tr_velo_cam")
    assert KittiCalibration.parse(text) == calib


def test_in_view_is_in_front_of_the_camera_and_inside_the_image() -> None:
    from lidarfuzz.scene.calib import KittiCalibration

    calib = KittiCalibration.default()
    mask = calib.in_view([[20.0, 0.0, -1.0], [-20.0, 0.0, -1.0], [5.0, 30.0, -1.0], [80.0, 2.0, 0.0]])
    assert mask.tolist() == [True, False, False, True]
