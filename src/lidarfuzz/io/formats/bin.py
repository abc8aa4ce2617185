"""KITTI Velodyne ``.bin``: N×4 little-endian float32 ``x, y, z, reflectance``, no header.

Reading memory-maps the file, so a 120k-point frame is available in well under a
millisecond; only a frame with non-finite coordinates is copied (to drop them).
An empty file is a valid, empty cloud.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.io.common import NonFinitePolicy, finish_cloud
from lidarfuzz.scene.points import STANDARD_CHANNELS, PointCloud
from lidarfuzz.scene.scene import Scene

SUFFIXES = (".bin",)
RECORD_BYTES = 16


def read_points(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> tuple[PointCloud, int]:
    """Read the cloud; returns it and the number of points dropped for NaN/Inf coordinates."""
    path = Path(path)
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    if size % RECORD_BYTES:
        raise DataFormatError(
            path,
            f"size {size} bytes is not a multiple of {RECORD_BYTES} "
            f"(a KITTI .bin holds N×4 float32 x, y, z, reflectance; {size % RECORD_BYTES} trailing bytes)",
            hint="the file is truncated or not a KITTI velodyne scan",
        )
    if size == 0:
        return PointCloud.empty(), 0
    data = np.memmap(path, dtype="<f4", mode="r").reshape(-1, 4)
    return finish_cloud(data, STANDARD_CHANNELS, path, nonfinite=nonfinite)


def read(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> Scene:
    cloud, dropped = read_points(path, nonfinite=nonfinite)
    meta: dict[str, object] = {"source": str(path), "format": "bin"}
    if dropped:
        meta["dropped_nonfinite"] = dropped
    return Scene(cloud, frame_id=Path(path).stem, metadata=meta)


def write_points(path: str | PathLike[str], cloud: PointCloud, *, overwrite: bool = False,
                 durable: bool = True) -> Path:
    """Write ``x, y, z, intensity`` (other channels cannot be stored in a .bin)."""
    with atomic_path(path, overwrite=overwrite, durable=durable) as tmp:
        np.ascontiguousarray(cloud.data[:, :4], dtype="<f4").tofile(tmp)
    return Path(path)


def write(path: str | PathLike[str], scene: Scene, *, overwrite: bool = False) -> Path:
    return write_points(path, scene.points, overwrite=overwrite)
