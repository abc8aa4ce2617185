"""A system under test for the cluster tests (``test_ray.py``): the classic pipeline with a real
segmentation fault on one frame, in its own process, as a native extension's bug would have it.
Stateless: every other frame gets the classic pipeline's answer, in any process, in any order.
Spec ``tests.campaign.ray_systems:SegfaultsOnFrame``."""

from __future__ import annotations

import ctypes

from lidarfuzz.scene.scene import Scene
from tests.campaign.systems import FailsOnFrame


class SegfaultsOnFrame(FailsOnFrame):
    """Reads address 0 on its frame: SIGSEGV, and the process (a Ray actor's, here) is gone — unlike
    :class:`~tests.campaign.systems.DiesOnFrame`, which exits cleanly with a segfault's status."""

    name = "segfaults-on-frame"

    def fail(self, sample: Scene) -> None:
        ctypes.string_at(0)
