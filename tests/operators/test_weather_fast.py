"""Rain and snow read each beam's expected particle count from a table (issue 25): its error
against the integral it replaced, worked out and asserted, and what that error can change.

Before the table, :class:`~lidarfuzz.operators.lidar.weather.Rain` and ``Snow`` integrated, for
every point, the density of the particles able to outshine its return along its beam,

    E(bar, R) = ∫ ν(r; bar) dr over [min_range, R],
    ν = (π θ²/4) (N₀/Λ) r² exp(−Λ d_need(r)),  d_need = max(10³ θ r √need, D_min),
    need = (bar/ρ_p) r² exp(2αr),  ν = 0 where need ≥ 1,

with a 28-node trapezoid per point (:func:`old_expected`, the code as it was). The reference here
is that integrand (:func:`old_density`, the same code) integrated to convergence
(:func:`exact_expected`). The table holds E at the nodes of a grid in (ln bar, R) and
interpolates bilinearly. Its error at a beam, exactly decomposed, is

    Ẽ − E = (1 − w_x) e_R(x_i) + w_x e_R(x_i+1) + e_x + e_node,

* ``e_R``: linear interpolation along R of the cumulative integral F(R) = ∫ν on a cell
  [R_j, R_j + h_R]. With w = (R − R_j)/h_R, ``F(R) − L(R) = (1 − w) A − w B`` where A, B are the
  integrals of ν over the two parts of the cell, so ``|e_R| ≤ w (1 − w) h_R osc(ν) ≤ h_R osc(ν)/4``
  (osc: max − min over the cell): no smoothness needed, so it holds across the cut-off where ν
  drops to 0.
* ``e_x``: linear interpolation along x = ln bar of g(x) = E(e^x, R); the same argument on g'
  gives ``|e_x| ≤ w_x (1 − w_x) h_x osc(g')``, with g' computed exactly (the derivative of ν and
  the moving cut-off, :func:`exact_slope`) and its oscillation taken over 17 points of the cell.
* ``e_node``: the table's node values are 3-point Gauss–Legendre integrals of each 5 cm cell;
  checked against the reference to 10⁻⁵ (relative) here, and carried into the bound as such.

What the error can change: a beam is affected (its return replaced by a particle's) when at least
one particle is drawn on it, with probability 1 − exp(−E). |exp(−Ẽ) − exp(−E)| ≤ |Ẽ − E|, so the
total-variation distance between the laws of the set of affected points with the table and with
the exact integral is at most Σ|Ẽ − E| over the frame; :func:`test_affected_points_law_is_within_the_bound`
asserts it is under 1 % of the expected number of affected points, and the drawn count of affected
points matches the exact expectation within four standard errors plus that bias.

Linearity: no timing here (timed tests are not allowed; ``benchmarks/`` measures scaling). What is
asserted is the algorithm's shape: its peak memory grows by at most 256 bytes per point (the old
integral alone held ten N × 28 float64 temporaries, 2,240 bytes per point).
"""

from __future__ import annotations

import tracemalloc
from functools import cache
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.special import lambertw

from lidarfuzz.operators.lidar.common import release_scratch
from lidarfuzz.operators.lidar.power import power_draws, power_margin
from lidarfuzz.operators.lidar.weather import (
    _PARTICLE_REACH,
    MIN_DIAMETER,
    Fog,
    ParticleTable,
    Rain,
    Snow,
    WetGround,
    _Precipitation,
    particle_table,
)
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim.dataset import GenerationConfig, render_frames

F64 = NDArray[np.float64]
#: (operator, rate): the centres of severities 1 and 5 of rain and snow.
CONFIGS = [(Rain, 0.5), (Rain, 40.0), (Snow, 0.2), (Snow, 4.0)]
#: Relative error of a table node (3-point Gauss–Legendre per 5 cm cell) against the reference.
NODE_TOLERANCE = 1e-5
#: ... plus an absolute 1e-12 particles per beam (2·10⁻⁶ over 2M points: rounding at the cut-off
#: of the last row, where both sides are ~1e-20).
NODE_ABSOLUTE = 1e-12


@cache
def hdl64() -> Scene:
    """The HDL-64E simulator frame of the issue's measurements (106,938 points)."""
    return next(iter(render_frames(GenerationConfig(frames=1, seed=11))))


class Model:
    """One rain or snow configuration on the frame: its constants, each beam's bar and reach."""

    def __init__(self, cls: type[_Precipitation], rate: float) -> None:
        scene = hdl64()
        op = cls(rate_range=(rate, rate))
        self.op, self.params = op, op.sample(np.random.default_rng(0), scene)
        p = self.params
        self.n0, self.lam = cls.distribution(p.rate)
        self.alpha, self.rho = cls.extinction(p.rate), cls.particle_reflectance
        self.theta = float(np.tan(p.beam_divergence))
        self.m, self.p_min = p.min_range, p.detection_threshold / 100.0**2
        cloud = scene.points
        ranges = np.linalg.norm(cloud.xyz.astype(np.float64), axis=1)
        clear = self.p_min * power_margin(cloud.intensity, ranges, scale=p.intensity_scale,
                                          detection_threshold=p.detection_threshold,
                                          draws=power_draws(p.seed, len(cloud)))
        self.bar = np.maximum(clear * np.exp(-2.0 * self.alpha * ranges), self.p_min)
        self.reach = np.clip(np.minimum(ranges, _PARTICLE_REACH), self.m, None)
        table = particle_table(self.n0, self.lam, self.alpha, self.rho, self.theta, self.m, self.p_min)
        assert table is not None
        self.table: ParticleTable = table

    @property
    def constants(self) -> dict[str, float]:
        return {"n0": self.n0, "lam": self.lam, "alpha": self.alpha, "rho_p": self.rho, "theta": self.theta}


@cache
def model(cls: type[_Precipitation], rate: float) -> Model:
    return Model(cls, rate)


# --------------------------------------------------------------------------- the old computation
#: The old per-beam quadrature's nodes: geometric over [min_range, reach].
_NODES = (np.geomspace(1.0, 41.0, 28) - 1.0) / 40.0


def old_density(r: F64, bar: F64, *, n0: float, lam: float, alpha: float, rho_p: float, theta: float) -> F64:
    """ν(r; bar) for beams ``bar`` (N) at ranges ``r`` (N × K): the operator's code before the table."""
    r2 = r * r
    need = (bar / rho_p)[:, None] * r2 * np.exp((2.0 * alpha) * r)
    possible = need < 1.0
    d_need = np.maximum((1e3 * theta) * r * np.sqrt(np.minimum(need, 1.0)), MIN_DIAMETER)
    density = (np.pi * theta**2 / 4.0 * n0 / lam) * r2 * np.exp(-lam * d_need)
    density[~possible] = 0.0
    return density


def old_expected(bar: F64, reach: F64, m: float, **constants: float) -> F64:
    """The expected count as the operator computed it before: a 28-node trapezoid per beam."""
    r = m + (reach - m)[:, None] * _NODES[None, :]
    density = old_density(r, bar, **constants)
    return (0.5 * (density[:, 1:] + density[:, :-1]) * np.diff(r, axis=1)).sum(axis=1)


# --------------------------------------------------------------------------- the exact integral
_GL_T, _GL_W = np.polynomial.legendre.leggauss(8)


def _unit_rule(panels: int) -> tuple[F64, F64]:
    """Composite 8-point Gauss–Legendre on [0, 1] with ``panels`` panels: (nodes, weights)."""
    nodes = ((np.arange(panels)[:, None] + (_GL_T[None, :] + 1.0) / 2.0) / panels).ravel()
    return nodes, np.tile(_GL_W / 2.0 / panels, panels)


def cutoff(bar: F64, alpha: float, rho_p: float) -> F64:
    """r_max: ``(bar/ρ_p) r² e^{2αr} = 1`` ⇔ ``αr e^{αr} = α √(ρ_p/bar)`` (Lambert W)."""
    return np.real(lambertw(alpha * np.sqrt(rho_p / bar))) / alpha


def kink(bar: F64, alpha: float, rho_p: float, theta: float) -> F64:
    """Where d_need reaches D_min: ``10³ θ √(bar/ρ_p) r² e^{αr} = D_min`` (ν has a kink there)."""
    k = np.sqrt(MIN_DIAMETER / (1e3 * theta * np.sqrt(bar / rho_p)))  # r e^{αr/2} = k
    return 2.0 * np.real(lambertw(alpha / 2.0 * k)) / alpha


def _integrate(integrand: Any, bar: F64, low: F64, high: F64, breaks: F64, panels: int = 16) -> F64:
    """∫ integrand(r, bar) dr over [low, high] per beam, split at ``breaks`` (where the integrand is
    not smooth), each piece by composite Gauss–Legendre (``panels`` × 8 nodes)."""
    nodes, weights = _unit_rule(panels)
    total = np.zeros(len(bar))
    split = np.clip(breaks, low, high)
    for a, b in ((low, split), (split, high)):
        width = np.maximum(b - a, 0.0)
        r = a[:, None] + width[:, None] * nodes[None, :]
        total += (integrand(r, bar) * weights[None, :]).sum(axis=1) * width
    return total


def exact_expected(bar: F64, reach: F64, m: float, panels: int = 16, **c: float) -> F64:
    """The reference: :func:`old_density` integrated over [m, min(R, r_max)], split at its kink."""
    out = np.empty(len(bar))
    for start in range(0, len(bar), 2048):  # blocks of 2048 beams
        b, r_end = bar[start:start + 2048], reach[start:start + 2048]
        top = np.maximum(np.minimum(r_end, cutoff(b, c["alpha"], c["rho_p"])), m)
        out[start:start + 2048] = _integrate(lambda r, bb: old_density(r, bb, **c), b, np.full(len(b), m), top,
                                             kink(b, c["alpha"], c["rho_p"], c["theta"]), panels)
    return out


def exact_slope(bar: F64, reach: F64, m: float, **c: float) -> F64:
    """g'(x) = dE/d(ln bar): ∂ν/∂x = −Λ (d_need/2) ν where d_need > D_min (d_need ∝ √bar), plus
    the moving cut-off's term ν(r_max⁻) dr_max/dx, dr_max/dx = −1/(2/r_max + 2α), while
    m < r_max < R."""
    alpha, rho_p, theta, lam = c["alpha"], c["rho_p"], c["theta"], c["lam"]

    def derivative(r: F64, b: F64) -> F64:
        need = (b / rho_p)[:, None] * r * r * np.exp(2.0 * alpha * r)
        d_need = 1e3 * theta * r * np.sqrt(np.minimum(need, 1.0))
        return np.where(d_need > MIN_DIAMETER, -lam * d_need / 2.0, 0.0) * old_density(r, b, **c)

    r_max = cutoff(bar, alpha, rho_p)
    top = np.maximum(np.minimum(reach, r_max), m)
    slope = _integrate(derivative, bar, np.full(len(bar), m), top, kink(bar, alpha, rho_p, theta))
    inside = (r_max > m) & (r_max < reach)
    edge = old_density(r_max[:, None] * (1.0 - 1e-13), bar, **c)[:, 0]
    return slope + np.where(inside, edge * (-1.0 / (2.0 / r_max + 2.0 * alpha)), 0.0)


# --------------------------------------------------------------------------- the bound
def interpolation_bound(mod: Model, bar: F64, reach: F64, expected: F64) -> F64:
    """The worked-out bound on |Ẽ − E| of each beam (module docstring)."""
    table, c = mod.table, mod.constants
    h_x = float(table.log_bars[1] - table.log_bars[0])
    h_r = float(table.ranges[1] - table.ranges[0])
    x = np.clip((np.log(bar) - table.log_bars[0]) / h_x, 0.0, len(table.log_bars) - 1.0)
    y = np.clip((reach - table.ranges[0]) / h_r, 0.0, len(table.ranges) - 1.0)
    i = np.minimum(x.astype(int), len(table.log_bars) - 2)
    j = np.minimum(y.astype(int), len(table.ranges) - 2)
    w_x = x - i

    # e_R on the rows i and i + 1: h_R osc(ν)/4, ν sampled on 65 points of the cell and just
    # before the cut-off when the cut-off falls inside it (ν is unimodal in r: log ν is concave
    # where d_need > D_min, increasing where d_need = D_min).
    cell = table.ranges[j][:, None] + h_r * np.linspace(0.0, 1.0, 65)[None, :]
    e_r = np.zeros(len(bar))
    for row in (i, i + 1):
        bar_row = np.exp(table.log_bars[row])
        r_max = cutoff(bar_row, c["alpha"], c["rho_p"])
        samples = np.column_stack([cell, np.clip(r_max * (1.0 - 1e-13), cell[:, 0], cell[:, -1])])
        nu = old_density(samples, bar_row, **c)
        e_r = np.maximum(e_r, h_r * (nu.max(axis=1) - nu.min(axis=1)) / 4.0)

    # e_x: w_x (1 − w_x) h_x osc(g') over the cell, g' exact at 17 points of it.
    points = table.log_bars[i][:, None] + h_x * np.linspace(0.0, 1.0, 17)[None, :]
    slopes = exact_slope(np.exp(points.ravel()), np.repeat(reach, 17), mod.m, **c).reshape(points.shape)
    e_x = w_x * (1.0 - w_x) * h_x * (slopes.max(axis=1) - slopes.min(axis=1))
    return e_r + e_x + NODE_TOLERANCE * expected + NODE_ABSOLUTE


def _beams(mod: Model, count: int, seed: int) -> tuple[F64, F64]:
    """Beams of the frame (half) and beams spread over the whole table (half: log-uniform bar,
    uniform reach), so the corners the frame does not visit are checked too."""
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(mod.bar), count // 2, replace=False)
    log_bar = rng.uniform(mod.table.log_bars[0], mod.table.log_bars[-1], count - count // 2)
    reach = rng.uniform(mod.m, _PARTICLE_REACH, count - count // 2)
    return np.concatenate([mod.bar[pick], np.exp(log_bar)]), np.concatenate([mod.reach[pick], reach])


# --------------------------------------------------------------------------- tests
@pytest.mark.parametrize(("cls", "rate"), CONFIGS)
def test_reference_integral_is_converged(cls, rate):
    # The reference must be far more accurate than the table it judges: four times the nodes
    # change it by less than 1e-9 (relative), and the cut-off and kink it splits at are where
    # the integrand's need reaches 1 and d_need reaches D_min.
    mod = model(cls, rate)
    bar, reach = _beams(mod, 400, seed=1)
    assert np.allclose(exact_expected(bar, reach, mod.m, **mod.constants),
                       exact_expected(bar, reach, mod.m, panels=64, **mod.constants), rtol=1e-9, atol=1e-300)
    r_max, r_kink = cutoff(bar, mod.alpha, mod.rho), kink(bar, mod.alpha, mod.rho, mod.theta)
    np.testing.assert_allclose(bar / mod.rho * r_max**2 * np.exp(2 * mod.alpha * r_max), 1.0, rtol=1e-9)
    np.testing.assert_allclose(1e3 * mod.theta * np.sqrt(bar / mod.rho) * r_kink**2 * np.exp(mod.alpha * r_kink),
                               MIN_DIAMETER, rtol=1e-9)


@pytest.mark.parametrize(("cls", "rate"), CONFIGS)
def test_table_nodes_are_the_integral(cls, rate):
    mod = model(cls, rate)
    table = mod.table
    rng = np.random.default_rng(2)
    i = rng.integers(0, len(table.log_bars), 400)
    j = rng.integers(0, len(table.ranges), 400)
    exact = exact_expected(np.exp(table.log_bars[i]), table.ranges[j], mod.m, **mod.constants)
    assert np.all(np.abs(table.counts[i, j] - exact) <= NODE_TOLERANCE * exact + NODE_ABSOLUTE)


@pytest.mark.parametrize(("cls", "rate"), CONFIGS)
def test_table_error_is_within_the_worked_out_bound(cls, rate):
    mod = model(cls, rate)
    bar, reach = _beams(mod, 600, seed=3)
    exact = exact_expected(bar, reach, mod.m, **mod.constants)
    table = mod.table.expected(bar, reach)
    bound = interpolation_bound(mod, bar, reach, exact)
    assert np.all(np.abs(table - exact) <= bound), np.max(np.abs(table - exact) / bound)
    # The bound is a real constraint, not a blanket: on the frame's beams with a count that
    # matters it is under 2 % of the count.
    frame = slice(0, 300)
    matters = exact[frame] > 1e-3 * exact[frame].max()
    assert np.all(bound[frame][matters] <= 0.02 * exact[frame][matters])


@pytest.mark.parametrize(("cls", "rate"), CONFIGS)
def test_table_is_closer_to_the_integral_than_the_old_quadrature(cls, rate):
    # The 28-node trapezoid the table replaced was itself off by 0.5-1.5 % on the frame's total
    # (its last cells are metres wide and straddle the cut-off); the table is within 0.1 %.
    mod = model(cls, rate)
    pick = np.random.default_rng(4).choice(len(mod.bar), 3000, replace=False)
    bar, reach = mod.bar[pick], mod.reach[pick]
    exact = exact_expected(bar, reach, mod.m, **mod.constants).sum()
    table = mod.table.expected(bar, reach).sum()
    old = old_expected(bar, reach, mod.m, **mod.constants).sum()
    assert abs(table - exact) <= 1e-3 * exact
    assert abs(table - exact) < abs(old - exact)


def _affected(op: _Precipitation, params: Any, scene: Scene) -> int:
    """Points whose return a particle replaced: they lose their label (every label set to 40)."""
    labelled = scene.with_points(scene.points.with_channel("label", np.full(len(scene.points), 40.0)))
    return int(np.count_nonzero(op.apply(labelled, params).points.channel("label") == 0))


@pytest.mark.parametrize(("cls", "rate"), [(Rain, 0.5), (Rain, 40.0), (Snow, 4.0)])
def test_affected_points_law_is_within_the_bound(cls, rate):
    mod = model(cls, rate)
    exact = exact_expected(mod.bar, mod.reach, mod.m, **mod.constants)
    table = mod.table.expected(mod.bar, mod.reach)
    p = -np.expm1(-exact)  # each point's probability of being affected
    # Total-variation distance between the laws of the affected set ≤ Σ|Ẽ − E|: under 1 % of the
    # expected number of affected points.
    distance = float(np.abs(table - exact).sum())
    assert distance <= 0.01 * p.sum()
    # And the operator draws them so: the mean count over 40 seeds within four standard errors
    # of the exact expectation, plus the table's bias (at most Σ|Ẽ − E|).
    seeds = 40
    counts = [_affected(mod.op, mod.params.model_copy(update={"seed": seed}), hdl64()) for seed in range(seeds)]
    tolerance = 4.0 * np.sqrt((p * (1.0 - p)).sum() / seeds) + distance
    assert abs(np.mean(counts) - p.sum()) <= tolerance, (np.mean(counts), p.sum(), tolerance)


def test_table_is_built_once_per_configuration():
    mod = model(Rain, 40.0)
    again = particle_table(mod.n0, mod.lam, mod.alpha, mod.rho, mod.theta, mod.m, mod.p_min)
    assert again is mod.table
    assert not mod.table.counts.flags.writeable  # shared: nobody may change it


def test_particles_are_drawn_before_the_cut_off():
    # A particle drawn past r_max could not outshine the bar it was drawn to beat; the table's
    # last cell of a beam spreads its count only up to the cut-off.
    mod = model(Snow, 4.0)
    rng = np.random.default_rng(5)
    bar = np.exp(rng.uniform(mod.table.log_bars[0], mod.table.log_bars[-1], 5000))
    reach = np.full(len(bar), _PARTICLE_REACH)
    r = mod.table.draw_ranges(bar, reach, rng.random(len(bar)))
    assert np.all(r < cutoff(bar, mod.alpha, mod.rho) * (1.0 + 1e-9))
    assert np.all(r >= mod.m)


def _tiled(scene: Scene, n: int) -> Scene:
    """``scene`` repeated to ``n`` points, jittered by 2 cm so no two points coincide."""
    base = scene.points
    data = np.concatenate([base.data] * int(np.ceil(n / len(base))))[:n].copy()
    data[:, :3] += np.random.default_rng(0).normal(0.0, 0.02, (n, 3)).astype(np.float32)
    return scene.with_points(PointCloud(data, base.channels))


def _peak_bytes(op: Any, scene: Scene) -> int:
    params = op.sample(np.random.default_rng(0), scene)
    op.apply(scene, params)  # tables built and cached outside the measurement
    # The per-point scratch arrays the call keeps for the next one (common.scratch) are dropped, so
    # the measured call makes them again and the peak counts them: they are memory linear in points.
    release_scratch()
    tracemalloc.start()
    try:
        op.apply(scene, params)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("op", [Rain.at_severity(5), Snow.at_severity(5), Fog.at_severity(5),
                                WetGround.at_severity(5)], ids=lambda op: op.name)
def test_memory_grows_linearly_with_few_bytes_per_point(op):
    # 2^17 → 2^19 points: the peak grows by at most 256 bytes per added point (the output copy is
    # 32 bytes a point, each full-length float64 array 8); the per-point work is done in blocks
    # of fixed size, so no N × K temporary can hide in the peak.
    small, large = 1 << 17, 1 << 19
    scene = hdl64()
    growth = _peak_bytes(op, _tiled(scene, large)) - _peak_bytes(op, _tiled(scene, small))
    assert growth <= 256 * (large - small), growth / (large - small)
