"""Point-level operators of the thesis (chapter 3.2) and of Zhou & Sun: noise, deletion, intensity.

Names follow the thesis's abbreviations as aliases (UNA, UPD, NNA, RRNA, RRPD, UIM, RIM).
None of them moves a labelled object, so labels are kept as they are.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar, Literal

import numpy as np
import shapely
from numpy.typing import NDArray
from pydantic import Field, model_validator

from lidarfuzz.operators.base import (
    Config,
    NonNegativeRange,
    Operator,
    Params,
    Relation,
    ShareRange,
    Target,
    draw_seed,
    uniform,
)
from lidarfuzz.operators.lidar.common import (
    COLUMN_BLOCK,
    cloud_extent,
    column_blocks,
    copy_with_maximum,
    declared_intensity_scale,
    scale_of_maximum,
    with_added_points,
)
from lidarfuzz.scene.drivable import ESTIMATED, FRAME_MAP, estimate_drivable, road_user_footprints
from lidarfuzz.scene.geometry import points_in_boxes
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

Range = tuple[float, float]
POINTS = frozenset({Target.POINTS})


def _z_extent(cloud: PointCloud) -> tuple[float, float]:
    """The lowest and highest z of a non-empty cloud — :func:`cloud_extent`'s z, without its four
    other (strided, unvectorised) reductions."""
    z = cloud.xyz[:, 2].copy()  # contiguous: two vectorised reductions after one strided pass, not two
    return float(z.min()), float(z.max())


def _planar_squares_and_extents(cloud: PointCloud) -> tuple[NDArray[np.float32], NDArray[np.float64]]:
    """For a non-empty cloud, in one pass (:func:`column_blocks`): ``x·x + y·y`` of every point
    (float32, in that order) and the lowest and highest z and intensity,
    ``[z_min, z_max, i_min, i_max]`` (a NaN anywhere in a column makes its two NaN, as the whole
    column's reductions do)."""
    squared = np.empty(len(cloud), np.float32)
    extents = []
    for rows, (x, y, z, intensity) in column_blocks(cloud.data, (0, 1, 2, 3)):
        out = np.multiply(x, x, out=squared[rows])
        out += np.multiply(y, y, out=y)
        extents.append((z.min(), z.max(), intensity.min(), intensity.max()))
    table = np.array(extents, np.float32)
    return squared, np.array([table[:, 0].min(), table[:, 1].max(), table[:, 2].min(), table[:, 3].max()],
                             np.float64)


def _farthest_in_plane(cloud: PointCloud, squared: NDArray[np.float32] | None = None) -> float:
    """``np.hypot(x, y).max()`` of a non-empty cloud, computing hypot on the candidates only;
    ``squared``: the points' float32 ``x·x + y·y`` when already computed.

    The float32 ``x² + y²`` (two roundings: within 2.4e-7 relative of the exact value) picks
    them: every point within 1e-5 (relative) of the largest. A point outside has an exact
    planar range more than 4e-6 (relative) below the farthest point's, and hypot is accurate to
    well within that (an ulp, 6e-8), so its hypot cannot reach the farthest point's: the
    candidates' maximum, by the same np.hypot, is the whole maximum, bit for bit. NaN or infinite
    coordinates (or squares that overflow) take the full computation, as before."""
    xyz = cloud.xyz
    x, y = xyz[:, 0], xyz[:, 1]
    if squared is None:
        with np.errstate(over="ignore", invalid="ignore"):  # overflow or NaN: handled below
            squared = x * x
            squared += y * y
    top = float(squared.max())
    if not np.isfinite(top):
        return float(np.hypot(x, y).max())
    candidates = np.flatnonzero(squared >= np.float32(top * (1.0 - 1e-5)))
    return float(np.hypot(x[candidates], y[candidates]).max())


#: Rows per block of :func:`_extent`'s pass (16384 × 32 bytes for an eight-channel frame: in the L2 cache).
EXTENT_BLOCK = 16384


def _extent(cloud: PointCloud) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`cloud_extent` in one pass over the rows: each block's x, y, z are copied into a
    small contiguous 3×block buffer (in the cache) and reduced there, where copying each strided
    column of the whole frame would read the whole N×C array three times (and reductions on the
    strided view are element by element). Minima of minima are the minima, NaN included."""
    data = cloud.data
    n = len(data)
    if n == 0:
        return cloud_extent(cloud)
    buffer = np.empty((3, min(EXTENT_BLOCK, n)), np.float32)
    blocks = -(-n // EXTENT_BLOCK)
    lows, highs = np.empty((3, blocks), np.float32), np.empty((3, blocks), np.float32)
    for j, start in enumerate(range(0, n, EXTENT_BLOCK)):
        rows = data[start:start + EXTENT_BLOCK]
        xyz = buffer[:, :len(rows)]
        np.copyto(xyz, rows[:, :3].T)
        np.minimum.reduce(xyz, axis=1, out=lows[:, j])
        np.maximum.reduce(xyz, axis=1, out=highs[:, j])
    return lows.min(axis=1).astype(np.float64), highs.max(axis=1).astype(np.float64)


def _in_column(xyz: NDArray[np.float32], center: tuple[float, float, float],
               size: tuple[float, float, float]) -> NDArray[np.bool_]:
    """:func:`in_axis_box`, the same comparisons in float32, made on the points that pass x only:
    a region is a small share of the cloud, so y and z are tested on the few that pass instead
    of all of them. Block by block (:data:`COLUMN_BLOCK` rows): reading x brings the block's rows
    into the cache, where the candidates' y and z are then gathered, each from its own column
    (indexing a one-dimensional strided column is ~3× faster than gathering N×3 rows)."""
    n = len(xyz)
    inside = np.empty(n, bool)
    cx, cy, cz = (np.float32(value) for value in center)
    hx, hy, hz = (np.float32(value / 2) for value in size)
    buffer = np.empty(min(COLUMN_BLOCK, n), np.float32)
    for start in range(0, n, COLUMN_BLOCK):
        rows = xyz[start:start + COLUMN_BLOCK]
        x = np.subtract(rows[:, 0], cx, out=buffer[:len(rows)])
        mask = np.less_equal(np.abs(x, out=x), hx, out=inside[start:start + len(rows)])
        candidates = np.flatnonzero(mask)
        passed = np.abs(rows[:, 1][candidates] - cy) <= hy
        passed &= np.abs(rows[:, 2][candidates] - cz) <= hz
        mask[candidates[~passed]] = False
    return inside


# --------------------------------------------------------------------------- UNA
Noise = Literal["uniform", "gaussian"]


class UniformNoiseConfig(Config):
    ratio_range: NonNegativeRange = Field((0.02, 0.02), description="noise points as a share of the cloud's points")
    jitter_range: NonNegativeRange = Field(
        (0.1, 0.1), description="offset from the copied point, metres: the half-width a "
                                                        "(uniform, each axis in [-a, a]) or the std (gaussian)")
    distribution: Noise = Field("uniform", description="uniform (the thesis's UNA) or gaussian (lidarfuzz before "
                                                       "issue 19)")


class UniformNoiseParams(Params):
    ratio: float = Field(ge=0)
    jitter: float = Field(ge=0)
    # params stored before the option had Gaussian offsets: they replay as they were drawn
    distribution: Noise = "gaussian"
    seed: int

    def is_identity(self) -> bool:
        return self.ratio == 0


class UniformNoiseAddition(Operator[Scene, UniformNoiseConfig, UniformNoiseParams]):
    """Spurious returns spread over the scene: copies of uniformly chosen points, each moved by a
    small random offset (the thesis's UNA). Adds points (intensity copied); leaves existing
    points, boxes and calibration alone.

    Thesis, section 3.2.2 (1): UNA adds "randomly, uniformly distributed noise": it takes a number
    of random points uniformly from the cloud as base points, copies each base point's data and
    modifies it slightly at random, and adds the copies. The offset is uniform by default
    (``distribution: uniform``: each axis in [-a, a] with a = ``jitter``, variance a²/3);
    ``distribution: gaussian`` keeps lidarfuzz's earlier Gaussian offset (std = ``jitter``)."""

    name = "uniform_noise_addition"
    aliases = ("UNA",)
    family = "noise"
    relation = Relation.INVARIANT
    harmless_up_to = 2
    harmless_because = "0.5-1 % of points duplicated within 10 cm of a real return; an object they crowd is not checked"
    targets = POINTS
    ConfigModel = UniformNoiseConfig
    ParamsModel = UniformNoiseParams
    IDENTITY: ClassVar = {"ratio_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"ratio_range": (r, r), "jitter_range": (j, j)} for s, r, j in
                            [(1, 0.005, 0.05), (2, 0.01, 0.1), (3, 0.02, 0.2), (4, 0.04, 0.3), (5, 0.08, 0.5)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> UniformNoiseParams:
        return UniformNoiseParams(ratio=uniform(rng, self.config.ratio_range),
                                  jitter=uniform(rng, self.config.jitter_range),
                                  distribution=self.config.distribution, seed=draw_seed(rng))

    def apply(self, sample: Scene, params: UniformNoiseParams) -> Scene:
        cloud = sample.points
        count = round(params.ratio * len(cloud))
        if count == 0 or len(cloud) == 0:
            return sample
        rng = np.random.default_rng(params.seed)
        base = rng.integers(0, len(cloud), count)
        if params.distribution == "uniform":
            offset = rng.uniform(-params.jitter, params.jitter, (count, 3))
        else:
            offset = rng.normal(0.0, params.jitter, (count, 3))
        xyz = cloud.xyz[base].astype(np.float64) + offset
        return sample.with_points(with_added_points(cloud, xyz, cloud.intensity[base]))


# --------------------------------------------------------------------------- UPD
class PointDeletionConfig(Config):
    ratio_range: ShareRange = Field((0.1, 0.1), description="share of points deleted")


class PointDeletionParams(Params):
    ratio: float = Field(ge=0, le=1)
    seed: int

    def is_identity(self) -> bool:
        return self.ratio == 0


class UniformPointDeletion(Operator[Scene, PointDeletionConfig, PointDeletionParams]):
    """Lost returns, uniformly at random over the cloud (the thesis's UPD): exactly
    round(ratio · N) points, drawn without replacement. Keeps boxes and calibration.

    Thesis, section 3.2.2 (2): UPD "randomly deletes a certain number of points" from the cloud;
    the number is ``ratio`` times the cloud's size, drawn per mutant from ``ratio_range``."""

    name = "uniform_point_deletion"
    aliases = ("UPD",)
    family = "deletion"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "5 % of points dropped at random leaves every object most of its points"
    targets = POINTS
    ConfigModel = PointDeletionConfig
    ParamsModel = PointDeletionParams
    IDENTITY: ClassVar = {"ratio_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"ratio_range": (r, r)} for s, r in
                            [(1, 0.05), (2, 0.1), (3, 0.2), (4, 0.35), (5, 0.5)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> PointDeletionParams:
        return PointDeletionParams(ratio=uniform(rng, self.config.ratio_range), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: PointDeletionParams) -> Scene:
        n = len(sample.points)
        count = round(params.ratio * n)
        if count == 0:
            return sample
        drop = np.random.default_rng(params.seed).choice(n, size=count, replace=False)
        keep = np.ones(n, bool)
        keep[drop] = False
        return sample.with_points(sample.points.select(keep))


# --------------------------------------------------------------------------- NNA
class NearNoiseConfig(Config):
    ratio_range: NonNegativeRange = Field((0.02, 0.02), description="noise points as a share of the cloud's points")
    spread_range: NonNegativeRange = Field(
        (8.0, 8.0), description="std of the half-normal distance from the sensor, metres")
    intensity_range: NonNegativeRange = Field((0.0, 0.1), description="intensity of the noise points (drawn per point)")


class NearNoiseParams(Params):
    ratio: float = Field(ge=0)
    spread: float = Field(gt=0)
    intensity_low: float
    intensity_high: float
    seed: int

    def is_identity(self) -> bool:
        return self.ratio == 0


class GaussianNoiseAddition(Operator[Scene, NearNoiseConfig, NearNoiseParams]):
    """Airborne clutter (snowflakes, haze, dust) whose density falls off with distance from the
    sensor: points at a half-normal distance in uniformly random directions, with low
    intensity (the thesis's NNA). Adds points only.

    Thesis, section 3.2.2 (3): NNA adds noise whose amount "falls off with distance from the car,
    so that the noise is Gaussian along the distance from the vehicle"; it draws the number of
    noise points at random and their x, y, z with a Gaussian generator. Here the distance from the
    sensor is half-normal with std ``spread`` and the direction uniform, which gives that fall-off;
    three choices the thesis does not make: 0.5 m is added to the distance (no return from inside
    the sensor's housing), no point lies below the cloud's lowest z (nothing under the ground),
    and the noise's intensity is drawn from ``intensity_range`` (the thesis does not say)."""

    name = "gaussian_noise_addition"
    aliases = ("NNA",)
    family = "noise"
    relation = Relation.INVARIANT
    harmless_up_to = 0
    harmless_because = ("airborne clutter around the sensor, like snow: even at 0.5 % of the cloud it fills the "
                        "gaps between nearby objects, which any clustering system may rightly join")
    targets = POINTS
    ConfigModel = NearNoiseConfig
    ParamsModel = NearNoiseParams
    IDENTITY: ClassVar = {"ratio_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"ratio_range": (r, r), "spread_range": (d, d)} for s, r, d in
                            [(1, 0.005, 5.0), (2, 0.01, 6.0), (3, 0.02, 8.0), (4, 0.04, 10.0), (5, 0.08, 12.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> NearNoiseParams:
        lo, hi = self.config.intensity_range
        return NearNoiseParams(ratio=uniform(rng, self.config.ratio_range),
                               spread=uniform(rng, self.config.spread_range), intensity_low=lo, intensity_high=hi,
                               seed=draw_seed(rng))

    def apply(self, sample: Scene, params: NearNoiseParams) -> Scene:
        cloud = sample.points
        count = round(params.ratio * len(cloud))
        if count == 0:
            return sample
        rng = np.random.default_rng(params.seed)
        distance = np.abs(rng.normal(0.0, params.spread, count)) + 0.5
        direction = rng.normal(size=(count, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        xyz = direction * distance[:, None]
        xyz[:, 2] = np.maximum(xyz[:, 2], _z_extent(cloud)[0] if len(cloud) else -1.0)  # nothing below the ground
        intensity = rng.uniform(params.intensity_low, params.intensity_high, count)
        return sample.with_points(with_added_points(cloud, xyz, intensity))


# --------------------------------------------------------------------------- regions
class RegionConfig(Config):
    size_range: NonNegativeRange = Field((4.0, 4.0), description="edge of the (cubic in x, y) region, metres")


def _draw_region(rng: np.random.Generator, sample: Scene, size: float) -> tuple[list[float], list[float]]:
    lo, hi = _extent(sample.points)
    centre = [float(rng.uniform(lo[i], hi[i])) for i in range(3)]
    return centre, [size, size, float(hi[2] - lo[2]) + 1.0]  # full height: a column of the scene


def _draw_region_on_points(rng: np.random.Generator, sample: Scene,
                           size: float) -> tuple[list[float], list[float]]:
    """A full-height column centred on a point drawn uniformly from the cloud.

    Operators that change the points already there (deletion, intensity) need a region where
    points are: a scan's bounding box is mostly empty (returns crowd near the sensor and on the
    ground), so a centre drawn uniformly in it leaves a 2 m column empty in most draws and the
    "mutant" equal to its source. Centring on a drawn point makes the region's chance
    proportional to its point count (a blind patch on the window hides a share of the returns,
    not of the bounding box) and never empty. The column spans the cloud's whole height (its
    centre at the extent's middle), so every point under the patch is in it.
    """
    if len(sample.points) == 0:  # nothing to centre on; apply leaves an empty cloud as it is
        lo, hi = cloud_extent(sample.points)
        x, y = float(rng.uniform(lo[0], hi[0])), float(rng.uniform(lo[1], hi[1]))
        z_low, z_high = float(lo[2]), float(hi[2])
    else:
        point = sample.points.xyz[int(rng.integers(0, len(sample.points)))]
        x, y = float(point[0]), float(point[1])
        z_low, z_high = _z_extent(sample.points)
    return [x, y, (z_low + z_high) / 2], [size, size, (z_high - z_low) + 1.0]


class RegionNoiseConfig(RegionConfig):
    count_range: NonNegativeRange = Field((100, 100), description="number of noise points")


class RegionNoiseParams(Params):
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    count: int = Field(ge=0)
    seed: int

    def is_identity(self) -> bool:
        return self.count == 0


class RandomRegionNoiseAddition(Operator[Scene, RegionNoiseConfig, RegionNoiseParams]):
    """A local burst of clutter (spray, a dust cloud, a reflection artefact): points uniformly
    inside one region drawn within the cloud's extent, intensity copied from random points
    (the thesis's RRNA). Adds points only.

    Thesis, section 3.2.2 (4): RRNA takes the extremes of each coordinate, draws a random region
    within them and adds randomly distributed noise points inside it. Here the region's centre is
    uniform in the cloud's extent, its x-y edge ``size`` and its height the cloud's whole height
    (a column; the thesis does not give the region's shape), and the points uniform in it."""

    name = "random_region_noise_addition"
    aliases = ("RRNA",)
    family = "noise"
    relation = Relation.INVARIANT
    harmless_up_to = 5
    harmless_because = "the noise lands in one region; an object it crowds is not checked"
    targets = POINTS
    ConfigModel = RegionNoiseConfig
    ParamsModel = RegionNoiseParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": (c, c), "size_range": (e, e)} for s, c, e in
                            [(1, 50, 2.0), (2, 100, 3.0), (3, 250, 4.0), (4, 500, 5.0), (5, 1000, 6.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> RegionNoiseParams:
        center, size = _draw_region(rng, sample, uniform(rng, self.config.size_range))
        lo, hi = self.config.count_range
        count = int(lo) if lo == hi else int(rng.integers(int(lo), int(hi) + 1))
        return RegionNoiseParams(center=tuple(center), size=tuple(size), count=count,  # type: ignore[arg-type]
                                 seed=draw_seed(rng))

    def apply(self, sample: Scene, params: RegionNoiseParams) -> Scene:
        if params.count == 0:
            return sample
        rng = np.random.default_rng(params.seed)
        center, size = np.asarray(params.center), np.asarray(params.size)
        lo, hi = _extent(sample.points)
        low = np.maximum(center - size / 2, lo)  # the region, clipped to the cloud's extent
        high = np.minimum(center + size / 2, hi)
        xyz = rng.uniform(low, high, (params.count, 3))
        source = sample.points.intensity
        intensity = source[rng.integers(0, len(source), params.count)] if len(source) else np.zeros(params.count)
        return sample.with_points(with_added_points(sample.points, xyz, intensity))


class RegionDeletionConfig(RegionConfig):
    share_range: ShareRange = Field((0.3, 0.9), description="share of the region's points deleted, drawn per mutant "
                                                       "(1: every point, lidarfuzz's RRPD before issue 19)")

    @model_validator(mode="after")
    def _share_is_a_probability(self) -> RegionDeletionConfig:
        if not 0.0 <= min(self.share_range) <= max(self.share_range) <= 1.0:
            raise ValueError(f"share_range: must lie in [0, 1], got {self.share_range}")
        return self


class RegionDeletionParams(Params):
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    # params stored before the share existed deleted the whole region: they replay as drawn
    share: float = Field(1.0, ge=0, le=1, description="chance that each point in the region is deleted")
    seed: int = 0

    def is_identity(self) -> bool:
        return min(self.size) == 0 or self.share == 0


class RandomRegionPointDeletion(Operator[Scene, RegionDeletionConfig, RegionDeletionParams]):
    """A patchy blind spot (a puddle or a dark, absorbing surface, dirt on the window): a random
    share of the points inside one full-height region centred on a randomly drawn point of the
    cloud is deleted (the thesis's RRPD; the region is never empty). Keeps boxes.

    Thesis, section 3.2.2 (5): RRPD takes the extremes of each coordinate, draws a random region
    within them, and then "randomly deletes points within the region". Here each point in the
    region is deleted independently with probability ``share`` (drawn per mutant from
    ``share_range``), so a region of N points loses Binomial(N, share) of them; ``share_range:
    (1, 1)`` deletes every point in it, as lidarfuzz did before. One deviation, on purpose: the
    region is centred on a point of the cloud rather than anywhere in its bounding box, which is
    mostly empty (see ``_draw_region_on_points``)."""

    name = "random_region_point_deletion"
    aliases = ("RRPD",)
    family = "deletion"
    relation = Relation.DEGRADING
    harmless_up_to = 5
    harmless_because = "points vanish from one region; an object left below half its evidence is not checked"
    targets = POINTS
    ConfigModel = RegionDeletionConfig
    ParamsModel = RegionDeletionParams
    IDENTITY: ClassVar = {"size_range": (0.0, 0.0)}
    # Larger regions and larger shares together: severity 5 clears nearly all of a 10 m column.
    SEVERITIES: ClassVar = {s: {"size_range": (e, e), "share_range": (lo, hi)} for s, e, lo, hi in
                            [(1, 2.0, 0.2, 0.4), (2, 4.0, 0.3, 0.5), (3, 6.0, 0.4, 0.7), (4, 8.0, 0.6, 0.9),
                             (5, 10.0, 0.8, 1.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> RegionDeletionParams:
        center, size = _draw_region_on_points(rng, sample, uniform(rng, self.config.size_range))
        if size[0] == 0:
            size = [0.0, 0.0, 0.0]
        return RegionDeletionParams(center=tuple(center), size=tuple(size),  # type: ignore[arg-type]
                                    share=uniform(rng, self.config.share_range), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: RegionDeletionParams) -> Scene:
        if params.is_identity() or len(sample.points) == 0:
            return sample
        inside = _in_column(sample.points.xyz, params.center, params.size)
        if params.share < 1.0:
            chosen = np.flatnonzero(inside)
            deleted = np.random.default_rng(params.seed).random(len(chosen)) < params.share
            inside = np.zeros(len(inside), bool)
            inside[chosen[deleted]] = True
        return sample.with_points(sample.points.select(~inside)) if inside.any() else sample


# --------------------------------------------------------------------------- intensity
class IntensityScaleConfig(Config):
    ratio_range: ShareRange = Field((0.2, 0.2), description="share of points rescaled")
    factor_range: NonNegativeRange = Field((0.5, 1.5), description="per-point factor, drawn uniformly")


class IntensityScaleParams(Params):
    ratio: float = Field(ge=0, le=1)
    factor_low: float = Field(ge=0)
    factor_high: float = Field(ge=0)
    seed: int

    def is_identity(self) -> bool:
        return self.ratio == 0 or self.factor_low == self.factor_high == 1.0


def _copy_with_limit(sample: Scene) -> tuple[NDArray[np.float32], float]:
    """A copy of the frame's points and the largest intensity a scaled one may take: the data's own
    scale (scene_intensity_scale: declared by its reader, else inferred, here from the maximum read
    as the data is copied): [0, 1] clouds stay in [0, 1], 8-bit ones in 0–255."""
    declared = declared_intensity_scale(sample)
    if declared is None:
        data, top = copy_with_maximum(sample.points.data, 3)
        return data, scale_of_maximum(top)
    return sample.points.data.copy(), declared


class IntensityScaling(Operator[Scene, IntensityScaleConfig, IntensityScaleParams]):
    """Reflectivity errors on scattered returns (wet or dirty surfaces, receiver gain jitter):
    a random share of the points get their intensity multiplied by a random factor each
    (the thesis's UIM), clipped to the data's own scale ([0, 1], 0–255 or 0–65535; declared, else inferred).
    Positions are untouched.

    Thesis, section 3.2.4 (1): UIM draws the number of points to modify, picks them at random, and
    "enhances or attenuates" each one's intensity by a random ratio of its own value; here the
    ratio is uniform in ``factor_range`` (spanning 1 at every severity) per point."""

    name = "intensity_scaling"
    aliases = ("UIM",)
    family = "intensity"
    relation = Relation.INVARIANT
    harmless_up_to = 2
    harmless_because = "up to a fifth of the returns 35 % brighter or darker keeps the geometry and most reflectances"
    targets = POINTS
    ConfigModel = IntensityScaleConfig
    ParamsModel = IntensityScaleParams
    IDENTITY: ClassVar = {"ratio_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"ratio_range": (r, r), "factor_range": (1 - f, 1 + f)} for s, r, f in
                            [(1, 0.1, 0.2), (2, 0.2, 0.35), (3, 0.3, 0.5), (4, 0.5, 0.7), (5, 0.8, 0.9)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> IntensityScaleParams:
        lo, hi = self.config.factor_range
        return IntensityScaleParams(ratio=uniform(rng, self.config.ratio_range), factor_low=lo, factor_high=hi,
                                    seed=draw_seed(rng))

    def apply(self, sample: Scene, params: IntensityScaleParams) -> Scene:
        cloud = sample.points
        count = round(params.ratio * len(cloud))
        if count == 0 or params.is_identity():
            return sample
        rng = np.random.default_rng(params.seed)
        chosen = rng.choice(len(cloud), size=count, replace=False)
        data, limit = _copy_with_limit(sample)
        # float64 for the chosen points only: the others would round-trip float32 → float64 exactly
        # the chosen intensities as flat positions: take/put on the flat array gather and scatter
        # them ~2× faster than data[chosen, 3] (no 2-D fancy-index machinery); same values
        flat, where = data.reshape(-1), chosen * data.shape[1] + 3
        scaled = flat.take(where).astype(np.float64)
        scaled *= rng.uniform(params.factor_low, params.factor_high, count)
        flat.put(where, np.clip(scaled, 0.0, limit, out=scaled))  # rounded to float32 as written
        return sample.with_points(PointCloud(data, cloud.channels))


Direction = Literal["both", "lower", "raise"]


class RegionIntensityConfig(RegionConfig):
    factor_range: NonNegativeRange = Field((0.5, 0.5), description="one factor f for every point in the region: lower "
                                                        "multiplies by min(f, 1/f), raise by max(f, 1/f)")
    direction: Direction = Field("both", description="both (lower or raise, even odds: the thesis's RIM), lower "
                                                     "(lidarfuzz before issue 19) or raise")

    @model_validator(mode="after")
    def _factor_positive(self) -> RegionIntensityConfig:
        low = min(self.factor_range)
        if low < 0 or (low == 0 and self.direction != "lower"):
            raise ValueError(f"factor_range: must be above 0 (0 only with direction lower: 1/f is the raising "
                             f"factor), got {self.factor_range}")
        return self


class RegionIntensityParams(Params):
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    factor: float = Field(ge=0)

    def is_identity(self) -> bool:
        return self.factor == 1.0 or min(self.size) == 0


class RegionIntensityScaling(Operator[Scene, RegionIntensityConfig, RegionIntensityParams]):
    """A region whose reflectivity changes as one (a puddle, a dirty patch of the window, spray
    from a street sprinkler): every point inside one full-height region centred on a randomly
    drawn point of the cloud has its intensity multiplied by a common factor (the thesis's RIM),
    clipped to the data's scale. Positions are untouched.

    Thesis, section 3.2.4 (2): RIM picks a random region (as RRNA or RRPD do), draws "a ratio of
    change of the intensity" with a random number generator and changes the intensity of every
    point in the region by that one ratio; section 3.2.4 (1) says the intensity modifications
    "enhance or attenuate" it. So with ``direction: both`` (the default) the drawn factor f lowers
    (by min(f, 1/f)) or raises (by max(f, 1/f)) with even odds, a raised value clipped at the
    data's full scale; ``direction: lower`` is lidarfuzz's earlier RIM, ``raise`` only raises."""

    name = "region_intensity_scaling"
    aliases = ("RIM",)
    family = "intensity"
    relation = Relation.INVARIANT
    harmless_up_to = 2
    harmless_because = "one region up to 40 % darker or 67 % brighter keeps its geometry"
    targets = POINTS
    ConfigModel = RegionIntensityConfig
    ParamsModel = RegionIntensityParams
    IDENTITY: ClassVar = {"factor_range": (1.0, 1.0)}
    SEVERITIES: ClassVar = {s: {"factor_range": (f, f), "size_range": (e, e)} for s, f, e in
                            [(1, 0.8, 4.0), (2, 0.6, 6.0), (3, 0.4, 8.0), (4, 0.2, 10.0), (5, 0.05, 12.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> RegionIntensityParams:
        center, size = _draw_region_on_points(rng, sample, uniform(rng, self.config.size_range))
        drawn = uniform(rng, self.config.factor_range)
        direction = self.config.direction
        if direction == "both":
            direction = "raise" if rng.random() < 0.5 else "lower"
        factor = drawn if drawn == 0 else (max if direction == "raise" else min)(drawn, 1.0 / drawn)
        return RegionIntensityParams(center=tuple(center), size=tuple(size),  # type: ignore[arg-type]
                                     factor=factor)

    def apply(self, sample: Scene, params: RegionIntensityParams) -> Scene:
        cloud = sample.points
        if params.is_identity() or len(cloud) == 0:
            return sample
        inside = _in_column(cloud.xyz, params.center, params.size)
        if not inside.any():
            return sample
        data, limit = _copy_with_limit(sample)
        # float64 for the region's points only: the others would round-trip float32 → float64 exactly;
        # their intensities as flat positions (take/put: no 2-D fancy-index machinery), as IntensityScaling
        flat, where = data.reshape(-1), np.flatnonzero(inside) * data.shape[1] + 3
        scaled = flat.take(where).astype(np.float64)
        scaled *= params.factor
        flat.put(where, np.clip(scaled, 0.0, limit, out=scaled))  # rounded to float32 as written
        return sample.with_points(PointCloud(data, cloud.channels))


# --------------------------------------------------------------------------- Zhou & Sun
Region = Literal["auto", "map", "estimated", "boxes"]


class OutsideRoiScatterConfig(Config):
    count_range: NonNegativeRange = Field((100, 100), description="scattered points (the paper uses 10, 100, 1000)")
    range_m: float | None = Field(None, gt=0, description="sensor range; default: the cloud's farthest point")
    region: Region = Field("auto", description="auto (the frame's map, else the estimate), map (required), "
                                               "estimated, or boxes (the fallback before the estimate)")
    margin_m: float = Field(3.0, ge=0, description="metres kept from the region's edge (a map's or an estimate's)")


class OutsideRoiScatterParams(Params):
    count: int = Field(ge=0)
    radius: float = Field(gt=0)
    z_low: float
    z_high: float
    intensity_low: float
    intensity_high: float
    region: str = Field(description="the region used: frame_map or dataset_map (the frame's map, by where it came "
                                    "from; 'roi' in older params), estimated, or boxes")
    margin: float = Field(0.0, ge=0, description="distance kept from the region's edge (metres)")
    seed: int

    def is_identity(self) -> bool:
        return self.count == 0


class OutsideRoiScatter(Operator[Scene, OutsideRoiScatterConfig, OutsideRoiScatterParams]):
    """Zhou & Sun's metamorphic test of Baidu Apollo: n random points in the 3D space outside
    the drivable-area ROI, within sensor range, with z and intensity drawn uniformly between
    the frame's own minimum and maximum. Points outside the ROI must not change what a
    correct perception module finds inside it. Adds points only.

    The region (``region: auto``) is the frame's map when it has one (``scene.roi``; the params
    say where it came from: ``frame_map``, or ``dataset_map`` for a map given with the data
    set), else the drivable region estimated from the frame itself
    (:func:`lidarfuzz.scene.drivable.estimate_drivable`: ground segmentation and the road's
    extent between kerbs and obstacles) with the labelled road users' footprints, grown by
    ``margin_m``; the params say ``estimated``. The estimate is a pure function of the frame, so
    replay recomputes it. ``region: boxes`` keeps the old fallback (outside every ground-truth box
    grown by 1 m — the road included, so MR1 is "violated" on most real frames); params stored
    as ``roi`` (a map) or ``boxes`` by older campaigns replay as they were drawn.

    MR1 presumes that the system under test drops what lies outside the ROI — Apollo's HD-map
    ROI filter does, and Zhou & Sun scattered outside "the ROI of t" that the system itself had
    identified. So the points must fall where the system does not look. Two consequences for a
    data set without a map:

    * Give the system the estimate as its map, for the original and the mutant alike: load the
      frames with :func:`~lidarfuzz.scene.drivable.with_estimated_roi` (the params then say
      ``estimated`` too, and the same region is used). A system with no map looks at every point,
      and then even a few points far off the road change its input: on real KITTI frames the
      built-in ``classic`` pipeline violates MR1 on about half of the mutants at n = 10 whatever
      the region (boxes or estimate alike; a quarter on simulator frames), because its RANSAC
      ground plane is drawn from its whole input and shifts by millimetres when points are added,
      which flips far objects near its height threshold.
    * ``margin_m`` (3 m) keeps the points off the estimate's uncertain edge (a kerb found half a
      metre out, a car parked half on the sidewalk) and out of the band that ROI filters keep
      around a map (the ``classic`` pipeline keeps 3 m). With both, the correct ``classic``
      pipeline violates MR1 on 0 % of mutants at n = 10 and 100 and on 0–7 % at n = 1000 (real KITTI
      frames, and simulator frames with real intensity statistics: ``benchmarks/mr1_without_map.py``).

    The margin applies to a map as well: ROI filters keep a band around their map (the ``classic``
    pipeline 3 m; Apollo's HD-map ROI filter extends its polygons too), and a point in that band is
    inside the region the system looks at — not MR1's premise. Without it, the correct ``classic``
    pipeline lost an object to 540 points scattered into its band at n = 10,000 (the campaign test
    on simulator frames). Set ``margin_m: 0`` for the paper's literal "outside the map"."""

    name = "outside_roi_scatter"
    aliases = ("ROI_SCATTER",)
    family = "noise"
    relation = Relation.INVARIANT
    harmless_up_to = 5
    harmless_because = ("points off the drivable area are what an HD-map ROI filter exists to ignore; an object they "
                        "crowd is not checked")
    targets = POINTS
    ConfigModel = OutsideRoiScatterConfig
    ParamsModel = OutsideRoiScatterParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": (c, c)} for s, c in
                            [(1, 10), (2, 100), (3, 1000), (4, 3000), (5, 10000)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> OutsideRoiScatterParams:
        cloud = sample.points
        if len(cloud):
            with np.errstate(over="ignore", invalid="ignore"):  # squares that overflow: see _farthest_in_plane
                squared, extents = _planar_squares_and_extents(cloud)
            z_low, z_high, i_lo, i_hi = (float(value) for value in extents)
            radius = self.config.range_m or _farthest_in_plane(cloud, squared)
        else:
            lo, hi = cloud_extent(cloud)
            z_low, z_high = float(lo[2]), float(hi[2])
            radius, i_lo, i_hi = self.config.range_m or 100.0, 0.0, 1.0
        c_lo, c_hi = self.config.count_range
        count = int(c_lo) if c_lo == c_hi else int(rng.integers(int(c_lo), int(c_hi) + 1))
        region = self._region(sample)
        margin = 0.0 if region == "boxes" else self.config.margin_m
        return OutsideRoiScatterParams(count=count, radius=max(radius, 1e-3), z_low=z_low, z_high=z_high,
                                       intensity_low=i_lo, intensity_high=i_hi, region=region, margin=margin,
                                       seed=draw_seed(rng))

    def _region(self, sample: Scene) -> str:
        chosen = self.config.region
        if chosen in ("estimated", "boxes"):
            return chosen
        if sample.roi is not None:
            return str(sample.metadata.get("roi_source") or FRAME_MAP)
        if chosen == "map":
            raise ValueError(f"outside_roi_scatter: region 'map' needs a frame with an ROI map; frame "
                             f"{sample.frame_id or '(unnamed)'} has none (use region 'auto' or 'estimated')")
        return ESTIMATED

    def apply(self, sample: Scene, params: OutsideRoiScatterParams) -> Scene:
        if params.count == 0:
            return sample
        outside = self._outside_test(sample, params)
        rng = np.random.default_rng(params.seed)
        chosen: list[np.ndarray] = []
        needed = params.count
        for _ in range(100):  # rejection sampling; the ROI rarely covers most of the disc
            batch = max(2 * needed, 64)
            r = params.radius * np.sqrt(rng.random(batch))  # uniform over the disc's area
            theta = rng.uniform(-np.pi, np.pi, batch)
            xy = np.column_stack([r * np.cos(theta), r * np.sin(theta)])
            ok = outside(xy)
            chosen.append(xy[ok][:needed])
            needed -= int(min(ok.sum(), needed))
            if needed == 0:
                break
        xy = np.concatenate(chosen)
        n = len(xy)
        z = rng.uniform(params.z_low, params.z_high, n)
        intensity = rng.uniform(params.intensity_low, params.intensity_high, n)
        return sample.with_points(with_added_points(sample.points, np.column_stack([xy, z]), intensity))

    @staticmethod
    def _outside_test(sample: Scene, params: OutsideRoiScatterParams) -> Callable[[np.ndarray], np.ndarray]:
        """The test "outside the region" of ``params.region`` on this frame."""
        if params.region == "boxes":
            return lambda xy: OutsideRoiScatter._outside_boxes(sample, xy)
        if params.region == ESTIMATED:
            # the estimate the frame was loaded with, or the same computed here; the labelled road
            # users join it here, not in a map a system under test may see
            roi = sample.roi if sample.roi is not None and sample.metadata.get("roi_source") == ESTIMATED \
                else estimate_drivable(sample, use_labels=False)
            area = shapely.union_all([roi.geometry, *road_user_footprints(sample.boxes)])
        elif sample.roi is None:
            raise ValueError(f"outside_roi_scatter: params were drawn for a frame with an ROI map "
                             f"({params.region}); this one has none")
        else:
            area = sample.roi.geometry
        if params.margin > 0:
            area = area.buffer(params.margin, quad_segs=4)
        shapely.prepare(area)
        return lambda xy: ~np.asarray(shapely.intersects_xy(area, xy[:, 0], xy[:, 1]), dtype=bool)

    @staticmethod
    def _outside_boxes(sample: Scene, xy: np.ndarray) -> np.ndarray:
        boxes = sample.boxes.select(sample.boxes.has_geometry)
        if len(boxes) == 0:
            return np.ones(len(xy), bool)
        grown = boxes.as_array().copy()
        grown[:, 2] = 0.0
        grown[:, 5] = 1e6  # any height: the test is in the ground plane
        points = np.column_stack([xy, np.zeros(len(xy))])
        inside = np.asarray(points_in_boxes(points, grown, margin=1.0).any(axis=1), dtype=bool)
        return ~inside


__all__ = [
    "GaussianNoiseAddition", "IntensityScaling", "OutsideRoiScatter", "RandomRegionNoiseAddition",
    "RandomRegionPointDeletion", "RegionIntensityScaling", "UniformNoiseAddition", "UniformPointDeletion",
]
