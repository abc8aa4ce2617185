"""A sequence system small enough to count by hand, for the structural campaign tests
(``tests.campaign.structural_system:Gate``).

The tests name lines by number: change nothing above ``Gate.step``'s last line.
"""

from __future__ import annotations

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.suts.sequence import Decision, SequenceSystem

#: The obstacle it always reports: a box 3 m ahead, 1 m long, so its near face is 2.5 m away.
AHEAD = Boxes3D.create([[3.0, 0.0, -1.0]], [[1.0, 1.0, 1.5]], [0.0], ["Car"], scores=[1.0])


class Gate(SequenceSystem):
    """Speeds up by 1 m/s a frame, and stops on a frame with a point higher than 5 m.

    ``step``'s graph (lines 28-34): blocks [29, 30] (the if: two successors), [31], [33], [34];
    edges entry(-28)->29, 29->31, 29->33, 31->34, 33->34, 34->exit — 4 nodes, 6 edges.
    """

    name = "gate"

    def reset(self) -> None:
        self.speed = 0.0

    def step(self, frame):  # type: ignore[no-untyped-def]
        top = float(frame.points.xyz[:, 2].max()) if len(frame.points) else 0.0
        if top > 5.0:
            self.speed = 0.0
        else:
            self.speed = self.speed + 1.0
        return Decision(steering=0.0, speed=self.speed, obstacles=AHEAD)
