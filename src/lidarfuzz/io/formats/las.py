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

A file's header is checked against its size before laspy or lazrs act on it (VLR and EVLR
counts, the point-data offset, the point count; for LAZ the chunk table's place and chunk count,
and at most 8,192 decoded bytes per stored byte). LAZ points are then decoded in a forked child
(single-threaded, under an address-space and a time limit) into shared memory: a corrupt file
that makes lazrs abort ends the child, and the caller gets a DataFormatError naming the file.
"""

from __future__ import annotations

import math
import mmap
import os
import resource
import select
import signal
import time
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import BinaryIO, NoReturn

import laspy  # type: ignore[import-untyped]
import lazrs  # type: ignore[import-untyped]
import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.io.common import NonFinitePolicy, cloud_from_columns, map_field_names
from lidarfuzz.io.guards import describe, file_size, reading, require_bytes
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


#: Bytes of a VLR's header (LAS 1.4 R15, 2.5) and of an EVLR's (2.6).
_VLR_HEADER = 54
_EVLR_HEADER = 60
#: The smallest public header a LAS file may have (LAS 1.0–1.2: 227 bytes).
_MIN_HEADER = 227
_LASZIP_USER_ID = b"laszip encoded"
#: The shortest point record (format 0).
_MIN_POINT_RECORD = 20
_LASZIP_RECORD_ID = 22204
#: Seconds the LAZ decoder may take per declared megabyte of points (plus a fixed allowance).
_DECODE_SECONDS_PER_MB = 0.5
_DECODE_SECONDS = 20.0
#: Decoded bytes a LAZ file may declare per byte it holds: the densest packing measured (a
#: million identical points) is 3,568:1, so this refuses no real file.
_MAX_LAZ_RATIO = 8192


@dataclass(frozen=True)
class _Layout:
    """What the public header and VLR headers say, checked against the file's real size."""

    size: int
    offset_to_point_data: int
    point_count: int
    record_length: int
    compressed: bool
    laszip_vlr: bytes | None


def _u(data: bytes, offset: int, width: int) -> int:
    return int.from_bytes(data[offset:offset + width], "little")


def _check_layout(path: Path) -> _Layout:
    """Check the LAS public header (ASPRS LAS 1.4 R15, 2.4–2.6) against the file's size before
    laspy or lazrs act on it: a header claiming 2³² VLRs, a point-data offset or point count
    beyond the file, EVLRs that cannot fit."""
    size = file_size(path)
    with open(path, "rb") as handle:
        head = handle.read(375)
        if head[:4] != b"LASF":
            raise DataFormatError(path, "not a readable LAS/LAZ file: no 'LASF' signature")
        if len(head) < _MIN_HEADER:
            raise DataFormatError(path, f"not a readable LAS/LAZ file: its public header is truncated ({len(head)} "
                                  f"of at least {_MIN_HEADER} bytes)")
        minor, header_size = head[25], _u(head, 94, 2)
        offset, vlr_count = _u(head, 96, 4), _u(head, 100, 4)
        format_id, record_length = head[104], _u(head, 105, 2)
        point_count = _u(head, 247, 8) if minor >= 4 and len(head) >= 255 else _u(head, 107, 4)
        if header_size < _MIN_HEADER or header_size > size:
            raise DataFormatError(path, f"header size {header_size} is not between {_MIN_HEADER} and the file's "
                                  f"{size:,} bytes", field="header_size")
        require_bytes(path, offset, size, field="offset_to_point_data", what="header and VLRs")
        require_bytes(path, vlr_count * _VLR_HEADER, offset - header_size, field="number_of_vlrs",
                      what="VLR headers")
        compressed = bool(format_id & 0x80)
        laszip = _walk_vlrs(path, handle, header_size, offset, vlr_count) if compressed else None
        if compressed and laszip is None:
            raise DataFormatError(path, "compressed points (LAZ) but no LASzip VLR describing them",
                                  field="point_data_format")
        if compressed:
            _check_chunk_table(path, handle, offset, size)
        if minor >= 4 and len(head) >= 247:
            evlr_start, evlr_count = _u(head, 235, 8), _u(head, 243, 4)
            if evlr_count:
                require_bytes(path, evlr_start, size, field="start_of_first_evlr", what="points")
                require_bytes(path, evlr_count * _EVLR_HEADER, size - evlr_start, field="number_of_evlrs",
                              what="EVLR headers")
    if not compressed:
        require_bytes(path, point_count * record_length, size - offset, field="point_count", what="points")
    return _Layout(size, offset, point_count, record_length, compressed, laszip)


def _check_chunk_table(path: Path, handle: BinaryIO, offset: int, size: int) -> None:
    """The LASzip chunk table's place and chunk count: each chunk starts with one raw point (at
    least 20 bytes), so the chunks cannot outnumber what lies between the points' start and the
    table. (lazrs reserves memory for the count it reads: 2³² − 1 chunks asked for 68 GB.)"""
    if size < offset + 8:
        raise DataFormatError(path, "the LAZ point data is truncated before its chunk table offset",
                              field="offset_to_point_data")
    handle.seek(offset)
    table = int.from_bytes(handle.read(8), "little", signed=True)
    if table == -1:  # written without seeking back: the offset is the file's last 8 bytes
        handle.seek(size - 8)
        table = int.from_bytes(handle.read(8), "little", signed=True)
    if not offset + 8 <= table <= size - 8:
        raise DataFormatError(path, f"the chunk table offset {table:,} lies outside the point data "
                              f"({offset + 8:,}…{size - 8:,})", field="chunk_table_offset")
    handle.seek(table + 4)
    chunks = int.from_bytes(handle.read(4), "little")
    require_bytes(path, chunks * _MIN_POINT_RECORD, table - offset - 8, field="number_of_chunks",
                  what="chunks (each starts with one raw point)")


def _walk_vlrs(path: Path, handle: BinaryIO, start: int, end: int, count: int) -> bytes | None:
    """The LASzip VLR's payload, walking ``count`` VLR headers (each within ``start``…``end``)."""
    position = start
    for index in range(count):
        handle.seek(position)
        vlr = handle.read(_VLR_HEADER)
        length = _u(vlr, 20, 2)
        if len(vlr) < _VLR_HEADER or position + _VLR_HEADER + length > end:
            raise DataFormatError(path, f"VLR {index} ({length} bytes at byte {position}) runs past the point data "
                                  f"at byte {end}", field="number_of_vlrs")
        if vlr[2:18].rstrip(b"\0") == _LASZIP_USER_ID and _u(vlr, 18, 2) == _LASZIP_RECORD_ID:
            return handle.read(length)
        position += _VLR_HEADER + length
    return None


def _decode_laz(path: Path, layout: _Layout) -> laspy.LasData:
    """Decode a LAZ file where an abort cannot take this process down.

    lazrs, given a corrupt chunk table, asks for tens of gigabytes and aborts (SIGABRT, which
    Python cannot catch). So the points are decoded in a forked child, single-threaded (a
    forked copy of a thread pool has no threads), under an address-space limit and a time
    limit, into shared memory the parent sized from the checked header; the parent parses the
    header and VLRs itself (pure Python, after :func:`_check_layout`). A child that dies or
    runs out of time becomes a DataFormatError naming the file. Where ``fork`` does not exist,
    the file is decoded in this process.
    """
    if not hasattr(os, "fork"):
        with reading(path, "read the LAS/LAZ file"):
            return laspy.read(path)
    with reading(path, "read the LAS/LAZ header"), open(path, "rb") as handle:
        header = laspy.LasHeader.read_from(handle)
    needed = header.point_count * header.point_format.size
    # LASzip packs constant points ~3,600:1 (1M identical points of lidarfuzz's format: 12.9 KB)
    require_bytes(path, needed, _MAX_LAZ_RATIO * layout.size, field="point_count", what="decoded points")
    with reading(path, "decode the LAZ points"):
        shared = mmap.mmap(-1, max(needed, 1))
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: decode, copy into the shared buffer, say how many bytes, exit
        os.close(read_fd)
        _laz_child(path, layout, header.point_count, shared, needed, write_fd)
    os.close(write_fd)
    limit = _DECODE_SECONDS + _DECODE_SECONDS_PER_MB * needed / 1e6
    status = _child_status(pid, read_fd, limit)
    if status != "ok":
        raise DataFormatError(path, f"cannot decode the LAZ points: {status}",
                              hint="the file is damaged (its chunk table or compressed data)")
    points = np.frombuffer(shared, dtype=header.point_format.dtype(), count=header.point_count)
    return laspy.LasData(header, points=laspy.PackedPointRecord(points, header.point_format))


def _laz_child(path: Path, layout: _Layout, count: int, shared: mmap.mmap, needed: int, status_fd: int) -> NoReturn:
    """In the forked child: decode with lazrs and report; never returns into the caller's code."""
    code = 1
    offset, laszip_vlr = layout.offset_to_point_data, layout.laszip_vlr
    try:
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
        budget = _address_space() + 2 * needed + _CHILD_ALLOWANCE
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        if soft == resource.RLIM_INFINITY or budget < soft:
            resource.setrlimit(resource.RLIMIT_AS, (budget, hard))
        with open(path, "rb") as source:
            source.seek(offset)
            decompressor = lazrs.LasZipDecompressor(source, laszip_vlr)
            if lazrs.LazVlr(laszip_vlr).item_size() * count != needed:
                message = "the LASzip VLR's point size differs from the header's point format"
            else:
                decompressor.decompress_many(memoryview(shared)[:needed])
                message, code = "ok", 0
    except MemoryError:
        message = "its chunk table or point count claims more memory than the file can hold"
    except BaseException as exc:  # everything goes back to the parent as one line
        message = describe(exc)
    try:
        os.write(status_fd, message.encode("utf-8", "replace")[:1000])
    finally:
        os._exit(code)


#: Address space the decoding child may use beyond its parent's and twice the points' size.
_CHILD_ALLOWANCE = 512 << 20


def _address_space() -> int:
    """This process's mapped address space in bytes (``VmSize``), 0 where unknown."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def _child_status(pid: int, status_fd: int, limit: float) -> str:
    """What the decoding child reported ("ok" or why not); killed past ``limit`` seconds."""
    chunks: list[bytes] = []
    deadline = time.monotonic() + limit
    try:
        while True:
            left = deadline - time.monotonic()
            ready = select.select([status_fd], [], [], max(left, 0))[0] if left > 0 else []
            if not ready:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                return f"the decoder did not finish within {limit:.0f} s"
            chunk = os.read(status_fd, 4096)
            if not chunk:
                break
            chunks.append(chunk)
    except BaseException:  # interrupted (Ctrl-C, a signal): the child must not outlive the wait
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        raise
    finally:
        os.close(status_fd)
    _, wait_status = os.waitpid(pid, 0)
    message = b"".join(chunks).decode("utf-8", "replace")
    if os.WIFSIGNALED(wait_status):
        return f"the decoder crashed ({signal.Signals(os.WTERMSIG(wait_status)).name})"
    return message or "the decoder exited without a word"


def _load(path: Path) -> laspy.LasData:
    layout = _check_layout(path)
    if layout.compressed:
        return _decode_laz(path, layout)
    with reading(path, "read the LAS file"):
        return laspy.read(path)


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
    with reading(path, "read the LAS/LAZ file"):
        return _read_loaded(path, _load(path), nonfinite)


def _read_loaded(path: Path, las: laspy.LasData, nonfinite: NonFinitePolicy) -> tuple[Scene, int]:
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
