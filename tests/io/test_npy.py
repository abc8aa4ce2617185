import dataclasses
import io
import re
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import OutputExistsError
from lidarfuzz.io.common import NonFiniteWarning
from lidarfuzz.io.formats import npy
from lidarfuzz.scene import (
    STANDARD_CHANNELS,
    Boxes3D,
    KittiCalibration,
    PointCloud,
    RoiMap,
    Scene,
)
from lidarfuzz.scene.points import frozen
from tests.io.helpers import expect_read_error
from tests.strategies import boxes as box_strategy
from tests.strategies import clouds

finite64 = st.floats(allow_nan=False, allow_infinity=False)




json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**53), 2**53) | finite64 | st.text(max_size=8),
    lambda children: st.lists(children, max_size=3) | st.dictionaries(st.text(max_size=5), children, max_size=3),
    max_leaves=8,
)


@st.composite
def calibrations(draw: st.DrawFn) -> KittiCalibration | None:
    if not draw(st.booleans()):
        return None

    def matrix(rows: int, cols: int) -> np.ndarray:
        return draw(hnp.arrays(np.float64, (rows, cols), elements=finite64))

    optional = {key: matrix(3, 4) for key in ("P0", "P1", "P3", "Tr_imu_to_velo") if draw(st.booleans())}
    shape = draw(st.tuples(st.integers(1, 4000), st.integers(1, 4000)))
    return KittiCalibration(
        P2=matrix(3, 4), R0_rect=matrix(3, 3), Tr_velo_to_cam=matrix(3, 4), **optional, image_shape=shape
    )


@st.composite
def rois(draw: st.DrawFn) -> RoiMap | None:
    if not draw(st.booleans()):
        return None
    squares = draw(st.lists(st.tuples(st.floats(-100, 100), st.floats(-100, 100), st.floats(0.5, 20)), max_size=3))
    rings = [[(x, y), (x + s, y), (x + s, y + s), (x, y + s)] for x, y, s in squares]
    return RoiMap.from_polygons(rings)


@st.composite
def scenes(draw: st.DrawFn) -> Scene:
    boxes = draw(box_strategy())
    if draw(st.booleans()):  # detector-style extras
        m = len(boxes)
        boxes = boxes.replace(
            scores=draw(hnp.arrays(np.float64, (m,), elements=st.floats(0, 1))),
            track_ids=draw(hnp.arrays(np.int64, (m,), elements=st.integers(-1, 10**9))),
            bbox2d=draw(hnp.arrays(np.float64, (m, 4), elements=finite64)),
        )
    pose = draw(st.none() | hnp.arrays(np.float64, (4, 4), elements=finite64))
    return Scene(
        draw(clouds()),
        boxes=boxes,
        calib=draw(calibrations()),
        frame_id=draw(st.text(max_size=12)),
        timestamp=draw(st.none() | finite64),
        pose=pose,
        roi=draw(rois()),
        metadata=draw(st.dictionaries(st.text(max_size=8), json_values, max_size=4)),
    )


def expect_error(path, pattern):
    return expect_read_error(npy.read, path, pattern)


def save(path, array):
    with open(path, "wb") as handle:
        np.save(handle, array)


# ---------------------------------------------------------------- .npy
@settings(max_examples=25, deadline=None)
@given(cloud=clouds())
def test_npy_round_trip_is_bit_exact(tmp_path_factory, cloud):
    path = tmp_path_factory.mktemp("npy") / "frame.npy"
    npy.write(path, Scene(cloud, frame_id="ignored", timestamp=3.0))
    scene = npy.read(path)
    assert scene.points.channels == cloud.channels
    assert scene.points.data.tobytes() == cloud.data.tobytes()
    assert scene.frame_id == "frame"
    assert scene.metadata == {"source": str(path), "format": "npy"}


def test_npy_is_a_structured_float32_array(tmp_path):
    cloud = PointCloud(np.ones((2, 5), np.float32), (*STANDARD_CHANNELS, "ring"))
    npy.write(tmp_path / "s.npy", Scene(cloud))
    array = np.load(tmp_path / "s.npy", allow_pickle=False)
    assert array.dtype.names == cloud.channels and all(array.dtype[i] == "<f4" for i in range(5))


def test_npy_empty_cloud_round_trip(tmp_path):
    cloud = PointCloud.empty(("x", "y", "z", "intensity", "label"))
    npy.write(tmp_path / "e.npy", Scene(cloud))
    assert npy.read(tmp_path / "e.npy").points == cloud


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int16, np.uint8])
def test_plain_array_columns(tmp_path, dtype):
    save(tmp_path / "p6.npy", np.arange(12).reshape(2, 6).astype(dtype))
    cloud = npy.read(tmp_path / "p6.npy").points
    assert cloud.channels == ("x", "y", "z", "intensity", "c4", "c5")
    assert cloud.data.tolist() == [[0, 1, 2, 3, 4, 5], [6, 7, 8, 9, 10, 11]]


def test_plain_array_with_three_columns_has_zero_intensity(tmp_path):
    save(tmp_path / "p3.npy", np.arange(6, dtype=np.float64).reshape(2, 3))
    cloud = npy.read(tmp_path / "p3.npy").points
    assert cloud.channels == STANDARD_CHANNELS and cloud.data.tolist() == [[0, 1, 2, 0], [3, 4, 5, 0]]


def test_foreign_structured_array_with_aliases_and_subarray(tmp_path):
    dtype = [
        ("X", "<f8"),
        ("Y", "<f8"),
        ("Z", "<f8"),
        ("reflectance", "u1"),
        ("t", "<f4"),
        ("normal", "<f4", (3,)),
    ]
    array = np.zeros(2, dtype)
    array["X"], array["reflectance"], array["t"] = [1, 2], [10, 20], [0.5, 0.25]
    array["normal"] = [[0, 0, 1], [0, 1, 0]]
    save(tmp_path / "f.npy", array)
    cloud = npy.read(tmp_path / "f.npy").points
    assert cloud.channels == ("x", "y", "z", "intensity", "time", "normal_0", "normal_1", "normal_2")
    assert cloud.data.tolist() == [[1, 0, 0, 10, 0.5, 0, 0, 1], [2, 0, 0, 20, 0.25, 0, 1, 0]]


def test_organised_structured_array_is_flattened(tmp_path):
    save(tmp_path / "o.npy", np.zeros((4, 8), [("x", "f4"), ("y", "f4"), ("z", "f4")]))
    assert len(npy.read(tmp_path / "o.npy").points) == 32


# ---------------------------------------------------------------- .npz scene archive
@settings(max_examples=25, deadline=None)
@given(scene=scenes())
def test_npz_scene_round_trip_is_exact(tmp_path_factory, scene):
    path = tmp_path_factory.mktemp("npz") / "scene.npz"
    npy.write(path, scene)
    back = npy.read(path)
    assert back == scene
    assert back.points.data.tobytes() == scene.points.data.tobytes()


def test_npz_round_trip_of_sample_scenes(tmp_path, sample_scenes):
    for i, scene in enumerate(sample_scenes):
        npy.write(tmp_path / f"{i}.npz", scene)
        assert npy.read(tmp_path / f"{i}.npz") == scene


def test_npz_keeps_yaw_exactly_even_when_not_wrapped(tmp_path):
    boxes = Boxes3D.create([[1.0, 2.0, 3.0]], [[4.0, 2.0, 1.5]], [0.0], ["Car"])
    boxes = dataclasses.replace(boxes, yaw=frozen(np.array([1e-20])))  # create() would make this 0.0
    scene = Scene(PointCloud.empty(), boxes=boxes)
    npy.write(tmp_path / "y.npz", scene)
    assert npy.read(tmp_path / "y.npz").boxes.yaw.tolist() == [1e-20]


def test_npz_scene_with_empty_roi_and_no_optional_parts(tmp_path):
    from shapely.geometry import MultiPolygon

    # numpy's unicode arrays drop trailing NULs; the archive must not.
    scene = Scene(PointCloud.empty(), roi=RoiMap(MultiPolygon()), frame_id="a\x00", metadata={"k\x00": "v\x00"})
    npy.write(tmp_path / "bare.npz", scene)
    assert npy.read(tmp_path / "bare.npz") == scene


def test_npz_archive_is_plain_arrays_without_pickles(tmp_path, sample_scenes):
    npy.write(tmp_path / "s.npz", sample_scenes[0])
    with zipfile.ZipFile(tmp_path / "s.npz") as archive:
        assert archive.testzip() is None
        assert all(info.compress_type == zipfile.ZIP_STORED for info in archive.infolist())
    with np.load(tmp_path / "s.npz", allow_pickle=False) as arrays:
        for key in arrays.files:
            assert arrays[key].dtype != object


def test_npz_nan_coordinates_dropped_or_rejected(tmp_path):
    data = np.ones((4, 4), np.float32)
    data[0, 2] = np.nan
    scene = Scene(PointCloud(data), frame_id="000001", metadata={"note": "x"})
    npy.write(tmp_path / "n.npz", scene)
    with pytest.warns(NonFiniteWarning, match=r"n\.npz: dropped 1 point"):
        back = npy.read(tmp_path / "n.npz")
    assert len(back.points) == 3 and back.metadata == {"note": "x", "dropped_nonfinite": 1}
    with pytest.warns(NonFiniteWarning):
        assert npy.read_points(tmp_path / "n.npz", nonfinite="drop")[1] == 1
    with pytest.raises(DataFormatError, match=r"n\.npz: 1 point\(s\) have NaN/Inf coordinates"):
        npy.read(tmp_path / "n.npz", nonfinite="reject")


@pytest.mark.parametrize("key", ["points", "only"])
def test_foreign_npz_points_array(tmp_path, key):
    buffer = io.BytesIO()
    arrays = {key: np.arange(8, dtype=np.float64).reshape(2, 4)}
    if key == "points":
        arrays["labels"] = np.zeros(3)
    np.savez_compressed(buffer, **arrays)
    (tmp_path / "f.npz").write_bytes(buffer.getvalue())
    scene = npy.read(tmp_path / "f.npz")
    assert scene.points.data.tolist() == [[0, 1, 2, 3], [4, 5, 6, 7]]
    assert scene.metadata == {"source": str(tmp_path / "f.npz"), "format": "npz", "array": key}
    assert scene.frame_id == "f" and len(scene.boxes) == 0


# ---------------------------------------------------------------- non-finite policy (.npy)
def test_npy_nan_coordinates_dropped_or_rejected(tmp_path):
    data = np.ones((6, 5), np.float32)
    data[1, 0] = np.nan
    data[2, 1] = np.inf
    npy.write(tmp_path / "n.npy", Scene(PointCloud(data, (*STANDARD_CHANNELS, "ring"))))
    with pytest.warns(NonFiniteWarning, match=r"n\.npy: dropped 2 point"):
        scene = npy.read(tmp_path / "n.npy")
    assert len(scene.points) == 4 and scene.metadata["dropped_nonfinite"] == 2
    with pytest.raises(DataFormatError, match=r"n\.npy: 2 point\(s\) have NaN/Inf coordinates"):
        npy.read(tmp_path / "n.npy", nonfinite="reject")


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("array", "found"),
    [
        (np.zeros(5), r"shape \(5,\) and dtype float64"),
        (np.zeros((5, 2)), r"shape \(5, 2\) and dtype float64"),
        (np.zeros((2, 3, 4)), r"shape \(2, 3, 4\)"),
        (np.zeros((2, 4), np.complex64), "dtype complex64"),
        (np.array([["a", "b", "c"]]), "dtype <U1"),
    ],
)
def test_npy_wrong_shape_or_dtype(tmp_path, array, found):
    save(tmp_path / "bad.npy", array)
    expect_error(tmp_path / "bad.npy", f"found an array of .*{found}.*expected a structured array .* or an N×C")


def test_npy_structured_with_text_field(tmp_path):
    save(tmp_path / "txt.npy", np.zeros(2, [("x", "f4"), ("y", "f4"), ("z", "f4"), ("name", "U4")]))
    assert expect_error(tmp_path / "txt.npy", "has dtype <U4; only numeric fields").field == "name"


def test_npy_structured_without_z(tmp_path):
    save(tmp_path / "noz.npy", np.zeros(2, [("x", "f4"), ("y", "f4")]))
    expect_error(tmp_path / "noz.npy", "no 'z' field")


def test_npy_object_array_is_refused_without_unpickling(tmp_path):
    with open(tmp_path / "obj.npy", "wb") as handle:
        np.save(handle, np.array([{"x": 1}, None], dtype=object), allow_pickle=True)
    expect_error(tmp_path / "obj.npy", "holds Python objects .* lidarfuzz never unpickles")


def test_npz_object_array_is_refused(tmp_path):
    with open(tmp_path / "obj.npz", "wb") as handle:
        np.savez(handle, points=np.array([[1, 2, 3, None]], dtype=object))
    assert expect_error(tmp_path / "obj.npz", "holds Python objects").field == "points"


def test_npz_without_points(tmp_path):
    with open(tmp_path / "two.npz", "wb") as handle:
        np.savez(handle, a=np.zeros((2, 4)), b=np.zeros((2, 4)))
    expect_error(tmp_path / "two.npz", r"no 'points' array among \['a', 'b'\]")


def test_npz_scene_archive_missing_a_part(tmp_path, sample_scenes):
    arrays = npy.scene_arrays(sample_scenes[0])
    del arrays["boxes_yaw"]
    with open(tmp_path / "part.npz", "wb") as handle:
        np.savez(handle, **arrays)
    expect_error(tmp_path / "part.npz", "scene archive lacks the 'boxes_yaw' array")


def test_npz_scene_archive_with_inconsistent_parts(tmp_path, sample_scenes):
    arrays = npy.scene_arrays(sample_scenes[0])
    arrays["channels"] = arrays["channels"][:-1]
    with open(tmp_path / "bad.npz", "wb") as handle:
        np.savez(handle, **arrays)
    expect_error(tmp_path / "bad.npz", "malformed scene archive: points must be an N×7 array")


def test_npz_from_a_newer_lidarfuzz(tmp_path):
    arrays = npy.scene_arrays(Scene(PointCloud.empty()))
    arrays[npy.ARCHIVE_KEY] = np.array(npy.ARCHIVE_VERSION + 1)
    with open(tmp_path / "new.npz", "wb") as handle:
        np.savez(handle, **arrays)
    expect_error(tmp_path / "new.npz", "scene archive version 2 is newer than this lidarfuzz reads")


@pytest.mark.parametrize(
    ("name", "content", "pattern"),
    [
        ("text.npy", b"x y z\n1 2 3\n", "not a NumPy file"),
        ("empty.npz", b"", "not a NumPy file"),
        ("broken.npz", b"PK\x03\x04" + b"\0" * 40, "not a readable .npz archive"),
        ("short.npy", b"\x93NUMPY\x01\x00", "cannot load"),
    ],
)
def test_not_a_numpy_file(tmp_path, name, content, pattern):
    (tmp_path / name).write_bytes(content)
    expect_error(tmp_path / name, pattern)


def test_truncated_npy(tmp_path):
    save(tmp_path / "t.npy", np.zeros((100, 4), np.float32))
    (tmp_path / "t.npy").write_bytes((tmp_path / "t.npy").read_bytes()[:-10])
    expect_error(tmp_path / "t.npy", "cannot load")


def test_missing_file(tmp_path):
    expect_error(tmp_path / "absent.npy", "file not found")


# ---------------------------------------------------------------- writing
@pytest.mark.parametrize("suffix", npy.SUFFIXES)
def test_write_refuses_to_overwrite(tmp_path, suffix):
    path = tmp_path / f"keep{suffix}"
    npy.write(path, Scene(PointCloud(np.ones((3, 4)))))
    original = path.read_bytes()
    with pytest.raises(OutputExistsError, match=re.escape(str(path))):
        npy.write(path, Scene(PointCloud(np.zeros((5, 4)))))
    assert path.read_bytes() == original
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]
    npy.write(path, Scene(PointCloud(np.zeros((5, 4)))), overwrite=True)
    assert len(npy.read(path).points) == 5


def test_write_rejects_other_suffixes_and_unjsonable_metadata(tmp_path):
    with pytest.raises(ValueError, match=r"suffix must be \.npy or \.npz"):
        npy.write(tmp_path / "a.txt", Scene(PointCloud.empty()))
    with pytest.raises(ValueError, match="metadata must be JSON-able"):
        npy.write(tmp_path / "b.npz", Scene(PointCloud.empty(), metadata={"when": object()}))
    assert not list(tmp_path.iterdir())
