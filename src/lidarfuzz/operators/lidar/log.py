"""Log operators (Neves et al.): mutants built from, and inserted into, an ordered log of frames.

* :class:`FrameAverage` (AVG) combines two consecutive frames point by point.
  Correspondence: the range-image cell — a point's ``ring`` and its azimuth column
  (azimuth = atan2(y, x) binned into as many columns as the sensor fires per turn). A
  cell seen in both frames becomes one point, the average of the two (x, y, z and
  intensity; its other channels come from the first frame); a cell seen in one frame
  only keeps that frame's point. Boxes with the same track id are averaged (centre,
  size, heading on the circle); others are kept from the first frame. The combined
  frame's timestamp and pose are the two frames' midpoint.
  Without a ``ring`` channel in either frame (a folder of PCD files, a log converted without
  it) the correspondence is *mutual nearest neighbours* within ``radius`` metres (0.5 m by
  default; scipy's cKDTree): a point of the first frame and one of the second are a pair when
  each is the other's nearest point and they lie within the radius; pairs are averaged as
  matched cells are, every other point is kept from its frame. The combined frame's metadata
  says which correspondence was used (``frame_average_correspondence``: ``ring`` or ``nearest``).
* :func:`interleave` writes a new log: for a single-frame operator (e.g. HGT) each
  mutated frame right after its source; for AVG each combined frame between its two
  sources — the shapes of log Neves et al. feed to the system under test.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.operators.base import Operator, Relation, Target, generator
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


@dataclass(frozen=True)
class FrameAverage:
    """AVG: the point-wise average of two consecutive frames (see the module docstring).

    Attributes:
        columns: Azimuth columns per turn; ``None`` estimates it from the data as the
            largest number of points in one ring (a full ring of returns).
        radius: Without rings, the farthest apart (metres) two points may be to pair.
    """

    columns: int | None = None
    radius: float = 0.5
    name = "frame_average"
    aliases = ("AVG",)
    family = "log"
    relation = Relation.DEGRADING
    targets = frozenset({Target.POINTS, Target.BOXES})

    def cells(self, cloud: PointCloud, columns: int) -> NDArray[np.int64]:
        if not cloud.has("ring"):
            raise ValueError("frame_average needs a ring channel to match points of two frames")
        ring = cloud.channel("ring").astype(np.int64)
        azimuth = np.arctan2(cloud.xyz[:, 1], cloud.xyz[:, 0]).astype(np.float64)
        column = np.floor((azimuth + np.pi) / (2 * np.pi) * columns).astype(np.int64) % columns
        return ring * columns + column

    def column_count(self, *clouds: PointCloud) -> int:
        if self.columns is not None:
            return self.columns
        counts = [np.bincount(c.channel("ring").astype(np.int64)).max() for c in clouds if len(c) and c.has("ring")]
        return int(max(counts, default=1))

    def _cell_pairs(self, a: PointCloud, b: PointCloud) -> tuple[NDArray[np.intp], NDArray[np.intp],
                                                                  NDArray[np.bool_], NDArray[np.bool_]]:
        columns = self.column_count(a, b)
        cell_a, cell_b = self.cells(a, columns), self.cells(b, columns)
        # One point per cell and frame (the first in firing order), then match cells.
        ua, ia = np.unique(cell_a, return_index=True)
        ub, ib = np.unique(cell_b, return_index=True)
        common, ja, jb = np.intersect1d(ua, ub, assume_unique=True, return_indices=True)
        both_a, both_b = ia[ja], ib[jb]
        only_a = np.ones(len(a), bool)
        only_a[both_a] = False
        only_b = np.ones(len(b), bool)
        only_b[both_b] = False
        # Points sharing a cell with a matched one (duplicates in a cell) are dropped with it.
        only_a &= ~np.isin(cell_a, common)
        only_b &= ~np.isin(cell_b, common)
        return both_a, both_b, only_a, only_b

    def nearest_pairs(self, a: PointCloud, b: PointCloud) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Indices (into ``a``, into ``b``) of mutual nearest neighbours within :attr:`radius`.

        Points with a NaN or infinite coordinate have no neighbour (they are kept unpaired).
        """
        finite_a = np.flatnonzero(np.all(np.isfinite(a.xyz), axis=1))
        finite_b = np.flatnonzero(np.all(np.isfinite(b.xyz), axis=1))
        if not len(finite_a) or not len(finite_b):
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        from scipy.spatial import cKDTree

        xyz_a, xyz_b = a.xyz[finite_a], b.xyz[finite_b]
        distance, to_b = cKDTree(xyz_b).query(xyz_a, distance_upper_bound=self.radius)
        _, to_a = cKDTree(xyz_a).query(xyz_b, distance_upper_bound=self.radius)
        near = np.flatnonzero(np.isfinite(distance))
        mutual = near[to_a[to_b[near]] == near]
        return finite_a[mutual].astype(np.intp), finite_b[to_b[mutual]].astype(np.intp)

    def apply(self, first: Scene, second: Scene) -> Scene:
        a, b = first.points, second.points.conform(first.points.channels)
        if first.points.has("ring") and second.points.has("ring"):
            both_a, both_b, only_a, only_b = self._cell_pairs(a, b)
            correspondence = "ring"
        else:
            both_a, both_b = self.nearest_pairs(a, b)
            only_a = np.ones(len(a), bool)
            only_a[both_a] = False
            only_b = np.ones(len(b), bool)
            only_b[both_b] = False
            correspondence = "nearest"
        averaged = a.data[both_a].copy()
        averaged[:, :4] = (a.data[both_a, :4].astype(np.float64) + b.data[both_b, :4]) / 2
        data = np.concatenate([averaged, a.data[only_a], b.data[only_b]])
        points = PointCloud(data, a.channels)
        return first.replace(points=points, boxes=self._boxes(first, second), timestamp=_mid(first.timestamp,
                             second.timestamp), pose=_mid_pose(first.pose, second.pose),
                             frame_id=f"{first.frame_id}+{second.frame_id}",
                             metadata={**first.metadata, "frame_average": [first.frame_id, second.frame_id],
                                       "frame_average_correspondence": correspondence})

    @staticmethod
    def _boxes(first: Scene, second: Scene) -> Any:
        boxes, other = first.boxes, second.boxes
        if not len(boxes) or not len(other):
            return boxes
        centers, sizes, yaw = boxes.centers.copy(), boxes.sizes.copy(), boxes.yaw.copy()
        index = {int(t): i for i, t in enumerate(other.track_ids) if t >= 0}
        for i, track in enumerate(boxes.track_ids):
            j = index.get(int(track)) if track >= 0 else None
            if j is None or not boxes.has_geometry[i] or not other.has_geometry[j]:
                continue
            centers[i] = (centers[i] + other.centers[j]) / 2
            sizes[i] = (sizes[i] + other.sizes[j]) / 2
            yaw[i] = np.arctan2(np.sin(yaw[i]) + np.sin(other.yaw[j]), np.cos(yaw[i]) + np.cos(other.yaw[j]))
        return boxes.with_geometry(centers=centers, sizes=sizes, yaw=yaw)


def _mid(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else (a + b) / 2


def _mid_pose(a: NDArray[np.float64] | None, b: NDArray[np.float64] | None) -> NDArray[np.float64] | None:
    if a is None or b is None:
        return None
    out = np.eye(4)
    out[:3, 3] = (a[:3, 3] + b[:3, 3]) / 2
    yaw = np.arctan2(np.sin(np.arctan2(a[1, 0], a[0, 0])) + np.sin(np.arctan2(b[1, 0], b[0, 0])),
                     np.cos(np.arctan2(a[1, 0], a[0, 0])) + np.cos(np.arctan2(b[1, 0], b[0, 0])))
    out[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    return out


def interleave(frames: Iterable[Scene], operator: Operator[Scene, Any, Any] | FrameAverage, *, seed: int = 0,
               ) -> Iterator[Scene]:
    """A new log with mutants inserted: after each source frame for a single-frame operator
    (timestamp + 1 µs, so the order is kept), between each pair for :class:`FrameAverage`."""
    previous: Scene | None = None
    for index, frame in enumerate(frames):
        if isinstance(operator, FrameAverage):
            if previous is not None:
                yield operator.apply(previous, frame)
            yield frame
            previous = frame
            continue
        yield frame
        mutant, _ = operator(frame, generator(seed, frame.frame_id or index, 0, 0))
        stamp = None if frame.timestamp is None else frame.timestamp + 1e-6
        yield mutant.replace(frame_id=f"{frame.frame_id}m", timestamp=stamp)
