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
from lidarfuzz.operators.lidar.common import intensity_scale, scene_intensity_scale
from lidarfuzz.operators.lidar.power import (
    HDL64E_DETECTION_THRESHOLD,
    effective_reflectivity,
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
    xyz = cloud.xyz
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    return np.sqrt((x * x + y * y + z * z).astype(np.float64))


def _rescaled(cloud: PointCloud, keep: NDArray[np.bool_], ranges: F64, new_range: F64, intensity: F64,
              in_air: NDArray[np.bool_]) -> PointCloud:
    """The kept points, each moved along its own beam to ``new_range`` and given a new intensity;
    points whose return now comes from the air lose their label and instance. One float32 copy
    of the kept rows; only the points whose range changed are rescaled (in float64)."""
    rows = np.flatnonzero(keep)
    data = cloud.data[rows]
    moved = np.flatnonzero(new_range[rows] != ranges[rows])
    if len(moved):
        source = rows[moved]
        factor = np.divide(new_range[source], ranges[source], out=np.ones(len(source)), where=ranges[source] > 0)
        data[moved, :3] = data[moved, :3] * factor[:, None]
    data[:, 3] = intensity[rows]
    air = np.flatnonzero(in_air[rows])
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
    lag = r[:, None] - r[None, :]  # R_j − r_k
    in_pulse = (lag >= 0) & (lag <= width)
    weights = np.where(in_pulse, np.sin(np.pi * np.clip(lag, 0, width) / width) ** 2, 0.0) * g[None, :] * step
    cumulative = np.cumsum(weights, axis=1)  # C[j, k]: fog up to r_k, seen at R_j
    j = np.arange(n)[:, None]
    m = np.arange(n_r0)[None, :]
    seen = cumulative[j, np.minimum(j, m)]  # fog only in front of the target: r ≤ R0
    best = np.argmax(seen, axis=0)
    integral = seen[best, np.arange(n_r0)]
    distance = np.maximum(r[best] - width / 2, r1)
    return r[:n_r0].astype(np.float64), np.asarray(integral, np.float64), np.asarray(distance, np.float64)


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
        r0_grid, integral, distance = fog_soft_response(alpha, params.tau_h_ns * 1e-9)

        ranges = _ranges(cloud)
        power = np.clip(cloud.intensity.astype(np.float64) / scale, 0.0, None)  # clear-weather power, full scale 1
        transmittance = np.exp(-2.0 * alpha * ranges)
        hard = power * transmittance
        gain = beta * np.pi / FOG_REFERENCE_REFLECTIVITY * (2.0 / SPEED_OF_LIGHT)
        soft = np.minimum(power * ranges**2 * gain * np.interp(ranges, r0_grid, integral), 1.0)
        fog_range = np.interp(ranges, r0_grid, distance)

        in_fog = (soft > hard) & (soft > params.threshold) & (fog_range < ranges)
        # Every point of the frame was detected in clear weather: it is lost only when the fog's
        # extinction outweighs its power margin.
        margin = power_margin(cloud.intensity, ranges, scale=scale, detection_threshold=params.detection_threshold,
                              draws=power_draws(params.seed, len(cloud)))
        keep = in_fog | (margin * transmittance >= 1.0)
        if not in_fog.any() and keep.all() and np.array_equal(hard, power):
            return sample
        rng = np.random.default_rng(params.seed)
        new_range = ranges.copy()
        new_range[in_fog] = np.minimum(fog_range[in_fog] + FOG_RETURN_JITTER * rng.beta(2.0, 20.0, int(in_fog.sum())),
                                       ranges[in_fog])
        intensity = np.where(in_fog, soft, hard) * scale
        return sample.with_points(_rescaled(cloud, keep, ranges, new_range, intensity, in_fog))


# =========================================================================== rain and snow
#: Fresnel reflectance at normal incidence, |(n − 1)/(n + 1)|², of water (n = 1.328) and ice (1.3031).
WATER_REFLECTANCE = ((1.328 - 1) / (1.328 + 1)) ** 2
ICE_REFLECTANCE = ((1.3031 - 1) / (1.3031 + 1)) ** 2
#: Smallest particle diameter drawn, mm (LISA).
MIN_DIAMETER = 0.05
#: Geometric nodes of the per-beam integral over the range of the winning particles.
_NODES = (np.geomspace(1.0, 41.0, 28) - 1.0) / 40.0
#: Particles farther than this cannot outshine the threshold (diameter needed ∝ r²), metres.
_PARTICLE_REACH = 40.0


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
        theta = np.tan(params.beam_divergence)
        p_min = params.detection_threshold / 100.0**2

        ranges = _ranges(cloud)
        # Every point of the frame was detected: its clear-weather signal (ρ_e / r², the units of
        # p_min) is its power margin times the threshold.
        clear = p_min * power_margin(cloud.intensity, ranges, scale=params.intensity_scale,
                                     detection_threshold=params.detection_threshold,
                                     draws=power_draws(params.seed, len(cloud)))
        hard = clear * np.exp(-2.0 * alpha * ranges)
        bar = np.maximum(hard, p_min)  # what a particle's return must beat

        # Particles that can beat the bar form a thinned Poisson process along each beam: at range r
        # a drop of diameter D returns ρ_p exp(−2αr) min(D/D_b, 1)² / r², D_b = θ r the beam's width.
        reach = np.clip(np.minimum(ranges, _PARTICLE_REACH), params.min_range, None)
        r = params.min_range + (reach - params.min_range)[:, None] * _NODES[None, :]  # N × K nodes
        r2 = r * r
        need = (bar / rho_p)[:, None] * r2 * np.exp((2.0 * alpha) * r)  # (D/D_b)² needed
        possible = need < 1.0
        d_need = np.maximum((1e3 * theta) * r * np.sqrt(np.minimum(need, 1.0)), MIN_DIAMETER)  # mm
        # Winners per metre: the beam's cross-section π (θ r / 2)² times the drops larger than d_need.
        density = (np.pi * theta**2 / 4.0 * n0 / lam) * r2 * np.exp(-lam * d_need)
        density[~possible] = 0.0
        steps = np.diff(r, axis=1)
        cells = 0.5 * (density[:, 1:] + density[:, :-1]) * steps
        expected = cells.sum(axis=1)
        count = rng.poisson(expected)

        scattered = np.zeros(len(cloud), bool)
        new_range = ranges.copy()
        intensity = cloud.intensity.astype(np.float64) * np.exp(-2.0 * alpha * ranges)
        beams = np.flatnonzero(count)
        if len(beams):
            owner = np.repeat(beams, count[beams])
            cdf = np.cumsum(cells[owner], axis=1)
            u = rng.random(len(owner)) * cdf[:, -1]
            cell = np.minimum((cdf < u[:, None]).sum(axis=1), cdf.shape[1] - 1)
            start = np.where(cell > 0, cdf[np.arange(len(owner)), cell - 1], 0.0)
            fraction = np.clip((u - start) / np.maximum(cells[owner, cell], 1e-300), 0.0, 1.0)
            r_p = r[owner, cell] + fraction * steps[owner, cell]
            need_p = bar[owner] * r_p**2 * np.exp(2.0 * alpha * r_p) / rho_p
            d_min = np.maximum(1e3 * theta * r_p * np.sqrt(np.minimum(need_p, 1.0)), MIN_DIAMETER)
            diameter = d_min + rng.exponential(1.0 / lam, len(owner))  # memoryless tail of N(D)
            echo = rho_p * np.exp(-2.0 * alpha * r_p) * np.minimum((diameter / (1e3 * theta * r_p)) ** 2, 1.0)
            power = echo / r_p**2
            order = np.lexsort((-power, owner))  # strongest particle of each beam first
            first = np.ones(len(order), bool)
            first[1:] = owner[order][1:] != owner[order][:-1]
            best = order[first]
            winner = owner[best][power[best] > bar[owner[best]]]
            best = best[power[best] > bar[owner[best]]]
            scattered[winner] = True
            new_range[winner] = r_p[best]
            intensity[winner] = echo[best] * params.intensity_scale

        lost = ~scattered & (hard < p_min)
        kept_hard = ~scattered & ~lost
        if params.range_accuracy > 0 and kept_hard.any():
            # Extra range noise from the weaker signal: σ² = dR² (1/(2 SNR) − 1/(2 SNR_clear)), SNR = P/P_min.
            var = params.range_accuracy**2 * p_min / 2.0 * (1.0 / hard[kept_hard] - 1.0 / clear[kept_hard])
            new_range[kept_hard] += rng.normal(0.0, 1.0, int(kept_hard.sum())) * np.sqrt(np.maximum(var, 0.0))
        return sample.with_points(_rescaled(cloud, ~lost, ranges, new_range, intensity, scattered))


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
    candidates = xyz[xyz[:, 2] <= np.percentile(xyz[:, 2], 30)]
    for _ in range(3):
        design = np.column_stack([candidates[:, 0], candidates[:, 1], np.ones(len(candidates))])
        (a, b, c), *_ = np.linalg.lstsq(design, candidates[:, 2], rcond=None)
        residual = xyz[:, 2] - (a * xyz[:, 0] + b * xyz[:, 1] + c)
        inliers = np.abs(residual) < 0.2
        if inliers.sum() < 3:
            break
        candidates = xyz[inliers]
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
        rows = np.take(cloud.data, index, axis=0)  # contiguous: ~8× faster than indexing the strided xyz view
        x, y, z = rows[:, 0], rows[:, 1], rows[:, 2]
        ranges = np.maximum(np.sqrt(x * x + y * y + z * z), np.float32(1e-6))
        nx, ny, nz = normal.astype(np.float32)
        cos_i = np.abs(x * nx + y * ny + z * nz) / ranges
        rho, floor = effective_reflectivity(rows[:, 3], ranges, scale=params.intensity_scale,
                                            detection_threshold=params.detection_threshold,
                                            draws=power_draws(params.seed, len(index)))
        escape = 0.93 / WATER_INDEX**2
        darkening = escape / (1.0 - np.minimum(rho, 1.0) * (1.0 - escape))
        factor = (1.0 - params.wetness) + params.wetness * (1.0 - _fresnel(cos_i)) ** 2 * darkening
        intensity = cloud.intensity.copy()
        intensity[index] *= factor.astype(np.float32)
        dropped = index[rho * factor < floor]  # margin ρ_e / ρ_det times the film's factor under 1
        if len(dropped):  # one copy of the kept rows
            keep = np.ones(len(cloud), bool)
            keep[dropped] = False
            data, intensity = cloud.data[keep], intensity[keep]
        else:
            data = cloud.data.copy()
        data[:, 3] = intensity
        return sample.with_points(PointCloud(data, cloud.channels))


__all__ = ["Fog", "Rain", "Snow", "WetGround", "fog_soft_response", "ground_mask", "infer_intensity_scale"]
