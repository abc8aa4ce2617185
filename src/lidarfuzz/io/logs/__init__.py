"""Recorded logs: ROS 1 bags, ROS 2 bags (sqlite3 or mcap storage) and MCAP files.

Point clouds travel as ``sensor_msgs/PointCloud2`` messages;
:mod:`lidarfuzz.io.logs.pointcloud2` converts their point data and
:mod:`lidarfuzz.io.logs.bags` reads and writes the containers.
"""

from lidarfuzz.io.logs.bags import BagLog, LogKind, detect_kind, inspect_bag, write_log
from lidarfuzz.io.logs.pointcloud2 import PointField, decode, encode

__all__ = [
    "BagLog",
    "LogKind",
    "PointField",
    "decode",
    "detect_kind",
    "encode",
    "inspect_bag",
    "write_log",
]
