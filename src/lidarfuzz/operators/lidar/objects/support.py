"""Shared machinery of the object operators: object points, local ground, range-image occlusion,
ground infill, and the choice of objects."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pydantic import Field
from scipy import ndimage

from lidarfuzz.operators.base import Config, Params, Target
from lidarfuzz.operators.lidar.common import intensity_scale
from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.geometry import bev_corners, bev_intersection_area
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
