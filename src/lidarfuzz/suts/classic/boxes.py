"""MinBox builder: an oriented rectangle around a cluster's footprint, then completion to a prior size.

``lshape`` searches the heading that makes the points hug two perpendicular edges (the
closeness criterion of L-shape fitting: a vehicle shows the sensor one or two of its
sides); ``min_area`` the heading of the smallest enclosing rectangle. A partly seen object
is then grown to its class's typical size away from the sensor, keeping the faces the
sensor saw where they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

_CLOSENESS_FLOOR = 0.01  # metres: points closer to an edge than this count as on it


@dataclass(frozen=True)
class Footprint:
    """A fitted rectangle: heading of axis 1, extents along both axes (in the rotated frame)."""

    angle: float
    lo: NDArray[np.float64]  # (2,) min projection on axis 1 and axis 2
    hi: NDArray[np.float64]

    @property
    def extent(self) -> NDArray[np.float64]:
        return self.hi - self.lo


def _axes(angles: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    e1 = np.stack([np.cos(angles), np.sin(angles)])  # 2 × A
    e2 = np.stack([-np.sin(angles), np.cos(angles)])
    return e1, e2


def _search(xy: NDArray[np.float64], angles: NDArray[np.float64], method: str) -> int:
    e1, e2 = _axes(angles)
    c1, c2 = xy @ e1, xy @ e2  # N × A
    lo1, hi1, lo2, hi2 = c1.min(axis=0), c1.max(axis=0), c2.min(axis=0), c2.max(axis=0)
    if method == "min_area":
        return int(np.argmin((hi1 - lo1) * (hi2 - lo2)))
    d1 = np.minimum(hi1 - c1, c1 - lo1)
    d2 = np.minimum(hi2 - c2, c2 - lo2)
    return int(np.argmax(np.sum(1.0 / np.maximum(np.minimum(d1, d2), _CLOSENESS_FLOOR), axis=0)))


def fit_footprint(xy: NDArray[np.float64], method: str, step_deg: float, max_points: int = 256) -> Footprint:
    """The rectangle around ``xy`` (N×2) whose heading (in [0, π/2)) is best by ``method``.

    The heading is searched on at most ``max_points`` points (an even stride through the
    cluster), coarse (3 steps at a time) then fine around the best; the extents are then
    taken over every point.
    """
    sample = xy[:: max(1, len(xy) // max_points)]
    coarse = np.deg2rad(np.arange(0.0, 90.0, 3.0 * step_deg))
    best = coarse[_search(sample, coarse, method)]
    fine = best + np.deg2rad(np.arange(-3.0 * step_deg, 3.0 * step_deg + 1e-9, step_deg))
    angle = float(fine[_search(sample, fine, method)] % (np.pi / 2.0))
    e1, e2 = _axes(np.array([angle]))
    c1, c2 = (xy @ e1)[:, 0], (xy @ e2)[:, 0]
    return Footprint(angle, np.array([c1.min(), c2.min()]), np.array([c1.max(), c2.max()]))


def _grow(lo: float, hi: float, sensor: float, target: float) -> tuple[float, float]:
    """Grow the interval [lo, hi] to ``target`` away from the sensor's projection ``sensor``."""
    if hi - lo >= target:
        return lo, hi
    if sensor <= lo:
        return lo, lo + target
    if sensor >= hi:
        return hi - target, hi
    middle = (lo + hi) / 2.0
    return middle - target / 2.0, middle + target / 2.0


def long_axis_first(fp: Footprint) -> Footprint:
    """The same rectangle described with its longer side as axis 1."""
    if fp.hi[1] - fp.lo[1] <= fp.hi[0] - fp.lo[0]:
        return fp
    return Footprint(fp.angle + np.pi / 2.0, np.array([fp.lo[1], -fp.hi[0]]), np.array([fp.hi[1], -fp.lo[0]]))


def end_on(fp: Footprint) -> bool:
    """True when the footprint's long side faces the sensor (origin) squarely: the line of
    sight to its centre is within 30° of the side's normal."""
    fp = long_axis_first(fp)
    centre_local = (fp.lo + fp.hi) / 2.0
    sight = np.hypot(*centre_local)
    if sight == 0:
        return False
    return bool(abs(centre_local[1]) / sight > np.cos(np.deg2rad(30.0)))


def box_from_footprint(
    fp: Footprint, z_bottom: float, z_top: float, prior: tuple[float, float, float] | None, width_seen: bool = False
) -> NDArray[np.float64]:
    """A ``[x, y, z, l, w, h, yaw]`` box: the longer side is the length — unless ``width_seen``
    (the visible side is the object's width, e.g. a car's rear) — and with a prior
    ``(l, w, h)``, extents shorter than the prior grow to it away from the sensor (origin)."""
    fp = long_axis_first(fp)
    if width_seen:  # the long visible side is the width: turn the frame by 90°
        fp = Footprint(fp.angle + np.pi / 2.0, np.array([fp.lo[1], -fp.hi[0]]), np.array([fp.hi[1], -fp.lo[0]]))
    lo, hi = fp.lo.copy(), fp.hi.copy()
    angle = fp.angle
    if prior is not None:
        lo[0], hi[0] = _grow(lo[0], hi[0], 0.0, prior[0])
        lo[1], hi[1] = _grow(lo[1], hi[1], 0.0, prior[1])
        z_top = max(z_top, z_bottom + 0.5 * prior[2])
    centre_local = (lo + hi) / 2.0
    e1 = np.array([np.cos(angle), np.sin(angle)])
    e2 = np.array([-np.sin(angle), np.cos(angle)])
    centre = centre_local[0] * e1 + centre_local[1] * e2
    yaw = (angle + np.pi / 2.0) % np.pi - np.pi / 2.0  # heading is ambiguous by π: keep it in [-π/2, π/2)
    size = hi - lo
    return np.array([centre[0], centre[1], (z_bottom + z_top) / 2.0, size[0], size[1], z_top - z_bottom, yaw])
