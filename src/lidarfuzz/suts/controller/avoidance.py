"""The obstacle-avoidance and speed controller: the role of ``cObstacleAvoidance`` in Neves et al.'s program.

Each frame, :meth:`ObstacleAvoidance.process`

1. estimates the ground (a RANSAC plane, :func:`~lidarfuzz.suts.classic.ground.ransac_plane`,
   kept from the last frame when this one's is not trusted);
2. classifies obstacle points by elevation and builds the local obstacle map
   (:mod:`~lidarfuzz.suts.controller.obstacles`);
3. asks the :class:`~lidarfuzz.suts.controller.vfh.VFH` for a direction;
4. decides the speed: a cruise / slow / stop state machine with hysteresis (slow down below
   ``slow_enter``, cruise again beyond ``slow_exit``), an **emergency stop** when an obstacle in
   the corridor ahead is nearer than the stopping distance ``v² / (2·a_max) + margin``, and a
   resume rule (the corridor clear beyond ``resume_distance`` for ``resume_frames`` frames);
   acceleration and braking are limited per step;
5. steers towards the direction, limited in angle and in rate.

State carried between frames (cleared by :meth:`reset`): speed, steering, the state, the
counters, the last trusted ground plane, the last timestamp, and the VFH's hysteresis.
Deterministic (RANSAC draws from a seeded generator), configurable (:class:`ControllerConfig`).
Each stage the bug-zoo variants change is a method of its own.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.classic.ground import height_above_plane, ransac_plane
from lidarfuzz.suts.controller.config import ControllerConfig
from lidarfuzz.suts.controller.obstacles import ObstacleMap, classify_elevation, occupancy
from lidarfuzz.suts.controller.vfh import VFH, VfhResult
from lidarfuzz.suts.sequence import Decision, SequenceSystem


class Mode(enum.StrEnum):
    CRUISE = "cruise"
    SLOW = "slow"
    STOP = "stop"


@dataclass(frozen=True)
class Diagnosis:
    """Why the last decision was taken (for tests, reports and relations).

    Attributes:
        mode: The speed state after the frame.
        nearest: Distance ahead of the nearest obstacle cell in the corridor (inf: none).
        stopping_distance: ``v²/(2·a_max) + margin`` at the speed the frame found.
        emergency: Whether the frame triggered an emergency stop.
        blind: Whether the frame had too few points to see anything.
        ground_trusted: Whether this frame's own ground plane was used.
        vfh: The VFH's answer (None on a blind frame).
        obstacles: The obstacle map (empty on a blind frame).
    """

    mode: Mode
    nearest: float
    stopping_distance: float
    emergency: bool
    blind: bool
    ground_trusted: bool
    vfh: VfhResult | None
    obstacles: ObstacleMap


class ObstacleAvoidance(SequenceSystem):
    """Obstacle avoidance (RANSAC ground, elevation classes, VFH) with a cruise/slow/stop speed controller."""

    name = "controller"
    version = "1"
    vfh_class: ClassVar[type[VFH]] = VFH

    def __init__(self, config: ControllerConfig | None = None, **fields: Any) -> None:
        if config is not None and fields:
            raise TypeError("pass a config or fields, not both")
        self.settings = config if config is not None else ControllerConfig(**fields)
        self.max_steering = self.settings.max_steering  # type: ignore[misc]
        self.vfh = self.vfh_class(self.settings)
        self.reset()

    def config(self) -> dict[str, Any]:
        return self.settings.model_dump(mode="json")

    def code_objects(self) -> tuple[Any, ...]:
        return (type(self), self.vfh_class)

    def reset(self) -> None:
        """Back to the start of a log: initial speed, straight, cruising, nothing remembered."""
        self.speed = self.settings.initial_speed
        self.steering = 0.0
        self.mode = Mode.CRUISE
        self.clear_frames = 0
        self.blind_frames = 0
        self.plane: NDArray[np.float64] | None = None
        self.last_time: float | None = None
        self.last: Diagnosis | None = None
        self.vfh.reset()

    def step(self, frame: Scene) -> Decision:
        return self.process(frame)

    # -- stages the variants change ------------------------------------------------------------
    def stopping_distance(self, speed: float) -> float:
        """Distance needed to stop from ``speed`` at full braking, plus the margin."""
        cfg = self.settings
        return speed * speed / (2.0 * cfg.max_decel) + cfg.stop_margin

    def fallback_plane(self) -> NDArray[np.float64]:
        """The ground when this frame's is not trusted: the last trusted plane, else the road
        ``sensor_height`` under the sensor."""
        if self.plane is not None:
            return self.plane
        return np.array([0.0, 0.0, 1.0, self.settings.sensor_height])

    def should_resume(self, corridor_clear: bool) -> bool:
        """In the stop state: count frames with a clear corridor; enough of them in a row resume."""
        self.clear_frames = self.clear_frames + 1 if corridor_clear else 0
        return self.clear_frames >= self.settings.resume_frames

    # -- the whole --------------------------------------------------------------------------------
    def process(self, frame: Scene) -> Decision:
        """The decision on one frame (see the module docstring for the stages)."""
        cfg = self.settings
        # time since the last frame
        stamp = frame.timestamp
        if stamp is None or self.last_time is None:
            dt = cfg.period
        elif stamp <= self.last_time:
            dt = cfg.period  # a repeated or earlier stamp: the log's clock is not to be trusted here
        elif stamp - self.last_time > cfg.max_dt:
            dt = cfg.max_dt
        else:
            dt = stamp - self.last_time
        if stamp is not None:
            self.last_time = stamp
        # the goal, from the frame when it carries one
        goal = math.radians(cfg.goal_direction_deg)
        if "goal_direction" in frame.metadata:
            value = frame.metadata["goal_direction"]
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"frame {frame.frame_id!r}: metadata 'goal_direction' must be a finite number of "
                                 f"radians, got {value!r}")
            goal = float(value)
        xyz = frame.points.xyz.astype(np.float64)
        xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
        reach = np.hypot(xyz[:, 0], xyz[:, 1])
        xyz = xyz[(reach >= cfg.min_range) & (reach <= cfg.max_range)]
        stopping = self.stopping_distance(self.speed)
        vfh: VfhResult | None = None
        obstacles = ObstacleMap.empty()
        nearest = math.inf
        trusted = False
        blind = len(xyz) < cfg.min_points
        if blind:
            self.blind_frames += 1
        else:
            self.blind_frames = 0
            # 1. ground
            plane = ransac_plane(xyz.astype(np.float32), iterations=cfg.ransac_iterations,
                                 threshold=cfg.ground_threshold, sample=cfg.ransac_sample,
                                 max_tilt_deg=cfg.max_tilt_deg, seed=cfg.seed)
            residual = np.abs(xyz @ plane[:3] + plane[3])
            inliers = int(np.count_nonzero(residual < cfg.ground_threshold))
            if inliers < cfg.min_ground_points:
                plane = self.fallback_plane()  # too little road seen to fit it
            elif plane[2] < math.cos(math.radians(cfg.max_tilt_deg)):
                plane = self.fallback_plane()  # the fit fell back to a plane RANSAC did not vouch for
            elif -plane[3] / plane[2] > -0.2 * cfg.sensor_height:
                plane = self.fallback_plane()  # "ground" at the sensor's own height: a wall or a roof
            else:
                trusted = True
                self.plane = plane
            # 2. obstacles by elevation, on the local grid
            height = height_above_plane(xyz.astype(np.float32), plane)
            is_obstacle = classify_elevation(xyz[:, :2], height, xyz[:, 2], cfg)
            obstacles = occupancy(xyz[is_obstacle, :2], height[is_obstacle], cfg)
            corridor = (obstacles.centers[:, 0] > 0.0) & (np.abs(obstacles.centers[:, 1]) < cfg.corridor_half_width)
            if corridor.any():
                nearest = float(obstacles.centers[corridor, 0].min() - cfg.cell / 2.0)
            # 3. a direction
            certainty = np.minimum(1.0, obstacles.counts / cfg.full_cell_points)
            vfh = self.vfh.calculate(obstacles.centers, certainty**2, goal)
        # 4. speed
        emergency = False
        previous_mode = self.mode
        if nearest < stopping and self.speed > 0.0:
            emergency = True
            self.mode = Mode.STOP
            self.clear_frames = 0
        elif blind and self.blind_frames > cfg.max_blind_frames:
            self.mode = Mode.STOP  # blind too long: brake to a stop
            self.clear_frames = 0
        elif blind:
            pass  # coast through a short blackout in the state it found
        elif self.mode is Mode.STOP:
            assert vfh is not None
            clear = not vfh.blocked and nearest > max(cfg.resume_distance, stopping)
            if self.should_resume(clear):
                self.mode = Mode.SLOW if nearest < cfg.slow_exit else Mode.CRUISE
        elif vfh is not None and vfh.blocked:
            self.mode = Mode.STOP  # no way through: stop in front of it
            self.clear_frames = 0
        elif self.mode is Mode.CRUISE and nearest < cfg.slow_enter:
            self.mode = Mode.SLOW
        elif self.mode is Mode.SLOW and nearest > cfg.slow_exit:
            self.mode = Mode.CRUISE
        # 5. steering: towards the direction, limited in angle and in rate
        if emergency or vfh is None or vfh.blocked:
            wanted = self.steering  # hold: no swerving while braking hard, nothing new to steer by
        else:
            wanted = float(np.clip(cfg.steering_gain * vfh.direction, -cfg.max_steering, cfg.max_steering))
        step_limit = cfg.max_steering_rate * dt
        if wanted > self.steering + step_limit:
            steering = self.steering + step_limit
        elif wanted < self.steering - step_limit:
            steering = self.steering - step_limit
        else:
            steering = wanted
        # the target speed of the state, lower while steering hard
        if self.mode is Mode.STOP:
            target = 0.0
        elif self.mode is Mode.SLOW:
            target = cfg.slow_speed
        else:
            target = cfg.cruise_speed
        if abs(steering) > cfg.turn_steering and target > cfg.turn_speed:
            target = cfg.turn_speed
        if emergency:
            speed = 0.0
        elif target > self.speed:
            speed = min(target, self.speed + cfg.max_accel * dt)
            if nearest < self.stopping_distance(speed):
                speed = self.speed  # never speed up into the distance the car needs to stop
        elif target < self.speed:
            speed = max(target, self.speed - cfg.max_decel * dt)
        else:
            speed = self.speed
        if previous_mode is not Mode.STOP and self.mode is Mode.STOP:
            self.clear_frames = 0
        self.speed, self.steering = float(speed), float(steering)
        self.last = Diagnosis(self.mode, nearest, stopping, emergency, blind, trusted, vfh, obstacles)
        return Decision(
            steering=self.steering,
            speed=self.speed,
            emergency_stop=emergency,
            obstacles=self.obstacle_boxes(obstacles, self.plane if trusted else None) if cfg.report_obstacles
            else None,
            path=self.path(),
        )

    def obstacle_boxes(self, obstacles: ObstacleMap, plane: NDArray[np.float64] | None) -> Boxes3D:
        """The obstacle cells as boxes standing on the ground (class ``Obstacle``, score from the points)."""
        if len(obstacles) == 0:
            return Boxes3D.empty()
        ground = plane if plane is not None else self.fallback_plane()
        x, y = obstacles.centers[:, 0], obstacles.centers[:, 1]
        base = -(ground[0] * x + ground[1] * y + ground[3]) / ground[2]
        tops = np.maximum(obstacles.tops, 0.1)
        cell = self.settings.cell
        centers = np.c_[x, y, base + tops / 2.0]
        sizes = np.c_[np.full(len(x), cell), np.full(len(x), cell), tops]
        scores = np.minimum(1.0, obstacles.counts / 20.0)
        return Boxes3D.create(centers, sizes, np.zeros(len(x)), ["Obstacle"] * len(x), scores=scores)

    def path(self) -> tuple[tuple[float, float], ...]:
        """The path ahead the steering points along: five points 2 m apart (none when stopped)."""
        if self.speed <= 0.0:
            return ()
        heading = self.steering / self.settings.steering_gain
        return tuple((float(s * math.cos(heading)), float(s * math.sin(heading))) for s in (2.0, 4.0, 6.0, 8.0, 10.0))
