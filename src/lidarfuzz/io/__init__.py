"""Reading and writing every data format users have, and data sets built on them.

Entry points: :func:`open_dataset` (a KITTI folder, a folder of frames, a frame
file, a ROS1/ROS2 bag or an MCAP file), :func:`read_frame` / :func:`write_frame`
(single files by suffix), :func:`write_kitti` (a data set in KITTI layout) and
:func:`lidarfuzz.io.logs.write_log` (a bag or MCAP log).
"""

from lidarfuzz.io.common import NonFiniteWarning, Problem
from lidarfuzz.io.dataset import Dataset, Log
from lidarfuzz.io.frames import FrameFolder, SingleFrame, read_frame, write_frame
from lidarfuzz.io.kitti import KittiDataset, KittiLog, KittiWriter, write_kitti
from lidarfuzz.io.open import open_dataset

__all__ = [
    "Dataset",
    "FrameFolder",
    "KittiDataset",
    "KittiLog",
    "KittiWriter",
    "Log",
    "NonFiniteWarning",
    "Problem",
    "SingleFrame",
    "open_dataset",
    "read_frame",
    "write_frame",
    "write_kitti",
]
