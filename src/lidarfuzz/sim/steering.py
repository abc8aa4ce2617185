"""Steering labels for the camera: the front-wheel angle that brings the ego vehicle along its route.

The label of a frame is the steering angle of a kinematic bicycle model
(:func:`~lidarfuzz.sim.motion.steering_angle`, wheelbase
:data:`~lidarfuzz.sim.terrain.WHEELBASE`) driven by **pure pursuit**: the route point
:data:`LOOKAHEAD` metres further along the route than the vehicle is seen in the vehicle's frame
at ``(x_L, y_L)``, and the arc through the vehicle, tangent to its heading, that reaches it has the
curvature ``κ = 2·y_L / (x_L² + y_L²)``. On the route's centre and heading this holds the route's
curvature (exactly on a circle, ahead of time where a bend begins); off it, it adds the correction
back: an ego vehicle to the right of its lane steers left (positive).

Independent frames have no bend: their ego vehicle is put off its lane's centre by a
:class:`LaneOffset` drawn from the frame's seed, like PilotNet's shifted and rotated camera
views (Bojarski et al., 2016), so the labels vary and the image shows why. Drive logs get their
labels from their route (stops, a turn).

Example (a vehicle 0.5 m right of a straight lane, heading along it: steer back left):
    >>> round(float(pure_pursuit(0.0, -0.5, 0.0, 8.0, 0.0)), 4)  # y_L = 0.5 at x_L = 8
    0.0422
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.sim.motion import steering_angle
from lidarfuzz.sim.spec import SceneSpec
from lidarfuzz.sim.world import ProfiledTrajectory, Trajectory, trajectory_of

#: Metres ahead along the route the pursued point lies (a car's look 0.7–1 s ahead at 30–40 km/h).
LOOKAHEAD = 8.0
#: Ranges of the offsets drawn for independent frames: lateral (metres, left positive; the room a
#: 1.9 m wide car has in a 3.5 m lane) and heading (degrees, left positive).
LATERAL_RANGE = (-0.8, 0.8)
HEADING_RANGE_DEG = (-5.0, 5.0)


def pure_pursuit(x: NDArray[np.float64] | float, y: NDArray[np.float64] | float, yaw: NDArray[np.float64] | float,
                 target_x: NDArray[np.float64] | float, target_y: NDArray[np.float64] | float,
                 ) -> NDArray[np.float64]:
    """Front-wheel angle (rad, left positive) of a vehicle at (x, y) heading ``yaw`` that
    pursues the point (target_x, target_y): ``atan(L · 2·y_L / d²)``."""
    dx, dy = np.asarray(target_x) - np.asarray(x), np.asarray(target_y) - np.asarray(y)
    c, s = np.cos(yaw), np.sin(yaw)
    forward, left = c * dx + s * dy, -s * dx + c * dy
    reach = np.maximum(forward * forward + left * left, 1e-6)
    return steering_angle(2.0 * left / reach)


def route_point(trajectory: Trajectory, s: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The point ``s`` metres along ``trajectory``'s route (straight on past its end)."""
    s = np.asarray(s, np.float64)
    if isinstance(trajectory, ProfiledTrajectory):
        length = trajectory.path.length
        x, y, yaw = trajectory.path.pose(np.minimum(s, length))
        beyond = np.maximum(s - length, 0.0)
        return x + beyond * np.cos(yaw), y + beyond * np.sin(yaw)
    waypoints = trajectory.waypoints
    steps = np.linalg.norm(np.diff(waypoints, axis=0), axis=1)
    keep = np.concatenate([[True], steps > 1e-9])
    waypoints, cumulative = waypoints[keep], np.concatenate([[0.0], np.cumsum(steps[steps > 1e-9])])
    if len(waypoints) < 2:
        return np.full(s.shape, waypoints[0, 0]), np.full(s.shape, waypoints[0, 1])
    x, y = np.interp(s, cumulative, waypoints[:, 0]), np.interp(s, cumulative, waypoints[:, 1])
    last = waypoints[-1] - waypoints[-2]
    last = last / np.linalg.norm(last)
    beyond = np.maximum(s - cumulative[-1], 0.0)
    return x + beyond * last[0], y + beyond * last[1]


@dataclass(frozen=True)
class LaneOffset:
    """Where an independent frame's ego vehicle is put relative to its lane: ``lateral`` metres
    to the left of the lane's centre (negative: right) and ``heading_deg`` degrees turned left."""

    lateral: float
    heading_deg: float

    @staticmethod
    def draw(seed: int) -> LaneOffset:
        """Uniform in :data:`LATERAL_RANGE` × :data:`HEADING_RANGE_DEG`, from ``[seed, 0x57E]``."""
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x57E]))
        lateral, heading = rng.uniform(*LATERAL_RANGE), rng.uniform(*HEADING_RANGE_DEG)
        return LaneOffset(round(float(lateral), 3), round(float(heading), 3))

    def applied(self, spec: SceneSpec) -> SceneSpec:
        """``spec`` with its ego vehicle moved off its lane (a route, if any, is left as it is)."""
        if spec.ego.route is not None:
            return spec
        yaw = np.deg2rad(spec.ego.yaw)
        x, y = spec.ego.position
        moved = (round(x - self.lateral * np.sin(yaw), 4), round(y + self.lateral * np.cos(yaw), 4))
        ego = spec.ego.model_copy(update={"position": moved, "yaw": round(spec.ego.yaw + self.heading_deg, 4)})
        return spec.model_copy(update={"ego": ego})


def steering_labels(spec: SceneSpec, times: NDArray[np.float64], *, lane: SceneSpec | None = None,
                    lookahead: float = LOOKAHEAD) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Steering angle (rad, left positive) and speed (m/s) of ``spec``'s ego vehicle at ``times``.

    The route pursued is the ego's own (a drive log's turn, a scene file's route), or, with
    ``lane``, the ego of ``lane`` (the same scene before :meth:`LaneOffset.applied` moved it):
    the vehicle where ``spec`` puts it pursues the lane it was moved off.
    """
    times = np.asarray(times, np.float64)
    ego = trajectory_of(spec.ego, spec.ego.speed)
    x, y, yaw = ego.at(times)
    speed, _ = ego.kinematics(times)
    route = ego if lane is None else trajectory_of(lane.ego, lane.ego.speed)
    if lane is None:
        along = np.atleast_1d(ego.distance(times)).astype(np.float64)
    else:  # the vehicle's place projected on the lane's route (its own arc length there)
        rx, ry, ryaw = route.at(times)
        along = np.atleast_1d(route.distance(times)).astype(np.float64)
        along = along + (x - rx) * np.cos(ryaw) + (y - ry) * np.sin(ryaw)
    target_x, target_y = route_point(route, along + lookahead)
    return pure_pursuit(x, y, yaw, target_x, target_y), np.asarray(speed, np.float64)


__all__ = ["HEADING_RANGE_DEG", "LATERAL_RANGE", "LOOKAHEAD", "LaneOffset", "pure_pursuit", "route_point",
           "steering_labels"]
