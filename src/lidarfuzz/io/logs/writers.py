"""Writing scenes as one ``sensor_msgs/PointCloud2`` topic of a new ROS 1 bag, ROS 2 bag or
MCAP file (:func:`write_log`).

Only the points, the timestamp and the sensor frame id of a scene are written (boxes,
calibration and metadata are not); ROS 2 bags are written with metadata version 8, which
ROS 2 Iron and later read (for Humble, write ``.mcap`` and play the file).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from fractions import Fraction
from os import PathLike
from pathlib import Path
from typing import Any, Literal

import numpy as np

from lidarfuzz import __version__
from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import check_destination
from lidarfuzz.io.logs.containers import LogKind
from lidarfuzz.io.logs.messages import NS, POINTCLOUD2, typestore
from lidarfuzz.io.logs.pointcloud2 import encode
from lidarfuzz.scene.scene import Scene

Ros2Storage = Literal["sqlite3", "mcap"]
_DEFAULT_PERIOD_NS = 100_000_000  # frames without a timestamp are written 0.1 s apart


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
        raise _unstorable(scene, index, f"timestamp {seconds} cannot be stored in a log (it must be finite and not "
                          "negative)")
    return round(Fraction(seconds) * NS)


def _unstorable(scene: Scene, index: int, message: str) -> DataFormatError:
    """A scene's timestamp a log cannot hold, as a DataFormatError naming the file the scene was read from
    (a ValueError, as before): the data's fault, said in one line, not a traceback."""
    source = scene.metadata.get("source") or f"<scene {index}>"
    return DataFormatError(str(source), f"scene {index} (frame {scene.frame_id!r}): {message}", field="timestamp")


def _frames(scenes: Iterable[Scene], limit_sec: int) -> Iterator[tuple[int, int, int, dict[str, Any]]]:
    """``(index, log time ns, stamp ns, encoded cloud)``; log times never go back, so order is kept."""
    previous = 0
    for index, scene in enumerate(scenes):
        if not isinstance(scene, Scene):
            raise TypeError(f"scene {index} is a {type(scene).__name__}, not a Scene")
        stamp = index * _DEFAULT_PERIOD_NS if scene.timestamp is None else _to_ns(scene.timestamp, index, scene)
        if stamp // NS >= limit_sec:
            raise _unstorable(scene, index, f"timestamp {stamp / NS} s is too large for this log kind (at most "
                              f"{limit_sec:,} s)")
        log_time = max(stamp, previous)
        previous = log_time
        yield index, log_time, stamp, encode(scene.points)


def _message(store: Any, ros1: bool, encoded: dict[str, Any], stamp: int, frame_id: str, seq: int) -> Any:
    types = store.types
    time = types["builtin_interfaces/msg/Time"](sec=stamp // NS, nanosec=stamp % NS)
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
    # rosbags is slow to import: loaded only when a log is touched
    from rosbags.rosbag1 import Writer

    store = typestore("ros1")
    with Writer(out) as writer:
        connection = writer.add_connection(topic, POINTCLOUD2, typestore=store)
        for index, log_time, stamp, encoded in _frames(scenes, 2**31):
            msg = _message(store, True, encoded, stamp, frame_id, index)
            writer.write(connection, log_time, store.serialize_ros1(msg, POINTCLOUD2))


def _write_ros2(out: Path, scenes: Iterable[Scene], topic: str, frame_id: str, storage: Ros2Storage) -> None:
    # rosbags is slow to import: loaded only when a log is touched
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
    store = typestore("cdr")
    with Writer(out, version=8, storage_plugin=plugin) as writer:
        connection = writer.add_connection(topic, POINTCLOUD2, typestore=store)
        for index, log_time, stamp, encoded in _frames(scenes, 2**31):
            msg = _message(store, False, encoded, stamp, frame_id, index)
            writer.write(connection, log_time, store.serialize_cdr(msg, POINTCLOUD2))


def _write_mcap(out: Path, scenes: Iterable[Scene], topic: str, frame_id: str) -> None:
    # mcap is slow to import: loaded only when a log is touched
    from mcap.writer import CompressionType, Writer

    store = typestore("cdr")
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
