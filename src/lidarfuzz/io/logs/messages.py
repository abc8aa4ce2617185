"""The ``sensor_msgs/PointCloud2`` message in ROS 1 and ROS 2 logs: its names, the reference
type stores, checks that a log's definition is the standard one, and its header stamp.

A topic whose type is called ``sensor_msgs/PointCloud2`` but whose definition differs from
the standard one is refused by the reader, because its bytes cannot be trusted to mean what
the standard layout says; :func:`definition_difference` says why it differs.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from functools import cache
from typing import Any

from lidarfuzz.io.guards import describe

#: The normalised (ROS 2 style) name of the point-cloud message type.
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
#: md5sum of the standard ROS 1 ``sensor_msgs/PointCloud2`` definition.
ROS1_POINTCLOUD2_MD5 = "1158d486dd51d683ce2f1be655c3c181"
#: Nanoseconds per second (log times and stamps are integer nanoseconds).
NS = 1_000_000_000
_DEFINITION_TYPES = (
    POINTCLOUD2,
    "sensor_msgs/msg/PointField",
    "std_msgs/msg/Header",
    "builtin_interfaces/msg/Time",
)


@cache
def typestore(encoding: str) -> Any:
    """The reference typestore for a message encoding (``ros1`` → Noetic, ``cdr`` → Humble)."""
    # rosbags is slow to import: loaded only when a log is touched
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if encoding == "ros1" else Stores.ROS2_HUMBLE)


def normalize_msgtype(name: str) -> str:
    # rosbags is slow to import: loaded only when a log is touched
    from rosbags.typesys.msg import normalize_msgtype

    return normalize_msgtype(name) if name else name


def _parse_definition(text: str, fmt: str) -> dict[str, Any]:
    """Type definitions from a message definition text (``msg`` or ``idl`` format)."""
    # rosbags is slow to import: loaded only when a log is touched
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
        return f"its definition cannot be parsed ({describe(err)})"
    reference = typestore(encoding).fielddefs
    if POINTCLOUD2 not in types:
        return f"its definition does not define {POINTCLOUD2}"
    for name in _DEFINITION_TYPES:
        if name not in types or name not in reference:
            continue
        have, want = list(types[name][1]), list(reference[name][1])
        if have != want:
            return f"{name} has fields ({_describe_fields(have)}); the standard has ({_describe_fields(want)})"
    return None



def header_stamp(raw: bytes | memoryview, encoding: str) -> int:
    """The header stamp (ns) read straight from a serialised PointCloud2, without decoding it."""
    if encoding == "ros1":
        _, sec, nanosec = struct.unpack_from("<III", raw, 0)  # seq, stamp.sec, stamp.nsec
    else:
        little = raw[1] & 1  # CDR encapsulation: 0x0001 = CDR_LE, 0x0000 = CDR_BE
        sec, nanosec = struct.unpack_from("<iI" if little else ">iI", raw, 4)
    return int(sec) * NS + int(nanosec)
