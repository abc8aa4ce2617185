"""HD-map ROI filter: points on the drivable area (grown by a margin), looked up in a raster.

The grown polygon is rasterised once per frame by scanlines (even-odd rule over every ring's
edges, so holes stay holes) and each point reads its cell: O(cells + points) rather than a
polygon test per point. A cell is inside when its centre is, so the boundary is exact to half
a cell.
"""

from __future__ import annotations

import numpy as np
import shapely
from numpy.typing import NDArray

from lidarfuzz.scene.roi import RoiMap


def _edges(geometry: shapely.Geometry) -> NDArray[np.float64]:
    """K×4 ``x1, y1, x2, y2`` of every ring of every polygon."""
    rings = shapely.get_rings(shapely.get_parts(geometry))
    out = []
    for ring in rings:
        xy = shapely.get_coordinates(ring)
        out.append(np.c_[xy[:-1], xy[1:]])
    return np.concatenate(out) if out else np.zeros((0, 4))


def rasterize(
    geometry: shapely.Geometry, origin: NDArray[np.float64], cell: float, shape: tuple[int, int]
) -> NDArray[np.bool_]:
    """Cells (``shape[0]`` along x, ``shape[1]`` along y, from ``origin``) whose centre lies in ``geometry``."""
    edges = _edges(geometry)
    if len(edges) == 0:
        return np.zeros(shape, dtype=bool)
    ys = origin[1] + (np.arange(shape[1]) + 0.5) * cell
    x1, y1, x2, y2 = (v[None, :] for v in edges.T)
    row = ys[:, None]
    # each edge crosses the rows whose centre y lies in [min(y1, y2), max(y1, y2))
    crossing = (np.minimum(y1, y2) <= row) & (row < np.maximum(y1, y2))
    with np.errstate(invalid="ignore", divide="ignore"):
        cut = x1 + (row - y1) / (y2 - y1) * (x2 - x1)  # rows × edges
    rows, which = np.nonzero(crossing)
    # the first cell whose centre is right of a cut toggles inside/outside (even-odd rule)
    first = np.ceil((cut[rows, which] - origin[0]) / cell - 0.5).astype(np.int64)
    first = np.clip(first, 0, shape[0])
    toggles = np.zeros((shape[0] + 1, shape[1]), dtype=np.int32)
    np.add.at(toggles, (first, rows), 1)
    inside = np.cumsum(toggles[:-1], axis=0) % 2 == 1
    return inside


def roi_mask(xy: NDArray[np.float32], roi: RoiMap | None, margin: float, cell: float) -> NDArray[np.bool_]:
    """Points whose (x, y) lie within ``margin`` metres of the drivable area."""
    n = len(xy)
    if roi is None or n == 0:
        return np.ones(n, dtype=bool)
    area = roi.geometry.buffer(margin, quad_segs=4) if margin > 0 else roi.geometry
    # the raster's cells sit on multiples of `cell`, not on the cloud's corner: a point's verdict
    # must not depend on where the other points are (with the origin at the cloud's minimum, one
    # point added far away shifted every cell and moved the boundary under points near the edge)
    lo = np.floor(xy.min(axis=0).astype(np.float64) / cell) * cell
    hi = xy.max(axis=0).astype(np.float64)
    shape = tuple(int(v) for v in np.maximum(np.ceil((hi - lo) / cell).astype(int) + 1, 1))
    inside = rasterize(area, lo, cell, shape)  # type: ignore[arg-type]
    ix = np.minimum(((xy[:, 0] - lo[0]) / cell).astype(np.int64), shape[0] - 1)
    iy = np.minimum(((xy[:, 1] - lo[1]) / cell).astype(np.int64), shape[1] - 1)
    return inside[ix, iy]
