"""Image data sets described by a CSV: Udacity's ``interpolated.csv``, the behavioural-cloning
``driving_log.csv`` and any CSV with an image column and a steering column.

Layouts (:func:`read_rows` picks the parser):

``udacity``
    The Udacity self-driving challenge 2 (``udacity-driving-reader`` output): ``interpolated.csv``
    with the header ``index,timestamp,width,height,frame_id,filename,angle,torque,speed,lat,long,alt``,
    one row per image of every camera; ``frame_id`` names the camera (``center_camera``,
    ``left_camera``, ``right_camera``), ``filename`` the image relative to the CSV
    (``center/1479424215880976321.jpg``), ``timestamp`` nanoseconds. ``angle`` is the
    steering-wheel angle in radians, left positive; ``speed`` m/s. The rows of the chosen camera
    make an ordered log (frame id: the file's stem, the timestamp in ns); the ``width``/``height``
    columns are checked against each decoded image.
``driving_log``
    The Udacity simulator's recordings used by the behavioural-cloning projects: ``driving_log.csv``
    with the columns ``center,left,right,steering,throttle,brake,speed`` and, usually, no header
    (a header row naming them is skipped). ``steering`` is the simulator's normalised steering in
    [-1, 1] (±25°), **right** positive — kept as it is, in the data set's units. The simulator
    wrote absolute paths of the recording machine; a path that does not exist is looked up as
    ``IMG/<file name>`` beside the CSV, where the recordings keep their images (the metadata's
    ``source`` says which file was read).
``csv``
    A CSV with a header: an image column (paths relative to the CSV) and a steering column,
    named by option or found among :data:`IMAGE_COLUMNS` and :data:`STEERING_COLUMNS`; an
    optional ``timestamp`` column (seconds) and ``speed`` column; other columns are kept as text
    in the metadata.

Every row is checked when the data set is opened: a missing column, an image that does not
exist, an angle that is not a finite number, the same image twice — one-line errors naming the
CSV, its line and the column. Nothing is skipped silently: with ``strict=False`` (``lidarfuzz
info``) a bad row is left out and listed as a problem. Images may differ in size within a data set
(steering networks resize their input); each sample's metadata has its ``size`` and
:meth:`TableImages.image_sizes` counts them from the image headers.
"""

from __future__ import annotations

import csv
import math
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.common import Problem
from lidarfuzz.io.dataset import Dataset, Log
from lidarfuzz.io.images.decode import decode_image, image_header
from lidarfuzz.scene.image import ImageSample

TableLayout = Literal["udacity", "driving_log", "csv"]
#: The cameras of the Udacity layouts, and the ``driving_log.csv`` column of each.
CAMERAS: dict[str, int] = {"center": 0, "left": 1, "right": 2}
UDACITY_FILE = "interpolated.csv"
DRIVING_LOG_FILE = "driving_log.csv"
UDACITY_COLUMNS = ("timestamp", "frame_id", "filename", "angle")
DRIVING_LOG_COLUMNS = ("center", "left", "right", "steering", "throttle", "brake", "speed")
#: Column names taken as the image column of a plain CSV (case-insensitive), in this order.
IMAGE_COLUMNS = ("image", "image_path", "filename", "file", "path", "frame", "center")
#: Column names taken as the steering column of a plain CSV (case-insensitive), in this order.
STEERING_COLUMNS = ("steering", "steering_angle", "angle", "steer")


@dataclass(frozen=True)
class Row:
    """One image a CSV names, with its label."""

    line: int  # 1-based line of the CSV
    image: Path
    named: str  # the path as written in the CSV
    column: str  # the column that named it
    steering: float
    timestamp: float | None = None
    size: tuple[int, int] | None = None  # (height, width) the CSV claims
    extra: dict[str, Any] = field(default_factory=dict)


class _Collector:
    """Problems of one CSV; ``strict`` raises the first when asked."""

    def __init__(self, source: Path) -> None:
        self.source = source
        self.problems: list[Problem] = []
        self.errors: list[DataFormatError] = []

    def error(self, exc: DataFormatError) -> None:
        self.errors.append(exc)
        self.problems.append(Problem("error", str(exc.path), _message(exc), exc.line))


def _message(exc: DataFormatError) -> str:
    text = f"field '{exc.field}': {exc.message}" if exc.field else exc.message
    return text + (f" ({exc.hint})" if exc.hint else "")


def number(text: str, source: Path, line: int, column: str) -> float:
    """A finite number from a CSV cell, or a DataFormatError naming the file, line and column."""
    value = text.strip()
    shown = repr(value) if len(value) <= 40 else f"{value[:20]!r}… ({len(value):,} characters)"
    try:
        parsed = float(value)
    except ValueError:
        raise DataFormatError(source, f"{shown} is not a number" if value else "empty, expected a number",
                              line=line, field=column) from None
    if not math.isfinite(parsed):
        raise DataFormatError(source, f"{shown} is not a finite number", line=line, field=column)
    return parsed


def _records(source: Path) -> list[tuple[int, list[str]]]:
    """(line, cells) of every non-empty record of a CSV."""
    try:
        with open(source, newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            out = []
            start = 1
            for cells in reader:
                if any(cell.strip() for cell in cells):
                    out.append((start, cells))
                start = reader.line_num + 1
            return out
    except UnicodeDecodeError as exc:
        raise DataFormatError(source, f"not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    except csv.Error as exc:
        raise DataFormatError(source, f"not a valid CSV: {exc}") from None
    except OSError as exc:
        raise DataFormatError(source, f"cannot read: {exc.strerror or exc}") from None


def _columns(source: Path, header: list[str], wanted: Sequence[str]) -> dict[str, int]:
    names = [cell.strip().lower() for cell in header]
    found: dict[str, int] = {}
    for column in wanted:
        if column not in names:
            raise DataFormatError(source, f"no column {column!r}; the header has {', '.join(names) or 'nothing'}",
                                  line=1, field=column)
        found[column] = names.index(column)
    return found


def _cell(cells: list[str], index: int, source: Path, line: int, column: str) -> str:
    if index >= len(cells):
        raise DataFormatError(source, f"the row has {len(cells)} cell(s), no value for this column",
                              line=line, field=column)
    return cells[index]


def _image_path(named: str, base: Path, *, fallback_img: bool = False) -> Path | None:
    """The image a CSV names (relative to the CSV's folder), or None when it does not exist."""
    text = named.strip().replace("\\", "/")
    candidate = Path(text) if os.path.isabs(text) else base / text
    if _is_file(candidate):
        return candidate
    if fallback_img:
        moved = base / "IMG" / text.rsplit("/", 1)[-1]
        if _is_file(moved):
            return moved
    return None


def _is_file(path: Path) -> bool:
    """Whether a file exists there; a name the system cannot look up (too long) names none."""
    try:
        return path.is_file()
    except OSError:
        return False


def _missing(source: Path, line: int, column: str, named: str) -> DataFormatError:
    return DataFormatError(source, f"image {named.strip()!r} does not exist", line=line, field=column,
                           hint="image paths are relative to the CSV's folder")


def _udacity(source: Path, records: list[tuple[int, list[str]]], camera: str, out: _Collector) -> list[Row]:
    if not records:
        raise DataFormatError(source, "empty: expected a header and one row per image")
    header = records[0][1]
    columns = _columns(source, header, UDACITY_COLUMNS)
    names = [cell.strip().lower() for cell in header]
    optional = {name: names.index(name) for name in ("width", "height", "speed", "torque", "lat", "long", "alt")
                if name in names}
    wanted = {camera, f"{camera}_camera"}
    rows: list[Row] = []
    cameras: Counter[str] = Counter()
    for line, cells in records[1:]:
        try:
            frame = _cell(cells, columns["frame_id"], source, line, "frame_id").strip()
            cameras[frame] += 1
            if frame not in wanted:
                continue
            named = _cell(cells, columns["filename"], source, line, "filename")
            steering = number(_cell(cells, columns["angle"], source, line, "angle"), source, line, "angle")
            stamp_text = _cell(cells, columns["timestamp"], source, line, "timestamp").strip()
            # integer nanoseconds exactly (a float loses the last digits); a 20-digit integer is ~3,000 years
            exact = stamp_text.isascii() and stamp_text.isdigit() and len(stamp_text) <= 20
            stamp = int(stamp_text) / 1e9 if exact else number(stamp_text, source, line, "timestamp") / 1e9
            extra: dict[str, Any] = {name: number(_cell(cells, i, source, line, name), source, line, name)
                     for name, i in optional.items() if name not in ("width", "height")}
            size = None
            if "width" in optional and "height" in optional:
                size = (int(number(_cell(cells, optional["height"], source, line, "height"), source, line, "height")),
                        int(number(_cell(cells, optional["width"], source, line, "width"), source, line, "width")))
            image = _image_path(named, source.parent)
            if image is None:
                raise _missing(source, line, "filename", named)
            rows.append(Row(line, image, named.strip(), "filename", steering, stamp, size,
                            {"camera": camera, **extra}))
        except DataFormatError as exc:
            out.error(exc)
    if not rows and not out.errors:
        found = ", ".join(f"{name} ({count})" for name, count in sorted(cameras.items())) or "none"
        raise DataFormatError(source, f"no rows for camera {camera!r} (frame_id {camera}_camera); cameras: {found}",
                              field="frame_id", hint="choose one with camera=... (--view)")
    return rows


def _driving_log(source: Path, records: list[tuple[int, list[str]]], camera: str, out: _Collector) -> list[Row]:
    if records and records[0][1][3:4] and records[0][1][3].strip().lower() == "steering":
        records = records[1:]  # the header the Udacity sample data adds
    if not records:
        raise DataFormatError(source, "empty: expected rows center,left,right,steering,throttle,brake,speed")
    index = CAMERAS[camera]
    rows: list[Row] = []
    for line, cells in records:
        try:
            if len(cells) < 4:
                raise DataFormatError(source, f"expected 7 cells ({','.join(DRIVING_LOG_COLUMNS)}), found "
                                      f"{len(cells)}", line=line)
            named = cells[index]
            if not named.strip():
                raise DataFormatError(source, f"no image for the {camera} camera", line=line, field=camera)
            steering = number(cells[3], source, line, "steering")
            extra: dict[str, Any] = {"camera": camera}
            for column, cell in zip(DRIVING_LOG_COLUMNS[4:], cells[4:7], strict=False):
                extra[column] = number(cell, source, line, column)
            image = _image_path(named, source.parent, fallback_img=True)
            if image is None:
                raise _missing(source, line, camera, named)
            rows.append(Row(line, image, named.strip(), camera, steering, extra=extra))
        except DataFormatError as exc:
            out.error(exc)
    return rows


def _pick(names: list[str], given: str | None, aliases: Sequence[str], what: str, option: str,
          source: Path) -> int:
    if given is not None:
        if given.strip().lower() not in names:
            raise DataFormatError(source, f"no column {given!r}; the header has {', '.join(names)}",
                                  line=1, field=given)
        return names.index(given.strip().lower())
    for alias in aliases:
        if alias in names:
            return names.index(alias)
    raise DataFormatError(source, f"no {what} column (looked for {', '.join(aliases)}); the header has "
                          f"{', '.join(names)}", line=1, field=what, hint=f"name it with {option}=...")


def _plain(source: Path, records: list[tuple[int, list[str]]], image_column: str | None,
           steering_column: str | None, out: _Collector) -> list[Row]:
    if not records:
        raise DataFormatError(source, "empty: expected a header naming an image and a steering column")
    names = [cell.strip().lower() for cell in records[0][1]]
    image_at = _pick(names, image_column, IMAGE_COLUMNS, "image", "image_column", source)
    steering_at = _pick(names, steering_column, STEERING_COLUMNS, "steering", "steering_column", source)
    image_name, steering_name = names[image_at], names[steering_at]
    stamp_at = names.index("timestamp") if "timestamp" in names else None
    speed_at = names.index("speed") if "speed" in names else None
    rest = [(i, name) for i, name in enumerate(names) if i not in (image_at, steering_at, stamp_at, speed_at)]
    rows: list[Row] = []
    for line, cells in records[1:]:
        try:
            named = _cell(cells, image_at, source, line, image_name)
            steering = number(_cell(cells, steering_at, source, line, steering_name), source, line, steering_name)
            stamp = None
            if stamp_at is not None:
                stamp = number(_cell(cells, stamp_at, source, line, "timestamp"), source, line, "timestamp")
            extra: dict[str, Any] = {name: cells[i].strip() for i, name in rest if i < len(cells)}
            if speed_at is not None:
                extra["speed"] = number(_cell(cells, speed_at, source, line, "speed"), source, line, "speed")
            if not named.strip():
                raise DataFormatError(source, "no image named", line=line, field=image_name)
            image = _image_path(named, source.parent)
            if image is None:
                raise _missing(source, line, image_name, named)
            rows.append(Row(line, image, named.strip(), image_name, steering, stamp, extra=extra))
        except DataFormatError as exc:
            out.error(exc)
    return rows


def sniff_layout(source: Path) -> TableLayout:
    """The layout of a CSV: by its name, else by its first record."""
    if source.name == UDACITY_FILE:
        return "udacity"
    if source.name == DRIVING_LOG_FILE:
        return "driving_log"
    first = [cell.strip().lower() for cell in _first_record(source)]
    if all(column in first for column in UDACITY_COLUMNS):
        return "udacity"
    if first[:4] == list(DRIVING_LOG_COLUMNS[:4]):
        return "driving_log"
    if len(first) == 7 and all(_is_number(cell) for cell in first[3:]):
        return "driving_log"
    return "csv"


def _first_record(source: Path) -> list[str]:
    """The first non-empty record of a CSV (the rest is not read: this runs on every folder opened)."""
    try:
        with open(source, newline="", encoding="utf-8-sig") as handle:
            return next((cells for cells in csv.reader(handle) if any(cell.strip() for cell in cells)), [])
    except (OSError, UnicodeDecodeError, csv.Error):
        return []  # opening it as a data set names what is wrong


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_rows(source: Path, layout: TableLayout, *, camera: str | None = None, image_column: str | None = None,
              steering_column: str | None = None) -> tuple[list[Row], list[DataFormatError], list[Problem]]:
    """The rows of a CSV in ``layout``, with the errors of its bad rows (left out of the rows).

    Raises:
        DataFormatError: The CSV cannot be read at all (a missing column, no rows for the camera).
        LidarfuzzError: An option that does not apply to the layout.
    """
    if camera is not None and layout == "csv":
        raise LidarfuzzError(f"{source}: camera={camera!r} applies to the udacity and driving_log layouts; "
                             "a plain CSV names its images in one column (image_column=...)")
    if (image_column or steering_column) and layout != "csv":
        raise LidarfuzzError(f"{source}: image_column/steering_column apply to a plain CSV, not the {layout} layout")
    chosen = camera or "center"
    if chosen not in CAMERAS:
        raise LidarfuzzError(f"{source}: camera {chosen!r} is not one of {', '.join(CAMERAS)}")
    records = _records(source)
    out = _Collector(source)
    if layout == "udacity":
        rows = _udacity(source, records, chosen, out)
    elif layout == "driving_log":
        rows = _driving_log(source, records, chosen, out)
    else:
        rows = _plain(source, records, image_column, steering_column, out)
    seen: dict[Path, int] = {}
    unique: list[Row] = []
    for row in rows:
        key = row.image.resolve()
        if key in seen:
            out.error(DataFormatError(source, f"image {row.named!r} is listed twice (first on line {seen[key]})",
                                      line=row.line, field=row.column))
            continue
        seen[key] = row.line
        unique.append(row)
    return unique, out.errors, out.problems


class TableImages(Dataset[ImageSample]):
    """The images a CSV names, with their steering labels (see the module docstring).

    Args:
        source: The CSV file.
        layout: ``udacity``, ``driving_log`` or ``csv``; by default from the file (:func:`sniff_layout`).
        camera: ``center`` (default), ``left`` or ``right`` for the Udacity layouts.
        image_column: The image column of a plain CSV (default: found by name).
        steering_column: The steering column of a plain CSV (default: found by name).
        strict: Raise on the first bad row; when False bad rows are left out and listed in :meth:`problems`.
    """

    def __init__(self, source: str | os.PathLike[str], *, layout: TableLayout | None = None,
                 camera: str | None = None, image_column: str | None = None, steering_column: str | None = None,
                 strict: bool = True) -> None:
        source = Path(source)
        super().__init__(source, name=source.parent.resolve().name)
        self.source = source
        self.layout: TableLayout = layout or sniff_layout(source)
        rows, errors, problems = read_rows(source, self.layout, camera=camera, image_column=image_column,
                                           steering_column=steering_column)
        self._problems.extend(problems)
        if strict and errors:
            first = errors[0]
            more = f" (and {len(errors) - 1} more problem(s); run 'lidarfuzz info' to list them)" if errors[1:] else ""
            raise DataFormatError(first.path, first.message + more, line=first.line, field=first.field,
                                  hint=first.hint)
        stems = [row.image.stem for row in rows]
        if len(set(stems)) == len(stems):
            ids = stems
        else:  # the same file name in two folders: the path relative to the CSV tells them apart
            ids = [os.path.splitext(os.path.relpath(row.image, source.parent))[0].replace(os.sep, "/") for row in rows]
        self._rows = dict(zip(ids, rows, strict=True))
        self._ids = tuple(ids)
        self._sizes: Counter[tuple[int, int]] | None = None

    @property
    def format(self) -> str:
        return self.layout

    def frame_ids(self) -> Sequence[str]:
        return self._ids

    def _id_set(self) -> set[str]:
        return set(self._rows)

    def row(self, frame_id: str) -> Row:
        """The CSV row of a frame."""
        if frame_id not in self._rows:
            raise KeyError(f"{self.source}: no frame with id {frame_id!r}")
        return self._rows[frame_id]

    def image_sizes(self) -> Counter[tuple[int, int]]:
        """How many images have each (height, width), from their headers (read once, then kept)."""
        if self._sizes is None:
            sizes: Counter[tuple[int, int]] = Counter()
            for row in self._rows.values():
                _, height, width = image_header(self._read(row), row.image)
                sizes[height, width] += 1
            self._sizes = sizes
        return Counter(self._sizes)

    def _read(self, row: Row) -> bytes:
        try:
            return row.image.read_bytes()
        except OSError as exc:
            raise DataFormatError(self.source, f"image {row.named!r} cannot be read: {exc.strerror or exc}",
                                  line=row.line, field=row.column) from None

    def load(self, frame_id: str) -> ImageSample:
        row = self.row(frame_id)
        data = self._read(row)
        try:
            image = decode_image(data, row.image)
        except DataFormatError as exc:
            raise DataFormatError(exc.path, f"{exc.message} (named on line {row.line} of {self.source.name})",
                                  hint=exc.hint) from None
        if row.size is not None and image.shape[:2] != row.size:
            raise DataFormatError(self.source, f"the image is {image.shape[1]}×{image.shape[0]} but the row says "
                                  f"{row.size[1]}×{row.size[0]}", line=row.line, field="width")
        metadata = {"source": str(row.image), "format": self.layout, "csv": str(self.source), "row": row.line,
                    "size": [int(image.shape[0]), int(image.shape[1])], **row.extra}
        return ImageSample(image, frame_id=frame_id, steering=row.steering, timestamp=row.timestamp,
                           metadata=metadata)


class TableImageLog(TableImages, Log[ImageSample]):
    """A CSV whose every row has a timestamp (Udacity's ``interpolated.csv``): frames in time order."""

    def __init__(self, source: str | os.PathLike[str], **kwargs: Any) -> None:
        super().__init__(source, **kwargs)
        missing = [row.line for row in self._rows.values() if row.timestamp is None]
        if missing:
            raise DataFormatError(self.source, "a log needs a timestamp on every row", line=missing[0],
                                  field="timestamp")
        order = sorted(self._ids, key=lambda i: (self._rows[i].timestamp, self._rows[i].line))
        if list(order) != list(self._ids):
            self._problems.append(Problem("warning", str(self.source), "rows are not in time order; frames are "
                                          "ordered by timestamp"))
        self._ids = tuple(order)

    def timestamps(self) -> NDArray[np.float64]:
        return np.array([self._rows[i].timestamp for i in self._ids], dtype=np.float64)


def open_table(source: str | os.PathLike[str], **kwargs: Any) -> TableImages:
    """A :class:`TableImageLog` for the Udacity layout (timestamps on every row), else :class:`TableImages`."""
    layout = kwargs.get("layout") or sniff_layout(Path(source))
    kwargs["layout"] = layout
    if layout == "udacity":
        return TableImageLog(source, **kwargs)
    return TableImages(source, **kwargs)
