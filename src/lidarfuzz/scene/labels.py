"""KITTI label fields of a 3D box seen by the camera: truncation, 2D box, alpha, occlusion level.

One definition for everything that writes labels — the simulator when it renders a frame,
the operators when they move a scene or an object or insert one — so a box's label means the
same whichever made it, and the devkit's difficulty filter (truncation ≤ 0.15 / 0.3 / 0.5,
occlusion, 2D box height) treats them alike:

* **truncation** = the share of the box's volume (a 5×5×5 grid of samples) that projects
  outside the image or lies behind the camera; 1 for a box with no area in the image;
* **2D box** = the devkit's: the projected 8 corners' extent clipped to the image, for a box
  wholly in front of the camera; for a box across the camera plane, the clipped extent of its
  in-front volume samples; NaN (no 2D box) when the box has no area in the image;
* **alpha** = the observation angle, as the devkit's tooling computes it;
* **occlusion** = KITTI's level from the visible share of the object.

Example:
    >>> from lidarfuzz.scene.calib import KittiCalibration
    >>> calib = KittiCalibration.default()
    >>> fields = camera_labels(calib, np.array([[10.0, 0.0, -0.9, 3.9, 1.6, 1.5, 0.0]]))
    >>> float(fields.truncation[0]), bool(np.isfinite(fields.bbox2d).all())
    (0.0, True)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.geometry import box_corners

F64 = NDArray[np.float64]

#: Volume samples of a box, in units of its size (5 per axis, the faces' 5 % margin left out).
VOLUME_SAMPLES: F64 = np.stack(np.meshgrid(*[np.linspace(-0.45, 0.45, 5)] * 3, indexing="ij"),
                               axis=-1).reshape(-1, 3)
#: Depth (m) in front of the camera below which a point counts as behind it.
MIN_DEPTH = 0.1


def occlusion_level(visibility: ArrayLike) -> NDArray[np.int64]:
    """KITTI occlusion state from the visible share of an object (≥ 0.8 → 0 fully visible,
    ≥ 0.4 → 1 partly occluded, else 2 largely occluded)."""
    v = np.asarray(visibility, np.float64)
    return np.where(v >= 0.8, 0, np.where(v >= 0.4, 1, 2)).astype(np.int64)


def _coverage(calib: KittiCalibration, b: F64) -> tuple[F64, F64, NDArray[np.bool_]]:
    """Share of each box's volume samples (``b`` M×7, M ≥ 1) that project into the image, with the
    samples' pixels (M×125×2) and which lie in front of the camera (M×125)."""
    n = len(b)
    c, s = np.cos(b[:, 6]), np.sin(b[:, 6])
    local = VOLUME_SAMPLES[None, :, :] * b[:, None, 3:6]  # n × 125 × 3
    world = np.empty_like(local)
    world[..., 0] = c[:, None] * local[..., 0] - s[:, None] * local[..., 1] + b[:, None, 0]
    world[..., 1] = s[:, None] * local[..., 0] + c[:, None] * local[..., 1] + b[:, None, 1]
    world[..., 2] = local[..., 2] + b[:, None, 2]
    uv, depth = calib.rect_to_image(calib.lidar_to_rect(world.reshape(-1, 3)))
    uv, depth = uv.reshape(n, -1, 2), depth.reshape(n, -1)
    height, width = calib.image_shape
    front = depth > MIN_DEPTH
    with np.errstate(invalid="ignore"):
        inside = front & (uv[..., 0] >= 0) & (uv[..., 0] < width) & (uv[..., 1] >= 0) & (uv[..., 1] < height)
    return inside.mean(axis=1), uv, front


def image_coverage(calib: KittiCalibration, boxes: ArrayLike) -> tuple[F64, list[F64]]:
    """Share of each box's volume samples that project into the image, and the pixels of each
    box's samples in front of the camera (for the 2D box of a box across the camera plane)."""
    b = np.asarray(boxes, np.float64).reshape(-1, 7)
    if len(b) == 0:
        return np.zeros(0), []
    share, uv, front = _coverage(calib, b)
    return share, [uv[i][front[i]] for i in range(len(b))]


def _boxes_2d(calib: KittiCalibration, b: F64, front_pixels: Callable[[int], F64]) -> F64:
    """:func:`image_boxes` of ``b`` (M×7), ``front_pixels(i)`` giving box i's in-front sample
    pixels — asked only for the boxes across the camera plane (few), so the others' are never
    gathered."""
    n = len(b)
    out = np.full((n, 4), np.nan)
    if n == 0:
        return out
    # only the corners' depth is needed here (the rectified z): the devkit's 2D box below
    # projects its own corners through P2, so these are not projected to pixels too
    depth = calib.lidar_to_rect(box_corners(b).reshape(-1, 3))[:, 2]
    in_front = np.all(depth.reshape(n, 8) > MIN_DEPTH, axis=1)
    if in_front.any():
        out[in_front] = calib.boxes_to_image(b[in_front])
    height, width = calib.image_shape
    for i in np.flatnonzero(~in_front):  # a loop over boxes (few), not points
        pixels = front_pixels(int(i))
        if len(pixels):
            lo, hi = pixels.min(axis=0), pixels.max(axis=0)
            out[i] = [np.clip(lo[0], 0, width - 1), np.clip(lo[1], 0, height - 1),
                      np.clip(hi[0], 0, width - 1), np.clip(hi[1], 0, height - 1)]
    with np.errstate(invalid="ignore"):
        flat = ~((out[:, 2] > out[:, 0]) & (out[:, 3] > out[:, 1]))
    out[flat] = np.nan
    return out


def image_boxes(calib: KittiCalibration, boxes: ArrayLike, front_uv: list[F64]) -> F64:
    """2D boxes ``[x1, y1, x2, y2]``: the devkit's (projected corners, clipped) for boxes wholly in
    front of the camera; for the others, the clipped extent of their in-front volume samples
    (``front_uv`` from :func:`image_coverage`); NaN where the clipped box has no area — a box
    beside the image would otherwise get a zero-width box the devkit still counts."""
    return _boxes_2d(calib, np.asarray(boxes, np.float64).reshape(-1, 7), front_uv.__getitem__)


@dataclass(frozen=True)
class CameraLabels:
    """Label fields of boxes seen by the camera (one row per box)."""

    truncation: F64  # rounded to 0.01, as the simulator writes it
    bbox2d: F64  # N×4, NaN outside the image
    alpha: F64
    inside: F64  # unrounded share of the volume samples in the image

    @property
    def in_image(self) -> NDArray[np.bool_]:
        """Boxes with some area in the image (the others get truncation 1 and no 2D box)."""
        return np.all(np.isfinite(self.bbox2d), axis=1)


def camera_labels(calib: KittiCalibration, boxes: ArrayLike) -> CameraLabels:
    """Truncation, 2D box and alpha of LiDAR-frame boxes (M×7) as the simulator labels them.

    A box with no area in the image (beside it, or behind the camera) is outside: truncation 1,
    no 2D box. KITTI labels exist only in the camera's view, so the devkit then ignores it at
    every difficulty instead of counting a box no camera-based label could have."""
    b = np.asarray(boxes, np.float64).reshape(-1, 7)
    if len(b) == 0:
        inside, bbox2d = np.zeros(0), np.full((0, 4), np.nan)
    else:
        inside, uv, front = _coverage(calib, b)
        bbox2d = _boxes_2d(calib, b, lambda i: uv[i][front[i]])
    truncation = np.clip(1.0 - inside, 0.0, 1.0).round(2)
    truncation[~np.isfinite(bbox2d).all(axis=1)] = 1.0
    return CameraLabels(truncation=truncation, bbox2d=bbox2d, alpha=calib.alpha(b), inside=inside)


__all__ = ["MIN_DEPTH", "VOLUME_SAMPLES", "CameraLabels", "camera_labels", "image_boxes", "image_coverage",
           "occlusion_level"]
