"""Helpers shared by the camera operators: the sample type, its targets, and affine warping of a
frame's pixels, depth map and camera matrix together."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from lidarfuzz.operators.base import Target
from lidarfuzz.scene.image import ImageSample

Range = tuple[float, float]
IMAGE = frozenset({Target.IMAGE})
#: The modality every operator of this package declares.
CAMERA = "camera"


def table_pairs(values: list[float]) -> dict[int, Range]:
    """Severity s → the interval from the (2s−1)-th to the 2s-th of Table 4's ten values (mildest first),
    as a sorted ``(low, high)``."""
    if len(values) != 10:
        raise ValueError(f"Table 4 has ten values per transformation, got {len(values)}")
    return {s: (min(values[2 * s - 2], values[2 * s - 1]), max(values[2 * s - 2], values[2 * s - 1]))
            for s in range(1, 6)}


def warp_affine(sample: ImageSample, matrix: NDArray[np.float64]) -> ImageSample:
    """``sample`` moved by the forward 2×3 pixel map ``matrix`` (source pixel → output pixel).

    Pixels: :func:`cv2.warpAffine` with bilinear interpolation (``INTER_LINEAR``) and a constant
    black border (``BORDER_CONSTANT``, 0): what the output does not cover from the input is black,
    as DeepTest's OpenCV calls give. A shift by whole pixels samples nearest neighbours
    (``INTER_NEAREST``), which gives the same pixels as bilinear there at a quarter of the cost.
    The depth map moves with the pixels by nearest-neighbour sampling (no depth is invented
    between a car and the road behind it), ``inf`` where uncovered.
    The camera matrix becomes ``A·K`` (A the 3×3 form of ``matrix``), so ``K⁻¹`` still gives each new
    pixel its ray (after a shear or a rotation K is no longer upper triangular). Everything else —
    steering label, frame id, pose, metadata — is kept.
    """
    height, width = sample.shape
    m = np.asarray(matrix, dtype=np.float64)
    whole_shift = np.array_equal(m[:, :2], np.eye(2)) and np.array_equal(m[:, 2], np.round(m[:, 2]))
    if whole_shift:
        image = cv2.warpAffine(np.ascontiguousarray(sample.image), m, (width, height), flags=cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
    else:
        # OpenCV's bilinear warp of 4-channel pixels is vectorised better than of 3-channel ones: with
        # the two conversions the same pixels come out a quarter faster
        rgba = cv2.warpAffine(cv2.cvtColor(np.ascontiguousarray(sample.image), cv2.COLOR_RGB2RGBA), m,
                              (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=(0, 0, 0, 0))
        image = cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB)
    depth = None
    if sample.depth is not None:
        depth = cv2.warpAffine(np.ascontiguousarray(sample.depth), m, (width, height), flags=cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=float("inf"))
    intrinsics = None
    if sample.intrinsics is not None:
        intrinsics = np.vstack([m, [0.0, 0.0, 1.0]]) @ sample.intrinsics
    return sample.replace(image=image, depth=depth, intrinsics=intrinsics)
