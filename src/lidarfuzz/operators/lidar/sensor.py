"""Sensor faults: what goes wrong in the LiDAR itself rather than in the world it measures.

Lost or fewer beams, interference from another LiDAR, a blocked window, ego motion during
the sweep, a wrong extrinsic calibration, a weaker receiver, a coarse or saturating
intensity channel, and position noise. Every operator here changes the points only; the
ground-truth boxes, the map and the calibration describe the world, which has not
changed, so each one supports the *degrading* relation (accuracy may drop, only a bound
applies). Small jitter is expected to leave a correct detector's output unchanged, but
large noise may not, so the jitters are degrading too.

Severity tables follow 3D_Corruptions_AD (Dong et al., CVPR 2023) and Robo3D (Kong et al.,
ICCV 2023) where those define the corruption; the values and their origin are listed in
each class's docstring. Where the public tools have a defect (beams drawn with replacement,
noise added to the intensity column, the FOV measured from the y axis) these operators
do it the physical way, and the tests pin it.

Conventions: the LiDAR frame has x forward, y left, z up; azimuth = atan2(y, x), 0 straight
ahead, positive to the left. The head spins clockwise seen from above, starting behind
the car at 10 Hz, so a point's firing time relative to the frame timestamp is
``(((π − azimuth) mod 2π) / 2π − ½) / rotation_hz`` — 0 straight ahead, as in
:meth:`lidarfuzz.sim.sensor.LidarSensor.time_of_azimuth`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import (
    AtLeastOneRange,
    Config,
    NonNegativeRange,
    Operator,
    Params,
    Relation,
    ShareRange,
    Target,
    TurnRange,
    draw_seed,
    uniform,
)
from lidarfuzz.operators.lidar.common import (
    declared_intensity_scale,
    mod_period,
    scale_of_maximum,
    scene_intensity_scale,
)
from lidarfuzz.operators.lidar.geometric import transformed_points
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

Range = tuple[float, float]
POINTS = frozenset({Target.POINTS})

#: Elevation histogram resolution and smoothing width for the ring estimate (degrees).
RING_BIN_DEG = 0.01
RING_SMOOTH_DEG = 0.05
#: The closest two beams may be (below the finest common spacing: Pandar128's 0.125°).
RING_MIN_SPACING_DEG = 0.12


# --------------------------------------------------------------------------- helpers
#: Rows per block of the in-cache work of motion distortion and jitter (8192 × 32 bytes for an
#: eight-channel frame).
MOTION_BLOCK = 8192


def estimate_rings(xyz: NDArray[np.floating], bin_deg: float = RING_BIN_DEG,
                   smooth_deg: float = RING_SMOOTH_DEG,
                   min_spacing_deg: float = RING_MIN_SPACING_DEG) -> NDArray[np.int64]:
    """Ring index of each point from its elevation angle (0 = lowest beam), for clouds without ``ring``.

    Method (histogram peaks): a spinning LiDAR fires each laser at one fixed elevation, so
    the elevation histogram of a frame has one peak per laser. Elevations are binned at
    ``bin_deg`` (0.01°) and smoothed with a ``smooth_deg`` (0.05°) box filter. A peak is a
    ring when it is at least ``min_spacing_deg`` (0.12°) from any higher peak, its
    prominence is at least half its height, and its height at least 5 % of the median
    peak's (so sampling ripples on one beam's spread and stray returns in the tails are
    not rings). Each point goes to the ring whose peak is nearest in elevation (boundaries
    half-way between peaks). Unlike splitting the sorted elevations at empty gaps, this
    survives beams whose elevation spreads overlap at the tails: on the simulator's
    HDL-64E, HDL-32E, OS1-64 and VLP-16 frames with 0.05° of Gaussian elevation noise
    added, ≥ 99.9 % of points get their true ring (the HDL-64E's beams are 0.33° apart).
    Rings that saw nothing in the frame are not counted, so numbering may differ from the
    sensor's when whole beams are empty. It does not use the point order (KITTI-style
    "azimuth wrap" estimates break on shuffled or cropped clouds).
    """
    n = len(xyz)
    if n == 0:
        return np.zeros(0, np.int64)
    p = np.asarray(xyz, np.float32)
    elevation = np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))  # radians, float32: fast and fine enough
    low = float(np.degrees(elevation.min())) - smooth_deg  # room for the filter at both ends
    # Non-negative, so truncation is floor.
    bins = ((elevation - np.float32(np.radians(low))) * np.float32(1.0 / np.radians(bin_deg))).astype(np.intp)
    width = max(1, round(smooth_deg / bin_deg))
    counts = np.bincount(bins, minlength=int(bins.max()) + width + 1).astype(np.float64)
    smooth = np.convolve(counts, np.ones(width) / width, mode="same")
    # here: scipy.signal takes about 1 s to import, and every operator listing imports this module
    from scipy.signal import find_peaks, peak_prominences

    peaks, _ = find_peaks(np.concatenate([[0.0], smooth, [0.0]]), distance=max(1, round(min_spacing_deg / bin_deg)))
    peaks -= 1
    if len(peaks) == 0:
        return np.zeros(n, np.int64)
    prominence = peak_prominences(smooth, peaks)[0]
    height = smooth[peaks]
    peaks = peaks[(prominence >= 0.5 * height) & (height >= 0.05 * float(np.median(height)))]
    centres = low + (peaks + 0.5) * bin_deg
    boundaries = (centres[1:] + centres[:-1]) / 2
    ring_of_bin = np.searchsorted(boundaries, low + (np.arange(len(counts)) + 0.5) * bin_deg)
    return ring_of_bin[bins].astype(np.int64)


def rings_of(cloud: PointCloud) -> tuple[NDArray[np.int64], str]:
    """The ring of each point and where it came from: the ``ring`` channel, or ``elevation``
    (:func:`estimate_rings`) when the cloud has none or only unknown rings (−1, the value
    readers fill in). Points of unknown ring in a ring channel (e.g. added noise) keep −1."""
    if cloud.has("ring") and len(cloud):
        values = cloud.channel("ring").copy()  # one pass over the strided column for both uses
        if float(values.max()) >= 0:  # (_has_rings)
            return np.rint(values, out=values).astype(np.int64), "channel"
    return estimate_rings(cloud.xyz), "elevation"


def ring_source(cloud: PointCloud) -> str:
    """Where :func:`rings_of` takes the rings from ("channel" or "elevation"), without computing them."""
    return "channel" if _has_rings(cloud) else "elevation"


def _has_rings(cloud: PointCloud) -> bool:
    return cloud.has("ring") and bool(len(cloud)) and float(cloud.channel("ring").max()) >= 0


def _has_times(cloud: PointCloud) -> bool:
    # Readers fill a missing time channel with zeros: a constant channel carries no timing.
    # (max > min is ptp > 0, NaN included; on a contiguous copy both reductions are vectorised.)
    if not cloud.has("time") or len(cloud) == 0:
        return False
    times = cloud.channel("time").copy()
    return float(times.max()) > float(times.min())


def _rings_for(cloud: PointCloud, source: str) -> NDArray[np.int64]:
    if source == "channel":
        if not cloud.has("ring"):
            raise ValueError("params were drawn for a cloud with a ring channel; this one has none")
        return np.rint(cloud.channel("ring")).astype(np.int64)
    return estimate_rings(cloud.xyz)


def _ring_mask(ring: NDArray[np.int64], chosen: NDArray[np.int64], unknown: bool) -> NDArray[np.bool_]:
    """``ring ∈ chosen`` by table lookup (O(N), unlike a sort); points of unknown ring (−1) get ``unknown``."""
    size = max(int(ring.max(initial=0)), int(chosen.max(initial=0))) + 2
    table = np.zeros(size, bool)
    table[chosen[chosen >= 0]] = True
    table[-1] = unknown  # index −1: the unknown ring
    return table[ring]


def azimuth_rad(xyz: NDArray[np.floating]) -> NDArray[np.floating]:
    """atan2(y, x): 0 straight ahead (+x), positive to the left (+y); in the points' own precision."""
    return np.arctan2(xyz[:, 1], xyz[:, 0])


def time_of_azimuth(azimuth: NDArray[np.floating], rotation_hz: float = 10.0) -> NDArray[np.floating]:
    """Firing time relative to the frame timestamp of a head spinning clockwise from behind
    (0 straight ahead; −period/2 behind at the start of the sweep)."""
    turns = mod_period(np.pi - azimuth, 2.0 * np.pi) / (2.0 * np.pi)
    return (turns - 0.5) / rotation_hz


#: Rows per block of :func:`_squared_ranges`: a block's rows (8192 × 32 bytes for an HDL-64E frame's
#: eight channels) stay in the L2 cache while its three columns are read.
SQUARED_BLOCK = 8192


def _squared_ranges(cloud: PointCloud, tops: NDArray[np.float32] | None = None) -> NDArray[np.float32]:
    """x² + y² + z² in float32, summed in that order, block by block: each strided column read
    from memory separately would bring the whole N×C array through the cache three times.
    ``tops`` (one entry per block of :data:`SQUARED_BLOCK` rows), when given, receives each
    block's largest intensity, read while the block is in the cache (see
    :func:`farthest_range_and_intensity_scale`)."""
    data = cloud.data
    n = len(data)
    total = np.empty(n, np.float32)
    term = np.empty(min(SQUARED_BLOCK, n), np.float32)
    for k, start in enumerate(range(0, n, SQUARED_BLOCK)):
        rows = data[start:start + SQUARED_BLOCK]
        out, t = total[start:start + len(rows)], term[:len(rows)]
        np.multiply(rows[:, 0], rows[:, 0], out=out)
        out += np.multiply(rows[:, 1], rows[:, 1], out=t)
        out += np.multiply(rows[:, 2], rows[:, 2], out=t)
        if tops is not None:
            tops[k] = rows[:, 3].max()
    return total


def farthest_range_and_intensity_scale(sample: Scene) -> tuple[float, float]:
    """(:func:`farthest_range` of the non-empty cloud, :func:`scene_intensity_scale` of the
    frame) in one pass over the points: where the scale is not declared, the intensity maximum
    it is inferred from is read block by block with the ranges (a strided column of the whole
    frame read on its own brings the whole array through the cache again)."""
    cloud = sample.points
    declared = declared_intensity_scale(sample)
    if declared is not None:
        return farthest_range(cloud), declared
    tops = np.empty(-(-len(cloud) // SQUARED_BLOCK), np.float32)
    farthest = _farthest_of(cloud, _squared_ranges(cloud, tops))
    return farthest, scale_of_maximum(float(tops.max()))  # NaN if an intensity is NaN, as ndarray.max


def farthest_range(cloud: PointCloud) -> float:
    """The largest float64 range ``‖(x, y, z)‖`` of a non-empty cloud, as
    ``np.linalg.norm(xyz.astype(float64), axis=1).max()`` gives it, without a float64 copy of
    every point.

    The float32 squared ranges pick the candidates: each is within 3 float32 roundings (relative
    3 · 2⁻²⁴ < 2e-7) of the exact value, so the point of the largest exact range has a float32
    square of at least (1 − 4e-7) times the largest one; every point above (1 − 1e-5) times it is
    a candidate, and the float64 norms of those (a handful) give the same maximum, bit for bit.
    """
    return _farthest_of(cloud, _squared_ranges(cloud))


def _farthest_of(cloud: PointCloud, squared: NDArray[np.float32]) -> float:
    """:func:`farthest_range` from the cloud's float32 squared ranges."""
    top = float(squared.max())
    if not np.isfinite(top):  # NaN or inf coordinates: the full computation, as before
        return float(np.linalg.norm(cloud.xyz.astype(np.float64), axis=1).max())
    # (their indices first: a boolean mask over the strided N×3 view is several times slower)
    candidates = cloud.xyz[np.flatnonzero(squared >= np.float32(top * (1.0 - 1e-5)))]
    return float(np.linalg.norm(candidates.astype(np.float64), axis=1).max())


def _present_rings(ring: NDArray[np.int64]) -> NDArray[np.int64]:
    """The distinct known rings (≥ 0), sorted, as ``np.unique`` gives them: marked in a table of
    the ring numbers (one pass, no sort, no hash table, no copy of the known ones) when they are
    small, as they are; the unknown ring (−1) marks the table's spare last entry."""
    if len(ring) == 0 or int(ring.min()) < -1 or int(ring.max()) >= 1 << 16:
        return np.unique(ring[ring >= 0])
    top = int(ring.max())
    seen = np.zeros(top + 2, bool)
    seen[ring] = True
    return np.flatnonzero(seen[:top + 1]).astype(np.int64)


def _with_intensity(cloud: PointCloud, values: NDArray[np.floating]) -> PointCloud:
    """``cloud.with_channel("intensity", values.astype(np.float32))`` with one copy of the data:
    the float64 values are rounded to float32 as they are written into it."""
    data = cloud.data.copy()
    data[:, 3] = values
    return PointCloud(data, cloud.channels)


def _draw_int(rng: np.random.Generator, interval: Range) -> int:
    lo, hi = round(interval[0]), round(interval[1])
    return lo if lo == hi else int(rng.integers(lo, hi + 1))


def _signed(rng: np.random.Generator, interval: Range) -> float:
    """A magnitude drawn from ``interval`` with a random sign."""
    value = uniform(rng, interval)
    return -value if rng.random() < 0.5 else value


def _jittered(sample: Scene, fill: Callable[[NDArray[np.float32]], object]) -> Scene:
    """The cloud with offsets added to x, then y, then z: ``fill(buffer)`` writes one axis's
    offsets into a preallocated float32 buffer (x's, then y's, then z's: the draws' order), and
    they are added block by block into the output as each block of rows is copied there, while
    it is in the cache — no N×3 temporaries, and no pass over a strided column of the whole frame
    (positions only: every other channel is copied as is)."""
    source = sample.points.data
    offsets = np.empty((3, len(source)), np.float32)
    for axis in range(3):
        fill(offsets[axis])
    data = np.empty_like(source)
    for start in range(0, len(source), MOTION_BLOCK):
        rows = data[start:start + MOTION_BLOCK]
        np.copyto(rows, source[start:start + MOTION_BLOCK])
        for axis in range(3):
            rows[:, axis] += offsets[axis, start:start + len(rows)]
    return sample.with_points(PointCloud(data, sample.points.channels))


def _uniform_offsets(rng: np.random.Generator, amplitude: np.float32) -> Callable[[NDArray[np.float32]], object]:
    """Fills a buffer with (2u − 1) · amplitude, u uniform in [0, 1), in place."""
    def fill(buffer: NDArray[np.float32]) -> None:
        rng.random(out=buffer, dtype=np.float32)
        buffer *= np.float32(2)
        buffer -= np.float32(1)
        buffer *= amplitude
    return fill


def _normal_offsets(rng: np.random.Generator, sigma: np.float32) -> Callable[[NDArray[np.float32]], object]:
    """Fills a buffer with N(0, 1) · sigma, in place."""
    def fill(buffer: NDArray[np.float32]) -> None:
        rng.standard_normal(out=buffer, dtype=np.float32)
        buffer *= sigma
    return fill


# --------------------------------------------------------------------------- beam missing
class BeamMissingConfig(Config):
    ratio_range: ShareRange = Field((0.25, 0.25), description="share of the frame's rings removed")


class BeamMissingParams(Params):
    rings: tuple[int, ...] = Field(description="ring indices removed (distinct)")
    ring_source: str = Field(description="'channel' (the ring channel) or 'elevation' (estimated)")

    def is_identity(self) -> bool:
        return not self.rings


class BeamMissing(Operator[Scene, BeamMissingConfig, BeamMissingParams]):
    """Dead lasers: whole rings lost (a failed emitter or receiver, a blocked channel).

    ``round(ratio · R)`` of the frame's R rings are drawn *without* replacement (Robo3D's
    generator draws with replacement, so it removes fewer rings than asked) and every
    point of those rings is removed. Rings come from the ``ring`` channel, or, when the
    cloud has none, from :func:`estimate_rings` (elevation histogram peaks); the params say
    which. Severity: ratio 0.1, 0.25, 0.4, 0.5, 0.75 (Robo3D's light/moderate/heavy drop
    16, 32, 48 of 64 beams = severities 2, 4, 5). Boxes, map and calibration are kept.
    """

    name = "beam_missing"
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = ("one beam in ten missing leaves every object most of its rows; one left below half is not "
                        "checked")
    targets = POINTS
    ConfigModel = BeamMissingConfig
    ParamsModel = BeamMissingParams
    IDENTITY: ClassVar = {"ratio_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"ratio_range": (r, r)} for s, r in
                            [(1, 0.1), (2, 0.25), (3, 0.4), (4, 0.5), (5, 0.75)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> BeamMissingParams:
        ring, source = rings_of(sample.points)
        present = _present_rings(ring)
        count = min(round(uniform(rng, self.config.ratio_range) * len(present)), len(present))
        chosen = rng.choice(present, size=count, replace=False) if count else np.zeros(0, np.int64)
        return BeamMissingParams(rings=tuple(sorted(int(r) for r in chosen)), ring_source=source)

    def apply(self, sample: Scene, params: BeamMissingParams) -> Scene:
        if params.is_identity() or len(sample.points) == 0:
            return sample
        ring = _rings_for(sample.points, params.ring_source)
        lost = _ring_mask(ring, np.asarray(params.rings, np.int64), unknown=False)
        return sample.with_points(sample.points.select(~lost)) if lost.any() else sample


# --------------------------------------------------------------------------- cross sensor
class CrossSensorConfig(Config):
    beam_factor_range: AtLeastOneRange = Field(
        (2.0, 2.0), description="ring spacing of the coarser sensor (≥ 1; 2 = every "
                                     "second ring; fractional values resample, e.g. 4/3 keeps 48 of 64)")
    azimuth_factor_range: AtLeastOneRange = Field(
        (2, 2), description="integer azimuth thinning (2 = every second firing)")


class CrossSensorParams(Params):
    beam_factor: float = Field(ge=1)
    beam_phase: float = Field(ge=0, description="first kept ring position, in rings (< beam_factor)")
    azimuth_factor: int = Field(ge=1)
    azimuth_phase: float = Field(ge=0, lt=1, description="firing phase within one coarse azimuth step")
    ring_source: str

    def is_identity(self) -> bool:
        return self.beam_factor == 1 and self.azimuth_factor == 1


class CrossSensor(Operator[Scene, CrossSensorConfig, CrossSensorParams]):
    """A sensor with fewer beams and a coarser azimuth step (a detector trained on a 64-beam
    LiDAR facing a 32- or 16-beam one; Robo3D's cross-sensor corruption).

    Beams: the kept rings are ``floor(phase + m · beam_factor)`` for m = 0, 1, …, so a
    factor 2 keeps every second ring and 4/3 keeps three in four. Azimuth: the native step
    is estimated as 2π over the largest ring's point count; a point is kept when its
    firing column (counted clockwise from behind, as the head turns) falls on the coarse
    grid ``column ≡ ⌊phase · factor⌋ (mod factor)`` (the estimate is a lower bound on the
    true column count, so the pattern slips by one column every few hundred; the kept
    share stays 1/factor). Rings from the ``ring`` channel, else estimated from elevation.
    Severity (beam factor, azimuth factor): (4/3, 2), (2, 2), (2, 3), (4, 2), (4, 4) —
    Robo3D's light/moderate/heavy (48/32/16 beams, half the points) are severities 1, 2
    and 4. Only points are removed; boxes, map, calibration and the kept points' values
    are untouched.
    """

    name = "cross_sensor"
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 0
    harmless_because = "another sensor's beam pattern changes every object's point density"
    targets = POINTS
    ConfigModel = CrossSensorConfig
    ParamsModel = CrossSensorParams
    IDENTITY: ClassVar = {"beam_factor_range": (1.0, 1.0), "azimuth_factor_range": (1, 1)}
    SEVERITIES: ClassVar = {s: {"beam_factor_range": (b, b), "azimuth_factor_range": (a, a)} for s, b, a in
                            [(1, 4 / 3, 2), (2, 2.0, 2), (3, 2.0, 3), (4, 4.0, 2), (5, 4.0, 4)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> CrossSensorParams:
        beam_factor = max(1.0, uniform(rng, self.config.beam_factor_range))
        return CrossSensorParams(beam_factor=beam_factor, beam_phase=float(rng.uniform(0.0, beam_factor)),
                                 azimuth_factor=max(1, _draw_int(rng, self.config.azimuth_factor_range)),
                                 azimuth_phase=float(rng.random()),
                                 ring_source="channel" if _has_rings(sample.points) else "elevation")

    def apply(self, sample: Scene, params: CrossSensorParams) -> Scene:
        cloud = sample.points
        if params.is_identity() or len(cloud) == 0:
            return sample
        ring = _rings_for(cloud, params.ring_source)
        # The known rings (≥ 0), tested once: where none is unknown, as in a full scan, they are all
        # of them, and no mask or copy of them is made.
        known = ring if int(ring.min()) >= 0 else ring[ring >= 0]
        keep = np.ones(len(cloud), bool)
        if params.beam_factor > 1 and len(known):
            top = int(ring.max()) + 1
            kept_rings = np.unique(np.floor(np.arange(params.beam_phase, top, params.beam_factor)).astype(np.int64))
            keep &= _ring_mask(ring, kept_rings, unknown=True)
        if params.azimuth_factor > 1:
            columns = int(np.bincount(known).max()) if len(known) else len(cloud)
            # floor(((π − azimuth) mod 2π) / 2π · columns), the same float32 steps in one buffer
            turns = np.subtract(np.pi, azimuth_rad(cloud.xyz))
            mod_period(turns, 2.0 * np.pi, out=turns)
            turns /= 2.0 * np.pi
            turns *= columns
            column = np.floor(turns, out=turns).astype(np.int64)
            phase = int(params.azimuth_phase * params.azimuth_factor)
            if int(column.min()) >= 0 and int(column.max()) <= 4 * columns + 4:  # (the cloud is not empty)
                # column mod factor == phase, read from a table of the few columns (an integer
                # division per point costs 3× the lookup)
                keep &= (np.arange(int(column.max()) + 1) % params.azimuth_factor == phase)[column]
            else:
                np.mod(column, params.azimuth_factor, out=column)
                keep &= column == phase
        return sample.with_points(cloud.select(keep))


# --------------------------------------------------------------------------- crosstalk
class CrosstalkConfig(Config):
    ratio_range: ShareRange = Field((0.008, 0.008), description="share of returns replaced by interference")
    max_range_m: float | None = Field(None, gt=0, description="farthest false range; default: the farthest return")
    intensity_range: ShareRange = Field(
        (0.0, 0.1), description="false returns' intensity, as a share of the data's scale")


class CrosstalkParams(Params):
    ratio: float = Field(ge=0, le=1)
    range_low: float = Field(ge=0)
    range_high: float = Field(ge=0)
    intensity_low: float = Field(ge=0, description="absolute, in the data's intensity scale")
    intensity_high: float = Field(ge=0)
    seed: int

    def is_identity(self) -> bool:
        return self.ratio == 0


class Crosstalk(Operator[Scene, CrosstalkConfig, CrosstalkParams]):
    """Interference from another LiDAR: its pulses reach this receiver at random instants, so a
    share of the returns report a random range along their own beam.

    Exactly ``round(ratio · N)`` points (without replacement) move to a range drawn
    uniformly in [1 m, max range] along their own direction, with a low random intensity
    (a share of the data's intensity scale: the frame's declared one, else inferred: 1, or
    255 for 8-bit data); their ``label`` becomes 0 (unlabelled) and ``instance`` −1, as they
    no longer lie on what they hit. Ring and time are kept (same laser, same firing).
    Severity: ratio 0.4, 0.8, 1.2, 1.6, 2.0 % (3D_Corruptions_AD; Robo3D uses 0.6–1.0 %).
    Unlike those tools, which add 3 m Gaussian noise to every column (intensity included),
    the false return stays on its beam. Small ratios are expected to leave a correct detector's output unchanged;
    the relation is degrading because large ones may not. Boxes are kept.
    """

    name = "crosstalk"
    aliases = ("lidar_crosstalk",)
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "0.4 % of returns displaced by another LiDAR; an object they crowd is not checked"
    targets = POINTS
    ConfigModel = CrosstalkConfig
    ParamsModel = CrosstalkParams
    IDENTITY: ClassVar = {"ratio_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"ratio_range": (r, r)} for s, r in
                            [(1, 0.004), (2, 0.008), (3, 0.012), (4, 0.016), (5, 0.02)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> CrosstalkParams:
        cloud = sample.points
        if len(cloud):
            farthest, scale = farthest_range_and_intensity_scale(sample)
        else:
            farthest, scale = 100.0, scene_intensity_scale(sample)
        high = max(self.config.max_range_m or farthest, 1.0)
        lo, hi = self.config.intensity_range
        return CrosstalkParams(ratio=uniform(rng, self.config.ratio_range), range_low=min(1.0, high), range_high=high,
                               intensity_low=lo * scale, intensity_high=hi * scale, seed=draw_seed(rng))

    def apply(self, sample: Scene, params: CrosstalkParams) -> Scene:
        cloud = sample.points
        count = round(params.ratio * len(cloud))
        if count == 0:
            return sample
        rng = np.random.default_rng(params.seed)
        chosen = rng.choice(len(cloud), size=count, replace=False)
        xyz = cloud.xyz[chosen].astype(np.float64)
        norm = np.linalg.norm(xyz, axis=1, keepdims=True)
        direction = np.where(norm > 1e-9, xyz / np.maximum(norm, 1e-9), [1.0, 0.0, 0.0])
        distance = rng.uniform(params.range_low, params.range_high, count)
        data = cloud.data.copy()
        data[chosen, :3] = direction * distance[:, None]
        data[chosen, 3] = rng.uniform(params.intensity_low, params.intensity_high, count)
        for name, value in (("label", 0.0), ("instance", -1.0)):
            if cloud.has(name):
                data[chosen, cloud.index(name)] = value
        return sample.with_points(cloud.with_data(data))


# --------------------------------------------------------------------------- FOV loss
class FovLossConfig(Config):
    center_range: Range = Field((-180.0, 180.0), description="sector centre azimuth, degrees (0 ahead, + left)")
    width_range: TurnRange = Field((90.0, 90.0), description="sector width, degrees")


class FovLossParams(Params):
    center: float = Field(description="degrees, atan2(y, x) in the LiDAR frame: 0 = +x (ahead), 90 = +y (left)")
    width: float = Field(ge=0, le=360)

    def is_identity(self) -> bool:
        return self.width == 0


class FovLoss(Operator[Scene, FovLossConfig, FovLossParams]):
    """A blocked angular sector of the sensor's window (mud, a sticker, a roof-rack bar): every
    point whose azimuth lies within ``width / 2`` of ``center`` is lost.

    Azimuth is atan2(y, x) in the x-forward LiDAR frame: 0° straight ahead, positive to
    the left (3D_Corruptions_AD measures it from the y axis, so its "front" sector is the
    left side). Severity: a sector of 45°, 90°, 135°, 180°, 270° at a random centre
    (3D_Corruptions_AD keeps 210°–90°, i.e. loses 150°–270°; its severities 2 and 5 are
    ours 4 and 5). Boxes, map and calibration are kept.
    """

    name = "fov_loss"
    aliases = ("fov_lost",)
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 5
    harmless_because = ("objects outside the lost sector keep every point; those inside have no evidence and are not "
                        "checked")
    targets = POINTS
    ConfigModel = FovLossConfig
    ParamsModel = FovLossParams
    IDENTITY: ClassVar = {"width_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"width_range": (w, w)} for s, w in
                            [(1, 45.0), (2, 90.0), (3, 135.0), (4, 180.0), (5, 270.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> FovLossParams:
        return FovLossParams(center=uniform(rng, self.config.center_range),
                             width=min(360.0, uniform(rng, self.config.width_range)))

    def apply(self, sample: Scene, params: FovLossParams) -> Scene:
        if params.is_identity() or len(sample.points) == 0:
            return sample
        # |((degrees(azimuth) − centre + 180) mod 360) − 180|, the same float32 steps in one buffer
        offset = np.degrees(azimuth_rad(sample.points.xyz))
        offset -= params.center
        offset += 180.0
        mod_period(offset, 360.0, out=offset)
        offset -= 180.0
        lost = np.abs(offset, out=offset) <= params.width / 2
        return sample.with_points(sample.points.select(~lost)) if lost.any() else sample


# --------------------------------------------------------------------------- motion distortion
class MotionDistortionConfig(Config):
    speed_range: Range = Field((10.0, 10.0), description="ego speed along x, m/s")
    yaw_rate_range: NonNegativeRange = Field((0.0, 0.0), description="yaw rate magnitude, deg/s (sign drawn)")
    rotation_hz: float = Field(10.0, gt=0, description="head rotation rate, for times estimated from azimuth")


class MotionDistortionParams(Params):
    speed: float = Field(description="m/s along +x")
    yaw_rate: float = Field(description="deg/s, counter-clockwise about +z")
    rotation_hz: float = Field(gt=0)
    time_source: str = Field(description="'channel' (the time channel) or 'azimuth' (estimated)")

    def is_identity(self) -> bool:
        return self.speed == 0 and self.yaw_rate == 0


class MotionDistortion(Operator[Scene, MotionDistortionConfig, MotionDistortionParams]):
    """Ego motion during the sweep left uncompensated (rolling-shutter skew of a spinning LiDAR).

    Each point is taken as fired at time t from the frame timestamp (the ``time`` channel,
    or, without it or when it is constant, :func:`time_of_azimuth` at ``rotation_hz``) by a sensor that has moved
    v·t along x and turned ω·t about z since; it is expressed in that sensor's frame:
    ``p' = R_z(−ω·t) · (p − (v·t, 0, 0))``. Points fired at t = 0 stay put; with ω = 0 a
    point moves by exactly −v·t along x (a point fired later appears nearer, as the car
    has driven towards it). Severity (speed m/s, |yaw rate| deg/s): (0–5, 5), (5–10, 10),
    (10–15, 15), (15–25, 25), (25–35, 35); at 10 Hz the largest shift is v · 0.05 s.
    Boxes, map and every channel but x, y, z are kept.
    """

    name = "motion_distortion"
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 0
    harmless_because = "the ego's motion during the sweep shears objects by up to half a metre"
    targets = POINTS
    ConfigModel = MotionDistortionConfig
    ParamsModel = MotionDistortionParams
    IDENTITY: ClassVar = {"speed_range": (0.0, 0.0), "yaw_rate_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"speed_range": (lo, hi), "yaw_rate_range": (w, w)} for s, lo, hi, w in
                            [(1, 0.0, 5.0, 5.0), (2, 5.0, 10.0, 10.0), (3, 10.0, 15.0, 15.0), (4, 15.0, 25.0, 25.0),
                             (5, 25.0, 35.0, 35.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> MotionDistortionParams:
        return MotionDistortionParams(speed=uniform(rng, self.config.speed_range),
                                      yaw_rate=_signed(rng, self.config.yaw_rate_range),
                                      rotation_hz=self.config.rotation_hz,
                                      time_source="channel" if _has_times(sample.points) else "azimuth")

    def apply(self, sample: Scene, params: MotionDistortionParams) -> Scene:
        cloud = sample.points
        if params.is_identity() or len(cloud) == 0:
            return sample
        # float32 throughout: the result is stored as float32, and this keeps a 120k frame under 10 ms.
        if params.time_source == "channel":
            t = cloud.channel("time")
        else:
            t = time_of_azimuth(azimuth_rad(cloud.xyz), params.rotation_hz).astype(np.float32)
        # The same float32 operations as on whole columns, block by block: each block of rows is
        # copied and rewritten while it is in the cache (a pass over a strided column of the whole
        # frame costs as much as copying it).
        source = cloud.data
        data = np.empty_like(source)
        speed = np.float32(params.speed)
        turn = np.float32(-np.deg2rad(params.yaw_rate))
        block = min(MOTION_BLOCK, len(source))
        shift, cos, x_moved, y_copy, term = (np.empty(block, np.float32) for _ in range(5))
        for start in range(0, len(source), block):
            rows = data[start:start + block]
            np.copyto(rows, source[start:start + block])
            k = len(rows)
            times, x, y = t[start:start + k], rows[:, 0], rows[:, 1]
            if params.yaw_rate == 0:
                x -= np.multiply(times, speed, out=shift[:k])
                continue
            # the moved x and the old y in contiguous buffers (each strided column read once), the
            # rotated values written straight into the rows: the same float32 operations
            moved = np.subtract(x, np.multiply(times, speed, out=shift[:k]), out=x_moved[:k])  # x − v·t
            old_y = y_copy[:k]
            np.copyto(old_y, y)
            angle = np.multiply(times, turn, out=shift[:k])
            c, s = np.cos(angle, out=cos[:k]), np.sin(angle, out=angle)
            sin_y = np.multiply(s, old_y, out=term[:k])
            np.multiply(c, moved, out=x)
            x -= sin_y  # cos·x − sin·y
            np.multiply(s, moved, out=y)
            y += np.multiply(c, old_y, out=c)  # sin·x + cos·y
        return sample.with_points(PointCloud(data, cloud.channels))


# --------------------------------------------------------------------------- spatial misalignment
class MisalignmentConfig(Config):
    rotation_range: NonNegativeRange = Field(
        (0.0, 0.5), description="|roll|, |pitch|, |yaw| each, degrees (sign drawn)")
    translation_range: NonNegativeRange = Field(
        (0.0, 8.0), description="|x|, |y|, |z| offset each, centimetres (sign drawn)")


class MisalignmentParams(Params):
    roll: float = Field(description="degrees about x")
    pitch: float = Field(description="degrees about y")
    yaw: float = Field(description="degrees about z")
    x_cm: float
    y_cm: float
    z_cm: float

    def is_identity(self) -> bool:
        return not any((self.roll, self.pitch, self.yaw, self.x_cm, self.y_cm, self.z_cm))


class SpatialMisalignment(Operator[Scene, MisalignmentConfig, MisalignmentParams]):
    """A wrong LiDAR extrinsic calibration (a knocked or drifting mount): the points are moved by
    a small rigid transform ``p' = R_z(yaw) R_y(pitch) R_x(roll) p + t`` while the labels,
    the map and the calibration stay where the world is.

    Severity (max |angle| per axis in degrees, max |offset| per axis in cm): (0.25, 4),
    (0.5, 8), (0.75, 12), (1.0, 16), (1.25, 20) — 3D_Corruptions_AD's σ of 0.004–0.02 rad
    and 4–20 cm, but as a proper rotation (that tool adds noise to the rotation matrix's
    entries, which is no rotation). Only x, y, z change.
    """

    name = "spatial_misalignment"
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 0
    harmless_because = "a miscalibrated sensor moves every object against the map and the labels"
    targets = POINTS
    ConfigModel = MisalignmentConfig
    ParamsModel = MisalignmentParams
    IDENTITY: ClassVar = {"rotation_range": (0.0, 0.0), "translation_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"rotation_range": (0.0, r), "translation_range": (0.0, t)} for s, r, t in
                            [(1, 0.25, 4.0), (2, 0.5, 8.0), (3, 0.75, 12.0), (4, 1.0, 16.0), (5, 1.25, 20.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> MisalignmentParams:
        r, t = self.config.rotation_range, self.config.translation_range
        return MisalignmentParams(roll=_signed(rng, r), pitch=_signed(rng, r), yaw=_signed(rng, r),
                                  x_cm=_signed(rng, t), y_cm=_signed(rng, t), z_cm=_signed(rng, t))

    @staticmethod
    def matrix(params: MisalignmentParams) -> NDArray[np.float64]:
        """The 4×4 transform applied to the points (not to the labels)."""
        a, b, c = np.deg2rad([params.roll, params.pitch, params.yaw])
        rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
        ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
        rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
        m = np.eye(4)
        m[:3, :3] = rz @ ry @ rx
        m[:3, 3] = np.array([params.x_cm, params.y_cm, params.z_cm]) / 100.0
        return m

    def apply(self, sample: Scene, params: MisalignmentParams) -> Scene:
        if params.is_identity() or len(sample.points) == 0:
            return sample
        # float64 maths, column by column in cache-sized blocks (see transformed_points)
        return sample.with_points(transformed_points(sample.points, self.matrix(params)))


# --------------------------------------------------------------------------- range degradation
class RangeDegradationConfig(Config):
    range_factor_range: ShareRange = Field(
        (0.7, 0.7), description="new maximum range, as a share of the farthest return")
    noise_range: NonNegativeRange = Field((0.05, 0.05), description="range noise std at the new maximum range, metres")


class RangeDegradationParams(Params):
    max_range: float | None = Field(gt=0, description="metres; None = no limit")
    noise_at_max: float = Field(ge=0, description="range noise std at max_range (or the farthest return), metres")
    seed: int

    def is_identity(self) -> bool:
        return self.max_range is None and self.noise_at_max == 0


class RangeDegradation(Operator[Scene, RangeDegradationConfig, RangeDegradationParams]):
    """A weaker receiver (aged laser, dirty optics, lower gain): returns beyond a reduced maximum
    range are lost and the rest get range noise along their beam that grows with range.

    The received power of a return falls as 1/r², and a time-of-flight receiver's range
    jitter grows as the signal-to-noise ratio drops, so the noise std is
    ``noise_at_max · (r / max_range)²``; points move radially only (their direction, hence
    their azimuth and elevation, is kept). Severity (max range as a share of the frame's
    farthest return, noise std at that range): (0.9, 2 cm), (0.8, 4 cm), (0.7, 6 cm),
    (0.6, 8 cm), (0.5, 10 cm). Intensity and the other channels, boxes and map are kept.
    """

    name = "range_degradation"
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "10 % less range with 2 cm of noise: objects beyond it lose their evidence and are not checked"
    targets = POINTS
    ConfigModel = RangeDegradationConfig
    ParamsModel = RangeDegradationParams
    IDENTITY: ClassVar = {"range_factor_range": (1.0, 1.0), "noise_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"range_factor_range": (f, f), "noise_range": (n, n)} for s, f, n in
                            [(1, 0.9, 0.02), (2, 0.8, 0.04), (3, 0.7, 0.06), (4, 0.6, 0.08), (5, 0.5, 0.10)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> RangeDegradationParams:
        cloud = sample.points
        factor = uniform(rng, self.config.range_factor_range)
        noise = uniform(rng, self.config.noise_range)
        max_range: float | None = None
        if factor < 1.0:
            farthest = float(np.sqrt(_squared_ranges(cloud).max())) if len(cloud) else 100.0
            max_range = max(factor * farthest, 1e-3)
        return RangeDegradationParams(max_range=max_range, noise_at_max=noise, seed=draw_seed(rng))

    def apply(self, sample: Scene, params: RangeDegradationParams) -> Scene:
        cloud = sample.points
        if params.is_identity() or len(cloud) == 0:
            return sample
        n = len(cloud)
        distance = np.sqrt(_squared_ranges(cloud))
        keep = distance <= params.max_range if params.max_range is not None else None
        if params.noise_at_max <= 0:
            return sample.with_points(cloud.select(keep)) if keep is not None and not keep.all() else sample
        reference = params.max_range if params.max_range is not None else max(float(distance.max()), 1e-3)
        noise = np.random.default_rng(params.seed).standard_normal(n, np.float32)  # drawn for every point
        # max(d + (noise · c) · d², 0.05) / max(d, 1e-9), the same float32 operations in place
        noise *= np.float32(params.noise_at_max / reference**2)
        squared = np.multiply(distance, distance)
        noise *= squared
        noise += distance
        noisy = np.maximum(noise, np.float32(0.05), out=noise)
        factor = np.divide(noisy, np.maximum(distance, np.float32(1e-9), out=squared), out=noisy)
        if keep is not None and not keep.all():  # one copy: the kept rows only
            factor = factor[keep]
        else:
            keep = None
        # radially, column by column, block by block: each block of (kept) rows is copied into the
        # output and scaled there while it is in the cache
        source = cloud.data
        data = np.empty((len(factor), source.shape[1]), np.float32)
        written = 0
        for start in range(0, n, MOTION_BLOCK):
            end = min(start + MOTION_BLOCK, n)
            if keep is None:
                rows = data[start:end]
                np.copyto(rows, source[start:end])
            else:
                kept = keep[start:end]
                rows = data[written:written + int(np.count_nonzero(kept))]
                np.compress(kept, source[start:end], axis=0, out=rows)
            for axis in range(3):
                rows[:, axis] *= factor[written:written + len(rows)]
            written += len(rows)
        return sample.with_points(PointCloud(data, cloud.channels))


# --------------------------------------------------------------------------- intensity
class QuantisationConfig(Config):
    levels_range: NonNegativeRange = Field((16, 16), description="number of intensity levels (0 = no quantisation)")
    threshold_range: ShareRange = Field((0.0, 1.0), description="comparator threshold within one step (0.5 = nearest)")


class QuantisationParams(Params):
    levels: int = Field(ge=0)
    threshold: float = Field(ge=0, le=1)
    scale: float = Field(gt=0, description="the data's intensity full scale (declared, else inferred: 1, 255, …)")

    def is_identity(self) -> bool:
        return self.levels == 0


class IntensityQuantisation(Operator[Scene, QuantisationConfig, QuantisationParams]):
    """A coarse intensity ADC: intensity quantised to ``levels`` values evenly spaced over
    [0, scale], where ``scale`` is the frame's declared intensity scale
    (``scene.metadata["intensity_scale"]``), else inferred from the data (1 for [0, 1] data,
    255 for 8-bit, 65535 for 16-bit). A value goes to level ``clip(⌊v / step + 1 − threshold⌋)``, so
    threshold 0.5 rounds to the nearest level; the threshold (the comparator offset) is
    drawn. Severity: 64, 32, 16, 8, 4 levels. Positions, the other channels, boxes and map
    are untouched.
    """

    name = "intensity_quantisation"
    aliases = ("intensity_quantization",)
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 2
    harmless_because = "32 or 64 intensity levels are as fine as many sensors report"
    targets = POINTS
    ConfigModel = QuantisationConfig
    ParamsModel = QuantisationParams
    IDENTITY: ClassVar = {"levels_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"levels_range": (n, n)} for s, n in [(1, 64), (2, 32), (3, 16), (4, 8), (5, 4)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> QuantisationParams:
        return QuantisationParams(levels=max(0, _draw_int(rng, self.config.levels_range)),
                                  threshold=uniform(rng, self.config.threshold_range),
                                  scale=scene_intensity_scale(sample))

    def apply(self, sample: Scene, params: QuantisationParams) -> Scene:
        cloud = sample.points
        if params.is_identity() or len(cloud) == 0:
            return sample
        if params.levels == 1:
            return sample.with_points(cloud.with_channel("intensity", np.zeros(len(cloud), np.float32)))
        step = params.scale / (params.levels - 1)
        # clip(floor(i / step + 1 − threshold), 0, levels − 1) · step: the same float64 steps in one buffer
        level = cloud.intensity.astype(np.float64)
        level /= step
        level += 1.0
        level -= params.threshold
        np.floor(level, out=level)
        np.clip(level, 0, params.levels - 1, out=level)
        level *= step
        return sample.with_points(_with_intensity(cloud, level))


class SaturationConfig(Config):
    gain_range: NonNegativeRange = Field((1.0, 1.5), description="receiver gain applied before clipping")
    level_range: ShareRange = Field((0.5, 0.5), description="saturation level, as a share of the data's scale")


class SaturationParams(Params):
    gain: float = Field(ge=0)
    level: float = Field(gt=0, description="saturation level, as a share of scale")
    scale: float = Field(gt=0, description="the data's intensity full scale (declared, else inferred: 1, 255, …)")

    def is_identity(self) -> bool:
        return self.gain == 1 and self.level >= 1


class IntensitySaturation(Operator[Scene, SaturationConfig, SaturationParams]):
    """A saturating receiver (too much gain, retro-reflectors, short range): intensity
    multiplied by a gain and clipped at a saturation level, ``min(gain · v, level)``.

    The level is a share of the data's scale (the frame's declared one, else inferred: 1 for
    [0, 1] data, 255 for 8-bit, 65535 for 16-bit), stored in the params with the scale.
    Severity (gain, level): (1.0–1.25, 0.8), (1.25–1.5, 0.6), (1.5–2, 0.4), (2–3, 0.3),
    (3–4, 0.2). Positions, the other channels, boxes and map are untouched.
    """

    name = "intensity_saturation"
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "up to 25 % more gain, clipped at 0.8, keeps the order of reflectances"
    targets = POINTS
    ConfigModel = SaturationConfig
    ParamsModel = SaturationParams
    IDENTITY: ClassVar = {"gain_range": (1.0, 1.0), "level_range": (1.0, 1.0)}
    SEVERITIES: ClassVar = {s: {"gain_range": (g0, g1), "level_range": (lv, lv)} for s, g0, g1, lv in
                            [(1, 1.0, 1.25, 0.8), (2, 1.25, 1.5, 0.6), (3, 1.5, 2.0, 0.4), (4, 2.0, 3.0, 0.3),
                             (5, 3.0, 4.0, 0.2)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> SaturationParams:
        return SaturationParams(gain=uniform(rng, self.config.gain_range), level=uniform(rng, self.config.level_range),
                                scale=scene_intensity_scale(sample))

    def apply(self, sample: Scene, params: SaturationParams) -> Scene:
        cloud = sample.points
        if params.is_identity() or len(cloud) == 0:
            return sample
        intensity = cloud.intensity.astype(np.float64)
        intensity *= params.gain
        np.minimum(intensity, params.level * params.scale, out=intensity)
        return sample.with_points(_with_intensity(cloud, intensity))


# --------------------------------------------------------------------------- jitter
class GaussianJitterConfig(Config):
    sigma_range: NonNegativeRange = Field((0.04, 0.04), description="std of the offset on each of x, y, z, metres")


class GaussianJitterParams(Params):
    sigma: float = Field(ge=0)
    seed: int

    def is_identity(self) -> bool:
        return self.sigma == 0


class GaussianJitter(Operator[Scene, GaussianJitterConfig, GaussianJitterParams]):
    """Position noise of the range/angle measurement: every point's x, y, z get independent
    Gaussian offsets of std ``sigma``. Intensity, ring, time, label and instance are left
    bit-identical (3D_Corruptions_AD adds the noise to every column, intensity included).
    Severity: σ = 2, 4, 6, 8, 10 cm (3D_Corruptions_AD). Small jitter is expected to leave a
    correct detector's output unchanged; large noise may not, hence degrading. Boxes kept.
    """

    name = "gaussian_jitter"
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "2 cm of Gaussian jitter is a HDL-64E's own ranging noise"
    targets = POINTS
    ConfigModel = GaussianJitterConfig
    ParamsModel = GaussianJitterParams
    IDENTITY: ClassVar = {"sigma_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"sigma_range": (v, v)} for s, v in
                            [(1, 0.02), (2, 0.04), (3, 0.06), (4, 0.08), (5, 0.10)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> GaussianJitterParams:
        return GaussianJitterParams(sigma=uniform(rng, self.config.sigma_range), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: GaussianJitterParams) -> Scene:
        if params.is_identity() or len(sample.points) == 0:
            return sample
        rng, sigma = np.random.default_rng(params.seed), np.float32(params.sigma)
        return _jittered(sample, _normal_offsets(rng, sigma))


class UniformJitterConfig(Config):
    amplitude_range: NonNegativeRange = Field(
        (0.04, 0.04), description="offsets on x, y, z drawn in ±amplitude, metres")


class UniformJitterParams(Params):
    amplitude: float = Field(ge=0)
    seed: int

    def is_identity(self) -> bool:
        return self.amplitude == 0


class UniformJitter(Operator[Scene, UniformJitterConfig, UniformJitterParams]):
    """Bounded position noise (quantised timing, encoder steps): every point's x, y, z get
    independent offsets uniform in ±``amplitude``. Intensity and every other channel are
    left bit-identical. Severity: ±2, 4, 6, 8, 10 cm (3D_Corruptions_AD). Small jitter is
    expected to be invariant; large may not, hence degrading. Boxes kept.
    """

    name = "uniform_jitter"
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "2 cm of uniform jitter is within a HDL-64E's ranging noise"
    targets = POINTS
    ConfigModel = UniformJitterConfig
    ParamsModel = UniformJitterParams
    IDENTITY: ClassVar = {"amplitude_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"amplitude_range": (v, v)} for s, v in
                            [(1, 0.02), (2, 0.04), (3, 0.06), (4, 0.08), (5, 0.10)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> UniformJitterParams:
        return UniformJitterParams(amplitude=uniform(rng, self.config.amplitude_range), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: UniformJitterParams) -> Scene:
        if params.is_identity() or len(sample.points) == 0:
            return sample
        rng, amplitude = np.random.default_rng(params.seed), np.float32(params.amplitude)
        return _jittered(sample, _uniform_offsets(rng, amplitude))


class ImpulseJitterConfig(Config):
    ratio_range: ShareRange = Field((1 / 20, 1 / 20), description="share of points displaced")
    offset_range: NonNegativeRange = Field(
        (0.3, 0.3), description="offset on each of x, y, z (sign drawn per axis), metres")


class ImpulseJitterParams(Params):
    ratio: float = Field(ge=0, le=1)
    offset: float = Field(ge=0)
    seed: int

    def is_identity(self) -> bool:
        return self.ratio == 0 or self.offset == 0


class ImpulseJitter(Operator[Scene, ImpulseJitterConfig, ImpulseJitterParams]):
    """Salt-and-pepper position errors (bad range readings, multipath): exactly
    ``round(ratio · N)`` points, without replacement, are displaced by ±``offset`` on each
    of x, y, z (signs drawn per axis). Intensity and every other channel are left
    bit-identical. Severity (share, offset): N/30, N/25, N/20, N/15, N/10 points as in
    3D_Corruptions_AD, with offsets 0.1, 0.2, 0.3, 0.4, 0.5 m (that tool uses 0.1 m for
    all). Small offsets are expected to be invariant; large may not, hence degrading.
    """

    name = "impulse_jitter"
    family = "sensor"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "3 % of points off by 10 cm is within a real scan's outliers"
    targets = POINTS
    ConfigModel = ImpulseJitterConfig
    ParamsModel = ImpulseJitterParams
    IDENTITY: ClassVar = {"ratio_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"ratio_range": (r, r), "offset_range": (o, o)} for s, r, o in
                            [(1, 1 / 30, 0.1), (2, 1 / 25, 0.2), (3, 1 / 20, 0.3), (4, 1 / 15, 0.4),
                             (5, 1 / 10, 0.5)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ImpulseJitterParams:
        return ImpulseJitterParams(ratio=uniform(rng, self.config.ratio_range),
                                   offset=uniform(rng, self.config.offset_range), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: ImpulseJitterParams) -> Scene:
        cloud = sample.points
        count = round(params.ratio * len(cloud))
        if params.is_identity() or count == 0:
            return sample
        rng = np.random.default_rng(params.seed)
        chosen = rng.choice(len(cloud), size=count, replace=False)
        signs = np.where(rng.random((count, 3)) < 0.5, -1.0, 1.0)
        # only the chosen rows go through float64 (the others would round-trip exactly)
        data = cloud.data.copy()
        moved = data[chosen, :3].astype(np.float64)
        moved += signs * params.offset
        data[chosen, :3] = moved
        return sample.with_points(PointCloud(data, cloud.channels))


__all__ = [
    "BeamMissing", "CrossSensor", "Crosstalk", "FovLoss", "GaussianJitter", "ImpulseJitter", "IntensityQuantisation",
    "IntensitySaturation", "MotionDistortion", "RangeDegradation", "SpatialMisalignment", "UniformJitter",
    "estimate_rings", "ring_source", "rings_of", "time_of_azimuth",
]
