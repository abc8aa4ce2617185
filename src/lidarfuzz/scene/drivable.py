"""Where the road is when no map says so: the drivable region estimated from one LiDAR frame.

Zhou & Sun's MR1 (``outside_roi_scatter``) needs the frame's drivable area: Apollo's HD-map
ROI. Real data sets rarely ship one (KITTI has none), so this module estimates it from the scan
itself, in two stages, both vectorised numpy (loops run over rings and range bins, never over
points):

1. **Ground segmentation** (:func:`segment_ground`), in the spirit of Patchwork (Lim et al.,
   RA-L 2021): the plane around the sensor is cut into patches by a concentric zone model (rings
   that widen with range, sectors per ring); each patch gets a least-squares plane fitted to the
   lowest return of each of its polar cells (seeds: within ``seed_band`` of the patch's 10th
   percentile), refitted twice on the cells within ``ground_band`` of the plane. A patch whose
   plane is steeper than ``max_tilt_deg`` or stands more than ``max_rise`` (plus a grade of
   ``max_grade`` per metre) above its inner neighbour's — a car roof, a wall top, a hedge with no
   ground seen — takes its inner neighbour's plane instead. Every point's height above its
   patch's plane follows: within ``ground_band`` it is ground, above ``obstacle_height`` an
   obstacle. Planes per patch follow slopes, camber and crests that one plane (RANSAC) cannot.
2. **The road's extent** (:func:`road_extent`): a fine polar grid (``sector_deg`` × ``bin_m``)
   holds each cell's lowest ground return and its obstacle returns. Every sector is walked
   outward from the ego vehicle (the sensor's origin, which stands on the road; the road around
   it is the lowest surface of the first ground ring, so a sidewalk beside the car is not taken
   for it) while the ground continues at road level. The walk stops at a **height step** larger
   than ``kerb_step`` (plus ``slope_tolerance`` per metre) between a ground cell and the road
   cell at least ``step_baseline`` before it, net of the road's grade measured over the 3 m
   before that (a kerb up to a sidewalk, a drop to a verge), and at an unobserved gap longer
   than ``max_gap`` (or ``gap_per_m`` of the range). Obstacles do not end the road by
   themselves: the walk passes through an obstacle and its shadow and goes on if the ground
   behind continues at road level (a car in the lane, a pedestrian crossing); if the ground
   behind is not road, the road ends behind the obstacle, at most ``hidden_depth`` past its first
   return (a car parked at the kerb: its hidden far side), and if no ground shows within
   ``max_shadow`` it ends ``hidden_depth`` past its first return or at its last, whichever is
   farther (a wall). The walk is written as events on the sectors × bins arrays, so it runs
   without a loop. Per-sector extents are median-filtered over ``smooth_sectors`` sectors (a
   sector that leaked through a dropped kerb is cut back to its neighbours), and the
   star-shaped polygon they trace is the estimate (:func:`estimate_drivable`). When the frame is
   labelled, the footprints of the classes that stand on roads (:data:`ROAD_CLASSES`), grown by
   ``box_margin``, are added (not for a map a system under test sees: :func:`with_estimated_roi`).

The estimate is a pure function of the frame (no randomness; the points' order does not matter),
so an operator can recompute it when it replays a mutant. It takes about 15 ms for a 120k-point
HDL-64E frame on one core (``benchmarks/operators.py``). On a synthetic street (4 % grade, 2.5 %
camber, 0.15 m kerbs, parked cars) it covers 94 % of the road within 20 m and 3 % of the
sidewalks (``tests/operators/test_roi_estimate.py``).

Limits — what it does not know and what it gets wrong:

* It sees only what the sensor sees: road behind occluders, past the last ground returns, or
  out of a camera-cropped scan's field of view is not in the region.
* A kerb is found only where consecutive ground returns are close enough to show the step: with
  an HDL-64E up to about 30 m, with a VLP-16 about 12 m. Farther out, the region runs on over
  the sidewalk to the next obstacle (a fence, a wall): it then contains more than the road, never
  less of what is near.
* Lowered kerbs (driveways, ramps), grass verges level with the road and car parks are drivable
  to it; a road with no kerb and no height change at its edge has no edge it can see.
* It assumes the sensor rides on a vehicle on the road (the origin is on the road) and that z
  is up.

Example:
    >>> import numpy as np
    >>> from lidarfuzz.scene.points import PointCloud
    >>> from lidarfuzz.scene.scene import Scene
    >>> ring = np.linspace(-np.pi, np.pi, 2000, endpoint=False)
    >>> flat = np.concatenate([np.c_[r * np.cos(ring), r * np.sin(ring), np.full(2000, -1.7)]
    ...                        for r in np.arange(4.0, 20.0, 0.5)])
    >>> roi = estimate_drivable(Scene(PointCloud(np.c_[flat, np.zeros(len(flat))])))
    >>> roi.contains_xy([[10.0, 0.0], [30.0, 0.0]]).tolist()
    [True, False]
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import MultiPolygon, Polygon

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import bev_corners
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene

#: Labelled classes that stand on roads: their footprints join the estimated region.
ROAD_CLASSES = frozenset({"car", "van", "truck", "tram", "cyclist", "bus", "trailer", "motorcycle"})

#: ``scene.metadata["roi_source"]`` of a scene whose ``roi`` is this module's estimate ...
ESTIMATED = "estimated"
#: ... and what a scene's ``roi`` is taken for when it does not say: the frame's own map.
FRAME_MAP = "frame_map"


@dataclass(frozen=True)
class DrivableSettings:
    """Knobs of the estimate; the defaults suit automotive spinning LiDARs (VLP-16 to HDL-64E).

    Attributes:
        max_range: Points and region farther than this (metres, ground plane) are not used.
        min_range: Returns nearer than this are the ego vehicle's own body.
        ring_edges: Edges of the concentric rings of ground patches (metres).
        ring_sectors: Sectors per ring (one fewer entry than ``ring_edges``).
        seed_band: Seeds of a patch's plane: points within this of its 5th height percentile.
        ground_band: A point within this of its patch's plane is ground.
        obstacle_height: A point higher than this above its patch's plane is an obstacle.
        max_obstacle_height: Higher points (branches, bridges) block nothing.
        max_tilt_deg: A steeper patch plane is not ground (a wall, a car's side).
        max_rise: How far a patch's plane may stand above its inner neighbour's, plus
            ``max_grade`` per metre between them.
        max_grade: The steepest road grade expected (0.15 = 15 %).
        sector_deg: Angular width of the cells of the road walk.
        bin_m: Radial length of those cells.
        kerb_step: The smallest height step that ends the road (a kerb is 0.08–0.20 m).
        step_baseline: Steps are measured from a road cell at least this far back (metres).
        slope_tolerance: Added to ``kerb_step`` per metre between two observed ground cells:
            grade changes and noise over a gap.
        max_gap: The longest unobserved stretch the walk crosses near the sensor (metres) ...
        gap_per_m: ... and, farther out, this share of the range (rings spread with range).
        max_shadow: How far behind an obstacle's first return the walk looks for ground.
        hidden_depth: Where the road ends behind an obstacle (a car parked at the kerb), it
            ends this far behind the obstacle's first return (at most, when ground shows behind
            it): the obstacle's hidden far side (a car's length).
        first_ground: How far out the first ground return may be (the car's body hides the
            ground around it: a roof-mounted HDL-64E sees it from about 5 m).
        min_obstacle_points: Points that make a cell an obstacle (one stray return does not).
        ego_radius: The region always holds this disc: the ego vehicle stands on the road.
        smooth_sectors: Width of the median filter over the sectors' extents.
        box_margin: Labelled road users' footprints join the region grown by this.
    """

    max_range: float = 60.0
    min_range: float = 1.5
    ring_edges: tuple[float, ...] = (1.5, 4.0, 7.0, 10.0, 14.0, 19.0, 25.0, 32.0, 40.0, 50.0, 60.0)
    ring_sectors: tuple[int, ...] = (8, 16, 24, 32, 40, 48, 56, 56, 64, 64)
    seed_band: float = 0.4
    ground_band: float = 0.2
    obstacle_height: float = 0.3
    max_obstacle_height: float = 3.0
    max_tilt_deg: float = 20.0
    max_rise: float = 0.5
    max_grade: float = 0.15
    sector_deg: float = 1.0
    bin_m: float = 0.5
    kerb_step: float = 0.07
    step_baseline: float = 1.0
    slope_tolerance: float = 0.02
    max_gap: float = 3.0
    gap_per_m: float = 0.25
    max_shadow: float = 12.0
    hidden_depth: float = 4.5
    first_ground: float = 15.0
    min_obstacle_points: int = 2
    ego_radius: float = 2.5
    smooth_sectors: int = 5
    box_margin: float = 0.5

    def __post_init__(self) -> None:
        if len(self.ring_sectors) != len(self.ring_edges) - 1:
            raise ValueError("ring_sectors needs one entry per ring (len(ring_edges) - 1)")
        if list(self.ring_edges) != sorted(self.ring_edges) or self.ring_edges[-1] < self.max_range:
            raise ValueError("ring_edges must increase and reach max_range")


DEFAULT_SETTINGS = DrivableSettings()


# --------------------------------------------------------------------------- ground
@dataclass(frozen=True)
class GroundSegmentation:
    """Per-point heights above the local ground, the patch planes they come from, and the cells.

    Attributes:
        height: Signed height of every point above its patch's plane (NaN for points inside
            ``min_range`` or beyond ``max_range``).
        planes: P×3 plane of every patch as ``z = a·x + b·y + c`` (LiDAR frame).
        cell: The polar cell (sector × range bin of the road walk) of every point, −1 when unused.
        settings: The settings used.
    """

    height: NDArray[np.float64]
    planes: NDArray[np.float64]
    cell: NDArray[np.int64]
    settings: DrivableSettings

    @property
    def ground(self) -> NDArray[np.bool_]:
        return np.abs(self.height) <= self.settings.ground_band

    @property
    def obstacle(self) -> NDArray[np.bool_]:
        s = self.settings
        return (self.height > s.obstacle_height) & (self.height < s.max_obstacle_height)


@dataclass(frozen=True)
class _Grid:
    """The polar cells of the road walk and the patches of the ground planes, for one settings."""

    sectors: int
    bins: int
    theta: NDArray[np.float64]  # centre angle of each sector
    r: NDArray[np.float64]  # centre range of each bin
    cell_patch: NDArray[np.int64]  # patch of each cell (by its centre), -1 outside the rings
    cell_x: NDArray[np.float64]
    cell_y: NDArray[np.float64]
    patches: int
    patch_ring: NDArray[np.int64]
    patch_inner: NDArray[np.int64]  # the patch of the ring inside under the patch's centre, -1: none
    patch_x: NDArray[np.float64]  # centre of each patch
    patch_y: NDArray[np.float64]
    patch_r: NDArray[np.float64]


@lru_cache(maxsize=8)
def _grid(s: DrivableSettings) -> _Grid:
    sectors = max(1, round(360.0 / s.sector_deg))
    bins = int(np.ceil(s.max_range / s.bin_m))
    theta = -np.pi + (np.arange(sectors, dtype=np.float64) + 0.5) * (2 * np.pi / sectors)
    r = (np.arange(bins, dtype=np.float64) + 0.5) * s.bin_m
    edges = np.asarray(s.ring_edges, np.float64)
    counts = np.asarray(s.ring_sectors, np.int64)
    offset = np.r_[0, np.cumsum(counts)]

    def patch_of(radius: NDArray[np.float64], angle: NDArray[np.float64]) -> NDArray[np.int64]:
        ring = np.searchsorted(edges, radius, side="right") - 1
        inside = (ring >= 0) & (ring < len(counts))
        ring = np.clip(ring, 0, len(counts) - 1)
        n = counts[ring]
        sector = np.minimum(((angle + np.pi) * (n / (2 * np.pi))).astype(np.int64), n - 1)
        return np.where(inside, offset[ring] + sector, -1)

    cell_r, cell_theta = np.tile(r, sectors), np.repeat(theta, bins)
    patch_ring = np.repeat(np.arange(len(counts)), counts)
    patch_sector = np.arange(offset[-1]) - offset[patch_ring]
    patch_r = 0.5 * (edges[patch_ring] + edges[patch_ring + 1])
    patch_theta = -np.pi + (patch_sector + 0.5) * 2 * np.pi / counts[patch_ring]
    inner = patch_of(np.where(patch_ring > 0, 0.5 * (edges[patch_ring - 1] + edges[patch_ring]), -1.0), patch_theta)
    return _Grid(sectors, bins, theta, r, patch_of(cell_r, cell_theta), cell_r * np.cos(cell_theta),
                 cell_r * np.sin(cell_theta), int(offset[-1]), patch_ring, inner, patch_r * np.cos(patch_theta),
                 patch_r * np.sin(patch_theta), patch_r)


def _fit_planes(x: NDArray[np.float64], y: NDArray[np.float64], z: NDArray[np.float64], patch: NDArray[np.int64],
                count: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares plane ``z = a·x + b·y + c`` of each patch's points: (P×3 planes, P counts)."""
    def total(w: NDArray[np.float64] | None) -> NDArray[np.float64]:
        return np.bincount(patch, w, count).astype(np.float64, copy=False)  # counts too: exact in float64

    n = total(None)
    sx, sy, sz = total(x), total(y), total(z)
    sxx, sxy, syy, sxz, syz = total(x * x), total(x * y), total(y * y), total(x * z), total(y * z)
    normal = np.stack([np.stack([sxx, sxy, sx], -1), np.stack([sxy, syy, sy], -1), np.stack([sx, sy, n], -1)], 1)
    rhs = np.stack([sxz, syz, sz], -1)
    well_posed = n >= 3
    normal[~well_posed] = np.eye(3)
    normal += np.eye(3) * 1e-6  # a patch whose points lie on a line: the least tilted plane through them
    planes = np.linalg.solve(normal, rhs[..., None])[..., 0].astype(np.float64, copy=False)
    planes[~well_posed] = 0.0
    return planes, n


def segment_ground(xyz: NDArray[np.floating], settings: DrivableSettings = DEFAULT_SETTINGS) -> GroundSegmentation:
    """Heights above the local ground of every point, from patch-wise planes (see the module's docstring).

    The planes are fitted to the lowest return of every polar cell (``sector_deg`` × ``bin_m``)
    rather than to every point: the ground is the lower envelope of a scan, and 43k cells are
    cheaper to fit than 120k points. A point's height is taken above its cell's ground (the
    plane at the cell's centre): within a cell of 0.5 m by 1° the plane rises less than a
    centimetre on ordinary grades.

    Args:
        xyz: N×3 points in the sensor's frame (z up).
        settings: The knobs.

    Example:
        >>> xy = np.random.default_rng(0).uniform(-20, 20, (20000, 2))
        >>> road = np.c_[xy, 0.05 * xy[:, 0] - 1.7]  # a 5 % grade
        >>> seg = segment_ground(np.r_[road, [[8.0, 0.0, -0.9]]])
        >>> bool(seg.ground[:-1].mean() > 0.99), round(float(seg.height[-1]), 1)
        (True, 0.4)
    """
    s = settings
    grid = _grid(s)
    p = np.asarray(xyz, np.float32).reshape(-1, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    size = grid.sectors * grid.bins
    r = np.sqrt(x * x + y * y)
    used = (r >= s.min_range) & (r < s.max_range)
    sector = ((np.arctan2(y, x) + np.float32(np.pi)) * np.float32(grid.sectors / (2 * np.pi))).astype(np.int32)
    cell = np.minimum(sector, grid.sectors - 1) * grid.bins + (r * np.float32(1.0 / s.bin_m)).astype(np.int32)
    cell = np.where(used, cell, size)  # one spare cell for every unused point
    planes = np.zeros((grid.patches, 3))
    lowest = np.full(size + 1, np.inf, np.float32)
    np.minimum.at(lowest, cell, z)
    # the cells that saw anything, their patch and lowest return
    seen = np.flatnonzero(np.isfinite(lowest[:size]) & (grid.cell_patch >= 0))
    if len(seen) == 0:
        return GroundSegmentation(np.full(len(p), np.nan), planes, np.where(used, cell, -1), s)
    cz, cpatch = lowest[seen].astype(np.float64), grid.cell_patch[seen]
    cx, cy = grid.cell_x[seen], grid.cell_y[seen]
    # seeds: cells within seed_band of their patch's 10th percentile (a histogram of 0.1 m levels
    # above the lowest cell, the last level holding everything higher: no sort)
    floor = float(cz.min())
    levels = np.minimum(((cz - floor) / 0.1).astype(np.int32), 199)
    histogram = np.bincount(cpatch * 200 + levels, minlength=grid.patches * 200).reshape(grid.patches, 200)
    cumulative = np.cumsum(histogram, axis=1, dtype=np.int32)
    wanted = np.maximum(np.ceil(0.1 * cumulative[:, -1]), 1)
    low = floor + 0.1 * np.argmax(cumulative >= wanted[:, None], axis=1)
    support = cz <= low[cpatch] + 0.1 + s.seed_band
    for _ in range(3):
        fitted, n = _fit_planes(cx[support], cy[support], cz[support], cpatch[support], grid.patches)
        plane = fitted[cpatch]
        residual = cz - (plane[:, 0] * cx + plane[:, 1] * cy + plane[:, 2])
        support = np.abs(residual) <= s.ground_band
    # patches that are not ground: too steep, too little support, or standing on something
    ok = (n >= 3) & (np.hypot(fitted[:, 0], fitted[:, 1]) <= np.tan(np.deg2rad(s.max_tilt_deg)))

    def height_at(plane: NDArray[np.float64], patch: NDArray[np.int64]) -> NDArray[np.float64]:
        return plane[:, 0] * grid.patch_x[patch] + plane[:, 1] * grid.patch_y[patch] + plane[:, 2]

    first = np.flatnonzero(grid.patch_ring == 0)
    reference = first[ok[first]]
    level = float(np.median(height_at(fitted[reference], reference))) if len(reference) \
        else float(np.quantile(cz, 0.05))
    planes[:, 2] = level  # a patch with no ground of its own and nothing inside it: the sensor's ground level
    planes[reference] = fitted[reference]
    for ring in range(1, int(grid.patch_ring.max()) + 1):  # outward: each checked against its final inner one
        members = np.flatnonzero(grid.patch_ring == ring)
        inner = grid.patch_inner[members]
        rise = height_at(fitted[members], members) - height_at(planes[inner], members)
        gap = grid.patch_r[members] - grid.patch_r[inner]
        good = ok[members] & (rise <= s.max_rise + s.max_grade * gap)
        planes[members] = np.where(good[:, None], fitted[members], planes[inner])
    plane = planes[np.maximum(grid.cell_patch, 0)]
    cell_ground = np.empty(size + 1, np.float32)
    cell_ground[:size] = plane[:, 0] * grid.cell_x + plane[:, 1] * grid.cell_y + plane[:, 2]
    cell_ground[:size][grid.cell_patch < 0] = np.nan
    cell_ground[size] = np.nan
    return GroundSegmentation(z - cell_ground[cell], planes, np.where(used, cell, -1), s)


# --------------------------------------------------------------------------- the road's extent
def road_extent(xyz: NDArray[np.floating], settings: DrivableSettings = DEFAULT_SETTINGS,
                ground: GroundSegmentation | None = None) -> NDArray[np.float64]:
    """How far the road reaches along every sector (metres; sectors from −π, ``sector_deg`` wide).

    See the module's docstring for the walk; ``ground`` is reused when given.
    """
    s = settings
    grid = _grid(s)
    p = np.asarray(xyz, np.float32).reshape(-1, 3)
    seg = ground if ground is not None else segment_ground(p, s)
    size = grid.sectors * grid.bins
    cell = np.where(seg.cell >= 0, seg.cell, size)
    height = seg.height
    # a cell's ground height is its lowest ground return: where a kerb crosses a cell the road
    # still shows, so the rise appears whole in the first cell wholly beyond it
    with np.errstate(invalid="ignore"):
        ground_point = np.abs(height) <= s.ground_band
        obstacle_point = (height > s.obstacle_height) & (height < s.max_obstacle_height)
    lowest = np.full(size + 1, np.inf, np.float32)
    np.minimum.at(lowest, cell, np.where(ground_point, p[:, 2], np.float32(np.inf)))
    ground_z = lowest[:size].reshape(grid.sectors, grid.bins).astype(np.float64)
    obstacle_n = np.bincount(cell[obstacle_point], minlength=size + 1)[:size].reshape(grid.sectors, grid.bins)
    blocked = obstacle_n >= s.min_obstacle_points
    ground_cell = np.isfinite(ground_z) & ~blocked
    ego = _ego_level(grid.theta, grid.r, ground_cell, ground_z, s)
    end = _walk(ground_z, ground_cell, blocked, ego, grid, s)
    if s.smooth_sectors > 1:
        from scipy.ndimage import median_filter  # here: scipy.ndimage takes 0.3 s to import, and io imports this module

        end = median_filter(end, size=s.smooth_sectors, mode="wrap")
    return np.maximum(end, s.ego_radius)


def _walk(ground_z: NDArray[np.float64], ground: NDArray[np.bool_], blocked: NDArray[np.bool_],
          ego: NDArray[np.float64], grid: _Grid, s: DrivableSettings) -> NDArray[np.float64]:
    """Every sector walked outward at once (sectors × bins arrays, no loop): where its road ends.

    The walk of the module's docstring, written as events on the grid. Each ground cell is
    compared with its *anchor* — the last ground cell at least ``step_baseline`` before it —
    raised by the road's grade, measured between the anchor and the ground cell about 3 m before
    that (the ego plane's grade where there is none); a cell with no anchor yet is compared with
    the ego plane itself (so a kerb face and the sidewalk behind it, each half a step above the
    cell before, do not pass as road beside the car). The road ends at the first of: a ground
    cell off road level (half-way from its anchor; behind the obstacle when one stood in
    between, at most ``hidden_depth`` past its first return), an unobserved gap longer than
    allowed (just past the last ground cell), and an obstacle with no ground within
    ``max_shadow`` behind its first return (``hidden_depth`` past it, or at its last return).
    """
    n_sectors, n_bins = ground.shape
    bin_m = s.bin_m
    first_bin = int(s.min_range / bin_m)
    ground = ground.copy()
    ground[:, :first_bin] = False
    blocked = blocked.copy()
    blocked[:, :first_bin] = False
    index = np.arange(n_bins, dtype=np.int32)
    base = (np.arange(n_sectors, dtype=np.int32) * n_bins)[:, None]  # flat index of each sector's first cell

    def range_of(cell: NDArray[np.int32]) -> NDArray[np.float64]:
        return (cell.astype(np.float64) + 0.5) * bin_m

    def last_at_or_before(mask: NDArray[np.bool_]) -> NDArray[np.int32]:
        return np.maximum.accumulate(np.where(mask, index, np.int32(-1)), axis=1)

    def shifted(values: NDArray[np.int32], by: int) -> NDArray[np.int32]:
        out = np.full_like(values, -1)
        if by < n_bins:
            out[:, by:] = values[:, : n_bins - by]
        return out

    def take(values: NDArray[Any], cell: NDArray[np.int32]) -> NDArray[Any]:  # values[sector, cell], cell ≥ 0
        return values.ravel().take(base + np.maximum(cell, 0))

    r_cell = range_of(index)[None, :]
    last_ground = last_at_or_before(ground)
    previous = shifted(last_ground, 1)  # the last ground cell before this one
    anchor = shifted(last_ground, max(1, int(np.ceil(s.step_baseline / bin_m - 1e-9))))
    has_anchor = anchor >= 0
    behind = np.where(has_anchor, take(shifted(last_ground, max(1, round(3.0 / bin_m))), anchor), -1)
    known_z = np.where(ground, ground_z, 0.0)  # anchors are ground cells; the rest never counts
    z_anchor, z_behind = take(known_z, anchor), take(known_z, behind)
    r_anchor = range_of(anchor)
    ego_grade = ego[0] * np.cos(grid.theta) + ego[1] * np.sin(grid.theta)
    with np.errstate(divide="ignore", invalid="ignore"):
        grade = np.where(behind >= 0, (z_anchor - z_behind) / (r_anchor - range_of(behind)), ego_grade[:, None])
    np.clip(grade, -s.max_grade, s.max_grade, out=grade)
    span = r_cell - r_anchor
    plane_z = (ego[0] * grid.cell_x + ego[1] * grid.cell_y + ego[2]).reshape(n_sectors, n_bins)
    expected = np.where(has_anchor, z_anchor + grade * span, plane_z)
    tolerance = np.where(has_anchor, s.kerb_step + s.slope_tolerance * span, s.kerb_step)
    with np.errstate(invalid="ignore"):
        step = ground & ~(np.abs(ground_z - expected) <= tolerance)
    # obstacles since the previous ground cell
    blocked_count = np.cumsum(blocked, axis=1, dtype=np.int32)
    before = shifted(blocked_count, 1)
    before[:, 0] = 0
    passed = before > np.where(previous >= 0, take(blocked_count, previous), 0)
    run_start = blocked & ~passed  # the first obstacle since the last ground cell
    allowed = np.where(previous >= 0, np.maximum(s.max_gap, s.gap_per_m * r_cell), s.first_ground)
    gap = (ground | run_start) & ~passed & (r_cell - np.where(previous >= 0, range_of(previous), 0.0) > allowed)
    next_ground = np.minimum.accumulate(np.where(ground, index, np.int32(n_bins))[:, ::-1], axis=1)[:, ::-1]
    shadow_bins = int(s.max_shadow / bin_m)
    lost = run_start & (next_ground - index > shadow_bins)
    event = step | gap | lost

    # where each sector's road ends: at its first event, or past its last ground cell
    first = np.argmax(event, axis=1).astype(np.int32)[:, None]
    stopped = take(event, first)[:, 0]
    final = last_ground[:, -1]
    out = np.where(final >= 0, range_of(final) + bin_m / 2, 0.0)
    at_gap, at_step, passed_here = take(gap, first)[:, 0], take(step, first)[:, 0], take(passed, first)[:, 0]
    previous_here, anchor_here = take(previous, first)[:, 0], take(anchor, first)[:, 0]
    r_here = range_of(first[:, 0])
    hidden = range_of(take(last_at_or_before(run_start), first)[:, 0]) - bin_m / 2 + s.hidden_depth
    stop = np.minimum(np.minimum(take(next_ground, first)[:, 0] - 1, first[:, 0] + shadow_bins), n_bins - 1)
    last_return = range_of(take(last_at_or_before(blocked), stop[:, None])[:, 0]) + bin_m / 2
    r_previous = np.where(previous_here >= 0, range_of(previous_here), 0.0)
    ends = np.where(at_gap, r_previous + bin_m / 2,
                    np.where(at_step, np.where(passed_here, np.minimum(r_here - bin_m / 2, hidden),
                                               0.5 * (np.where(anchor_here >= 0, range_of(anchor_here), r_previous)
                                                      + r_here)),
                             np.maximum(last_return, hidden)))
    out[stopped] = ends[stopped]
    return np.clip(out, 0.0, s.max_range)


def _ego_level(theta: NDArray[np.float64], centre_r: NDArray[np.float64], observed: NDArray[np.bool_],
               ground_z: NDArray[np.float64], s: DrivableSettings) -> NDArray[np.float64]:
    """The plane ``z = a·x + b·y + c`` of the road under and around the ego vehicle.

    A plane (grade and camber) through the first ground cells of all sectors, fitted to the
    *lowest* surface among them — a sidewalk beside the car stands a kerb higher and is left
    out — so the walk starts at road level, not at kerb level. Three least-squares fits, each on
    the lower half of the cells by their residual from the last, find that surface whatever its
    grade (the road must hold about a quarter of the first ring: ahead and behind); a last fit
    takes every cell within ``kerb_step`` of it.
    """
    first = np.argmax(observed, axis=1)
    rows = np.arange(len(theta))
    has = observed[rows, first]
    if has.sum() < 8:
        return np.array([0.0, 0.0, float(np.median(ground_z[rows, first][has])) if has.any() else 0.0])
    r = centre_r[first]
    design = np.c_[r * np.cos(theta), r * np.sin(theta), np.ones(len(theta))]
    z = np.where(has, ground_z[rows, first], 0.0)
    keep = has
    for _ in range(3):
        coef, *_ = np.linalg.lstsq(design[keep], z[keep], rcond=None)
        residual = z - design @ coef
        keep = has & (residual <= np.median(residual[has]))
    coef, *_ = np.linalg.lstsq(design[keep], z[keep], rcond=None)
    near = has & (np.abs(z - design @ coef) <= s.kerb_step)
    if near.sum() >= 8:
        coef, *_ = np.linalg.lstsq(design[near], z[near], rcond=None)
    return np.asarray(coef, np.float64)


def estimate_drivable(scene: Scene, settings: DrivableSettings = DEFAULT_SETTINGS, *,
                      use_labels: bool = True) -> RoiMap:
    """The drivable region of a frame without a map, as a :class:`RoiMap` in the LiDAR frame.

    Args:
        scene: The frame (its points; its labelled boxes when ``use_labels``).
        settings: The knobs (see :class:`DrivableSettings`).
        use_labels: Add the grown footprints of labelled road users (:data:`ROAD_CLASSES`).

    Returns:
        One polygon (the star-shaped region the sectors trace) plus the footprints, merged.
    """
    s = settings
    xyz = scene.points.xyz if len(scene.points) else np.zeros((0, 3))
    extent = road_extent(xyz, s)
    n = len(extent)
    theta = -np.pi + (np.arange(n) + 0.5) * (2 * np.pi / n)
    ring = np.c_[extent * np.cos(theta), extent * np.sin(theta)]
    region = shapely.make_valid(Polygon(ring))
    parts = [region, *road_user_footprints(scene.boxes, s.box_margin)] if use_labels else [region]
    merged = shapely.union_all(parts) if len(parts) > 1 else region
    return RoiMap(_as_multipolygon(merged))


def road_user_footprints(boxes: Boxes3D, margin: float = DEFAULT_SETTINGS.box_margin) -> list[Polygon]:
    """Bird's-eye footprints of the labelled boxes of :data:`ROAD_CLASSES`, grown by ``margin``."""
    if len(boxes) == 0:
        return []
    road_users = boxes.has_geometry & np.isin(np.char.lower(boxes.labels.astype(str)), list(ROAD_CLASSES))
    if not road_users.any():
        return []
    footprints = shapely.polygons(bev_corners(boxes.as_array()[road_users]))
    return list(shapely.buffer(footprints, margin, quad_segs=2)) if margin > 0 else list(footprints)


def _as_multipolygon(geometry: Any) -> MultiPolygon:
    if isinstance(geometry, MultiPolygon):
        return geometry
    if isinstance(geometry, Polygon):
        return MultiPolygon([geometry]) if not geometry.is_empty else MultiPolygon()
    polygons = [g for g in getattr(geometry, "geoms", []) if isinstance(g, Polygon)]
    polygons += [p for g in getattr(geometry, "geoms", []) if isinstance(g, MultiPolygon) for p in g.geoms]
    return MultiPolygon(polygons)


def with_estimated_roi(scene: Scene, settings: DrivableSettings = DEFAULT_SETTINGS) -> Scene:
    """``scene`` with its ``roi`` set to the estimate (``metadata["roi_source"] = "estimated"``);
    a scene that already has a map is returned as it is.

    For data sets without a map, applied when frames are loaded: the system under test and every
    mutant of the frame then see the same region, as Apollo's ROI filter sees the same HD map.
    """
    if scene.roi is not None:
        return scene
    return scene.replace(roi=estimate_drivable(scene, settings, use_labels=False),
                         metadata={**scene.metadata, "roi_source": ESTIMATED})


__all__ = ["DEFAULT_SETTINGS", "ESTIMATED", "FRAME_MAP", "ROAD_CLASSES", "DrivableSettings", "GroundSegmentation",
           "estimate_drivable", "road_extent", "road_user_footprints", "segment_ground", "with_estimated_roi"]
