"""A system under test with a bug behind a rarely taken branch, for code-guided searches: it
answers one fixed car on every frame, except that a frame of more than 115,000 points (the
bug-zoo's dense-cloud threshold; the simulator's HDL-64E frames hold 103-112k) goes down a
branch that fails. Named by spec: ``tests.campaign.code_systems:CrowdedCrash``."""

from __future__ import annotations

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.classic import ClassicPipeline


class CrowdedCrash(ClassicPipeline):
    name = "crowded-crash"
    DENSE = 115_000

    def detect(self, sample: Scene) -> Boxes3D:
        if len(sample.points) > self.DENSE:
            return self.crowded(sample)
        return Boxes3D.create([[10.0, 1.5, -0.9]], [[4.0, 1.8, 1.5]], [0.0], ["Car"], scores=[0.9])

    def crowded(self, sample: Scene) -> Boxes3D:
        cells = len(sample.points) // 1_000_000  # 0 for any real frame: the bug
        return Boxes3D.create([[10.0, 1.5, -0.9]], [[4.0, 1.8, 1.5]], [0.0], ["Car"], scores=[1.0 / cells])
