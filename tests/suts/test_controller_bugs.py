"""The controller's bug zoo: each variant differs from the correct controller on a hand-made log where its bug
matters and agrees with it on one where it does not (defaults as in test_controller.py)."""

from __future__ import annotations

import math

import pytest

from lidarfuzz.suts.controller import ObstacleAvoidance
from lidarfuzz.suts.controller.bugs import (
    CONTROLLER_BUGS,
    LeftSectorOffset,
    LinearStoppingDistance,
    StickyHysteresis,
)
from lidarfuzz.suts.registry import available_sequences
from lidarfuzz.suts.sequence import Decision, SequenceSystem, replay
from tests.suts.controller_scenes import log

WALL_AT_5 = (5.0, 5.2, -3.0, 3.0)
LEFT_BLOCK = (6.0, 7.0, 1.3, 3.0)
RIGHT_BLOCK = (6.0, 7.0, -3.0, -1.3)


def decisions(system: SequenceSystem, frames: list) -> list[Decision]:
    out = [r.decision for r in replay(system, frames)]
    assert all(d is not None for d in out)
    return [d for d in out if d is not None]


def test_every_variant_is_documented_registered_and_fingerprinted_apart() -> None:
    registered = available_sequences()
    correct = ObstacleAvoidance().fingerprint()
    for cls in CONTROLLER_BUGS:
        assert registered[cls.name] is cls
        assert cls.bug and cls.hidden and cls.reveal.relation in {"safety", "steering_tolerance", "speed_tolerance"}
        assert cls().fingerprint() != correct


def test_linear_stopping_distance_misses_the_emergency_stop() -> None:
    # at 8 m/s the stopping distance is 8²/8 + 2 = 10 m: the wall 5 m ahead is an emergency stop; the variant's
    # 8/8 + 2 = 3 m is shorter than 5 m, so it only slows: 8 − 4 × 0.1 = 7.6 m/s
    correct = decisions(ObstacleAvoidance(initial_speed=8.0), log((WALL_AT_5,)))[0]
    buggy = decisions(LinearStoppingDistance(initial_speed=8.0), log((WALL_AT_5,)))[0]
    assert correct.emergency_stop and correct.speed == 0.0
    assert not buggy.emergency_stop and buggy.speed == pytest.approx(7.6)
    # nothing in the corridor: the stopping distance decides nothing, the decisions agree
    road = log((), (), (LEFT_BLOCK,))
    assert decisions(LinearStoppingDistance(initial_speed=8.0), road) == decisions(
        ObstacleAvoidance(initial_speed=8.0), road)


def test_sticky_hysteresis_keeps_avoiding_an_obstacle_that_is_gone() -> None:
    # frame 0 blocks the sectors of the block on the left (steer right towards -12.5°, -0.06 after the rate
    # limit); on the empty road after it the correct controller frees them and steers back to 0 (within 0.06 of
    # -0.06); the variant never frees them and keeps turning right by 0.06 per frame
    frames = log((LEFT_BLOCK,), (), ())
    correct = [d.steering for d in decisions(ObstacleAvoidance(initial_speed=8.0), frames)]
    buggy = [d.steering for d in decisions(StickyHysteresis(initial_speed=8.0), frames)]
    assert correct == pytest.approx([-0.06, 0.0, 0.0])
    assert buggy == pytest.approx([-0.06, -0.12, -0.18])
    # nothing is ever blocked on an open road: no difference
    road = log((), (), ())
    assert decisions(StickyHysteresis(initial_speed=8.0), road) == decisions(ObstacleAvoidance(initial_speed=8.0), road)


def test_left_sector_offset_swerves_less_around_an_obstacle_on_the_left() -> None:
    # five frames with the block on the left: the correct controller settles at -12.5° (see test_controller:
    # its cone reaches -2.3°, sector 18 and up are blocked). The variant shifts every index of an angle left of
    # straight ahead: the cone's first covered centre, found as sector_of(-2.3° + 2.5° = 0.2°), becomes 19, the
    # goal sector 18 is free, the valley (0, 18), and the car aims 2 sectors in from its end: 16, -7.5°
    left = log(*[(LEFT_BLOCK,)] * 5)
    correct = decisions(ObstacleAvoidance(initial_speed=8.0), left)[-1].steering
    buggy_system = LeftSectorOffset(initial_speed=8.0)
    buggy = decisions(buggy_system, left)[-1].steering
    assert correct == pytest.approx(-math.radians(12.5))
    assert buggy == pytest.approx(-math.radians(7.5))
    assert buggy_system.last is not None and buggy_system.last.vfh is not None
    assert buggy_system.last.vfh.valley == (0, 18)
    # its mirror image on the right lies at negative angles where the index is right: the same decisions
    right = log(*[(RIGHT_BLOCK,)] * 5)
    assert decisions(LeftSectorOffset(initial_speed=8.0), right) == decisions(ObstacleAvoidance(initial_speed=8.0),
                                                                              right)
