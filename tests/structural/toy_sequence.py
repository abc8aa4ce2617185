"""A small sequence system whose rarely taken branches need high points, and a flat log to search
from (``tests.structural.toy_sequence:HeightLadder``).

Each frame climbs a ladder by the mean height of its points: above 0.25 m (``low``), 0.6 m (``mid``)
and 1.1 m (``top``); two frames in a row above 1.1 m take ``top``'s inner branch (``sustained``,
state kept across frames). The log's frames lie on the ground (mean height within 2 cm of 0).
``height_shift`` moves a frame by at most 0.5 m (its severity 5: an offset drawn from [-0.5, 0.5]),
so a candidate of two operators reaches at most 1.0 m from the ground: ``top`` needs mutations
built on one another.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidarfuzz.io.kitti import KittiWriter
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


class HeightLadder:
    def reset(self) -> None:
        self.run = 0

    def step(self, frame: Scene) -> str:
        z = float(frame.points.xyz[:, 2].mean())
        if z > 1.1:
            self.run += 1
            if self.run >= 2:
                return "sustained"
            return "top"
        self.run = 0
        if z > 0.6:
            return "mid"
        if z > 0.25:
            return "low"
        return "ground"


def flat_log(root: Path, frames: int = 12, points: int = 200) -> Path:
    """A log of ``frames`` frames at 10 Hz, each ``points`` points on flat ground (z within ±2 cm)."""
    rng = np.random.default_rng(0)
    with KittiWriter(root) as writer:
        for i in range(frames):
            xyz = np.column_stack([rng.uniform(2, 30, points), rng.uniform(-10, 10, points),
                                   rng.uniform(-0.02, 0.02, points)])
            data = np.column_stack([xyz, rng.uniform(0, 1, points)]).astype(np.float32)
            writer.add(Scene(PointCloud(data), frame_id=f"{i:06d}", timestamp=0.1 * i))
    return root
