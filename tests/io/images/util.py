"""Tiny image files for the camera readers' tests (written with OpenCV, so the readers' decoding is
checked against an independent encoder)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

#: A 2×3 RGB image whose every pixel differs and whose channels differ (RGB vs BGR shows).
PIXELS = np.array([[[200, 100, 50], [10, 20, 30], [0, 0, 255]],
                   [[255, 0, 0], [0, 255, 0], [1, 2, 3]]], dtype=np.uint8)


def write_png(path: Path, rgb: NDArray[np.uint8] = PIXELS) -> Path:
    """``rgb`` as a PNG (OpenCV writes BGR: the channels are reversed here)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]))
    return path


def solid(height: int, width: int, rgb: tuple[int, int, int]) -> NDArray[np.uint8]:
    """One colour everywhere (a JPEG keeps a flat colour to within a few levels)."""
    return np.broadcast_to(np.array(rgb, dtype=np.uint8), (height, width, 3)).copy()


def write_jpeg(path: Path, rgb: NDArray[np.uint8]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 95])
    return path


def png_bytes(rgb: NDArray[np.uint8] = PIXELS) -> bytes:
    ok, buffer = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    assert ok
    return buffer.tobytes()


def jpeg_bytes(rgb: NDArray[np.uint8]) -> bytes:
    ok, buffer = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return buffer.tobytes()
