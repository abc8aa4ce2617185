import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarfuzz.scene import box_corners, box_index_of_points, iou_3d, iou_bev, points_in_boxes

box_st = st.tuples(
    st.floats(-20, 20), st.floats(-20, 20), st.floats(-2, 2),
    st.floats(0.2, 8), st.floats(0.2, 4), st.floats(0.2, 3), st.floats(-np.pi, np.pi),
).map(lambda t: np.array(t, dtype=np.float64))


def _reference_iou_bev(a, b):
    pa = shapely.Polygon(box_corners(a[None])[0, :4, :2])
    pb = shapely.Polygon(box_corners(b[None])[0, :4, :2])
    return pa.intersection(pb).area / pa.union(pb).area


def test_corners_of_axis_aligned_box():
    corners = box_corners([[1.0, 2.0, 3.0, 4.0, 2.0, 1.0, 0.0]])[0]
    assert corners.min(axis=0).tolist() == [-1.0, 1.0, 2.5]
    assert corners.max(axis=0).tolist() == [3.0, 3.0, 3.5]


def test_corners_rotate_counter_clockwise():
    # yaw = 90°: the box's length now runs along +y; its front-right corner is at (+w/2, +l/2).
    corners = box_corners([[0, 0, 0, 4.0, 2.0, 1.0, np.pi / 2]])[0]
    np.testing.assert_allclose(corners[0], [1.0, 2.0, -0.5], atol=1e-12)


def test_iou_hand_worked():
    a = np.array([[0, 0, 0, 2, 2, 2, 0.0]])
    b = np.array([[1, 0, 0, 2, 2, 2, 0.0]])  # half overlap in x: inter 2, union 6
    assert iou_bev(a, b)[0, 0] == pytest.approx(2 / 6)
    assert iou_3d(a, b)[0, 0] == pytest.approx(4 / 12)
    c = np.array([[0, 0, 1, 2, 2, 2, 0.0]])  # same footprint, half height overlap
    assert iou_bev(a, c)[0, 0] == pytest.approx(1.0)
    assert iou_3d(a, c)[0, 0] == pytest.approx(4 / 12)
    # a square rotated 45° inside itself: octagon overlap = 8(√2 − 1) for side 2
    d = np.array([[0, 0, 0, 2, 2, 2, np.pi / 4]])
    inter = 8 * (np.sqrt(2) - 1)
    assert iou_bev(a, d)[0, 0] == pytest.approx(inter / (8 - inter))


def test_iou_disjoint_nan_and_empty():
    a = np.array([[0, 0, 0, 2, 2, 2, 0.0], [np.nan] * 7])
    b = np.array([[10, 0, 0, 2, 2, 2, 0.0]])
    assert iou_bev(a, b).tolist() == [[0.0], [0.0]]
    assert iou_3d(a, np.zeros((0, 7))).shape == (2, 0)


@settings(max_examples=60, deadline=None)
@given(box_st, box_st, st.floats(-np.pi, np.pi), st.floats(-30, 30), st.floats(-30, 30))
def test_iou_properties(a, b, angle, tx, ty):
    ab, ba = iou_bev(a[None], b[None])[0, 0], iou_bev(b[None], a[None])[0, 0]
    assert ab == pytest.approx(ba, abs=1e-9)
    assert iou_bev(a[None], a[None])[0, 0] == pytest.approx(1.0)
    assert iou_3d(a[None], a[None])[0, 0] == pytest.approx(1.0)
    assert ab == pytest.approx(_reference_iou_bev(a, b), abs=1e-9)
    assert 0.0 <= iou_3d(a[None], b[None])[0, 0] <= ab + 1e-9  # o·(Aa+Ab) ≤ Aa·ha + Ab·hb

    def move(box):
        c, s = np.cos(angle), np.sin(angle)
        out = box.copy()
        out[0], out[1] = c * box[0] - s * box[1] + tx, s * box[0] + c * box[1] + ty
        out[6] = box[6] + angle
        return out

    assert iou_bev(move(a)[None], move(b)[None])[0, 0] == pytest.approx(ab, abs=1e-7)
    assert iou_3d(move(a)[None], move(b)[None])[0, 0] == pytest.approx(iou_3d(a[None], b[None])[0, 0], abs=1e-7)


@settings(max_examples=40, deadline=None)
@given(st.lists(box_st, min_size=0, max_size=8), st.integers(0, 2**32 - 1))
def test_points_in_boxes_matches_brute_force(box_list, seed):
    boxes = np.array(box_list).reshape(-1, 7)
    points = np.random.default_rng(seed).uniform([-25, -25, -4], [25, 25, 4], (500, 3))
    expected = np.zeros((500, len(boxes)), dtype=bool)
    for j, (x, y, z, length, width, height, yaw) in enumerate(boxes):
        d = points - [x, y, z]
        lx = d[:, 0] * np.cos(yaw) + d[:, 1] * np.sin(yaw)
        ly = -d[:, 0] * np.sin(yaw) + d[:, 1] * np.cos(yaw)
        expected[:, j] = (np.abs(lx) <= length / 2) & (np.abs(ly) <= width / 2) & (np.abs(d[:, 2]) <= height / 2)
    assert np.array_equal(points_in_boxes(points, boxes), expected)


def test_box_index_of_points():
    boxes = np.array([[0, 0, 0, 2, 2, 2, 0.0], [5, 0, 0, 2, 2, 2, 0.0]])
    points = np.array([[0, 0, 0], [5, 0.5, 0.5], [9, 9, 9.0]])
    assert box_index_of_points(points, boxes).tolist() == [0, 1, -1]
    assert box_index_of_points(points, np.zeros((0, 7))).tolist() == [-1, -1, -1]


def test_boxes_without_geometry_overlap_nothing() -> None:
    from lidarfuzz.scene.geometry import iou_3d, iou_bev

    box = [0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0]
    dontcare = [np.nan] * 7
    assert iou_bev([box, dontcare], [box]).tolist() == [[1.0], [0.0]]
    assert iou_3d([dontcare], [box, dontcare]).tolist() == [[0.0, 0.0]]
