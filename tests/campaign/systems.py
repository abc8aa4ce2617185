"""Systems under test for the engine's and the report's tests: the classic pipeline slowed down
(to interrupt a run mid-way), one that kills its own process on one frame (a segfault, as far
as the pool can tell) and one that raises on one frame. Named by spec, e.g.
``tests.campaign.systems:SlowClassic``."""

from __future__ import annotations

import os
import time
from typing import Any

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.classic import ClassicPipeline


class SlowClassic(ClassicPipeline):
    name = "slow-classic"

    def __init__(self, delay: float = 0.05, **fields: Any) -> None:
        super().__init__(**fields)
        self.delay = delay

    def config(self) -> dict[str, Any]:
        return {**super().config(), "delay": self.delay}

    def detect(self, sample: Scene) -> Boxes3D:
        time.sleep(self.delay)
        return super().detect(sample)


class FailsOnFrame(ClassicPipeline):
    """The classic pipeline failing on one frame (how: :meth:`fail`)."""

    name = "fails-on-frame"

    def __init__(self, frame: str = "000001", **fields: Any) -> None:
        super().__init__(**fields)
        self.frame = frame

    def config(self) -> dict[str, Any]:
        return {**super().config(), "frame": self.frame}

    def fail(self, sample: Scene) -> None:
        raise NotImplementedError

    def detect(self, sample: Scene) -> Boxes3D:
        if sample.frame_id == self.frame:
            self.fail(sample)
        return super().detect(sample)


class DiesOnFrame(FailsOnFrame):
    name = "dies-on-frame"

    def fail(self, sample: Scene) -> None:
        os._exit(139)  # kills the process, as a segfault would


class RaisesOnFrame(FailsOnFrame):
    """A crash as the guard records it (an exception)."""

    name = "raises-on-frame"

    def fail(self, sample: Scene) -> None:
        raise RuntimeError(f"cannot handle frame {sample.frame_id}")


class RandomBoxes(ClassicPipeline):
    """Non-deterministic: the classic pipeline's cars, each moved 1.5-3 m along its heading, forwards or
    backwards, by an unseeded generator on every call, so the same frame never gets the same answer
    twice (each box still covers part of its car's points: the relations check it)."""

    name = "random-boxes"

    def detect(self, sample: Scene) -> Boxes3D:
        import numpy as np

        found = super().detect(sample)
        rng = np.random.default_rng()
        shift = rng.uniform(1.5, 3.0, len(found)) * rng.choice([-1.0, 1.0], len(found))
        rows = found.as_array().copy()
        rows[:, 0] += shift * np.cos(rows[:, 6])
        rows[:, 1] += shift * np.sin(rows[:, 6])
        return Boxes3D.from_array(rows, found.labels, scores=found.scores)


class FixedBox(ClassicPipeline):
    """Blind: one car at (10, 1.5) whatever the input, so a mirrored frame (y -> -y) always breaks
    equivariance (the moved source box lies at (10, -1.5), 3 m from it: no overlap for 1.8 m
    wide boxes), while a change that moves nothing never breaks a relation."""

    name = "fixed-box"

    def detect(self, sample: Scene) -> Boxes3D:
        return Boxes3D.create([[10.0, 1.5, -0.9]], [[4.0, 1.8, 1.5]], [0.0], ["Car"], scores=[0.9])
