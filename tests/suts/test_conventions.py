"""Box conventions at the edge: round trips and hand-checked cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.geometry import box_corners
from lidarfuzz.suts.conventions import (
    CONVENTIONS,
    detections,
    from_kitti_camera,
    from_lidarfuzz,
    labels_from_ids,
    to_kitti_camera,
    to_lidarfuzz,
)
from lidarfuzz.suts.python import to_detections

finite = st.floats(-50, 50, allow_nan=False, width=64)
boxes_strategy = st.integers(0, 6).flatmap(
    lambda n: st.tuples(
        arrays(np.float64, (n, 3), elements=finite),
        arrays(np.float64, (n, 3), elements=st.floats(0.2, 10, width=64)),
        arrays(np.float64, (n, 1), elements=st.floats(-np.pi, np.pi, exclude_max=True, width=64)),
    ).map(lambda t: np.concatenate(t, axis=1))
)


@settings(max_examples=60, deadline=None)
@given(boxes_strategy, st.sampled_from(CONVENTIONS))
def test_round_trip_keeps_the_same_solid(boxes: np.ndarray, convention: str) -> None:
    there = from_lidarfuzz(boxes, convention)  # type: ignore[arg-type]
    back = to_lidarfuzz(there, convention)  # type: ignore[arg-type]
    # the same physical box: identical corners as a set (yaw may differ by 2π)
    a, b = box_corners(boxes).reshape(len(boxes), 24), box_corners(back).reshape(len(back), 24)
    np.testing.assert_allclose(np.sort(a, axis=1), np.sort(b, axis=1), atol=1e-9)


def test_mmdet3d_is_bottom_centred_and_legacy_swaps_sizes_and_turns_yaw() -> None:
    ours = np.array([[10.0, 2.0, -0.75, 4.0, 1.8, 1.5, 0.3]])
    np.testing.assert_allclose(from_lidarfuzz(ours, "mmdet3d"), [[10.0, 2.0, -1.5, 4.0, 1.8, 1.5, 0.3]])
    legacy = from_lidarfuzz(ours, "mmdet3d-legacy")
    np.testing.assert_allclose(legacy, [[10.0, 2.0, -1.5, 1.8, 4.0, 1.5, -0.3 - np.pi / 2]])
    np.testing.assert_allclose(from_lidarfuzz(ours, "openpcdet"), ours)
    with pytest.raises(ValueError, match="unknown box convention"):
        to_lidarfuzz(ours, "waymo")  # type: ignore[arg-type]


def test_class_ids() -> None:
    assert labels_from_ids([1, 3], ["Car", "Pedestrian", "Cyclist"], one_based=True) == ["Car", "Cyclist"]
    assert labels_from_ids([0], ["Car"], one_based=False) == ["Car"]
    with pytest.raises(ValueError, match="outside"):
        labels_from_ids([4], ["Car"], one_based=True)


def test_detector_outputs_of_each_tool_agree() -> None:
    ours = np.array([[10.0, 2.0, -0.75, 4.0, 1.8, 1.5, 0.3]])
    names = ["Car", "Pedestrian", "Cyclist"]
    pcdet = to_detections({"pred_boxes": ours, "pred_scores": [0.8], "pred_labels": [1]}, class_names=names)
    mmdet = to_detections(
        {"bboxes_3d": from_lidarfuzz(ours, "mmdet3d"), "scores_3d": [0.8], "labels_3d": [0]}, class_names=names
    )
    plain = to_detections((ours, ["Car"], [0.8]))
    for d in (pcdet, mmdet, plain):
        np.testing.assert_allclose(d.as_array(), ours)
        assert d.labels.tolist() == ["Car"] and d.scores.tolist() == [0.8]
    assert len(detections(np.zeros((0, 7)), [], [])) == 0


def test_kitti_camera_round_trip() -> None:
    calib = KittiCalibration.default()
    ours = np.array([[12.0, -3.0, -0.8, 4.2, 1.7, 1.5, 1.0]])
    loc, dims, ry = to_kitti_camera(detections(ours, ["Car"], [0.5]), calib)
    back = from_kitti_camera(loc, dims, ry, ["Car"], [0.5], calib)
    np.testing.assert_allclose(back.as_array(), ours, atol=1e-9)
    np.testing.assert_allclose(dims, [[1.5, 1.7, 4.2]])
