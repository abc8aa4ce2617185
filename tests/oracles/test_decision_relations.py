"""Relations on decisions: steering and speed tolerance in DeepTest's form (with labels, without them, under a
mirror flip) and safety (no speed-up inside the stopping distance) — on hand-made pairs worked out by hand,
then on the controller and its bug-zoo variants replayed on hand-made logs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarfuzz.operators.base import Relation
from lidarfuzz.operators.lidar.geometric import FlipParams, GlobalFlip
from lidarfuzz.oracles.relations import Pair, for_operator, from_spec, get
from lidarfuzz.oracles.relations.decisions import (
    Safety,
    SpeedTolerance,
    SteeringTolerance,
    consecutive_pairs,
    corridor_distance,
)
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.suts.controller import ObstacleAvoidance
from lidarfuzz.suts.controller.bugs import LeftSectorOffset, LinearStoppingDistance
from lidarfuzz.suts.sequence import Decision, replay
from tests.suts.controller_scenes import frame, log

FLIP = np.diag([1.0, -1.0, 1.0, 1.0])
POST = (2.6, 2.8, -0.3, 0.3)  # a post 2.6 m ahead in the corridor
LEFT_BLOCK = (6.0, 7.0, 1.3, 3.0)


def pair(source: Decision, follow: Decision, **fields: object) -> Pair:
    scene = frame()
    return Pair(scene, scene, source, follow, **fields)  # type: ignore[arg-type]


def test_steering_tolerance_against_lambda_mse_orig_from_labels() -> None:
    relation = SteeringTolerance()
    reference = {"mse_orig_steering": 0.01}  # λ·MSE_orig = 5 × 0.01 = 0.05
    ok = relation(pair(Decision(0.1, 5.0), Decision(0.3, 5.0), reference=reference))
    assert ok.holds and ok.stats["squared_error"] == pytest.approx(0.04)  # (0.3 − 0.1)² = 0.04 ≤ 0.05
    bad = relation(pair(Decision(0.1, 5.0), Decision(0.35, 5.0), reference=reference))
    assert not bad.holds and bad.violations[0].kind == "deviation"
    assert bad.violations[0].magnitude == pytest.approx(0.0625)  # 0.25² > 0.05
    assert bad.stats["limit_from"] == "labels" and bad.stats["limit"] == pytest.approx(0.05)
    configured = SteeringTolerance(**{"lambda": 2.0, "mse_orig": 0.01})  # 2 × 0.01 = 0.02 < 0.04
    assert not configured(pair(Decision(0.1, 5.0), Decision(0.3, 5.0))).holds


def test_without_labels_an_absolute_tolerance_stands_in() -> None:
    relation = SteeringTolerance()  # tolerance 0.05 rad: limit 0.0025
    assert relation(pair(Decision(0.1, 5.0), Decision(0.14, 5.0))).holds  # 0.04² = 0.0016
    outcome = relation(pair(Decision(0.1, 5.0), Decision(0.16, 5.0)))  # 0.06² = 0.0036
    assert not outcome.holds and outcome.stats["limit_from"] == "tolerance"
    speed = SpeedTolerance()  # 0.5 m/s: limit 0.25
    assert speed(pair(Decision(0.0, 8.0), Decision(0.0, 7.6))).holds  # 0.4² = 0.16
    assert not speed(pair(Decision(0.0, 8.0), Decision(0.0, 7.4))).holds  # 0.6² = 0.36


def test_a_mirror_flip_expects_the_steering_mirrored_and_the_speed_kept() -> None:
    flipped = {"operator_relation": Relation.EQUIVARIANT, "transform": FLIP}
    relation = SteeringTolerance()
    assert relation(pair(Decision(0.2, 5.0), Decision(-0.2, 5.0), **flipped)).holds
    wrong = relation(pair(Decision(0.2, 5.0), Decision(0.2, 5.0), **flipped))
    assert not wrong.holds and wrong.stats["expected"] == -0.2 and wrong.stats["squared_error"] == pytest.approx(0.16)
    assert SpeedTolerance()(pair(Decision(0.2, 5.0), Decision(-0.2, 5.0), **flipped)).holds
    # a rotation moves the road: no expected steering, not applicable
    turn = np.eye(4)
    turn[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]
    rotated = relation(pair(Decision(0.2, 5.0), Decision(0.2, 5.0), operator_relation=Relation.EQUIVARIANT,
                            transform=turn))
    assert not rotated.applicable


def test_detection_outputs_are_not_decisions() -> None:
    boxes = Boxes3D.empty()
    scene = frame()
    assert not SteeringTolerance()(Pair(scene, scene, boxes, boxes)).applicable
    assert not Safety()(Pair(scene, scene, boxes, boxes)).applicable


def test_mse_orig_of_a_labelled_log() -> None:
    frames = [frame().replace(metadata={"steering": 0.1}), frame(), frame().replace(metadata={"steering": -0.3})]
    outputs = [Decision(0.2, 1.0), Decision(0.5, 1.0), Decision(-0.1, 1.0)]
    # (0.2 − 0.1)² = 0.01 and (−0.1 + 0.3)² = 0.04 over 2 labelled frames: 0.025
    mse, n = SteeringTolerance().mse_orig_of(frames, outputs)
    assert n == 2 and mse == pytest.approx(0.025)
    assert SpeedTolerance().mse_orig_of(frames, outputs) == (pytest.approx(math.nan, nan_ok=True), 0)


def test_safety_on_hand_made_steps() -> None:
    labelled = frame(POST, labelled=True)
    # stopping distance at the previous 2.5 m/s: 2.5² / 8 + 2 = 2.78125 m; the post is 2.6 m ahead
    faster = Safety()(Pair(frame(), labelled, Decision(0.0, 2.5), Decision(0.0, 2.65)))
    assert not faster.holds and faster.violations[0].kind == "speed_up"
    assert faster.violations[0].magnitude == pytest.approx(0.15) and faster.stats["nearest"] == pytest.approx(2.6)
    assert faster.stats["stopping_distance"] == pytest.approx(2.78125)
    assert Safety()(Pair(frame(), labelled, Decision(0.0, 2.5), Decision(0.0, 2.5))).holds  # no speed-up
    farther = frame((3.0, 3.2, -0.3, 0.3), labelled=True)  # 3.0 m > 2.78 m: speeding up is allowed
    assert Safety()(Pair(frame(), farther, Decision(0.0, 2.5), Decision(0.0, 2.65))).holds
    # no ground truth: the obstacles the system reported; neither: not checked
    reported = Boxes3D.from_array([[2.7, 0.0, -1.0, 0.2, 0.6, 1.5, 0.0]], ["Obstacle"])
    with_report = Safety()(Pair(frame(), frame(), Decision(0.0, 2.5), Decision(0.0, 2.65, obstacles=reported)))
    assert not with_report.holds and with_report.stats["obstacles_from"] == "reported by the system"
    assert not Safety()(Pair(frame(), frame(), Decision(0.0, 2.5), Decision(0.0, 2.65))).applicable


def test_corridor_distance_takes_the_nearest_corner_of_boxes_overlapping_the_corridor() -> None:
    boxes = Boxes3D.from_array([[6.0, 1.9, -1.0, 2.0, 1.4, 1.5, 0.0],   # y from 1.2 to 2.6: overlaps |y| < 1.25
                                [4.0, 3.0, -1.0, 2.0, 1.4, 1.5, 0.0],   # y from 2.3: outside
                                [-5.0, 0.0, -1.0, 2.0, 1.4, 1.5, 0.0]],  # behind
                               ["Car"] * 3)
    assert corridor_distance(boxes, 1.25) == pytest.approx(5.0)
    assert corridor_distance(Boxes3D.empty(), 1.25) == math.inf


def test_safety_tells_the_linear_stopping_distance_variant_from_the_controller() -> None:
    # step 0 on an empty road: 2.5 + 0.15 = 2.65 m/s; step 1 the post 2.6 m ahead (its nearest cell 2.5 m):
    # the controller's stopping distance 2.65²/8 + 2 = 2.88 m: emergency stop, 0 m/s. The variant's
    # 2.65/8 + 2 = 2.33 m is short of 2.5 m: it slows to nothing, its target (slow, 3 m/s) is higher, and it
    # speeds up to 2.8 m/s — inside the true stopping distance of 2.88 m, 2.6 m from the post
    frames = [frame(index=0), frame(POST, index=1, labelled=True)]
    for system, holds in ((ObstacleAvoidance(initial_speed=2.5), True), (LinearStoppingDistance(initial_speed=2.5),
                                                                         False)):
        decided = [r.decision for r in replay(system, frames)]
        outcomes = [Safety()(p) for p in consecutive_pairs(frames, decided)]
        assert len(outcomes) == 1 and outcomes[0].holds is holds, system.name
    assert [r.decision.speed for r in replay(LinearStoppingDistance(initial_speed=2.5), frames)
            if r.decision] == pytest.approx([2.65, 2.8])
    # unlabelled, with the obstacles the controller reports: its cell [2.5, 3.0) is the nearest, 2.5 m ahead
    unlabelled = [frame(index=0), frame(POST, index=1)]
    for system, holds in ((ObstacleAvoidance(initial_speed=2.5, report_obstacles=True), True),
                          (LinearStoppingDistance(initial_speed=2.5, report_obstacles=True), False)):
        decided = [r.decision for r in replay(system, unlabelled)]
        outcome = Safety()(consecutive_pairs(unlabelled, decided)[0])
        assert outcome.holds is holds and outcome.stats["obstacles_from"] == "reported by the system"
        assert outcome.stats["nearest"] == pytest.approx(2.5)


def test_steering_tolerance_under_global_flip_tells_the_left_sector_variant_from_the_controller() -> None:
    # the block on the left for five frames, and the same log mirrored by global_flip (block on the right):
    # the controller settles at -12.5° and +12.5° (holds: the mirrored steering is expected); the variant at
    # -7.5° and +12.5°: (12.5° − 7.5°)² = 0.0873² = 0.0076 rad² > the tolerance² 0.0025
    flip = GlobalFlip.at_severity(1)
    params = FlipParams(flipped=True)
    original = log(*[(LEFT_BLOCK,)] * 5)
    mirrored = [flip.apply(scene, params) for scene in original]
    for system, holds in ((ObstacleAvoidance(initial_speed=8.0), True), (LeftSectorOffset(initial_speed=8.0), False)):
        before = replay(system, original)[-1].decision
        after = replay(system, mirrored)[-1].decision
        outcome = SteeringTolerance()(Pair(original[-1], mirrored[-1], before, after,
                                           operator_relation=Relation.EQUIVARIANT, transform=flip.transform(params)))
        assert outcome.applicable and outcome.holds is holds, system.name


def test_registered_listed_and_kept_out_of_detection_campaigns() -> None:
    assert get("steering_tolerance") is SteeringTolerance and get("speed-tolerance") is SpeedTolerance
    assert get("safety") is Safety
    assert from_spec(SteeringTolerance(**{"lambda": 3}).spec()).config.lambda_ == 3
    for kind in Relation:
        assert not {"steering_tolerance", "speed_tolerance", "safety"} & {r.name for r in for_operator(kind)}
    assert {r.name for r in for_operator(Relation.INVARIANT, output="decisions")} == {
        "steering_tolerance", "speed_tolerance", "safety"}
