"""Driving as a vehicle does: routes with rounded corners, and a speed profile with bounded
acceleration, stops and starts.

A road user whose scene entry has any of the motion fields (``speeds``, ``stops``,
``corner_radius``, ``accel``, ``decel``, ``lateral_accel``; :mod:`lidarfuzz.sim.spec`) moves
along a :class:`RoundedPath` with a :class:`SpeedProfile`; one without them keeps the plain
constant-speed polyline motion (:class:`~lidarfuzz.sim.world.Trajectory`), bit for bit.

* **Path.** Each interior corner of the route is replaced by a circular arc of
  ``corner_radius`` tangent to both legs, so the heading is continuous and the curvature is
  bounded by ``1 / corner_radius``. A corner whose legs are too short for the radius gets the
  largest arc that fits (each corner may use up to half of a leg shared with another corner,
  the whole of the first and last legs).
* **Speed.** Each leg has a speed limit (``speeds``, one per leg, or the entry's ``speed``); on
  an arc the limit is lowered to ``sqrt(lateral_accel / |curvature|)``; at every stop and at
  the route's end the speed is zero. The profile is the fastest one that keeps under these
  limits while accelerating at no more than ``accel`` and braking at no more than ``decel``:
  ``v²`` along the path is the lower envelope of the limits and of the cones ``v² + 2·accel·Δs``
  forward and ``v² + 2·decel·Δs`` backward from each limit's ends — exact, piecewise constant
  acceleration, no time stepping. At a stop it stands ``duration`` seconds, then starts again.

Defaults: :data:`ACCEL` 2 m/s² (a calm start), :data:`DECEL` 3 m/s² (a firm, comfortable stop;
emergency braking reaches 8–9 m/s²), :data:`LATERAL_ACCEL` 2 m/s² (a relaxed turn).

Labels: the curvature ``κ`` of the path under the vehicle gives its yaw rate ``v·κ`` and, through
a kinematic bicycle model with the wheelbase :data:`~lidarfuzz.sim.terrain.WHEELBASE` (KITTI's
VW Passat, 2.71 m), its steering angle ``δ = atan(L·κ)`` (:func:`steering_angle`).

Example (10 m/s, a stop at 100 m for 5 s; braking at 3 m/s² starts 100/6 m before it):
    >>> profile = SpeedProfile.plan(300.0, [(0.0, 300.0, 10.0)], stops=[(100.0, 5.0)])
    >>> round(profile.time_at(100.0), 4), round(float(profile.distance(16.0)[0]), 4)  # standing at 16 s
    (11.6667, 100.0)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.sim.terrain import WHEELBASE

ACCEL = 2.0  #: m/s², default acceleration from a stop or to a higher limit
DECEL = 3.0  #: m/s², default deceleration to a stop or a lower limit
LATERAL_ACCEL = 2.0  #: m/s², default lateral acceleration in rounded corners

_EPS = 1e-9


def steering_angle(curvature: NDArray[np.float64] | float, wheelbase: float = WHEELBASE) -> NDArray[np.float64]:
    """Front-wheel angle (rad, left positive) of a kinematic bicycle model following ``curvature``.

    >>> round(float(steering_angle(1 / 10.0)), 6) == round(math.atan(2.71 / 10.0), 6)
    True
    """
    return np.arctan(wheelbase * np.asarray(curvature, np.float64))


# --------------------------------------------------------------------------- path
@dataclass(frozen=True)
class RoundedPath:
    """A polyline with its interior corners rounded by circular arcs: pieces of constant curvature
    (0 for a straight line), each from ``offsets[k]`` to ``offsets[k + 1]`` metres along the path."""

    starts: NDArray[np.float64]  # K×2, where each piece begins
    headings: NDArray[np.float64]  # K, heading where each piece begins (rad)
    curvatures: NDArray[np.float64]  # K, signed (left positive), 1/m
    offsets: NDArray[np.float64]  # K+1, arc length at each piece's start, then the total
    waypoint_offsets: NDArray[np.float64]  # one per waypoint: the arc length nearest it (a corner's arc middle)

    @staticmethod
    def of(waypoints: Sequence[Sequence[float]] | NDArray[np.float64], corner_radius: float | None) -> RoundedPath:
        """Round the corners of ``waypoints`` with arcs of ``corner_radius`` (None or 0: sharp corners,
        the heading changing in an instant as a plain route's does)."""
        points = np.asarray(waypoints, np.float64)
        keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > _EPS])
        index_of = np.cumsum(keep) - 1  # each original waypoint → its kept one
        points = points[keep]
        if len(points) < 2:  # a route that goes nowhere: one point, facing +x
            zero = np.zeros(1)
            return RoundedPath(points[:1], zero, zero, np.zeros(2), np.zeros(len(keep)))
        legs = np.diff(points, axis=0)
        lengths = np.linalg.norm(legs, axis=1)
        units = legs / lengths[:, None]
        headings = np.arctan2(units[:, 1], units[:, 0])
        turns = np.angle(np.exp(1j * np.diff(headings)))  # at each interior corner, in (−π, π]
        radius = corner_radius or 0.0
        n_legs = len(lengths)
        tangent = np.zeros(n_legs + 1)  # tangent length used at each waypoint (0 at both ends)
        radii = np.zeros(n_legs + 1)
        for corner in range(1, n_legs):
            half_turn = abs(turns[corner - 1]) / 2
            if radius <= 0 or half_turn < _EPS or math.tan(half_turn) > 1e12:
                continue
            before = lengths[corner - 1] if corner == 1 else lengths[corner - 1] / 2
            after = lengths[corner] if corner == n_legs - 1 else lengths[corner] / 2
            radii[corner] = min(radius, min(before, after) / math.tan(half_turn))
            tangent[corner] = radii[corner] * math.tan(half_turn)
        starts, piece_headings, curvatures, pieces = [], [], [], []
        waypoint_offsets = np.zeros(len(points))
        travelled = 0.0
        for leg in range(n_legs):
            start = points[leg] + tangent[leg] * units[leg]
            straight = lengths[leg] - tangent[leg] - tangent[leg + 1]
            starts.append(start)
            piece_headings.append(headings[leg])
            curvatures.append(0.0)
            pieces.append(max(straight, 0.0))
            travelled += pieces[-1]
            corner = leg + 1
            if corner < n_legs and radii[corner] > 0:
                turn = turns[corner - 1]
                arc = radii[corner] * abs(turn)
                starts.append(points[corner] - tangent[corner] * units[leg])
                piece_headings.append(headings[leg])
                curvatures.append(math.copysign(1.0 / radii[corner], turn))
                pieces.append(arc)
                waypoint_offsets[corner] = travelled + arc / 2
                travelled += arc
            else:
                waypoint_offsets[corner] = travelled
        offsets = np.concatenate([[0.0], np.cumsum(pieces)])
        return RoundedPath(np.asarray(starts), np.asarray(piece_headings), np.asarray(curvatures), offsets,
                           waypoint_offsets[index_of])

    @property
    def length(self) -> float:
        return float(self.offsets[-1])

    def _piece(self, s: NDArray[np.float64]) -> NDArray[np.intp]:
        return np.clip(np.searchsorted(self.offsets, s, side="right") - 1, 0, len(self.headings) - 1)

    def pose(self, s: NDArray[np.float64] | float
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(x, y, heading) at arc length(s) ``s``: before 0 along the first heading, beyond the end at the end."""
        s = np.minimum(np.atleast_1d(np.asarray(s, np.float64)), self.length)
        k = self._piece(s)
        along = s - self.offsets[k]
        h0, kappa = self.headings[k], self.curvatures[k]
        heading = h0 + kappa * along
        curved = np.abs(kappa) > 0
        safe = np.where(curved, kappa, 1.0)
        dx = np.where(curved, (np.sin(heading) - np.sin(h0)) / safe, along * np.cos(h0))
        dy = np.where(curved, (np.cos(h0) - np.cos(heading)) / safe, along * np.sin(h0))
        return self.starts[k, 0] + dx, self.starts[k, 1] + dy, np.angle(np.exp(1j * heading))

    def curvature(self, s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Signed curvature (1/m, left positive) at ``s``; 0 before the start and beyond the end."""
        s = np.atleast_1d(np.asarray(s, np.float64))
        inside = (s >= 0) & (s < self.length)
        return np.where(inside, self.curvatures[self._piece(s)], 0.0)


# --------------------------------------------------------------------------- speed
@dataclass(frozen=True)
class SpeedProfile:
    """Distance and speed over time: pieces of constant acceleration from knot ``k`` (time
    ``times[k]``, distance ``distances[k]``, speed ``speeds[k]``, acceleration ``accels[k]``) to knot
    ``k + 1``. Before time 0 it extrapolates at the start speed; after the last knot it stands."""

    times: NDArray[np.float64]
    distances: NDArray[np.float64]
    speeds: NDArray[np.float64]
    accels: NDArray[np.float64]  # one fewer than the knots

    @staticmethod
    def plan(length: float, limits: Sequence[tuple[float, float, float]], *,
             stops: Sequence[tuple[float, float]] = (), accel: float = ACCEL, decel: float = DECEL) -> SpeedProfile:
        """The fastest profile over ``[0, length]`` under ``limits`` (``(from, to, max speed)``
        intervals; the start speed is the first limit's), standing at each ``(at, duration)``
        stop and at the end, accelerating at most ``accel`` and braking at most ``decel``."""
        if accel <= 0 or decel <= 0:
            raise ValueError("accel and decel must be positive")
        lines = _envelope_constraints(length, limits, stops, accel, decel)
        knots_s, knots_u = _lower_envelope(lines, length)
        dwell: dict[float, float] = {}
        for at, duration in stops:
            key = float(min(max(at, 0.0), length))
            dwell[key] = dwell.get(key, 0.0) + duration
        times, distances, speeds, accels = [0.0], [float(knots_s[0])], [math.sqrt(knots_u[0])], []

        def stand(at: float) -> None:
            for stop_at, duration in list(dwell.items()):
                if abs(stop_at - at) < 1e-6 and duration > 0 and speeds[-1] < 1e-6:
                    del dwell[stop_at]  # once, however many knots lie at the stop
                    accels.append(0.0)
                    times.append(times[-1] + duration)
                    distances.append(distances[-1])
                    speeds.append(0.0)

        stand(distances[0])
        for k in range(len(knots_s) - 1):
            ds = knots_s[k + 1] - knots_s[k]
            v0, v1 = math.sqrt(knots_u[k]), math.sqrt(knots_u[k + 1])
            if v0 + v1 < 1e-9:  # a stretch it never moves along: it stands here for good
                break
            a = (knots_u[k + 1] - knots_u[k]) / (2 * ds)
            dt = (v1 - v0) / a if abs(a) > 1e-12 else ds / v0
            accels.append(a)
            times.append(times[-1] + dt)
            distances.append(float(knots_s[k + 1]))
            speeds.append(v1)
            stand(distances[-1])
        return SpeedProfile(np.asarray(times), np.asarray(distances), np.asarray(speeds), np.asarray(accels))

    @property
    def duration(self) -> float:
        """Seconds from the start until it stands at its end for good."""
        return float(self.times[-1])

    @property
    def top_speed(self) -> float:
        return float(self.speeds.max())

    def _state(self, t: NDArray[np.float64] | float
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        t = np.atleast_1d(np.asarray(t, np.float64))
        if len(self.accels) == 0:
            n = len(t)
            return np.full(n, self.distances[0]), np.zeros(n), np.zeros(n)
        k = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.accels) - 1)
        tau = np.clip(t - self.times[k], None, self.times[k + 1] - self.times[k])
        a = self.accels[k]
        s = self.distances[k] + self.speeds[k] * tau + 0.5 * a * tau**2
        v = self.speeds[k] + a * tau
        before = t < 0
        s = np.where(before, self.distances[0] + self.speeds[0] * t, s)
        v = np.where(before, self.speeds[0], v)
        a = np.where(before | (t >= self.times[-1]), 0.0, a)
        v = np.where(t >= self.times[-1], 0.0, v)
        return s, np.maximum(v, 0.0), a

    def distance(self, t: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Metres along the path at time(s) ``t``."""
        return self._state(t)[0]

    def speed(self, t: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """m/s at time(s) ``t``."""
        return self._state(t)[1]

    def acceleration(self, t: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """m/s² at time(s) ``t`` (the piece's; at a knot, the piece that starts there)."""
        return self._state(t)[2]

    def time_at(self, s: float) -> float:
        """The first time it reaches ``s`` metres (``inf`` when it never does)."""
        if s <= self.distances[0]:
            return float(self.times[0] + (s - self.distances[0]) / self.speeds[0]) if self.speeds[0] > 0 else 0.0
        for k in range(len(self.accels)):
            if self.distances[k + 1] >= s - 1e-12:
                v0, a, ds = self.speeds[k], self.accels[k], s - self.distances[k]
                if abs(a) < 1e-12:
                    return float(self.times[k] + ds / v0)
                v = math.sqrt(max(v0 * v0 + 2 * a * ds, 0.0))
                return float(self.times[k] + (v - v0) / a)
        return math.inf


def _envelope_constraints(length: float, limits: Sequence[tuple[float, float, float]],
                          stops: Sequence[tuple[float, float]], accel: float, decel: float,
                          ) -> list[tuple[float, float, float, float]]:
    """Upper bounds on ``u = v²``: ``(lo, hi, u at lo, slope)`` lines, each valid on ``[lo, hi]``."""
    lines = []
    for lo, hi, speed in limits:
        lo, hi = max(lo, 0.0), min(hi, length)
        if hi < lo:
            continue
        u = speed * speed
        lines.append((lo, hi, u, 0.0))
        lines.append((hi, length, u, 2 * accel))  # accelerating away from the limit's end
        lines.append((0.0, lo, u + 2 * decel * lo, -2 * decel))  # braking towards its start
    if limits:  # the start speed is the first limit's
        u0 = limits[0][2] ** 2
        lines.append((0.0, length, u0, 2 * accel))
    for at, _duration in (*stops, (length, 0.0)):
        at = min(max(at, 0.0), length)
        lines.append((at, length, 0.0, 2 * accel))
        lines.append((0.0, at, 2 * decel * at, -2 * decel))
    return lines


def _lower_envelope(lines: list[tuple[float, float, float, float]], length: float
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Knots (s, u) of the lower envelope of ``lines`` over ``[0, length]``; it is piecewise linear
    with breaks only at the lines' ends and their pairwise crossings."""
    lo, hi, u0, slope = (np.array(column, np.float64) for column in zip(*lines, strict=True))
    intercept = u0 - slope * lo  # u = intercept + slope · s
    with np.errstate(divide="ignore", invalid="ignore"):
        crossings = (intercept[None, :] - intercept[:, None]) / (slope[:, None] - slope[None, :])
    candidates = np.concatenate([[0.0, length], lo, hi, crossings[np.isfinite(crossings)]])
    candidates = np.unique(np.clip(candidates, 0.0, length))
    candidates = candidates[np.concatenate([[True], np.diff(candidates) > 1e-9])]
    if length <= 0 or len(candidates) < 2:
        return np.array([0.0]), np.array([0.0])

    def envelope(s: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
        valid = (lo[None, :] <= s[:, None] + 1e-12) & (s[:, None] <= hi[None, :] + 1e-12)
        values = np.where(valid, intercept[None, :] + slope[None, :] * s[:, None], np.inf)
        best = np.argmin(values, axis=1)
        return values[np.arange(len(s)), best], best

    _, piece = envelope((candidates[:-1] + candidates[1:]) / 2)
    u = np.empty(len(candidates))
    u[:-1] = intercept[piece] + slope[piece] * candidates[:-1]
    u[-1] = intercept[piece[-1]] + slope[piece[-1]] * candidates[-1]
    # Where two pieces meet the envelope is continuous; take the smaller value against rounding.
    inner = intercept[piece[:-1]] + slope[piece[:-1]] * candidates[1:-1]
    u[1:-1] = np.minimum(u[1:-1], inner)
    u = np.maximum(u, 0.0)
    # Merge collinear neighbours: fewer, longer pieces.
    keep = np.ones(len(candidates), bool)
    for k in range(1, len(candidates) - 1):
        left = (u[k] - u[k - 1]) / (candidates[k] - candidates[k - 1])
        right = (u[k + 1] - u[k]) / (candidates[k + 1] - candidates[k])
        keep[k] = abs(left - right) > 1e-9 * max(1.0, abs(left), abs(right))
    return candidates[keep], u[keep]


__all__ = ["ACCEL", "DECEL", "LATERAL_ACCEL", "RoundedPath", "SpeedProfile", "steering_angle"]
