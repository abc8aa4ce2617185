"""Open logs through their reader libraries: ROS 1 and ROS 2 bags through ``rosbags``, plain
``.mcap`` files through ``mcap``, behind one small interface (:class:`Backend`): the topics
with their types and counts, and one topic's raw messages in log-time order."""

from __future__ import annotations

import contextlib
import inspect
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.logs.containers import LogKind, McapFooterError, reading
from lidarfuzz.io.logs.messages import (
    POINTCLOUD2,
    ROS1_POINTCLOUD2_MD5,
    definition_difference,
    normalize_msgtype,
    typestore,
)
from lidarfuzz.io.textfiles import check_yaml, read_text


@dataclass(frozen=True)
class Topic:
    """A topic as found in a log."""

    name: str
    msgtype: str  # normalised; "" when the connections disagree or there is no schema
    count: int
    encoding: str  # "ros1", "cdr" or whatever the log declares
    difference: str | None  # why the definition is not the standard PointCloud2, if it is not


class Backend:
    """One open log; subclasses wrap a reader library."""

    kind: LogKind
    storage: str | None = None

    def topics(self) -> list[Topic]:
        raise NotImplementedError

    def messages(
        self, topic: str, start: int | None = None, stop: int | None = None
    ) -> Iterator[tuple[int, bytes | memoryview]]:
        """``(log time ns, raw message)`` of one topic in log-time order, within ``[start, stop)``."""
        raise NotImplementedError

    def time_range(self) -> tuple[int, int] | None:
        """First and last log time (ns), or ``None`` for an empty log."""
        raise NotImplementedError

    def definition(self, topic: str) -> tuple[str, str] | None:
        """The message definition the log stores for a topic, as ``(text, "msg" or "idl")``, or None."""
        raise NotImplementedError

    def message_count(self) -> int:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class _RosbagsBackend(Backend):
    """ROS 1 bags and ROS 2 bag directories through ``rosbags``."""

    def __init__(self, path: Path, kind: LogKind) -> None:
        # rosbags is slow to import: loaded only when a log is touched
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
        # rosbags is slow to import: loaded only when a log is touched
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
            standard = typestore("cdr").hash_rihs01(POINTCLOUD2)
            if digest != standard:
                return f"its type hash {digest} is not the standard {standard}"
        return None

    def topics(self) -> list[Topic]:
        found = []
        for name, info in self.reader.topics.items():
            if not isinstance(name, str) or not name:
                raise ValueError(f"a topic is named {name!r}, not a topic name")
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
            found.append(Topic(name, msgtype, int(info.msgcount), encoding, difference))
        return found

    def messages(
        self, topic: str, start: int | None = None, stop: int | None = None
    ) -> Iterator[tuple[int, bytes | memoryview]]:
        connections = [c for c in self.reader.connections if c.topic == topic]
        if not connections:
            return
        for _, log_time, raw in self.reader.messages(connections=connections, start=start, stop=stop):
            yield log_time, raw

    def definition(self, topic: str) -> tuple[str, str] | None:
        # rosbags is slow to import: loaded only when a log is touched
        from rosbags.interfaces import MessageDefinitionFormat

        for connection in self.reader.connections:
            if connection.topic == topic and connection.msgdef.data:
                fmt = "idl" if connection.msgdef.format == MessageDefinitionFormat.IDL else "msg"
                return str(connection.msgdef.data), fmt
        return None

    def time_range(self) -> tuple[int, int] | None:
        if not self.reader.message_count:
            return None
        return int(self.reader.start_time), int(self.reader.end_time) - 1

    def message_count(self) -> int:
        return int(self.reader.message_count)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.reader.close()


class _McapBackend(Backend):
    """Plain ``.mcap`` files through the ``mcap`` package."""

    kind: LogKind = "mcap"

    def __init__(self, path: Path) -> None:
        # mcap is slow to import: loaded only when a log is touched
        from mcap.reader import make_reader

        self.stream: BinaryIO = open(path, "rb")  # noqa: SIM115 - closed by close()
        try:
            self.reader: Any = make_reader(self.stream)
            self.reader.get_header()
            try:
                summary = self.reader.get_summary()
            except Exception as err:
                raise McapFooterError(f"no readable footer and summary at the end of the file ({err})") from err
            self._bounds = _mcap_bound_names(self.reader)
            self.channels: dict[int, Any] = {}
            self.schemas: dict[int, Any] = {}
            counts: dict[int, int] = {}
            first = last = None
            total = 0
            if summary is not None:
                _check_chunks(path, summary.chunk_indexes)
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

    def topics(self) -> list[Topic]:
        by_topic: dict[str, list[Any]] = {}
        for channel in self.channels.values():
            by_topic.setdefault(channel.topic, []).append(channel)
        found = []
        for name in sorted(by_topic):
            channels = by_topic[name]
            types = {
                normalize_msgtype(self.schemas[c.schema_id].name) if c.schema_id in self.schemas else ""
                for c in channels
            }
            encodings = {c.message_encoding for c in channels}
            msgtype = types.pop() if len(types) == 1 else ""
            encoding = encodings.pop() if len(encodings) == 1 else "mixed"
            difference = None
            if msgtype == POINTCLOUD2:
                difference = next((d for c in channels if (d := self._difference(c))), None)
            count = sum(self.counts.get(c.id, 0) for c in channels)
            found.append(Topic(name, msgtype, count, encoding, difference))
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

    def definition(self, topic: str) -> tuple[str, str] | None:
        for channel in self.channels.values():
            schema = self.schemas.get(channel.schema_id)
            if channel.topic == topic and schema is not None and schema.data:
                fmt = "idl" if schema.encoding in ("ros2idl", "omgidl") else "msg"
                return bytes(schema.data).decode("utf-8", "replace"), fmt
        return None

    def time_range(self) -> tuple[int, int] | None:
        return self.range

    def message_count(self) -> int:
        return int(self.total)

    def close(self) -> None:
        self.stream.close()


#: Largest chunk an MCAP file may ask to decompress (writers chunk at ~1–4 MiB): a bigger claim is damage,
#: or a decompression bomb, refused before the reader allocates it.
MAX_MCAP_CHUNK = 1 << 30


def _check_chunks(path: Path, indexes: Any) -> None:
    """Each chunk the summary lists lies inside the file and decompresses to at most :data:`MAX_MCAP_CHUNK`."""
    size = path.stat().st_size
    for number, chunk in enumerate(indexes):
        end = chunk.chunk_start_offset + chunk.chunk_length
        problem = None
        if end > size or chunk.compressed_size > chunk.chunk_length:
            problem = (f"claims bytes {chunk.chunk_start_offset:,} to {end:,} ({chunk.compressed_size:,} compressed) "
                       f"of a file of {size:,}")
        elif chunk.uncompressed_size > MAX_MCAP_CHUNK:
            problem = f"claims {chunk.uncompressed_size:,} bytes once decompressed (at most {MAX_MCAP_CHUNK:,})"
        elif not chunk.compression and chunk.uncompressed_size != chunk.compressed_size:
            problem = f"is not compressed but claims {chunk.uncompressed_size:,} bytes from {chunk.compressed_size:,}"
        if problem is not None:
            raise DataFormatError(path, f"chunk {number} {problem}", field="chunk index",
                                  hint="the file is damaged; 'mcap recover' can often repair it")


def _mcap_bound_names(reader: Any) -> tuple[str, str]:
    """Keyword names of the time bounds (``starting_at`` since mcap 1.3, ``start_time`` before)."""
    parameters = inspect.signature(reader.iter_messages).parameters
    if "starting_at" in parameters:
        return "starting_at", "ending_before"
    return "start_time", "end_time"


def _check_metadata(bag: Path) -> None:
    """Refuse a ROS 2 bag's ``metadata.yaml`` that is not YAML, or that would make a YAML parser
    recurse or expand without bound (:func:`lidarfuzz.io.textfiles.check_yaml`), before ``rosbags``
    parses it: its pure-Python parser took 25 s to find the error in a line of a million characters."""
    import yaml

    metadata = bag / "metadata.yaml"
    text = read_text(metadata, "a ROS 2 bag's metadata.yaml", limit=4 << 20)
    try:
        # rosbag2 writes short values (a topic's QoS profiles are ~1 KB): 600,000 characters took 3 s there
        check_yaml(text, metadata, scalar_limit=64 << 10)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise DataFormatError(metadata, f"not valid YAML: {problem}",
                              line=mark.line + 1 if mark is not None else None) from None


def open_backend(path: Path, kind: LogKind) -> Backend:
    what = {"ros1": "open the ROS 1 bag", "ros2": "open the ROS 2 bag", "mcap": "open the MCAP file"}[kind]
    if kind == "ros2":
        _check_metadata(path)
    with reading(path, what):
        if kind == "mcap":
            return _McapBackend(path)
        return _RosbagsBackend(path, kind)
