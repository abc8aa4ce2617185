"""Object-level operators: ground-truth objects removed, corrupted, moved or inserted.

Every operator here acts on labelled objects (boxes with a geometry; ``DontCare``
regions, whose geometry is NaN, are never chosen). An object's points are the points
inside its box (grown by :data:`BOX_MARGIN`) that lie above the local ground band
(:data:`GROUND_BAND` over the lower of the fitted ground and the box's bottom), plus,
when the cloud has an ``instance`` channel, the box's points labelled with the box's
track id: the ground under a box belongs to the road, not to the object. Params record
the chosen boxes by index *and* track id, and replaying them on another frame is an error.

Occlusion after a move or an insertion is recomputed with a spherical range image
(z-buffer) at the sensor's own angular resolution, estimated from the data around the
object: one row per beam (from the ``ring`` channel, or elevation clusters when there is
none) and the azimuth step between neighbouring returns of a beam. Only the wedge of
azimuth around the object is rasterised: one cheap pass over the frame picks it out.
Vacated space (a removed or moved object's footprint and shadow) can be filled with
ground: the object's own rays are re-cast onto the local ground plane (a plane fitted
to ground points in a ring around the box), which gives the density of the real scan
pattern without any tuning.

Intensity: inserted and infilled points take intensities from the frame itself or
from a library normalised to [0, 1] and rescaled to the frame's scale (0–255 when the
frame's maximum exceeds 1), so both conventions work.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy import ndimage

from lidarfuzz.operators.base import Config, Operator, Params, Relation, Target, draw_seed, uniform
from lidarfuzz.operators.lidar.common import intensity_scale, relabel_in_image
from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.geometry import bev_corners, bev_intersection_area
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim.materials import OBJECT_SEMANTIC, SEMANTIC_ID

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
    """A frame's coordinates with contiguous x, y, z columns, for fast neighbourhood queries."""

    __slots__ = ("x", "xyz", "y", "z")

    def __init__(self, xyz: NDArray[np.floating]) -> None:
        self.xyz = xyz
        self.x, self.y, self.z = np.ascontiguousarray(np.asarray(xyz).T).reshape(3, -1)

    def __len__(self) -> int:
        return len(self.xyz)

    def near(self, cx: float, cy: float, reach: float) -> NDArray[np.intp]:
        """Indices of the points in the axis-aligned square of half-edge ``reach`` around (cx, cy)."""
        index = np.flatnonzero(np.abs(self.x - np.float32(cx)) <= reach)
        return index[np.abs(self.y[index] - cy) <= reach]


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


@dataclass(frozen=True)
class _Ground:
    """A local ground plane z = a·x + b·y + c and the ground points it was fitted to."""

    a: float
    b: float
    c: float
    inliers: NDArray[np.intp]

    def height(self, xy: NDArray[np.floating]) -> F64:
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        return self.a * xy[:, 0] + self.b * xy[:, 1] + self.c


def _local_ground(pts: _Pts, box: F64, free: bool = False) -> _Ground:
    """Plane fitted to the lowest points in a ring around the box's footprint.

    The ring is 2.5 m wide, widened to 6 and 12 m while it holds fewer than ten candidates (a
    sparse sensor far away); candidates lie within a metre of the box's bottom, and the plane
    is fitted by least squares to those within 20 cm of the candidates' 10th height percentile,
    then again to the points within 10 cm of that fit. For a box that stands there (not
    ``free``) a plane more than 0.3 m off the box's bottom is not believed, and the ground is
    taken flat at the bottom, as it is without candidates. For a ``free`` place (an insertion)
    the bottom is unknown, so the ring's 10th height percentile stands in for it."""
    inner = float(np.hypot(box[3], box[4])) / 2 + 0.2
    bottom = float(box[2] - box[5] / 2)
    xyz = pts.xyz
    ring = np.zeros(0, np.intp)
    for width in (2.5, 6.0, 12.0):
        near = pts.near(box[0], box[1], inner + width)
        if free and len(near):
            bottom = float(np.percentile(pts.z[near], 10))
        near = near[np.abs(pts.z[near] - bottom) <= 1.0]
        r = np.hypot(pts.x[near] - box[0], pts.y[near] - box[1])
        ring = near[(r >= inner) & (r <= inner + width)]
        if len(ring) >= 10:
            break
    if len(ring) >= 5:
        z = pts.z[ring].astype(np.float64)
        low = ring[z <= np.percentile(z, 10) + 0.2]  # the ground, not kerbs, walls or legs
        for _ in range(2):
            if len(low) < 3:
                break
            design = np.column_stack([xyz[low, :2].astype(np.float64) - box[:2], np.ones(len(low))])
            coef, *_ = np.linalg.lstsq(design, pts.z[low].astype(np.float64), rcond=None)
            coef[:2] = np.clip(coef[:2], -0.2, 0.2)  # a road is never steeper than 20 %
            fitted = np.column_stack([xyz[ring, :2] - box[:2], np.ones(len(ring))]) @ coef
            low = ring[np.abs(fitted - pts.z[ring]) <= 0.1]
        if len(low) >= 3 and (free or abs(coef[2] - bottom) <= 0.3):
            a, b = float(coef[0]), float(coef[1])
            return _Ground(a, b, float(coef[2] - a * box[0] - b * box[1]), low)
    return _Ground(0.0, 0.0, bottom, ring[np.abs(pts.z[ring] - bottom) <= 0.1])


def _object_points(pts: _Pts, box: F64, ground: _Ground, cloud: PointCloud | None = None,
                   track_id: int = -1) -> NDArray[np.intp]:
    """Indices of an object's points: inside its (grown) box and above the ground band (the band
    starts at the ground or at the box's bottom, whichever is lower); with an ``instance``
    channel, the box's points labelled with its track id count too (a tyre's lowest returns)."""
    inside = _in_box(pts, box, BOX_MARGIN)
    floor = np.minimum(ground.height(pts.xyz[inside, :2]), box[2] - box[5] / 2)
    mine = pts.z[inside] > floor + GROUND_BAND
    if cloud is not None and cloud.has("instance") and track_id >= 0:
        mine |= cloud.channel("instance")[inside] == track_id
    return inside[mine]


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
    return bool(scene.roi.contains_xy(bev_corners(box[None])[0]).all())


def _clutter(pts: _Pts, box: F64, ground: _Ground, own: NDArray[np.intp]) -> int:
    """Points of something else (a wall, a pole, a tree) above the ground inside ``box``."""
    inside = np.setdiff1d(_in_box(pts, box, 0.0), own, assume_unique=True)
    return int(np.count_nonzero(pts.z[inside] > ground.height(pts.xyz[inside, :2]) + GROUND_BAND))


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
        pos = np.clip(np.searchsorted(self.elevations, elev), 1, max(len(self.elevations) - 1, 1))
        lower = self.elevations[np.maximum(pos - 1, 0)]
        upper = self.elevations[np.minimum(pos, len(self.elevations) - 1)]
        row = np.where(np.abs(elev - lower) <= np.abs(elev - upper), pos - 1, pos)
        row = np.clip(row, 0, len(self.elevations) - 1).astype(np.intp)
        return row, np.floor(az / self.az_step).astype(np.intp), depth


def _spherical(xyz: NDArray[np.floating], centre: float) -> tuple[F64, F64, F64]:
    p = np.asarray(xyz, np.float64)
    c, s = np.cos(centre), np.sin(centre)
    along, across = p[:, 0] * c + p[:, 1] * s, -p[:, 0] * s + p[:, 1] * c
    flat = np.hypot(p[:, 0], p[:, 1])
    return np.arctan2(across, along), np.arctan2(p[:, 2], flat), np.hypot(flat, p[:, 2])


def _wedge_index(pts: _Pts, centre: float, half_width: float) -> NDArray[np.intp]:
    """Indices of the points within ``half_width`` of azimuth ``centre``."""
    c, s = np.float32(np.cos(centre)), np.float32(np.sin(centre))
    along = pts.x * c + pts.y * s
    if half_width >= np.pi / 2:
        return np.flatnonzero(along >= np.hypot(pts.x, pts.y) * np.cos(min(half_width, np.pi)))
    cos2 = np.float32(np.cos(half_width) ** 2)
    index = np.flatnonzero(along >= 0)
    return index[along[index] ** 2 >= (pts.x[index] ** 2 + pts.y[index] ** 2) * cos2]


def _wedge_of(xyz: NDArray[np.floating], ring: NDArray[np.floating] | None, index: NDArray[np.intp],
              centre: float) -> _Wedge:
    """Rasterise points (their ids ``index``) at the data's resolution, azimuth relative to ``centre``."""
    az, elev, depth = _spherical(xyz, centre)
    ring_of_row: F64 | None = None
    if ring is not None and len(index) and np.all(ring >= 0):
        rings, inverse = np.unique(ring, return_inverse=True)
        order = np.lexsort((elev, inverse))
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
        order = np.lexsort((az, row))
        gaps = np.diff(az[order])[np.diff(row[order]) == 0]
        gaps = gaps[gaps > 1e-5]
        if len(gaps) >= 8:
            az_step = float(np.median(gaps))
    col = np.floor(az / az_step).astype(np.intp)
    return _Wedge(index, np.asarray(row, np.intp), col, depth, np.asarray(elevations, np.float64), ring_of_row,
                  az_step, centre)


def _azimuth_span(xyz: NDArray[np.floating]) -> tuple[float, float]:
    """(centre, half width) of the azimuths of ``xyz``, robust to the ±π seam."""
    az = np.arctan2(xyz[:, 1], xyz[:, 0]).astype(np.float64)
    centre = float(np.arctan2(np.sin(az).mean(), np.cos(az).mean()))
    return centre, float(np.abs(wrap_angle(az - centre)).max())


@dataclass(frozen=True)
class _Occlusion:
    keep_background: NDArray[np.bool_]  # over the frame's points
    keep_new: NDArray[np.bool_]  # over the new points
    ring: F64  # of the new points (−1 unknown)
    time: F64 | None  # of the new points, from their column


def _occlude(cloud: PointCloud, pts: _Pts, new_xyz: F64, range_ratio: float,
             source_steps: tuple[float, float] | None = None, exclude: NDArray[np.intp] | None = None,
             extra: PointCloud | None = None) -> _Occlusion:
    """Z-buffer of new points (a moved or inserted object) against the frame's points.

    The new points' angular spacing, in the frame's pixels, is ``range_ratio`` (source range /
    new range) times the source sensor's (elevation, azimuth) steps over the frame's (the frame's
    own when ``source_steps`` is None); holes that wide in the object's silhouette are closed
    before the background points behind it are removed. Of several new points in one pixel
    only the nearest survives, as a scan gives one return per beam and firing.

    The background is the frame's points less ``exclude`` (the object's old points) plus
    ``extra`` (ground infill); ``keep_background`` covers the frame's points, then ``extra``'s."""
    extra = extra if extra is not None else PointCloud.empty(cloud.channels)
    keep_bg = np.ones(len(cloud) + len(extra), bool)
    if len(new_xyz) == 0:
        return _Occlusion(keep_bg, np.zeros(0, bool), np.zeros(0), None)
    centre, half = _azimuth_span(new_xyz)
    index = _wedge_index(pts, centre, half + np.deg2rad(3.0))
    if exclude is not None and len(exclude):
        index = index[~np.isin(index, exclude)]
    extra_index = _wedge_index(_Pts(extra.xyz), centre, half + np.deg2rad(3.0)) if len(extra) else index[:0]
    ring = time_values = None
    if cloud.has("ring"):
        ring = np.concatenate([cloud.channel("ring")[index], extra.channel("ring")[extra_index]])
    if cloud.has("time"):
        time_values = np.concatenate([cloud.channel("time")[index], extra.channel("time")[extra_index]])
    wedge = _wedge_of(np.concatenate([cloud.xyz[index], extra.xyz[extra_index]]), ring,
                      np.concatenate([index, len(cloud) + extra_index]), centre)
    row, col, depth = wedge.pixels(new_xyz)
    spacing = (range_ratio, range_ratio)
    if source_steps is not None:
        spacing = (range_ratio * source_steps[0] / wedge.elev_step, range_ratio * source_steps[1] / wedge.az_step)
    col_lo = min(int(col.min()), int(wedge.col.min(initial=col.min()))) - 16
    cols = max(int(col.max()), int(wedge.col.max(initial=col.max()))) - col_lo + 17
    rows = len(wedge.elevations)
    key = row * cols + (col - col_lo)
    bg_key = wedge.row * cols + (wedge.col - col_lo)
    # Nearest new point per pixel; then drop new points hidden behind a nearer existing one.
    order = np.lexsort((depth, key))
    first = np.ones(len(order), bool)
    first[1:] = key[order][1:] != key[order][:-1]
    keep_new = np.zeros(len(new_xyz), bool)
    keep_new[order[first]] = True
    bg_depth = np.full(rows * cols, np.inf)
    np.minimum.at(bg_depth, bg_key, wedge.depth)
    keep_new &= depth <= bg_depth[key] + DEPTH_MARGIN
    # The object's silhouette, holes closed, with its farthest nearby depth in the filled pixels.
    flat_image = np.zeros(rows * cols)
    flat_image[key[keep_new]] = depth[keep_new]
    image = flat_image.reshape(rows, cols)
    size = (int(np.clip(np.ceil(spacing[0]) + 1, 2, 15)), int(np.clip(np.ceil(spacing[1]) + 1, 2, 15)))
    filled = ndimage.binary_closing(image > 0, structure=np.ones(size, bool), border_value=0) | (image > 0)
    occluder = np.where(image > 0, image, ndimage.maximum_filter(image, size=size)).ravel()
    covered = filled.ravel()[bg_key] & (occluder[bg_key] > 0)
    hidden = covered & (wedge.depth > occluder[bg_key] + DEPTH_MARGIN)
    keep_bg[wedge.index[hidden]] = False
    ring = wedge.ring_of_row[row] if wedge.ring_of_row is not None else np.full(len(new_xyz), -1.0)
    time = None
    if time_values is not None and len(wedge.index):
        # A return's time follows the head's azimuth: the mean time of the column's existing returns.
        bg_col = wedge.col - col_lo
        counts = np.bincount(bg_col, minlength=cols)
        sums = np.bincount(bg_col, time_values.astype(np.float64), minlength=cols)
        seen = np.flatnonzero(counts)
        time = np.interp(col - col_lo, seen, sums[seen] / counts[seen])
    return _Occlusion(keep_bg, keep_new, ring, time)


def _recast_to_ground(rays: NDArray[np.floating], ground: _Ground, box: F64, reach: float) -> NDArray[np.intp]:
    """Which of the rays through ``rays`` (points) hit ``ground`` beyond the point and within
    ``reach`` metres of the box's centre; their hits are :func:`_ground_hits`."""
    hit, ok = _ground_hits(rays, ground)
    near = np.hypot(hit[:, 0] - box[0], hit[:, 1] - box[1]) <= reach
    return np.flatnonzero(ok & near)


def _ground_hits(rays: NDArray[np.floating], ground: _Ground) -> tuple[F64, NDArray[np.bool_]]:
    p = np.asarray(rays, np.float64)
    length = np.linalg.norm(p, axis=1)
    d = p / np.maximum(length, 1e-9)[:, None]
    denom = d[:, 2] - ground.a * d[:, 0] - ground.b * d[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ground.c / denom
    ok = np.isfinite(t) & (t >= length - 1e-6) & (denom < 0)
    return d * np.where(ok, t, 0.0)[:, None], ok


def _ground_infill(cloud: PointCloud, removed: NDArray[np.intp], box: F64, ground: _Ground,
                   rng: np.random.Generator) -> PointCloud:
    """Ground returns for the rays that hit a removed object: each ray re-cast onto the local
    ground plane (the footprint and the near part of the shadow, up to the fitted ring), with the
    ray's ring and time, an intensity and class drawn from the ring's ground points, and the
    plane's residual scatter as range noise."""
    channels = cloud.channels
    if len(removed) == 0:
        return PointCloud.empty(channels)
    reach = float(np.hypot(box[3], box[4])) / 2 + 2.7
    ray_index = _recast_to_ground(cloud.xyz[removed], ground, box, reach)
    if len(ray_index) == 0:
        return PointCloud.empty(channels)
    hits, _ = _ground_hits(cloud.xyz[removed[ray_index]], ground)
    data = cloud.data[removed[ray_index]].astype(np.float32).copy()
    donors = ground.inliers if len(ground.inliers) else np.arange(len(cloud))
    if len(donors):
        resid = cloud.xyz[donors, 2] - ground.height(cloud.xyz[donors, :2])
        hits[:, 2] += rng.normal(0.0, float(min(np.std(resid), 0.05)), len(hits))
        data[:, 3] = cloud.intensity[donors[rng.integers(0, len(donors), len(hits))]]
        if cloud.has("label"):
            labels = cloud.channel("label")[donors].astype(np.int64)
            data[:, cloud.index("label")] = np.bincount(np.maximum(labels, 0)).argmax()
    data[:, :3] = hits
    if cloud.has("instance"):
        data[:, cloud.index("instance")] = -1.0
    return PointCloud(data, channels)


# =========================================================================== choosing objects
class ObjectChoiceConfig(Config):
    count_range: Range = Field((1, 1), description="number of objects chosen (drawn as an integer)")
    classes: tuple[str, ...] | None = Field(None, description="only objects of these classes; None: any")
    min_points: int = Field(5, ge=0, description="prefer objects with at least this many points")


def _draw_count(rng: np.random.Generator, interval: Range) -> int:
    lo, hi = round(interval[0]), round(interval[1])
    return lo if lo >= hi else int(rng.integers(lo, hi + 1))


def _point_counts(scene: Scene, candidates: NDArray[np.intp]) -> NDArray[np.int64]:
    """Points in each box above its bottom's ground band (cheap: no ground fit)."""
    arr, pts = scene.boxes.as_array(), _Pts(scene.points.xyz)
    counts = [np.count_nonzero(pts.z[_in_box(pts, arr[i], BOX_MARGIN)] > arr[i, 2] - arr[i, 5] / 2 + GROUND_BAND)
              for i in candidates]
    return np.array(counts, np.int64)


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
class ObjectRemovalConfig(ObjectChoiceConfig):
    fill_ground: bool = Field(True, description="re-cast the object's rays onto the local ground")


class ObjectRemovalParams(ObjectsParams):
    fill_ground: bool


class ObjectRemoval(Operator[Scene, ObjectRemovalConfig, ObjectRemovalParams]):
    """Objects that are not there: each chosen object's points (inside its box grown by 5 cm,
    above the 15 cm ground band, see the module docs) are deleted and its label removed. With ``fill_ground`` the
    rays that hit the object are re-cast onto the local ground plane (fitted in a 2.5 m ring
    around the box), so the footprint and the near shadow get ground returns at the scan's own
    density (intensity and class drawn from the ring's ground points) instead of a tell-tale hole.

    Params: chosen box indices and track ids, a seed for the infill. Leaves other objects,
    their labels, the ground under the box, calibration and map alone."""

    name = "object_removal"
    aliases = ("OBJ_REMOVE",)
    family = "object"
    relation = Relation.DEGRADING
    targets = POINTS_BOXES
    ConfigModel = ObjectRemovalConfig
    ParamsModel = ObjectRemovalParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": c} for s, c in
                            [(1, (1, 1)), (2, (1, 2)), (3, (2, 2)), (4, (2, 3)), (5, (3, 4))]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectRemovalParams:
        chosen = _choose_objects(rng, sample, self.config, _draw_count(rng, self.config.count_range))
        return ObjectRemovalParams(objects=tuple(chosen), track_ids=tuple(int(sample.boxes.track_ids[i])
                                                                          for i in chosen),
                                   fill_ground=self.config.fill_ground, seed=draw_seed(rng))

    def apply(self, sample: Scene, params: ObjectRemovalParams) -> Scene:
        if params.is_identity():
            return sample
        _check_objects(self.name, sample, params.objects, params.track_ids)
        cloud, arr = sample.points, sample.boxes.as_array()
        rng = np.random.default_rng(params.seed)
        pts = _Pts(cloud.xyz)
        drop = np.zeros(len(cloud), bool)
        fills = []
        for i in params.objects:
            ground = _local_ground(pts, arr[i])
            own = _object_points(pts, arr[i], ground, cloud, int(sample.boxes.track_ids[i]))
            drop[own] = True
            if params.fill_ground:
                fills.append(_ground_infill(cloud, own, arr[i], ground, rng))
        keep_boxes = np.ones(len(sample.boxes), bool)
        keep_boxes[list(params.objects)] = False
        points = PointCloud(np.concatenate([_rows(cloud.data, ~drop), *(f.data for f in fills)]), cloud.channels)
        return sample.replace(points=points, boxes=sample.boxes.select(keep_boxes))


# =========================================================================== in-box corruptions
class ObjectCutoutConfig(ObjectChoiceConfig):
    fraction_range: Range = Field((0.3, 0.3), description="sub-box edge as a share of the box's edges")


class ObjectCutoutParams(ObjectsParams):
    centers: tuple[tuple[float, float, float], ...] = Field(description="sub-box centres in each box's frame")
    sizes: tuple[tuple[float, float, float], ...] = Field(description="sub-box l, w, h, metres")


class ObjectCutout(Operator[Scene, ObjectCutoutConfig, ObjectCutoutParams]):
    """Part of an object unseen (a dark or glass panel, a partial occluder that was not
    scanned): the points in one random axis-aligned sub-box of each chosen object's box frame
    are deleted. The sub-box is centred on one of the object's points (so it always cuts
    something), clipped to the box. Labels, other objects and the ground stay."""

    name = "object_cutout"
    aliases = ("OBJ_CUTOUT",)
    family = "object"
    relation = Relation.DEGRADING
    targets = POINTS
    ConfigModel = ObjectCutoutConfig
    ParamsModel = ObjectCutoutParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": c, "fraction_range": (f, f)} for s, c, f in
                            [(1, (1, 1), 0.2), (2, (1, 1), 0.3), (3, (1, 2), 0.4), (4, (2, 2), 0.5),
                             (5, (2, 3), 0.6)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectCutoutParams:
        chosen = _choose_objects(rng, sample, self.config, _draw_count(rng, self.config.count_range))
        arr, xyz = sample.boxes.as_array(), sample.points.xyz
        pts = _Pts(xyz)
        centers, sizes = [], []
        for i in chosen:
            size = arr[i, 3:6] * uniform(rng, self.config.fraction_range)
            own = _object_points(pts, arr[i], _local_ground(pts, arr[i]), sample.points,
                                 int(sample.boxes.track_ids[i]))
            if len(own):
                local = _to_box_frame(xyz[own[rng.integers(len(own))]][None], arr[i])[0]
            else:
                local = rng.uniform(-0.5, 0.5, 3) * arr[i, 3:6]
            centers.append(tuple(float(v) for v in local))
            sizes.append(tuple(float(v) for v in size))
        return ObjectCutoutParams(objects=tuple(chosen), track_ids=tuple(int(sample.boxes.track_ids[i])
                                                                         for i in chosen),
                                  centers=tuple(centers), sizes=tuple(sizes), seed=draw_seed(rng))  # type: ignore[arg-type]

    def apply(self, sample: Scene, params: ObjectCutoutParams) -> Scene:
        if params.is_identity():
            return sample
        _check_objects(self.name, sample, params.objects, params.track_ids)
        xyz, arr = sample.points.xyz, sample.boxes.as_array()
        pts = _Pts(xyz)
        drop = np.zeros(len(xyz), bool)
        for i, centre, size in zip(params.objects, params.centers, params.sizes, strict=True):
            own = _object_points(pts, arr[i], _local_ground(pts, arr[i]), sample.points,
                                 int(sample.boxes.track_ids[i]))
            local = _to_box_frame(xyz[own], arr[i])
            inside = np.all(np.abs(local - np.asarray(centre)) <= np.asarray(size) / 2, axis=1)
            drop[own[inside]] = True
        return sample.with_points(_rows(sample.points.data, ~drop)) if drop.any() else sample


def _to_box_frame(xyz: NDArray[np.floating], box: F64) -> F64:
    return (np.asarray(xyz, np.float64) - box[:3]) @ _rotation_z(box[6])


class ObjectDensityConfig(ObjectChoiceConfig):
    ratio_range: Range = Field((0.3, 0.3), description="share of each chosen object's points dropped")


class ObjectDensityParams(ObjectsParams):
    ratio: float = Field(ge=0, le=1)


class ObjectDensityLoss(Operator[Scene, ObjectDensityConfig, ObjectDensityParams]):
    """A sparser object (a dark or wet surface, a far-away-looking object): a share of each
    chosen object's points, at least one, is dropped uniformly at random. Labels, other
    objects and the ground under the box stay."""

    name = "object_density_loss"
    aliases = ("OBJ_SPARSE",)
    family = "object"
    relation = Relation.DEGRADING
    targets = POINTS
    ConfigModel = ObjectDensityConfig
    ParamsModel = ObjectDensityParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": c, "ratio_range": (r, r)} for s, c, r in
                            [(1, (1, 1), 0.1), (2, (1, 1), 0.25), (3, (1, 2), 0.4), (4, (2, 2), 0.6),
                             (5, (2, 3), 0.8)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectDensityParams:
        chosen = _choose_objects(rng, sample, self.config, _draw_count(rng, self.config.count_range))
        return ObjectDensityParams(objects=tuple(chosen), track_ids=tuple(int(sample.boxes.track_ids[i])
                                                                          for i in chosen),
                                   ratio=uniform(rng, self.config.ratio_range), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: ObjectDensityParams) -> Scene:
        if params.is_identity() or params.ratio == 0:
            return sample
        _check_objects(self.name, sample, params.objects, params.track_ids)
        xyz, arr = sample.points.xyz, sample.boxes.as_array()
        pts = _Pts(xyz)
        rng = np.random.default_rng(params.seed)
        drop = np.zeros(len(xyz), bool)
        for i in params.objects:
            own = _object_points(pts, arr[i], _local_ground(pts, arr[i]), sample.points,
                                 int(sample.boxes.track_ids[i]))
            if len(own):
                count = max(1, round(params.ratio * len(own)))
                drop[rng.choice(own, size=count, replace=False)] = True
        return sample.with_points(_rows(sample.points.data, ~drop)) if drop.any() else sample


class ObjectJitterConfig(ObjectChoiceConfig):
    sigma_range: Range = Field((0.05, 0.05), description="std of the Gaussian offset per axis, metres")


class ObjectJitterParams(ObjectsParams):
    sigma: float = Field(ge=0)


class ObjectJitter(Operator[Scene, ObjectJitterConfig, ObjectJitterParams]):
    """A noisy object (multipath, a vibrating or rain-covered surface): each chosen object's
    points get independent Gaussian offsets of std ``sigma`` on x, y and z. Intensity, the
    other channels, labels, other objects and the ground stay."""

    name = "object_jitter"
    aliases = ("OBJ_JITTER",)
    family = "object"
    relation = Relation.DEGRADING
    targets = POINTS
    ConfigModel = ObjectJitterConfig
    ParamsModel = ObjectJitterParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": c, "sigma_range": (g, g)} for s, c, g in
                            [(1, (1, 1), 0.02), (2, (1, 1), 0.05), (3, (1, 2), 0.1), (4, (2, 2), 0.15),
                             (5, (2, 3), 0.25)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectJitterParams:
        chosen = _choose_objects(rng, sample, self.config, _draw_count(rng, self.config.count_range))
        return ObjectJitterParams(objects=tuple(chosen), track_ids=tuple(int(sample.boxes.track_ids[i])
                                                                         for i in chosen),
                                  sigma=uniform(rng, self.config.sigma_range), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: ObjectJitterParams) -> Scene:
        if params.is_identity() or params.sigma == 0:
            return sample
        _check_objects(self.name, sample, params.objects, params.track_ids)
        xyz, arr = sample.points.xyz, sample.boxes.as_array()
        pts = _Pts(xyz)
        rng = np.random.default_rng(params.seed)
        own = [_object_points(pts, arr[i], _local_ground(pts, arr[i]), sample.points,
                              int(sample.boxes.track_ids[i])) for i in params.objects]
        index = np.concatenate(own) if own else np.zeros(0, np.intp)
        if len(index) == 0:
            return sample
        data = sample.points.data.copy()
        data[index, :3] += rng.normal(0.0, params.sigma, (len(index), 3)).astype(np.float32)
        return sample.with_points(sample.points.with_data(data))


# =========================================================================== moving one object
def _splice_box(scene: Scene, i: int, new_box: F64) -> Boxes3D:
    """The frame's boxes with box ``i`` given a new geometry (alpha and 2D box re-projected,
    occlusion unknown); every other box is kept exactly."""
    boxes = scene.boxes
    one = boxes.select([i])
    one = one.with_geometry(centers=new_box[None, :3], sizes=new_box[None, 3:6], yaw=new_box[None, 6])
    one = relabel_in_image(one, scene.calib).replace(occlusion=[-1])
    fields = {}
    for name in ("centers", "sizes", "yaw", "truncation", "occlusion", "alpha", "bbox2d"):
        values = np.array(getattr(boxes, name))
        values[i] = getattr(one, name)[0]
        fields[name] = values
    return boxes.replace(**fields)


def _move_points(cloud: PointCloud, pts: _Pts, old: NDArray[np.intp], new_xyz: F64, fill: PointCloud,
                 range_ratio: float) -> PointCloud:
    """The frame with points ``old`` replaced by ``new_xyz`` (their other channels kept, ring and
    time re-derived where they land), ``fill`` added, and occlusion recomputed both ways."""
    occlusion = _occlude(cloud, pts, new_xyz, range_ratio, exclude=old, extra=fill)
    keep = occlusion.keep_background
    keep[old] = False
    moved = cloud.data[old].copy()
    moved[:, :3] = new_xyz
    if cloud.has("ring") and np.any(occlusion.ring >= 0):
        moved[:, cloud.index("ring")] = occlusion.ring
    if cloud.has("time") and occlusion.time is not None:
        moved[:, cloud.index("time")] = occlusion.time
    data = np.concatenate([_rows(cloud.data, keep[:len(cloud)]), _rows(fill.data, keep[len(cloud):]),
                           _rows(moved, occlusion.keep_new)])
    return PointCloud(data, cloud.channels)


class ObjectMoveParams(Params):
    object: int = Field(description="index into the frame's boxes; −1: nothing moved")
    track_id: int
    fill_ground: bool
    seed: int


class _ObjectMove:
    """Shared apply of the three object transforms: the subclass maps points and the box."""

    name: ClassVar[str]

    def _map(self, xyz: F64, box: F64, params: Any) -> tuple[F64, F64]:
        raise NotImplementedError

    def _moved(self, sample: Scene, params: Any) -> Scene:
        i = params.object
        _check_objects(self.name, sample, [i], [params.track_id])
        cloud, box = sample.points, sample.boxes.as_array()[i]
        pts = _Pts(cloud.xyz)
        ground = _local_ground(pts, box)
        own = _object_points(pts, box, ground, cloud, params.track_id)
        new_xyz, new_box = self._map(cloud.xyz[own].astype(np.float64), box, params)
        fill = PointCloud.empty(cloud.channels)
        if params.fill_ground:
            fill = _ground_infill(cloud, own, box, ground, np.random.default_rng(params.seed))
        old_range, new_range = float(np.hypot(*box[:2])), float(np.hypot(*new_box[:2]))
        points = _move_points(cloud, pts, own, new_xyz, fill, old_range / max(new_range, 1e-3))
        return sample.replace(points=points, boxes=_splice_box(sample, i, new_box))

    @staticmethod
    def _free(sample: Scene, pts: _Pts, i: int, new_box: F64, ground: _Ground, own: NDArray[np.intp]) -> bool:
        return _footprint_free(sample.boxes, new_box, skip=i) and _clutter(pts, new_box, ground, own) <= 3


# -- translation
class ObjectTranslateConfig(ObjectChoiceConfig):
    distance_range: Range = Field((1.0, 1.0), description="distance moved in the ground plane, metres")
    fill_ground: bool = Field(True, description="re-cast the vacated rays onto the local ground")
    attempts: int = Field(40, ge=1, description="destinations tried before giving up (identity)")


class ObjectTranslateParams(ObjectMoveParams):
    offset: tuple[float, float, float] = Field(description="dx, dy in the ground plane; dz follows the ground")

    def is_identity(self) -> bool:
        return self.object < 0 or self.offset == (0.0, 0.0, 0.0)


class ObjectTranslate(_ObjectMove, Operator[Scene, ObjectTranslateConfig, ObjectTranslateParams]):
    """One object displaced on the ground (a car parked a little further on, a pedestrian a step
    aside; the three object transforms move one object per mutant, ``count_range`` (0, 0) being
    the identity): its points and box move by (dx, dy) in a random direction, plus dz so the box keeps
    its height above the local ground. The destination is free: no other box within 20 cm, no
    other object's or structure's points above the ground inside it, and, when the frame has an
    ROI map, an object on the drivable area stays wholly on it while one off it (a pedestrian on
    the pavement) stays off it. Occlusion is recomputed with the range-image z-buffer: points the
    object now hides are removed, and so are its own points now behind something nearer; the
    vacated rays are re-cast onto the ground (``fill_ground``). Ring and time of moved points
    follow their new beam and azimuth. Not a global transform: other boxes, calibration and map
    stay; the moved box gets a re-projected alpha and 2D box, occlusion unknown."""

    name = "object_translate"
    aliases = ("OBJ_SHIFT",)
    family = "object"
    relation = Relation.DEGRADING
    targets = POINTS_BOXES
    ConfigModel = ObjectTranslateConfig
    ParamsModel = ObjectTranslateParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"distance_range": (d, d)} for s, d in
                            [(1, 0.5), (2, 1.0), (3, 2.0), (4, 3.5), (5, 5.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectTranslateParams:
        none = ObjectTranslateParams(object=-1, track_id=-1, offset=(0.0, 0.0, 0.0),
                                     fill_ground=self.config.fill_ground, seed=0)
        count = min(_draw_count(rng, self.config.count_range), 1)
        candidates = _choose_objects(rng, sample, self.config, len(sample.boxes) if count else 0)
        if not candidates:
            return none
        order = rng.permutation(candidates)
        pts, arr = _Pts(sample.points.xyz), sample.boxes.as_array()
        seed = draw_seed(rng)
        for attempt in range(self.config.attempts):
            i = int(order[attempt % len(order)])
            box = arr[i]
            distance, theta = uniform(rng, self.config.distance_range), float(rng.uniform(-np.pi, np.pi))
            new_box = box.copy()
            new_box[:2] += distance * np.array([np.cos(theta), np.sin(theta)])
            here, there = _local_ground(pts, box), _local_ground(pts, new_box)
            new_box[2] += float(there.height(new_box[None, :2])[0] - here.height(box[None, :2])[0])
            if sample.roi is not None:
                on_road = bool(sample.roi.contains_xy(box[None, :2])[0])
                if (_on_roi(sample, new_box) if on_road else sample.roi.contains_xy(new_box[None, :2])[0]) != on_road:
                    continue
            own = _object_points(pts, box, here, sample.points, int(sample.boxes.track_ids[i]))
            if not self._free(sample, pts, i, new_box, there, own):
                continue
            offset = tuple(float(v) for v in new_box[:3] - box[:3])
            return ObjectTranslateParams(object=i, track_id=int(sample.boxes.track_ids[i]), offset=offset,  # type: ignore[arg-type]
                                         fill_ground=self.config.fill_ground, seed=seed)
        return none

    def _map(self, xyz: F64, box: F64, params: ObjectTranslateParams) -> tuple[F64, F64]:
        offset = np.asarray(params.offset, np.float64)
        new_box = box.copy()
        new_box[:3] += offset
        return xyz + offset, new_box

    def apply(self, sample: Scene, params: ObjectTranslateParams) -> Scene:
        return sample if params.is_identity() else self._moved(sample, params)


# -- rotation
class ObjectRotateConfig(ObjectChoiceConfig):
    angle_range: Range = Field((10.0, 10.0), description="rotation magnitude about the box's axis, degrees")
    both_directions: bool = Field(True, description="draw the sign too")
    fill_ground: bool = Field(True, description="re-cast the vacated rays onto the local ground")
    attempts: int = Field(20, ge=1, description="draws tried before giving up (identity)")


class ObjectRotateParams(ObjectMoveParams):
    angle: float = Field(description="degrees, counter-clockwise about the box's vertical axis")

    def is_identity(self) -> bool:
        return self.object < 0 or self.angle == 0


class ObjectRotate(_ObjectMove, Operator[Scene, ObjectRotateConfig, ObjectRotateParams]):
    """One object turned on the spot (a car at another heading): its points rotate about the
    box's vertical axis and the box's heading changes by the same angle. The turned footprint
    must be free (see ``object_translate``); occlusion is recomputed with the range-image
    z-buffer and the vacated rays are re-cast onto the ground. Other boxes, calibration and map
    stay; the turned box gets a re-projected alpha and 2D box, occlusion unknown."""

    name = "object_rotate"
    aliases = ("OBJ_ROTATE",)
    family = "object"
    relation = Relation.DEGRADING
    targets = POINTS_BOXES
    ConfigModel = ObjectRotateConfig
    ParamsModel = ObjectRotateParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"angle_range": (a, a)} for s, a in
                            [(1, 5.0), (2, 15.0), (3, 30.0), (4, 60.0), (5, 90.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectRotateParams:
        none = ObjectRotateParams(object=-1, track_id=-1, angle=0.0, fill_ground=self.config.fill_ground, seed=0)
        count = min(_draw_count(rng, self.config.count_range), 1)
        candidates = _choose_objects(rng, sample, self.config, len(sample.boxes) if count else 0)
        if not candidates:
            return none
        order = rng.permutation(candidates)
        pts, arr = _Pts(sample.points.xyz), sample.boxes.as_array()
        seed = draw_seed(rng)
        for attempt in range(self.config.attempts):
            i = int(order[attempt % len(order)])
            angle = uniform(rng, self.config.angle_range)
            if self.config.both_directions and rng.random() < 0.5:
                angle = -angle
            params = ObjectRotateParams(object=i, track_id=int(sample.boxes.track_ids[i]), angle=angle,
                                        fill_ground=self.config.fill_ground, seed=seed)
            ground = _local_ground(pts, arr[i])
            own = _object_points(pts, arr[i], ground, sample.points, int(sample.boxes.track_ids[i]))
            if self._free(sample, pts, i, self._map(np.zeros((0, 3)), arr[i], params)[1], ground, own):
                return params
        return none

    def _map(self, xyz: F64, box: F64, params: ObjectRotateParams) -> tuple[F64, F64]:
        angle = np.deg2rad(params.angle)
        new_box = box.copy()
        new_box[6] = float(wrap_angle(box[6] + angle))
        return (xyz - box[:3]) @ _rotation_z(angle).T + box[:3], new_box

    def apply(self, sample: Scene, params: ObjectRotateParams) -> Scene:
        return sample if params.is_identity() else self._moved(sample, params)


# -- scaling
class ObjectScaleConfig(ObjectChoiceConfig):
    factor_range: Range = Field((0.9, 1.1), description="scale factor about the box's bottom centre")
    fill_ground: bool = Field(True, description="re-cast the vacated rays onto the local ground")
    attempts: int = Field(20, ge=1, description="draws tried before giving up (identity)")


class ObjectScaleParams(ObjectMoveParams):
    factor: float = Field(gt=0)

    def is_identity(self) -> bool:
        return self.object < 0 or self.factor == 1.0


class ObjectScale(_ObjectMove, Operator[Scene, ObjectScaleConfig, ObjectScaleParams]):
    """One object of another size (a bigger car, a smaller child): its points scale about the
    box's bottom centre, so it stays on the ground, and the box's length, width and height scale
    by the same factor. A grown footprint must be free (see ``object_translate``); occlusion is
    recomputed with the range-image z-buffer. Other boxes, calibration and map stay; the scaled
    box gets a re-projected alpha and 2D box, occlusion unknown."""

    name = "object_scale"
    aliases = ("OBJ_SCALE",)
    family = "object"
    relation = Relation.DEGRADING
    targets = POINTS_BOXES
    ConfigModel = ObjectScaleConfig
    ParamsModel = ObjectScaleParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"factor_range": (1 - f, 1 + f)} for s, f in
                            [(1, 0.05), (2, 0.1), (3, 0.15), (4, 0.2), (5, 0.3)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectScaleParams:
        none = ObjectScaleParams(object=-1, track_id=-1, factor=1.0, fill_ground=self.config.fill_ground, seed=0)
        count = min(_draw_count(rng, self.config.count_range), 1)
        candidates = _choose_objects(rng, sample, self.config, len(sample.boxes) if count else 0)
        if not candidates:
            return none
        order = rng.permutation(candidates)
        pts, arr = _Pts(sample.points.xyz), sample.boxes.as_array()
        seed = draw_seed(rng)
        for attempt in range(self.config.attempts):
            i = int(order[attempt % len(order)])
            params = ObjectScaleParams(object=i, track_id=int(sample.boxes.track_ids[i]),
                                       factor=uniform(rng, self.config.factor_range),
                                       fill_ground=self.config.fill_ground, seed=seed)
            ground = _local_ground(pts, arr[i])
            own = _object_points(pts, arr[i], ground, sample.points, int(sample.boxes.track_ids[i]))
            if params.factor <= 1.0 or self._free(sample, pts, i, self._map(np.zeros((0, 3)), arr[i], params)[1],
                                                  ground, own):
                return params
        return none

    def _map(self, xyz: F64, box: F64, params: ObjectScaleParams) -> tuple[F64, F64]:
        bottom = box[:3] - np.array([0.0, 0.0, box[5] / 2])
        new_box = box.copy()
        new_box[3:6] *= params.factor
        new_box[2] = bottom[2] + new_box[5] / 2
        return bottom + (xyz - bottom) * params.factor, new_box

    def apply(self, sample: Scene, params: ObjectScaleParams) -> Scene:
        return sample if params.is_identity() else self._moved(sample, params)


# =========================================================================== object library
def _cache_dir() -> Path:
    return Path(os.environ.get("LIDARFUZZ_CACHE") or Path.home() / ".cache" / "lidarfuzz")


@dataclass(frozen=True)
class ObjectLibrary:
    """Labelled objects cut out of real or simulated frames, for insertion.

    Each entry holds its points in the box frame (centred, heading along +x), intensity
    normalised to [0, 1], with the class, box size, the source's range and observation angle
    (heading minus the azimuth of the centre: which side faced the sensor), the box bottom's
    height above the local ground, the source sensor's angular resolution and a source id
    ``frame_id:track_id``. Saved and loaded as one ``.npz``.

    Example:
        >>> library = ObjectLibrary.from_scenes(scenes)          # doctest: +SKIP
        >>> library.save("objects.npz"); ObjectLibrary.load("objects.npz")  # doctest: +SKIP
    """

    points: NDArray[np.float32]  # N×4: x, y, z in the box frame, intensity in [0, 1]
    offsets: NDArray[np.int64]  # M+1
    classes: NDArray[np.str_]
    sizes: F64  # M×3
    ranges: F64
    views: F64
    ground_offsets: F64
    angular_steps: F64  # M×2: elevation and azimuth step of the source sensor, radians
    sources: NDArray[np.str_]

    def __len__(self) -> int:
        return len(self.classes)

    def entry_points(self, i: int) -> NDArray[np.float32]:
        return self.points[self.offsets[i]:self.offsets[i + 1]]

    @property
    def counts(self) -> NDArray[np.int64]:
        return np.diff(self.offsets)

    @classmethod
    def from_scenes(cls, scenes: Sequence[Scene], min_points: int = 20) -> ObjectLibrary:
        """Every labelled object with at least ``min_points`` points above the ground band."""
        parts: list[NDArray[np.float32]] = []
        rows: list[tuple[str, F64, float, float, float, tuple[float, float], str]] = []
        for scene in scenes:
            cloud, arr = scene.points, scene.boxes.as_array()
            if len(cloud) == 0:
                continue
            scale = _intensity_scale(cloud)
            pts = _Pts(cloud.xyz)
            steps: tuple[float, float] | None = None
            for i in np.flatnonzero(scene.boxes.has_geometry):
                box = arr[i]
                ground = _local_ground(pts, box)
                own = _object_points(pts, box, ground, cloud, int(scene.boxes.track_ids[i]))
                if len(own) < min_points:
                    continue
                if steps is None:
                    ring = cloud.channel("ring") if cloud.has("ring") else None
                    wedge = _wedge_of(cloud.xyz, ring, np.arange(len(cloud)), 0.0)
                    steps = (wedge.elev_step, wedge.az_step)
                local = _to_box_frame(cloud.xyz[own], box)
                parts.append(np.column_stack([local, cloud.intensity[own] / scale]).astype(np.float32))
                azimuth = float(np.arctan2(box[1], box[0]))
                bottom = box[2] - box[5] / 2 - float(ground.height(box[None, :2])[0])
                rows.append((str(scene.boxes.labels[i]), box[3:6].copy(), float(np.hypot(box[0], box[1])),
                             float(wrap_angle(box[6] - azimuth)), bottom, steps,
                             f"{scene.frame_id}:{int(scene.boxes.track_ids[i])}"))
        counts = [len(p) for p in parts]
        return cls(
            points=np.concatenate(parts) if parts else np.zeros((0, 4), np.float32),
            offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            classes=np.array([r[0] for r in rows], dtype=np.str_),
            sizes=np.array([r[1] for r in rows], np.float64).reshape(-1, 3),
            ranges=np.array([r[2] for r in rows], np.float64),
            views=np.array([r[3] for r in rows], np.float64),
            ground_offsets=np.array([r[4] for r in rows], np.float64),
            angular_steps=np.array([r[5] for r in rows], np.float64).reshape(-1, 2),
            sources=np.array([r[6] for r in rows], dtype=np.str_),
        )

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the library (an ``.npz``; written to a temporary name, then renamed into place)."""
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        temporary = target.with_name(f".{target.name}.{os.getpid()}.tmp.npz")
        np.savez_compressed(temporary, **{f: getattr(self, f) for f in self.__dataclass_fields__})
        os.replace(temporary, target)
        return target

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> ObjectLibrary:
        try:
            with np.load(Path(path), allow_pickle=False) as data:
                return cls(**{f: data[f] for f in cls.__dataclass_fields__})
        except (OSError, KeyError, ValueError) as exc:
            raise ValueError(f"{path}: not an object library written by ObjectLibrary.save ({exc})") from exc

    @classmethod
    def default(cls) -> ObjectLibrary:
        """A small library built from four simulated HDL-64E frames at first use, cached as
        ``$LIDARFUZZ_CACHE/object_library_sim_v1.npz`` (default cache: ``~/.cache/lidarfuzz``)."""
        path = _cache_dir() / "object_library_sim_v1.npz"
        if path.exists():
            return _load_cached(str(path))
        from lidarfuzz.sim import GenerationConfig, render_frames

        library = cls.from_scenes(list(render_frames(GenerationConfig(frames=4, seed=11))))
        with contextlib.suppress(OSError):  # a read-only home: the library is rebuilt next time
            library.save(path)
        return library

    def fingerprint(self) -> str:
        return hashlib.sha1(self.sources.tobytes() + self.points.tobytes()).hexdigest()[:12]


_LIBRARIES: dict[str, ObjectLibrary] = {}


def _load_cached(path: str) -> ObjectLibrary:
    key = f"{path}:{os.stat(path).st_mtime_ns}"
    if key not in _LIBRARIES:
        _LIBRARIES[key] = ObjectLibrary.load(path)
    return _LIBRARIES[key]


# =========================================================================== insertion
class Insertion(BaseModel):
    """One inserted object: which library entry, where, at which heading, with which track id."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    entry: int = Field(ge=0)
    source: str = Field(description="the entry's source id, checked on replay")
    center: tuple[float, float, float]
    yaw: float = Field(description="radians, LiDAR frame")
    track_id: int


class ObjectInsertionConfig(Config):
    library: str | None = Field(None, description="path of an ObjectLibrary .npz; None: the cached simulator one")
    count_range: Range = Field((1, 1), description="objects inserted")
    classes: tuple[str, ...] | None = Field(None, description="only library entries of these classes")
    distance_ratio_range: Range = Field((0.8, 1.25), description="new range / the entry's source range")
    azimuth_range: Range = Field((-180.0, 180.0), description="azimuths of the new positions, degrees")
    attempts: int = Field(40, ge=1, description="positions tried per object before giving up")


class ObjectInsertionParams(Params):
    insertions: tuple[Insertion, ...]
    library: str = Field(description="fingerprint of the library the entries come from")

    def is_identity(self) -> bool:
        return not self.insertions


class ObjectInsertion(Operator[Scene, ObjectInsertionConfig, ObjectInsertionParams]):
    """Objects that were not there: entries of an :class:`ObjectLibrary` (cut out of labelled
    frames) placed on free ground. The new position is on the drivable area when the frame has
    an ROI map, at a range near the entry's source range (so its point density is plausible),
    with the heading that shows the sensor the same side as in the source; the box sits at the
    local ground height. Occlusion both ways with the range-image z-buffer: background points
    behind the object are removed, and so are the object's points behind nearer returns; of
    several object points in one beam and firing only the nearest is kept (a denser source is
    thinned to the frame's resolution). New points get the ring and time of their beam and
    azimuth, ``instance`` = a new track id and ``label`` = the class's semantic id when those
    channels exist; intensity is rescaled to the frame's scale. The box label is added with
    alpha and 2D box projected through the calibration, occlusion unknown. Existing points
    elsewhere, boxes, calibration and map stay.

    The library is the config's ``library`` path, or a small one built from simulated frames at
    first use and cached (see :meth:`ObjectLibrary.default`); a library can also be passed to
    the constructor (``ObjectInsertion(library=path)`` keeps ``spec()`` replayable)."""

    name = "object_insertion"
    aliases = ("OBJ_INSERT",)
    family = "object"
    relation = Relation.DEGRADING
    targets = POINTS_BOXES
    ConfigModel = ObjectInsertionConfig
    ParamsModel = ObjectInsertionParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": (c, c)} for s, c in [(1, 1), (2, 2), (3, 3), (4, 4), (5, 5)]}

    def __init__(self, config: ObjectInsertionConfig | None = None, *, objects: ObjectLibrary | None = None,
                 **fields: Any) -> None:
        super().__init__(config, **fields)
        self._library = objects
        self._in_memory = objects is not None

    @property
    def library(self) -> ObjectLibrary:
        if self._library is None:
            path = self.config.library
            self._library = _load_cached(path) if path is not None else ObjectLibrary.default()
        return self._library

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectInsertionParams:
        count = _draw_count(rng, self.config.count_range)
        if count == 0:
            return ObjectInsertionParams(insertions=(), library="")
        library = self.library
        entries = np.arange(len(library))
        if self.config.classes is not None:
            entries = entries[np.isin(library.classes, list(self.config.classes))]
        inserted: list[Insertion] = []
        if count and len(entries):
            boxes = sample.boxes
            ids = np.concatenate([boxes.track_ids, sample.points.channel("instance").astype(np.int64)
                                  if sample.points.has("instance") and len(sample.points) else []])
            next_id = int(ids.max(initial=-1)) + 1
            placed: list[F64] = []
            for _ in range(count):
                found = self._place(rng, sample, entries, placed, next_id)
                if found is not None:
                    inserted.append(found)
                    placed.append(self._box(found))
                    next_id += 1
        return ObjectInsertionParams(insertions=tuple(inserted), library=library.fingerprint())

    def _box(self, insertion: Insertion) -> F64:
        return np.array([*insertion.center, *self.library.sizes[insertion.entry], insertion.yaw])

    def _place(self, rng: np.random.Generator, sample: Scene, entries: NDArray[np.intp], placed: list[F64],
               track_id: int) -> Insertion | None:
        library, pts = self.library, _Pts(sample.points.xyz)
        others = Boxes3D.from_array(np.array(placed).reshape(-1, 7), ["Car"] * len(placed))
        occupied = Boxes3D.concat([sample.boxes, others])
        lo, hi = np.deg2rad(self.config.azimuth_range)
        for _ in range(self.config.attempts):
            entry = int(rng.choice(entries))
            distance = library.ranges[entry] * uniform(rng, self.config.distance_ratio_range)
            azimuth = uniform(rng, (float(lo), float(hi)))
            yaw = float(wrap_angle(library.views[entry] + azimuth))
            box = np.array([distance * np.cos(azimuth), distance * np.sin(azimuth), 0.0, *library.sizes[entry], yaw])
            if not _on_roi(sample, box) or not _footprint_free(occupied, box, skip=-1, margin=0.3):
                continue
            ground = _local_ground(pts, box, free=True)
            box[2] = float(ground.height(box[None, :2])[0]) + library.ground_offsets[entry] + box[5] / 2
            if _clutter(pts, box, ground, np.zeros(0, np.intp)) > 3:
                continue
            return Insertion(entry=entry, source=str(library.sources[entry]), center=tuple(float(v) for v in box[:3]),  # type: ignore[arg-type]
                             yaw=yaw, track_id=track_id)
        return None

    def apply(self, sample: Scene, params: ObjectInsertionParams) -> Scene:
        if params.is_identity():
            return sample
        library = self.library
        if params.library != library.fingerprint():
            raise ValueError(f"{self.name}: params were drawn from object library {params.library}, "
                             f"this operator has {library.fingerprint()} (configure the same library path)")
        cloud, boxes = sample.points, sample.boxes
        scale = _intensity_scale(cloud)
        channels = cloud.channels
        for ins in params.insertions:
            if not (0 <= ins.entry < len(library)) or library.sources[ins.entry] != ins.source:
                raise ValueError(f"{self.name}: library entry {ins.entry} is not {ins.source!r}")
            local = library.entry_points(ins.entry).astype(np.float64)
            new_xyz = local[:, :3] @ _rotation_z(ins.yaw).T + np.asarray(ins.center)
            steps = library.angular_steps[ins.entry]
            ratio = library.ranges[ins.entry] / max(float(np.hypot(*ins.center[:2])), 1e-3)
            occlusion = _occlude(cloud, _Pts(cloud.xyz), new_xyz, ratio, (float(steps[0]), float(steps[1])))
            data = np.zeros((len(new_xyz), len(channels)), np.float32)
            data[:, :3] = new_xyz
            data[:, 3] = local[:, 3] * scale
            if cloud.has("ring"):
                data[:, cloud.index("ring")] = occlusion.ring
            if cloud.has("time"):
                data[:, cloud.index("time")] = occlusion.time if occlusion.time is not None else 0.0
            if cloud.has("label"):
                semantic = OBJECT_SEMANTIC.get(str(library.classes[ins.entry]))
                data[:, cloud.index("label")] = SEMANTIC_ID.get(semantic, 0) if semantic else 0
            if cloud.has("instance"):
                data[:, cloud.index("instance")] = ins.track_id
            cloud = PointCloud(np.concatenate([_rows(cloud.data, occlusion.keep_background),
                                               _rows(data, occlusion.keep_new)]),
                               channels)
            added = Boxes3D.from_array(self._box(ins)[None], [str(library.classes[ins.entry])],
                                       track_ids=[ins.track_id], occlusion=[-1])
            added = relabel_in_image(added, sample.calib)
            if sample.calib is not None and np.isnan(added.truncation[0]):
                added = added.replace(truncation=[0.0])
            boxes = Boxes3D.concat([boxes, added])
        return sample.replace(points=cloud, boxes=boxes)

    def spec(self) -> dict[str, Any]:
        if self._in_memory and self.config.library is None:
            raise ValueError(f"{self.name}: an operator built from an in-memory library cannot be rebuilt from its "
                             "spec; save the library and pass its path as library=...")
        return super().spec()


__all__ = [
    "Insertion", "ObjectCutout", "ObjectDensityLoss", "ObjectInsertion", "ObjectJitter", "ObjectLibrary",
    "ObjectRemoval", "ObjectRotate", "ObjectScale", "ObjectTranslate",
]
