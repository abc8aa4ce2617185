import re

import numpy as np
import plyfile
import pytest
from hypothesis import given, settings

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import OutputExistsError
from lidarfuzz.io.common import NonFiniteWarning
from lidarfuzz.io.formats import ply
from lidarfuzz.scene import STANDARD_CHANNELS, PointCloud, Scene
from tests.io.helpers import expect_read_error
from tests.strategies import clouds


def expect_error(path, pattern):
    return expect_read_error(ply.read, path, pattern)


def write_foreign(path, elements, text=False):
    plyfile.PlyData(elements, text=text).write(str(path))


# ---------------------------------------------------------------- round trips
@pytest.mark.parametrize("text", [False, True])
@settings(max_examples=25, deadline=None)
@given(cloud=clouds())
def test_round_trip_is_bit_exact(tmp_path_factory, text, cloud):
    path = tmp_path_factory.mktemp("ply") / "frame.ply"
    ply.write(path, Scene(cloud), text=text)
    scene = ply.read(path)
    assert scene.points.channels == cloud.channels
    assert scene.points.data.tobytes() == cloud.data.tobytes()
    assert scene.frame_id == "frame"
    assert scene.metadata == {"source": str(path), "format": "ply", "encoding": "ascii" if text else "binary"}


@pytest.mark.parametrize("text", [False, True])
def test_empty_cloud_round_trip(tmp_path, text):
    cloud = PointCloud.empty(("x", "y", "z", "intensity", "time"))
    ply.write(tmp_path / "e.ply", Scene(cloud), text=text)
    assert ply.read(tmp_path / "e.ply").points == cloud


def test_binary_file_is_little_endian_float_per_channel(tmp_path):
    cloud = PointCloud(np.arange(10, dtype=np.float32).reshape(2, 5), (*STANDARD_CHANNELS, "ring"))
    ply.write(tmp_path / "b.ply", Scene(cloud))
    raw = (tmp_path / "b.ply").read_bytes()
    head, _, body = raw.partition(b"end_header\n")
    assert b"format binary_little_endian 1.0" in head
    assert b"element vertex 2" in head and b"property float ring" in head
    assert body == np.arange(10, dtype="<f4").tobytes()


# ---------------------------------------------------------------- foreign files
def test_foreign_mesh_with_integer_and_list_properties(tmp_path):
    vertex = np.array(
        [(1.0, 2.0, 3.0, 200, 7, 1.5), (4.0, 5.0, 6.0, 10, 8, -2.5)],
        dtype=[
            ("x", "f8"),
            ("y", "f8"),
            ("z", "f8"),
            ("reflectance", "u1"),
            ("laser_id", "u2"),
            ("Range", "f4"),
        ],
    )
    faces = np.array([([0, 1, 1],)], dtype=[("vertex_indices", "i4", (3,))])
    path = tmp_path / "mesh.ply"
    write_foreign(
        path,
        [plyfile.PlyElement.describe(vertex, "vertex"), plyfile.PlyElement.describe(faces, "face")],
        text=True,
    )
    scene = ply.read(path)
    assert scene.points.channels == ("x", "y", "z", "intensity", "ring", "range")
    assert scene.points.data.tolist() == [[1, 2, 3, 200, 7, 1.5], [4, 5, 6, 10, 8, -2.5]]
    assert scene.metadata["encoding"] == "ascii"


def test_list_property_on_vertices_is_skipped_and_recorded(tmp_path):
    vertex = np.empty(2, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("tags", object)])
    vertex["x"], vertex["y"], vertex["z"] = 1, 2, 3
    vertex["tags"] = [np.array([1, 2], np.int32), np.array([3], np.int32)]
    path = tmp_path / "tags.ply"
    write_foreign(path, [plyfile.PlyElement.describe(vertex, "vertex")])
    scene = ply.read(path)
    assert scene.points.channels == STANDARD_CHANNELS
    assert scene.metadata["skipped_properties"] == ["tags"]
    assert not scene.points.intensity.any()


# ---------------------------------------------------------------- non-finite policy
def test_nan_coordinates_dropped_or_rejected(tmp_path):
    data = np.ones((5, 4), np.float32)
    data[0, 1] = np.nan
    data[3, 0] = np.inf
    data[4, 2] = np.nan
    path = tmp_path / "n.ply"
    ply.write(path, Scene(PointCloud(data)))
    with pytest.warns(NonFiniteWarning, match=r"n\.ply: dropped 3 point"):
        scene = ply.read(path)
    assert len(scene.points) == 2 and scene.metadata["dropped_nonfinite"] == 3
    with pytest.raises(DataFormatError, match=r"n\.ply: 3 point\(s\) have NaN/Inf coordinates"):
        ply.read(path, nonfinite="reject")


# ---------------------------------------------------------------- bad input
def test_no_vertex_element(tmp_path):
    path = tmp_path / "faces.ply"
    faces = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))])
    write_foreign(path, [plyfile.PlyElement.describe(faces, "face")])
    expect_error(path, r"no 'vertex' element; found elements \['face'\]")


@pytest.mark.parametrize("missing", ["x", "y", "z"])
def test_missing_coordinate_property(tmp_path, missing):
    names = [n for n in ("x", "y", "z", "intensity") if n != missing]
    vertex = np.zeros(2, dtype=[(n, "f4") for n in names])
    path = tmp_path / "nocoord.ply"
    write_foreign(path, [plyfile.PlyElement.describe(vertex, "vertex")])
    expect_error(path, f"the 'vertex' element has no '{missing}' property")


def test_truncated_binary(tmp_path):
    path = tmp_path / "trunc.ply"
    ply.write(path, Scene(PointCloud(np.ones((4, 4), np.float32))))
    path.write_bytes(path.read_bytes()[:-20])
    expect_error(path, "header claims 4 'vertex' rows but the data holds only 2 complete rows")


def test_truncated_text(tmp_path):
    path = tmp_path / "trunc_text.ply"
    ply.write(path, Scene(PointCloud(np.ones((4, 4), np.float32))), text=True)
    path.write_text("\n".join(path.read_text().splitlines()[:-2]) + "\n")
    # two rows "1 1 1 1" left: 16 bytes, at most 16 // 8 rows of four 2-character values
    expect_error(path, "header claims 4 'vertex' rows but the data holds only at most 2 complete rows")


def test_malformed_text_value(tmp_path):
    path = tmp_path / "word.ply"
    ply.write(path, Scene(PointCloud(np.ones((2, 4), np.float32))), text=True)
    path.write_text(path.read_text().replace("\n1 1 1 1\n", "\n1 one 1 1\n", 1))
    expect_error(path, "cannot read 'vertex' row 0, property 'y': malformed input")


@pytest.mark.parametrize(
    ("content", "pattern"),
    [
        (b"hello\n", "bad PLY header: expected 'ply'"),
        (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty floot x\nend_header\n",
            "bad PLY header: field type 'floot'",
        ),
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n", "bad PLY header"),
        (b"", "bad PLY header"),
    ],
)
def test_not_a_ply_file(tmp_path, content, pattern):
    path = tmp_path / "junk.ply"
    path.write_bytes(content)
    expect_error(path, pattern)


def test_missing_file(tmp_path):
    expect_error(tmp_path / "absent.ply", "file not found")


# ---------------------------------------------------------------- writing
def test_write_refuses_to_overwrite(tmp_path):
    path = tmp_path / "keep.ply"
    ply.write(path, Scene(PointCloud(np.ones((3, 4)))))
    original = path.read_bytes()
    with pytest.raises(OutputExistsError, match=re.escape(str(path))):
        ply.write(path, Scene(PointCloud(np.zeros((5, 4)))), text=True)
    assert path.read_bytes() == original
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.ply"]
    ply.write(path, Scene(PointCloud(np.zeros((5, 4)))), overwrite=True)
    assert len(ply.read(path).points) == 5
