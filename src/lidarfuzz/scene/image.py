"""One camera frame with its label: the sample of the camera modality.

:class:`ImageSample` is to camera readers, image transformations, steering systems and the
camera task what :class:`~lidarfuzz.scene.scene.Scene` is to the LiDAR ones. It satisfies the
:class:`~lidarfuzz.scene.scene.Sample` protocol (frame id, timestamp, pose, metadata), so logs,
stores and reports treat both modalities alike.

Conventions (every reader, the renderer and every transformation keep them):

* ``image`` is H×W×3 ``uint8`` in **RGB** order (OpenCV's functions take BGR; code that calls
  them converts or, for channel-independent maths, does not care), read-only;
* ``steering`` is the label in the data set's own units; the built-in world writes the
  front-wheel angle in radians, left positive (a kinematic bicycle model,
  :func:`lidarfuzz.sim.motion.steering_angle`); the Udacity data sets record the steering-wheel
  angle in radians, left positive;
* ``depth`` is the z-depth in metres along the optical axis per pixel, ``inf`` where nothing was
  hit (sky), ``nan`` where unknown; None when the sample has none (a photo);
* ``intrinsics`` is the 3×3 pinhole matrix K of ``image`` (None when unknown).

Example:
    >>> sample = ImageSample(np.zeros((2, 3, 3), np.uint8), frame_id="000001", steering=0.1)
    >>> sample.shape, sample.replace(steering=-0.1).steering
    ((2, 3), -0.1)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.scene.points import frozen


@dataclass(frozen=True, eq=False)
class ImageSample:
    """A camera frame: pixels, its steering label, optional per-pixel depth and camera matrix.

    Attributes:
        image: H×W×3 uint8 RGB (read-only).
        frame_id: Stable id within its data set.
        steering: The label (see the module docstring for units); None when unlabelled.
        depth: H×W float32 z-depth in metres (``inf``: sky, ``nan``: unknown), or None.
        intrinsics: 3×3 float64 camera matrix K, or None.
        timestamp: Seconds, or None.
        pose: 4×4 camera → world transform for frames of a log, or None.
        metadata: JSON-able provenance (source file, CSV row, speed, …).
    """

    image: NDArray[np.uint8]
    frame_id: str = ""
    steering: float | None = None
    depth: NDArray[np.float32] | None = None
    intrinsics: NDArray[np.float64] | None = None
    timestamp: float | None = None
    pose: NDArray[np.float64] | None = None
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        image = np.asarray(self.image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"image must be H×W×3 uint8 RGB, got {image.dtype} of shape {image.shape}")
        object.__setattr__(self, "image", frozen(image))
        if self.depth is not None:
            depth = np.asarray(self.depth, dtype=np.float32)
            if depth.shape != image.shape[:2]:
                raise ValueError(f"depth must be H×W {image.shape[:2]}, got shape {depth.shape}")
            object.__setattr__(self, "depth", frozen(depth))
        for name, shape in (("intrinsics", (3, 3)), ("pose", (4, 4))):
            value = getattr(self, name)
            if value is not None:
                matrix = np.asarray(value, dtype=np.float64)
                if matrix.shape != shape:
                    raise ValueError(f"{name} must be a {shape[0]}×{shape[1]} matrix, got shape {matrix.shape}")
                object.__setattr__(self, name, frozen(matrix))
        if self.steering is not None:
            object.__setattr__(self, "steering", float(self.steering))
        if self.timestamp is not None:
            object.__setattr__(self, "timestamp", float(self.timestamp))
        object.__setattr__(self, "metadata", dict(self.metadata))

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) in pixels."""
        return int(self.image.shape[0]), int(self.image.shape[1])

    def replace(self, **changes: Any) -> ImageSample:
        """A new sample with some fields replaced (the original is untouched)."""
        return dataclasses.replace(self, **changes)

    def with_image(self, image: NDArray[np.uint8], depth: NDArray[np.float32] | None = None) -> ImageSample:
        """The same frame with new pixels; ``depth`` replaces the depth map (None drops it when the
        new image's size differs, since the old map no longer lines up)."""
        keep = depth if depth is not None else (self.depth if image.shape[:2] == self.image.shape[:2] else None)
        return self.replace(image=image, depth=keep)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ImageSample):
            return NotImplemented

        def same(a: NDArray[Any] | None, b: NDArray[Any] | None) -> bool:
            if a is None or b is None:
                return a is None and b is None
            return bool(np.array_equal(a, b, equal_nan=True))

        return (np.array_equal(self.image, other.image) and self.frame_id == other.frame_id
                and self.steering == other.steering and same(self.depth, other.depth)
                and same(self.intrinsics, other.intrinsics) and self.timestamp == other.timestamp
                and same(self.pose, other.pose) and dict(self.metadata) == dict(other.metadata))

    __hash__ = None  # type: ignore[assignment]

    def __len__(self) -> int:
        return self.shape[0] * self.shape[1]

    def __repr__(self) -> str:
        return f"ImageSample(frame_id={self.frame_id!r}, shape={self.shape}, steering={self.steering})"
