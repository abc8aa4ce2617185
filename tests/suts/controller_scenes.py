"""Hand-made frames for the controller's tests: a flat road 1.73 m under the sensor and boxes of points on it.

The road is a 0.5 m grid of points from 1 m to 29.5 m ahead and 10 m to either side (2,320 points
at z = -1.73); an obstacle is a block of points 0.1 m apart from 0.2 m to ``height`` above the road.
"""

from __future__ import annotations

import numpy as np

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

ROAD_Z = -1.73


def road() -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(1.0, 30.0, 0.5), np.arange(-10.0, 10.0, 0.5))
    return np.c_[xs.ravel(), ys.ravel(), np.full(xs.size, ROAD_Z)]


def block(x0: float, x1: float, y0: float, y1: float, height: float = 1.5) -> np.ndarray:
    """Points filling the box [x0, x1] × [y0, y1] × [0.2, height] above the road, 0.1 m apart."""
    xs, ys, zs = np.meshgrid(np.arange(x0, x1 + 1e-9, 0.1), np.arange(y0, y1 + 1e-9, 0.1),
                             np.arange(ROAD_Z + 0.2, ROAD_Z + height + 1e-9, 0.1))
    return np.c_[xs.ravel(), ys.ravel(), zs.ravel()]


def box_of(x0: float, x1: float, y0: float, y1: float, height: float = 1.5) -> list[float]:
    """The ground-truth box [x, y, z, l, w, h, yaw] of a block."""
    return [(x0 + x1) / 2, (y0 + y1) / 2, ROAD_Z + height / 2, x1 - x0, y1 - y0, height, 0.0]


def frame(*blocks: tuple[float, float, float, float], index: int = 0, labelled: bool = False,
          timestamp: float | None = None) -> Scene:
    """The road with the given blocks ``(x0, x1, y0, y1)`` on it (ground-truth boxes when ``labelled``)."""
    points = np.vstack([road(), *(block(*b) for b in blocks)])
    boxes = Boxes3D.empty()
    if labelled and blocks:
        boxes = Boxes3D.from_array(np.array([box_of(*b) for b in blocks]), ["Obstacle"] * len(blocks))
    return Scene(PointCloud(np.c_[points, np.zeros(len(points))]), boxes=boxes, frame_id=f"{index:06d}",
                 timestamp=timestamp)


def log(*frames_blocks: tuple[tuple[float, float, float, float], ...]) -> list[Scene]:
    """A log: one frame per tuple of blocks."""
    return [frame(*blocks, index=i) for i, blocks in enumerate(frames_blocks)]
