"""One frame of sensor data with its ground truth: the unit every layer works on.

:class:`Sample` is what every modality shares (a frame id, a timestamp, an ego pose,
metadata), so that data sets, logs, operators, systems under test and relations can
be written for camera frames too; :class:`Scene` is the LiDAR sample.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.points import PointCloud, frozen
from lidarfuzz.scene.roi import RoiMap


@runtime_checkable
class Sample(Protocol):
    """What every frame of every modality has."""

    @property
    def frame_id(self) -> str: ...

    @property
    def timestamp(self) -> float | None: ...

    @property
    def pose(self) -> NDArray[np.float64] | None: ...

    @property
    def metadata(self) -> Mapping[str, Any]: ...


@dataclass(frozen=True, eq=False)
class Scene:
    """A LiDAR frame: points, ground-truth boxes, calibration, map and provenance.

    Attributes:
        points: The cloud (N×C float32, named channels).
        boxes: Ground-truth boxes in the LiDAR frame (empty when unlabelled).
        calib: KITTI calibration, when the frame has a camera.
        frame_id: Stable id within its data set (e.g. ``"000042"``).
        timestamp: Seconds: the frame's reference instant (the simulator, like KITTI, uses the
            instant the spinning head faces forward); ``None`` when unknown.
        pose: 4×4 LiDAR → world transform for frames of a log; ``None`` when unknown.
        roi: Drivable-area polygons in the LiDAR frame (the HD-map ROI), if known.
        metadata: JSON-able provenance (source file, sensor, notes from readers).

    Example:
        >>> scene = Scene(PointCloud(np.zeros((2, 4))), frame_id="000001")
        >>> scene.replace(timestamp=1.5).timestamp
        1.5
    """

    points: PointCloud
    boxes: Boxes3D = field(default_factory=Boxes3D.empty)
    calib: KittiCalibration | None = None
    frame_id: str = ""
    timestamp: float | None = None
    pose: NDArray[np.float64] | None = None
    roi: RoiMap | None = None
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.points, PointCloud):
            raise TypeError(f"points must be a PointCloud, got {type(self.points).__name__}")
        if self.pose is not None:
            pose = np.asarray(self.pose, dtype=np.float64)
            if pose.shape != (4, 4):
                raise ValueError(f"pose must be a 4×4 matrix, got shape {pose.shape}")
            object.__setattr__(self, "pose", frozen(pose))
        if self.timestamp is not None:
            object.__setattr__(self, "timestamp", float(self.timestamp))
        object.__setattr__(self, "metadata", dict(self.metadata))

    def replace(self, **changes: Any) -> Scene:
        """A new scene with some fields replaced (the original is untouched)."""
        return dataclasses.replace(self, **changes)

    def with_points(self, points: PointCloud | ArrayLike) -> Scene:
        if not isinstance(points, PointCloud):
            points = self.points.with_data(points)
        return self.replace(points=points)

    def __len__(self) -> int:
        return len(self.points)

    def __repr__(self) -> str:
        return (
            f"Scene(frame_id={self.frame_id!r}, points={len(self.points)}, "
            f"channels={self.points.channels}, boxes={len(self.boxes)})"
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Scene):
            return NotImplemented
        same_pose = (self.pose is None and other.pose is None) or (
            self.pose is not None and other.pose is not None and np.array_equal(self.pose, other.pose)
        )
        return (
            self.points == other.points
            and self.boxes == other.boxes
            and self.calib == other.calib
            and self.frame_id == other.frame_id
            and self.timestamp == other.timestamp
            and same_pose
            and self.roi == other.roi
            and dict(self.metadata) == dict(other.metadata)
        )

    __hash__ = None  # type: ignore[assignment]
