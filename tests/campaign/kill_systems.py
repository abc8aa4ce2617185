"""The system under test of the kill -9 harness (:mod:`benchmarks.kills` and ``test_kill.py``): the
classic pipeline slowed down (so a run can be killed mid-way) and raising on one frame (so the run
has findings whose numbering the comparison puts to the test). Stateless: the same frame always
gets the same answer, in any process, in any order. Spec ``tests.campaign.kill_systems:SlowRaises``."""

from __future__ import annotations

import time
from typing import Any

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from tests.campaign.systems import RaisesOnFrame


class SlowRaises(RaisesOnFrame):
    name = "slow-raises"

    def __init__(self, delay: float = 0.1, **fields: Any) -> None:
        super().__init__(**fields)
        self.delay = delay

    def config(self) -> dict[str, Any]:
        return {**super().config(), "delay": self.delay}

    def detect(self, sample: Scene) -> Boxes3D:
        time.sleep(self.delay)
        return super().detect(sample)
