"""Small deterministic detectors for the adapter tests (importable as ``tests.suts.detectors:...``)."""

from __future__ import annotations

import os
import time

import numpy as np

from lidarfuzz.scene.scene import Scene


def centroid_detector(points: np.ndarray) -> tuple[np.ndarray, list[str], np.ndarray]:
    """One "Car" box around the above-ground points ahead (x 2–22 m, |y| < 4 m), OpenPCDet layout."""
    p = points[(points[:, 0] > 2) & (points[:, 0] < 22) & (np.abs(points[:, 1]) < 4) & (points[:, 2] > -1.3)]
    if len(p) < 20:
        return np.zeros((0, 7)), [], np.zeros(0)
    lo, hi = p[:, :3].min(axis=0), p[:, :3].max(axis=0)
    box = np.r_[(lo + hi) / 2, hi - lo + 0.1, 0.0][None, :]
    return box, ["Car"], np.array([min(1.0, len(p) / 500)])


def flaky(scene: Scene) -> object:
    """Crashes, hangs, dies or talks nonsense depending on the frame id's last digit."""
    mode = int(scene.frame_id[-1]) % 5 if scene.frame_id else 0
    if mode == 1:
        raise RuntimeError("segmentation of the cloud failed")
    if mode == 2:
        time.sleep(60)
    if mode == 3:
        os._exit(9)
    if mode == 4:
        return {"boxes": [[np.nan, 0, 0, 4, 2, 1.5, 0]], "labels": ["Car"], "scores": [0.5]}
    return centroid_detector(scene.points.data)


def behind_and_ahead(scene: Scene) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Two cars: 15 m behind the sensor and 15 m ahead."""
    boxes = np.array([[-15.0, 0.0, -0.9, 4.0, 1.7, 1.5, 0.0], [15.0, 0.0, -0.9, 4.0, 1.7, 1.5, 0.0]])
    return boxes, ["Car", "Car"], np.array([0.9, 0.8])
