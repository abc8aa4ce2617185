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
from lidarfuzz.operators.lidar.sensor import POINTS, _rings_for, azimuth_rad, rings_of
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


def ring_azimuth_order(ring: NDArray[np.int64], azimuth: NDArray[np.floating]) -> NDArray[np.intp]:
    """``np.lexsort((azimuth, ring))``: by ring, then azimuth, ties in index order — computed as a
    stable (radix) sort of the rings and a stable sort of each ring's azimuths.

    A spinning LiDAR publishes each ring's points in firing order, i.e. in azimuth order (falling,
    as the head turns clockwise): the per-ring sort then meets one long run, which the stable
    sort (timsort) takes in linear time, where ``lexsort`` sorts everything from scratch
    (6 ms against 1.3 ms on a 120k HDL-64E frame). Same order, element for element.
    """
    if len(ring) == 0 or int(ring.min()) < np.iinfo(np.int16).min or int(ring.max()) > np.iinfo(np.int16).max:
        return np.lexsort((azimuth, ring))
    by_ring = np.argsort(ring.astype(np.int16), kind="stable")  # radix sort: small integers
    sorted_rings = ring[by_ring]
    bounds = np.flatnonzero(sorted_rings[1:] != sorted_rings[:-1]) + 1
    order = np.empty_like(by_ring)
    for start, end in zip(np.r_[0, bounds], np.r_[bounds, len(ring)], strict=True):
        members = by_ring[start:end]
        order[start:end] = members[np.argsort(azimuth[members], kind="stable")]
    return order


def far_neighbour(cloud: PointCloud, ring: NDArray[np.int64], edge_m: float,
                  max_gap_deg: float) -> NDArray[np.int64]:
    """For each point, the index of its farther azimuth neighbour on the same ring when that one
    lies more than ``edge_m`` behind it (the beam's footprint straddles an edge), else −1.
    Neighbours more than ``max_gap_deg`` away in azimuth (across a gap of sky) do not count;
    points of unknown ring (−1) have none."""
    n = len(cloud)
    result = np.full(n, -1, np.int64)
    if n < 2:
        return result
    xyz = cloud.xyz.astype(np.float64)
    distance = np.sqrt(np.einsum("ij,ij->i", xyz, xyz))
    azimuth = azimuth_rad(xyz)
    order = ring_azimuth_order(ring, azimuth)
    ring_s, az_s, dist_s = ring[order], azimuth[order], distance[order]
    adjacent = (ring_s[1:] == ring_s[:-1]) & (ring_s[1:] >= 0) & (np.diff(az_s) <= np.radians(max_gap_deg))
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
    has = best >= 0
    result[order[has]] = order[best[has]]
    return result


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
        _, source = rings_of(sample.points) if len(sample.points) else (None, "elevation")
        cfg = self.config
        return DualReturnParams(ratio=uniform(rng, cfg.ratio_range), edge_m=cfg.edge_m, max_gap_deg=cfg.max_gap_deg,
                                behind_share=cfg.behind_share, ring_source=source, seed=draw_seed(rng))

    def apply(self, sample: Scene, params: DualReturnParams) -> Scene:
        cloud = sample.points
        count = round(params.ratio * len(cloud))
        if count == 0:
            return sample
        chosen = np.sort(np.random.default_rng(params.seed).choice(len(cloud), size=count, replace=False))
        second = cloud.data[chosen].copy()
        ring = _rings_for(cloud, params.ring_source)
        behind = far_neighbour(cloud, ring, params.edge_m, params.max_gap_deg)[chosen]
        distinct = behind >= 0
        if distinct.any():
            far = cloud.data[behind[distinct]]
            xyz = second[distinct, :3].astype(np.float64)
            scale = np.linalg.norm(far[:, :3].astype(np.float64), axis=1) / np.maximum(np.linalg.norm(xyz, axis=1),
                                                                                         1e-9)
            second[distinct, :3] = xyz * scale[:, None]
            second[distinct, 3] = far[:, 3] * params.behind_share
            for name in ("label", "instance"):
                if cloud.has(name):
                    second[distinct, cloud.index(name)] = far[:, cloud.index(name)]
        # np.insert(data, chosen + 1, second): each chosen row twice (repeat), then its copy
        # (the k-th, at chosen[k] + 1 + k once the k earlier ones are in) becomes the second return
        repeats = np.ones(len(cloud), np.intp)
        repeats[chosen] = 2
        data = np.repeat(cloud.data, repeats, axis=0)
        data[chosen + 1 + np.arange(count)] = second
        return sample.with_points(cloud.with_data(data))
