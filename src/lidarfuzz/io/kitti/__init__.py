"""The KITTI object layout: ``velodyne/``, ``label_2/``, ``calib/``, ``image_2/``, ``ImageSets/``.

Layout (``root`` may also contain ``training/`` and ``testing/`` with this inside)::

    root/velodyne/000000.bin        N×4 float32 x, y, z, reflectance
    root/label_2/000000.txt         one object per line (camera frame; score optional)
    root/calib/000000.txt           P0–P3, R0_rect, Tr_velo_to_cam, Tr_imu_to_velo
    root/image_2/000000.png         optional; only its size is read
    root/ImageSets/{train,val}.txt  optional frame-id lists

lidarfuzz adds side files that plain KITTI tools ignore:

    root/velodyne_extra/000000.npz  point channels beyond x, y, z, intensity (ring, time, ...)
    root/roi/000000.json            drivable-area polygons (GeoJSON, LiDAR frame)
    root/label_2_extra/000000.json  per-object fields KITTI labels lack ({"track_ids": [...], "objects":
                                    {"num_points": [...], ...}}, one entry per label line)
    root/timestamps.txt             "<frame_id> <seconds>" per line: the data set is a log
    root/poses.txt                  "<frame_id> <12 numbers>" per line: 3×4 LiDAR → world
    root/ego.txt                    "<frame_id> speed yaw_rate curvature steering" per line (simulator
                                    logs; "#" lines are comments): in each frame's metadata under those names

One module per job: :mod:`~lidarfuzz.io.kitti.labels` reads and writes label lines (their
format is described there), :mod:`~lidarfuzz.io.kitti.dataset` opens a folder as a data set
or a log, and :mod:`~lidarfuzz.io.kitti.writer` writes one.
"""

from lidarfuzz.io.kitti.dataset import (
    KittiDataset,
    KittiLog,
    find_kitti_root,
    open_kitti,
    png_size,
    unlabelled_note,
)
from lidarfuzz.io.kitti.labels import KITTI_CLASSES, LABEL_FIELDS, format_labels, parse_labels, read_label_file
from lidarfuzz.io.kitti.writer import KittiWriter, compact_channel, write_kitti, write_kitti_frame

__all__ = [
    "KITTI_CLASSES",
    "LABEL_FIELDS",
    "KittiDataset",
    "KittiLog",
    "KittiWriter",
    "compact_channel",
    "find_kitti_root",
    "format_labels",
    "open_kitti",
    "parse_labels",
    "png_size",
    "read_label_file",
    "unlabelled_note",
    "write_kitti",
    "write_kitti_frame",
]
