"""The sensor's return mode: one echo per firing, or two (dual return).

Spinning LiDARs (Velodyne, Hesai, Ouster) can report two returns per firing — the strongest
and the last, or the first and the last. Their manuals state what a driver then publishes:
when only one echo came back, *both* blocks of the pair hold the same measurement; when the
beam's footprint straddled an edge (or passed through foliage, rain or dust), the second is a
farther surface behind the first. Switching a sensor or its driver from single to dual return
therefore roughly doubles the point count, mostly with exact duplicates, and adds a few
returns from behind object edges. A system whose buffers, voxel limits or per-cell counts were
sized for single-return data meets this the day the configuration changes.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import Config, Operator, Params, Relation, ShareRange, draw_seed, uniform
from lidarfuzz.operators.lidar.sensor import POINTS, _rings_for, ring_source
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


class DualReturnConfig(Config):
    ratio_range: ShareRange = Field((1.0, 1.0), description="share of firings whose pair of returns is published")
    edge_m: float = Field(1.0, gt=0, description="a ring neighbour this much farther makes the second return distinct")
    max_gap_deg: float = Field(1.0, gt=0, description="farthest azimuth step to a neighbour on the same ring")
    behind_share: float = Field(0.5, ge=0, le=1, description="the far surface's intensity share in a distinct second "
                                                             "return (the beam's energy it received)")


class DualReturnParams(Params):
    ratio: float = Field(ge=0, le=1)
    edge_m: float = Field(gt=0)
    max_gap_deg: float = Field(gt=0)
    behind_share: float = Field(ge=0, le=1)
    ring_source: str = Field(description="'channel' or 'elevation': where the rings came from")
    seed: int

    def is_identity(self) -> bool:
        return self.ratio == 0


#: Points per block of :func:`far_neighbour`'s float64 work: a block's coordinates stay in the L2
#: cache, and no N×3 float64 copy of the cloud (2.7 MB on an HDL-64E frame, new pages each call) is made.
BLOCK = 8192


def _narrow_rings(ring: NDArray[np.int64]) -> NDArray[np.signedinteger] | None:
    """The rings as int8, or int16 where they do not fit (None beyond, or for no points): the
    stable argsort of int8 is a one-pass radix sort (int16 takes two, 2.5× the time), and
    gathering them moves an eighth of the bytes."""
    if len(ring) == 0:
        return None
    low, high = int(ring.min()), int(ring.max())
    if np.iinfo(np.int8).min <= low and high <= np.iinfo(np.int8).max:
        return ring.astype(np.int8)
    if np.iinfo(np.int16).min <= low and high <= np.iinfo(np.int16).max:
        return ring.astype(np.int16)
    return None


def _sorted_within_rings(sorted_rings: NDArray[np.signedinteger], azimuth: NDArray[np.floating]) -> NDArray[np.intp]:
    """Positions that stably sort each ring's run of ``azimuth`` (both in ring-sorted order)."""
    bounds = np.flatnonzero(sorted_rings[1:] != sorted_rings[:-1]) + 1
    positions = np.empty(len(sorted_rings), np.intp)
    for start, end in zip(np.r_[0, bounds], np.r_[bounds, len(sorted_rings)], strict=True):
        positions[start:end] = start + np.argsort(azimuth[start:end], kind="stable")
    return positions


def ring_azimuth_order(ring: NDArray[np.int64], azimuth: NDArray[np.floating]) -> NDArray[np.intp]:
    """``np.lexsort((azimuth, ring))``: by ring, then azimuth, ties in index order — computed as a
    stable (radix) sort of the rings and a stable sort of each ring's azimuths.

    A spinning LiDAR publishes each ring's points in firing order, i.e. in azimuth order (falling,
    as the head turns clockwise): the per-ring sort then meets one long run, which the stable
    sort (timsort) takes in linear time, where ``lexsort`` sorts everything from scratch
    (6 ms against 1.3 ms on a 120k HDL-64E frame). Same order, element for element.
    """
    narrow = _narrow_rings(ring)
    if narrow is None:
        return np.lexsort((azimuth, ring))
    by_ring = np.argsort(narrow, kind="stable")
    return by_ring[_sorted_within_rings(narrow[by_ring], azimuth[by_ring])]


def _falling_within_rings(sorted_rings: NDArray[np.signedinteger], azimuth: NDArray[np.floating]) -> bool:
    """Whether, in ring-sorted order, every ring's azimuths fall strictly (no ties, no NaN): a
    spinning sensor's scan order. Each ring's ascending azimuth order is then its reverse."""
    rising = azimuth[1:] >= azimuth[:-1]  # False for NaN on either side
    rising &= sorted_rings[1:] == sorted_rings[:-1]
    return not rising.any() and not np.isnan(azimuth).any()


def _range_and_azimuth_of_rows(rows: NDArray[np.float32], columns: NDArray[np.float64], term: NDArray[np.float64],
                               distance: NDArray[np.float64], azimuth: NDArray[np.float64]) -> None:
    """:func:`range_and_azimuth` of a block of rows into ``distance`` and ``azimuth``; ``columns``
    (3 × at least the block) and ``term`` are scratch buffers.

    The squares are summed as ``einsum("ij,ij->i", p, p)`` sums a row of three, ``(x·x + z·z) +
    y·y`` (its vector lanes: x and z share one), in place, ~3× faster than the einsum kernel on
    rows of three; ``tests/operators/test_simple_fast.py`` holds the einsum as the reference.
    arctan2 reads contiguous rows: the same kernel at half the time of the strided columns."""
    k = len(rows)
    x, y, z = columns[0, :k], columns[1, :k], columns[2, :k]
    np.copyto(columns[:, :k], rows[:, :3].T)  # widened to float64
    squared = np.multiply(x, x, out=distance)
    squared += np.multiply(z, z, out=term[:k])
    squared += np.multiply(y, y, out=term[:k])
    np.sqrt(squared, out=squared)
    np.arctan2(y, x, out=azimuth)


def range_and_azimuth(data: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """float64 range and azimuth of a cloud's points (``data``: its rows, x, y, z first):
    ``sqrt(einsum("ij,ij->i", p, p))`` and ``arctan2(p[:, 1], p[:, 0])`` of their float64
    coordinates ``p``, as :func:`far_neighbour` computed them on a whole N×3 float64 copy — the
    same values — in blocks of :data:`BLOCK` rows, each block's x, y and z widened into three
    contiguous float64 rows of one small buffer (:func:`_range_and_azimuth_of_rows`)."""
    n = len(data)
    distance, azimuth = np.empty(n), np.empty(n)
    block = min(BLOCK, n)
    columns, term = np.empty((3, block)), np.empty(block)
    for start in range(0, n, block):
        end = min(start + block, n)
        _range_and_azimuth_of_rows(data[start:end], columns, term, distance[start:end], azimuth[start:end])
    return distance, azimuth


Pairs = tuple[NDArray[np.intp], NDArray[np.intp]]


def _neighbours_in_scan_order(data: NDArray[np.float32], by_ring: NDArray[np.intp],
                              ring_s: NDArray[np.signedinteger], edge_m: float, gap: float) -> Pairs | None:
    """:func:`far_neighbour_pairs` of a cloud in scan order, block by block of the ring-sorted
    positions; None (the caller sorts) where the cloud is not in scan order.

    ``by_ring`` is the stable ring sort and ``ring_s`` the rings in its order. Each block's rows
    are gathered in that order with one position more on either side (a position's neighbours are
    the positions next to it), their range and azimuth computed there, the scan order tested on
    the block's pairs (:func:`_falling_within_rings`: every pair and every point is in some
    block) and the neighbours of the block's own positions found as on the whole arrays — so no
    N-long float64 array (range, azimuth, their sorted copies, the running farthest range) is
    made: with them the call's peak memory could make the allocator return the heap top after
    each call and the next one fault ~1,800 fresh pages in (~2 ms of system time)."""
    n = len(by_ring)
    points, neighbours = [], []
    width = min(BLOCK, n) + 2
    rows = np.empty((width, data.shape[1]), np.float32)
    columns, term, distance, azimuth = np.empty((3, width)), np.empty(width), np.empty(width), np.empty(width)
    for start in range(0, n, BLOCK):
        low, high = max(start - 1, 0), min(start + BLOCK + 1, n)
        k = high - low
        # ('clip': by_ring is a permutation, so no bounds check is needed, and none buffers the gather)
        block_rows = np.take(data, by_ring[low:high], axis=0, out=rows[:k], mode="clip")
        dist_s, az_s = distance[:k], azimuth[:k]
        _range_and_azimuth_of_rows(block_rows, columns, term, dist_s, az_s)
        rings = ring_s[low:high]
        if not _falling_within_rings(rings, az_s):
            return None
        # adjacent[j]: positions j and j + 1 are azimuth neighbours (the same subtraction, higher
        # azimuth minus lower, as in ascending order)
        adjacent = (rings[1:] == rings[:-1]) & (rings[1:] >= 0) & (az_s[:-1] - az_s[1:] <= gap)
        best = np.full(k, -1, np.int64)
        best_range = dist_s + edge_m
        farther = adjacent & (dist_s[:-1] > best_range[1:])  # position j + 1's next neighbour is j
        best[1:][farther] = np.flatnonzero(farther)
        best_range[1:][farther] = dist_s[:-1][farther]
        farther = adjacent & (dist_s[1:] > best_range[:-1])  # position j's previous one is j + 1
        best[:-1][farther] = np.flatnonzero(farther) + 1
        own = best[start - low:start - low + min(BLOCK, n - start)]  # the block's own positions
        has = np.flatnonzero(own >= 0)
        points.append(by_ring[start + has])
        neighbours.append(by_ring[low + own[has]])
    return np.concatenate(points), np.concatenate(neighbours)


def far_neighbour(cloud: PointCloud, ring: NDArray[np.int64], edge_m: float,
                  max_gap_deg: float) -> NDArray[np.int64]:
    """For each point, the index of its far neighbour (:func:`far_neighbour_pairs`), else −1."""
    result = np.full(len(cloud), -1, np.int64)
    points, neighbours = far_neighbour_pairs(cloud, ring, edge_m, max_gap_deg)
    result[points] = neighbours
    return result


def far_neighbour_pairs(cloud: PointCloud, ring: NDArray[np.int64], edge_m: float, max_gap_deg: float) -> Pairs:
    """The points whose farther azimuth neighbour on the same ring lies more than ``edge_m``
    behind them (the beam's footprint straddles an edge), and those neighbours' indices, as
    ``(points, neighbours)``: the pairs only, so a caller that wants some points' neighbours
    makes no N-long array (:func:`far_neighbour` gives one). Neighbours more than
    ``max_gap_deg`` away in azimuth (across a gap of sky) do not count; points of unknown ring
    (−1) have none.

    Neighbours are adjacent in the (ring, azimuth) order; of the two, the next one (higher
    azimuth) wins unless the previous one lies farther still. A cloud in scan order (each ring's
    azimuths strictly falling in index order, as a spinning sensor publishes them) needs no
    azimuth sort: the stable ring sort already holds each ring in exactly reversed azimuth order,
    so the same comparisons run on it with next and previous swapped
    (:func:`_neighbours_in_scan_order`). Other clouds are sorted as :func:`ring_azimuth_order`
    sorts them.
    """
    n = len(cloud)
    if n < 2:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    gap = np.radians(max_gap_deg)
    narrow = _narrow_rings(ring)
    ring_s: NDArray[np.signedinteger]
    if narrow is not None:
        by_ring = np.argsort(narrow, kind="stable")
        ring_s = narrow[by_ring]
        in_scan_order = _neighbours_in_scan_order(cloud.data, by_ring, ring_s, edge_m, gap)
        if in_scan_order is not None:
            return in_scan_order
    distance, azimuth = range_and_azimuth(cloud.data)
    # (each large temporary is released once used: a lower peak of memory, fewer fresh pages to fault in)
    if narrow is None:
        order = np.lexsort((azimuth, ring))
        ring_s, az_s, dist_s = ring[order], azimuth[order], distance[order]
        del distance, azimuth
    else:
        az_s, dist_s = azimuth[by_ring], distance[by_ring]
        del distance, azimuth
        within = _sorted_within_rings(ring_s, az_s)
        order, az_s, dist_s = by_ring[within], az_s[within], dist_s[within]  # ring_s: the same after
    adjacent = (ring_s[1:] == ring_s[:-1]) & (ring_s[1:] >= 0) & (np.diff(az_s) <= gap)
    # sorted position k: its next neighbour is k + 1 (when adjacent[k]) and previous k − 1 (adjacent[k − 1])
    # the next neighbour (k + 1) first, then the previous (k − 1) when it lies farther still; with
    # slices of the sorted arrays (position k's partner is k ± 1) instead of gathered copies
    best = np.full(n, -1, np.int64)
    best_range = dist_s + edge_m  # a neighbour must lie beyond this
    farther = adjacent & (dist_s[1:] > best_range[:-1])
    best[:-1][farther] = np.flatnonzero(farther) + 1
    best_range[:-1][farther] = dist_s[1:][farther]
    farther = adjacent & (dist_s[:-1] > best_range[1:])
    best[1:][farther] = np.flatnonzero(farther)
    has = np.flatnonzero(best >= 0)
    return order[has], order[best[has]]


class DualReturn(Operator[Scene, DualReturnConfig, DualReturnParams]):
    """A dual-return sensor or driver: each chosen firing reports a second return right after
    its first, as the driver publishes the pair.

    Exactly ``round(ratio · N)`` firings (points, without replacement) get a second return,
    inserted after the first in the cloud's order, so the scan order stays the sensor's. It
    is an exact copy of the first (the manuals: with one echo, both blocks hold the same data),
    unless a neighbour on the same ring (:func:`far_neighbour`) lies more than ``edge_m``
    farther: then the beam straddled an edge and the second return lies on that farther
    surface, along this firing's own direction, with ``behind_share`` of the neighbour's
    intensity and its ``label`` and ``instance``. Rings come from the ``ring`` channel or,
    without one, from the elevations (the params say which). Severity: ratio 0.2, 0.4, 0.6,
    0.8, 0.9; ``ratio_range=(1, 1)`` is the raw dual-return stream, twice the points. Boxes, map and
    calibration are kept (the world has not changed). Degrading and not harmless at any
    severity: a learned detector's point-density features legitimately change; compare with a
    reference system (``objects_lost``) to see a limit the point count crosses.
    """

    name = "dual_return"
    aliases = ("DUAL",)
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 0
    targets = POINTS
    ConfigModel = DualReturnConfig
    ParamsModel = DualReturnParams
    IDENTITY: ClassVar = {"ratio_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"ratio_range": (r, r)} for s, r in
                            [(1, 0.2), (2, 0.4), (3, 0.6), (4, 0.8), (5, 0.9)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> DualReturnParams:
        source = ring_source(sample.points)
        cfg = self.config
        return DualReturnParams(ratio=uniform(rng, cfg.ratio_range), edge_m=cfg.edge_m, max_gap_deg=cfg.max_gap_deg,
                                behind_share=cfg.behind_share, ring_source=source, seed=draw_seed(rng))

    def apply(self, sample: Scene, params: DualReturnParams) -> Scene:
        cloud = sample.points
        n = len(cloud)
        count = round(params.ratio * n)
        if count == 0:
            return sample
        # the draw's indices in increasing order (they are distinct): a mask read back, O(N), not a sort
        picked = np.zeros(n, bool)
        picked[np.random.default_rng(params.seed).choice(n, size=count, replace=False)] = True
        chosen = np.flatnonzero(picked)
        # Each chosen row twice, in place in the scan order: the copy after it is its second return
        # (the k-th chosen one's at chosen[k] + 1 + k), an exact copy unless the beam straddled an edge.
        # The output is made first, before the neighbour search's temporaries: freed above it, they
        # leave the heap's free top at most their peak plus the output once the caller drops it
        # (made last, it sat above them and the free top reached the allocator's trim threshold:
        # the heap was given back and every call faulted ~2,300 fresh pages in, ~2.5 ms).
        data = np.repeat(cloud.data, picked.view(np.uint8) + np.uint8(1), axis=0)
        ring = _rings_for(cloud, params.ring_source)
        points, neighbours = far_neighbour_pairs(cloud, ring, params.edge_m, params.max_gap_deg)
        del ring
        # far_neighbour(…)[chosen], without its N-long array: the chosen points' neighbours, else −1
        wanted = picked[points]
        behind = np.full(count, -1, np.int64)
        behind[np.searchsorted(chosen, points[wanted])] = neighbours[wanted]
        distinct = np.flatnonzero(behind >= 0)
        if len(distinct):
            second, far = cloud.data[chosen[distinct]], cloud.data[behind[distinct]]  # (new arrays)
            xyz = second[:, :3].astype(np.float64)
            scale = np.linalg.norm(far[:, :3].astype(np.float64), axis=1) / np.maximum(np.linalg.norm(xyz, axis=1),
                                                                                         1e-9)
            second[:, :3] = xyz * scale[:, None]
            second[:, 3] = far[:, 3] * params.behind_share
            for name in ("label", "instance"):
                if cloud.has(name):
                    second[:, cloud.index(name)] = far[:, cloud.index(name)]
            data[chosen[distinct] + 1 + distinct] = second
        return sample.with_points(cloud.with_data(data))
