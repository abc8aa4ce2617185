"""``sensor_msgs/PointCloud2`` point data ⇄ :class:`~lidarfuzz.scene.points.PointCloud`, in pure numpy.

The codec knows nothing of ROS serialisation: it takes the already deserialised
message fields (``fields``, ``point_step``, ``row_step``, ``height``, ``width``,
``is_bigendian``, ``data``) and views ``data`` as a structured numpy array, so a
120k-point frame is decoded without a Python loop over points.

Decoding supports:

* every ``PointField`` datatype (``INT8`` … ``FLOAT64``), at any offset, in either
  byte order;
* ``count > 1`` (a field ``f`` with count 3 becomes channels ``f_0, f_1, f_2``);
* padding inside a point (``point_step`` larger than the fields) and at the end of
  each row (``row_step`` larger than ``width × point_step``), including organised
  clouds (``height > 1``), which are flattened row by row;
* foreign field names, mapped with :func:`~lidarfuzz.io.common.map_field_names`
  (``reflectance`` → ``intensity``, ``laser_id`` → ``ring``, ``timestamp`` → ``time`` …);
  fields named ``""`` or only underscores are padding and are skipped;
* per-point times stored as *absolute* float64 stamps (Apollo, Hesai and Livox
  drivers write seconds or nanoseconds since the epoch): when ``time_reference``
  (the header stamp) is given and the values' median lies within a day of it (and
  much closer to it than to zero), they are made relative to it, because the
  ``time`` channel holds seconds since the frame timestamp and float32 cannot hold
  an epoch time to better than two minutes. Other time fields are kept as they are.

Non-finite coordinates follow the shared policy of
:func:`~lidarfuzz.io.common.cloud_from_columns`. Encoding writes every channel as
little-endian ``FLOAT32`` in a single row, which round-trips a cloud bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from os import PathLike
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFinitePolicy, cloud_from_columns, map_field_names
from lidarfuzz.scene.points import PointCloud

INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)

#: ``PointField.datatype`` → numpy type code (byte order added when decoding).
DATATYPES: dict[int, str] = {
    INT8: "i1",
    UINT8: "u1",
    INT16: "i2",
    UINT16: "u2",
    INT32: "i4",
    UINT32: "u4",
    FLOAT32: "f4",
    FLOAT64: "f8",
}

#: ``PointField.datatype`` → its ROS constant name (for messages and ``lidarfuzz info``).
DATATYPE_NAMES: dict[int, str] = {
    INT8: "INT8",
    UINT8: "UINT8",
    INT16: "INT16",
    UINT16: "UINT16",
    INT32: "INT32",
    UINT32: "UINT32",
    FLOAT32: "FLOAT32",
    FLOAT64: "FLOAT64",
}

# A per-point time further than this from the frame stamp cannot be a sweep offset.
_ABSOLUTE_TIME_WINDOW_S = 86_400.0


@dataclass(frozen=True, slots=True)
class PointField:
    """One ``sensor_msgs/PointField``: where a named value sits inside a point."""

    name: str
    offset: int
    datatype: int
    count: int = 1


def field_of(field: Any) -> PointField:
    """Read a point field from a ROS message object, a mapping or a tuple."""
    if isinstance(field, PointField):
        return field
    if isinstance(field, Mapping):
        return PointField(str(field["name"]), int(field["offset"]), int(field["datatype"]), int(field["count"]))
    if isinstance(field, tuple):
        return PointField(*field)
    return PointField(str(field.name), int(field.offset), int(field.datatype), int(field.count))


def _where(context: str) -> str:
    return f"{context}: " if context else ""


#: The largest point a PointCloud2 message may declare (bytes): far above any driver's.
MAX_POINT_STEP = 1 << 16


def _layout(
    fields: Sequence[PointField], point_step: int, is_bigendian: bool, path: str | PathLike[str], context: str
) -> tuple[np.dtype[Any], list[tuple[str, PointField]]]:
    """The structured dtype of one point and the (dtype field name, point field) pairs used."""
    order = ">" if is_bigendian else "<"
    if point_step > MAX_POINT_STEP:  # numpy's dtypes hold at most 2^31 - 1 bytes; real points a few dozen
        raise DataFormatError(path, f"{_where(context)}point_step {point_step:,} bytes per point is more than "
                              f"the {MAX_POINT_STEP:,} lidarfuzz reads", field="point_step")
    names: list[str] = []
    formats: list[Any] = []
    offsets: list[int] = []
    used: list[tuple[str, PointField]] = []
    seen: set[str] = set()
    for field in fields:
        if field.name.strip("_") == "":
            continue  # PCL and some drivers list padding as fields named "_"
        if field.datatype not in DATATYPES:
            raise DataFormatError(
                path,
                f"{_where(context)}field {field.name!r}: unknown PointField datatype {field.datatype} "
                f"(expected 1..8: {', '.join(f'{k}={v}' for k, v in DATATYPE_NAMES.items())})",
            )
        if field.name in seen:
            raise DataFormatError(path, f"{_where(context)}field {field.name!r} is listed twice")
        seen.add(field.name)
        if field.count == 0:
            continue
        code = np.dtype(order + DATATYPES[field.datatype])
        end = field.offset + code.itemsize * field.count
        if field.offset < 0 or end > point_step:
            raise DataFormatError(
                path,
                f"{_where(context)}field {field.name!r}: {DATATYPE_NAMES[field.datatype]}×{field.count} "
                f"at offset {field.offset} runs past point_step {point_step} (ends at byte {end})",
                hint="the message's fields and point_step disagree",
            )
        key = f"f{len(names)}"
        names.append(key)
        formats.append(code if field.count == 1 else (code, (field.count,)))
        offsets.append(field.offset)
        used.append((key, field))
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})
    return dtype, used


def _relative_time(values: NDArray[Any], reference: float) -> NDArray[Any]:
    """Make absolute float64 per-point stamps (s or ns since the epoch) relative to ``reference``."""
    finite = values[np.isfinite(values)]
    if reference <= 0 or finite.size == 0:
        return values
    middle = float(np.median(finite))

    def near_reference(seconds: float) -> bool:
        # Much closer to the stamp than to zero: sweep offsets of a sim-time log (stamp 5 s,
        # offsets 0..0.1 s) are not mistaken for absolute times.
        return abs(seconds - reference) < min(_ABSOLUTE_TIME_WINDOW_S, 0.5 * abs(seconds))

    if near_reference(middle):
        return values - reference
    if near_reference(middle * 1e-9):
        return (values - reference * 1e9) * 1e-9
    return values


def decode(
    fields: Sequence[Any],
    point_step: int,
    row_step: int,
    height: int,
    width: int,
    is_bigendian: bool,
    data: bytes | bytearray | memoryview | NDArray[np.uint8],
    *,
    path: str | PathLike[str],
    nonfinite: NonFinitePolicy = "drop",
    context: str = "",
    time_reference: float | None = None,
) -> tuple[PointCloud, int]:
    """Decode PointCloud2 point data into a cloud.

    Args:
        fields: The message's ``PointField`` entries (message objects, :class:`PointField`,
            mappings or tuples).
        point_step: Bytes per point.
        row_step: Bytes per row (at least ``width × point_step``).
        height: Rows (1 for an unorganised cloud).
        width: Points per row.
        is_bigendian: Byte order of every field.
        data: The point bytes (``height × row_step`` of them, or more).
        path: The file the message came from, for error messages.
        nonfinite: ``"drop"`` or ``"reject"`` points with NaN/Inf coordinates.
        context: Where in the file the message is (e.g. ``"topic /points, message 3"``),
            prefixed to error messages.
        time_reference: The message's header stamp in seconds; absolute float64
            per-point times are made relative to it (see the module docstring).

    Returns:
        The cloud and the number of points dropped for non-finite coordinates.

    Raises:
        DataFormatError: Sizes are inconsistent, a datatype is unknown, a field runs
            past ``point_step``, there is no ``x``/``y``/``z`` field, or (with
            ``nonfinite="reject"``) a coordinate is not finite.

    Example:
        >>> raw = np.array([[1, 2, 3, 4]], "<f4").tobytes()
        >>> fields = [PointField(n, 4 * i, FLOAT32) for i, n in enumerate("xyzi")]
        >>> cloud, _ = decode(fields, 16, 16, 1, 1, False, raw, path="scan.bag")
        >>> cloud.data.tolist(), cloud.channels
        ([[1.0, 2.0, 3.0, 4.0]], ('x', 'y', 'z', 'intensity'))
    """
    point_step, row_step, height, width = int(point_step), int(row_step), int(height), int(width)
    where = _where(context)
    if min(point_step, row_step, height, width) < 0:
        raise DataFormatError(path, f"{where}negative size in the PointCloud2 header")
    parsed = [field_of(f) for f in fields]
    dtype, used = _layout(parsed, point_step, bool(is_bigendian), path, context)
    if width and row_step < width * point_step:
        raise DataFormatError(
            path,
            f"{where}row_step {row_step} is smaller than width {width} × point_step {point_step}",
        )
    buffer = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.view(np.uint8)
    count = height * width
    if buffer.size < height * row_step:
        raise DataFormatError(
            path,
            f"{where}data holds {buffer.size} bytes but height {height} × row_step {row_step} "
            f"needs {height * row_step}",
            hint="the message is truncated or its header is wrong",
        )
    if count and point_step == 0:
        raise DataFormatError(path, f"{where}point_step is 0 for {count} points")

    if count:
        points = np.ndarray(shape=(height, width), dtype=dtype, buffer=buffer, strides=(row_step, point_step)).reshape(
            -1
        )
    else:
        points = np.zeros(0, dtype=dtype)

    mapping = map_field_names([field.name for _, field in used])
    columns: dict[str, NDArray[Any]] = {}
    for key, field in used:
        channel = mapping[field.name]
        values = points[key]
        if channel == "time" and field.datatype == FLOAT64 and time_reference is not None:
            values = _relative_time(values, time_reference)
        if field.count == 1:
            columns[channel] = values
        else:
            for k in range(field.count):
                columns[f"{channel}_{k}"] = values[:, k]
    try:
        return cloud_from_columns(columns, path, nonfinite=nonfinite)
    except DataFormatError as err:
        if not context:
            raise
        prefix = f"field {err.field!r}: " if err.field else ""
        raise DataFormatError(path, f"{where}{prefix}{err.message}", hint=err.hint) from None


def encode(cloud: PointCloud) -> dict[str, Any]:
    """The PointCloud2 fields that store ``cloud``: every channel as little-endian FLOAT32.

    Returns:
        ``height`` (1), ``width``, ``fields`` (a list of :class:`PointField`),
        ``is_bigendian`` (False), ``point_step``, ``row_step``, ``data`` (a uint8
        array) and ``is_dense`` (True unless some value is NaN/Inf).

    Example:
        >>> msg = encode(PointCloud(np.ones((2, 4))))
        >>> msg["point_step"], msg["width"], [f.name for f in msg["fields"]]
        (16, 2, ['x', 'y', 'z', 'intensity'])
    """
    values = np.ascontiguousarray(cloud.data, dtype="<f4")
    step = 4 * len(cloud.channels)
    return {
        "height": 1,
        "width": len(cloud),
        "fields": [PointField(name, 4 * i, FLOAT32, 1) for i, name in enumerate(cloud.channels)],
        "is_bigendian": False,
        "point_step": step,
        "row_step": step * len(cloud),
        "data": values.reshape(-1).view(np.uint8),
        "is_dense": bool(np.isfinite(values).all()),
    }
