"""How far above the receiver's detection threshold a reported return was: its power margin.

Weather and wet-ground operators decide which returns are lost by how much power the return
loses on its way (two-way extinction, a water film) and how much it had to spare. The loss
needs that spare power, the *margin* ``m = P / P_th`` of the return's clear-weather received
power ``P`` over the detection threshold ``P_th``; a return is lost when the attenuation
``T`` brings it under the threshold, ``m · T < 1``. This module derives ``m`` from what is
known about a reported return.

**The LiDAR equation.** A Lambertian target of reflectivity ρ at range R, hit at incidence θ,
returns ``P = C · ρ cos θ / R²`` (C: the sensor's constant: pulse energy, aperture, optics).
Call ``ρ_e = ρ cos θ`` the *effective* reflectivity: what the return shows of its surface.

**The threshold, from the range specification.** A datasheet gives the range at which a target
of stated reflectivity is still detected: the HDL-64E S2/S3 (KITTI's sensor) 50 m on 10 %
pavement and 120 m on 80 % cars and foliage (Velodyne HDL-64E S2 user manual, Specifications;
the two give ``ρ/R²`` of 4.0·10⁻⁵ and 5.6·10⁻⁵ m⁻², within 1.4× of each other). So
``P_th = C · ρ_ref / R_ref²``, and as a *detection threshold* ``d`` — the weakest effective
reflectivity detected at 100 m — the HDL-64E's pavement figure is ``d = 0.1 · (100/50)² = 0.4``
(:data:`HDL64E_DETECTION_THRESHOLD`). The lidarfuzz simulator's receiver is more sensitive
(d = 0.05); a sensor of another class is one config value away (e.g. a 200 m-on-10 % sensor:
d = 0.025). At range R the weakest detectable effective reflectivity, the *detection floor*, is
``ρ_det(R) = d · (R / 100 m)²``, and the margin of a return is ``m = ρ_e / ρ_det(R)``.

**What the intensity reading says.** The reading, divided by the data's full scale (the
frame's ``intensity_scale``: 1 for KITTI, 255 for 8-bit data), is taken as the sensor's
estimate ``ρ̂`` of ρ_e: spinning LiDARs report a per-beam calibrated, range-compensated
reflectivity (Velodyne: 0–100 for diffuse targets, above for retro-reflectors, HDL-32E
manual; the HDL-64E driver adds a range-dependent term per beam and clamps to the beam's
``minIntensity``/``maxIntensity``, HDL-64E S2 manual, db.xml parameters). Neither KITTI's
calibration nor the simulator's intensity removes cos θ, which is why ρ_e, not ρ, is the
quantity. A reading is *resolved* — it fixes ρ_e = ρ̂ — when it is at least one quantisation
step (``q`` = 1/255 of full scale) and at least what the detection implies, ``ρ̂ ≥ ρ_det(R)``.

**Readings that say nothing.** A zero (or sub-step) reading is a clamp, not a measurement:
within 10 m the three KITTI frames this was checked on (training 000000–000002) hold 2,900–8,600
zeros each against 40–55 readings of 0.01–0.02 (beyond 10 m, hundreds to thousands of zeros
against a handful), so a 0 tells only that the beam's calibrated value fell below its floor.
And readings below ``ρ_det(R)`` are refuted by the detection itself (the KITTI HDL-64E's
readings are range-compensated to about 25 m, then fall: the median is 0.3 at 5–20 m and 0
beyond 50 m, where 60–95 % read 0). For these returns all
that is known is ``ρ_e ≥ ρ_det(R)``; ρ_e is drawn, per point and seeded, from a uniform prior
over the admissible interval ``[ρ_det(R), 1]`` (1: a white diffuse target; brighter returns
are retro-reflectors, whose readings are never at the floor). Reading the zero as a reflectivity
under one step instead — an interval ``[ρ_det, q]`` — would put every zero beyond
``R = 100 m · √(q / d)`` (16 m for the HDL-64E with KITTI's q = 0.01) exactly at the threshold,
so the lightest haze would delete all of them: the cliff the public fog simulator shows on
KITTI and Waymo, where intensity is read as received power and zeros have none.

**What follows.** Under attenuation T (power ratio), a resolved return is lost iff
``ρ̂ T < ρ_det(R)``; an unresolved one with probability

    p(R, T) = min(1, ρ_det(R) (1/T − 1) / (1 − ρ_det(R))),

which is 0 without attenuation, grows smoothly with range (as R² and through T) and with
falling visibility, and never jumps: no zero-intensity return vanishes unless the attenuation
at its range outweighs the power the detection guarantees it.

Example (fog, MOR 750 m: α = ln 20 / 750 = 0.0040 /m, T = exp(−2αR); HDL-64E, d = 0.4), for
an unresolved return:

====  ======  ======  =========
R     ρ_det   T       p
====  ======  ======  =========
5 m   0.001   0.961   0.0041 %
20 m  0.016   0.852   0.28 %
40 m  0.064   0.726   2.6 %
60 m  0.144   0.619   10.3 %
====  ======  ======  =========
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

#: The weakest effective reflectivity an HDL-64E detects at 100 m: 10 % pavement at 50 m.
HDL64E_DETECTION_THRESHOLD = 0.1 * (100.0 / 50.0) ** 2
#: The range at which a detection threshold is stated, metres.
REFERENCE_RANGE = 100.0
#: One quantisation step of a reading, as a share of full scale (8-bit intensity).
QUANTISATION_STEP = 1.0 / 255.0
#: Keeps the detection floor of a return at the origin positive.
_MIN_RANGE = 1e-3


def detection_floor(ranges: NDArray[np.floating], detection_threshold: float) -> F64:
    """``ρ_det(R) = d · (R / 100 m)²``: the weakest effective reflectivity detected at range R."""
    r = np.maximum(np.asarray(ranges, np.float64), _MIN_RANGE) / REFERENCE_RANGE
    return detection_threshold * r * r


def power_draw_stream(seed: int) -> np.random.Generator:
    """The generator :func:`power_draws` reads: ``random(k)`` calls on it, block after block,
    give the same numbers as one ``power_draws(seed, n)``, so an operator that works in blocks
    never holds all n draws at once."""
    return np.random.default_rng(np.random.SeedSequence([seed, 0x9E7]))


def power_draws(seed: int, n: int, out: F64 | None = None) -> F64:
    """Uniform draws in [0, 1) for the unresolved returns, from a stream of their own (so an
    operator's other draws from ``seed`` are unchanged by them); written into ``out`` (n float64
    elements) when given — the same numbers, in a buffer the caller reuses."""
    if out is None:
        return power_draw_stream(seed).random(n)
    return power_draw_stream(seed).random(out=out[:n])


def effective_reflectivity(intensity: NDArray[np.floating], ranges: NDArray[np.floating], *, scale: float,
                           detection_threshold: float, draws: NDArray[np.floating]) -> tuple[F64, F64]:
    """(ρ_e, ρ_det) of each return: the reading where it is resolved, else a draw from the
    uniform prior on ``[ρ_det, 1]`` (see the module docstring).

    Args:
        intensity: The readings, on the data's scale.
        ranges: Range of each return, metres.
        scale: The reading of a white diffuse target (the data's full scale).
        detection_threshold: ``d``, the weakest effective reflectivity detected at 100 m.
        draws: One uniform [0, 1) number per return (:func:`power_draws`).
    """
    floor = detection_floor(ranges, detection_threshold)
    reading = np.asarray(intensity, np.float64) / scale
    resolved = (reading >= QUANTISATION_STEP) & (reading >= floor)
    unknown = floor + np.asarray(draws, np.float64) * np.maximum(1.0 - floor, 0.0)
    return np.where(resolved, reading, unknown), floor


def power_margin(intensity: NDArray[np.floating], ranges: NDArray[np.floating], *, scale: float,
                 detection_threshold: float, draws: NDArray[np.floating]) -> F64:
    """``m = P / P_th ≥ 1``: each return's clear-weather received power over the detection
    threshold. A return is lost under a power attenuation T when ``m · T < 1``.

    >>> import numpy as np
    >>> # 0.3 at 20 m is resolved: 0.3 / (0.4 · 0.2²) = 18.75; a 0 at 20 m with draw 0.5:
    >>> # (0.016 + 0.5 · 0.984) / 0.016 = 31.75.
    >>> power_margin(np.array([0.3, 0.0]), np.array([20.0, 20.0]), scale=1.0,
    ...              detection_threshold=0.4, draws=np.array([0.5, 0.5])).round(2).tolist()
    [18.75, 31.75]
    """
    rho, floor = effective_reflectivity(intensity, ranges, scale=scale, detection_threshold=detection_threshold,
                                        draws=draws)
    return rho / floor


__all__ = [
    "HDL64E_DETECTION_THRESHOLD", "QUANTISATION_STEP", "REFERENCE_RANGE", "detection_floor",
    "effective_reflectivity", "power_draw_stream", "power_draws", "power_margin",
]
