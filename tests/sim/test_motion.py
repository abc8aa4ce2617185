"""Motion along routes: speed profiles (stops, limits, bounded acceleration), rounded corners,
ego labels (speed, yaw rate, curvature, steering), and scenes without these fields unchanged.

Expected values are worked by hand in the comments (v² = v0² + 2·a·s, t = Δv / a)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.sim import compile_world, parse_scene
from lidarfuzz.sim.motion import RoundedPath, SpeedProfile, steering_angle
from lidarfuzz.sim.world import ProfiledTrajectory, Trajectory, ego_labels
from tests.sim.helpers import street


# --------------------------------------------------------------------------- speed profile
def test_a_stop_brakes_at_3_stands_and_accelerates_back_at_2():
    # 10 m/s, stop at 100 m for 5 s, 300 m long, decel 3, accel 2:
    #   braking takes 10/3 s over 10²/(2·3) = 16.667 m: it starts at 83.333 m, at t = 8.333 s;
    #   it stands at 100 m from t = 11.667 s to 16.667 s;
    #   back at 10 m/s after 10/2 = 5 s and 10²/(2·2) = 25 m: at 125 m, t = 21.667 s;
    #   braking for the end starts at 300 − 16.667 = 283.333 m, t = 21.667 + 158.333/10 = 37.5 s;
    #   it stands at 40.833 s.
    profile = SpeedProfile.plan(300.0, [(0.0, 300.0, 10.0)], stops=[(100.0, 5.0)], accel=2.0, decel=3.0)
    # At t = 10: 1.667 s into braking, 83.333 + 10·1.667 − ½·3·1.667² = 95.833 m at 10 − 3·1.667 = 5 m/s;
    # at t = 19: 2.333 s into the start, 100 + ½·2·2.333² = 105.444 m at 4.667 m/s.
    t = np.array([0.0, 8.3333333, 10.0, 11.6666667, 14.0, 16.6666667, 19.0, 21.6666667, 30.0, 37.5, 40.8333333, 50.0])
    np.testing.assert_allclose(profile.distance(t), [0.0, 83.333333, 95.833333, 100.0, 100.0, 100.0, 105.444444,
                                                     125.0, 208.333333, 283.333333, 300.0, 300.0], atol=1e-4)
    np.testing.assert_allclose(profile.speed(t), [10, 10, 5, 0, 0, 0, 4.666667, 10, 10, 10, 0, 0], atol=1e-4)
    assert profile.time_at(100.0) == pytest.approx(11.666667, abs=1e-5)
    assert profile.duration == pytest.approx(40.833333, abs=1e-5)
    # Never harder than the limits, and the speed is continuous (no jump anywhere).
    dense = np.arange(-1.0, 45.0, 0.01)
    assert profile.acceleration(dense).min() >= -3.0 - 1e-9 and profile.acceleration(dense).max() <= 2.0 + 1e-9
    assert np.abs(np.diff(profile.speed(dense))).max() <= 3.0 * 0.01 + 1e-9


def test_leg_speeds_brake_before_the_slower_leg_and_a_short_stretch_never_reaches_its_limit():
    # 10 → 5 m/s at 100 m: (10² − 5²) / (2·3) = 12.5 m of braking, from 87.5 m.
    profile = SpeedProfile.plan(400.0, [(0.0, 100.0, 10.0), (100.0, 400.0, 5.0)])
    assert profile.speed(profile.time_at(87.5))[0] == pytest.approx(10.0)
    assert profile.speed(profile.time_at(93.75))[0] == pytest.approx(math.sqrt(25 + 2 * 3 * 6.25))
    assert profile.speed(profile.time_at(100.0))[0] == pytest.approx(5.0)
    # From rest (a stop at 0 for 2 s) over 10 m, limit 5 m/s: v² = 2·2·s up, 2·3·(10 − s) down,
    # they meet at 4s = 60 − 6s, s = 6 m, v = √24 = 4.899 < 5.
    short = SpeedProfile.plan(10.0, [(0.0, 10.0, 5.0)], stops=[(0.0, 2.0)])
    assert short.distance(1.9)[0] == 0.0
    assert short.top_speed == pytest.approx(math.sqrt(24.0))
    assert short.duration == pytest.approx(2.0 + math.sqrt(24) / 2 + math.sqrt(24) / 3)


# --------------------------------------------------------------------------- rounded corners
def test_a_rounded_right_turn_is_an_arc_with_continuous_heading_and_ends_on_the_new_heading():
    # A 90° right turn at (50, 0) with R = 8: tangent length R·tan 45° = 8, so the arc runs from
    # (42, 0) to (50, −8), 8·π/2 = 12.566 m long; the whole path is 42 + 12.566 + 42 = 96.566 m.
    path = RoundedPath.of([[0, 0], [50, 0], [50, -50]], 8.0)
    assert path.length == pytest.approx(84 + 4 * math.pi)
    x, y, heading = path.pose([42.0, 42 + 2 * math.pi, 42 + 4 * math.pi, path.length])
    np.testing.assert_allclose(x, [42, 42 + 8 * math.sin(math.pi / 4), 50, 50], atol=1e-9)
    np.testing.assert_allclose(y, [0, -8 + 8 * math.cos(math.pi / 4), -8, -50], atol=1e-9)
    np.testing.assert_allclose(heading, [0, -math.pi / 4, -math.pi / 2, -math.pi / 2], atol=1e-9)
    s = np.arange(0.0, path.length, 0.01)
    _, _, h = path.pose(s)
    assert np.abs(np.diff(h)).max() <= 0.01 / 8 + 1e-9  # heading changes at most ds/R: no jump
    assert np.abs(path.curvature(s)).max() == pytest.approx(1 / 8)
    assert path.waypoint_offsets[1] == pytest.approx(42 + 2 * math.pi)  # the corner's mark: the arc's middle


def test_a_corner_too_tight_for_its_radius_gets_the_largest_arc_that_fits():
    # Legs of 4 m (first and last: each may give all of it): tangent 4 m at 90° → R = 4 m.
    path = RoundedPath.of([[0, 0], [4, 0], [4, 4]], 10.0)
    assert path.curvatures.max() == pytest.approx(1 / 4)
    assert path.length == pytest.approx(2 * math.pi)  # the quarter circle of radius 4, no straight left
    # Without a radius the corners stay sharp, as a plain route's.
    assert RoundedPath.of([[0, 0], [4, 0], [4, 4]], None).curvatures.tolist() == [0.0, 0.0]


# --------------------------------------------------------------------------- labels
def test_steering_on_a_circle_of_radius_r_is_atan_of_wheelbase_over_r():
    # Around a square with corners rounded at R = 20 m at 5 m/s (under the corner's √(2·20) = 6.3 m/s):
    # on the arc κ = 1/20, yaw rate 5/20 = 0.25 rad/s, steering atan(2.71 / 20) = 0.13468 rad.
    spec = parse_scene({"ego": {"speed": 5, "route": [[0, 0], [100, 0], [100, 100], [0, 100]], "corner_radius": 20}})
    world = compile_world(spec)
    assert isinstance(world.ego, ProfiledTrajectory)
    mid_arc = world.ego.profile.time_at(80 + 5 * math.pi)  # 80 m of straight, then a quarter of the arc
    speed, yaw_rate, curvature, steering = ego_labels(world.ego, np.array([mid_arc]))[0]
    assert (speed, yaw_rate, curvature) == pytest.approx((5.0, 0.25, 0.05))
    assert steering == pytest.approx(0.13468, abs=1e-5) == math.atan(2.71 / 20)
    assert float(steering_angle(-0.05)) == pytest.approx(-0.13468, abs=1e-5)  # right turns are negative
    # The corner's speed limit: lateral acceleration 2 m/s² on R = 8 m gives √16 = 4 m/s.
    tight = compile_world(parse_scene({"ego": {"speed": 10, "route": [[0, 0], [60, 0], [60, 60]],
                                               "corner_radius": 8}})).ego
    assert tight.kinematics(tight.profile.time_at(52 + 2 * math.pi))[0][0] == pytest.approx(4.0)


def test_plain_routes_label_a_constant_speed_and_no_curvature_then_stand_at_the_end():
    world = compile_world(parse_scene({"ego": {"speed": 10, "route": [[0, 0], [20, 0], [20, 20]]}}))
    rows = ego_labels(world.ego, np.array([0.0, 1.0, 3.9, 4.0, 9.0]))  # 40 m of route at 10 m/s: 4 s
    np.testing.assert_allclose(rows, [[10, 0, 0, 0]] * 3 + [[0, 0, 0, 0]] * 2)


# --------------------------------------------------------------------------- scene entries
def test_actors_wait_then_walk_and_parked_actors_and_bad_fields_are_refused():
    spec = parse_scene(street(actors=[{"class": "Pedestrian", "position": [30, -6], "speed": 1.2,
                                       "route": [[30, -6], [30, 6]], "stops": [{"at": 0, "duration": 3}]}]))
    walker = compile_world(spec).actors[0].trajectory
    _, y, heading = walker.at(np.array([0.0, 2.9, 3.6, 20.0]))
    # Stands 3 s, then 2 m/s² for 0.6 s: 0.5·2·0.6² = 0.36 m; at the far end (12 m) it stands.
    np.testing.assert_allclose(y, [-6, -6, -5.64, 6], atol=1e-9)
    np.testing.assert_allclose(heading, math.pi / 2)
    bad = [
        ({"class": "Car", "position": [0, 0], "parked": True, "stops": [{"at": 0, "duration": 1}]}, "parked"),
        ({"class": "Car", "position": [0, 0], "speed": 3, "route": [[0, 0], [5, 0]], "speeds": [1, 2]},
         "speeds: expected one per leg"),
        ({"class": "Car", "position": [0, 0], "speed": 3, "route": [[0, 0], [5, 0]], "stops": [{"at": 9}]},
         r"stops\[0\].at"),
        ({"class": "Car", "position": [0, 0], "stops": [{"at": 1}]}, "does not move"),
        ({"class": "Car", "position": [0, 0], "speed": 3, "decel": 0}, "decel"),
    ]
    for entry, message in bad:
        with pytest.raises(DataFormatError, match=message) as info:
            parse_scene(street(actors=[entry]))
        assert "actors.0" in str(info.value) and "\n" not in str(info.value)


def test_entries_without_motion_fields_keep_their_dumps_and_the_plain_trajectory():
    spec = parse_scene(street(ego={"position": [0, -1.75], "speed": 8, "route": [[0, -1.75], [50, -1.75]]},
                              actors=[{"class": "Car", "position": [20, 1.75], "speed": 5}]))
    dumped = json.loads(spec.to_json())
    # The keys these entries had before the motion fields existed, in the same order.
    assert list(dumped["ego"]) == ["position", "yaw", "speed", "route"]
    assert list(dumped["actors"][0]) == ["class", "position", "yaw", "size", "speed", "route", "parked",
                                         "reflectivity", "id"]
    world = compile_world(spec)
    assert type(world.ego) is Trajectory and type(world.actors[0].trajectory) is Trajectory
    with_stop = parse_scene({**dumped, "ego": {**dumped["ego"], "stops": [{"at": 10, "duration": 1}]}})
    assert json.loads(with_stop.to_json())["ego"]["stops"] == [{"at": 10.0, "duration": 1.0}]
    assert parse_scene(json.loads(with_stop.to_json())) == with_stop  # round trip
