"""Hostile frame files (issue 23): each escape the fuzzing found, minimised, built here in code.

A file whose header lies must be refused with one line naming the file (and the header field),
never obeyed. The escapes that hung, exhausted memory or aborted the process before the fix
run in a child process under a time limit and an address-space limit, so that a regression
fails this test instead of killing pytest.
"""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFiniteWarning
from lidarfuzz.io.formats import las, npy, pcd
from lidarfuzz.io.frames import read_frame
from lidarfuzz.scene import PointCloud, Scene

REPO = Path(__file__).resolve().parents[2]
#: The child's address-space limit: far below what the hostile headers claim (tens of GB).
CHILD_MEMORY = 3 << 30

_CHILD = """
import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({memory}, {memory}))
{setup}
from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.frames import read_frame
try:
    read_frame(sys.argv[1])
    print(json.dumps({{"outcome": "read"}}))
except DataFormatError as exc:
    print(json.dumps({{"outcome": "refused", "message": str(exc), "field": exc.field}}))
"""


def read_isolated(path: Path, *, timeout: float = 60.0, setup: str = "") -> dict[str, str]:
    """Read ``path`` with read_frame in a child (limited memory and time); what came of it.

    A hang, an abort (SIGABRT), a MemoryError or any foreign exception fails the calling test.
    """
    code = _CHILD.format(memory=CHILD_MEMORY, setup=setup)
    env = {"PATH": "/usr/bin:/bin", "RUST_BACKTRACE": "0", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "PYTHONPATH": os.environ.get("PYTHONPATH", "")}
    try:
        done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True,
                              timeout=timeout, cwd=REPO, env=env)
    except subprocess.TimeoutExpired:
        pytest.fail(f"reading {path.name} hung for over {timeout:g} s")
    assert done.returncode == 0, f"the reader died (exit {done.returncode}): {done.stderr[-1500:]}"
    result: dict[str, str] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def expect_refusal(result: dict[str, str], path: Path, pattern: str, field: str | None = None) -> None:
    """A one-line refusal that starts with the file's path, names the field and matches ``pattern``."""
    assert result["outcome"] == "refused", result
    message = result["message"]
    assert message.startswith(str(path)), message
    assert "\n" not in message
    if field is not None:
        assert result["field"] == field
        assert f"field '{field}'" in message
    assert pytest.importorskip("re").search(pattern, message), message


# ----------------------------------------------------------------------------- LAS / LAZ
def small_las(path: Path, points: int = 100) -> bytes:
    """A valid LAS/LAZ written by lidarfuzz's own writer (format 6, LAS 1.4, four lf_ channels)."""
    rng = np.random.default_rng(0)
    las.write(path, Scene(PointCloud(rng.uniform(-10, 10, (points, 4)).astype(np.float32))), overwrite=True)
    return path.read_bytes()


def laz_with_chunk_count(path: Path, chunks: int) -> Path:
    """LAZ whose chunk table header claims ``chunks`` chunks (LASzip: the i64 at the point data's start
    is the table's offset; the table starts with u32 version, u32 number of chunks)."""
    data = bytearray(small_las(path))
    offset = int.from_bytes(data[96:100], "little")  # offset_to_point_data (LAS 1.4 R15, table 3)
    table = struct.unpack_from("<q", data, offset)[0]
    struct.pack_into("<I", data, table + 4, chunks)
    path.write_bytes(bytes(data))
    return path


def test_laz_chunk_table_claiming_2_32_chunks_is_refused(tmp_path):
    # A ~4 KB LAZ of 100 points whose chunk table claims 2^32 - 1 chunks: lazrs reserved memory for
    # them (68 GB at 16 bytes each), failed and aborted the whole process (exit 134). Each chunk
    # starts with one raw point (>= 20 bytes), so the claim needs 85,899,345,900 bytes.
    path = laz_with_chunk_count(tmp_path / "chunks.laz", 0xFFFFFFFF)
    assert path.stat().st_size < 5000
    expect_refusal(read_isolated(path), path, "85,899,345,900 bytes of chunks", field="number_of_chunks")


def test_laz_decoder_abort_cannot_take_the_caller_down(tmp_path):
    # Defence in depth: with the chunk-table check switched off, lazrs still aborts on this file,
    # but in the forked child that decodes; the caller gets a DataFormatError naming the file.
    path = laz_with_chunk_count(tmp_path / "abort.laz", 0xFFFFFFFF)
    setup = "import lidarfuzz.io.formats.las as L; L._check_chunk_table = lambda *a: None"
    expect_refusal(read_isolated(path, setup=setup), path, r"cannot decode the LAZ points: the decoder crashed "
                   r"\(SIGABRT\)")


def test_lidarfuzz_info_on_a_corrupt_laz_reports_the_problem(tmp_path):
    # `lidarfuzz info x.laz` exited 134 (SIGABRT); now it reports the unreadable frame as a problem
    # (exit 1, info's code for error-level problems): 2^31 - 1 chunks x 20 bytes = 42,949,672,940
    path = laz_with_chunk_count(tmp_path / "x.laz", 0x7FFFFFFF)
    capped = f"import resource; resource.setrlimit(resource.RLIMIT_AS, ({CHILD_MEMORY}, {CHILD_MEMORY}))"
    done = subprocess.run([sys.executable, "-c", f"{capped}; from lidarfuzz.cli.app import main; main()", "info",
                           str(path)], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert done.returncode == 1, done.stderr
    assert done.stderr == ""
    problems = [line for line in done.stdout.splitlines() if line.strip().startswith("error:")]
    assert len(problems) == 1 and f"{path}: field 'number_of_chunks': " in problems[0]
    assert "42,949,672,940 bytes of chunks" in problems[0]


def test_las_claiming_2_32_vlrs_is_refused(tmp_path):
    # number_of_vlrs (u32 at byte 100) = 2^32 - 1: laspy read empty VLRs from its prefetched header
    # for ever. 2^32 - 1 VLR headers of 54 bytes cannot fit between the 375-byte header and the
    # point data.
    path = tmp_path / "vlrs.las"
    data = bytearray(small_las(path))
    struct.pack_into("<I", data, 100, 0xFFFFFFFF)
    path.write_bytes(bytes(data))
    expect_refusal(read_isolated(path, timeout=30), path, "231,928,233,930 bytes of VLR headers",
                   field="number_of_vlrs")


def test_las_point_count_beyond_the_file_is_refused(tmp_path):
    # LAS 1.4 point count (u64 at byte 247) = 2^40: 2^40 records of 46 bytes (format 6's 30 + four
    # float32 extra bytes) = 50,577,534,877,696 bytes, checked before laspy allocates
    path = tmp_path / "count.las"
    data = bytearray(small_las(path))
    struct.pack_into("<Q", data, 247, 1 << 40)
    path.write_bytes(bytes(data))
    expect_refusal(read_isolated(path), path, "50,577,534,877,696 bytes of points", field="point_count")


def test_las_offset_to_point_data_beyond_the_file_is_refused(tmp_path):
    path = tmp_path / "offset.las"
    data = bytearray(small_las(path))
    struct.pack_into("<I", data, 96, len(data) + 1)
    path.write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match="field 'offset_to_point_data'") as info:
        read_frame(path)
    assert str(info.value).startswith(str(path))


# ----------------------------------------------------------------------------- PCD
def pcd_with_count(path: Path, count: int, encoding: str = "ascii", points: int = 0) -> Path:
    path.write_bytes(
        f"VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 {count} 1\n"
        f"WIDTH {points}\nHEIGHT 1\nPOINTS {points}\nDATA {encoding}\n".encode())
    return path


@pytest.mark.parametrize("count", [10**12, 10**6])
def test_pcd_count_is_capped(tmp_path, count):
    # COUNT 10^12 exhausted memory, 10^6 spun for over 200 s (a record layout of a million fields)
    path = pcd_with_count(tmp_path / f"count{count}.pcd", count)
    expect_refusal(read_isolated(path, timeout=30), path, f"COUNT claims {count + 3:,} values per point",
                   field="COUNT")


def test_pcd_binary_compressed_size_beyond_lzf_is_refused(tmp_path):
    # 100,000,000 points x 16 bytes = 1,600,000,000 bytes declared from a 16-byte compressed block:
    # LZF packs at most 88:1, so at most 88 x 16 + 8 = 1,416 bytes can come out of it
    path = tmp_path / "lzf.pcd"
    header = pcd_with_count(path, 1, "binary_compressed", 100_000_000).read_bytes()
    path.write_bytes(header + struct.pack("<II", 16, 1_600_000_000) + b"\0" * 16)
    expect_refusal(read_isolated(path), path, "1,600,000,000 bytes of decompressed data", field="POINTS")


# ----------------------------------------------------------------------------- NPY / NPZ
def npy_bytes(header: str) -> bytes:
    """A version 1.0 .npy whose header text is ``header`` (padded as numpy pads it)."""
    text = header.encode("latin1")
    text += b" " * (-(len(text) + 11) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(text)) + text


def test_npy_shape_beyond_the_file_is_refused(tmp_path):
    # numpy allocated 10^12 x 4 float32 = 16 TB and its MemoryError escaped
    path = tmp_path / "shape.npy"
    path.write_bytes(npy_bytes("{'descr': '<f4', 'fortran_order': False, 'shape': (1000000000000, 4), }"))
    expect_refusal(read_isolated(path), path, r"shape \(1000000000000, 4\) \(16,000,000,000,000 bytes\)",
                   field="shape")


def test_npy_header_with_an_unclosed_bracket_is_refused(tmp_path):
    # numpy's header filter ran Python's tokenizer: tokenize.TokenError escaped
    path = tmp_path / "token.npy"
    path.write_bytes(npy_bytes("{'descr': '<f4', 'fortran_order': False, 'shape': (3,\n"))
    with pytest.raises(DataFormatError, match=r"cannot load: the \.npy header is not a Python literal") as info:
        npy.read(path)
    assert str(info.value).startswith(str(path))


def test_npy_header_nested_deeply_is_refused(tmp_path):
    # a descr nested 3,000 deep (within numpy's 10,000-byte header limit): RecursionError or a
    # parser overflow in numpy's parsing
    path = tmp_path / "deep.npy"
    path.write_bytes(npy_bytes("{'descr': " + "[" * 3000 + "]" * 3000 + ", 'fortran_order': False, 'shape': (1,), }"))
    with pytest.raises(DataFormatError, match="nests deeper than 16 levels"):
        npy.read(path)


def npz_bytes(members: dict[str, bytes], declared: dict[str, int] | None = None) -> bytes:
    """A zip of ``members``; ``declared`` overrides a member's uncompressed size in both headers."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    data = bytearray(buffer.getvalue())
    for name, size in (declared or {}).items():
        encoded = name.encode()
        for signature, size_at in ((b"PK\x03\x04", 22), (b"PK\x01\x02", 24)):  # local header, central directory
            at = data.find(signature + b"")
            while at >= 0:
                name_at = at + (30 if signature == b"PK\x03\x04" else 46)
                if data[name_at:name_at + len(encoded)] == encoded:
                    struct.pack_into("<I", data, at + size_at, size)
                at = data.find(signature, at + 4)
    return bytes(data)


def test_npz_member_shape_beyond_the_archive_is_refused(tmp_path):
    path = tmp_path / "shape.npz"
    path.write_bytes(npz_bytes({"points.npy": npy_bytes(
        "{'descr': '<f4', 'fortran_order': False, 'shape': (1000000000000, 4), }")}))
    expect_refusal(read_isolated(path), path, "16,000,000,000,000 bytes", field="points.shape")


def test_npz_member_declaring_more_than_deflate_can_pack_is_refused(tmp_path):
    # a member whose directory entry declares 4,000,000,000 uncompressed bytes from a few dozen
    # compressed ones: DEFLATE packs at most ~1,032:1
    member = npy_bytes("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 4), }") + b"\0" * 32
    path = tmp_path / "ratio.npz"
    path.write_bytes(npz_bytes({"points.npy": member}, declared={"points.npy": 4_000_000_000}))
    expect_refusal(read_isolated(path), path, "4,000,000,000 bytes of decompressed data", field="points.npy")


def test_npz_member_header_with_an_unclosed_bracket_is_refused(tmp_path):
    path = tmp_path / "token.npz"
    path.write_bytes(npz_bytes({"points.npy": npy_bytes("{'descr': '<f4', 'fortran_order': False, 'shape': ((")}))
    with pytest.raises(DataFormatError, match=r"field 'points': cannot load: the \.npy header is not a Python literal"):
        npy.read(path)


def test_scene_archive_with_deeply_nested_metadata_is_refused(tmp_path):
    # metadata_json nested 100,000 deep: json.loads raised RecursionError
    arrays = npy.scene_arrays(Scene(PointCloud.empty()))
    arrays["metadata_json"] = np.array("[" * 100_000 + "]" * 100_000, dtype=np.str_)
    path = tmp_path / "deep.npz"
    with open(path, "wb") as handle:
        np.savez(handle, **arrays)
    with pytest.raises(DataFormatError) as info:
        npy.read(path)
    assert str(info.value).startswith(str(path))


def test_pcd_module_refuses_count_in_process(tmp_path):
    # the same cap, in process, for a COUNT just over it: 65,534 + 3 values > 65,536
    path = pcd_with_count(tmp_path / "over.pcd", pcd.MAX_VALUES_PER_POINT - 2)
    with pytest.raises(DataFormatError, match="field 'COUNT': COUNT claims 65,537 values per point"):
        pcd.read(path)


# ----------------------------------------------------------------------------- warnings on the terminal
@pytest.mark.parametrize(("name", "content"), [
    ("big.pcd", b"VERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 2\n"
                b"HEIGHT 1\nPOINTS 2\nDATA ascii\n1e308 1 1 0.5\n1 2 3 0.25\n"),
    ("big.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
                b"property float intensity\nend_header\n1e308 1 1 0.5\n1 2 3 0.25\n"),
])
def test_values_beyond_float32_become_inf_without_a_numpy_warning(tmp_path, name, content):
    # The fuzzing's CLI run of `lidarfuzz info` on a PLY holding 1e308 printed numpy's two-line
    # "RuntimeWarning: overflow encountered in cast". Such a value becomes inf, silently, and the
    # non-finite policy applies: the point with x = inf is dropped, the other kept.
    path = tmp_path / name
    path.write_bytes(content)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        warnings.simplefilter("ignore", NonFiniteWarning)
        scene = read_frame(path)
    assert len(scene.points) == 1
    assert scene.points.xyz.tolist() == [[1.0, 2.0, 3.0]]
    assert scene.points.intensity.tolist() == [0.25]
