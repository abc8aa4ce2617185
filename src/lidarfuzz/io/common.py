"""What every reader shares: channel-name mapping, the non-finite policy, problem records.

Non-finite coordinates policy (documented in the README): by default a reader
**drops** points whose x, y or z is NaN or ±Inf and emits one
:class:`NonFiniteWarning` that names the file and counts them (the count is also
stored in ``scene.metadata["dropped_nonfinite"]``); with ``nonfinite="reject"`` it
raises :class:`~lidarfuzz.errors.DataFormatError` instead. Non-finite values in
other channels are always rejected: they cannot be repaired without guessing.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from os import PathLike
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.scene.points import STANDARD_CHANNELS, PointCloud

NonFinitePolicy = Literal["drop", "reject"]

#: Foreign field names mapped onto lidarfuzz channels (first match wins; case-insensitive).
FIELD_ALIASES: dict[str, tuple[str, ...]] = {
    "x": ("x",),
    "y": ("y",),
    "z": ("z",),
    "intensity": ("intensity", "i", "reflectance", "remission", "intensities"),
    "ring": ("ring", "laser_id", "channel", "line", "beam"),
    "time": ("time", "t", "timestamp", "time_offset", "offset_time", "gps_time"),
    "label": ("label", "semantic_label", "class"),
    "instance": ("instance", "instance_id", "object_id"),
}


class NonFiniteWarning(UserWarning):
    """Points with NaN/Inf coordinates were dropped while reading a file."""


@dataclass(frozen=True)
class Problem:
    """Something wrong (``error``) or suspicious (``warning``) found while inspecting data."""

    severity: Literal["error", "warning"]
    path: str
    message: str
    line: int | None = None

    def __str__(self) -> str:
        where = self.path + (f":{self.line}" if self.line is not None else "")
        return f"{self.severity}: {where}: {self.message}"


def map_field_names(names: list[str]) -> dict[str, str]:
    """Map a file's field names to channel names: ``{file_field: channel}``.

    Standard and optional channels are recognised through :data:`FIELD_ALIASES`;
    any other field keeps its own name (made a valid identifier, lower-case).
    """
    lower = {n.lower(): n for n in names}
    mapping: dict[str, str] = {}
    taken: set[str] = set()
    for channel, aliases in FIELD_ALIASES.items():
        for alias in aliases:
            if alias in lower and lower[alias] not in mapping:
                mapping[lower[alias]] = channel
                taken.add(channel)
                break
    for name in names:
        if name in mapping:
            continue
        clean = "".join(ch if (ch.isascii() and ch.isalnum()) or ch == "_" else "_" for ch in name.lower()) or "field"
        if clean[0].isdigit():
            clean = "f_" + clean
        while clean in taken:
            clean += "_"
        mapping[name] = clean
        taken.add(clean)
    return mapping


def cloud_from_columns(
    columns: Mapping[str, NDArray[np.generic]],
    path: str | PathLike[str],
    *,
    nonfinite: NonFinitePolicy = "drop",
) -> tuple[PointCloud, int]:
    """Build a cloud from named columns (already mapped to channel names).

    Returns the cloud and the number of points dropped for non-finite coordinates.
    Intensity defaults to zeros when the file has none.
    """
    for axis in ("x", "y", "z"):
        if axis not in columns:
            raise DataFormatError(path, f"no '{axis}' field; found fields {sorted(columns)}")
    n = int(np.asarray(columns["x"]).shape[0])
    names = list(STANDARD_CHANNELS) + [c for c in columns if c not in STANDARD_CHANNELS]
    data = np.empty((n, len(names)), dtype=np.float32)
    # a value beyond float32 (1e308 in a float64 field) becomes ±inf for the non-finite policy,
    # without numpy's RuntimeWarning on the terminal
    with np.errstate(over="ignore", invalid="ignore"):
        for i, name in enumerate(names):
            if name == "intensity" and name not in columns:
                data[:, i] = 0.0
            else:
                data[:, i] = columns[name]
    return finish_cloud(data, names, path, nonfinite=nonfinite)


def finish_cloud(
    data: NDArray[np.float32],
    channels: list[str] | tuple[str, ...],
    path: str | PathLike[str],
    *,
    nonfinite: NonFinitePolicy = "drop",
) -> tuple[PointCloud, int]:
    """Apply the non-finite policy to an N×C float32 array and wrap it as a cloud."""
    if nonfinite not in ("drop", "reject"):
        raise ValueError(f"nonfinite must be 'drop' or 'reject', got {nonfinite!r}")
    finite = np.isfinite(data)
    if finite.all():
        return PointCloud(data, channels), 0
    coords_ok = finite[:, :3].all(axis=1)
    bad_other = ~finite[:, 3:].all(axis=1) & coords_ok
    if bad_other.any():
        row = int(np.argmax(bad_other))
        col = channels[3 + int(np.argmax(~finite[row, 3:]))]
        raise DataFormatError(
            path, f"{int(bad_other.sum())} point(s) have a NaN/Inf value (first at point {row})", field=col
        )
    dropped = int((~coords_ok).sum())
    if nonfinite == "reject":
        raise DataFormatError(
            path,
            f"{dropped} point(s) have NaN/Inf coordinates (first at point {int(np.argmin(coords_ok))})",
            hint="read with nonfinite='drop' (--drop-nonfinite) to drop them",
        )
    warnings.warn(
        f"{path}: dropped {dropped} point(s) with NaN/Inf coordinates", NonFiniteWarning, stacklevel=3
    )
    return PointCloud(data[coords_ok], channels), dropped
