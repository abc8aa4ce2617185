import re

import laspy
import numpy as np
import pytest
from hypothesis import given, settings

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import OutputExistsError
from lidarfuzz.io.common import NonFiniteWarning
from lidarfuzz.io.formats import las
from lidarfuzz.scene import STANDARD_CHANNELS, PointCloud, Scene
from tests.io.helpers import expect_read_error
from tests.strategies import clouds


def expect_error(path, pattern):
    return expect_read_error(las.read, path, pattern)


def foreign_las(path, n=50, point_format=3, seed=0, extra=()):
    """A LAS file as another tool writes it: no lf_ dimensions, 1 mm scale, non-zero offsets."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=point_format, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([10.0, -20.0, 1.5])
    if extra:
        header.add_extra_dims(list(extra))
    data = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(n, header=header))
    xyz = rng.uniform(-50, 50, size=(n, 3))
    data.x, data.y, data.z = xyz.T
    data.intensity = rng.integers(0, 65535, n, dtype=np.uint16)
    data.classification = rng.integers(0, 10, n, dtype=np.uint8)
    if "gps_time" in data.point_format.dimension_names:
        data.gps_time = 3.5e8 + np.sort(rng.uniform(0, 0.1, n))
    data.write(str(path))
    return laspy.read(str(path))


# ---------------------------------------------------------------- round trips
@pytest.mark.parametrize("suffix", las.SUFFIXES)
@settings(max_examples=25, deadline=None)
@given(cloud=clouds())
def test_round_trip_is_bit_exact(tmp_path_factory, suffix, cloud):
    path = tmp_path_factory.mktemp("las") / f"frame{suffix}"
    las.write(path, Scene(cloud))
    scene = las.read(path)
    assert scene.points.channels == cloud.channels
    assert scene.points.data.tobytes() == cloud.data.tobytes()
    assert scene.frame_id == "frame"
    assert scene.metadata == {"source": str(path), "format": suffix[1:]}


@pytest.mark.parametrize("suffix", las.SUFFIXES)
def test_empty_cloud_round_trip(tmp_path, suffix):
    cloud = PointCloud.empty(("x", "y", "z", "intensity", "ring"))
    las.write(tmp_path / f"e{suffix}", Scene(cloud))
    assert las.read(tmp_path / f"e{suffix}").points == cloud


def test_laz_is_compressed_and_las_is_not(tmp_path):
    cloud = PointCloud(np.zeros((100, 4), np.float32))
    las.write(tmp_path / "a.las", Scene(cloud))
    las.write(tmp_path / "a.laz", Scene(cloud))
    assert not laspy.read(tmp_path / "a.las").header.are_points_compressed
    assert laspy.read(tmp_path / "a.laz").header.are_points_compressed
    assert (tmp_path / "a.laz").stat().st_size < (tmp_path / "a.las").stat().st_size


# ---------------------------------------------------------------- what other tools see in our files
def test_written_file_is_standard_las_14_format_6(tmp_path):
    rng = np.random.default_rng(1)
    n = 200
    data = np.column_stack(
        [
            rng.uniform(-80, 80, (n, 3)),
            rng.uniform(0, 1, n),
            rng.uniform(0, 0.1, n),
            rng.integers(0, 300, n),
        ]
    ).astype(np.float32)
    cloud = PointCloud(data, (*STANDARD_CHANNELS, "time", "label"))
    las.write(tmp_path / "std.las", Scene(cloud, timestamp=1000.0))
    theirs = laspy.read(tmp_path / "std.las")
    assert theirs.header.version == "1.4" and theirs.header.point_format.id == 6
    assert np.allclose(theirs.header.scales, 1e-4)
    assert np.allclose(theirs.header.offsets, data[:, :3].min(axis=0))
    xyz = np.column_stack([theirs.x, theirs.y, theirs.z])
    assert np.abs(xyz - data[:, :3]).max() <= 0.5e-4 + 1e-9
    assert np.array_equal(theirs.intensity, np.round(data[:, 3].astype(np.float64) * 65535).astype(np.uint16))
    np.testing.assert_allclose(theirs.gps_time, 1000.0 + data[:, 4].astype(np.float64))
    assert np.array_equal(theirs.classification, np.clip(data[:, 5], 0, 255).astype(np.uint8))
    assert set(theirs.return_number) == {1} and set(theirs.number_of_returns) == {1}


def test_intensity_above_one_is_taken_as_counts(tmp_path):
    data = np.zeros((3, 4), np.float32)
    data[:, 3] = [3.4, 250.0, 1e6]
    las.write(tmp_path / "i.las", Scene(PointCloud(data)))
    assert laspy.read(tmp_path / "i.las").intensity.tolist() == [3, 250, 65535]


def test_huge_extent_gets_a_coarser_scale(tmp_path):
    data = np.array([[-3e38, 0, 0, 0], [3e38, 1, 2, 0]], np.float32)
    las.write(tmp_path / "big.las", Scene(PointCloud(data)))
    header = laspy.read(tmp_path / "big.las").header
    assert header.scales[0] > 1e20 and header.scales[1] == pytest.approx(1e-4)
    assert las.read(tmp_path / "big.las").points.data.tobytes() == data.tobytes()


# ---------------------------------------------------------------- foreign files
def test_foreign_las_scaled_coordinates_intensity_time_and_class(tmp_path):
    path = tmp_path / "foreign.las"
    theirs = foreign_las(path)
    scene = las.read(path)
    cloud = scene.points
    assert cloud.channels == ("x", "y", "z", "intensity", "time", "label")
    expected = np.column_stack([theirs.x, theirs.y, theirs.z])
    assert np.abs(cloud.xyz - expected).max() <= 1e-4
    assert np.array_equal(cloud.intensity, theirs.intensity.astype(np.float32))  # not rescaled
    assert np.array_equal(cloud.channel("label"), np.asarray(theirs.classification, np.float32))
    assert scene.timestamp == pytest.approx(theirs.gps_time.min(), abs=0)
    np.testing.assert_allclose(cloud.channel("time"), theirs.gps_time - theirs.gps_time.min(), atol=1e-6)
    assert cloud.channel("time").min() == 0.0
    assert scene.metadata == {"source": str(path), "format": "las", "intensity_scale": "uint16"}


def test_foreign_without_gps_time_and_without_classes(tmp_path):
    path = tmp_path / "plain.las"
    header = laspy.LasHeader(point_format=0, version="1.2")
    data = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(3, header=header))
    data.x, data.y, data.z = [1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]
    data.write(str(path))
    scene = las.read(path)
    assert scene.points.channels == STANDARD_CHANNELS and scene.timestamp is None
    assert np.allclose(scene.points.xyz, [[1, 4, 7], [2, 5, 8], [3, 6, 9]], atol=1e-4)


def test_foreign_extra_bytes_become_channels(tmp_path):
    path = tmp_path / "extra.laz"
    extra = (
        laspy.ExtraBytesParams(name="Amplitude", type=np.float32),
        laspy.ExtraBytesParams(name="normal", type="3f4"),
    )
    foreign_las(tmp_path / "extra.las", n=4, extra=extra)
    data = laspy.read(tmp_path / "extra.las")
    data["Amplitude"] = np.array([1, 2, 3, 4], np.float32)
    data["normal"] = np.arange(12, dtype=np.float32).reshape(4, 3)
    data.write(str(path))
    cloud = las.read(path).points
    assert cloud.channels == (
        "x",
        "y",
        "z",
        "intensity",
        "time",
        "amplitude",
        "normal_0",
        "normal_1",
        "normal_2",
        "label",
    )
    assert cloud.channel("amplitude").tolist() == [1, 2, 3, 4]
    assert cloud.channel("normal_2").tolist() == [2, 5, 8, 11]
    assert las.read(path).metadata["format"] == "laz"


def test_file_stripped_of_lf_dims_reads_as_foreign(tmp_path):
    cloud = PointCloud(np.array([[1.25, -2.5, 3.0, 0.5]], np.float32))
    las.write(tmp_path / "own.las", Scene(cloud))
    theirs = laspy.read(tmp_path / "own.las")
    theirs.remove_extra_dims(["lf_x", "lf_y", "lf_z", "lf_intensity"])
    theirs.write(str(tmp_path / "stripped.las"))
    scene = las.read(tmp_path / "stripped.las")
    assert np.allclose(scene.points.xyz, cloud.xyz, atol=1e-4)
    assert scene.points.intensity.tolist() == [round(0.5 * 65535)]
    assert scene.metadata["intensity_scale"] == "uint16"


# ---------------------------------------------------------------- non-finite policy
@pytest.mark.parametrize("suffix", las.SUFFIXES)
def test_nan_coordinates_dropped_or_rejected(tmp_path, suffix):
    data = np.ones((5, 5), np.float32)
    data[2, 0] = np.nan
    data[3, 1] = -np.inf
    path = tmp_path / f"n{suffix}"
    las.write(path, Scene(PointCloud(data, (*STANDARD_CHANNELS, "ring"))))
    with pytest.warns(NonFiniteWarning, match=rf"n\{suffix}: dropped 2 point"):
        scene = las.read(path)
    assert len(scene.points) == 3 and scene.metadata["dropped_nonfinite"] == 2
    with pytest.raises(DataFormatError, match=rf"n\{suffix}: 2 point\(s\) have NaN/Inf coordinates"):
        las.read(path, nonfinite="reject")


# ---------------------------------------------------------------- bad input
def test_not_a_las_file(tmp_path):
    path = tmp_path / "text.las"
    path.write_text("hello, world\n")
    expect_error(path, "not a readable LAS/LAZ file: no 'LASF' signature")


@pytest.mark.parametrize("suffix", las.SUFFIXES)
def test_truncated_file(tmp_path, suffix):
    path = tmp_path / f"trunc{suffix}"
    rng = np.random.default_rng(0)
    las.write(path, Scene(PointCloud(rng.normal(size=(500, 4)).astype(np.float32))))
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    # LAS: the header's 500 points cannot fit in half the file; LAZ: its chunk table (at the end) is cut off
    expect_error(path, "field 'point_count': the header claims" if suffix == ".las" else "field 'chunk_table_offset'")


def test_truncated_header(tmp_path):
    path = tmp_path / "head.las"
    las.write(path, Scene(PointCloud(np.ones((2, 4)))))
    path.write_bytes(path.read_bytes()[:100])
    expect_error(path, r"not a readable LAS/LAZ file: its public header is truncated \(100 of at least 227 bytes\)")


def test_missing_file(tmp_path):
    expect_error(tmp_path / "absent.las", "file not found")


# ---------------------------------------------------------------- writing
def test_write_refuses_to_overwrite(tmp_path):
    path = tmp_path / "keep.laz"
    las.write(path, Scene(PointCloud(np.ones((3, 4)))))
    original = path.read_bytes()
    with pytest.raises(OutputExistsError, match=re.escape(str(path))):
        las.write(path, Scene(PointCloud(np.zeros((5, 4)))))
    assert path.read_bytes() == original
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.laz"]
    las.write(path, Scene(PointCloud(np.zeros((5, 4)))), overwrite=True)
    assert len(las.read(path).points) == 5


def test_channel_name_too_long_for_extra_bytes(tmp_path):
    name = "a" * 30
    with pytest.raises(ValueError, match="too long for LAS extra bytes"):
        las.write(tmp_path / "long.las", Scene(PointCloud(np.ones((1, 5)), (*STANDARD_CHANNELS, name))))
    assert not list(tmp_path.iterdir())
