"""Ground removal: a RANSAC plane, or the lowest point of each grid cell.

Both return each point's height above the ground model; the pipeline calls points lower
than ``ground_threshold`` ground.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def ransac_plane(
    xyz: NDArray[np.float32], *, iterations: int, threshold: float, sample: int, max_tilt_deg: float, seed: int
) -> NDArray[np.float64]:
    """The plane ``[a, b, c, d]`` (``ax + by + cz + d = 0``, ``c > 0``, unit normal) with the most
    inliers among hypotheses from three low points; refitted by least squares on its inliers.

    Hypotheses come only from the lowest tenth of the points (the road, not walls), planes
    steeper than ``max_tilt_deg`` are rejected, and the result is deterministic for a seed.
    Without enough points the horizontal plane through the lowest decile is returned.
    """
    rng = np.random.default_rng(seed)
    p = xyz.astype(np.float64)
    if len(p) < 3:
        return np.array([0.0, 0.0, 1.0, -(float(p[:, 2].min()) if len(p) else 0.0)])
    low_cut = np.quantile(p[:: max(1, len(p) // 20000), 2], 0.1)  # on a stride: the decile barely moves
    low = p[p[:, 2] <= low_cut + 0.3]
    scored = p[rng.choice(len(p), size=min(sample, len(p)), replace=False)]
    best, best_count = np.array([0.0, 0.0, 1.0, -low_cut]), -1
    min_cos = np.cos(np.deg2rad(max_tilt_deg))
    for _ in range(iterations):
        a, b, c = low[rng.choice(len(low), size=3, replace=False)] if len(low) >= 3 else p[:3]
        normal = np.cross(b - a, c - a)
        norm = np.linalg.norm(normal)
        if norm < 1e-9:
            continue
        normal /= norm
        if normal[2] < 0:
            normal = -normal
        if normal[2] < min_cos:
            continue
        d = -normal @ a
        count = int(np.count_nonzero(np.abs(scored @ normal + d) < threshold))
        if count > best_count:
            best, best_count = np.r_[normal, d], count
    inliers = scored[np.abs(scored @ best[:3] + best[3]) < threshold]
    if len(inliers) >= 3:
        # least squares z = ux + vy + w on the inliers
        design = np.c_[inliers[:, :2], np.ones(len(inliers))]
        (u, v, w), *_ = np.linalg.lstsq(design, inliers[:, 2], rcond=None)
        normal = np.array([-u, -v, 1.0])
        scale = np.linalg.norm(normal)
        best = np.r_[normal / scale, -w / scale]
    return best


def height_above_plane(xyz: NDArray[np.float32], plane: NDArray[np.float64]) -> NDArray[np.float64]:
    return xyz.astype(np.float64) @ plane[:3] + plane[3]


def height_above_grid(xyz: NDArray[np.float32], cell: float) -> NDArray[np.float64]:
    """Height of each point above the lowest point of its ``cell`` × ``cell`` column."""
    if len(xyz) == 0:
        return np.zeros(0)
    ij = np.floor(xyz[:, :2] / cell).astype(np.int64)
    _, cell_of = np.unique(ij, axis=0, return_inverse=True)
    cell_of = cell_of.reshape(-1)
    lowest = np.full(int(cell_of.max()) + 1, np.inf)
    np.minimum.at(lowest, cell_of, xyz[:, 2].astype(np.float64))
    return xyz[:, 2].astype(np.float64) - lowest[cell_of]
