"""A system under test for the report's tests: the classic pipeline raising on one frame
(a crash, as the guard records it). Named by spec: ``tests.report.systems:RaisesOnFrame``."""

from __future__ import annotations

from typing import Any

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.classic import ClassicPipeline


class RaisesOnFrame(ClassicPipeline):
    name = "raises-on-frame"

    def __init__(self, frame: str = "000001", **fields: Any) -> None:
        super().__init__(**fields)
        self.frame = frame

    def config(self) -> dict[str, Any]:
        return {**super().config(), "frame": self.frame}

    def detect(self, sample: Scene) -> Boxes3D:
        if sample.frame_id == self.frame:
            raise RuntimeError(f"cannot handle frame {sample.frame_id}")
        return super().detect(sample)
