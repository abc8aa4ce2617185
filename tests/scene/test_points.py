import numpy as np
import pytest

from lidarfuzz.scene import PointCloud


def test_channels_must_start_with_xyz_intensity():
    with pytest.raises(ValueError, match="first four channels"):
        PointCloud(np.zeros((1, 4)), ("x", "y", "intensity", "z"))
    with pytest.raises(ValueError, match="duplicate"):
        PointCloud(np.zeros((1, 5)), ("x", "y", "z", "intensity", "x"))
    with pytest.raises(ValueError, match="N×5"):
        PointCloud(np.zeros((3, 4)), ("x", "y", "z", "intensity", "ring"))


def test_data_is_read_only_and_caller_array_untouched():
    raw = np.ones((5, 4), np.float32)
    cloud = PointCloud(raw)
    with pytest.raises(ValueError):
        cloud.data[0, 0] = 3.0
    raw[0, 0] = 7.0  # the caller's own array stays writable
    assert cloud.data[0, 0] == 7.0  # no copy was made for float32 input


def test_derivations_return_new_clouds():
    cloud = PointCloud(np.arange(8, dtype=np.float32).reshape(2, 4))
    ringed = cloud.with_channel("ring", [3, 4])
    assert ringed.channels[-1] == "ring" and cloud.channels == ("x", "y", "z", "intensity")
    moved = ringed.with_xyz(np.zeros((2, 3)))
    assert moved.xyz.sum() == 0 and ringed.xyz.sum() != 0
    assert moved.channel("ring").tolist() == [3.0, 4.0]
    assert len(cloud.select([True, False])) == 1
    assert ringed.without_channels(["ring"]) == cloud


def test_concat_unions_channels_with_defaults():
    a = PointCloud(np.zeros((2, 4)))
    b = PointCloud(np.ones((1, 5)), ("x", "y", "z", "intensity", "ring"))
    both = PointCloud.concat([a, b])
    assert both.channels == ("x", "y", "z", "intensity", "ring")
    assert both.channel("ring").tolist() == [-1.0, -1.0, 1.0]


def test_from_channels_defaults_intensity():
    cloud = PointCloud.from_channels({"x": [1.0], "y": [2.0], "z": [3.0], "time": [0.05]})
    assert cloud.channels == ("x", "y", "z", "intensity", "time")
    assert cloud.intensity.tolist() == [0.0]


def test_empty_cloud():
    cloud = PointCloud.empty(("x", "y", "z", "intensity", "ring"))
    assert len(cloud) == 0 and cloud.xyz.shape == (0, 3)
