"""Headerless ``.bin`` scans: N records of a :class:`~lidarfuzz.io.layouts.PointLayout`.

KITTI's velodyne scans (N×4 little-endian float32 ``x, y, z, reflectance``) are the default;
nuScenes' ``.pcd.bin`` (5 columns), Waymo's KITTI-format exports (6), SemanticKITTI (KITTI
plus ``labels/``) and explicit column specs are read by layout (:mod:`lidarfuzz.io.layouts`).
Since the file has no header, every read checks a strided sample of its rows against the
layout and refuses values that cannot be what the layout says, naming the layout that fits.

Reading a float32 layout memory-maps the file (``mmap``), so a 120k-point frame is available in well
under a millisecond; only a frame with non-finite coordinates, other column types or point
labels is copied. An empty file is a valid, empty cloud.
"""

from __future__ import annotations

import mmap
import os
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.io.common import NonFinitePolicy, cloud_from_columns, finish_cloud
from lidarfuzz.io.formats import semantickitti
from lidarfuzz.io.layouts import LAYOUTS, PointLayout, check_plausible, resolve_layout
from lidarfuzz.scene.points import CHANNEL_DEFAULTS, PointCloud
from lidarfuzz.scene.scene import Scene

SUFFIXES = (".bin",)
RECORD_BYTES = 16  # a KITTI record


def frame_id_of(path: str | PathLike[str]) -> str:
    """A scan's frame id: its name without ``.bin`` (or nuScenes' ``.pcd.bin``)."""
    name = Path(path).name
    return name[: -len(".pcd.bin")] if name.lower().endswith(".pcd.bin") else Path(name).stem


@dataclass(frozen=True)
class ScanRead:
    """A scan read with a layout, and what the reader learnt about it."""

    cloud: PointCloud
    dropped: int
    layout: PointLayout
    intensity_scale: float | None
    doubts: tuple[str, ...] = ()

    def metadata(self) -> dict[str, Any]:
        """The scene metadata a reader records: the layout, the intensity scale (when known), the
        doubts a user-chosen layout overrode and the points dropped for NaN/Inf coordinates."""
        meta: dict[str, Any] = {"layout": self.layout.name}
        if self.intensity_scale is not None:
            meta["intensity_scale"] = self.intensity_scale
        if self.doubts:
            meta["layout_doubts"] = list(self.doubts)
        if self.dropped:
            meta["dropped_nonfinite"] = self.dropped
        return meta


def _size_error(path: Path, size: int, layout: PointLayout) -> DataFormatError:
    record = layout.record_size
    fits = [n for n in ("kitti", "nuscenes", "waymo") if size % LAYOUTS[n].record_size == 0
            and LAYOUTS[n].record_size != record]
    hint = (f"the size fits {LAYOUTS[fits[0]].describe()}: try --layout {fits[0]}" if fits
            else "the file is truncated or not a scan of this layout")
    what = ("a KITTI .bin holds N×4 float32 x, y, z, reflectance" if layout.name in ("kitti", "kitti360")
            else f"a {layout.describe()} record is {record} bytes")
    return DataFormatError(path, f"size {size} bytes is not a multiple of {record} ({what}; {size % record} "
                           "trailing bytes)", hint=hint)


def read_scan(path: str | PathLike[str], *, layout: PointLayout | str | None = None,
              nonfinite: NonFinitePolicy = "drop", user_chosen: bool | None = None) -> ScanRead:
    """Read a scan with ``layout`` (default: what the path says, else KITTI's).

    ``user_chosen`` says whether a :class:`PointLayout` passed in was the user's choice (a data
    set resolves its layout once and passes it for every scan); a name or spec always is.

    Raises:
        DataFormatError: A missing file, a size that is not whole records, values that do not
            fit the layout (naming the layout that does), or a bad SemanticKITTI label file.
    """
    path = Path(path)
    chosen_layout, chosen = resolve_layout(path, layout, user_chosen=user_chosen)
    if chosen_layout.container != "bin":
        raise DataFormatError(path, f"layout {chosen_layout.name} reads .{chosen_layout.container} files, not .bin")
    try:
        with open(path, "rb") as handle:
            size = os.fstat(handle.fileno()).st_size
            if size % chosen_layout.record_size:
                raise _size_error(path, size, chosen_layout)
            scale = chosen_layout.intensity_scale
            if size == 0:
                return ScanRead(PointCloud.empty(chosen_layout.channels), 0, chosen_layout, scale)
            # mmap itself, not np.memmap (whose Python-level set-up costs more than the read); the
            # array keeps the map alive
            raw = np.frombuffer(mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ), dtype=np.uint8)
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except IsADirectoryError:
        raise DataFormatError(path, "is a folder, not a scan") from None
    verdict = check_plausible(path, raw, chosen_layout, chosen=chosen)
    scale = verdict.intensity_scale or scale
    doubts = () if verdict.fits else verdict.reasons
    labels = (semantickitti.read_labels(semantickitti.label_path(path), size // chosen_layout.record_size)
              if chosen_layout.point_labels else None)
    if chosen_layout.float32_only and labels is None:
        data = raw.view("<f4").reshape(-1, len(chosen_layout.columns))
        cloud, dropped = finish_cloud(data, chosen_layout.channels, path, nonfinite=nonfinite)
    else:
        records = raw.view(chosen_layout.record_dtype)
        columns: dict[str, Any] = {c.channel: records[c.channel] for c in chosen_layout.columns if not c.skipped}
        columns.update(labels or {})
        cloud, dropped = cloud_from_columns(columns, path, nonfinite=nonfinite)
    return ScanRead(cloud, dropped, chosen_layout, scale, doubts)


def read_points(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop",
                layout: PointLayout | str | None = None) -> tuple[PointCloud, int]:
    """Read the cloud; returns it and the number of points dropped for NaN/Inf coordinates."""
    scan = read_scan(path, layout=layout, nonfinite=nonfinite)
    return scan.cloud, scan.dropped


def read(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop",
         layout: PointLayout | str | None = None) -> Scene:
    scan = read_scan(path, layout=layout, nonfinite=nonfinite)
    meta: dict[str, object] = {"source": str(path), "format": "bin", **scan.metadata()}
    return Scene(scan.cloud, frame_id=frame_id_of(path), metadata=meta)


#: Records per write of :func:`_write_first4`: 256 KiB, small enough that the gathered chunk is
#: still in the CPU's cache when the kernel copies it into the page cache.
_WRITE_CHUNK_RECORDS = 16384


def _write_first4(path: Path, data: NDArray[np.float32]) -> None:
    """Write the first four float32 columns of ``data`` as little-endian KITTI records.

    A cloud usually carries more channels than a KITTI record holds (ring, time, labels), so its
    first four columns are strided. Gathering them as one 16-byte item per row (a ``V16`` view)
    instead of four floats, and writing in cache-sized chunks instead of one 2 MB copy, halves
    the cost of a 120k-point frame (0.9 -> 0.5 ms); the bytes are the same.
    """
    if data.dtype != np.dtype("<f4") or data.ndim != 2 or data.shape[1] < 4 or data.strides[1] != 4:
        np.ascontiguousarray(data[:, :4], dtype="<f4").tofile(path)
        return
    records = data[:, :4].view("V16")[:, 0]
    with open(path, "wb") as handle:
        for start in range(0, len(records), _WRITE_CHUNK_RECORDS):
            handle.write(np.ascontiguousarray(records[start:start + _WRITE_CHUNK_RECORDS]).data)


def write_points(path: str | PathLike[str], cloud: PointCloud, *, overwrite: bool = False,
                 durable: bool = True, layout: PointLayout | str | None = None) -> Path:
    """Write the cloud's records in ``layout`` (default KITTI's ``x, y, z, intensity``; other
    channels cannot be stored in a KITTI .bin). A layout column the cloud lacks is written with
    the channel's default (ring −1, time 0, …) or zero; SemanticKITTI also writes
    ``../labels/<id>.label`` when the cloud has labels."""
    chosen = resolve_layout(path, layout)[0]
    if chosen.container != "bin":
        raise ValueError(f"layout {chosen.name} writes .{chosen.container} files, not .bin")
    with atomic_path(path, overwrite=overwrite, durable=durable) as tmp:
        if chosen.float32_only and len(chosen.columns) == 4:
            _write_first4(tmp, cloud.data)
        else:
            records = np.zeros(len(cloud), dtype=chosen.record_dtype)
            for column in chosen.columns:
                if column.skipped:
                    continue
                values = (cloud.channel(column.channel) if cloud.has(column.channel)
                          else np.full(len(cloud), CHANNEL_DEFAULTS.get(column.channel, 0.0)))
                records[column.channel] = values
            records.tofile(tmp)
    if chosen.point_labels:
        semantickitti.write_labels(semantickitti.label_path(Path(path)), cloud, overwrite=overwrite, durable=durable)
    return Path(path)


def write(path: str | PathLike[str], scene: Scene, *, overwrite: bool = False,
          layout: PointLayout | str | None = None) -> Path:
    return write_points(path, scene.points, overwrite=overwrite, layout=layout)
