"""LAS/LAZ (ASPRS LiDAR exchange format; LAZ is its compressed form), via :mod:`laspy` and ``lazrs``.

Reading a foreign file:

* ``x, y, z`` are the scaled coordinates converted to float32 — georeferenced files
  with large coordinates (UTM eastings, say) lose precision in float32;
* ``intensity`` is the stored uint16 value, not rescaled
  (``metadata["intensity_scale"] = "uint16"``);
* ``gps_time``, when the point format has it, becomes ``time`` relative to the
  earliest point, whose absolute GPS time becomes ``scene.timestamp`` (absolute GPS
  seconds would lose whole seconds in float32);
* ``classification`` becomes ``label`` when any point has a non-zero class;
* extra-bytes dimensions become channels under their (cleaned) names, ``name_0`` …
  for array dimensions; the other standard dimensions are ignored.

Writing produces LAS 1.4 point format 6 (LAZ when the path ends in ``.laz``) that
other tools can use: coordinates scaled by 1e-4 with the offset at the cloud's minimum
(a coarser power of ten when the extent does not fit 32-bit integers; NaN/Inf
coordinates are stored at the offset), ``intensity`` as uint16 — values in [0, 1]
(KITTI reflectance) scaled by 65535, otherwise rounded and clipped to 0…65535 —,
``time`` (plus the scene timestamp when known) as ``gps_time``, ``label`` as
``classification`` (clipped to 0…255). So that lidarfuzz's own files round-trip
bit-exactly, every channel is also stored as a float32 extra-bytes dimension
``lf_<channel>``; the reader prefers these whenever ``lf_x``, ``lf_y`` and ``lf_z``
exist. Channel names may be at most 29 characters long (extra-bytes names hold 32).
Only points are stored; boxes, calibration and the timestamp do not round-trip.
"""

from __future__ import annotations

import math
from os import PathLike
from pathlib import Path

import laspy  # type: ignore[import-untyped]
import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.io.common import NonFinitePolicy, cloud_from_columns, map_field_names
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

SUFFIXES = (".las", ".laz")
PREFIX = "lf_"
COORDINATE_SCALE = 1e-4
POINT_FORMAT = 6
VERSION = "1.4"
_MAX_NAME = 32
# Largest scaled integer written, a margin below 2**31 - 1 for rounding.
_MAX_SCALED = 2_000_000_000


def _load(path: Path) -> laspy.LasData:
    try:
        return laspy.read(path)
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except Exception as exc:  # laspy, lazrs and numpy all raise their own types on bad input
        raise DataFormatError(path, f"not a readable LAS/LAZ file: {exc}") from exc


def _own_columns(las: laspy.LasData, names: list[str], path: Path) -> dict[str, NDArray[np.generic]]:
    """Channels stored verbatim by lidarfuzz's writer as ``lf_<channel>`` dimensions."""
    columns: dict[str, NDArray[np.generic]] = {}
    for dim in names:
        channel = dim[len(PREFIX) :]
        if not channel.isidentifier():
            raise DataFormatError(path, f"'{dim}' does not name a valid channel", field=dim)
        values = np.asarray(las[dim])
        if values.ndim != 1:
            raise DataFormatError(path, f"expected one value per point, got shape {values.shape}", field=dim)
        columns[channel] = values
    return columns


def _foreign_columns(las: laspy.LasData, path: Path) -> tuple[dict[str, NDArray[np.generic]], float | None]:
    """Channels of a file written by another tool, and the absolute time of its earliest point."""
    sources: dict[str, NDArray[np.generic]] = {
        "x": np.asarray(las.x, dtype=np.float64),
        "y": np.asarray(las.y, dtype=np.float64),
        "z": np.asarray(las.z, dtype=np.float64),
        "intensity": np.asarray(las.intensity),
    }
    t0: float | None = None
    if "gps_time" in las.point_format.dimension_names:
        gps = np.asarray(las.gps_time, dtype=np.float64)
        finite = gps[np.isfinite(gps)]
        t0 = float(finite.min()) if finite.size else 0.0
        sources["gps_time"] = gps - t0
    for dim in las.point_format.extra_dimension_names:
        values = np.asarray(las[dim])
        if values.ndim == 1:
            sources[dim] = values
        else:
            for k in range(values.shape[1]):
                sources[f"{dim}_{k}"] = values[:, k]
    mapping = map_field_names(list(sources))
    columns = {mapping[name]: values for name, values in sources.items()}
    classification = np.asarray(las.classification)
    if "label" not in columns and classification.any():
        columns["label"] = classification
    return columns, t0


def _read(path: Path, nonfinite: NonFinitePolicy) -> tuple[Scene, int]:
    las = _load(path)
    extra = list(las.point_format.extra_dimension_names)
    own = [name for name in extra if name.startswith(PREFIX)]
    meta: dict[str, object] = {
        "source": str(path),
        "format": "laz" if las.header.are_points_compressed else "las",
    }
    timestamp: float | None = None
    if {f"{PREFIX}x", f"{PREFIX}y", f"{PREFIX}z"} <= set(own):
        columns = _own_columns(las, own, path)
    else:
        columns, t0 = _foreign_columns(las, path)
        meta["intensity_scale"] = "uint16"
        if t0:
            timestamp = t0
    cloud, dropped = cloud_from_columns(columns, path, nonfinite=nonfinite)
    if dropped:
        meta["dropped_nonfinite"] = dropped
    return Scene(cloud, frame_id=path.stem, timestamp=timestamp, metadata=meta), dropped


def read_points(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> tuple[PointCloud, int]:
    """Read the cloud; returns it and the number of points dropped for NaN/Inf coordinates."""
    scene, dropped = _read(Path(path), nonfinite)
    return scene.points, dropped


def read(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> Scene:
    """Read a LAS or LAZ file as a scene (points, and a timestamp from ``gps_time`` for foreign files)."""
    scene, _ = _read(Path(path), nonfinite)
    return scene


def _scaled(values: NDArray[np.float64]) -> tuple[NDArray[np.int32], float, float]:
    """Scaled integers, scale and offset for one axis; non-finite values go to the offset."""
    finite = np.isfinite(values)
    if not finite.any():
        return np.zeros(len(values), np.int32), COORDINATE_SCALE, 0.0
    low, high = float(values[finite].min()), float(values[finite].max())
    scale = COORDINATE_SCALE
    if (high - low) / scale > _MAX_SCALED:
        scale = 10.0 ** math.ceil(math.log10((high - low) / _MAX_SCALED))
    scaled = np.zeros(len(values), np.int32)
    scaled[finite] = np.round((values[finite] - low) / scale)
    return scaled, scale, low


def _intensity_uint16(intensity: NDArray[np.float32]) -> NDArray[np.uint16]:
    values = np.where(np.isfinite(intensity), intensity, 0.0).astype(np.float64)
    if values.size and values.max() > 1.0:
        return np.clip(np.round(values), 0, 65535).astype(np.uint16)
    return np.round(np.clip(values, 0.0, 1.0) * 65535).astype(np.uint16)


def write_points(
    path: str | PathLike[str],
    cloud: PointCloud,
    *,
    overwrite: bool = False,
    compress: bool | None = None,
    timestamp: float | None = None,
) -> Path:
    """Write LAS 1.4 point format 6 with every channel also stored exactly as ``lf_<channel>``.

    Args:
        path: Destination file.
        cloud: The points.
        overwrite: Replace an existing file.
        compress: Write LAZ; by default when the path ends in ``.laz``.
        timestamp: Added to ``time`` to give absolute ``gps_time`` values.
    """
    too_long = [c for c in cloud.channels if len(PREFIX + c) > _MAX_NAME]
    if too_long:
        raise ValueError(
            f"channel names {too_long} are too long for LAS extra bytes (at most {_MAX_NAME - len(PREFIX)} characters)"
        )
    if compress is None:
        compress = Path(path).suffix.lower() == ".laz"
    header = laspy.LasHeader(point_format=POINT_FORMAT, version=VERSION)
    header.add_extra_dims([laspy.ExtraBytesParams(name=PREFIX + c, type=np.float32) for c in cloud.channels])
    n = len(cloud)
    xyz = cloud.xyz.astype(np.float64)
    scaled = [_scaled(xyz[:, axis]) for axis in range(3)]
    header.scales = np.array([s for _, s, _ in scaled])
    header.offsets = np.array([o for _, _, o in scaled])
    las = laspy.LasData(header, points=laspy.ScaleAwarePointRecord.zeros(n, header=header))
    las.X, las.Y, las.Z = (ints for ints, _, _ in scaled)
    las.intensity = _intensity_uint16(cloud.intensity)
    las.return_number = np.ones(n, np.uint8)
    las.number_of_returns = np.ones(n, np.uint8)
    if cloud.has("time") or timestamp is not None:
        time = cloud.channel("time").astype(np.float64) if cloud.has("time") else np.zeros(n)
        time = np.where(np.isfinite(time), time, 0.0)
        las.gps_time = time + (timestamp or 0.0)
    if cloud.has("label"):
        label = cloud.channel("label")
        las.classification = np.clip(np.round(np.where(np.isfinite(label), label, 0.0)), 0, 255).astype(np.uint8)
    for i, channel in enumerate(cloud.channels):
        las[PREFIX + channel] = cloud.data[:, i]
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as handle:
        las.write(handle, do_compress=compress)
    return Path(path)


def write(path: str | PathLike[str], scene: Scene, *, overwrite: bool = False) -> Path:
    """Write the scene's points (LAZ for a ``.laz`` path); ``gps_time`` is timestamp + ``time``."""
    return write_points(path, scene.points, overwrite=overwrite, timestamp=scene.timestamp)
