"""The data model: point clouds, boxes, calibration, drivable-area maps and scenes."""

from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.geometry import (
    bev_corners,
    box_corners,
    box_index_of_points,
    iou_3d,
    iou_bev,
    points_in_boxes,
)
from lidarfuzz.scene.points import OPTIONAL_CHANNELS, STANDARD_CHANNELS, PointCloud
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Sample, Scene

__all__ = [
    "OPTIONAL_CHANNELS",
    "STANDARD_CHANNELS",
    "Boxes3D",
    "KittiCalibration",
    "PointCloud",
    "RoiMap",
    "Sample",
    "Scene",
    "bev_corners",
    "box_corners",
    "box_index_of_points",
    "iou_3d",
    "iou_bev",
    "points_in_boxes",
    "wrap_angle",
]
