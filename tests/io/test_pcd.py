import re
import struct

import numpy as np
import pypcd4
import pytest
from hypothesis import given, settings

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import OutputExistsError
from lidarfuzz.io.common import NonFiniteWarning
from lidarfuzz.io.formats import pcd
from lidarfuzz.scene import STANDARD_CHANNELS, PointCloud, Scene
from tests.io.helpers import expect_read_error
from tests.strategies import clouds


def header(fields, sizes, types, n, data="binary", counts=None, extra=""):
    lines = [
        "# .PCD v0.7 - Point Cloud Data file format",
        "VERSION 0.7",
        f"FIELDS {' '.join(fields)}",
        f"SIZE {' '.join(map(str, sizes))}",
        f"TYPE {' '.join(types)}",
    ]
    if counts is not None:
        lines.append(f"COUNT {' '.join(map(str, counts))}")
    lines += [f"WIDTH {n}", "HEIGHT 1", extra, f"POINTS {n}", f"DATA {data}"]
    return ("\n".join(line for line in lines if line) + "\n").encode()


XYZI = (("x", "y", "z", "intensity"), (4, 4, 4, 4), ("F", "F", "F", "F"))


def expect_error(path, pattern):
    return expect_read_error(pcd.read, path, pattern)


# ---------------------------------------------------------------- round trips
@pytest.mark.parametrize("encoding", pcd.ENCODINGS)
@settings(max_examples=25, deadline=None)
@given(cloud=clouds())
def test_round_trip_is_bit_exact(tmp_path_factory, encoding, cloud):
    path = tmp_path_factory.mktemp("pcd") / "frame.pcd"
    pcd.write(path, Scene(cloud), encoding=encoding)
    scene = pcd.read(path)
    assert scene.points.channels == cloud.channels
    assert scene.points.data.tobytes() == cloud.data.tobytes()  # bit-exact, -0.0 included
    assert scene.frame_id == "frame"
    assert scene.metadata == {"source": str(path), "format": "pcd", "encoding": encoding}


@pytest.mark.parametrize("encoding", pcd.ENCODINGS)
def test_empty_cloud_round_trip(tmp_path, encoding):
    cloud = PointCloud.empty(("x", "y", "z", "intensity", "ring"))
    pcd.write(tmp_path / "e.pcd", Scene(cloud), encoding=encoding)
    assert pcd.read(tmp_path / "e.pcd").points == cloud


def test_tiny_and_huge_values_survive_ascii(tmp_path):
    values = np.array([[1e-45, -3.4028235e38, 1.1754944e-38, 0.1], [-0.0, 16777217, 1e-7, 1 / 3]], np.float32)
    pcd.write(tmp_path / "a.pcd", Scene(PointCloud(values)), encoding="ascii")
    assert pcd.read(tmp_path / "a.pcd").points.data.tobytes() == values.tobytes()


def test_binary_compressed_stays_compressed_when_lzf_cannot_shrink(tmp_path):
    noise = np.random.default_rng(3).random((50, 4)).astype(np.float32)  # incompressible
    pcd.write(tmp_path / "c.pcd", Scene(PointCloud(noise)), encoding="binary_compressed")
    assert b"DATA binary_compressed\n" in (tmp_path / "c.pcd").read_bytes()
    assert pcd.read(tmp_path / "c.pcd").points == PointCloud(noise)


@pytest.mark.parametrize("encoding", pcd.ENCODINGS)
def test_pypcd4_reads_what_we_write(tmp_path, encoding):
    cloud = PointCloud(np.arange(20, dtype=np.float32).reshape(4, 5) / 7, (*STANDARD_CHANNELS, "ring"))
    pcd.write(tmp_path / "p.pcd", Scene(cloud), encoding=encoding)
    theirs = pypcd4.PointCloud.from_path(tmp_path / "p.pcd")
    assert theirs.fields == cloud.channels
    np.testing.assert_allclose(theirs.numpy(), cloud.data, rtol=1e-7)


def test_we_read_what_pypcd4_writes(tmp_path):
    xyz = np.random.default_rng(0).normal(size=(6, 3)).astype(np.float32)
    ring = np.arange(6, dtype=np.uint16)
    theirs = pypcd4.PointCloud.from_points(
        [xyz[:, 0], xyz[:, 1], xyz[:, 2], ring], ("x", "y", "z", "ring"), (np.float32,) * 3 + (np.uint16,)
    )
    theirs.save(tmp_path / "t.pcd", encoding=pypcd4.Encoding.BINARY_COMPRESSED)
    cloud = pcd.read(tmp_path / "t.pcd").points
    assert cloud.channels == ("x", "y", "z", "intensity", "ring")
    assert np.array_equal(cloud.xyz, xyz) and np.array_equal(cloud.channel("ring"), ring)
    assert not cloud.intensity.any()


# ---------------------------------------------------------------- hand-written files
def test_ascii_with_intensity_and_u16_ring(tmp_path):
    path = tmp_path / "hand.pcd"
    path.write_bytes(
        header(("x", "y", "z", "intensity", "ring"), (4, 4, 4, 4, 2), ("F", "F", "F", "F", "U"), 3, "ascii")
        + b"1.5 -2 3.25 0.5 0\n"
        + b"4\t5  6 7 15 \r\n"  # tabs, double spaces, CRLF and trailing blanks are all whitespace
        + b"\n-1e-3 0 1e2 255 65535\n"
    )
    scene = pcd.read(path)
    assert scene.points.channels == ("x", "y", "z", "intensity", "ring")
    expected = [[1.5, -2, 3.25, 0.5, 0], [4, 5, 6, 7, 15], [-1e-3, 0, 100, 255, 65535]]
    assert np.array_equal(scene.points.data, np.array(expected, np.float32))
    assert scene.metadata["encoding"] == "ascii" and scene.frame_id == "hand"


def test_binary_with_padding_array_and_foreign_names(tmp_path):
    path = tmp_path / "pad.pcd"
    fields = ("x", "y", "z", "_", "reflectance", "normal", "t", "Ambient")
    record = np.dtype(
        [
            ("x", "<f4"),
            ("y", "<f4"),
            ("z", "<f4"),
            ("_", "u1", (3,)),
            ("i", "<f8"),
            ("n", "<f4", (3,)),
            ("t", "<u4"),
            ("a", "<i2"),
        ]
    )
    rows = np.zeros(2, record)
    rows["x"], rows["y"], rows["z"] = [1, 2], [3, 4], [5, 6]
    rows["_"] = 0xAB
    rows["i"] = [0.25, 0.75]
    rows["n"] = [[0, 0, 1], [1, 0, 0]]
    rows["t"] = [10, 20]
    rows["a"] = [-5, 7]
    head = header(
        fields,
        (4, 4, 4, 1, 8, 4, 4, 2),
        ("F", "F", "F", "U", "F", "F", "U", "I"),
        2,
        counts=(1, 1, 1, 3, 1, 3, 1, 1),
    )
    path.write_bytes(head + rows.tobytes())
    cloud = pcd.read(path).points
    assert cloud.channels == (
        "x",
        "y",
        "z",
        "intensity",
        "normal_0",
        "normal_1",
        "normal_2",
        "time",
        "ambient",
    )
    assert cloud.data.tolist() == [[1, 3, 5, 0.25, 0, 0, 1, 10, -5], [2, 4, 6, 0.75, 1, 0, 0, 20, 7]]


def test_packed_colour_is_split_even_when_it_is_nan_as_a_float(tmp_path):
    packed = np.array([0xFF_80_10_20, 0x00_01_02_03], np.uint32)  # the first is NaN as a float32
    assert np.isnan(packed.view(np.float32)[0])
    rows = np.zeros(2, [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    rows["rgb"] = packed
    path = tmp_path / "rgb.pcd"
    path.write_bytes(header(("x", "y", "z", "rgb"), (4, 4, 4, 4), ("F", "F", "F", "F"), 2) + rows.tobytes())
    cloud = pcd.read(path).points
    assert cloud.channels == ("x", "y", "z", "intensity", "red", "green", "blue")
    assert cloud.data[:, 4:].tolist() == [[0x80, 0x10, 0x20], [1, 2, 3]]


def test_packed_colour_in_ascii_as_pcl_writes_it(tmp_path):
    path = tmp_path / "rgba.pcd"
    fields = ("x", "y", "z", "rgba")
    path.write_bytes(header(fields, (4, 4, 4, 4), ("F", "F", "F", "U"), 1, "ascii") + f"1 2 3 {0xFF804143}\n".encode())
    cloud = pcd.read(path).points
    assert cloud.channels == ("x", "y", "z", "intensity", "red", "green", "blue", "alpha")
    assert cloud.data[0, 4:].tolist() == [0x80, 0x41, 0x43, 0xFF]


def test_header_without_count_and_with_many_lines(tmp_path):
    # An eleven-line header (pypcd4 alone stops after ten) and COUNT left out.
    path = tmp_path / "long.pcd"
    head = header(*XYZI, 2, extra="VIEWPOINT 1 2 3 1 0 0 0").replace(b"VERSION", b"# a comment\nVERSION")
    path.write_bytes(head + np.arange(8, dtype="<f4").tobytes())
    scene = pcd.read(path)
    assert scene.points.data.ravel().tolist() == list(range(8))
    assert scene.metadata["viewpoint"] == [1, 2, 3, 1, 0, 0, 0]


def test_organised_cloud_is_flattened(tmp_path):
    path = tmp_path / "org.pcd"
    head = header(*XYZI, 6).replace(b"WIDTH 6\nHEIGHT 1", b"WIDTH 3\nHEIGHT 2")
    path.write_bytes(head + np.arange(24, dtype="<f4").tobytes())
    assert len(pcd.read(path).points) == 6


# ---------------------------------------------------------------- non-finite policy
@pytest.mark.parametrize("encoding", pcd.ENCODINGS)
def test_nan_coordinates_dropped_or_rejected(tmp_path, encoding):
    data = np.ones((6, 5), np.float32)
    data[1, 0] = np.nan
    data[4, 2] = -np.inf
    path = tmp_path / "n.pcd"
    pcd.write(path, Scene(PointCloud(data, (*STANDARD_CHANNELS, "ring"))), encoding=encoding)
    with pytest.warns(NonFiniteWarning, match=r"n\.pcd: dropped 2 point"):
        scene = pcd.read(path)
    assert len(scene.points) == 4 and scene.metadata["dropped_nonfinite"] == 2
    with pytest.raises(DataFormatError, match=r"n\.pcd: 2 point\(s\) have NaN/Inf coordinates"):
        pcd.read(path, nonfinite="reject")


def test_nan_in_other_channel_is_rejected(tmp_path):
    data = np.ones((3, 5), np.float32)
    data[2, 4] = np.nan
    pcd.write(tmp_path / "r.pcd", Scene(PointCloud(data, (*STANDARD_CHANNELS, "ring"))))
    expect_error(tmp_path / "r.pcd", r"field 'ring': 1 point\(s\) have a NaN/Inf value")


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize(("size", "kind", "shown"), [(2, "F", "F2"), (4, "X", "X4"), (3, "U", "U3"), (16, "I", "I16")])
def test_unsupported_field_type(tmp_path, size, kind, shown):
    path = tmp_path / "t.pcd"
    path.write_bytes(header(("x", "y", "z"), (size, 4, 4), (kind, "F", "F"), 0))
    error = expect_error(path, f"unsupported field type {shown} for field 'x'")
    assert error.field == "x" and error.line is not None


def test_points_differs_from_width_times_height(tmp_path):
    path = tmp_path / "wh.pcd"
    path.write_bytes(header(*XYZI, 5).replace(b"WIDTH 5", b"WIDTH 4"))
    expect_error(path, r"header claims 5 points \(POINTS\) but WIDTH×HEIGHT is 4×1 = 4")


def test_binary_shorter_than_header_claims(tmp_path):
    path = tmp_path / "short.pcd"
    path.write_bytes(header(*XYZI, 10) + np.zeros(7 * 4, "<f4").tobytes() + b"\0\0")
    expect_error(
        path,
        r"header claims 10 points \(160 bytes .*\) but the binary data section holds 114 bytes \(7 points\)",
    )


def test_ascii_fewer_lines_than_header_claims(tmp_path):
    path = tmp_path / "few.pcd"
    path.write_bytes(header(*XYZI, 4, "ascii") + b"1 2 3 4\n5 6 7 8\n")
    expect_error(path, "header claims 4 points but the ascii data holds 2 lines")


def test_ascii_more_lines_than_header_claims(tmp_path):
    path = tmp_path / "many.pcd"
    path.write_bytes(header(*XYZI, 1, "ascii") + b"1 2 3 4\n5 6 7 8\n")
    expect_error(path, "header claims 1 points but the ascii data holds 2 lines")


def test_ascii_line_with_wrong_value_count_names_line(tmp_path):
    path = tmp_path / "cols.pcd"
    path.write_bytes(header(*XYZI, 2, "ascii") + b"1 2 3 4\n5 6 7\n")
    error = expect_error(path, "expected 4 values .* found 3")
    assert error.line == 11  # 9 header lines (comment included), then data lines 10 and 11


def test_ascii_value_that_is_not_a_number(tmp_path):
    path = tmp_path / "word.pcd"
    path.write_bytes(header(*XYZI, 1, "ascii") + b"1 2 three 4\n")
    expect_error(path, "cannot parse the ascii data: .*'three'")


def test_compressed_block_size_lies(tmp_path):
    path = tmp_path / "lie.pcd"
    raw = np.zeros(3 * 4, "<f4").tobytes()
    path.write_bytes(header(*XYZI, 5, "binary_compressed") + struct.pack("<II", 10, len(raw)) + b"\0" * 10)
    expect_error(path, r"header claims 5 points \(80 bytes .*\) but the compressed data holds 48 bytes \(3 points\)")


def test_compressed_data_truncated(tmp_path):
    path = tmp_path / "trunc.pcd"
    pcd.write(path, Scene(PointCloud(np.ones((40, 4), np.float32))), encoding="binary_compressed")
    path.write_bytes(path.read_bytes()[:-5])
    expect_error(path, "compressed data block claims .* bytes but only .* follow")


def test_compressed_data_corrupt_is_wrapped(tmp_path):
    path = tmp_path / "bad.pcd"
    path.write_bytes(header(*XYZI, 2, "binary_compressed") + struct.pack("<II", 12, 32) + b"\xff" * 12)
    expect_error(path, "cannot decode the binary_compressed data")


def test_compressed_without_size_fields(tmp_path):
    path = tmp_path / "nosize.pcd"
    path.write_bytes(header(*XYZI, 2, "binary_compressed") + b"\0\0")
    expect_error(path, "header claims 2 points but the binary_compressed data section holds 2 bytes")


def test_unknown_data_encoding(tmp_path):
    path = tmp_path / "enc.pcd"
    path.write_bytes(header(*XYZI, 0, "binary_zstd"))
    expect_error(path, "unknown DATA encoding 'binary_zstd'; expected ascii, binary or binary_compressed")


@pytest.mark.parametrize("key", ["FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "POINTS"])
def test_missing_required_key(tmp_path, key):
    path = tmp_path / "k.pcd"
    lines = [line for line in header(*XYZI, 0).split(b"\n") if not line.startswith(key.encode())]
    path.write_bytes(b"\n".join(lines))
    expect_error(path, f"header lacks {key}")


def test_header_lengths_must_agree(tmp_path):
    path = tmp_path / "len.pcd"
    path.write_bytes(header(("x", "y", "z"), (4, 4), ("F", "F", "F"), 0))
    expect_error(path, "SIZE lists 2 values but FIELDS names 3 fields")


def test_duplicate_key_and_field(tmp_path):
    path = tmp_path / "dup.pcd"
    path.write_bytes(header(*XYZI, 0).replace(b"HEIGHT 1\n", b"HEIGHT 1\nHEIGHT 1\n"))
    expect_error(path, "header key HEIGHT appears twice")
    path.write_bytes(header(("x", "y", "z", "x"), (4,) * 4, ("F",) * 4, 0))
    assert expect_error(path, "appears twice in FIELDS").field == "x"


def test_non_integer_and_negative_header_values(tmp_path):
    path = tmp_path / "int.pcd"
    path.write_bytes(header(*XYZI, 1).replace(b"WIDTH 1", b"WIDTH one"))
    expect_error(path, "WIDTH values must be integers, got 'one'")
    path.write_bytes(header(*XYZI, 0).replace(b"SIZE 4 4 4 4", b"SIZE 4 4 4 -4"))
    expect_error(path, "SIZE values must be ≥ 1")


def test_missing_xyz_field(tmp_path):
    path = tmp_path / "noz.pcd"
    path.write_bytes(header(("x", "y", "intensity"), (4, 4, 4), ("F", "F", "F"), 1, "ascii") + b"1 2 3\n")
    expect_error(path, "no 'z' field")


@pytest.mark.parametrize(
    ("content", "pattern"),
    [
        (b"", "empty file; expected a PCD header"),
        (b"\x89PNG\r\n\x1a\n" + bytes(range(256)), "header line is not text; not a PCD file"),
        (b"hello world\n", "unknown header key 'hello'"),
        (b"VERSION 0.7\nFIELDS x y z\n", "header ends without a DATA line"),
        (b"x" * 70000, "header line too long; not a PCD file"),
    ],
)
def test_not_a_pcd_file(tmp_path, content, pattern):
    path = tmp_path / "junk.pcd"
    path.write_bytes(content)
    expect_error(path, pattern)


def test_missing_file(tmp_path):
    expect_error(tmp_path / "absent.pcd", "file not found")


# ---------------------------------------------------------------- writing
def test_write_refuses_to_overwrite(tmp_path):
    path = tmp_path / "keep.pcd"
    pcd.write(path, Scene(PointCloud(np.ones((3, 4)))))
    original = path.read_bytes()
    with pytest.raises(OutputExistsError, match=re.escape(str(path))):
        pcd.write(path, Scene(PointCloud(np.zeros((5, 4)))))
    assert path.read_bytes() == original
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.pcd"]  # no temporary left behind
    pcd.write(path, Scene(PointCloud(np.zeros((5, 4)))), overwrite=True)
    assert len(pcd.read(path).points) == 5


def test_write_rejects_unknown_encoding_and_padding_channel(tmp_path):
    with pytest.raises(ValueError, match="encoding must be one of"):
        pcd.write(tmp_path / "a.pcd", Scene(PointCloud(np.ones((1, 4)))), encoding="zip")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="marks padding"):
        pcd.write(tmp_path / "b.pcd", Scene(PointCloud(np.ones((1, 5)), (*STANDARD_CHANNELS, "_"))))
    assert not list(tmp_path.iterdir())
