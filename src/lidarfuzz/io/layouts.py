"""Point layouts: what the columns of a headerless scan file mean, and checks that they fit.

A ``.bin`` scan has no header: the same 8,000 bytes are 500 KITTI points (4 float32 columns)
or 400 nuScenes points (5 columns), and reading one as the other gives garbage that looks like
points. A :class:`PointLayout` says which columns a file holds, their types and the scale of
their intensity; :func:`check_plausible` looks at a strided sample of the rows read with it and
refuses a read whose values cannot be what the layout says (whole numbers or 0–255 readings in
x, y, z; negative intensities; ring numbers that are not small whole numbers) — naming the file
and the layout that does fit.

Named layouts (:data:`LAYOUTS`):

================ ====================================================== ===============
name             columns                                                intensity
================ ====================================================== ===============
``kitti``        x y z intensity (float32)                              0–1
``kitti360``     x y z intensity (float32)                              0–1
``nuscenes``     x y z intensity ring (float32), ``.pcd.bin``           0–255
``semantickitti`` kitti + ``labels/NNNNNN.label`` (uint32 per point:     0–1
                 low 16 bits class, high 16 bits instance)
``argoverse2``   ``.feather``: x y z intensity(uint8) laser_number      0–255
                 offset_ns → x y z intensity ring time
``waymo``        x y z intensity elongation range_index (float32), as    raw (none)
                 mmdetection3d's Waymo → KITTI converter writes them
================ ====================================================== ===============

An explicit layout names the columns and their types: ``x,y,z,intensity,ring:f4`` (one type
for all), or a type per column (``x,y,z:f4,intensity:u1,ring:u1`` — a column without a type
takes the next one given to its right); ``_`` skips a padding column.

Example:
    >>> layout = parse_layout("x,y,z,intensity,ring:f4")
    >>> layout.record_size, layout.channels
    (20, ('x', 'y', 'z', 'intensity', 'ring'))
    >>> parse_layout("nuscenes").intensity_scale
    255.0
"""

from __future__ import annotations

import functools
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from os import PathLike
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.common import FIELD_ALIASES

Container = Literal["bin", "feather"]

#: Types an explicit layout may name (little-endian, as every public data set stores them).
DTYPES: dict[str, str] = {
    "f4": "<f4", "f8": "<f8", "f2": "<f2", "u1": "u1", "u2": "<u2", "u4": "<u4",
    "i1": "i1", "i2": "<i2", "i4": "<i4",
}
#: Below this many sampled rows a file is too small to judge (a few points can be anything).
MIN_ROWS_TO_JUDGE = 32
#: Another layout is suggested only on this many rows of evidence: a few hundred random values can
#: fit a layout by chance, a scan's rows do not.
MIN_ROWS_TO_VOUCH = 200
#: Rows looked at, at most (runs of rows spread over the whole scan; 2,048 rows estimate a share
#: of 10 % to ±1.3 points at 2 sigma).
SAMPLE_ROWS = 2048
SAMPLE_BLOCKS = 4
#: Coordinates beyond this (metres) are taken as not a LiDAR return (long-range sensors reach
#: about 250 m).
MAX_RANGE_M = 300.0


class LayoutError(LidarfuzzError, ValueError):
    """A layout name or explicit spec that does not parse (one line, naming the bad part)."""


@dataclass(frozen=True)
class Column:
    """One column of a record: the channel it fills and its type on disk."""

    channel: str
    dtype: str  # a numpy type string, e.g. "<f4"
    source: str = ""  # the column's own name in a self-describing file (feather); "" for .bin

    @property
    def skipped(self) -> bool:
        return self.channel == "_"


@dataclass(frozen=True)
class PointLayout:
    """What a scan file's columns are (see the module docstring).

    Attributes:
        name: The layout's name (``kitti``, …) or the explicit spec it was parsed from.
        columns: The record's columns in file order.
        container: ``bin`` (headerless records) or ``feather`` (Arrow IPC, columns by name).
        intensity_scale: The intensity reading of the strongest return (1.0 or 255.0); ``None``
            when the layout does not fix one (an explicit spec, Waymo's raw intensity).
        point_labels: Per-point SemanticKITTI labels in a sibling ``labels/`` folder.
    """

    name: str
    columns: tuple[Column, ...]
    container: Container = "bin"
    intensity_scale: float | None = None
    point_labels: bool = False

    @functools.cached_property
    def record_dtype(self) -> np.dtype:
        """The record as a packed structured type (padding columns get unique names)."""
        names = [c.channel if not c.skipped else f"_pad{i}" for i, c in enumerate(self.columns)]
        return np.dtype({"names": names, "formats": [c.dtype for c in self.columns]})

    @functools.cached_property
    def record_size(self) -> int:
        return int(sum(np.dtype(c.dtype).itemsize for c in self.columns))

    @functools.cached_property
    def float32_only(self) -> bool:
        """Every column float32 and the first four x, y, z, intensity: the file is the cloud's array."""
        return (all(np.dtype(c.dtype) == np.dtype("<f4") and not c.skipped for c in self.columns)
                and tuple(c.channel for c in self.columns[:4]) == ("x", "y", "z", "intensity"))

    @functools.cached_property
    def channels(self) -> tuple[str, ...]:
        """The cloud's channels: x, y, z, intensity first, then the other columns in file order."""
        named = [c.channel for c in self.columns if not c.skipped]
        rest = [c for c in named if c not in ("x", "y", "z", "intensity")]
        return ("x", "y", "z", "intensity", *rest)

    def describe(self) -> str:
        """``kitti (4 columns)`` — how messages name a layout."""
        return f"{self.name} ({len(self.columns)} columns)"


def _f4(*names: str) -> tuple[Column, ...]:
    return tuple(Column(name, "<f4") for name in names)


#: The named layouts. Waymo: mmdetection3d's ``tools/dataset_converters/waymo_converter.py``
#: (``Waymo2KITTI.save_lidar``) writes ``np.column_stack((points, intensity, elongation,
#: mask_indices)).astype(np.float32)`` — 6 float32 columns, the last the point's index in the top
#: LiDAR's range image (-1 for the other LiDARs), and its configs read them with ``load_dim=6``.
#: Waymo's intensity is the sensor's raw return strength (mostly below 1, unbounded above;
#: OpenPCDet squashes it with tanh), so no scale is recorded for it.
LAYOUTS: dict[str, PointLayout] = {
    "kitti": PointLayout("kitti", _f4("x", "y", "z", "intensity"), intensity_scale=1.0),
    "kitti360": PointLayout("kitti360", _f4("x", "y", "z", "intensity"), intensity_scale=1.0),
    "nuscenes": PointLayout("nuscenes", _f4("x", "y", "z", "intensity", "ring"), intensity_scale=255.0),
    "semantickitti": PointLayout("semantickitti", _f4("x", "y", "z", "intensity"), intensity_scale=1.0,
                                 point_labels=True),
    "argoverse2": PointLayout(
        "argoverse2",
        (Column("x", "<f4", "x"), Column("y", "<f4", "y"), Column("z", "<f4", "z"),
         Column("intensity", "u1", "intensity"), Column("ring", "u1", "laser_number"),
         Column("time", "<i8", "offset_ns")),
        container="feather", intensity_scale=255.0),
    "waymo": PointLayout("waymo", _f4("x", "y", "z", "intensity", "elongation", "range_index")),
}

#: Layouts tried, in this order, when the chosen one does not fit a .bin: the named ones, then
#: float32 records of 5 to 8 columns whose extra columns lidarfuzz cannot name (x y z intensity
#: and a time column, say), so a file of N float32 columns is never silently read as 4 or 5.
_CANDIDATES: tuple[PointLayout, ...] = (
    LAYOUTS["kitti"], LAYOUTS["nuscenes"], LAYOUTS["waymo"],
    *(PointLayout(",".join(("x", "y", "z", "intensity", *(f"c{i}" for i in range(4, width)))) + ":f4",
                  _f4("x", "y", "z", "intensity", *(f"c{i}" for i in range(4, width))))
      for width in (5, 7, 8)),
)

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _channel_name(name: str) -> str:
    """A column name as a channel (``reflectance`` → ``intensity``, ``laser_id`` → ``ring``)."""
    lower = name.lower()
    for channel, aliases in FIELD_ALIASES.items():
        if lower in aliases:
            return channel
    return lower


def parse_layout(text: str) -> PointLayout:
    """A named layout (:data:`LAYOUTS`) or an explicit spec (``x,y,z,intensity,ring:f4``).

    Raises:
        LayoutError: An unknown name, a bad type, a repeated or missing column — one line.
    """
    given = text.strip()
    if given.lower() in LAYOUTS:
        return LAYOUTS[given.lower()]
    if "," not in given and ":" not in given:
        raise LayoutError(f"--layout {text!r}: not a layout name ({', '.join(LAYOUTS)}) nor a column spec "
                          "such as x,y,z,intensity,ring:f4")
    items = [item.strip() for item in given.split(",")]
    parsed: list[tuple[str, str | None]] = []
    for item in items:
        name, sep, dtype = item.partition(":")
        name, dtype = name.strip(), dtype.strip().lower()
        if not name or not (name == "_" or _NAME.match(name)):
            raise LayoutError(f"--layout {text!r}: column {name or '(empty)'!r} is not a name "
                              "(letters, digits and _; '_' skips a padding column)")
        if sep and dtype not in DTYPES:
            raise LayoutError(f"--layout {text!r}: column {name!r} has unknown type {dtype or '(empty)'!r}; "
                              f"use one of {', '.join(DTYPES)}")
        parsed.append((name, DTYPES[dtype] if sep else None))
    if parsed[-1][1] is None:
        raise LayoutError(f"--layout {text!r}: give the columns' type after the last one, e.g. {given}:f4")
    columns: list[Column] = []
    pending: str | None = None
    for name, declared in reversed(parsed):
        pending = declared or pending
        assert pending is not None
        columns.append(Column(name if name == "_" else _channel_name(name), pending))
    columns.reverse()
    names = [c.channel for c in columns if not c.skipped]
    for axis in ("x", "y", "z"):
        if axis not in names:
            raise LayoutError(f"--layout {text!r}: no {axis!r} column (a scan needs x, y and z)")
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise LayoutError(f"--layout {text!r}: column(s) {', '.join(repeated)} given twice")
    return PointLayout(given, tuple(columns))


# --------------------------------------------------------------------------- choosing one
def is_semantickitti_sequence(folder: str | PathLike[str]) -> bool:
    """``…/sequences/NN`` holding ``velodyne/`` and ``labels/``: a SemanticKITTI sequence."""
    folder = os.fspath(folder)
    return (os.path.basename(os.path.dirname(folder)) == "sequences" and os.path.isdir(os.path.join(folder, "velodyne"))
            and os.path.isdir(os.path.join(folder, "labels")))


def layout_from_structure(path: str | PathLike[str]) -> PointLayout | None:
    """The layout a file's name or a folder's place says unambiguously, or ``None``.

    ``*.pcd.bin`` and files in a nuScenes ``samples/LIDAR_TOP`` or ``sweeps/LIDAR_TOP`` folder →
    nuscenes; ``*.feather`` → argoverse2; a SemanticKITTI ``sequences/NN`` folder (with
    ``labels/``), or a scan in its ``velodyne/`` → semantickitti.
    """
    # string operations, not pathlib: this runs on every scan read
    text = os.fspath(path).rstrip("/") or "/"
    name = os.path.basename(text).lower()
    if name.endswith(".pcd.bin"):
        return LAYOUTS["nuscenes"]
    if name.endswith(".feather"):
        return LAYOUTS["argoverse2"]
    folder = os.path.dirname(text) if name.endswith(".bin") or not os.path.isdir(text) else text
    folder_name, parent = os.path.basename(folder), os.path.dirname(folder)
    if folder_name == "LIDAR_TOP" and os.path.basename(parent) in ("samples", "sweeps"):
        return LAYOUTS["nuscenes"]
    if (folder_name == "velodyne" and is_semantickitti_sequence(parent)) or (
            os.path.basename(parent) == "sequences" and is_semantickitti_sequence(folder)):
        return LAYOUTS["semantickitti"]
    return None


def resolve_layout(path: str | PathLike[str], chosen: str | PointLayout | None, *,
                   user_chosen: bool | None = None) -> tuple[PointLayout, bool]:
    """The layout to read ``path`` with, and whether the user chose it (flag or option).

    A chosen layout wins; else the data set's own structure (:func:`layout_from_structure`);
    else ``kitti``. ``user_chosen`` overrides the second answer for a :class:`PointLayout` a data
    set resolved once for all its scans.
    """
    if isinstance(chosen, PointLayout):
        return chosen, True if user_chosen is None else user_chosen
    if chosen:
        return parse_layout(chosen), True
    return layout_from_structure(path) or LAYOUTS["kitti"], False


# --------------------------------------------------------------------------- plausibility
@dataclass(frozen=True)
class Verdict:
    """What a sample of rows says about a layout.

    Attributes:
        fits: No doubt at all (the columns are where the layout says).
        reasons: Why not, one short phrase each.
        intensity_scale: The scale the intensities show (255.0 for 0–255 readings in a layout
            whose nominal scale is 1), or ``None`` when they agree with the layout.
        strong: Some reason is one no real scan shows (whole-number or out-of-range
            coordinates, ring numbers that are not whole): the layout is wrong, not just the data
            odd. Odd intensities alone (negative, above the scale) are weak: synthetic data has
            them, so alone they refuse a read only when another layout fits.
    """

    fits: bool
    reasons: tuple[str, ...] = ()
    intensity_scale: float | None = None
    strong: bool = False
    judged: bool = True  # enough non-zero coordinates to say anything (a mostly-zero sample fits anything)


def _pct(share: float) -> str:
    return f"{100 * share:.0f}%"


def judge(sample: Mapping[str, NDArray[np.floating]], layout: PointLayout) -> Verdict:
    """Whether sampled columns (channel → values) can be what ``layout`` says.

    Cheap statistics over about 2,000 rows; every threshold leaves room for real scans
    (KITTI has ~0.1 % whole-number coordinates and 8–26 % zero intensities; a misread
    nuScenes sweep has ~37 % whole numbers in x, y, z and ~48 % negative intensities):

    * x, y, z: more than 10 % of the non-zero values whole numbers (ring numbers or 0–255
      intensities of another column), more than 5 % beyond ±300 m, or more than 5 % of
      non-zero magnitudes below 1e-6 m (integers read as floats);
    * intensity: more than 1 % negative (coordinates of another column), or above the
      layout's scale (readings of 0–255 in a 0–1 layout are recorded as scale 255, not refused);
    * ring: more than 1 % not a whole number in 0–255.
    """
    reasons: list[str] = []
    # few, whole-array numpy calls: this runs on every scan read (NaN compares false everywhere,
    # so it only dilutes the shares a little; the reader handles non-finite points itself)
    coords = np.concatenate([sample["x"], sample["y"], sample["z"]])
    zeros = int(np.count_nonzero(coords == 0))
    nonzero = coords.size - zeros
    if nonzero >= MIN_ROWS_TO_JUDGE:
        whole = (int(np.count_nonzero(coords == np.round(coords))) - zeros) / nonzero
        if whole > 0.10:
            reasons.append(f"{_pct(whole)} of the non-zero x, y, z are whole numbers, as ring numbers or "
                           "0–255 intensities of a shifted column are")
        magnitude = np.abs(coords)
        if magnitude.max() > MAX_RANGE_M:  # count only when the extreme says it may matter
            far = int(np.count_nonzero(magnitude > MAX_RANGE_M)) / nonzero
            if far > 0.05:
                reasons.append(f"{_pct(far)} of x, y, z lie beyond ±{MAX_RANGE_M:.0f} m")
        tiny = (int(np.count_nonzero(magnitude < 1e-6)) - zeros) / nonzero
        if tiny > 0.05:
            reasons.append(f"{_pct(tiny)} of x, y, z are below 1e-6 m (integers read as floats)")
    strong = bool(reasons)
    scale: float | None = None
    if "intensity" in sample:
        intensity = sample["intensity"]
        if intensity.size >= MIN_ROWS_TO_JUDGE:
            lowest, highest = float(intensity.min()), float(intensity.max())
            negative = float(np.count_nonzero(intensity < 0)) / intensity.size if lowest < 0 else 0.0
            if negative > 0.01:
                reasons.append(f"{_pct(negative)} of the intensities are negative")
            nominal = layout.intensity_scale
            if nominal is not None and highest > nominal * 1.001:
                above = float(np.count_nonzero(intensity > nominal * 1.001)) / intensity.size
                if above > 0.01:
                    if nominal == 1.0 and highest <= 255.5:
                        scale = 255.0  # a 0–255 sensor's readings in a KITTI-shaped file: not a misread
                    else:
                        reasons.append(f"{_pct(above)} of the intensities exceed the layout's 0–{nominal:g} "
                                       f"(up to {highest:.4g})")
    if "ring" in sample:
        ring = np.asarray(sample["ring"], dtype=np.float32)
        if ring.size >= MIN_ROWS_TO_JUDGE:
            bad = ~np.isfinite(ring) | (ring != np.round(ring)) | (ring < 0) | (ring > 255)
            share = float(np.count_nonzero(bad)) / ring.size
            if share > 0.01:
                reasons.append(f"{_pct(share)} of the ring numbers are not whole numbers in 0–255")
                strong = True
    return Verdict(not reasons, tuple(reasons), scale, strong, nonzero >= MIN_ROWS_TO_JUDGE)


def sample_records(flat: NDArray[np.generic], layout: PointLayout) -> dict[str, NDArray[np.floating]] | None:
    """A sample of ≤ :data:`SAMPLE_ROWS` rows of a raw byte buffer read as ``layout``, as
    channel → values; ``None`` when the buffer does not hold whole records of it.

    The rows are :data:`SAMPLE_BLOCKS` runs of consecutive records spread evenly over the scan
    (every azimuth sector of a spinning sensor's sweep is represented), so a memory-mapped file is
    touched in a few pages, not in every page as single strided rows would.
    """
    raw = np.frombuffer(flat, dtype=np.uint8)  # a plain array: a memmap's Python-level hooks cost more here
    size = layout.record_size
    if raw.size % size:
        return None
    rows = raw.size // size
    records = raw.view("<f4").reshape(rows, len(layout.columns)) if layout.float32_only else raw.view(
        layout.record_dtype)
    if rows > SAMPLE_ROWS:
        run = SAMPLE_ROWS // SAMPLE_BLOCKS
        gap = (rows - run) / (SAMPLE_BLOCKS - 1)
        records = np.concatenate([records[int(i * gap):int(i * gap) + run] for i in range(SAMPLE_BLOCKS)])
    else:
        records = np.array(records)
    if layout.float32_only:
        return {c.channel: records[:, i] for i, c in enumerate(layout.columns) if not c.skipped}
    return {c.channel: records[c.channel] for c in layout.columns if not c.skipped}


def check_plausible(path: str | PathLike[str], raw: NDArray[np.generic], layout: PointLayout, *,
                    chosen: bool) -> Verdict:
    """Refuse a .bin read whose values cannot be what ``layout`` says.

    Args:
        path: The file (named in the error).
        raw: Its bytes (any view: a memory map is sampled, not read whole).
        layout: The layout it is read with.
        chosen: The user named the layout: their word stands (the verdict's reasons are kept as
            doubts) unless another layout fits. A layout chosen by default is refused then, and
            also when a reason is strong (:class:`Verdict`).

    Returns:
        The verdict on ``layout`` (possibly with doubts the user overrode, and the intensity
        scale the values show).

    Raises:
        DataFormatError: The values do not fit ``layout`` and another layout's do (naming the
            file, what looks wrong and the layout to try), or they cannot be a scan of a layout
            lidarfuzz chose by default.
    """
    sample = sample_records(raw, layout)
    if sample is None or len(next(iter(sample.values()))) < MIN_ROWS_TO_JUDGE:
        return Verdict(True)
    verdict = judge(sample, layout)
    if verdict.fits:
        return verdict
    better = None
    for other in _CANDIDATES:
        if other.record_size == layout.record_size and other.channels == layout.channels:
            continue
        other_sample = sample_records(raw, other)
        if other_sample is None or len(other_sample["x"]) < MIN_ROWS_TO_VOUCH:
            continue
        other_verdict = judge(other_sample, other)
        if other_verdict.fits and other_verdict.judged:  # enough evidence to vouch for it
            better = other
            break
    if better is None and (chosen or not verdict.strong):
        return verdict
    what = "; ".join(verdict.reasons)
    if better is not None:
        unnamed = "" if better.name in LAYOUTS else " (name the extra columns: ring, time, …)"
        raise DataFormatError(path, f"read as {layout.describe()}, the values look wrong: {what}",
                              hint=f"they fit {better.describe()}: try --layout {better.name}{unnamed}")
    raise DataFormatError(path, f"does not look like a {layout.describe()} scan: {what}",
                          hint=f"if it is, say so with --layout {layout.name}; else give its columns, "
                               "e.g. --layout x,y,z,intensity,ring:f4")


__all__ = [
    "LAYOUTS", "Column", "LayoutError", "PointLayout", "Verdict", "check_plausible", "judge",
    "layout_from_structure", "parse_layout", "resolve_layout", "sample_records",
]
