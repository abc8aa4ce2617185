"""Recorded logs: ROS 1 bags, ROS 2 bags and MCAP files carrying ``sensor_msgs/PointCloud2``.

Supported containers, read and written:

========= ============================================================ ====================
``ros1``  ROS 1 bag, format 2.0 (``.bag``; uncompressed, bz2 or lz4)  ``rosbags.rosbag1``
``ros2``  ROS 2 bag directory (``metadata.yaml`` + sqlite3 or mcap     ``rosbags.rosbag2``
          storage; zstd file/message compression is read)
``mcap``  a plain ``.mcap`` file, ROS 2 (``cdr``) messages; ``ros1``   ``mcap``
          encoded channels are read too
========= ============================================================ ====================

One module per job:

* :mod:`~lidarfuzz.io.logs.pointcloud2` converts PointCloud2 point data ⇄ point clouds;
* :mod:`~lidarfuzz.io.logs.messages`: the PointCloud2 message type, its reference
  definitions and the checks that a log's definition is the standard one;
* :mod:`~lidarfuzz.io.logs.containers`: what a path holds (:func:`detect_kind`), and
  reader-library errors turned into errors naming the file;
* :mod:`~lidarfuzz.io.logs.backends`: the two reader libraries behind one interface;
* :mod:`~lidarfuzz.io.logs.reader`: :class:`BagLog`, one topic as a log of scenes;
* :mod:`~lidarfuzz.io.logs.summary`: :func:`inspect_bag`, for ``lidarfuzz info``;
* :mod:`~lidarfuzz.io.logs.writers`: :func:`write_log`, ROS 1, ROS 2 and MCAP writers.
"""

from lidarfuzz.io.logs.containers import LogKind, detect_kind
from lidarfuzz.io.logs.pointcloud2 import PointField, decode, encode
from lidarfuzz.io.logs.reader import BagLog
from lidarfuzz.io.logs.summary import inspect_bag
from lidarfuzz.io.logs.writers import write_log

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
