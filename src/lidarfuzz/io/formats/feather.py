"""Argoverse 2 LiDAR sweeps: ``sensors/lidar/<timestamp_ns>.feather`` (Apache Arrow IPC).

Columns ``x, y, z`` (metres, ego-vehicle frame), ``intensity`` (uint8, 0–255),
``laser_number`` (the beam: the two stacked 32-beam sensors give 0–63) and ``offset_ns`` (the
point's firing time after the sweep's timestamp, in nanoseconds) become the channels ``x, y, z,
intensity, ring, time`` (time in seconds); any other column is kept under its own name. The
file name is the sweep's timestamp in nanoseconds, read as the scene's timestamp (seconds).

Needs ``pyarrow``: ``pip install 'lidarfuzz[argoverse]'``. The file names its columns, so
nothing is guessed and no plausibility check is needed.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from lidarfuzz.errors import DataFormatError, MissingDependencyError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.io.common import NonFinitePolicy, cloud_from_columns, map_field_names
from lidarfuzz.io.guards import reading
from lidarfuzz.io.layouts import LAYOUTS, PointLayout, resolve_layout
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

SUFFIXES = (".feather",)
NANOSECONDS = 1e-9


def _feather() -> Any:
    try:
        import pyarrow.feather as feather
    except ImportError:
        raise MissingDependencyError("pyarrow", "argoverse", "reading Argoverse 2 .feather sweeps") from None
    return feather


def _layout(path: Path, layout: PointLayout | str | None) -> PointLayout:
    chosen = resolve_layout(path, layout)[0] if layout is not None else LAYOUTS["argoverse2"]
    if chosen.container != "feather":
        raise DataFormatError(path, f"layout {chosen.name} reads .{chosen.container} files, not .feather",
                              hint="--layout argoverse2")
    return chosen


def read_points(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop",
                layout: PointLayout | str | None = None) -> tuple[PointCloud, int]:
    """Read the cloud; returns it and the number of points dropped for NaN/Inf coordinates."""
    path = Path(path)
    chosen = _layout(path, layout)
    feather = _feather()
    try:
        table = feather.read_table(path, memory_map=True)
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except Exception as exc:  # pyarrow raises its own ArrowInvalid / OSError kinds
        raise DataFormatError(path, f"not a readable .feather file: {exc}") from None
    with reading(path, "read the .feather file"):  # pyarrow's errors on odd column types
        names = list(table.column_names)
        columns: dict[str, Any] = {}
        for column in chosen.columns:
            if column.source not in names:
                raise DataFormatError(path, f"no column {column.source!r}; found {', '.join(names)}",
                                      field=column.source)
            values = table.column(column.source).to_numpy()
            columns[column.channel] = values * NANOSECONDS if column.source.endswith("_ns") else values
        known = {c.source for c in chosen.columns}
        others = [n for n in names if n not in known]
        for name, channel in map_field_names(others).items():
            if channel in columns:
                channel = f"{channel}_"
            try:
                columns[channel] = table.column(name).to_numpy().astype(np.float32)
            except (TypeError, ValueError):
                continue  # a non-numeric column (strings) is not a point channel
        return cloud_from_columns(columns, path, nonfinite=nonfinite)


def read(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop",
         layout: PointLayout | str | None = None) -> Scene:
    path = Path(path)
    cloud, dropped = read_points(path, nonfinite=nonfinite, layout=layout)
    meta: dict[str, object] = {"source": str(path), "format": "feather", "layout": "argoverse2",
                               "intensity_scale": LAYOUTS["argoverse2"].intensity_scale}
    if dropped:
        meta["dropped_nonfinite"] = dropped
    timestamp = int(path.stem) * NANOSECONDS if path.stem.isdigit() else None
    return Scene(cloud, frame_id=path.stem, timestamp=timestamp, metadata=meta)


def write(path: str | PathLike[str], scene: Scene, *, overwrite: bool = False) -> Path:
    """Write an Argoverse 2 sweep: x, y, z as float32, intensity and laser_number as uint8 when
    they are whole numbers in 0–255 (else float32), offset_ns as int64 (time rounded to the
    nanosecond); other channels as float32 columns of their own name."""
    import pyarrow as pa

    _feather()
    cloud = scene.points
    arrays: dict[str, Any] = {axis: cloud.channel(axis) for axis in ("x", "y", "z")}
    for channel, name in (("intensity", "intensity"), ("ring", "laser_number")):
        values = cloud.channel(channel) if cloud.has(channel) else np.zeros(len(cloud), np.float32)
        whole = bool(np.all((values == np.round(values)) & (values >= 0) & (values <= 255)))
        arrays[name] = values.astype(np.uint8) if whole else values
    time = cloud.channel("time") if cloud.has("time") else np.zeros(len(cloud), np.float32)
    arrays["offset_ns"] = np.round(time.astype(np.float64) / NANOSECONDS).astype(np.int64)
    for channel in cloud.channels:
        if channel not in ("x", "y", "z", "intensity", "ring", "time"):
            arrays[channel] = cloud.channel(channel)
    table = pa.table({name: pa.array(np.ascontiguousarray(values)) for name, values in arrays.items()})
    with atomic_path(path, overwrite=overwrite) as tmp:
        _feather().write_feather(table, tmp, compression="uncompressed")
    return Path(path)
