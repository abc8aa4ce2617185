import numpy as np
import pytest

from lidarfuzz.scene import Boxes3D, wrap_angle


def test_create_validates_and_wraps_yaw():
    boxes = Boxes3D.create([[1, 2, 3]], [[4, 2, 1.5]], [3 * np.pi / 2], ["Car"])
    assert boxes.yaw[0] == pytest.approx(-np.pi / 2)
    assert np.isnan(boxes.scores[0]) and boxes.track_ids[0] == -1 and boxes.occlusion[0] == -1
    with pytest.raises(ValueError, match="negative size"):
        Boxes3D.create([[0, 0, 0]], [[-1, 1, 1]], [0], ["Car"])
    with pytest.raises(ValueError, match="expected shape"):
        Boxes3D.create([[0, 0]], [[1, 1, 1]], [0], ["Car"])


def test_wrap_angle_range():
    angles = wrap_angle(np.linspace(-10, 10, 101))
    assert np.all(angles >= -np.pi) and np.all(angles < np.pi)
    assert wrap_angle(np.pi) == pytest.approx(-np.pi)


def test_select_concat_and_arrays_are_frozen():
    boxes = Boxes3D.from_array(np.arange(14, dtype=float).reshape(2, 7), ["Car", "Van"], scores=[0.9, 0.4])
    assert boxes.is_detection
    first = boxes.select([0])
    assert len(first) == 1 and first.labels[0] == "Car"
    both = Boxes3D.concat([first, boxes.select([1])])
    assert both == boxes
    with pytest.raises(ValueError):
        boxes.centers[0, 0] = 1.0


def test_with_geometry_keeps_other_fields():
    boxes = Boxes3D.create([[1, 0, 0]], [[4, 2, 1.5]], [0.1], ["Car"], track_ids=[5], scores=[0.7])
    moved = boxes.with_geometry(centers=[[2, 0, 0]])
    assert moved.centers[0, 0] == 2 and moved.track_ids[0] == 5 and moved.scores[0] == 0.7
    assert boxes.centers[0, 0] == 1


def test_allclose_compares_yaw_on_the_circle():
    a = Boxes3D.create([[0, 0, 0]], [[1, 1, 1]], [np.pi - 1e-9], ["Car"])
    b = Boxes3D.create([[0, 0, 0]], [[1, 1, 1]], [-np.pi + 1e-9], ["Car"])
    assert a.allclose(b, atol=1e-6)
