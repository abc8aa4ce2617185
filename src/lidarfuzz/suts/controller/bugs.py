"""The controller's bug zoo: :class:`~lidarfuzz.suts.controller.ObstacleAvoidance` with one realistic
fault seeded in each variant, documented as the classic pipeline's (:mod:`lidarfuzz.suts.bugzoo`):
the bug, the operator and relation expected to reveal it, and where it hides. Each overrides
exactly one method. Registered as sequence systems ``controller-bug-<name>``; ``CONTROLLER_BUGS``
lists them.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.suts.bugzoo import Reveal
from lidarfuzz.suts.controller.avoidance import ObstacleAvoidance
from lidarfuzz.suts.controller.vfh import VFH


class BuggyController(ObstacleAvoidance):
    """Base of the variants: the bug's story, what reveals it, where it hides."""

    bug: ClassVar[str]
    reveal: ClassVar[Reveal]
    hidden: ClassVar[str]

    def config(self) -> dict[str, Any]:
        return {**super().config(), "bug": self.bug}


class LinearStoppingDistance(BuggyController):
    """The stopping distance is computed as ``v / (2·a_max) + margin`` — speed where speed² belongs —
    so above 1 m/s the controller thinks it stops sooner than it does."""

    name = "controller-bug-linear-stop"
    bug = "stopping distance v/(2·a_max) + margin instead of v²/(2·a_max) + margin"
    reveal = Reveal("object_insertion", 3, "safety",
                    "an object inserted a few metres ahead in the lane while the car drives: the variant neither "
                    "brakes hard nor holds its speed, and speeds up inside the true stopping distance")
    hidden = ("logs where nothing enters the corridor within the true stopping distance (at 8 m/s, 10 m); below "
              "1 m/s the variant is the more cautious")

    def stopping_distance(self, speed: float) -> float:
        cfg = self.settings
        return speed / (2.0 * cfg.max_decel) + cfg.stop_margin


class StickyVFH(VFH):
    """A hysteresis whose release was lost: a sector once blocked stays blocked until the reset."""

    def threshold(self, smoothed: NDArray[np.float64]) -> NDArray[np.bool_]:
        return self.previous_binary | (smoothed > self.config.threshold_high)


class StickyHysteresis(BuggyController):
    """The VFH's hysteresis never releases a blocked sector (the ``threshold_low`` branch was lost in a
    refactor): after passing an obstacle the car keeps avoiding where it was, and a log with
    obstacles on both sides ends with every sector blocked and the car stopped."""

    name = "controller-bug-sticky-block"
    vfh_class = StickyVFH
    bug = "VFH hysteresis never frees a blocked sector (the release below threshold_low is missing)"
    reveal = Reveal("object_removal", 5, "steering_tolerance",
                    "with an obstacle removed from some frames, the correct controller steers back to the goal "
                    "once it is gone; the variant keeps steering around where it was for the rest of the log")
    hidden = "logs where no sector is ever blocked (an open road) or where obstacles stay in view until the log ends"


class LeftSectorOffByOne(VFH):
    """Angles on the left side land one sector further left: ``floor`` applied after adding an
    extra sector for positive angles."""

    def sector_of(self, angle: NDArray[np.float64]) -> NDArray[np.int64]:
        angle = np.asarray(angle, dtype=np.float64)
        index = np.floor((angle + self.half_fov) / self.sector).astype(np.int64) + (angle > 0)
        return np.clip(index, 0, self.n_sectors - 1)


class LeftSectorOffset(BuggyController):
    """The polar histogram's sector index is off by one on the left side, so whatever lies left of
    straight ahead is placed one sector (5°) further left than it is: an obstacle on the left seems
    farther from the heading than it is, and the car swerves less around it (7.5° instead of
    12.5° in the tests' scene) — closer past it than around its mirror image on the right."""

    name = "controller-bug-left-sector"
    vfh_class = LeftSectorOffByOne
    bug = "sector index one too high for angles left of straight ahead (an off-by-one on one side)"
    reveal = Reveal("global_flip", 1, "steering_tolerance",
                    "mirroring the scene left to right should mirror the steering; the variant turns 5° less "
                    "around an obstacle on its left than around its mirror image on the right")
    hidden = "obstacles on the right (their enlarged extent's left edge seldom decides the valley) and open roads"


CONTROLLER_BUGS: tuple[type[BuggyController], ...] = (LinearStoppingDistance, StickyHysteresis, LeftSectorOffset)
