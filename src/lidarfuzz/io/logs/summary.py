"""Summarising any log for ``lidarfuzz info``: its topics, time span and, for PointCloud2
topics, whether their definition is the standard one and the layout of their first message."""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.logs.backends import Backend, Topic, open_backend
from lidarfuzz.io.logs.containers import detect_kind, reading
from lidarfuzz.io.logs.messages import NS, POINTCLOUD2, typestore
from lidarfuzz.io.logs.pointcloud2 import DATATYPE_NAMES, field_of


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
    backend = open_backend(source, kind)
    try:
        with reading(source, "inspect the log"):
            topics = backend.topics()
            span = backend.time_range()
            count = backend.message_count()
        report: dict[str, Any] = {
            "path": str(source),
            "format": kind,
            "storage": backend.storage,
            "message_count": count,
            "start_time": None if span is None else span[0] / NS,
            "end_time": None if span is None else span[1] / NS,
            "duration": 0.0 if span is None else (span[1] - span[0]) / NS,
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


def _first_layout(path: Path, backend: Backend, topic: Topic) -> dict[str, Any]:
    with reading(path, f"read the first message of {topic.name!r}"):
        first = next(backend.messages(topic.name), None)
        if first is None:
            return {}
        store = typestore(topic.encoding)
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
