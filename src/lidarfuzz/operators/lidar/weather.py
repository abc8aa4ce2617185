"""Adverse weather: fog, rain, snow and wet ground, after the published physical LiDAR models.

All four change points only (boxes, calibration and the map are kept) and are *degrading*:
returns are attenuated, lost, or replaced by returns from the air (fog, drops, flakes).
A return that now comes from the air keeps its ``ring``, ``time`` and any foreign channel
(it is the same laser firing), but gets ``label`` 0 (unlabelled) and ``instance`` −1: it no
longer hits the surface or object it was labelled with.

Which returns are lost: every operator here decides it with the power model of
:mod:`lidarfuzz.operators.lidar.power`. A reported return was detected, so its clear-weather
power was at least the receiver's threshold whatever its intensity reads; its margin over the
threshold comes from the LiDAR equation, the sensor's range specification (default: the
HDL-64E's, ``detection_threshold`` 0.4 = 10 % reflectivity at 50 m) and the reading where the
reading resolves it (zero and refuted readings: a seeded draw over what the detection admits).
A return is lost when the attenuation at its range outweighs that margin, so losses grow
smoothly with range and with the severity, on real intensities (many zeros) as on the
simulator's.

Intensity units: the models work on a physical scale (received power or reflectivity in
[0, 1]). Each operator converts with an explicit ``intensity_scale`` — given in the config,
else the one the frame's reader declared (``scene.metadata["intensity_scale"]``: 1 for KITTI,
255 for nuScenes), else inferred from the values (1 for [0, 1] data, 255 for 8-bit, 65535 for
16-bit) — stored in the params, and converts back, so a [0, 1] frame and the same frame in
0–255 give the same result up to the scale.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import (
    Config,
    NonNegativeRange,
    Operator,
    Params,
    PositiveRange,
    Relation,
    ShareRange,
    Target,
    draw_seed,
    uniform,
)
from lidarfuzz.operators.lidar.common import intensity_scale, scene_intensity_scale, scratch
from lidarfuzz.operators.lidar.power import (
    HDL64E_DETECTION_THRESHOLD,
    effective_reflectivity,
    power_draw_stream,
    power_draws,
    power_margin,
)
from lidarfuzz.scene.points import CHANNEL_DEFAULTS, PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.scene.semantics import GROUND_CLASSES, SEMANTIC_ID

Range = tuple[float, float]
POINTS = frozenset({Target.POINTS})
F64 = NDArray[np.float64]

SPEED_OF_LIGHT = 299_792_458.0  # m/s


def _detection_threshold() -> Any:
    """The receiver's sensitivity (see :mod:`~lidarfuzz.operators.lidar.power`); the params default
    to it too, so params stored before it existed still replay."""
    return Field(HDL64E_DETECTION_THRESHOLD, gt=0, description="weakest effective reflectivity detected at 100 m "
                 "(HDL-64E: 0.4, i.e. 10 % at 50 m; the lidarfuzz simulator's: 0.05)")


def infer_intensity_scale(cloud: PointCloud) -> float:
    """The cloud's intensity full scale (see :func:`~lidarfuzz.operators.lidar.common.intensity_scale`)."""
    return intensity_scale(cloud.intensity)


def _scale(configured: float | None, scene: Scene) -> float:
    return float(configured) if configured is not None else scene_intensity_scale(scene)


def _ranges(cloud: PointCloud) -> F64:
    """Each point's range: x² + y² + z² column by column in float32 (a float64 copy of the
    strided N×3 view costs more than the whole sum), the square root in float64."""
    return _block_ranges(cloud.data)


def _block_ranges(data: NDArray[np.float32]) -> F64:
    """:func:`_ranges` of a block of rows of a cloud's data (x, y, z its first three columns)."""
    x, y, z = data[:, 0], data[:, 1], data[:, 2]
    return np.sqrt((x * x + y * y + z * z).astype(np.float64))


_TINY = float(np.finfo(np.float64).tiny)
#: Points per block of the per-point passes: the temporaries of a block (a few float64 arrays of
#: this length, 256 KiB each) stay in cache and are reused, so a pass costs the same per point at
#: 30k points as at 2M, instead of streaming a dozen fresh N-long temporaries through memory.
_BLOCK = 32768


def _blocks(n: int) -> list[slice]:
    return [slice(start, min(start + _BLOCK, n)) for start in range(0, n, _BLOCK)]


def _rescaled(cloud: PointCloud, keep: NDArray[np.bool_], ranges: F64, new_range: F64, intensity: F64,
              in_air: NDArray[np.bool_]) -> PointCloud:
    """The kept points, each moved along its own beam to ``new_range`` and given a new intensity;
    points whose return now comes from the air lose their label and instance. One float32 copy
    of the kept rows; only the points whose range changed are rescaled (in float64). Where most
    rows moved (rain's range noise moves them all), x, y and z are scaled column by column with
    a factor of exactly 1 for the others — the same bytes, without the gathers and N×3
    temporaries of a fancy-indexed update. The kept rows' values are gathered into this thread's
    scratch arrays (:func:`~lidarfuzz.operators.lidar.common.scratch`): fresh N-long temporaries
    were faulted in afresh on every call; only the output is new."""
    n = len(keep)
    kept = int(np.count_nonzero(keep))
    moved_mask = np.not_equal(new_range, ranges, out=scratch("rescaled.moved", n, bool))
    moved_mask &= keep  # kept points that moved
    n_moved = int(np.count_nonzero(moved_mask))
    kept_intensity = np.compress(keep, intensity, out=scratch("rescaled.intensity", kept))
    # Kept rows whose return comes from the air, as rows of the copy.
    air = np.flatnonzero(np.compress(keep, in_air, out=scratch("rescaled.air", kept, bool)))
    data = np.compress(keep, cloud.data, axis=0)  # as fast as a take of the kept rows, ~3× a boolean index
    if 4 * n_moved > kept:
        kept_ranges = np.compress(keep, ranges, out=scratch("rescaled.ranges", kept))
        kept_new = np.compress(keep, new_range, out=scratch("rescaled.new_range", kept))
        factor = np.empty(min(_BLOCK, kept))
        for block in _blocks(kept):
            f = factor[:block.stop - block.start]
            f.fill(1.0)
            np.divide(kept_new[block], kept_ranges[block], out=f, where=kept_ranges[block] > 0)
            moved_rows = data[block]
            for axis in range(3):
                moved_rows[:, axis] = moved_rows[:, axis] * f
    else:
        source = np.flatnonzero(moved_mask)
        moved = np.flatnonzero(np.compress(keep, moved_mask, out=scratch("rescaled.moved_kept", kept, bool)))
        factor = np.divide(new_range[source], ranges[source], out=np.ones(len(source)), where=ranges[source] > 0)
        if len(source):
            data[moved, :3] = data[moved, :3] * factor[:, None]
    data[:, 3] = kept_intensity
    for name in ("label", "instance"):
        if cloud.has(name) and len(air):
            data[air, cloud.index(name)] = CHANNEL_DEFAULTS[name]
    return PointCloud(data, cloud.channels)


# =========================================================================== fog
#: Hahner et al.'s reference target reflectivity Γ (β₀ = Γ/π): with it, the clear-weather
#: intensity of a return fixes the system constant C_A·P₀ of its beam (their eq. 9–10).
FOG_REFERENCE_REFLECTIVITY = 1e-6
#: Overlap of transmitter and receiver: none below R₁, full beyond R₂ (linear between), metres.
FOG_OVERLAP = (0.9, 1.0)
#: β = 0.046 / MOR (Hahner et al., after Rasshofer et al. 2011): backscatter per unit solid angle.
FOG_BACKSCATTER_PER_MOR = 0.046
#: Fog returns are pushed back by jitter · Beta(2, 20) metres (the paper's noise variant v4).
FOG_RETURN_JITTER = 10.0


class FogConfig(Config):
    mor_range: PositiveRange | None = Field(
        (200.0, 200.0), description="meteorological optical range, metres; None: no fog")
    tau_h_ns: float = Field(20.0, gt=0, description="half-power width of the transmitted pulse, ns")
    threshold: float = Field(0.5 / 255, ge=0, description="threshold of a fog return, as a fraction of full intensity")
    detection_threshold: float = _detection_threshold()
    intensity_scale: float | None = Field(None, gt=0, description="full-scale intensity; None: the frame's "
                                          "declared scale, else inferred (1, 255 or 65535)")


class FogParams(Params):
    alpha: float = Field(ge=0, description="extinction coefficient, 1/m (= ln 20 / MOR)")
    tau_h_ns: float = Field(gt=0)
    threshold: float = Field(ge=0)
    detection_threshold: float = _detection_threshold()
    intensity_scale: float = Field(gt=0)
    seed: int

    def is_identity(self) -> bool:
        return self.alpha == 0


def fog_soft_response(alpha: float, tau_h: float, step: float = 0.05) -> tuple[F64, F64, F64]:
    """The fog (soft-target) return of the LiDAR equation, tabulated over the hard target's range.

    For a beam whose hard target is at ``R0``, the received power from fog at receiver range
    ``R`` is ``C_A P0 β (2/c) ∫ sin²(π (R − r)/(c τ_H)) ξ(r) exp(−2 α r) / r² dr`` over
    ``r ∈ [R − c τ_H, min(R, R0)]`` (the pulse ``sin²(π t / 2τ_H)``, 0 ≤ t ≤ 2τ_H, spread over
    the fog in front of the target). Computed on one fixed range grid for every ``R0`` at once
    (a masked cumulative sum), then maximised over ``R``.

    Returns:
        ``(r0, integral, distance)``: for each grid value of ``R0`` the peak of the integral
        (1/m, without ``C_A P0 β (2/c)``) and the range at which the sensor reports it (the
        pulse's peak, ``R − c τ_H / 2``). Beyond the last ``r0`` both are constant.
    """
    width = SPEED_OF_LIGHT * tau_h
    r1, r2 = FOG_OVERLAP
    n_r0 = int(np.ceil((r2 + width + 1.0) / step)) + 1  # beyond this R0 the target no longer cuts the peak
    n = n_r0 + int(np.ceil(width / step)) + 1
    r = np.arange(n) * step
    overlap = np.clip((r - r1) / (r2 - r1), 0.0, 1.0)
    g = np.divide(overlap * np.exp(-2.0 * alpha * r), r**2, out=np.zeros(n), where=r > 0)
    # Only the fog in front of a target within the table counts (r_k ≤ R0 < r[n_r0]): the first
    # n_r0 columns, whose prefix sums do not depend on the others.
    weights = _pulse_kernel(n, step, width)[:, :n_r0] * g[None, :n_r0] * step
    cumulative = np.cumsum(weights, axis=1)  # C[j, k]: fog up to r_k, seen at R_j
    j = np.arange(n)[:, None]
    m = np.arange(n_r0)[None, :]
    # seen[j, m] = C[j, min(j, m)] (fog only in front of the target: r ≤ R0): C[j, m], or the
    # diagonal C[j, j] where m > j — a selection, not a gather of n × n_r0 elements.
    diagonal = np.zeros(n)
    diagonal[:n_r0] = cumulative[np.arange(n_r0), np.arange(n_r0)]
    seen = np.where(m > j, diagonal[:, None], cumulative)
    best = np.argmax(seen, axis=0)
    integral = seen[best, np.arange(n_r0)]
    distance = np.maximum(r[best] - width / 2, r1)
    return r[:n_r0].astype(np.float64), np.asarray(integral, np.float64), np.asarray(distance, np.float64)


@lru_cache(maxsize=8)
def _pulse_kernel(n: int, step: float, width: float) -> F64:
    """The pulse's weight ``sin²(π (R_j − r_k) / (c τ_H))`` of fog at grid range ``r_k`` seen at
    ``R_j`` (0 outside the pulse), n × n. It does not depend on the fog (α), which a campaign
    draws afresh for every frame (the MOR is a range per severity): built once per pulse width,
    it leaves :func:`fog_soft_response` a product and a cumulative sum. Read-only, being shared."""
    r = np.arange(n) * step
    lag = r[:, None] - r[None, :]  # R_j − r_k
    in_pulse = (lag >= 0) & (lag <= width)
    kernel = np.where(in_pulse, np.sin(np.pi * np.clip(lag, 0, width) / width) ** 2, 0.0)
    kernel.flags.writeable = False
    return kernel


@lru_cache(maxsize=64)
def _cached_fog_soft_response(alpha: float, tau_h: float, step: float = 0.05) -> tuple[F64, F64, F64]:
    """:func:`fog_soft_response`, kept per (α, τ_H, step): a replay, a shrink or a fixed-MOR
    configuration asks for the same table again. A campaign draws each frame's MOR from its
    severity's range, so most calls build a new one (~0.3 ms). Read-only, being shared."""
    tables = fog_soft_response(alpha, tau_h, step)
    for table in tables:
        table.flags.writeable = False
    return tables


def _interp_near(ranges: F64, grid: F64, tables: tuple[F64, ...]) -> list[F64]:
    """``np.interp(ranges, grid, table)`` for each table of the uniform, finite ``grid``
    (``grid[k] = k · step``, as :func:`fog_soft_response` makes it), interpolating only the points
    within the grid: beyond its end every table is constant, and np.interp returns exactly its last
    value there, so the result is the same to the bit at a fraction of the cost (most returns lie
    far beyond the few metres the fog's soft response depends on).

    Within the grid, np.interp's own arithmetic: the cell ``grid[j] ≤ r < grid[j+1]`` its search
    finds, the node's value where ``r`` is a node, else ``slope[j] · (r − grid[j]) + table[j]``
    with ``slope[j] = (table[j+1] − table[j]) / (grid[j+1] − grid[j])``. The cell comes from the
    uniform step (one multiplication, corrected by one where rounding put it in the neighbour)
    instead of a binary search per point and table: np.interp cost ~40 ns a point per table here."""
    near = np.flatnonzero(ranges < grid[-1])
    results = [np.full(len(ranges), table[-1]) for table in tables]
    if len(near) == 0:
        return results
    x = np.take(ranges, near)
    j = (x * (1.0 / (grid[1] - grid[0]))).astype(np.intp)
    np.clip(j, 0, len(grid) - 2, out=j)
    j -= np.take(grid, j) > x
    j += np.take(grid, j + 1) <= x
    offset = x - np.take(grid, j)
    nodes = np.flatnonzero(offset == 0.0)
    spacing = grid[1:] - grid[:-1]
    for values, table in zip(results, tables, strict=True):
        inside = np.take((table[1:] - table[:-1]) / spacing, j)
        inside *= offset
        inside += np.take(table, j)
        inside[nodes] = table[j[nodes]]
        np.put(values, near, inside)
    return results


class Fog(Operator[Scene, FogConfig, FogParams]):
    """Fog after Hahner et al., "Fog Simulation on Real LiDAR Point Clouds" (ICCV 2021).

    Every return's power falls by the two-way extinction ``exp(−2 α R)`` (the hard target),
    with ``α = ln 20 / MOR`` (Koschmieder, 5 % contrast). The fog in front of the target scatters
    part of the pulse back (the soft target, backscatter ``β = 0.046 / MOR``); its power follows
    the paper's LiDAR model — a ``sin²`` pulse of half-power width ``τ_H`` (20 ns), overlap of
    transmitter and receiver from 0.9 m to 1 m — and is scaled, as in the paper, by the beam's
    system constant inferred from the return's clear-weather intensity with the reference
    reflectivity Γ = 10⁻⁶. Where the fog's return beats the attenuated hard return and the
    receiver threshold (a fraction of full scale, default 0.5/255, one 8-bit step), the point
    moves along its beam to the fog's range (plus the paper's ``10 · Beta(2, 20)`` m jitter) with
    the fog's intensity.

    Which hard returns are lost does not follow the paper, which reads intensity as received power
    — so a zero reading has none, and its public tool turns almost every KITTI or Waymo point with
    a dark reading into fog or deletes it. Here a return is lost when ``m · exp(−2 α R) < 1``, with
    ``m`` its clear-weather power margin from :func:`~lidarfuzz.operators.lidar.power.power_margin`
    (the LiDAR equation, the sensor's range specification ``detection_threshold``, the reading
    where it resolves the reflectivity, a seeded draw over ``[ρ_det(R), 1]`` where it does not):
    losses grow smoothly with range and with falling MOR, zero readings included.

    Against the published curves: the two-way extinction is Hahner et al.'s (and every fog
    simulator's), so the loss differs from theirs only through the margin. Their model keeps a
    return while ``i · exp(−2αR)`` stays above one 8-bit step, independent of range otherwise: a
    reading of 0.3 survives to ``2αR = ln(0.3 · 510)``, 42 m at MOR 50 m and 630 m at MOR 750 m,
    while a zero is lost at any range under any fog. With the power margin, a target of effective
    reflectivity ρ is seen to the range R where ``(R / 100 m)² exp(2αR) = ρ / d``; for the HDL-64E
    (d = 0.4), ρ = 0.1 / 0.9: clear 50 / 150 m, MOR 750 m 42 / 100 m, MOR 200 m 31 / 61 m,
    MOR 50 m 17.5 / 28 m, MOR 20 m 10.5 / 15 m. Bijelic et al. ("A Benchmark for Lidar Sensors in
    Fog: Is Detection Breaking Down?", IV 2018) measured the HDL-64 S3D and the VLP-32 in the
    CEREMA fog chamber (targets within its 30 m) and found the maximum viewing distance shrinking
    steadily as the MOR falls, dark targets first; the curve values themselves could not be
    retrieved here to check these figures against.

    Intensity is read on the scale ``intensity_scale`` (the frame's declared scale, else inferred:
    1 for [0, 1] data, 255 for 0–255 data) and written back on it. The public tool rounds
    attenuated intensities as if they were 0–255 integers, so on [0, 1] data it zeroes every hard
    return and turns nearly the whole cloud into fog; here both scales give the same result.

    Severity (MOR): 1: 600–900 m (haze, just under the 1 km that defines fog), 2: 300–500 m,
    3: 150–250 m, 4: 80–120 m, 5: 40–60 m (the densest fog of the paper's chamber data).
    Points are moved (to fog returns) or removed; everything else is kept, boxes included.
    """

    name = "fog"
    family = "weather"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "light fog (visibility 600-900 m) takes almost no return from an object within 70 m"
    targets = POINTS
    ConfigModel = FogConfig
    ParamsModel = FogParams
    IDENTITY: ClassVar = {"mor_range": None}
    SEVERITIES: ClassVar = {s: {"mor_range": (a, b)} for s, a, b in
                            [(1, 600.0, 900.0), (2, 300.0, 500.0), (3, 150.0, 250.0), (4, 80.0, 120.0),
                             (5, 40.0, 60.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> FogParams:
        cfg = self.config
        alpha = 0.0 if cfg.mor_range is None else float(np.log(20.0) / uniform(rng, cfg.mor_range))
        return FogParams(alpha=alpha, tau_h_ns=cfg.tau_h_ns, threshold=cfg.threshold,
                         detection_threshold=cfg.detection_threshold,
                         intensity_scale=_scale(cfg.intensity_scale, sample), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: FogParams) -> Scene:
        cloud = sample.points
        if params.is_identity() or len(cloud) == 0:
            return sample
        alpha, scale = params.alpha, params.intensity_scale
        beta = FOG_BACKSCATTER_PER_MOR * alpha / np.log(20.0)
        r0_grid, integral, distance = _cached_fog_soft_response(alpha, params.tau_h_ns * 1e-9)

        gain = beta * np.pi / FOG_REFERENCE_REFLECTIVITY * (2.0 / SPEED_OF_LIGHT)
        n = len(cloud)
        # The per-point arrays are this thread's scratch arrays (see _rescaled), never returned.
        draws = power_draws(params.seed, n, out=scratch("weather.draws", n))
        ranges, fog_range = scratch("weather.ranges", n), scratch("weather.fog_range", n)
        intensity = scratch("weather.intensity", n)
        in_fog, keep = scratch("weather.in_fog", n, bool), scratch("weather.keep", n, bool)
        unattenuated = True  # every hard return keeps its power (no extinction at all)
        # One pass, block by block (see _BLOCK): the same float64 arithmetic per point as over the
        # whole cloud at once, so the same bytes.
        for block in _blocks(n):
            rows = cloud.data[block]
            r = ranges[block] = _block_ranges(rows)
            power = np.clip(rows[:, 3].astype(np.float64) / scale, 0.0, None)  # clear-weather power, full scale 1
            transmittance = np.exp(-2.0 * alpha * r)
            hard = power * transmittance
            soft_integral, fog_range[block] = _interp_near(r, r0_grid, (integral, distance))
            soft = np.minimum(power * r**2 * gain * soft_integral, 1.0)
            fog = in_fog[block] = (soft > hard) & (soft > params.threshold) & (fog_range[block] < r)
            # Every point of the frame was detected in clear weather: it is lost only when the fog's
            # extinction outweighs its power margin.
            margin = power_margin(rows[:, 3], r, scale=scale, detection_threshold=params.detection_threshold,
                                  draws=draws[block])
            keep[block] = fog | (margin * transmittance >= 1.0)
            unattenuated = unattenuated and np.array_equal(hard, power)
            intensity[block] = np.where(fog, soft, hard) * scale
        if not in_fog.any() and keep.all() and unattenuated:
            return sample
        rng = np.random.default_rng(params.seed)
        new_range = scratch("weather.new_range", n)
        np.copyto(new_range, ranges)
        new_range[in_fog] = np.minimum(fog_range[in_fog] + FOG_RETURN_JITTER * rng.beta(2.0, 20.0, int(in_fog.sum())),
                                       ranges[in_fog])
        return sample.with_points(_rescaled(cloud, keep, ranges, new_range, intensity, in_fog))


# =========================================================================== rain and snow
#: Fresnel reflectance at normal incidence, |(n − 1)/(n + 1)|², of water (n = 1.328) and ice (1.3031).
WATER_REFLECTANCE = ((1.328 - 1) / (1.328 + 1)) ** 2
ICE_REFLECTANCE = ((1.3031 - 1) / (1.3031 + 1)) ** 2
#: Smallest particle diameter drawn, mm (LISA).
MIN_DIAMETER = 0.05
#: Particles farther than this cannot outshine the threshold (diameter needed ∝ r²), metres.
_PARTICLE_REACH = 40.0
#: Range step of the expected-count table, metres, and its nodes per decade of the bar.
_TABLE_RANGE_STEP = 0.05
_TABLE_NODES_PER_DECADE = 40
#: Gauss–Legendre nodes and weights on [0, 1] for each cell of the table (3 points: exact for
#: polynomials of degree 5; the nodes are within 10⁻⁵ of the integral even in the cells where
#: d_need reaches D_min and the integrand has a kink, far under the interpolation error).
_GAUSS_NODES = (1.0 + np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)])) / 2.0
_GAUSS_WEIGHTS = np.array([5.0, 8.0, 5.0]) / 18.0


@dataclass(frozen=True)
class ParticleTable:
    """The expected number of particles able to outshine a beam's bar, tabulated once per rain
    (or snow) configuration.

    For a beam whose return must beat the power ``bar`` (the attenuated hard return, at least the
    receiver threshold), the particles that can win form a thinned Poisson process along the beam
    with density ``ν(r; bar) = (π θ²/4) (N₀/Λ) r² exp(−Λ d_need(r))`` per metre, where
    ``d_need = max(10³ θ r √min(need, 1), D_min)`` mm and ``need = (bar/ρ_p) r² exp(2αr)``, and
    none where ``need ≥ 1`` (beyond ``r_max(bar)``, no drop covering the beam is bright enough).
    ``counts[i, j]`` is ``∫ ν dr`` from ``min_range`` to ``ranges[j]`` for ``bar = exp(log_bars[i])``,
    each cell integrated by 3-point Gauss–Legendre up to the cut-off ``r_max``; a beam reads its
    expected count by bilinear interpolation in (ln bar, reach). The lowest row is the receiver
    threshold (no bar is lower); beyond the highest row no particle can win at ``min_range``.

    Why a table: the integral used to be taken per point (28 nodes each, ten N × 28 float64
    temporaries a call, 80 % of the operator's time) although it depends on two numbers only.
    The table (about 93 × 771 nodes: 40 per decade of bar, 5 cm in range) costs ~0.6 ms to build
    and is cached per configuration. Its error is bounded in ``tests/operators/test_weather_fast.py``
    (linear interpolation of a cumulative integral is off by at most h·osc(ν)/4 per direction):
    within 0.1 % of the exact frame total, and the drawn set of affected points within 1 % (total
    variation) of the law the exact integral gives — closer than the old 28-node quadrature, which
    was 0.5-1.5 % off the exact total.
    """

    log_bars: F64
    ranges: F64
    counts: F64
    alpha: float
    particle_reflectance: float

    @property
    def log_bar_step(self) -> float:
        return float(self.log_bars[1] - self.log_bars[0])

    def locate(self, bar: F64, reach: F64) -> tuple[NDArray[np.intp], F64, F64]:
        """(flat index of the lower-left table node, weight along ln bar, weight along the range)."""
        n_bars, n_ranges = self.counts.shape
        x = (np.log(bar) - self.log_bars[0]) * (1.0 / self.log_bar_step)
        np.clip(x, 0.0, n_bars - 1.0, out=x)
        y = (reach - self.ranges[0]) * (1.0 / _TABLE_RANGE_STEP)
        np.clip(y, 0.0, n_ranges - 1.0, out=y)
        i = np.minimum(x.astype(np.intp), n_bars - 2)
        j = np.minimum(y.astype(np.intp), n_ranges - 2)
        x -= i
        y -= j
        i *= n_ranges
        i += j
        return i, x, y

    def expected(self, bar: F64, reach: F64) -> F64:
        """The expected count of winning particles of each beam (bilinear in ln bar and reach)."""
        flat, wx, wy = self.locate(bar, reach)
        table = self.counts.ravel()
        n_ranges = self.counts.shape[1]
        low = table[flat]
        low += (table[flat + 1] - low) * wy
        high = table[flat + n_ranges]
        high += (table[flat + n_ranges + 1] - high) * wy
        high -= low
        high *= wx
        low += high
        return low

    def draw_ranges(self, bar: F64, reach: F64, u: F64) -> F64:
        """Ranges of particles on beams (``bar``, ``reach``), one per uniform ``u`` in [0, 1): the
        inverse of the beam's cumulative count (interpolated in ln bar, linear within a cell, i.e.
        uniform density within a cell, as the integral's quadrature assumed before)."""
        flat, wx, _ = self.locate(bar, reach)
        n_ranges = self.counts.shape[1]
        row = flat - flat % n_ranges
        top = self.counts.ravel()

        def cumulative(k: NDArray[np.intp]) -> F64:
            return (1.0 - wx) * top[row + k] + wx * top[row + n_ranges + k]

        target = u * self.expected(bar, reach)
        # Binary search for the first node whose cumulative count reaches the target.
        low = np.zeros(len(u), np.intp)
        high = flat % n_ranges + 1
        while True:
            active = low < high
            if not active.any():
                break
            mid = (low + high) // 2
            below = cumulative(mid) < target
            low = np.where(active & below, mid + 1, low)
            high = np.where(active & ~below, mid, high)
        k = np.clip(low, 1, n_ranges - 1)
        start, end = cumulative(k - 1), cumulative(k)
        fraction = np.clip(np.divide(target - start, end - start, out=np.zeros(len(u)), where=end > start), 0.0, 1.0)
        # The count lies before the beam's cut-off: the cell it cuts is spread up to it, and what
        # the interpolation between two bars puts beyond it (within the table's error) is drawn
        # just before it — a particle past r_max could not outshine the bar it was drawn to beat.
        r_max = cutoff_range(bar, self.alpha, self.particle_reflectance) * (1.0 - 1e-12)
        cell_start = self.ranges[k - 1]
        cell_end = np.minimum(cell_start + _TABLE_RANGE_STEP, np.maximum(r_max, cell_start))
        return np.minimum(np.minimum(cell_start + fraction * (cell_end - cell_start), reach), r_max)


def cutoff_range(bar: F64, alpha: float, rho_p: float) -> F64:
    """``r_max(bar)``: where ``(bar/ρ_p) r² exp(2αr) = 1``, i.e. ``r e^{αr} = √(ρ_p/bar)``
    (Newton from the α = 0 solution, which overshoots: the iteration is monotone)."""
    target = np.sqrt(rho_p / bar)
    r = target.copy()
    for _ in range(50):
        g = r * np.exp(alpha * r)
        step = (g - target) / (np.exp(alpha * r) * (1.0 + alpha * r))
        r = r - step
        if np.all(np.abs(step) <= 1e-12 * r):
            break
    return r


@lru_cache(maxsize=16)
def particle_table(n0: float, lam: float, alpha: float, rho_p: float, theta: float, min_range: float,
                   p_min: float) -> ParticleTable | None:
    """The :class:`ParticleTable` of one configuration, or None where no particle can win
    (everything beyond reach or the blind zone). Kept for a replay, a shrink or a fixed rate; a
    campaign draws each frame's rate from its severity's range, so most calls build one (~0.6 ms)."""
    end = max(_PARTICLE_REACH, min_range)
    # Beyond this bar not even a drop at the blind zone's edge covering the whole beam wins.
    edge = max(min_range, _TABLE_RANGE_STEP)
    bar_high = rho_p / (edge * edge * np.exp(2.0 * alpha * edge))
    if end <= min_range or bar_high <= p_min:
        return None
    decades = np.log10(bar_high / p_min)
    n_bars = max(int(np.ceil(decades * _TABLE_NODES_PER_DECADE)) + 1, 2)
    log_bars = np.linspace(np.log(p_min), np.log(bar_high), n_bars)
    n_ranges = int(np.ceil((end - min_range) / _TABLE_RANGE_STEP)) + 1
    ranges = min_range + np.arange(n_ranges, dtype=np.float64) * _TABLE_RANGE_STEP
    bars = np.exp(log_bars)
    r_max = cutoff_range(bars, alpha, rho_p)
    # Inside the cut-off d_need = max(√(bar/ρ_p) · 10³ θ r² e^{αr}, D_min): an outer product of a
    # factor per bar and one per range, so a cell costs one exponential per Gauss node. Only the
    # cells wholly inside their bar's cut-off are integrated here — a prefix of each row, 16 % of
    # the table (the rest held exponentials, most underflowing, that were then zeroed): gathered
    # into one contiguous array, the same elementwise operations give the same bits at a sixth
    # of the cost (an exponential of a contiguous array does not depend on its neighbours).
    root = np.sqrt(bars / rho_p)
    left = ranges[:-1]
    n_full = np.searchsorted(ranges[1:], r_max, side="right")  # cell j of row i is full ⇔ ranges[j+1] ≤ r_max[i]
    starts = np.cumsum(n_full) - n_full
    row = np.repeat(np.arange(n_bars), n_full)
    col = np.arange(len(row)) - np.repeat(starts, n_full)
    full_cells = np.zeros(len(row))
    for node, weight in zip(_GAUSS_NODES, _GAUSS_WEIGHTS, strict=True):
        r = left + node * _TABLE_RANGE_STEP
        d_need = np.maximum(root[row] * (1e3 * theta * r * r * np.exp(alpha * r))[col], MIN_DIAMETER)
        full_cells += ((weight * _TABLE_RANGE_STEP) * (r * r))[col] * np.exp(-lam * d_need)
    # No particle wins beyond the cut-off: cells past it hold nothing, the one it cuts only its part.
    cells = np.zeros((n_bars, n_ranges - 1))
    cells.ravel()[row * (n_ranges - 1) + col] = full_cells
    partial_row = np.flatnonzero((r_max > ranges[0]) & (r_max < ranges[-1]))
    partial_col = np.searchsorted(ranges, r_max[partial_row], side="right") - 1  # ranges[col] ≤ r_max < ranges[col+1]
    start = left[partial_col]
    width = np.maximum(r_max[partial_row] - start, 0.0)
    partial = np.zeros(len(partial_row))
    for node, weight in zip(_GAUSS_NODES, _GAUSS_WEIGHTS, strict=True):
        r = start + node * width
        d_need = np.maximum(root[partial_row] * 1e3 * theta * r * r * np.exp(alpha * r), MIN_DIAMETER)
        partial += weight * width * r * r * np.exp(-lam * d_need)
    cells[partial_row, partial_col] = partial
    cells *= np.pi * theta**2 / 4.0 * n0 / lam
    counts = np.zeros((n_bars, n_ranges))
    np.cumsum(cells, axis=1, out=counts[:, 1:])
    counts.flags.writeable = False  # shared through the cache
    return ParticleTable(log_bars, ranges, counts, alpha, rho_p)


class PrecipitationConfig(Config):
    rate_range: NonNegativeRange = Field((5.0, 5.0), description="precipitation rate (water equivalent), mm/h")
    beam_divergence: float = Field(3e-3, gt=0, description="full beam divergence, rad (LISA)")
    min_range: float = Field(1.5, ge=0, description="blind zone of the bistatic optics, metres: no particle returns")
    detection_threshold: float = _detection_threshold()
    range_accuracy: float = Field(0.04, ge=0, description="range error at the threshold's SNR, metres (LISA's dR)")
    intensity_scale: float | None = Field(None, gt=0, description="intensity of reflectivity 1; None: the frame's "
                                          "declared scale, else inferred")


class PrecipitationParams(Params):
    rate: float = Field(ge=0, description="mm/h, water equivalent")
    beam_divergence: float = Field(gt=0)
    min_range: float = Field(ge=0)
    detection_threshold: float = Field(gt=0)
    range_accuracy: float = Field(ge=0)
    intensity_scale: float = Field(gt=0)
    seed: int

    def is_identity(self) -> bool:
        return self.rate == 0


class _Precipitation(Operator[Scene, PrecipitationConfig, PrecipitationParams]):
    """Shared LISA machinery; subclasses give the particle size distribution and reflectance."""

    family = "weather"
    relation = Relation.DEGRADING
    targets = POINTS
    ConfigModel = PrecipitationConfig
    ParamsModel = PrecipitationParams
    IDENTITY: ClassVar = {"rate_range": (0.0, 0.0)}
    particle_reflectance: ClassVar[float]

    @staticmethod
    def distribution(rate: float) -> tuple[float, float]:
        """(N₀ in m⁻³ mm⁻¹, Λ in mm⁻¹) of ``N(D) = N₀ exp(−Λ D)``."""
        raise NotImplementedError

    @classmethod
    def extinction(cls, rate: float) -> float:
        """α in 1/m: ``(π/4) ∫ Q_ext D² N(D) dD`` with the large-drop limit ``Q_ext = 2`` (D ≫ λ)."""
        if rate <= 0:
            return 0.0
        n0, lam = cls.distribution(rate)
        d = MIN_DIAMETER
        moment = np.exp(-lam * d) * (d**2 / lam + 2 * d / lam**2 + 2 / lam**3)  # ∫_d^∞ D² e^{−ΛD} dD, mm³
        return float(np.pi / 4 * 2.0 * n0 * moment * 1e-6)

    def sample(self, rng: np.random.Generator, sample: Scene) -> PrecipitationParams:
        cfg = self.config
        return PrecipitationParams(rate=uniform(rng, cfg.rate_range), beam_divergence=cfg.beam_divergence,
                                   min_range=cfg.min_range, detection_threshold=cfg.detection_threshold,
                                   range_accuracy=cfg.range_accuracy,
                                   intensity_scale=_scale(cfg.intensity_scale, sample), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: PrecipitationParams) -> Scene:
        cloud = sample.points
        if params.is_identity() or len(cloud) == 0:
            return sample
        rng = np.random.default_rng(params.seed)
        n0, lam = self.distribution(params.rate)
        alpha = self.extinction(params.rate)
        rho_p = self.particle_reflectance
        theta = float(np.tan(params.beam_divergence))
        p_min = params.detection_threshold / 100.0**2
        n = len(cloud)

        table = particle_table(n0, lam, alpha, rho_p, theta, params.min_range, p_min)
        # The per-point arrays are this thread's scratch arrays (see _rescaled), never returned.
        draws = power_draws(params.seed, n, out=scratch("weather.draws", n))
        ranges, bar, reach = scratch("weather.ranges", n), scratch("weather.bar", n), scratch("weather.reach", n)
        expected = scratch("weather.expected", n)
        expected.fill(0.0)
        intensity, sigma = scratch("weather.intensity", n), scratch("weather.sigma", n)
        lost = scratch("weather.lost", n, bool)
        noise_scale = params.range_accuracy**2 * p_min / 2.0
        # One pass, block by block (see _BLOCK), over everything a point needs before the draws.
        for block in _blocks(n):
            rows = cloud.data[block]
            r = ranges[block] = _block_ranges(rows)
            # Every point of the frame was detected: its clear-weather signal (ρ_e / r², the units
            # of p_min) is its power margin times the threshold.
            clear = power_margin(rows[:, 3], r, scale=params.intensity_scale,
                                 detection_threshold=params.detection_threshold, draws=draws[block])
            clear *= p_min
            transmittance = np.exp(r * (-2.0 * alpha))
            hard = clear * transmittance
            lost[block] = hard < p_min
            b = bar[block] = np.maximum(hard, p_min)  # what a particle's return must beat
            np.multiply(rows[:, 3], transmittance, out=intensity[block])
            # Extra range noise from the weaker signal: σ² = dR² (1/(2 SNR) − 1/(2 SNR_clear)), SNR = P/P_min.
            s = np.reciprocal(np.maximum(hard, _TINY, out=hard), out=hard)  # finite noise where hard underflows
            s -= np.reciprocal(clear, out=clear)
            np.maximum(s, 0.0, out=s)
            s *= noise_scale
            s[lost[block]] = 0.0  # a lost return gets no noise
            np.sqrt(s, out=sigma[block])
            if table is not None:
                # Particles that can beat the bar form a thinned Poisson process along each beam
                # (see ParticleTable): its expected count is read from the configuration's table.
                np.minimum(r, _PARTICLE_REACH, out=reach[block])
                np.maximum(reach[block], params.min_range, out=reach[block])
                expected[block] = table.expected(b, reach[block])

        scattered = scratch("weather.scattered", n, bool)
        scattered.fill(False)
        new_range = scratch("weather.new_range", n)
        np.copyto(new_range, ranges)
        # Independent Poisson counts per beam, drawn as one Poisson total spread over the beams in
        # proportion to their expectations: the same distribution, without N Poisson draws.
        cumulative = np.cumsum(expected, out=scratch("weather.cumulative", n))
        total = float(cumulative[-1])
        count = int(rng.poisson(total)) if table is not None and total > 0 else 0
        if table is not None and count:
            owner = np.minimum(np.searchsorted(cumulative, rng.random(count) * total, side="right"), n - 1)
            r_p = table.draw_ranges(bar[owner], reach[owner], rng.random(count))
            need_p = bar[owner] * r_p**2 * np.exp(2.0 * alpha * r_p) / rho_p
            d_min = np.maximum(1e3 * theta * r_p * np.sqrt(np.minimum(need_p, 1.0)), MIN_DIAMETER)
            diameter = d_min + rng.exponential(1.0 / lam, count)  # memoryless tail of N(D)
            echo = rho_p * np.exp(-2.0 * alpha * r_p) * np.minimum((diameter / (1e3 * theta * r_p)) ** 2, 1.0)
            power = echo / r_p**2
            order = np.lexsort((-power, owner))  # strongest particle of each beam first
            first = np.ones(len(order), bool)
            first[1:] = owner[order][1:] != owner[order][:-1]
            best = order[first]
            best = best[power[best] > bar[owner[best]]]
            winner = owner[best]
            scattered[winner] = True
            new_range[winner] = r_p[best]
            intensity[winner] = echo[best] * params.intensity_scale
            sigma[winner] = 0.0  # a particle's return is not the hard return: no extra noise
            lost[winner] = False

        if params.range_accuracy > 0:
            # One normal draw per point (those that get no noise have σ = 0), block by block from
            # one stream: the same draws as one call for all points.
            noise = np.empty(min(n, _BLOCK))
            for block in _blocks(n):
                z = rng.standard_normal(out=noise[: block.stop - block.start])
                z *= sigma[block]
                new_range[block] += z
        kept = np.logical_not(lost, out=scratch("weather.keep", n, bool))
        return sample.with_points(_rescaled(cloud, kept, ranges, new_range, intensity, scattered))


class Rain(_Precipitation):
    """Rain after LISA (Kilic et al., "Lidar Light Scattering Augmentation", 2021).

    Drops follow the Marshall–Palmer distribution ``N(D) = 8000 exp(−4.1 R^−0.21 D)`` m⁻³ mm⁻¹
    (R in mm/h); extinction ``α = (π/4) ∫ 2 D² N(D) dD`` attenuates every return by
    ``exp(−2 α r)``. A drop in the beam's cone returns the Fresnel reflectance of water scaled by
    the share of the beam it covers, ``min(D / D_b, 1)²``, over ``r²``. Per beam, the drops able
    to outshine the (attenuated) hard return and the receiver threshold are drawn at once from
    their Poisson statistics over the beam's cone — not one by one — and the strongest one
    replaces the hard return (a spurious near return, low intensity, label 0). A hard return
    whose attenuated signal falls below the threshold, with no drop in its place, is lost; the
    rest get the extra range noise of their lower SNR. A hard return's clear-weather signal is its
    power margin (:func:`~lidarfuzz.operators.lidar.power.power_margin`: every frame point was
    detected; ``intensity / intensity_scale`` is its effective reflectivity where the reading
    resolves it, a seeded draw over what the detection admits where it does not — zeros, for one)
    times the receiver threshold, ``detection_threshold`` (default the HDL-64E's: reflectivity 0.4
    at 100 m, i.e. 10 % at 50 m). LISA instead gives every return without a usable reflectivity 4/3
    of the threshold, so all of them at a range share one fate: none is lost, then all are.

    Severity (rain rate): 1: 0.5 mm/h (drizzle), 2: 2 (light), 3: 5 (moderate), 4: 15 (heavy),
    5: 40 mm/h (violent), each ±20 %. Points are moved, re-intensified or removed; the rest of
    the scene is kept.
    """

    name = "rain"
    particle_reflectance = WATER_REFLECTANCE
    harmless_up_to = 1
    harmless_because = "drizzle (0.4-0.6 mm/h) scatters a few returns; an object they crowd is not checked"
    SEVERITIES: ClassVar = {s: {"rate_range": (0.8 * v, 1.2 * v)} for s, v in
                            [(1, 0.5), (2, 2.0), (3, 5.0), (4, 15.0), (5, 40.0)]}

    @staticmethod
    def distribution(rate: float) -> tuple[float, float]:
        return 8000.0, 4.1 * rate**-0.21


class Snow(_Precipitation):
    """Snowfall after LISA (Kilic et al. 2021) and Hahner et al., "LiDAR Snowfall Simulation for
    Robust 3D Object Detection" (CVPR 2022), which parameterises snowfall by its water-equivalent
    rate and draws flakes from the Gunn–Marshall distribution.

    The same model as :class:`Rain`, with Gunn–Marshall flakes ``N(D) = 7600 R^−0.87
    exp(−2.55 R^−0.48 D)`` m⁻³ mm⁻¹ (R the water-equivalent rate, mm/h) and the Fresnel
    reflectance of ice. At equal water-equivalent rate snow has far more large particles than
    rain (Λ is about half), so it extinguishes more and gives more near clutter.

    Severity (water-equivalent rate): 1: 0.2 mm/h (light), 2: 0.5, 3: 1 (moderate), 4: 2 (heavy),
    5: 4 mm/h (very heavy), each ±20 %. Points are moved, re-intensified or removed.
    """

    name = "snow"
    particle_reflectance = ICE_REFLECTANCE
    harmless_up_to = 1
    harmless_because = "light snow (0.16-0.24 mm/h) scatters a few returns; an object they crowd is not checked"
    SEVERITIES: ClassVar = {s: {"rate_range": (0.8 * v, 1.2 * v)} for s, v in
                            [(1, 0.2), (2, 0.5), (3, 1.0), (4, 2.0), (5, 4.0)]}

    @staticmethod
    def distribution(rate: float) -> tuple[float, float]:
        return 7600.0 * rate**-0.87, 2.55 * rate**-0.48


# =========================================================================== wet ground

WATER_INDEX = 1.33


def _fresnel(cos_i: NDArray[np.floating], n: float = WATER_INDEX) -> NDArray[np.floating]:
    """Unpolarised Fresnel reflectance of an air–water surface at incidence cos θ."""
    cos_i = np.clip(cos_i, 1e-6, 1.0)
    sin_t = np.sqrt(1.0 - cos_i**2) / n
    cos_t = np.sqrt(1.0 - sin_t**2)
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return 0.5 * (rs**2 + rp**2)


def ground_plane(xyz: F64) -> tuple[F64, float]:
    """(unit normal, offset) of a robust ground plane ``n · p = d``: least squares on the lowest
    30 % of (an evenly strided subsample of at most ~8000 of) the points, refitted twice on the
    points within 0.2 m of the previous fit."""
    xyz = xyz[:: max(1, len(xyz) // 4000)]  # a deterministic subsample is plenty for three parameters
    # (rows picked by np.compress: the same rows as a boolean index, ~3× faster)
    candidates = np.compress(xyz[:, 2] <= np.percentile(xyz[:, 2], 30), xyz, axis=0)
    for _ in range(3):
        design = np.column_stack([candidates[:, 0], candidates[:, 1], np.ones(len(candidates))])
        (a, b, c), *_ = np.linalg.lstsq(design, candidates[:, 2], rcond=None)
        residual = xyz[:, 2] - (a * xyz[:, 0] + b * xyz[:, 1] + c)
        inliers = np.abs(residual) < 0.2
        if np.count_nonzero(inliers) < 3:
            break
        candidates = np.compress(inliers, xyz, axis=0)
    normal = np.array([-a, -b, 1.0]) / np.sqrt(a * a + b * b + 1.0)
    return normal, float(c / np.sqrt(a * a + b * b + 1.0))


def _ground(cloud: PointCloud) -> tuple[NDArray[np.intp], F64]:
    """(indices of the ground points, the ground plane's unit normal)."""
    if cloud.has("label"):
        ids = np.array([SEMANTIC_ID[name] for name in GROUND_CLASSES], np.float32)
        index = np.flatnonzero(np.isin(cloud.channel("label"), ids))
        if len(index) < 3:
            return index, np.array([0.0, 0.0, 1.0])
        normal, _ = ground_plane(cloud.xyz[index[:: max(1, len(index) // 4000)]].astype(np.float64))
        return index, normal
    xyz = cloud.xyz
    normal, offset = ground_plane(xyz.astype(np.float64))
    return np.flatnonzero(np.abs(xyz @ normal.astype(np.float32) - np.float32(offset)) < 0.2), normal


def ground_mask(cloud: PointCloud) -> NDArray[np.bool_]:
    """Ground points: by ``label`` when the cloud has it, else within 0.2 m of :func:`ground_plane`."""
    mask = np.zeros(len(cloud), bool)
    if len(cloud):
        mask[_ground(cloud)[0]] = True
    return mask


class WetGroundConfig(Config):
    wetness_range: ShareRange = Field((0.5, 0.5), description="share of the ground under a continuous water film, 0–1")
    detection_threshold: float = _detection_threshold()
    intensity_scale: float | None = Field(None, gt=0, description="intensity of reflectivity 1; None: the frame's "
                                          "declared scale, else inferred")


class WetGroundParams(Params):
    wetness: float = Field(ge=0, le=1)
    detection_threshold: float = Field(gt=0)
    intensity_scale: float = Field(gt=0)
    seed: int = Field(0, description="draws of the reflectivities the readings leave open")

    def is_identity(self) -> bool:
        return self.wetness == 0


class WetGround(Operator[Scene, WetGroundConfig, WetGroundParams]):
    """A wet road: a water film turns the ground partly into a mirror.

    On the wetted share ``w`` of the ground, the beam crosses the air–water surface twice
    (Fresnel transmittance ``(1 − F(θ))²`` at the incidence θ on the ground plane, so grazing
    beams — far ground — lose most), and the diffuse light under the film is partly trapped
    by total internal reflection, darkening the surface (Lekner & Dorf 1988:
    ``ρ_wet = ρ e / (1 − ρ (1 − e))``, escape share ``e = 0.93 / n²``, n = 1.33). Intensity
    becomes ``(1 − w) I + w I_wet``, i.e. it is multiplied by the film's factor ``f``; a ground
    return drops out when ``m · f < 1``, ``m`` its clear-weather power margin over the receiver
    threshold (:func:`~lidarfuzz.operators.lidar.power.power_margin`: the reading as effective
    reflectivity where it resolves it, a seeded draw over what the detection admits where it does
    not — a zero reading is a detected return, not a return without power; ``detection_threshold``
    defaults to the HDL-64E's, reflectivity 0.4 at 100 m). So dark and far ground goes first, and
    the share lost grows smoothly with the wetness.

    Ground points: the ``label`` channel (road, lane-marking, sidewalk, other-ground, terrain)
    when present, else points within 0.2 m of a robust least-squares ground plane. Incidence is
    taken on the fitted ground plane. Non-ground points, boxes and everything else are untouched.

    Severity (wetness): 1: 0.2, 2: 0.4, 3: 0.6, 4: 0.8, 5: 1.0 (flooded), each ±0.05.
    """

    name = "wet_ground"
    family = "weather"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "a damp road (wetness 0.15-0.25) darkens the ground, not the objects"
    targets = POINTS
    ConfigModel = WetGroundConfig
    ParamsModel = WetGroundParams
    IDENTITY: ClassVar = {"wetness_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"wetness_range": (w - 0.05, min(w + 0.05, 1.0))} for s, w in
                            [(1, 0.2), (2, 0.4), (3, 0.6), (4, 0.8), (5, 1.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> WetGroundParams:
        cfg = self.config
        return WetGroundParams(wetness=uniform(rng, cfg.wetness_range), detection_threshold=cfg.detection_threshold,
                               intensity_scale=_scale(cfg.intensity_scale, sample), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: WetGroundParams) -> Scene:
        cloud = sample.points
        if params.is_identity() or len(cloud) == 0:
            return sample
        index, normal = _ground(cloud)
        if len(index) == 0:
            return sample
        wet, lost = _wet_ground_rows(cloud.data, index, normal, params)
        # One copy of the kept rows; only the ground rows' intensity is then written.
        kept = np.flatnonzero(~lost)
        if len(kept) < len(index):
            keep = np.ones(len(cloud), bool)
            keep[index[lost]] = False
            data = np.compress(keep, cloud.data, axis=0)  # ~3× faster than cloud.data[keep], same bytes
            # Every dropped row is a ground row: the j-th kept ground row, ground row i, moves up by
            # the i − j lost ground rows before it (in place; written through the one-dimensional
            # intensity column, faster than the two-index form).
            rows = index[kept]
            rows -= kept
            rows += np.arange(len(kept))
            data[:, 3][rows] = wet[kept]
        else:
            data = cloud.data.copy()
            data[index, 3] = wet
        return sample.with_points(PointCloud(data, cloud.channels))


#: Ground rows per block of :func:`_wet_ground_rows`: its float64 temporaries (128 KiB each) are
#: reused from the heap; full-length ones made the heap peak high enough that the allocator gave
#: it back after each call and the next call faulted ~2,600 fresh pages in (2–3.6 ms of system
#: time a frame). Larger blocks cost more (numpy calls are few either way; the cache is not).
_GROUND_BLOCK = 16384


def _wet_ground_rows(data: NDArray[np.float32], index: NDArray[np.intp], normal: F64,
                     params: WetGroundParams) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """(new intensity, lost) of the ground rows ``data[index]``, block by block: every quantity is
    per point, so each block gives the bytes the whole-array expressions gave, and the power
    draws are read from their stream block after block (the same numbers as one draw of all)."""
    n = len(index)
    wet = np.empty(n, np.float32)
    lost = np.empty(n, bool)
    nx, ny, nz = normal.astype(np.float32)
    escape = 0.93 / WATER_INDEX**2
    stream = power_draw_stream(params.seed)
    buffer = np.empty((min(_GROUND_BLOCK, n), data.shape[1]), np.float32)
    for start in range(0, n, _GROUND_BLOCK):
        block = slice(start, min(start + _GROUND_BLOCK, n))
        # contiguous rows: ~8× faster than indexing the strided xyz view ('clip': no bounds-check copy)
        rows = np.take(data, index[block], axis=0, out=buffer[:block.stop - start], mode="clip")
        x, y, z = rows[:, 0], rows[:, 1], rows[:, 2]
        ranges = np.maximum(np.sqrt(x * x + y * y + z * z), np.float32(1e-6))
        cos_i = np.abs(x * nx + y * ny + z * nz) / ranges
        rho, floor = effective_reflectivity(rows[:, 3], ranges, scale=params.intensity_scale,
                                            detection_threshold=params.detection_threshold,
                                            draws=stream.random(block.stop - start))
        darkening = escape / (1.0 - np.minimum(rho, 1.0) * (1.0 - escape))
        factor = (1.0 - params.wetness) + params.wetness * (1.0 - _fresnel(cos_i)) ** 2 * darkening
        np.multiply(rows[:, 3], factor.astype(np.float32), out=wet[block])  # the ground's new intensities
        np.less(rho * factor, floor, out=lost[block])  # margin ρ_e / ρ_det times the film's factor under 1
    return wet, lost


__all__ = ["Fog", "Rain", "Snow", "WetGround", "fog_soft_response", "ground_mask", "infer_intensity_scale"]
