"""Recorded logs: ROS 1 bags, ROS 2 bags and MCAP files carrying ``sensor_msgs/PointCloud2``.

Supported containers, read and written:

========= ============================================================ ====================
``ros1``  ROS 1 bag, format 2.0 (``.bag``; uncompressed, bz2 or lz4)  ``rosbags.rosbag1``
``ros2``  ROS 2 bag directory (``metadata.yaml`` + sqlite3 or mcap     ``rosbags.rosbag2``
          storage; zstd file/message compression is read)
``mcap``  a plain ``.mcap`` file, ROS 2 (``cdr``) messages; ``ros1``   ``mcap``
          encoded channels are read too
========= ============================================================ ====================

:class:`BagLog` opens one PointCloud2 topic of a log as a :class:`~lidarfuzz.io.dataset.Log`
of :class:`~lidarfuzz.scene.scene.Scene` frames. Opening indexes the topic (one pass that
reads each message's header stamp from its first bytes; point data is not decoded);
``load`` decodes one message, fetching it by its log time so that the storage's own index
skips every other message (the chunk around it is still read); iteration streams the
topic in one pass. Frame ids are message indices (``"000000"``, ``"000001"`` …) in log-time
order, stable across runs; timestamps are header stamps, or the log (receive) time where a
stamp is zero. Message definitions are checked: a topic whose type is called
``sensor_msgs/PointCloud2`` but whose definition differs from the standard one is refused,
because its bytes cannot be trusted to mean what the standard layout says.

:func:`write_log` writes scenes as one PointCloud2 topic (all channels FLOAT32), and
:func:`inspect_bag` summarises any log for ``lidarfuzz info``.

Limitations: poses are not read (``poses()`` returns ``None``; a log's ``/tf`` would need a
transform tree); only the points, the timestamp and the sensor frame id of a scene are
written (boxes, calibration and metadata are not); ROS 2 bags are written with metadata
version 8, which ROS 2 Iron and later read (for Humble, write ``.mcap`` and play the file).
"""

from __future__ import annotations

import contextlib
import inspect
import os
import shutil
import struct
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from functools import cache
from os import PathLike
from pathlib import Path
from typing import Any, BinaryIO, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.atomic import check_destination
from lidarfuzz.io.common import NonFinitePolicy, Problem
from lidarfuzz.io.dataset import Log
from lidarfuzz.io.logs.pointcloud2 import DATATYPE_NAMES, decode, encode, field_of
from lidarfuzz.scene.scene import Scene

LogKind = Literal["ros1", "ros2", "mcap"]
Ros2Storage = Literal["sqlite3", "mcap"]

#: The normalised (ROS 2 style) name of the point-cloud message type.
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
#: md5sum of the standard ROS 1 ``sensor_msgs/PointCloud2`` definition.
ROS1_POINTCLOUD2_MD5 = "1158d486dd51d683ce2f1be655c3c181"

_ROS1_MAGIC = b"#ROSBAG"
_MCAP_MAGIC = b"\x89MCAP"
_NS = 1_000_000_000
_DEFAULT_PERIOD_NS = 100_000_000  # frames without a timestamp are written 0.1 s apart
_DEFINITION_TYPES = (
    POINTCLOUD2,
    "sensor_msgs/msg/PointField",
    "std_msgs/msg/Header",
    "builtin_interfaces/msg/Time",
)


# -- shared helpers ---------------------------------------------------------------------


@cache
def _typestore(encoding: str) -> Any:
    """The reference typestore for a message encoding (``ros1`` → Noetic, ``cdr`` → Humble)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if encoding == "ros1" else Stores.ROS2_HUMBLE)


def _hint_for(err: BaseException) -> str | None:
    text = str(err).lower()
    if "reindex" in text or "not indexed" in text or "index looks damaged" in text:
        return "the bag looks truncated or was not closed properly; 'rosbag reindex' on a copy may repair it"
    if isinstance(err, _McapFooterError):
        return "the file looks truncated or damaged; 'mcap recover' can often repair it"
    return None


class _McapFooterError(Exception):
    """An MCAP file's footer or summary section cannot be read."""


@contextlib.contextmanager
def _reading(path: Path, what: str) -> Iterator[None]:
    """Turn any library error on malformed input into a DataFormatError naming the file."""
    try:
        yield
    except LidarfuzzError:
        raise
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except Exception as err:
        detail = str(err) or type(err).__name__
        if type(err).__module__ in ("builtins", "struct", "_struct"):  # a bare KeyError('x') says little alone
            detail = f"{type(err).__name__}: {detail}"
        raise DataFormatError(path, f"cannot {what}: {detail}", hint=_hint_for(err)) from err


def detect_kind(path: str | PathLike[str]) -> tuple[Path, LogKind]:
    """Find what a path holds: ``(path to open, kind)``; raises DataFormatError when it is no log.

    A ROS 2 bag may be named by its directory, its ``metadata.yaml`` or its ``.db3`` file.
    """
    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, "file not found")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return path, "ros2"
        raise DataFormatError(
            path,
            "directory has no metadata.yaml, so it is not a ROS 2 bag",
            hint="pass a ROS 1 .bag file, a ROS 2 bag directory or an .mcap file",
        )
    if path.name == "metadata.yaml" or (path.suffix == ".db3" and (path.parent / "metadata.yaml").is_file()):
        return path.parent, "ros2"
    with _reading(path, "read the file"), open(path, "rb") as handle:
        head = handle.read(16)
    if head.startswith(_ROS1_MAGIC):
        return path, "ros1"
    if head.startswith(_MCAP_MAGIC):
        return path, "mcap"
    found = "the file is empty" if not head else f"it starts with {head[:8]!r}"
    raise DataFormatError(
        path,
        f"not a ROS 1 bag, ROS 2 bag or MCAP file ({found})",
        hint="a ROS 1 bag starts with '#ROSBAG V2.0', an MCAP file with '\\x89MCAP0'",
    )


def _normalize_msgtype(name: str) -> str:
    from rosbags.typesys.msg import normalize_msgtype

    return normalize_msgtype(name) if name else name


def _parse_definition(text: str, fmt: str) -> dict[str, Any]:
    """Type definitions from a message definition text (``msg`` or ``idl`` format)."""
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    if fmt == "idl":
        separator = "=" * 80 + "\n"
        types: dict[str, Any] = {}
        if text.startswith(f"{separator}IDL: "):
            for part in text.split(separator)[1:]:
                types.update(get_types_from_idl(part.split("\n", 1)[1]))
        else:
            types.update(get_types_from_idl(text))
        return types
    return dict(get_types_from_msg(text, POINTCLOUD2))


def _describe_fields(fields: Sequence[tuple[str, Any]]) -> str:
    def type_name(desc: Any) -> str:
        kind, rest = desc
        if getattr(kind, "name", "") == "BASE":
            return str(rest[0])
        if getattr(kind, "name", "") == "NAME":
            return str(rest)
        return f"{type_name(rest[0])}[]"

    return ", ".join(f"{type_name(desc)} {name}" for name, desc in fields)


def definition_difference(text: str, fmt: str, encoding: str) -> str | None:
    """Why a PointCloud2 definition differs from the standard one, or ``None`` when it matches.

    Args:
        text: The definition as stored in the log (``.msg`` text with embedded
            dependencies, or IDL).
        fmt: ``"msg"`` or ``"idl"``.
        encoding: ``"ros1"`` or ``"cdr"``; selects the reference (Noetic or Humble).
    """
    try:
        types = _parse_definition(text, fmt)
    except Exception as err:
        return f"its definition cannot be parsed ({err})"
    reference = _typestore(encoding).fielddefs
    if POINTCLOUD2 not in types:
        return f"its definition does not define {POINTCLOUD2}"
    for name in _DEFINITION_TYPES:
        if name not in types or name not in reference:
            continue
        have, want = list(types[name][1]), list(reference[name][1])
        if have != want:
            return f"{name} has fields ({_describe_fields(have)}); the standard has ({_describe_fields(want)})"
    return None


# -- storage backends -------------------------------------------------------------------


@dataclass(frozen=True)
class _Topic:
    """A topic as found in a log."""

    name: str
    msgtype: str  # normalised; "" when the connections disagree or there is no schema
    count: int
    encoding: str  # "ros1", "cdr" or whatever the log declares
    difference: str | None  # why the definition is not the standard PointCloud2, if it is not


class _Backend:
    """One open log; subclasses wrap a reader library."""

    kind: LogKind
    storage: str | None = None

    def topics(self) -> list[_Topic]:
        raise NotImplementedError

    def messages(
        self, topic: str, start: int | None = None, stop: int | None = None
    ) -> Iterator[tuple[int, bytes | memoryview]]:
        """``(log time ns, raw message)`` of one topic in log-time order, within ``[start, stop)``."""
        raise NotImplementedError

    def time_range(self) -> tuple[int, int] | None:
        """First and last log time (ns), or ``None`` for an empty log."""
        raise NotImplementedError

    def message_count(self) -> int:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class _RosbagsBackend(_Backend):
    """ROS 1 bags and ROS 2 bag directories through ``rosbags``."""

    def __init__(self, path: Path, kind: LogKind) -> None:
        from rosbags.rosbag1 import Reader as Reader1
        from rosbags.rosbag2 import Reader as Reader2

        self.kind = kind
        self.reader: Any = Reader1(path) if kind == "ros1" else Reader2(path)
        self.reader.open()
        if kind == "ros2":
            plugins = {"McapReader": "mcap", "Sqlite3Reader": "sqlite3"}
            storages = getattr(getattr(self.reader, "storage", None), "storages", [])
            self.storage = plugins.get(type(storages[0]).__name__) if storages else None

    def _difference(self, connection: Any) -> str | None:
        from rosbags.interfaces import MessageDefinitionFormat

        encoding = "ros1" if self.kind == "ros1" else "cdr"
        fmt = {MessageDefinitionFormat.MSG: "msg", MessageDefinitionFormat.IDL: "idl"}.get(connection.msgdef.format)
        if self.kind == "ros1":
            if connection.digest == ROS1_POINTCLOUD2_MD5:
                return None
            detail = definition_difference(connection.msgdef.data, "msg", "ros1") if fmt else None
            reason = f"its md5sum {connection.digest} is not the standard {ROS1_POINTCLOUD2_MD5}"
            return f"{reason}: {detail}" if detail else reason
        if fmt is not None and connection.msgdef.data:
            return definition_difference(connection.msgdef.data, fmt, encoding)
        digest = str(connection.digest or "")
        if digest.startswith("RIHS01_"):
            standard = _typestore("cdr").hash_rihs01(POINTCLOUD2)
            if digest != standard:
                return f"its type hash {digest} is not the standard {standard}"
        return None

    def topics(self) -> list[_Topic]:
        found = []
        for name, info in self.reader.topics.items():
            connections = info.connections
            msgtype = info.msgtype or ""
            if self.kind == "ros1":
                encoding = "ros1"
            else:
                formats = {c.ext.serialization_format for c in connections}
                encoding = formats.pop() if len(formats) == 1 else "mixed"
            difference = None
            if msgtype == POINTCLOUD2:
                difference = next((d for c in connections if (d := self._difference(c))), None)
            found.append(_Topic(name, msgtype, int(info.msgcount), encoding, difference))
        return found

    def messages(
        self, topic: str, start: int | None = None, stop: int | None = None
    ) -> Iterator[tuple[int, bytes | memoryview]]:
        connections = [c for c in self.reader.connections if c.topic == topic]
        if not connections:
            return
        for _, log_time, raw in self.reader.messages(connections=connections, start=start, stop=stop):
            yield log_time, raw

    def time_range(self) -> tuple[int, int] | None:
        if not self.reader.message_count:
            return None
        return int(self.reader.start_time), int(self.reader.end_time) - 1

    def message_count(self) -> int:
        return int(self.reader.message_count)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.reader.close()


class _McapBackend(_Backend):
    """Plain ``.mcap`` files through the ``mcap`` package."""

    kind: LogKind = "mcap"

    def __init__(self, path: Path) -> None:
        from mcap.reader import make_reader

        self.stream: BinaryIO = open(path, "rb")  # noqa: SIM115 - closed by close()
        try:
            self.reader: Any = make_reader(self.stream)
            self.reader.get_header()
            try:
                summary = self.reader.get_summary()
            except Exception as err:
                raise _McapFooterError(f"no readable footer and summary at the end of the file ({err})") from err
            self._bounds = _mcap_bound_names(self.reader)
            self.channels: dict[int, Any] = {}
            self.schemas: dict[int, Any] = {}
            counts: dict[int, int] = {}
            first = last = None
            total = 0
            if summary is not None and summary.statistics is not None:
                self.channels, self.schemas = dict(summary.channels), dict(summary.schemas)
                counts = dict(summary.statistics.channel_message_counts)
                total = summary.statistics.message_count
                if total:
                    first = summary.statistics.message_start_time
                    last = summary.statistics.message_end_time
            else:
                # No statistics (an unindexed or minimal file): one scan finds everything.
                for schema, channel, message in self.reader.iter_messages(log_time_order=False):
                    self.channels[channel.id] = channel
                    if schema is not None:
                        self.schemas[schema.id] = schema
                    counts[channel.id] = counts.get(channel.id, 0) + 1
                    total += 1
                    first = message.log_time if first is None else min(first, message.log_time)
                    last = message.log_time if last is None else max(last, message.log_time)
                if summary is not None:
                    self.channels.update(summary.channels)
                    self.schemas.update(summary.schemas)
            self.counts = counts
            self.total = total
            self.range = None if first is None or last is None else (int(first), int(last))
        except BaseException:
            self.stream.close()
            raise

    def _difference(self, channel: Any) -> str | None:
        schema = self.schemas.get(channel.schema_id)
        if schema is None or not schema.data:
            return None
        fmt = {"ros1msg": "msg", "ros2msg": "msg", "ros2idl": "idl", "omgidl": "idl"}.get(schema.encoding)
        if fmt is None:
            return f"its schema is encoded as {schema.encoding!r}, not a ROS message definition"
        encoding = "ros1" if channel.message_encoding == "ros1" else "cdr"
        return definition_difference(bytes(schema.data).decode("utf-8", "replace"), fmt, encoding)

    def topics(self) -> list[_Topic]:
        by_topic: dict[str, list[Any]] = {}
        for channel in self.channels.values():
            by_topic.setdefault(channel.topic, []).append(channel)
        found = []
        for name in sorted(by_topic):
            channels = by_topic[name]
            types = {
                _normalize_msgtype(self.schemas[c.schema_id].name) if c.schema_id in self.schemas else ""
                for c in channels
            }
            encodings = {c.message_encoding for c in channels}
            msgtype = types.pop() if len(types) == 1 else ""
            encoding = encodings.pop() if len(encodings) == 1 else "mixed"
            difference = None
            if msgtype == POINTCLOUD2:
                difference = next((d for c in channels if (d := self._difference(c))), None)
            count = sum(self.counts.get(c.id, 0) for c in channels)
            found.append(_Topic(name, msgtype, count, encoding, difference))
        return found

    def messages(
        self, topic: str, start: int | None = None, stop: int | None = None
    ) -> Iterator[tuple[int, bytes | memoryview]]:
        lower, upper = self._bounds
        bounds: dict[str, int] = {}
        if start is not None:
            bounds[lower] = start
        if stop is not None:
            bounds[upper] = stop
        for _, _, message in self.reader.iter_messages(topics=[topic], **bounds):
            yield message.log_time, message.data

    def time_range(self) -> tuple[int, int] | None:
        return self.range

    def message_count(self) -> int:
        return int(self.total)

    def close(self) -> None:
        self.stream.close()


def _mcap_bound_names(reader: Any) -> tuple[str, str]:
    """Keyword names of the time bounds (``starting_at`` since mcap 1.3, ``start_time`` before)."""
    parameters = inspect.signature(reader.iter_messages).parameters
    if "starting_at" in parameters:
        return "starting_at", "ending_before"
    return "start_time", "end_time"


def _open_backend(path: Path, kind: LogKind) -> _Backend:
    what = {"ros1": "open the ROS 1 bag", "ros2": "open the ROS 2 bag", "mcap": "open the MCAP file"}[kind]
    with _reading(path, what):
        if kind == "mcap":
            return _McapBackend(path)
        return _RosbagsBackend(path, kind)


# -- reading ----------------------------------------------------------------------------


class _Entry(NamedTuple):
    """What the index keeps of one message (no point data)."""

    log_time: int  # ns
    stamp: int  # header stamp, ns; 0 when unset
    size: int  # raw message bytes
    rank: int  # position among earlier messages with the same (log_time, stamp, size)

    @property
    def time_ns(self) -> int:
        return self.stamp if self.stamp else self.log_time


def _header_stamp(raw: bytes | memoryview, encoding: str) -> int:
    """The header stamp (ns) read straight from a serialised PointCloud2, without decoding it."""
    if encoding == "ros1":
        _, sec, nanosec = struct.unpack_from("<III", raw, 0)  # seq, stamp.sec, stamp.nsec
    else:
        little = raw[1] & 1  # CDR encapsulation: 0x0001 = CDR_LE, 0x0000 = CDR_BE
        sec, nanosec = struct.unpack_from("<iI" if little else ">iI", raw, 4)
    return int(sec) * _NS + int(nanosec)


def _pick_topic(path: Path, topics: list[_Topic], wanted: str | None) -> _Topic:
    def listing(items: Iterable[_Topic]) -> str:
        return ", ".join(f"{t.name} ({t.msgtype or 'unknown type'}, {t.count} messages)" for t in items) or "none"

    clouds = [t for t in topics if t.msgtype == POINTCLOUD2]
    names = ", ".join(t.name for t in clouds) or "none"
    if wanted is not None:
        chosen = next((t for t in topics if t.name == wanted), None)
        if chosen is None:
            raise DataFormatError(
                path,
                f"no topic {wanted!r}; sensor_msgs/PointCloud2 topics: {names}",
                hint="pass one of them as topic=... (--topic)" if clouds else None,
            )
        if chosen.msgtype != POINTCLOUD2:
            raise DataFormatError(
                path,
                f"topic {wanted!r} carries {chosen.msgtype or 'an unknown type'}, "
                f"not sensor_msgs/PointCloud2; sensor_msgs/PointCloud2 topics: {names}",
            )
        return chosen
    if not clouds:
        raise DataFormatError(path, f"no sensor_msgs/PointCloud2 messages in {path}; topics found: {listing(topics)}")
    candidates = [t for t in clouds if t.count > 0] or clouds
    if len(candidates) > 1:
        raise DataFormatError(
            path,
            f"{len(candidates)} sensor_msgs/PointCloud2 topics: {listing(candidates)}",
            hint="choose one with topic=... (--topic)",
        )
    return candidates[0]


class BagLog(Log[Scene]):
    """One PointCloud2 topic of a ROS 1 bag, ROS 2 bag or MCAP file, as a log of scenes.

    Args:
        path: A ``.bag`` file, a ROS 2 bag directory (or its ``metadata.yaml``), or an
            ``.mcap`` file.
        topic: The PointCloud2 topic to read; may be left out when the log has only one.
        nonfinite: ``"drop"`` (default) or ``"reject"`` points with NaN/Inf coordinates.
        name: Display name (defaults to the file name).

    Raises:
        DataFormatError: The path is no readable log, the topic is missing, ambiguous or
            not a standard PointCloud2, or a message header is malformed.

    Each scene's metadata holds ``source``, ``format``, ``topic``, ``sensor_frame_id``
    (the header's ``frame_id``), ``message_index`` and, when points were dropped,
    ``dropped_nonfinite``. Readers for :meth:`load` stay open until :meth:`close` (or
    the end of a ``with`` block); a pickled log reopens them when next used.

    Example:
        >>> import tempfile, pathlib
        >>> from lidarfuzz.scene.points import PointCloud
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "scan.mcap"
        >>> _ = write_log(out, [Scene(PointCloud(np.ones((5, 4))), timestamp=12.5)])
        >>> with BagLog(out) as log:
        ...     log.format, log.frame_ids(), log.timestamps().tolist(), len(log["000000"])
        ('mcap', ('000000',), [12.5], 5)
    """

    def __init__(
        self,
        path: str | PathLike[str],
        topic: str | None = None,
        *,
        nonfinite: NonFinitePolicy = "drop",
        name: str | None = None,
    ) -> None:
        source, kind = detect_kind(path)
        super().__init__(source, name)
        self._kind: LogKind = kind
        self.nonfinite: NonFinitePolicy = nonfinite
        self._reader: _Backend | None = None
        backend = _open_backend(source, kind)
        try:
            self.storage: str | None = backend.storage
            with _reading(source, "list the topics"):
                topics = backend.topics()
            chosen = _pick_topic(source, topics, topic)
            if chosen.difference:
                raise DataFormatError(
                    source,
                    f"topic {chosen.name!r} is typed sensor_msgs/PointCloud2 but its message definition "
                    f"differs from the standard one: {chosen.difference}",
                    hint="lidarfuzz reads only the standard sensor_msgs/PointCloud2 layout",
                )
            if chosen.encoding not in ("ros1", "cdr"):
                raise DataFormatError(
                    source,
                    f"messages on topic {chosen.name!r} are encoded as {chosen.encoding!r}; "
                    "only 'ros1' and 'cdr' can be read",
                )
            self._topic = chosen
            self._entries = self._index(backend)
        finally:
            backend.close()
        self._ids = tuple(f"{i:06d}" for i in range(len(self._entries)))
        self._times = np.array([e.time_ns for e in self._entries], dtype=np.int64)
        # Python's int / int is correctly rounded, so these equal each loaded scene's timestamp.
        self._seconds = np.array([e.time_ns / _NS for e in self._entries], dtype=np.float64)
        self._check_times()

    # -- opening ------------------------------------------------------------------------
    def _index(self, backend: _Backend) -> list[_Entry]:
        entries: list[_Entry] = []
        ranks: dict[tuple[int, int, int], int] = {}
        previous_time: int | None = None
        with _reading(self.path, f"index topic {self._topic.name!r}"):
            for index, (log_time, raw) in enumerate(backend.messages(self._topic.name)):
                stamp = self._stamp(raw, index)
                key = (log_time, stamp, len(raw))
                if log_time != previous_time:
                    ranks.clear()
                    previous_time = log_time
                rank = ranks.get(key, 0)
                ranks[key] = rank + 1
                entries.append(_Entry(log_time, stamp, len(raw), rank))
        return entries

    def _stamp(self, raw: bytes | memoryview, index: int) -> int:
        try:
            return _header_stamp(raw, self._topic.encoding)
        except (struct.error, IndexError):
            raise DataFormatError(
                self.path,
                f"topic {self._topic.name}, message {index}: {len(raw)} bytes are too few to hold a header",
            ) from None

    def _check_times(self) -> None:
        # An unset stamp only matters when the log time used instead is not zero as well.
        unset = sum(1 for e in self._entries if not e.stamp and e.log_time)
        if unset:
            self._problems.append(
                Problem(
                    "warning",
                    str(self.path),
                    f"{unset} message(s) on {self._topic.name} have a zero header stamp; "
                    "their log time is used as timestamp",
                )
            )
        if len(self._times) > 1 and (np.diff(self._times) < 0).any():
            first = int(np.argmax(np.diff(self._times) < 0)) + 1
            self._problems.append(
                Problem(
                    "warning",
                    str(self.path),
                    f"header stamps on {self._topic.name} go back in time (first at message {first}); "
                    "frames stay in log-time order",
                )
            )

    # -- Dataset API --------------------------------------------------------------------
    @property
    def format(self) -> str:
        """``"ros1"``, ``"ros2"`` or ``"mcap"``."""
        return self._kind

    @property
    def topic(self) -> str:
        """The PointCloud2 topic this log reads."""
        return self._topic.name

    def frame_ids(self) -> Sequence[str]:
        """Zero-padded message indices in log-time order (``"000000"``, ``"000001"`` …)."""
        return self._ids

    def timestamps(self) -> NDArray[np.float64]:
        """Header stamps in seconds (the log time where a stamp is zero), one per frame."""
        return self._seconds.copy()

    def poses(self) -> NDArray[np.float64] | None:
        """Always ``None``: ego poses live in ``/tf`` or localisation topics, which are not read."""
        return None

    def __len__(self) -> int:
        return len(self._entries)

    def _id_set(self) -> set[str]:
        return set(self._ids)

    def _position(self, frame_id: str) -> int:
        if isinstance(frame_id, str) and frame_id.isdigit():
            index = int(frame_id)
            if index < len(self._ids) and self._ids[index] == frame_id:
                return index
        raise KeyError(f"{self.path}: no frame with id {frame_id!r} (ids run 000000..{len(self._ids) - 1:06d})")

    def load(self, frame_id: str) -> Scene:
        """Decode one message; only the stored chunk around it is read."""
        index = self._position(frame_id)
        entry = self._entries[index]
        with _reading(self.path, f"read message {index} of topic {self._topic.name!r}"):
            if self._reader is None:
                self._reader = _open_backend(self.path, self._kind)
            matches = [
                raw
                for _, raw in self._reader.messages(self._topic.name, entry.log_time, entry.log_time + 1)
                if len(raw) == entry.size and self._stamp(raw, index) == entry.stamp
            ]
        if entry.rank >= len(matches):
            raise DataFormatError(
                self.path,
                f"topic {self._topic.name!r}, message {index} is no longer where the index found it",
                hint="the log changed since it was opened; open it again",
            )
        return self._finish(self._scene(index, entry.log_time, matches[entry.rank]))

    def __iter__(self) -> Iterator[Scene]:
        """Stream every frame in one pass over the log."""
        backend = _open_backend(self.path, self._kind)
        try:
            messages = backend.messages(self._topic.name)
            index = 0
            while True:
                with _reading(self.path, f"read message {index} of topic {self._topic.name!r}"):
                    item = next(messages, None)
                if item is None:
                    return
                yield self._finish(self._scene(index, *item))
                index += 1
        finally:
            backend.close()

    def _scene(self, index: int, log_time: int, raw: bytes | memoryview) -> Scene:
        encoding = self._topic.encoding
        store = _typestore(encoding)
        where = f"topic {self._topic.name}, message {index}"
        try:
            if encoding == "ros1":
                msg = store.deserialize_ros1(raw, POINTCLOUD2)
            else:
                msg = store.deserialize_cdr(raw, POINTCLOUD2)
        except Exception as err:
            raise DataFormatError(self.path, f"{where}: cannot deserialize sensor_msgs/PointCloud2: {err}") from err
        stamp = int(msg.header.stamp.sec) * _NS + int(msg.header.stamp.nanosec)
        time_ns = stamp if stamp else log_time
        seconds = time_ns / _NS
        cloud, dropped = decode(
            msg.fields,
            msg.point_step,
            msg.row_step,
            msg.height,
            msg.width,
            msg.is_bigendian,
            msg.data,
            path=self.path,
            nonfinite=self.nonfinite,
            context=where,
            time_reference=seconds,
        )
        metadata: dict[str, Any] = {
            "source": str(self.path),
            "format": self._kind,
            "topic": self._topic.name,
            "sensor_frame_id": str(msg.header.frame_id),
            "message_index": index,
        }
        if dropped:
            metadata["dropped_nonfinite"] = dropped
        return Scene(cloud, frame_id=f"{index:06d}", timestamp=seconds, metadata=metadata)

    # -- resources ----------------------------------------------------------------------
    def close(self) -> None:
        """Close the reader kept open for :meth:`load` (it reopens when needed)."""
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.close()

    def __enter__(self) -> BagLog:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_reader"] = None
        return state

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()


# -- inspection -------------------------------------------------------------------------


def inspect_bag(path: str | PathLike[str]) -> dict[str, Any]:
    """Summarise a log for ``lidarfuzz info``.

    Returns:
        ``path``, ``format`` (``ros1``/``ros2``/``mcap``), ``storage`` (ROS 2 only),
        ``message_count``, ``start_time``/``end_time`` (log time, seconds; ``None`` when
        empty), ``duration`` (seconds), ``pointcloud2_topics`` (names) and ``topics``: one
        dict per topic with ``name``, ``type``, ``count``, ``encoding``, ``pointcloud2``
        and, for PointCloud2 topics, ``standard_definition``, ``definition_problem`` and
        the layout of the first message: ``height``, ``width``, ``point_step``,
        ``row_step``, ``is_bigendian`` and ``fields`` (``name``, ``datatype`` number,
        ``datatype_name``, ``offset``, ``count``). A first message that cannot be
        decoded is reported under ``error`` instead of raising.

    Raises:
        DataFormatError: The path is not a readable log.
    """
    source, kind = detect_kind(path)
    backend = _open_backend(source, kind)
    try:
        with _reading(source, "inspect the log"):
            topics = backend.topics()
            span = backend.time_range()
            count = backend.message_count()
        report: dict[str, Any] = {
            "path": str(source),
            "format": kind,
            "storage": backend.storage,
            "message_count": count,
            "start_time": None if span is None else span[0] / _NS,
            "end_time": None if span is None else span[1] / _NS,
            "duration": 0.0 if span is None else (span[1] - span[0]) / _NS,
            "pointcloud2_topics": [t.name for t in topics if t.msgtype == POINTCLOUD2],
            "topics": [],
        }
        for topic in topics:
            entry: dict[str, Any] = {
                "name": topic.name,
                "type": topic.msgtype or None,
                "count": topic.count,
                "encoding": topic.encoding,
                "pointcloud2": topic.msgtype == POINTCLOUD2,
            }
            if topic.msgtype == POINTCLOUD2:
                entry["standard_definition"] = topic.difference is None
                entry["definition_problem"] = topic.difference
                if topic.difference is None and topic.count and topic.encoding in ("ros1", "cdr"):
                    try:
                        entry.update(_first_layout(source, backend, topic))
                    except DataFormatError as err:
                        entry["error"] = err.message
            report["topics"].append(entry)
        return report
    finally:
        backend.close()


def _first_layout(path: Path, backend: _Backend, topic: _Topic) -> dict[str, Any]:
    with _reading(path, f"read the first message of {topic.name!r}"):
        first = next(backend.messages(topic.name), None)
        if first is None:
            return {}
        store = _typestore(topic.encoding)
        raw = first[1]
        msg = (
            store.deserialize_ros1(raw, POINTCLOUD2)
            if topic.encoding == "ros1"
            else store.deserialize_cdr(raw, POINTCLOUD2)
        )
    fields = [field_of(f) for f in msg.fields]
    return {
        "height": int(msg.height),
        "width": int(msg.width),
        "point_step": int(msg.point_step),
        "row_step": int(msg.row_step),
        "is_bigendian": bool(msg.is_bigendian),
        "fields": [
            {
                "name": f.name,
                "datatype": f.datatype,
                "datatype_name": DATATYPE_NAMES.get(f.datatype, "unknown"),
                "offset": f.offset,
                "count": f.count,
            }
            for f in fields
        ],
    }


# -- writing ----------------------------------------------------------------------------


def _infer_kind(path: Path, kind: str | None) -> LogKind:
    if kind is not None:
        if kind not in ("ros1", "ros2", "mcap"):
            raise ValueError(f"kind must be 'ros1', 'ros2' or 'mcap', got {kind!r}")
        return kind  # type: ignore[return-value]
    suffix = path.suffix.lower()
    if suffix == ".bag":
        return "ros1"
    if suffix == ".mcap":
        return "mcap"
    if suffix == "" or path.is_dir():
        return "ros2"
    raise ValueError(
        f"{path}: cannot tell the log kind from the suffix {suffix!r}; use .bag (ROS 1), .mcap, "
        "a directory name without suffix (ROS 2 bag), or pass kind=..."
    )


def _to_ns(seconds: float, index: int, scene: Scene) -> int:
    """Seconds → integer nanoseconds, exactly (so reading back gives the same float)."""
    if not np.isfinite(seconds) or seconds < 0:
        raise ValueError(
            f"scene {index} (frame {scene.frame_id!r}): timestamp {seconds} cannot be stored in a log "
            "(it must be finite and not negative)"
        )
    return round(Fraction(seconds) * _NS)


def _frames(scenes: Iterable[Scene], limit_sec: int) -> Iterator[tuple[int, int, int, dict[str, Any]]]:
    """``(index, log time ns, stamp ns, encoded cloud)``; log times never go back, so order is kept."""
    previous = 0
    for index, scene in enumerate(scenes):
        if not isinstance(scene, Scene):
            raise TypeError(f"scene {index} is a {type(scene).__name__}, not a Scene")
        stamp = index * _DEFAULT_PERIOD_NS if scene.timestamp is None else _to_ns(scene.timestamp, index, scene)
        if stamp // _NS >= limit_sec:
            raise ValueError(
                f"scene {index} (frame {scene.frame_id!r}): timestamp {stamp / _NS} s is too large for this log kind"
            )
        log_time = max(stamp, previous)
        previous = log_time
        yield index, log_time, stamp, encode(scene.points)


def _message(store: Any, ros1: bool, encoded: dict[str, Any], stamp: int, frame_id: str, seq: int) -> Any:
    types = store.types
    time = types["builtin_interfaces/msg/Time"](sec=stamp // _NS, nanosec=stamp % _NS)
    header_type = types["std_msgs/msg/Header"]
    header = header_type(seq=seq, stamp=time, frame_id=frame_id) if ros1 else header_type(stamp=time, frame_id=frame_id)
    point_field = types["sensor_msgs/msg/PointField"]
    fields = [point_field(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in encoded["fields"]]
    return types[POINTCLOUD2](
        header=header,
        height=encoded["height"],
        width=encoded["width"],
        fields=fields,
        is_bigendian=encoded["is_bigendian"],
        point_step=encoded["point_step"],
        row_step=encoded["row_step"],
        data=encoded["data"],
        is_dense=encoded["is_dense"],
    )


def _write_ros1(out: Path, scenes: Iterable[Scene], topic: str, frame_id: str) -> None:
    from rosbags.rosbag1 import Writer

    store = _typestore("ros1")
    with Writer(out) as writer:
        connection = writer.add_connection(topic, POINTCLOUD2, typestore=store)
        for index, log_time, stamp, encoded in _frames(scenes, 2**31):
            msg = _message(store, True, encoded, stamp, frame_id, index)
            writer.write(connection, log_time, store.serialize_ros1(msg, POINTCLOUD2))


def _write_ros2(out: Path, scenes: Iterable[Scene], topic: str, frame_id: str, storage: Ros2Storage) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
    store = _typestore("cdr")
    with Writer(out, version=8, storage_plugin=plugin) as writer:
        connection = writer.add_connection(topic, POINTCLOUD2, typestore=store)
        for index, log_time, stamp, encoded in _frames(scenes, 2**31):
            msg = _message(store, False, encoded, stamp, frame_id, index)
            writer.write(connection, log_time, store.serialize_cdr(msg, POINTCLOUD2))


def _write_mcap(out: Path, scenes: Iterable[Scene], topic: str, frame_id: str) -> None:
    from mcap.writer import CompressionType, Writer

    from lidarfuzz import __version__

    store = _typestore("cdr")
    schema_text, _ = store.generate_msgdef(POINTCLOUD2, ros_version=2)
    with open(out, "xb") as stream:
        writer = Writer(stream, compression=CompressionType.NONE)
        writer.start(profile="ros2", library=f"lidarfuzz {__version__}")
        schema_id = writer.register_schema(name=POINTCLOUD2, encoding="ros2msg", data=schema_text.encode())
        channel_id = writer.register_channel(topic=topic, message_encoding="cdr", schema_id=schema_id)
        for index, log_time, stamp, encoded in _frames(scenes, 2**31):
            msg = _message(store, False, encoded, stamp, frame_id, index)
            writer.add_message(
                channel_id=channel_id,
                log_time=log_time,
                data=store.serialize_cdr(msg, POINTCLOUD2),
                publish_time=log_time,
                sequence=index,
            )
        writer.finish()


def _fsync_tree(path: Path) -> None:
    files = [path] if path.is_file() else [p for p in path.rglob("*") if p.is_file()]
    for file in files:
        with open(file, "rb+") as handle:
            os.fsync(handle.fileno())


@contextlib.contextmanager
def _staged(path: Path, overwrite: bool) -> Iterator[Path]:
    """Yield a path with ``path``'s name inside a hidden staging folder next to it; move it in on success.

    Unlike :func:`lidarfuzz.io.atomic.atomic_path` this also handles directories (ROS 2
    bags) and keeps the final name inside the output (a ROS 2 bag names its storage file
    after its directory).
    """
    target = check_destination(path, overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        out = staging / target.name
        yield out
        _fsync_tree(out)
        if target.exists() and (target.is_dir() or out.is_dir()):
            # os.replace cannot put a directory over a non-empty one: move the old one aside first.
            os.replace(target, staging / f"{target.name}.old")
        os.replace(out, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def write_log(
    path: str | PathLike[str],
    scenes: Iterable[Scene],
    *,
    kind: LogKind | None = None,
    topic: str = "/points",
    frame_id: str = "velodyne",
    storage: Ros2Storage = "sqlite3",
    overwrite: bool = False,
) -> Path:
    """Write scenes as one ``sensor_msgs/PointCloud2`` topic of a new log.

    Each scene becomes one message: every channel as a little-endian FLOAT32 field
    (named after the channel), one row, ``is_dense`` true unless a value is NaN/Inf.
    The header stamp is the scene's timestamp (exact to the nanosecond), or index × 0.1 s
    when it is ``None``; the log time is the same, except that it never goes back in
    time, so frames keep their order. The log is written next to ``path`` and moved in
    place when complete.

    Args:
        path: ``.bag`` (ROS 1), ``.mcap`` (MCAP file, ROS 2 profile) or a directory name
            (ROS 2 bag).
        scenes: The frames, in order (any iterable; consumed once).
        kind: ``"ros1"``, ``"ros2"`` or ``"mcap"``; inferred from ``path`` when ``None``.
        topic: Topic name.
        frame_id: The sensor frame written into every header.
        storage: ROS 2 bags only: ``"sqlite3"`` (default) or ``"mcap"``.
        overwrite: Replace an existing file or bag directory.

    Returns:
        ``path``.

    Raises:
        OutputExistsError: ``path`` exists and ``overwrite`` is false.
        ValueError: Unknown kind or storage, or a timestamp that the log cannot store.
    """
    path = Path(path)
    chosen = _infer_kind(path, kind)
    if storage not in ("sqlite3", "mcap"):
        raise ValueError(f"storage must be 'sqlite3' or 'mcap', got {storage!r}")
    with _staged(path, overwrite) as out:
        if chosen == "ros1":
            _write_ros1(out, scenes, topic, frame_id)
        elif chosen == "ros2":
            _write_ros2(out, scenes, topic, frame_id, storage)
        else:
            _write_mcap(out, scenes, topic, frame_id)
    return path
