"""Vectorised box geometry on CPU: corners, points in boxes, rotated BEV and 3D IoU.

Boxes are M×7 arrays ``[x, y, z, l, w, h, yaw]`` in the LiDAR frame with the centre
as origin (see :mod:`lidarfuzz.scene.boxes`). Rotated overlaps are exact polygon
clips done by shapely (GEOS) on all candidate pairs at once; pairs whose bounding
circles do not touch are skipped. Boxes with NaN geometry overlap nothing.
"""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray

# Unit corners: bottom face counter-clockwise seen from above, starting front-right,
# then the top face in the same order.
_UNIT_CORNERS = np.array(
    [
        [0.5, -0.5, -0.5],
        [0.5, 0.5, -0.5],
        [-0.5, 0.5, -0.5],
        [-0.5, -0.5, -0.5],
        [0.5, -0.5, 0.5],
        [0.5, 0.5, 0.5],
        [-0.5, 0.5, 0.5],
        [-0.5, -0.5, 0.5],
    ]
)


def _boxes(boxes: ArrayLike) -> NDArray[np.float64]:
    array = np.asarray(boxes, dtype=np.float64)
    if array.size == 0:
        return array.reshape(0, 7)
    if array.ndim != 2 or array.shape[1] != 7:
        raise ValueError(f"boxes must be M×7 [x, y, z, l, w, h, yaw], got shape {array.shape}")
    return array


def box_corners(boxes: ArrayLike) -> NDArray[np.float64]:
    """M×8×3 corners (bottom face then top face, each counter-clockwise from front-right).

    Example:
        >>> box_corners([[0, 0, 0, 2, 1, 1, 0]])[0, 0].tolist()
        [1.0, -0.5, -0.5]
    """
    b = _boxes(boxes)
    local = _UNIT_CORNERS[None, :, :] * b[:, None, 3:6]
    c, s = np.cos(b[:, 6])[:, None], np.sin(b[:, 6])[:, None]
    x = local[..., 0] * c - local[..., 1] * s
    y = local[..., 0] * s + local[..., 1] * c
    return np.stack([x, y, local[..., 2]], axis=-1) + b[:, None, :3]


def bev_corners(boxes: ArrayLike) -> NDArray[np.float64]:
    """M×4×2 bird's-eye-view footprint corners, counter-clockwise."""
    return box_corners(boxes)[:, :4, :2]


def points_in_boxes(points: ArrayLike, boxes: ArrayLike, margin: float = 0.0) -> NDArray[np.bool_]:
    """N×M mask: point i lies in box j (faces included, optionally grown by ``margin`` metres).

    Points are sorted by x once so that each box only tests the points in its x-extent;
    the cost is O(N log N + Σ points near each box) rather than O(N·M).
    """
    xyz = np.asarray(points, dtype=np.float64)
    xyz = xyz.reshape(0, 3) if xyz.size == 0 else xyz[:, :3]
    b = _boxes(boxes)
    n, m = xyz.shape[0], b.shape[0]
    mask = np.zeros((n, m), dtype=bool)
    if n == 0 or m == 0:
        return mask
    order = np.argsort(xyz[:, 0], kind="stable")
    xs = xyz[order, 0]
    half = b[:, 3:6] / 2.0 + margin
    radius = np.hypot(half[:, 0], half[:, 1])
    lo = np.searchsorted(xs, b[:, 0] - radius, side="left")
    hi = np.searchsorted(xs, b[:, 0] + radius, side="right")
    cos, sin = np.cos(b[:, 6]), np.sin(b[:, 6])
    for j in range(m):
        if not np.all(np.isfinite(b[j])) or hi[j] <= lo[j]:
            continue
        idx = order[lo[j] : hi[j]]
        d = xyz[idx] - b[j, :3]
        local_x = d[:, 0] * cos[j] + d[:, 1] * sin[j]
        local_y = -d[:, 0] * sin[j] + d[:, 1] * cos[j]
        inside = (
            (np.abs(local_x) <= half[j, 0])
            & (np.abs(local_y) <= half[j, 1])
            & (np.abs(d[:, 2]) <= half[j, 2])
        )
        mask[idx[inside], j] = True
    return mask


def box_index_of_points(points: ArrayLike, boxes: ArrayLike, margin: float = 0.0) -> NDArray[np.int64]:
    """For each point, the index of the first box containing it, or -1."""
    mask = points_in_boxes(points, boxes, margin)
    if mask.shape[1] == 0:
        return np.full(mask.shape[0], -1, dtype=np.int64)
    first = np.argmax(mask, axis=1).astype(np.int64)
    first[~mask.any(axis=1)] = -1
    return first


def _polygons(boxes: NDArray[np.float64]) -> NDArray[np.object_]:
    return shapely.polygons(bev_corners(boxes))


#: Precision grid for re-clipping pairs GEOS reports as disjoint (see :func:`polygon_intersection_area`).
_SNAP_GRID = 1e-9


def polygon_intersection_area(polys_a: NDArray[np.object_], polys_b: NDArray[np.object_]) -> NDArray[np.float64]:
    """Element-wise intersection area of two arrays of polygons, robust to coincident edges.

    Plain GEOS overlay can answer an empty intersection for two footprints whose edges
    coincide up to rounding (a box and the same box turned by π). Pairs it calls disjoint
    are clipped again on a 1e-9 m precision grid, which gets them right; pairs that really
    are disjoint stay at 0. Only those pairs pay for the second clip.
    """
    area = np.asarray(shapely.area(shapely.intersection(polys_a, polys_b)), dtype=np.float64)
    empty = np.flatnonzero(area <= 0.0)
    if empty.size:
        touching = empty[shapely.intersects(polys_a[empty], polys_b[empty])]
        if touching.size:
            area[touching] = shapely.area(
                shapely.intersection(polys_a[touching], polys_b[touching], grid_size=_SNAP_GRID)
            )
    return area


def _candidates(a: NDArray[np.float64], b: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    ra = np.hypot(a[:, 3], a[:, 4]) / 2.0
    rb = np.hypot(b[:, 3], b[:, 4]) / 2.0
    dist = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
    with np.errstate(invalid="ignore"):
        close = dist < (ra[:, None] + rb[None, :])
    rows, cols = np.nonzero(close)
    return rows, cols


def bev_intersection_area(boxes_a: ArrayLike, boxes_b: ArrayLike) -> NDArray[np.float64]:
    """M×K area of the rotated BEV footprints' intersection (square metres)."""
    a, b = _boxes(boxes_a), _boxes(boxes_b)
    area = np.zeros((a.shape[0], b.shape[0]))
    if area.size == 0:
        return area
    ia, ib = _candidates(a, b)
    if ia.size:
        # polygons only for boxes with a candidate (NaN boxes, e.g. DontCare, never are)
        ua, inv_a = np.unique(ia, return_inverse=True)
        ub, inv_b = np.unique(ib, return_inverse=True)
        polys_a, polys_b = _polygons(a[ua]), _polygons(b[ub])
        area[ia, ib] = polygon_intersection_area(polys_a[inv_a], polys_b[inv_b])
    return area


def iou_bev(boxes_a: ArrayLike, boxes_b: ArrayLike) -> NDArray[np.float64]:
    """M×K rotated bird's-eye-view IoU."""
    a, b = _boxes(boxes_a), _boxes(boxes_b)
    inter = bev_intersection_area(a, b)
    union = (a[:, 3] * a[:, 4])[:, None] + (b[:, 3] * b[:, 4])[None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(union > 0, inter / union, 0.0)
    return np.nan_to_num(iou, nan=0.0)


def iou_3d(boxes_a: ArrayLike, boxes_b: ArrayLike) -> NDArray[np.float64]:
    """M×K 3D IoU: BEV overlap area × vertical overlap over the union volume (as the KITTI devkit)."""
    a, b = _boxes(boxes_a), _boxes(boxes_b)
    inter_bev = bev_intersection_area(a, b)
    top = np.minimum((a[:, 2] + a[:, 5] / 2)[:, None], (b[:, 2] + b[:, 5] / 2)[None, :])
    bottom = np.maximum((a[:, 2] - a[:, 5] / 2)[:, None], (b[:, 2] - b[:, 5] / 2)[None, :])
    inter = inter_bev * np.clip(top - bottom, 0.0, None)
    vol_a = a[:, 3] * a[:, 4] * a[:, 5]
    vol_b = b[:, 3] * b[:, 4] * b[:, 5]
    union = vol_a[:, None] + vol_b[None, :] - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        iou = np.where(union > 0, inter / union, 0.0)
    return np.nan_to_num(iou, nan=0.0)


def transform_boxes(boxes: ArrayLike, matrix: ArrayLike) -> NDArray[np.float64]:
    """M×7 boxes mapped by a 4×4 transform whose linear part keeps z vertical.

    Centres go through the full map; the heading follows the image of the box's forward
    axis (so a mirror turns ``yaw`` into ``-yaw``); length, width and height scale by the
    stretch of the forward, sideways and vertical axes.

    Example:
        >>> m = np.diag([1.0, -1.0, 1.0, 1.0])
        >>> transform_boxes([[5, 2, 0, 4, 2, 1.5, 0.5]], m).round(2).tolist()
        [[5.0, -2.0, 0.0, 4.0, 2.0, 1.5, -0.5]]
    """
    b = _boxes(boxes)
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4):
        raise ValueError(f"matrix must be 4×4, got shape {m.shape}")
    linear = m[:3, :3]
    out = b.copy()
    out[:, :3] = b[:, :3] @ linear.T + m[:3, 3]
    cos, sin = np.cos(b[:, 6]), np.sin(b[:, 6])
    forward = np.stack([cos, sin, np.zeros_like(cos)], axis=1) @ linear.T
    sideways = np.stack([-sin, cos, np.zeros_like(cos)], axis=1) @ linear.T
    out[:, 6] = (np.arctan2(forward[:, 1], forward[:, 0]) + np.pi) % (2.0 * np.pi) - np.pi
    out[:, 3] = b[:, 3] * np.linalg.norm(forward, axis=1)
    out[:, 4] = b[:, 4] * np.linalg.norm(sideways, axis=1)
    out[:, 5] = b[:, 5] * np.linalg.norm(linear[:, 2])
    return out
