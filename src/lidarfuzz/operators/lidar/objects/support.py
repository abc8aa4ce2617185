"""Shared machinery of the object operators: object points, local ground, range-image occlusion,
ground infill, and the choice of objects."""

from __future__ import annotations

import weakref
from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import Config, NonNegativeRange, Params, Target
from lidarfuzz.operators.lidar.common import intensity_scale
from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.geometry import bev_intersection_area
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

Range = tuple[float, float]
F64 = NDArray[np.float64]
POINTS = frozenset({Target.POINTS})
POINTS_BOXES = frozenset({Target.POINTS, Target.BOXES})

#: Metres a box is grown by when its points are collected (returns on mirrors, noise).
BOX_MARGIN = 0.05
#: Points less than this above the local ground plane are ground, never the object's.
GROUND_BAND = 0.15
#: Depth tolerance of the z-buffer, metres.
DEPTH_MARGIN = 0.25


# =========================================================================== geometry
class _Pts:
    """A frame's coordinates with contiguous x, y, z columns and a spatial index, for fast
    neighbourhood queries.

    Queries touch only the points near the object: :meth:`near` reads the cells of a square grid
    (points sorted by cell once), :meth:`wedge` the bins of azimuth around a direction. Both then
    apply the exact test of a full scan to those candidates and return ascending indices, so every
    result is the one a scan of all points gives (the ground fits sum in that order). The index is
    built lazily, once per cloud: :meth:`of` caches it on the cloud's data array (the operators'
    ``sample`` and ``apply``, and every operator applied to one frame, share it), with the results
    of the ground fits and object point queries made on it (:attr:`memo`)."""

    __slots__ = ("__weakref__", "_azimuth", "_columns", "_farthest", "_grid", "_max_range", "_parent", "_xyz", "memo")

    def __init__(self, xyz: NDArray[np.floating]) -> None:
        self._xyz: NDArray[np.floating] | None = xyz
        self._columns: NDArray[np.float32] | None = np.ascontiguousarray(np.asarray(xyz).T)
        self._max_range: float | None = None
        self._farthest: tuple[np.float32, int] | None = None
        self._grid: _Buckets | None = None
        self._azimuth: _Buckets | None = None
        #: (parent, the parent's points not kept (ascending), x/y/z columns of the points that follow the
        #: parent's), see :meth:`derive`
        self._parent: tuple[_Pts, NDArray[np.intp], NDArray[np.float32]] | None = None
        #: results computed from these points, keyed by what they depend on (see :func:`_memoised`)
        self.memo: dict[Hashable, Any] = {}

    @classmethod
    def of(cls, cloud: PointCloud) -> _Pts:
        """The (cached) index of ``cloud``'s points: built at the first call for this cloud's data,
        found again while the cloud lives (a point cloud's data is read-only, so it stays valid)."""
        data = cloud.data
        entry = _INDEXES.get(id(data))
        if entry is not None and entry[0]() is data:
            _INDEXES.move_to_end(id(data))
            return entry[1]
        return _remember(data, cls(cloud.xyz))

    @classmethod
    def derive(cls, parent: _Pts, kept: NDArray[np.bool_], added: NDArray[np.floating]) -> _Pts:
        """The index of ``parent``'s points where ``kept`` (in their order) followed by ``added``
        (N×3, an inserted object's points): its queries ask the parent's index and scan only the
        added points, and its columns are only gathered if someone reads them, so a frame grown
        object by object costs no index of its own."""
        pts = cls.__new__(cls)
        pts._xyz, pts._columns, pts._max_range, pts._farthest = None, None, None, None
        pts._grid = pts._azimuth = None
        pts.memo = {}
        pts._parent = (parent, np.flatnonzero(~kept), np.ascontiguousarray(np.asarray(added, np.float32).T))
        return pts

    @property
    def xyz(self) -> NDArray[np.floating]:
        """The points, N×3."""
        return self._xyz if self._xyz is not None else self.columns.T

    @property
    def columns(self) -> NDArray[np.float32]:
        """x, y and z, one contiguous row each."""
        if self._columns is None:
            parent, dropped, tail = self._parent  # type: ignore[misc]
            kept = np.ones(len(parent), bool)
            kept[dropped] = False
            self._columns = np.ascontiguousarray(np.concatenate([np.compress(kept, parent.columns, axis=1), tail],
                                                                axis=1))
        return self._columns

    @property
    def x(self) -> NDArray[np.float32]:
        return self.columns[0]

    @property
    def y(self) -> NDArray[np.float32]:
        return self.columns[1]

    @property
    def z(self) -> NDArray[np.float32]:
        return self.columns[2]

    def __len__(self) -> int:
        if self._parent is not None:
            parent, dropped, tail = self._parent
            return len(parent) - len(dropped) + tail.shape[1]
        return len(self.xyz)

    def _kept_rank(self, found: NDArray[np.intp]) -> NDArray[np.intp]:
        """The indices here of the parent's points ``found`` (ascending) that were kept."""
        _, dropped, _ = self._parent  # type: ignore[misc]
        before = np.searchsorted(dropped, found)
        gone = np.zeros(len(found), bool)
        if len(dropped):
            gone = dropped[np.minimum(before, len(dropped) - 1)] == found
        return (found - before)[~gone]

    def farthest(self) -> tuple[np.float32, int]:
        """(The largest squared range, in float32 as a scan of the x, y, z columns computes it (NaN if
        any is), and the index of a point with it, −1 for no point.) A derived index asks its parent:
        unless the insertion removed the parent's farthest point, only the new points are new."""
        if self._farthest is None:
            if self._parent is not None:
                parent, dropped, tail = self._parent
                top, at = parent.farthest()
                if at >= 0 and not np.isin(at, dropped):
                    squared = tail[0] ** 2 + tail[1] ** 2 + tail[2] ** 2
                    value = np.append(squared, top).max()
                    if value == top or (np.isnan(value) and np.isnan(top)):
                        self._farthest = (value, int(self._kept_rank(np.array([at], np.intp))[0]))
                    else:
                        self._farthest = (value, len(self) - len(squared) + int(squared.argmax()))
                    return self._farthest
            squared = self.x ** 2 + self.y ** 2 + self.z ** 2
            self._farthest = (squared.max(initial=np.float32(0.0)), int(squared.argmax()) if len(squared) else -1)
        return self._farthest

    def max_range(self) -> float:
        """The farthest return's range: the sensor returns nothing beyond it in this frame."""
        if self._max_range is None:
            self._max_range = float(np.sqrt(self.farthest()[0]))
        return self._max_range

    def near(self, cx: float, cy: float, reach: float) -> NDArray[np.intp]:
        """Indices of the points in the axis-aligned square of half-edge ``reach`` around (cx, cy)."""
        if self._parent is not None:
            parent, _, (x, y, _) = self._parent
            start = len(self) - len(x)
            tail = np.flatnonzero((np.abs(x - np.float32(cx)) <= reach) & (np.abs(y - cy) <= reach)) + start
            return np.concatenate([self._kept_rank(parent.near(cx, cy, reach)), tail])
        if len(self) < _INDEX_FROM:
            index = np.flatnonzero(np.abs(self.x - np.float32(cx)) <= reach)
            return index[np.abs(self.y[index] - cy) <= reach]
        if self._grid is None:
            self._grid = _Buckets.grid(self.x, self.y)
        candidates = self._grid.square(float(cx), float(cy), float(reach))
        x, y = self.x[candidates], self.y[candidates]
        keep = (np.abs(x - np.float32(cx)) <= reach) & (np.abs(y - cy) <= reach)
        return np.sort(candidates[keep])

    def wedge(self, centre: float, half_width: float) -> NDArray[np.intp]:
        """Indices of the points within ``half_width`` of azimuth ``centre`` (see :func:`_wedge_index`)."""
        c, s = np.float32(np.cos(centre)), np.float32(np.sin(centre))
        if half_width >= np.pi / 2:
            along = self.x * c + self.y * s
            return np.flatnonzero(along >= np.hypot(self.x, self.y) * np.cos(min(half_width, np.pi)))
        cos2 = np.float32(np.cos(half_width) ** 2)
        if self._parent is not None:
            parent, _, (x, y, _) = self._parent
            start = len(self) - len(x)
            along = x * c + y * s
            tail = np.flatnonzero((along >= 0) & (along ** 2 >= (x ** 2 + y ** 2) * cos2)) + start
            return np.concatenate([self._kept_rank(parent.wedge(centre, half_width)), tail])
        if len(self) < _INDEX_FROM:
            along = self.x * c + self.y * s
            index = np.flatnonzero(along >= 0)
            return index[along[index] ** 2 >= (self.x[index] ** 2 + self.y[index] ** 2) * cos2]
        if self._azimuth is None:
            self._azimuth = _Buckets.azimuth(self.x, self.y)
        candidates = self._azimuth.arc(centre, half_width)
        x, y = self.x[candidates], self.y[candidates]
        along = x * c + y * s
        keep = (along >= 0) & (along ** 2 >= (x ** 2 + y ** 2) * cos2)
        return np.sort(candidates[keep])


def _remember(data: NDArray[np.float32], pts: _Pts) -> _Pts:
    """Cache ``pts`` as the index of the cloud whose data is ``data``, while that array lives."""
    key = id(data)
    # the table is bound now: at exit the module's globals may be gone before the last callback
    _INDEXES[key] = (weakref.ref(data, lambda _, key=key, table=_INDEXES: table.pop(key, None)), pts)  # type: ignore[misc]
    while len(_INDEXES) > _INDEXES_KEPT:
        _INDEXES.popitem(last=False)
    return pts


def _stack_rows(*parts: tuple[NDArray[np.float32], NDArray[np.bool_]]) -> NDArray[np.float32]:
    """The rows of each ``(data, mask)`` where its mask holds, one part after the other, written
    straight into the result (one pass over the frame, no temporary per part)."""
    rows = [np.flatnonzero(mask) for _, mask in parts]
    out = np.empty((sum(len(r) for r in rows), parts[0][0].shape[1]), np.float32)
    start = 0
    for (data, _), index in zip(parts, rows, strict=True):
        # take, not compress: compress (and take in mode "raise") buffers ``out``, a second copy
        np.take(data, index, axis=0, out=out[start:start + len(index)], mode="clip")
        start += len(index)
    return out


#: Clouds smaller than this are scanned whole (an index would cost more than it saves).
_INDEX_FROM = 4096
#: Point indexes kept (the clouds an operator call and the next few see).
_INDEXES_KEPT = 8
_INDEXES: OrderedDict[int, tuple[weakref.ref[NDArray[np.float32]], _Pts]] = OrderedDict()
#: Azimuth bins of the wedge index (0.5° each).
_AZIMUTH_BINS = 720


@dataclass(frozen=True)
class _Buckets:
    """Points sorted by bucket (a cell of a square grid, or a bin of azimuth), with each bucket's
    slice of the order: one counting sort builds it, a query gathers a few slices.

    The buckets only narrow the search: a query returns every point of the buckets that may hold
    a match (one bucket of margin on each side, and the points whose bucket is meaningless: non-
    finite, or at the origin, where every azimuth test holds), and the caller applies the exact test."""

    order: NDArray[np.intp]
    bounds: NDArray[np.intp]  # bucket b is order[bounds[b]:bounds[b + 1]]
    always: NDArray[np.intp]  # candidates of every query
    origin: tuple[float, float]
    cell: float
    shape: tuple[int, int]

    @staticmethod
    def _sorted(key: NDArray[np.integer], buckets: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        # int16 keys take numpy's radix sort: linear in the points
        order = np.argsort(key.astype(np.int16 if buckets <= 32767 else np.int32), kind="stable")
        bounds = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=buckets))]).astype(np.intp)
        return order, bounds

    @classmethod
    def grid(cls, x: NDArray[np.float32], y: NDArray[np.float32]) -> _Buckets:
        finite = np.isfinite(x) & np.isfinite(y)
        if not finite.any():
            return cls(np.zeros(0, np.intp), np.zeros(2, np.intp), np.flatnonzero(~finite), (0.0, 0.0), 1.0, (1, 1))
        if not finite.all():
            x, y = np.where(finite, x, x[finite][0]), np.where(finite, y, y[finite][0])  # they fail every test
        x0, y0, x1, y1 = float(x.min()), float(y.min()), float(x.max()), float(y.max())
        cell = max(1.0, max(x1 - x0, y1 - y0) / 180.0)  # at most 181 × 181 cells: int16 keys
        nx, ny = int((x1 - x0) // cell) + 1, int((y1 - y0) // cell) + 1
        ix = np.clip(((x - np.float32(x0)) / np.float32(cell)).astype(np.int32), 0, nx - 1)
        iy = np.clip(((y - np.float32(y0)) / np.float32(cell)).astype(np.int32), 0, ny - 1)
        order, bounds = cls._sorted(ix * ny + iy, nx * ny)
        return cls(order, bounds, np.zeros(0, np.intp), (x0, y0), cell, (nx, ny))

    @classmethod
    def azimuth(cls, x: NDArray[np.float32], y: NDArray[np.float32]) -> _Buckets:
        with np.errstate(invalid="ignore"):
            az = np.arctan2(y, x)
            bins = np.floor((az + np.float32(np.pi)) * np.float32(_AZIMUTH_BINS / (2 * np.pi)))
            odd = ~np.isfinite(bins) | ~(x * x + y * y >= np.float32(1e-6))
        # odd points go to a bucket of their own, never read: they are in every answer's candidates
        key = np.where(odd, _AZIMUTH_BINS, np.clip(np.nan_to_num(bins), 0, _AZIMUTH_BINS - 1)).astype(np.int64)
        order, bounds = cls._sorted(key, _AZIMUTH_BINS + 1)
        return cls(order, bounds, np.flatnonzero(odd), (-np.pi, 0.0), 2 * np.pi / _AZIMUTH_BINS, (_AZIMUTH_BINS, 1))

    def _gather(self, starts: NDArray[np.intp], ends: NDArray[np.intp]) -> NDArray[np.intp]:
        lengths = np.maximum(ends - starts, 0)
        total = int(lengths.sum())
        offsets = np.cumsum(lengths) - lengths
        slots = np.repeat(starts - offsets, lengths) + np.arange(total)
        return np.concatenate([self.order[slots], self.always]) if len(self.always) else self.order[slots]

    def square(self, cx: float, cy: float, reach: float) -> NDArray[np.intp]:
        """Candidates for the square of half-edge ``reach`` around (cx, cy)."""
        nx, ny = self.shape
        lo_x = max(int(np.floor((cx - reach - self.origin[0]) / self.cell)) - 1, 0)
        hi_x = min(int(np.floor((cx + reach - self.origin[0]) / self.cell)) + 1, nx - 1)
        lo_y = max(int(np.floor((cy - reach - self.origin[1]) / self.cell)) - 1, 0)
        hi_y = min(int(np.floor((cy + reach - self.origin[1]) / self.cell)) + 1, ny - 1)
        if lo_x > hi_x or lo_y > hi_y:
            return self.always
        columns = np.arange(lo_x, hi_x + 1) * ny
        return self._gather(self.bounds[columns + lo_y], self.bounds[columns + hi_y + 1])

    def arc(self, centre: float, half_width: float) -> NDArray[np.intp]:
        """Candidates within ``half_width`` of azimuth ``centre`` (radians)."""
        bins = self.shape[0]
        lo = int(np.floor((centre - half_width + np.pi) / self.cell)) - 2
        hi = int(np.floor((centre + half_width + np.pi) / self.cell)) + 2
        if hi - lo + 1 >= bins:
            return self._gather(self.bounds[:1], self.bounds[bins:bins + 1])
        pieces = np.arange(lo, hi + 1) % bins
        return self._gather(self.bounds[pieces], self.bounds[pieces + 1])


#: Results kept per point index (ground fits, object points): a search tries tens of places.
_MEMO_KEPT = 512
_T = TypeVar("_T")


def _memoised(pts: _Pts, key: Hashable, compute: Callable[[], _T]) -> _T:
    """``compute()``, or its value from an earlier call with the same ``key`` on the same points
    (``sample`` and ``apply`` fit the same ground and find the same object points)."""
    memo = pts.memo
    if key in memo:
        return memo[key]  # type: ignore[no-any-return]
    value = compute()
    if len(memo) >= _MEMO_KEPT:
        memo.pop(next(iter(memo)))
    memo[key] = value
    return value


def _frozen(index: NDArray[Any]) -> NDArray[Any]:
    index.flags.writeable = False  # shared through the memo: nobody may change it
    return index


def _in_box(pts: _Pts, box: F64, margin: float = 0.0) -> NDArray[np.intp]:
    """Indices of the points inside one box (faces included, grown by ``margin``)."""
    if len(pts) == 0:
        return np.zeros(0, np.intp)
    half = box[3:6] / 2.0 + margin
    near = pts.near(box[0], box[1], float(np.hypot(half[0], half[1])))
    d = pts.xyz[near].astype(np.float64) - box[:3]
    c, s = np.cos(box[6]), np.sin(box[6])
    inside = ((np.abs(d[:, 0] * c + d[:, 1] * s) <= half[0]) & (np.abs(-d[:, 0] * s + d[:, 1] * c) <= half[1])
              & (np.abs(d[:, 2]) <= half[2]))
    return near[inside]


#: Edge of the cells whose lowest return samples the ground around a box, metres.
GROUND_CELL = 0.5
#: (above, below) tolerances of the successive ground fits, metres: a cell's lowest return above the
#: plane by more is an obstacle's (a car's flank, a wall, the pavement beyond a kerb), below by
#: more a stray return. The first passes reach out along a slope from the starting level.
_GROUND_PASSES = ((0.2, 0.25), (0.15, 0.2), (0.15, 0.2), (0.1, 0.15), (0.06, 0.12))
#: Fewest ground cells a fit is believed from.
_GROUND_MIN_CELLS = 6
#: Distance from the footprint (m) at which a ground cell counts half as much as one beside it.
_GROUND_NEAR = 1.0


@dataclass(frozen=True)
class _Ground:
    """A local ground plane z = a·x + b·y + c, the ground points near it and how many ground
    cells supported the fit (0: no ground was seen; the plane is then a guess)."""

    a: float
    b: float
    c: float
    inliers: NDArray[np.intp]
    cells: int = 0

    def height(self, xy: NDArray[np.floating]) -> F64:
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return self.a * xy[:, 0] + self.b * xy[:, 1] + self.c


def _lowest_per_cell(dx: F64, dy: F64, z: F64, cell: float) -> NDArray[np.intp]:
    """Index of the lowest point of each occupied ``cell`` × ``cell`` square, by cell (the first
    such point where several are lowest), as a sort of (cell, z) orders them (no loop).

    Cells are few (a ground fit's ring is at most some 60 × 60 of them), so the points are put
    in cell order by a stable counting sort of 16-bit keys and each cell's minimum is found by
    one reduction, not by a two-key sort (about 3 times faster). Non-finite coordinates (whose
    keys are meaningless) or more cells take the two-key sort (:func:`_lowest_per_cell_sorted`)."""
    ix, iy = np.floor(dx / cell).astype(np.int64), np.floor(dy / cell).astype(np.int64)
    key = (ix - ix.min(initial=0)) * (int(iy.max(initial=0) - iy.min(initial=0)) + 1) + (iy - iy.min(initial=0))
    if len(key) == 0 or not (np.isfinite(dx).all() and np.isfinite(dy).all() and np.isfinite(z).all()):
        return _lowest_per_cell_sorted(key, z)
    cells = int(key.max()) + 1
    if cells > _CELL_SORT_MAX:
        return _lowest_per_cell_sorted(key, z)
    by_cell = np.argsort(key.astype(np.int16), kind="stable")  # radix sort: linear in the points
    counts = np.bincount(key, minlength=cells)
    counts = counts[counts > 0]
    z_by_cell = z[by_cell]
    lowest = np.minimum.reduceat(z_by_cell, np.cumsum(counts) - counts)
    at_lowest = np.flatnonzero(z_by_cell == np.repeat(lowest, counts))
    # the first lowest point of each cell: a stable sort keeps a cell's points in index order
    group = np.repeat(np.arange(len(counts)), counts)[at_lowest]
    first = np.ones(len(at_lowest), bool)
    first[1:] = group[1:] != group[:-1]
    return by_cell[at_lowest[first]]


#: Most cells :func:`_lowest_per_cell` counts (16-bit keys); beyond, it sorts.
_CELL_SORT_MAX = 32767


def _lowest_per_cell_sorted(key: NDArray[np.int64], z: F64) -> NDArray[np.intp]:
    """:func:`_lowest_per_cell` by one sort of (key, z): any keys, NaN heights last in a cell."""
    order = np.lexsort((z, key))
    first = np.ones(len(order), bool)
    first[1:] = key[order][1:] != key[order][:-1]
    return order[first]


def _fit_ground(dx: F64, dy: F64, z: F64, weight: F64, level: float) -> F64 | None:
    """Plane ``[a, b, c]`` (z = a·dx + b·dy + c) through the ground among cell minima, or None.

    The fit starts flat at ``level`` (the caller's best prior for the ground under the
    footprint) and is refitted by weighted least squares to the cells within tolerances that
    shrink pass by pass (:data:`_GROUND_PASSES`, asymmetric: far more obstacles stand above the
    ground than stray returns lie below it), so walls, cars and the pavement beyond a kerb drop
    out while a slope or a camber is followed outwards. A small ridge keeps the slope finite when
    the cells line up (a camera-cropped or half-hidden ring); a road is never steeper than 20 %."""
    if len(z) < _GROUND_MIN_CELLS:
        return None
    coef = np.array([0.0, 0.0, level])
    design = np.column_stack([dx, dy, np.ones(len(z))])
    ridge = np.diag([1.0, 1.0, 0.0])
    for above, below in _GROUND_PASSES:
        resid = z - design @ coef
        ok = (resid <= above) & (resid >= -below)
        if np.count_nonzero(ok) < _GROUND_MIN_CELLS:
            return None
        d, w = design[ok], weight[ok]
        coef = np.linalg.solve((d * w[:, None]).T @ d + ridge, (d * w[:, None]).T @ z[ok])
        coef[:2] = np.clip(coef[:2], -0.2, 0.2)
    support = np.abs(z - design @ coef) <= _GROUND_PASSES[-1][0]
    return coef if np.count_nonzero(support) >= _GROUND_MIN_CELLS else None


def _local_ground(pts: _Pts, box: F64, free: bool = False) -> _Ground:
    """Ground plane under a box's footprint (see :func:`_fit_local_ground`), fitted once per
    frame, box and kind of place."""
    box = np.asarray(box, np.float64)
    return _memoised(pts, ("ground", box.tobytes(), free), lambda: _fit_local_ground(pts, box, free))


def _fit_local_ground(pts: _Pts, box: F64, free: bool) -> _Ground:
    """Ground plane under a box's footprint from the frame's own returns around it.

    The returns in a ring around the footprint (its rectangle grown by 0.2 m, out to 2 m beyond its
    corners, widened to 4, 8 and 12 m while the fit finds too little ground: a sparse sensor far
    away; the nearer the ring, the less a bent ground departs from a plane in it) are binned into
    :data:`GROUND_CELL` squares; each square's lowest return samples the ground or whatever stands
    on it, and :func:`_fit_ground` keeps the ground, cells near the footprint counting most. A
    camera-cropped or half-hidden ring simply has fewer cells. The fit starts at the box's bottom
    for a box that stands there; for a ``free`` place (an insertion), where nothing stands, the
    footprint's own returns count too, the fit starts at their median lowest return (the ring's
    lower quartile when the footprint holds too few), and the plane is finally moved by the
    footprint cells' median departure from it (the ground right there, where it bends). For a box
    that stands there a plane more than 0.3 m off its bottom is not believed, and the ground is
    taken flat at the bottom, as it is when no ground was seen (``cells`` = 0)."""
    half_diagonal = float(np.hypot(box[3], box[4])) / 2
    bottom = float(box[2] - box[5] / 2)
    c, s = np.cos(box[6]), np.sin(box[6])
    coef: F64 | None = None
    ring = np.zeros(0, np.intp)
    for width in (2.0, 4.0, 8.0, 12.0):
        near = pts.near(box[0], box[1], half_diagonal + width)
        dx = pts.x[near].astype(np.float64) - box[0]
        dy = pts.y[near].astype(np.float64) - box[1]
        # distance beyond the footprint's rectangle (0 inside it)
        along = np.maximum(np.abs(dx * c + dy * s) - box[3] / 2, 0.0)
        across = np.maximum(np.abs(-dx * s + dy * c) - box[4] / 2, 0.0)
        beyond = np.hypot(along, across)
        use = (np.hypot(dx, dy) <= half_diagonal + width) & ((beyond > 0.2) | free)
        ring, dx, dy, beyond = near[use], dx[use], dy[use], beyond[use]
        lowest = _lowest_per_cell(dx, dy, pts.z[ring].astype(np.float64), GROUND_CELL)
        z = pts.z[ring[lowest]].astype(np.float64)
        level = bottom
        if free and len(z):
            under = beyond[lowest] == 0.0
            level = float(np.median(z[under])) if np.count_nonzero(under) >= 3 else float(np.percentile(z, 25))
        weight = 1.0 / (1.0 + (beyond[lowest] / _GROUND_NEAR) ** 2)
        coef = _fit_ground(dx[lowest], dy[lowest], z, weight, level)
        if coef is not None:
            if free:
                # Where the sensor saw the footprint itself, its returns say how far a bent ground
                # (a camber's crown or trough) departs from the plane right there.
                under = beyond[lowest] == 0.0
                resid = z[under] - (coef[0] * dx[lowest][under] + coef[1] * dy[lowest][under] + coef[2])
                resid = resid[np.abs(resid) <= _GROUND_PASSES[-1][0]]
                if len(resid) >= 3:
                    coef[2] += float(np.median(resid))
            break
    if coef is not None and (free or abs(coef[2] - bottom) <= 0.3):
        a, b = float(coef[0]), float(coef[1])
        ground = _Ground(a, b, float(coef[2] - a * box[0] - b * box[1]), ring)
        near_plane = np.abs(pts.z[ring] - ground.height(pts.xyz[ring, :2])) <= 0.1
        lowest = _lowest_per_cell(pts.x[ring].astype(np.float64), pts.y[ring].astype(np.float64),
                                  pts.z[ring].astype(np.float64), GROUND_CELL)
        cells = int(np.count_nonzero(near_plane[lowest]))
        return _Ground(ground.a, ground.b, ground.c, _frozen(ring[near_plane]), cells)
    return _Ground(0.0, 0.0, bottom, _frozen(ring[np.abs(pts.z[ring] - bottom) <= 0.1]))


def _object_points(pts: _Pts, box: F64, ground: _Ground, cloud: PointCloud | None = None,
                   track_id: int = -1) -> NDArray[np.intp]:
    """Indices of an object's points: inside its (grown) box and above the ground band (the band
    starts at the ground or at the box's bottom, whichever is lower); with an ``instance``
    channel, the box's points labelled with its track id count too (a tyre's lowest returns).
    ``cloud`` is the one ``pts`` index (found once per frame, box, ground and track id)."""
    box = np.asarray(box, np.float64)
    labelled = cloud is not None and cloud.has("instance") and track_id >= 0
    key = ("object", box.tobytes(), ground.a, ground.b, ground.c, track_id if labelled else -1)

    def find() -> NDArray[np.intp]:
        inside = _in_box(pts, box, BOX_MARGIN)
        floor = np.minimum(ground.height(pts.xyz[inside, :2]), box[2] - box[5] / 2)
        mine = pts.z[inside] > floor + GROUND_BAND
        if labelled:
            mine |= cloud.channel("instance")[inside] == track_id  # type: ignore[union-attr]
        return _frozen(inside[mine])

    return _memoised(pts, key, find)


def _rows(data: NDArray[np.float32], mask: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Rows of ``data`` where ``mask`` holds (``np.compress`` is several times faster than boolean indexing)."""
    return np.compress(mask, data, axis=0)


def _intensity_scale(cloud: PointCloud) -> float:
    return intensity_scale(cloud.intensity)


def _rotation_z(angle: float) -> F64:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _footprint_free(boxes: Boxes3D, new_box: F64, skip: int, margin: float = 0.2) -> bool:
    """No other labelled box's footprint (DontCare regions included when they have a geometry)
    comes within ``margin`` of the new box's footprint."""
    others = [i for i in np.flatnonzero(boxes.has_geometry) if i != skip]
    if not others:
        return True
    grown = new_box.copy()
    grown[3:5] += 2 * margin
    return bool(bev_intersection_area(grown[None], boxes.as_array()[others]).max() == 0.0)


def _on_roi(scene: Scene, box: F64) -> bool:
    if scene.roi is None:
        return True
    return bool(scene.roi.contains_xy(_footprint(box)).all())


#: The footprint's corners in the box frame, in :func:`bev_corners`' order, as fractions of (l, w).
_FOOTPRINT_UNIT = np.array([[0.5, -0.5], [0.5, 0.5], [-0.5, 0.5], [-0.5, -0.5]])


def _footprint(box: F64) -> F64:
    """``bev_corners(box[None])[0]`` (4×2), the same arithmetic on the four bottom corners only: a
    place search tests tens of footprints, and the eight corners cost twice as much."""
    local = _FOOTPRINT_UNIT * box[3:5]
    yaw = box[6:7]  # an array, as bev_corners' column of yaws: the same cos and sin loop
    c, s = np.cos(yaw), np.sin(yaw)
    corners = np.empty((4, 2))
    corners[:, 0] = local[:, 0] * c - local[:, 1] * s + box[0]
    corners[:, 1] = local[:, 0] * s + local[:, 1] * c + box[1]
    return corners


def _clutter(pts: _Pts, box: F64, ground: _Ground, own: NDArray[np.intp]) -> int:
    """Points of something else (a wall, a pole, a tree) above the ground inside ``box``."""
    inside = np.setdiff1d(_in_box(pts, box, 0.0), own, assume_unique=True)
    return int(np.count_nonzero(pts.z[inside] > ground.height(pts.xyz[inside, :2]) + GROUND_BAND))


@dataclass(frozen=True)
class _Grown:
    """A frame with objects inserted, not yet written out: the frame's points less ``dropped``
    (ascending indices) followed by the ``added`` rows, with its point index. Each insertion reads
    only the rows in its wedge, so the frame is copied once, when the last object is in
    (:meth:`cloud`), and a grown frame costs memory in proportion to what changed."""

    frame: PointCloud
    dropped: NDArray[np.intp]
    added: NDArray[np.float32]
    pts: _Pts

    @classmethod
    def start(cls, frame: PointCloud) -> _Grown:
        return cls(frame, np.zeros(0, np.intp), np.zeros((0, len(frame.channels)), np.float32), _Pts.of(frame))

    @property
    def channels(self) -> tuple[str, ...]:
        return self.frame.channels

    def has(self, name: str) -> bool:
        return self.frame.has(name)

    def index(self, name: str) -> int:
        return self.frame.index(name)

    @property
    def frame_rows(self) -> int:
        """How many of the frame's points are still in (they come first)."""
        return len(self.frame) - len(self.dropped)

    def __len__(self) -> int:
        return self.frame_rows + len(self.added)

    def _frame_index(self, position: NDArray[np.intp]) -> NDArray[np.intp]:
        """The frame's index of the points at ``position`` (< :attr:`frame_rows`): the position plus
        the dropped points before it (the j-th dropped point precedes position p iff its index − j ≤ p)."""
        return position + np.searchsorted(self.dropped - np.arange(len(self.dropped)), position, side="right")

    def rows(self, index: NDArray[np.intp]) -> NDArray[np.float32]:
        """The rows of the points ``index`` (ascending), as the written-out cloud has them."""
        split = int(np.searchsorted(index, self.frame_rows))
        return np.concatenate([self.frame.data[self._frame_index(index[:split])],
                               self.added[index[split:] - self.frame_rows]])

    def grow(self, keep: NDArray[np.bool_], rows: NDArray[np.float32]) -> _Grown:
        """These points where ``keep`` holds, then ``rows`` (an inserted object's)."""
        gone = self._frame_index(np.flatnonzero(~keep[:self.frame_rows]))
        dropped = np.union1d(self.dropped, gone).astype(np.intp)
        added = np.concatenate([self.added[keep[self.frame_rows:]], rows])
        return _Grown(self.frame, dropped, added, _Pts.derive(self.pts, keep, rows[:, :3]))

    def intensity_scale(self) -> float:
        """:func:`intensity_scale` of the points' intensities (the frame's kept ones, the added ones)."""
        top, at = _memoised(_Pts.of(self.frame), "intensity_top", lambda: _top(self.frame.intensity))
        if at < 0 or np.isin(at, self.dropped):
            return intensity_scale(np.concatenate([np.delete(self.frame.intensity, self.dropped), self.added[:, 3]]))
        return intensity_scale(np.append(self.added[:, 3], top))

    def cloud(self) -> PointCloud:
        """The points written out, one copy of the frame's rows."""
        if not len(self.added) and not len(self.dropped):
            return self.frame
        kept = np.ones(len(self.frame), bool)
        kept[self.dropped] = False
        return PointCloud(_stack_rows((self.frame.data, kept), (self.added, np.ones(len(self.added), bool))),
                          self.channels)


def _top(values: NDArray[np.float32]) -> tuple[np.float32, int]:
    """(The largest value (NaN if any is), the index of one point with it; −1 for none.)"""
    return (values.max(), int(values.argmax())) if len(values) else (np.float32(0.0), -1)


# =========================================================================== range image
@dataclass(frozen=True)
class _Wedge:
    """The range image of the frame's points in a wedge of azimuth (rows = beams)."""

    index: NDArray[np.intp]  # the frame's points in the wedge
    row: NDArray[np.intp]
    col: NDArray[np.intp]
    depth: F64
    elevations: F64  # row → elevation (rad), ascending
    ring_of_row: F64 | None
    az_step: float
    centre: float

    @property
    def elev_step(self) -> float:
        return float(np.median(np.diff(self.elevations))) if len(self.elevations) > 1 else np.deg2rad(0.4)

    def pixels(self, xyz: NDArray[np.floating]) -> tuple[NDArray[np.intp], NDArray[np.intp], F64]:
        az, elev, depth = _spherical(xyz, self.centre)
        row, col = self.cells(az, elev)
        return row, col, depth

    def cells(self, az: F64, elev: F64) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """(row, column) of directions given by azimuth (relative to ``centre``) and elevation."""
        pos = np.clip(np.searchsorted(self.elevations, elev), 1, max(len(self.elevations) - 1, 1))
        lower = self.elevations[np.maximum(pos - 1, 0)]
        upper = self.elevations[np.minimum(pos, len(self.elevations) - 1)]
        row = np.where(np.abs(elev - lower) <= np.abs(elev - upper), pos - 1, pos)
        row = np.clip(row, 0, len(self.elevations) - 1).astype(np.intp)
        return row, np.floor(az / self.az_step).astype(np.intp)


def _spherical(xyz: NDArray[np.floating], centre: float) -> tuple[F64, F64, F64]:
    p = np.asarray(xyz, np.float64)
    c, s = np.cos(centre), np.sin(centre)
    along, across = p[:, 0] * c + p[:, 1] * s, -p[:, 0] * s + p[:, 1] * c
    flat = np.hypot(p[:, 0], p[:, 1])
    return np.arctan2(across, along), np.arctan2(p[:, 2], flat), np.hypot(flat, p[:, 2])


def _wedge_index(pts: _Pts, centre: float, half_width: float) -> NDArray[np.intp]:
    """Indices of the points within ``half_width`` of azimuth ``centre``."""
    return pts.wedge(centre, half_width)


def _wedge_of(xyz: NDArray[np.floating], ring: NDArray[np.floating] | None, index: NDArray[np.intp],
              centre: float) -> _Wedge:
    """Rasterise points (their ids ``index``) at the data's resolution, azimuth relative to ``centre``."""
    az, elev, depth = _spherical(xyz, centre)
    ring_of_row: F64 | None = None
    if ring is not None and len(index) and np.all(ring >= 0):
        rings, inverse = _ring_ids(ring)
        order = _order_within(elev, inverse, len(rings))
        starts = np.searchsorted(inverse[order], np.arange(len(rings)))
        ends = np.append(starts[1:], len(order))
        ring_elev = elev[order][(starts + ends) // 2]  # median elevation of each ring
        by_elev = np.argsort(ring_elev, kind="stable")
        elevations, ring_of_row = ring_elev[by_elev], rings[by_elev].astype(np.float64)
        rank = np.empty(len(rings), np.intp)
        rank[by_elev] = np.arange(len(rings))
        row = rank[inverse]
    elif len(index):
        # No ring channel: a beam's returns share one elevation, so beams are the gaps' clusters.
        order = np.argsort(elev)
        starts = np.concatenate([[0], np.flatnonzero(np.diff(elev[order]) > np.deg2rad(0.08)) + 1])
        if len(starts) > 256:  # not a spinning multi-beam pattern: fall back to even bins
            edges = np.linspace(elev.min(), elev.max() + 1e-9, 129)
            row = np.clip(np.searchsorted(edges, elev, side="right") - 1, 0, 127)
            elevations = (edges[:-1] + edges[1:]) / 2
        else:
            cluster = np.zeros(len(elev), np.intp)
            cluster[order] = np.cumsum(np.isin(np.arange(len(elev)), starts)) - 1
            row = cluster
            elevations = np.bincount(cluster, elev) / np.bincount(cluster)
    else:
        row, elevations = np.zeros(0, np.intp), np.deg2rad(np.array([-25.0, 3.0]))
    az_step = np.deg2rad(0.2)
    if len(index) > 1:
        order = _order_within(az, row, len(elevations))
        gaps = np.diff(az[order])[np.diff(row[order]) == 0]
        gaps = gaps[gaps > 1e-5]
        if len(gaps) >= 8:
            az_step = float(np.median(gaps))
    col = np.floor(az / az_step).astype(np.intp)
    return _Wedge(index, np.asarray(row, np.intp), col, depth, np.asarray(elevations, np.float64), ring_of_row,
                  az_step, centre)


def _ring_ids(ring: NDArray[np.floating]) -> tuple[NDArray[np.floating], NDArray[np.intp]]:
    """``np.unique(ring, return_inverse=True)`` (rings ≥ 0): by counting when the rings are whole
    numbers below 32767, as a ring channel's are (no sort)."""
    whole = ring.astype(np.int64)
    if len(ring) == 0 or not np.array_equal(whole, ring) or whole.max() >= 32767:
        rings, inverse = np.unique(ring, return_inverse=True)
        return rings, inverse.reshape(-1)
    present = np.bincount(whole)
    return np.flatnonzero(present).astype(ring.dtype), (np.cumsum(present > 0) - 1)[whole]


def _order_within(values: F64, group: NDArray[np.intp], groups: int) -> NDArray[np.intp]:
    """An order of the points by ``group`` (0 ≤ group < ``groups``), then by ``values``: the values
    in that order are those of ``np.lexsort((values, group))`` (only ties may be ordered otherwise).
    A sort of the values, then a stable counting sort of 16-bit groups: faster than ``lexsort``'s
    two merge sorts."""
    by_value = np.argsort(values)
    grouped = group[by_value]
    return by_value[np.argsort(grouped.astype(np.int16) if groups <= 32767 else grouped, kind="stable")]


def _azimuth_span(xyz: NDArray[np.floating]) -> tuple[float, float]:
    """(centre, half width) of the azimuths of ``xyz``, robust to the ±π seam."""
    az = np.arctan2(xyz[:, 1], xyz[:, 0]).astype(np.float64)
    centre = float(np.arctan2(np.sin(az).mean(), np.cos(az).mean()))
    return centre, float(np.abs(wrap_angle(az - centre)).max())


@dataclass(frozen=True)
class _Occlusion:
    keep_background: NDArray[np.bool_]  # over the frame's points, then extra's
    keep_new: NDArray[np.bool_]  # over the new points
    sensed: NDArray[np.bool_]  # new points the sensor would return were nothing else there
    ring: F64  # of the new points (−1 unknown)
    time: F64 | None  # of the new points, from their column
    same_row: NDArray[np.bool_] | None = None  # a moved point still on its source beam's row
    time_shift: F64 | None = None  # a moved point's time change, from its source column to its new one


def _silhouette(key: NDArray[np.intp], depth: F64, shape: tuple[int, int],
                size: tuple[int, int]) -> tuple[NDArray[np.bool_], F64]:
    """Pixels an object's points cover (holes up to ``size`` closed) and the depth behind which
    the object hides what is there (its nearest return in a pixel, its farthest nearby one in a
    filled hole), both flattened.

    Both are zero farther than ``size`` from the object's pixels (the closing only fills between
    them, the maximum filter reaches ``size`` − 1), so they are computed on the object's rows and
    columns with twice that margin, clipped to the image (the image's own edges stay the filters'
    edges), and put into zeros: the same arrays as over the whole range image, for a fraction of
    its pixels."""
    covered = np.zeros(shape[0] * shape[1], bool)
    occluder = np.zeros(shape[0] * shape[1])
    if len(key) == 0:
        return covered, occluder
    row, col = np.divmod(key, shape[1])
    top, bottom = max(int(row.min()) - 2 * size[0], 0), min(int(row.max()) + 2 * size[0] + 1, shape[0])
    left, right = max(int(col.min()) - 2 * size[1], 0), min(int(col.max()) + 2 * size[1] + 1, shape[1])
    crop = (bottom - top, right - left)
    nearest = np.full(crop[0] * crop[1], np.inf)
    np.minimum.at(nearest, (row - top) * crop[1] + (col - left), depth)
    image = np.where(np.isfinite(nearest), nearest, 0.0).reshape(crop)
    # here: scipy.ndimage takes 0.3 s to import, and every operator listing imports this module
    from scipy import ndimage

    filled = ndimage.binary_closing(image > 0, structure=np.ones(size, bool), border_value=0) | (image > 0)
    nearby = np.where(image > 0, image, ndimage.maximum_filter(image, size=size))
    covered.reshape(shape)[top:bottom, left:right] = filled & (nearby > 0)
    occluder.reshape(shape)[top:bottom, left:right] = nearby
    return covered, occluder


def _closing_size(spacing: tuple[float, float]) -> tuple[int, int]:
    return int(np.clip(np.ceil(spacing[0]) + 1, 2, 15)), int(np.clip(np.ceil(spacing[1]) + 1, 2, 15))


def _occlude(cloud: PointCloud | _Grown, pts: _Pts, new_xyz: F64, range_ratio: float,
             source_steps: tuple[float, float] | None = None, exclude: NDArray[np.intp] | None = None,
             extra: PointCloud | None = None, source_xyz: F64 | None = None) -> _Occlusion:
    """Z-buffer of new points (a moved or inserted object) against the frame's points.

    A new point is *sensed* when the sensor could return it with nothing else there: its
    elevation within the frame's beams, its azimuth among the columns the frame has returns in
    (a camera-cropped scan has none beside the image), its range within the frame's farthest
    return; of several sensed points in one pixel (beam and firing) only the nearest is, as a
    scan gives one return per ray. A sensed point is kept unless a nearer existing return hides
    it. Background points behind the object's silhouette (holes as wide as the new points'
    spacing closed: ``range_ratio`` (source range / new range) times the source sensor's
    (elevation, azimuth) steps over the frame's, the frame's own when ``source_steps`` is None)
    are removed.

    ``source_xyz`` (the same points where the object stands in the frame: a move) makes each
    test differential, because the frame *observed* the object there: the pixel grid estimated
    from a real scan (no ring channel, per-laser offsets, motion correction) is coarser and less
    regular than the scan, so it puts distinct returns in one pixel and nearer neighbours in front
    of observed points, and its hole closing covers ground seen under a car. So of the moved
    points that share a pixel, as many are kept (pro rata) as the grid merged where the object
    was observed — the object loses only the returns its move packs closer together, as when
    it moves away — a moved point is hidden only if it was not already "hidden" where it was
    observed, and a frame point is removed only if the old silhouette did not already cover it.
    A zero move then changes nothing; a real move removes what the move newly hides.

    The background is the frame's points less ``exclude`` (the object's old points) plus
    ``extra`` (ground infill; synthetic rays through the object's points, hidden behind any
    object return in their pixel); ``keep_background`` covers the frame's points, then ``extra``'s."""
    extra = extra if extra is not None else PointCloud.empty(cloud.channels)
    keep_bg = np.ones(len(cloud) + len(extra), bool)
    if len(new_xyz) == 0:
        return _Occlusion(keep_bg, np.zeros(0, bool), np.zeros(0, bool), np.zeros(0), None)
    moving = source_xyz is not None and len(source_xyz) == len(new_xyz)
    span = np.concatenate([new_xyz, source_xyz]) if moving else new_xyz  # type: ignore[list-item]
    centre, half = _azimuth_span(span)
    index = _wedge_index(pts, centre, half + np.deg2rad(3.0))
    extra_index = _wedge_index(_Pts(extra.xyz), centre, half + np.deg2rad(3.0)) if len(extra) else index[:0]
    in_frame = np.concatenate([np.ones(len(index), bool), np.zeros(len(extra_index), bool)])
    is_bg = in_frame.copy()
    if exclude is not None and len(exclude):
        is_bg[:len(index)] = ~np.isin(index, exclude)
    is_bg[len(index):] = True
    ring = time_values = None
    rows = cloud.rows(index) if isinstance(cloud, _Grown) else cloud.data[index]
    if cloud.has("ring"):
        ring = np.concatenate([rows[:, cloud.index("ring")], extra.channel("ring")[extra_index]])
    if cloud.has("time"):
        time_values = np.concatenate([rows[:, cloud.index("time")], extra.channel("time")[extra_index]])
    wedge = _wedge_of(np.concatenate([rows[:, :3], extra.xyz[extra_index]]), ring,
                      np.concatenate([index, len(cloud) + extra_index]), centre)
    az, elev, depth = _spherical(new_xyz, centre)
    row, col = wedge.cells(az, elev)
    cols_in = [col, wedge.col]
    if moving:
        src_az, src_elev, src_depth = _spherical(source_xyz, centre)  # type: ignore[arg-type]
        src_row, src_col = wedge.cells(src_az, src_elev)
        cols_in.append(src_col)
    col_lo = min(int(c.min()) for c in cols_in if len(c)) - 16
    cols = max(int(c.max()) for c in cols_in if len(c)) - col_lo + 17
    shape = (len(wedge.elevations), cols)
    key = row * cols + (col - col_lo)
    bg_key = wedge.row * cols + (wedge.col - col_lo)

    # What the sensor returns from the object alone: in its beams, columns and range, one per pixel.
    half_step = wedge.elev_step / 2
    scanned = np.unique(wedge.col[in_frame])
    sensed = ((elev >= wedge.elevations[0] - half_step) & (elev <= wedge.elevations[-1] + half_step)
              & (depth <= pts.max_range() + DEPTH_MARGIN)
              & (np.isin(col, scanned) | np.isin(col - 1, scanned) | np.isin(col + 1, scanned)))
    candidates = np.flatnonzero(sensed)
    order = candidates[np.lexsort((depth[candidates], key[candidates]))]
    first = np.ones(len(order), bool)
    first[1:] = key[order][1:] != key[order][:-1]
    alone = np.zeros(len(new_xyz), bool)
    alone[order[first]] = True
    if moving:
        # The grid already merged some of the observed returns where the object stood: as many
        # (pro rata) of the points sharing a new pixel are kept, those that shared their source
        # pixel with the pixel's nearest point first, then the nearer.
        src_key = src_row * cols + (src_col - col_lo)
        merged_at_source = len(new_xyz) - len(np.unique(src_key))
        extra_points = order[~first]
        budget = min(len(extra_points), round(merged_at_source * len(candidates) / len(new_xyz)))
        if budget:
            group_start = np.flatnonzero(first)[np.cumsum(first) - 1]
            nearest = order[group_start]
            rank = (np.arange(len(order)) - group_start)[~first]
            shared = (src_key[order] == src_key[nearest])[~first]
            alone[extra_points[np.lexsort((rank, ~shared))[:budget]]] = True

    def buffer(entries: NDArray[np.bool_]) -> F64:
        nearest = np.full(shape[0] * cols, np.inf)
        np.minimum.at(nearest, bg_key[entries], wedge.depth[entries])
        return nearest

    bg_depth = buffer(is_bg)
    hidden = depth > bg_depth[key] + DEPTH_MARGIN
    if moving:
        frame_depth = buffer(is_bg & in_frame)
        hidden &= ~(src_depth > frame_depth[src_key] + DEPTH_MARGIN)
    keep_new = alone & ~hidden

    # Background behind the object's new silhouette goes (behind its old one it was seen: stays).
    spacing = (range_ratio, range_ratio)
    if source_steps is not None:
        spacing = (range_ratio * source_steps[0] / wedge.elev_step, range_ratio * source_steps[1] / wedge.az_step)
    covered, occluder = _silhouette(key[keep_new], depth[keep_new], shape, _closing_size(spacing))
    behind = covered[bg_key] & (wedge.depth > occluder[bg_key] + np.where(in_frame, DEPTH_MARGIN, 0.0))
    if moving:
        old_covered, old_occluder = _silhouette(src_key, src_depth, shape, _closing_size((1.0, 1.0)))
        behind &= ~(in_frame & old_covered[bg_key] & (wedge.depth > old_occluder[bg_key] + DEPTH_MARGIN))
    keep_bg[wedge.index[behind & is_bg]] = False

    ring_out = wedge.ring_of_row[row] if wedge.ring_of_row is not None else np.full(len(new_xyz), -1.0)
    time = time_shift = None
    if time_values is not None and np.any(in_frame):
        # A return's time follows the head's azimuth: the mean time of the column's frame returns.
        bg_col = wedge.col[in_frame] - col_lo
        counts = np.bincount(bg_col, minlength=cols)
        sums = np.bincount(bg_col, time_values[in_frame].astype(np.float64), minlength=cols)
        seen = np.flatnonzero(counts)
        mean_time = sums[seen] / counts[seen]
        time = np.interp(col - col_lo, seen, mean_time)
        if moving:
            time_shift = time - np.interp(src_col - col_lo, seen, mean_time)
    same_row = row == src_row if moving else None
    return _Occlusion(keep_bg, keep_new, sensed & alone, ring_out, time, same_row, time_shift)


def _recast_to_ground(rays: NDArray[np.floating], ground: _Ground, box: F64, reach: float) -> NDArray[np.intp]:
    """Which of the rays through ``rays`` (points) hit ``ground`` beyond the point and within
    ``reach`` metres of the box's centre; their hits are :func:`_ground_hits`."""
    hit, ok = _ground_hits(rays, ground)
    near = np.hypot(hit[:, 0] - box[0], hit[:, 1] - box[1]) <= reach
    return np.flatnonzero(ok & near)


def _ground_hits(rays: NDArray[np.floating], ground: _Ground,
                 roughness: F64 | None = None) -> tuple[F64, NDArray[np.bool_]]:
    """Where the rays through ``rays`` meet the ground plane (raised by ``roughness`` per ray:
    the hit slides along its ray, so it stays in its beam and firing), and which rays do so
    beyond their point."""
    p = np.asarray(rays, np.float64)
    length = np.linalg.norm(p, axis=1)
    d = p / np.maximum(length, 1e-9)[:, None]
    denom = d[:, 2] - ground.a * d[:, 0] - ground.b * d[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ground.c / denom
        ok = np.isfinite(t) & (t >= length - 1e-6) & (denom < 0)
        if roughness is not None:
            t = np.where(ok, np.maximum(t + roughness / denom, length), t)
    return d * np.where(ok, t, 0.0)[:, None], ok


def _ground_infill(cloud: PointCloud, removed: NDArray[np.intp], box: F64, ground: _Ground,
                   rng: np.random.Generator) -> PointCloud:
    """Ground returns for the rays that hit a removed object: each ray re-cast onto the local
    ground plane (the footprint and the near part of the shadow, up to the fitted ring), with the
    ray's ring and time, an intensity and class drawn from the ring's ground points, and the
    plane's residual scatter as the surface's roughness (the hit slides along its ray)."""
    channels = cloud.channels
    if len(removed) == 0:
        return PointCloud.empty(channels)
    reach = float(np.hypot(box[3], box[4])) / 2 + 2.7
    ray_index = _recast_to_ground(cloud.xyz[removed], ground, box, reach)
    if len(ray_index) == 0:
        return PointCloud.empty(channels)
    data = cloud.data[removed[ray_index]].astype(np.float32).copy()
    donors = ground.inliers if len(ground.inliers) else np.arange(len(cloud))
    roughness = np.zeros(len(ray_index))
    if len(donors):
        resid = cloud.xyz[donors, 2] - ground.height(cloud.xyz[donors, :2])
        roughness = rng.normal(0.0, float(min(np.std(resid), 0.05)), len(ray_index))
        data[:, 3] = cloud.intensity[donors[rng.integers(0, len(donors), len(ray_index))]]
        if cloud.has("label"):
            labels = cloud.channel("label")[donors].astype(np.int64)
            data[:, cloud.index("label")] = np.bincount(np.maximum(labels, 0)).argmax()
    data[:, :3], _ = _ground_hits(cloud.xyz[removed[ray_index]], ground, roughness)
    if cloud.has("instance"):
        data[:, cloud.index("instance")] = -1.0
    return PointCloud(data, channels)


# =========================================================================== choosing objects
class ObjectChoiceConfig(Config):
    count_range: NonNegativeRange = Field((1, 1), description="number of objects chosen (drawn as an integer)")
    classes: tuple[str, ...] | None = Field(None, description="only objects of these classes; None: any")
    min_points: int = Field(5, ge=0, description="prefer objects with at least this many points")


def _draw_count(rng: np.random.Generator, interval: Range) -> int:
    lo, hi = round(interval[0]), round(interval[1])
    return lo if lo >= hi else int(rng.integers(lo, hi + 1))


def _point_counts(scene: Scene, candidates: NDArray[np.intp]) -> NDArray[np.int64]:
    """Points in each box above its bottom's ground band (cheap: no ground fit)."""
    arr, pts = scene.boxes.as_array(), _Pts.of(scene.points)

    def count(box: F64) -> int:
        def above_band() -> int:
            inside = _in_box(pts, box, BOX_MARGIN)
            return int(np.count_nonzero(pts.z[inside] > box[2] - box[5] / 2 + GROUND_BAND))

        return _memoised(pts, ("count", box.tobytes()), above_band)

    return np.array([count(arr[i]) for i in candidates], np.int64)


def _choose_objects(rng: np.random.Generator, scene: Scene, config: ObjectChoiceConfig, count: int) -> list[int]:
    """Up to ``count`` distinct labelled objects, those with ``min_points`` points first."""
    boxes = scene.boxes
    ok = boxes.has_geometry
    if config.classes is not None:
        ok &= np.isin(boxes.labels, list(config.classes))
    candidates = np.flatnonzero(ok)
    if count <= 0 or len(candidates) == 0:
        return []
    shuffled = candidates[rng.permutation(len(candidates))]
    enough = _point_counts(scene, shuffled) >= config.min_points
    ranked = np.concatenate([shuffled[enough], shuffled[~enough]])
    return sorted(int(i) for i in ranked[:count])


def _check_objects(name: str, scene: Scene, objects: Sequence[int], track_ids: Sequence[int]) -> None:
    boxes = scene.boxes
    for i, tid in zip(objects, track_ids, strict=True):
        if not (0 <= i < len(boxes)) or not boxes.has_geometry[i] or int(boxes.track_ids[i]) != tid:
            raise ValueError(f"{name}: params name box {i} with track id {tid}, which this frame does not have "
                             "(the params were drawn for another frame)")


class ObjectsParams(Params):
    objects: tuple[int, ...] = Field(description="indices into the frame's boxes")
    track_ids: tuple[int, ...] = Field(description="their track ids (−1 unknown), checked on replay")
    seed: int

    def is_identity(self) -> bool:
        return not self.objects


# =========================================================================== removal
