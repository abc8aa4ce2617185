"""The KITTI ``.bin`` writer's fast path writes exactly the bytes of the former one-copy code.

``write_points`` gathers a cloud's first four columns as 16-byte records and writes them in
chunks (:func:`lidarfuzz.io.formats.bin._write_first4`). The reference here is the former
computation, ``np.ascontiguousarray(data[:, :4], dtype="<f4").tobytes()``, over the memory
layouts a :class:`PointCloud` can hold: many channels or exactly four, more rows than one
chunk, row-strided and column-major views, unaligned data, and no points at all.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.io.formats import bin as bin_format
from lidarfuzz.scene.points import PointCloud


def former_bytes(data: np.ndarray) -> bytes:
    """What ``write_points`` wrote before the fast path."""
    return np.ascontiguousarray(data[:, :4], dtype="<f4").tobytes()


def values(rows: int, columns: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    data = rng.normal(0.0, 30.0, (rows, columns)).astype(np.float32)
    data[::7, 3] = np.nan  # odd values travel as bytes too
    data[::11, 0] = -0.0
    return data


def unaligned(rows: int, columns: int) -> np.ndarray:
    """A float32 array whose rows start 4 bytes off a 16-byte boundary."""
    raw = np.zeros(rows * columns * 4 + 20, np.uint8)
    start = (-raw.ctypes.data) % 16 + 4
    data = raw[start:start + rows * columns * 4].view(np.float32).reshape(rows, columns)
    data[...] = values(rows, columns, seed=3)
    return data


CHUNK = bin_format._WRITE_CHUNK_RECORDS
LAYOUTS = {
    "eight channels, several chunks": values(2 * CHUNK + 17, 8),
    "four channels (already contiguous)": values(CHUNK + 1, 4),
    "five channels": values(1000, 5, seed=1),
    "exactly one chunk": values(CHUNK, 6, seed=2),
    "every second row": values(3000, 8)[::2],
    "column-major": np.asfortranarray(values(500, 8)),
    "one row, column-major": np.asfortranarray(values(1, 8)),
    "unaligned": unaligned(999, 8),
    "empty": np.zeros((0, 8), np.float32),
}


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_write_points_bytes_match_the_former_copy(tmp_path: Path, name: str) -> None:
    data = LAYOUTS[name]
    channels = ("x", "y", "z", "intensity", "ring", "time", "label", "instance")[: data.shape[1]]
    cloud = PointCloud(data, channels)
    out = bin_format.write_points(tmp_path / "velodyne" / "000000.bin", cloud)
    assert out.read_bytes() == former_bytes(cloud.data)
    assert out.stat().st_size == 16 * len(cloud)
