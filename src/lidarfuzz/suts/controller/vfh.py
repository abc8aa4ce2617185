"""The Vector Field Histogram (Borenstein & Koren 1991, with VFH+'s enlargement and hysteresis).

Directions ahead of the car are cut into sectors (5° over the forward half-plane by default;
sector 0 is the rightmost, angles are left positive). Each obstacle cell within the active window
(``window_radius``) adds its magnitude — its weight times ``1 − d / window_radius`` — to every
sector whose centre direction lies in the cell's cone once the obstacle is enlarged by the car's
radius plus a safety distance (``asin(r / d)`` either side; VFH+'s enlargement). The histogram is
smoothed over neighbouring sectors and thresholded with hysteresis into blocked and free sectors;
runs of free sectors are valleys. The valley nearest the goal direction is chosen: in a wide
valley the car keeps ``wide_valley / 2`` sectors off the border nearest the goal (or heads
straight for the goal when it lies well inside), in a narrow one it aims at the middle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.suts.controller.config import ControllerConfig


@dataclass(frozen=True)
class VfhResult:
    """What :meth:`VFH.calculate` found.

    Attributes:
        direction: The chosen direction (rad, left positive); the previous one when blocked.
        blocked: True when no sector is free.
        valley: First and last sector of the chosen valley (None when blocked).
        wide: Whether the chosen valley is wide.
        goal_sector: The sector of the goal direction.
        histogram: The smoothed polar obstacle density per sector.
        binary: True for blocked sectors.
    """

    direction: float
    blocked: bool
    valley: tuple[int, int] | None
    wide: bool
    goal_sector: int
    histogram: NDArray[np.float64]
    binary: NDArray[np.bool_]


class VFH:
    """A vector field histogram with memory: the blocked sectors of the last call (hysteresis)
    and the last direction (ties, and the direction held while every sector is blocked).

    Example:
        >>> vfh = VFH(ControllerConfig())
        >>> free = vfh.calculate(np.zeros((0, 2)), np.zeros(0), goal=0.0)
        >>> free.direction, free.blocked, free.valley
        (0.0, False, (0, 35))
    """

    def __init__(self, config: ControllerConfig) -> None:
        self.config = config
        self.half_fov = math.radians(config.field_of_view_deg) / 2.0
        self.sector = math.radians(config.sector_deg)
        self.n_sectors = max(1, round(2.0 * self.half_fov / self.sector))
        self.reset()

    def reset(self) -> None:
        """Forget the previous call: every sector free, straight ahead."""
        self.previous_binary = np.zeros(self.n_sectors, dtype=bool)
        self.previous_direction = 0.0

    def sector_of(self, angle: NDArray[np.float64]) -> NDArray[np.int64]:
        """The sector index of each angle (angles outside the field of view go to its edge sectors)."""
        index = np.floor((np.asarray(angle, dtype=np.float64) + self.half_fov) / self.sector).astype(np.int64)
        return np.clip(index, 0, self.n_sectors - 1)

    def angle_of(self, sector: float) -> float:
        """The direction of a sector's centre (a fractional sector gives the angle between centres)."""
        return -self.half_fov + (sector + 0.5) * self.sector

    def smooth(self, histogram: NDArray[np.float64]) -> NDArray[np.float64]:
        """VFH's smoothing: weights 1, 2, …, l + 1, …, 2, 1 over ``l`` sectors each side, divided
        by 2l + 1; the edge sectors are repeated beyond the field of view."""
        width = self.config.smoothing
        if width == 0:
            return histogram.copy()
        padded = np.pad(histogram, width, mode="edge")
        kernel = (width + 1 - np.abs(np.arange(-width, width + 1))).astype(np.float64)
        return np.convolve(padded, kernel, mode="valid") / (2 * width + 1)

    def threshold(self, smoothed: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Blocked sectors, with hysteresis: above ``threshold_high`` a sector is blocked, below
        ``threshold_low`` free, and in between it keeps its state of the last call."""
        binary = self.previous_binary.copy()
        binary[smoothed > self.config.threshold_high] = True
        binary[smoothed < self.config.threshold_low] = False
        return binary

    def calculate(self, obstacles: NDArray[np.float64], weights: NDArray[np.float64], goal: float) -> VfhResult:
        """The direction to drive in, from obstacle cells (M×2 ``x, y`` in metres, their weights)
        and the goal direction (rad, left positive).

        Example (one cell 10 m ahead weighing 24, no smoothing: a density of 24 × (1 − 10/12) = 4
        blocks the four sectors whose centres lie within asin(1.5/10) = 8.6° of straight ahead, and
        the car keeps 2 sectors off the border of the nearest valley, on the left):
            >>> vfh = VFH(ControllerConfig(smoothing=0))
            >>> r = vfh.calculate(np.array([[10.0, 0.0]]), np.array([24.0]), goal=0.0)
            >>> round(float(r.histogram.max()), 6), np.flatnonzero(r.binary).tolist(), r.valley
            (4.0, [16, 17, 18, 19], (20, 35))
            >>> round(math.degrees(r.direction), 6)
            22.5
        """
        cfg = self.config
        n = self.n_sectors
        obstacles = np.asarray(obstacles, dtype=np.float64).reshape(-1, 2)
        weights = np.asarray(weights, dtype=np.float64).reshape(-1)
        if len(weights) != len(obstacles):
            raise ValueError(f"VFH: {len(obstacles)} obstacle cells but {len(weights)} weights")
        finite = np.all(np.isfinite(obstacles), axis=1) & np.isfinite(weights)
        if not finite.all():
            obstacles, weights = obstacles[finite], weights[finite]  # a cell without a place adds nothing
        if (weights < 0).any():
            raise ValueError(f"VFH: weights must be ≥ 0, got {float(weights.min()):g}")
        # the goal, inside the field of view
        if not math.isfinite(goal):
            goal = self.previous_direction
        if goal > self.half_fov:
            goal = self.half_fov
        elif goal < -self.half_fov:
            goal = -self.half_fov
        goal_sector = int(self.sector_of(np.array(goal)))
        # polar obstacle density
        histogram = np.zeros(n)
        if len(obstacles):
            distance = np.hypot(obstacles[:, 0], obstacles[:, 1])
            near = (distance > 1e-6) & (distance < cfg.window_radius) & (weights > 0)
            if near.any():
                xy, d, w = obstacles[near], distance[near], weights[near]
                angle = np.arctan2(xy[:, 1], xy[:, 0])
                magnitude = w * (1.0 - d / cfg.window_radius)
                radius = cfg.robot_radius + cfg.safety_distance
                # an obstacle within the enlargement radius covers half the circle
                spread = np.where(d > radius, np.arcsin(np.minimum(1.0, radius / np.maximum(d, 1e-9))), np.pi / 2)
                low, high = angle - spread, angle + spread
                # a sector is covered when its centre direction lies in the enlarged cone
                half_sector = self.sector / 2.0
                seen = (high >= -self.half_fov + half_sector) & (low <= self.half_fov - half_sector)
                if seen.any():
                    first = self.sector_of(low[seen] + half_sector)
                    last = self.sector_of(high[seen] - half_sector)
                    sectors = np.arange(n)
                    covered = (sectors[None, :] >= first[:, None]) & (sectors[None, :] <= last[:, None])
                    histogram = magnitude[seen] @ covered
        smoothed = self.smooth(histogram)
        binary = self.previous_binary = self.threshold(smoothed)
        # valleys: runs of free sectors
        free = ~binary
        edges = np.diff(np.r_[0, free.astype(np.int8), 0])
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
        if len(starts) == 0:
            return VfhResult(self.previous_direction, True, None, False, goal_sector, smoothed, binary)
        # the valley nearest the goal sector
        gaps = np.where((starts <= goal_sector) & (goal_sector <= ends), 0,
                        np.minimum(np.abs(starts - goal_sector), np.abs(ends - goal_sector)))
        nearest = np.flatnonzero(gaps == gaps.min())
        if len(nearest) == 1:
            chosen = int(nearest[0])
        else:
            # a tie: keep to the side the car is already turning to, else the right (lower sectors)
            left = [int(k) for k in nearest if ends[k] > goal_sector]
            right = [int(k) for k in nearest if starts[k] < goal_sector]
            if self.previous_direction > 0 and left:
                chosen = left[0]
            elif right:
                chosen = right[-1]
            else:
                chosen = int(nearest[0])
        start, end = int(starts[chosen]), int(ends[chosen])
        width = end - start + 1
        wide = width >= cfg.wide_valley
        half = cfg.wide_valley // 2
        if wide:
            if start <= goal_sector <= end:
                if goal_sector - start >= half and end - goal_sector >= half:
                    direction = goal  # well inside the valley: straight at the goal
                elif goal_sector - start < half:
                    direction = self.angle_of(start + half)  # too near the right border
                else:
                    direction = self.angle_of(end - half)  # too near the left border
            elif goal_sector < start:
                direction = self.angle_of(start + half)  # near border on the right of the valley
            else:
                direction = self.angle_of(end - half)
        elif start <= goal_sector <= end and width == 1:
            direction = goal  # a one-sector valley holding the goal: no better aim
        else:
            direction = self.angle_of((start + end) / 2.0)  # narrow: through the middle
        if direction > self.half_fov:
            direction = self.half_fov
        elif direction < -self.half_fov:
            direction = -self.half_fov
        self.previous_direction = direction = float(direction)
        return VfhResult(direction, False, (start, end), wide, goal_sector, smoothed, binary)
