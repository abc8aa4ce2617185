"""Reading one topic of a log as a :class:`~lidarfuzz.io.dataset.Log`.

:class:`TopicLog` is what every modality's log reader shares (the camera's is
:class:`lidarfuzz.io.images.logs.ImageLog`); :class:`BagLog` opens one PointCloud2 topic of a log as a log of
:class:`~lidarfuzz.scene.scene.Scene` frames. Opening indexes the topic (one pass that
reads each message's header stamp from its first bytes; point data is not decoded);
``load`` decodes one message, fetching it by its log time so that the storage's own index
skips every other message (the chunk around it is still read); iteration streams the
topic in one pass. Frame ids are message indices (``"000000"``, ``"000001"`` …) in log-time
order, stable across runs; timestamps are header stamps, or the log (receive) time where a
stamp is zero. Message definitions are checked (:mod:`lidarfuzz.io.logs.messages`).

Poses are not read (``poses()`` returns ``None``; a log's ``/tf`` would need a transform tree).
"""

from __future__ import annotations

import contextlib
import struct
from abc import abstractmethod
from collections.abc import Iterable, Iterator, Sequence
from os import PathLike
from pathlib import Path
from typing import Any, ClassVar, NamedTuple, Self, TypeVar

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFinitePolicy, Problem
from lidarfuzz.io.dataset import Log
from lidarfuzz.io.logs.backends import Backend, Topic, open_backend
from lidarfuzz.io.logs.containers import LogKind, detect_kind, reading
from lidarfuzz.io.logs.messages import NS, POINTCLOUD2, header_stamp, typestore
from lidarfuzz.io.logs.pointcloud2 import decode
from lidarfuzz.scene.scene import Sample, Scene

S = TypeVar("S", bound=Sample)


class _Entry(NamedTuple):
    """What the index keeps of one message (no point data)."""

    log_time: int  # ns
    stamp: int  # header stamp, ns; 0 when unset
    size: int  # raw message bytes
    rank: int  # position among earlier messages with the same (log_time, stamp, size)

    @property
    def time_ns(self) -> int:
        return self.stamp if self.stamp else self.log_time


def _pick_topic(path: Path, topics: list[Topic], wanted: str | None,
                msgtypes: tuple[str, ...] = (POINTCLOUD2,), what: str = "sensor_msgs/PointCloud2") -> Topic:
    """The topic to read: ``wanted``, or the only non-empty one of ``msgtypes`` (``what`` names them)."""
    def listing(items: Iterable[Topic]) -> str:
        return ", ".join(f"{t.name} ({t.msgtype or 'unknown type'}, {t.count} messages)" for t in items) or "none"

    clouds = [t for t in topics if t.msgtype in msgtypes]
    names = ", ".join(t.name for t in clouds) or "none"
    if wanted is not None:
        chosen = next((t for t in topics if t.name == wanted), None)
        if chosen is None:
            raise DataFormatError(
                path,
                f"no topic {wanted!r}; {what} topics: {names}",
                hint="pass one of them as topic=... (--topic)" if clouds else None,
            )
        if chosen.msgtype not in msgtypes:
            raise DataFormatError(
                path,
                f"topic {wanted!r} carries {chosen.msgtype or 'an unknown type'}, "
                f"not {what}; {what} topics: {names}",
            )
        return chosen
    if not clouds:
        raise DataFormatError(path, f"no {what} messages in {path}; topics found: {listing(topics)}")
    candidates = [t for t in clouds if t.count > 0] or clouds
    if len(candidates) > 1:
        raise DataFormatError(
            path,
            f"{len(candidates)} {what} topics: {listing(candidates)}",
            hint="choose one with topic=... (--topic)",
        )
    return candidates[0]


class TopicLog(Log[S]):
    """One topic of a ROS 1 bag, ROS 2 bag or MCAP file, as a log of samples of one modality.

    Subclasses name the message types they read (:attr:`msgtypes`, :attr:`what` for messages)
    and turn one raw message into a sample (:meth:`_sample`); opening, the index, ``load`` by
    log time, streaming iteration and the reader's lifetime are shared.
    """

    #: Normalised message types the topic may carry.
    msgtypes: ClassVar[tuple[str, ...]] = (POINTCLOUD2,)
    #: How messages name those types.
    what: ClassVar[str] = "sensor_msgs/PointCloud2"

    def __init__(
        self,
        path: str | PathLike[str],
        topic: str | None = None,
        *,
        name: str | None = None,
    ) -> None:
        source, kind = detect_kind(path)
        super().__init__(source, name)
        self._kind: LogKind = kind
        self._reader: Backend | None = None
        backend = open_backend(source, kind)
        try:
            self.storage: str | None = backend.storage
            with reading(source, "list the topics"):
                topics = backend.topics()
            chosen = _pick_topic(source, topics, topic, self.msgtypes, self.what)
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
        late = next((i for i, e in enumerate(self._entries) if not 0 <= e.time_ns < 1 << 63), None)
        if late is not None:  # an MCAP log time is a uint64: past 2^63 - 1 ns (the year 2262) is damage
            raise DataFormatError(source, f"message {late} on topic {chosen.name!r} is stamped "
                                  f"{self._entries[late].time_ns:,} ns, outside 0 … 2^63 - 1", field="log_time")
        self._times = np.array([e.time_ns for e in self._entries], dtype=np.int64)
        # Python's int / int is correctly rounded, so these equal each loaded scene's timestamp.
        self._seconds = np.array([e.time_ns / NS for e in self._entries], dtype=np.float64)
        self._check_times()

    # -- opening ------------------------------------------------------------------------
    def _index(self, backend: Backend) -> list[_Entry]:
        entries: list[_Entry] = []
        ranks: dict[tuple[int, int, int], int] = {}
        previous_time: int | None = None
        with reading(self.path, f"index topic {self._topic.name!r}"):
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
            return header_stamp(raw, self._topic.encoding)
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
        """The topic this log reads."""
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

    def load(self, frame_id: str) -> S:
        """Decode one message; only the stored chunk around it is read."""
        index = self._position(frame_id)
        entry = self._entries[index]
        with reading(self.path, f"read message {index} of topic {self._topic.name!r}"):
            if self._reader is None:
                self._reader = open_backend(self.path, self._kind)
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
        return self._finish(self._sample(index, entry.log_time, matches[entry.rank]))

    def __iter__(self) -> Iterator[S]:
        """Stream every frame in one pass over the log."""
        backend = open_backend(self.path, self._kind)
        try:
            messages = backend.messages(self._topic.name)
            index = 0
            while True:
                with reading(self.path, f"read message {index} of topic {self._topic.name!r}"):
                    item = next(messages, None)
                if item is None:
                    return
                yield self._finish(self._sample(index, *item))
                index += 1
        finally:
            backend.close()

    @abstractmethod
    def _sample(self, index: int, log_time: int, raw: bytes | memoryview) -> S:
        """Message ``index`` (received at ``log_time`` ns) as a sample."""

    # -- resources ----------------------------------------------------------------------
    def close(self) -> None:
        """Close the reader kept open for :meth:`load` (it reopens when needed)."""
        reader, self._reader = self._reader, None
        if reader is not None:
            reader.close()

    def __enter__(self) -> Self:
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


class BagLog(TopicLog[Scene]):
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
        >>> from lidarfuzz.io.logs import write_log
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
        self.nonfinite: NonFinitePolicy = nonfinite
        super().__init__(path, topic, name=name)

    def _sample(self, index: int, log_time: int, raw: bytes | memoryview) -> Scene:
        encoding = self._topic.encoding
        store = typestore(encoding)
        where = f"topic {self._topic.name}, message {index}"
        try:
            if encoding == "ros1":
                msg = store.deserialize_ros1(raw, POINTCLOUD2)
            else:
                msg = store.deserialize_cdr(raw, POINTCLOUD2)
        except Exception as err:
            raise DataFormatError(self.path, f"{where}: cannot deserialize sensor_msgs/PointCloud2: {err}") from err
        stamp = int(msg.header.stamp.sec) * NS + int(msg.header.stamp.nanosec)
        time_ns = stamp if stamp else log_time
        seconds = time_ns / NS
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
