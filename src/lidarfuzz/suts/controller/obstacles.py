"""Obstacle classification by elevation, on a local grid.

A point is an obstacle point when its height above the ground estimate lies in the band
``[min_height, max_height]`` (lower: road, kerbs, debris the car drives over; higher: branches
and bridges it passes under), or when it stands ``step_height`` above the lowest point of its
grid cell — a relative height difference, which finds obstacles even where the ground plane is
off (a slope, a misfit) — and is still under ``max_height``. Cells with at least
``min_cell_points`` obstacle points form the obstacle map: their centres and point counts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.suts.controller.config import ControllerConfig


@dataclass(frozen=True)
class ObstacleMap:
    """Occupied cells of the local grid.

    Attributes:
        centers: M×2 cell centres ``x, y`` (m).
        counts: Obstacle points per cell.
        tops: Highest obstacle point per cell, as height above ground (m).
    """

    centers: NDArray[np.float64]
    counts: NDArray[np.float64]
    tops: NDArray[np.float64]

    @classmethod
    def empty(cls) -> ObstacleMap:
        return cls(np.zeros((0, 2)), np.zeros(0), np.zeros(0))

    def __len__(self) -> int:
        return len(self.counts)


def cell_index(xy: NDArray[np.float64], cell: float) -> tuple[NDArray[np.int64], int]:
    """Each point's cell as one flat index into the dense grid spanning the points, and the grid's
    size (a dense grid, not ``np.unique`` over rows: one pass instead of a sort)."""
    ij = np.floor(xy / cell).astype(np.int64)
    low = ij.min(axis=0)
    ij -= low
    width = int(ij[:, 1].max()) + 1
    return ij[:, 0] * width + ij[:, 1], (int(ij[:, 0].max()) + 1) * width


def relative_heights(xy: NDArray[np.float64], z: NDArray[np.float64], cell: float) -> NDArray[np.float64]:
    """Each point's height above the lowest point of its ``cell`` × ``cell`` column.

    Example:
        >>> xy = np.array([[0.1, 0.1], [0.2, 0.3], [5.0, 5.0]])
        >>> relative_heights(xy, np.array([-1.7, -1.0, -1.7]), 0.5).round(2).tolist()
        [0.0, 0.7, 0.0]
    """
    if len(z) == 0:
        return np.zeros(0)
    cell_of, size = cell_index(xy, cell)
    lowest = np.full(size, np.inf)
    np.minimum.at(lowest, cell_of, z)
    return z - lowest[cell_of]


def classify_elevation(xy: NDArray[np.float64], height: NDArray[np.float64], z: NDArray[np.float64],
                       config: ControllerConfig) -> NDArray[np.bool_]:
    """The obstacle points: in the height band above ground, or a step above their cell's lowest
    point (and under ``max_height`` either way)."""
    in_band = (height >= config.min_height) & (height <= config.max_height)
    step = relative_heights(xy, z, config.cell) >= config.step_height
    return (in_band | step) & (height <= config.max_height)


def occupancy(xy: NDArray[np.float64], height: NDArray[np.float64], config: ControllerConfig) -> ObstacleMap:
    """The cells holding at least ``min_cell_points`` of the given obstacle points."""
    if len(xy) == 0:
        return ObstacleMap.empty()
    ij = np.floor(xy / config.cell).astype(np.int64)
    cell_of, size = cell_index(xy, config.cell)
    counts = np.bincount(cell_of, minlength=size)
    tops = np.full(size, -np.inf)
    np.maximum.at(tops, cell_of, height)
    keep = np.flatnonzero(counts >= config.min_cell_points)
    # a kept cell's integer coordinates: those of any of its points (the first)
    first = np.full(size, len(cell_of))
    np.minimum.at(first, cell_of, np.arange(len(cell_of)))
    centers = (ij[first[keep]].astype(np.float64) + 0.5) * config.cell
    return ObstacleMap(centers, counts[keep].astype(np.float64), tops[keep])
