"""The built-in controller on hand-made scenes: the VFH's histogram, valleys and hysteresis worked out by
hand, and ObstacleAvoidance.process's speed and steering decisions (defaults unless a test says otherwise:
36 sectors of 5° from -90° (sector 0, right) to +90°, sector k centred at -87.5° + 5k, a cell covering the
sectors whose centre lies in its cone enlarged by 1.0 + 0.5 = 1.5 m, thresholds 3.0 / 1.5, wide valleys from
4 sectors (the car keeps 2 off their border), period 0.1 s, a_max 4 m/s², margin 2 m, cruise 8 m/s)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import FailureKind
from lidarfuzz.suts.controller import VFH, ControllerConfig, Mode, ObstacleAvoidance
from lidarfuzz.suts.sequence import replay
from tests.suts.controller_scenes import frame, log

# the VFH tests: no smoothing, and an active window of 25 m, so that a cell's magnitude is weight × (1 − d/25)
VFH_CONFIG = ControllerConfig(smoothing=0, window_radius=25.0)


def cell(x: float, y: float) -> np.ndarray:
    return np.array([[x, y]])


def test_vfh_free_road_heads_for_the_goal() -> None:
    result = VFH(ControllerConfig()).calculate(np.zeros((0, 2)), np.zeros(0), goal=0.0)
    assert result.valley == (0, 35) and result.wide and not result.blocked
    assert result.direction == 0.0 and result.goal_sector == 18  # floor((0 + 90) / 5)


def test_vfh_obstacle_dead_ahead() -> None:
    # one cell 10 m ahead weighing 6: magnitude 6 × (1 − 10/25) = 3.6 > 3.0, enlarged by asin(1.5/10) = 8.63°:
    # the centres -7.5°, -2.5°, 2.5°, 7.5° (sectors 16 to 19) lie in its cone
    result = VFH(VFH_CONFIG).calculate(cell(10.0, 0.0), np.array([6.0]), goal=0.0)
    assert np.flatnonzero(result.binary).tolist() == [16, 17, 18, 19]
    assert result.histogram[16:20] == pytest.approx([3.6] * 4)
    # valleys (0, 15) and (20, 35); the goal sector 18 is 3 from the first, 2 from the second: the left one,
    # wide (16 sectors), entered 2 sectors in from its border: sector 22, centre -87.5 + 22 × 5 = 22.5°
    assert result.valley == (20, 35) and result.wide
    assert math.degrees(result.direction) == pytest.approx(22.5)


def test_vfh_obstacle_left_steers_right() -> None:
    # a cell at (10, 2): d = 10.198, magnitude 6 × (1 − 10.198/25) = 3.553, angle 11.31°, spread
    # asin(1.5/10.198) = 8.46°: the cone [2.85°, 19.77°] holds the centres 7.5°, 12.5°, 17.5° (sectors 19-21)
    result = VFH(VFH_CONFIG).calculate(cell(10.0, 2.0), np.array([6.0]), goal=0.0)
    assert np.flatnonzero(result.binary).tolist() == [19, 20, 21]
    assert result.histogram[19] == pytest.approx(6 * (1 - math.hypot(10, 2) / 25))
    # the goal sector 18 is free, in the valley (0, 18), but at its left end: 2 sectors in, sector 16, -7.5°
    assert result.valley == (0, 18)
    assert math.degrees(result.direction) == pytest.approx(-7.5)


def test_vfh_narrow_valley_aims_at_its_middle_not_the_goal() -> None:
    # cells at (10, ±2.6): d = 10.333, magnitude 6 × (1 − 10.333/25) = 3.52, angle ±14.57°, spread 8.35°:
    # cones [-22.92°, -6.23°] (centres of sectors 13-16) and [6.23°, 22.92°] (sectors 19-22)
    result = VFH(VFH_CONFIG).calculate(np.array([[10.0, -2.6], [10.0, 2.6]]), np.array([6.0, 6.0]), goal=0.05)
    assert np.flatnonzero(result.binary).tolist() == [13, 14, 15, 16, 19, 20, 21, 22]
    # the goal (2.9°, sector 18) lies in the valley (17, 18), 2 sectors wide: narrow, through its middle,
    # sector 17.5, -87.5 + 17.5 × 5 = 0°
    assert result.valley == (17, 18) and not result.wide
    assert result.direction == pytest.approx(0.0)


def test_vfh_goal_outside_the_field_of_view_is_clipped() -> None:
    # 2 rad > 90°: clipped to 90°, sector 36 clipped to 35; the valley (0, 35) is wide but the goal is 0 sectors
    # from its left end: 2 sectors in, sector 33, -87.5 + 33 × 5 = 77.5°
    result = VFH(ControllerConfig()).calculate(np.zeros((0, 2)), np.zeros(0), goal=2.0)
    assert result.goal_sector == 35
    assert math.degrees(result.direction) == pytest.approx(77.5)


def test_vfh_hysteresis_keeps_a_sector_blocked_until_under_the_low_threshold() -> None:
    vfh = VFH(VFH_CONFIG)
    assert vfh.calculate(cell(10.0, 0.0), np.array([6.0]), goal=0.0).binary[16:20].all()  # 3.6 > 3.0
    # weight 4.9: 4.9 × 0.6 = 2.94, just under the high threshold and above the low one (1.5): still blocked
    held = vfh.calculate(cell(10.0, 0.0), np.array([4.9]), goal=0.0)
    assert held.binary[16:20].all() and math.degrees(held.direction) == pytest.approx(22.5)
    # a fresh histogram (or one after a reset) sees 2.94 as free
    fresh = VFH(VFH_CONFIG).calculate(cell(10.0, 0.0), np.array([4.9]), goal=0.0)
    assert not fresh.binary.any() and fresh.direction == 0.0
    # weight 2: 1.2 < 1.5 frees the sectors
    released = vfh.calculate(cell(10.0, 0.0), np.array([2.0]), goal=0.0)
    assert not released.binary.any() and released.direction == 0.0
    vfh.calculate(cell(10.0, 0.0), np.array([6.0]), goal=0.0)
    vfh.reset()
    assert not vfh.calculate(cell(10.0, 0.0), np.array([4.9]), goal=0.0).binary.any()


def test_vfh_everything_blocked_holds_the_last_direction() -> None:
    # a cell 1 m ahead, inside the enlargement radius (1.5 m): its cone is -90° to +90°, every sector, with
    # 5 × (1 − 1/25) = 4.8 > 3.0
    vfh = VFH(VFH_CONFIG)
    vfh.calculate(cell(10.0, 2.0), np.array([6.0]), goal=0.0)  # -7.5°, as above
    result = vfh.calculate(cell(1.0, 0.0), np.array([5.0]), goal=0.0)
    assert result.blocked and result.valley is None and result.binary.all()
    assert math.degrees(result.direction) == pytest.approx(-7.5)


def test_empty_road_cruises_straight() -> None:
    controller = ObstacleAvoidance()
    speeds = [controller.step(f).speed for f in log(*[()] * 4)]
    # from standing, 1.5 m/s² × 0.1 s = 0.15 m/s more per frame towards the cruise speed
    assert speeds == pytest.approx([0.15, 0.30, 0.45, 0.60])
    last = controller.step(frame())
    assert last.steering == 0.0 and not last.emergency_stop
    assert last.path[0] == (2.0, 0.0) and last.path[-1] == (10.0, 0.0)
    assert controller.last is not None and controller.last.mode is Mode.CRUISE and controller.last.ground_trusted
    cruising = ObstacleAvoidance(initial_speed=8.0)
    assert [cruising.step(f).speed for f in log((), ())] == [8.0, 8.0]


def test_wall_ahead_at_5_m_is_an_emergency_stop_and_the_car_resumes_once_clear() -> None:
    wall = ((5.0, 5.2, -3.0, 3.0),)
    controller = ObstacleAvoidance(initial_speed=8.0)
    results = replay(controller, log(wall, wall, (), (), (), ()))
    decisions = [r.decision for r in results]
    assert all(d is not None for d in decisions)
    # stopping distance at 8 m/s: 8² / (2 × 4) + 2 = 10 m; the wall's nearest cell [5.0, 5.5) is 5.0 m ahead
    first = decisions[0]
    assert first is not None and first.emergency_stop and first.speed == 0.0 and first.steering == 0.0
    # standing: no second emergency; clear corridor for 3 frames (the resume rule) then cruise from standing
    assert [d.emergency_stop for d in decisions if d] == [True, False, False, False, False, False]
    assert [d.speed for d in decisions if d] == pytest.approx([0.0, 0.0, 0.0, 0.0, 0.15, 0.30])
    again = ObstacleAvoidance(initial_speed=8.0)
    again.step(log(wall)[0])
    assert again.last is not None and again.last.nearest == pytest.approx(5.0)
    assert again.last.stopping_distance == pytest.approx(10.0) and again.last.mode is Mode.STOP


@pytest.mark.parametrize(("side", "sign", "valley"), [((1.3, 3.0), -1, (0, 17)), ((-3.0, -1.3), 1, (18, 35))])
def test_obstacle_on_one_side_steers_to_the_other(side: tuple[float, float], sign: int,
                                                  valley: tuple[int, int]) -> None:
    # a 1 m × 1.7 m block 6-7 m ahead, beside the corridor (|y| ≥ 1.3 > 1.25): its nearest cell (6.25, 1.25) is
    # 11.3° left and 6.37 m away, enlarged by asin(1.5/6.37) = 13.6° its cone reaches -2.3°, short of sector 17's
    # centre (-2.5°), and smoothing leaves sector 17 at 1.8 < 3: the blocked run starts at the goal's sector 18,
    # the valley on the right ends at 17, and the car aims 2 sectors in: sector 15, -87.5 + 15 × 5 = -12.5°
    # (on the right: blocked up to 17, valley (18, 35), sector 20: +12.5°)
    controller = ObstacleAvoidance(initial_speed=8.0)
    steering = [controller.step(f).steering for f in log(*[((6.0, 7.0, *side),)] * 5)]
    assert controller.last is not None and controller.last.vfh is not None
    assert controller.last.vfh.valley == valley
    assert math.degrees(controller.last.vfh.direction) == pytest.approx(sign * 12.5)
    # steering rate limit: 0.6 rad/s × 0.1 s = 0.06 rad per frame, until 12.5° = 0.2182 rad
    assert steering == pytest.approx([sign * 0.06, sign * 0.12, sign * 0.18] + [sign * math.radians(12.5)] * 2)


def test_blind_frames_are_coasted_through_then_the_car_stops() -> None:
    controller = ObstacleAvoidance(initial_speed=8.0)
    blind = [Scene(frame().points.select(np.arange(5)), frame_id=str(i)) for i in range(5)]
    speeds = [controller.step(f).speed for f in blind]
    # 3 blind frames keep 8 m/s; the 4th (more than max_blind_frames) stops: 8 − 4 × 0.1 = 7.6, then 7.2
    assert speeds == pytest.approx([8.0, 8.0, 8.0, 7.6, 7.2])


def test_time_steps_come_from_timestamps_within_limits() -> None:
    controller = ObstacleAvoidance()
    stamps = [10.0, 10.2, 10.2, 15.0]
    speeds = [controller.step(frame(timestamp=t)).speed for t in stamps]
    # dt: no previous stamp → period 0.1; 0.2; a repeated stamp → 0.1; 4.8 s gap → max_dt 0.5;
    # speed += 1.5 × dt: 0.15, 0.45, 0.60, 1.35
    assert speeds == pytest.approx([0.15, 0.45, 0.60, 1.35])


def test_reset_clears_every_state() -> None:
    controller = ObstacleAvoidance(initial_speed=8.0)
    wall = log(((5.0, 5.2, -3.0, 3.0),))
    first = replay(controller, wall + log((), ()))
    assert controller.mode is Mode.STOP and controller.speed == 0.0
    controller.reset()
    assert controller.speed == 8.0 and controller.mode is Mode.CRUISE and controller.plane is None
    assert controller.clear_frames == 0 and not controller.vfh.previous_binary.any()
    assert [r.decision for r in replay(controller, wall + log((), ()))] == [r.decision for r in first]


def test_bad_goal_and_bad_config_are_one_line_errors_naming_the_field() -> None:
    bad = frame().replace(metadata={"goal_direction": "north"})
    result = replay(ObstacleAvoidance(), [bad])[0]
    assert result.failure is not None and result.failure.kind is FailureKind.CRASH
    assert "metadata 'goal_direction' must be a finite number" in result.failure.message
    with pytest.raises(ValidationError, match="threshold_low"):
        ControllerConfig(threshold_low=4.0, threshold_high=3.0)
    with pytest.raises(TypeError, match="config or fields"):
        ObstacleAvoidance(ControllerConfig(), cruise_speed=3.0)


def test_goal_from_the_frame_turns_the_car() -> None:
    controller = ObstacleAvoidance()
    controller.step(frame().replace(metadata={"goal_direction": 0.3}))
    # free road, goal 17.2° (sector 21) well inside the valley: straight at it; steering limited to 0.06
    assert controller.last is not None and controller.last.vfh is not None
    assert controller.last.vfh.direction == pytest.approx(0.3) and controller.steering == pytest.approx(0.06)


def test_speed_states_have_hysteresis() -> None:
    # a post in the corridor at 17, 14, 17, 21, 17 m (its nearest cell [x, x + 0.5) is x ahead): slow below
    # slow_enter 15 m, cruise again only beyond slow_exit 20 m; in between the state is kept
    controller = ObstacleAvoidance(initial_speed=8.0)
    modes, speeds = [], []
    for x in (17.0, 14.0, 17.0, 21.0, 17.0):
        speeds.append(controller.step(frame((x, x + 0.2, -0.3, 0.3))).speed)
        assert controller.last is not None and controller.last.nearest == pytest.approx(x)
        modes.append(controller.last.mode)
    assert modes == [Mode.CRUISE, Mode.SLOW, Mode.SLOW, Mode.CRUISE, Mode.CRUISE]
    # slowing at 4 m/s² × 0.1 s towards 3 m/s: 7.6, 7.2; cruising again at 1.5 × 0.1: 7.35, 7.5
    assert speeds == pytest.approx([8.0, 7.6, 7.2, 7.35, 7.5])


def test_too_little_road_falls_back_to_the_last_trusted_ground() -> None:
    sparse = frame().points.select(np.arange(0, 2320, 80))  # 29 road points: not blind (≥ 20), but < 50 inliers
    controller = ObstacleAvoidance()
    controller.step(frame())
    assert controller.last is not None and controller.last.ground_trusted
    trusted = controller.plane
    controller.step(Scene(sparse, frame_id="sparse"))
    assert controller.last is not None and not controller.last.ground_trusted and not controller.last.blind
    assert controller.plane is trusted and len(controller.last.obstacles) == 0
    # without a plane seen before, the fallback is the road sensor_height (1.73 m) under the sensor
    fresh = ObstacleAvoidance()
    fresh.step(Scene(sparse, frame_id="sparse"))
    assert fresh.last is not None and not fresh.last.ground_trusted and len(fresh.last.obstacles) == 0
