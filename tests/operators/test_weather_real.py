"""Weather and sensor operators on real intensity distributions: a reported return was detected.

Real scans are not used here (they stay outside the repository); the frames below are synthetic,
built from statistics measured on three real KITTI HDL-64E scans.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarfuzz.operators.lidar.common import declared_intensity_scale, scene_intensity_scale
from lidarfuzz.operators.lidar.power import HDL64E_DETECTION_THRESHOLD, power_margin
from lidarfuzz.operators.lidar.sensor import Crosstalk, CrosstalkParams, IntensityQuantisation, IntensitySaturation
from lidarfuzz.operators.lidar.weather import Fog, FogParams, Rain, WetGround
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

# Statistics of three real KITTI HDL-64E scans (object benchmark training 000000-000002, 362,543
# points), measured locally: per range bin (0-10, 10-20, 20-40, 40-80 m) the share of the points,
# the share reading exactly 0, and the mean and standard deviation of the non-zero readings.
# Readings are hundredths; 0.01 and 0.02 almost never occur (within 10 m, 40-55 per frame against
# 2,900-8,600 zeros), so 0 is a clamp at the beam's calibration floor, not a dim measurement.
RANGE_BINS = ((0.0, 10.0), (10.0, 20.0), (20.0, 40.0), (40.0, 80.0))
BIN_SHARE = (0.689, 0.200, 0.090, 0.021)
ZERO_SHARE = (0.079, 0.053, 0.159, 0.690)
NONZERO_MEAN = (0.296, 0.321, 0.251, 0.205)
NONZERO_SD = (0.108, 0.124, 0.105, 0.168)
GROUND_SHARE = 0.5  # about half the points of a street scan are road and pavement
SENSOR_HEIGHT = 1.73  # KITTI's HDL-64E above the road, metres


def real_like_frame(n: int = 60_000, seed: int = 7) -> Scene:
    """A street frame with KITTI's intensity distribution: flat ground 1.73 m below the sensor
    and upright surfaces, at ranges and with readings (0 included) drawn per range bin."""
    rng = np.random.default_rng(seed)
    counts = np.round(np.array(BIN_SHARE) * n).astype(int)
    parts = []
    for (lo, hi), count, zero, mean, sd in zip(RANGE_BINS, counts, ZERO_SHARE, NONZERO_MEAN, NONZERO_SD, strict=True):
        distance = rng.uniform(max(lo, 2.0), hi, count)  # horizontal distance
        azimuth = rng.uniform(-np.pi, np.pi, count)
        ground = rng.random(count) < GROUND_SHARE
        z = np.where(ground, -SENSOR_HEIGHT, rng.uniform(-1.2, 1.5, count))
        reading = np.clip(np.round(rng.normal(mean, sd, count), 2), 0.03, 0.99)
        reading[rng.random(count) < zero] = 0.0
        parts.append(np.column_stack([distance * np.cos(azimuth), distance * np.sin(azimuth), z, reading]))
    return Scene(PointCloud(np.concatenate(parts).astype(np.float32)), frame_id="real-like")


def shell(count: int, radius: float, intensity: float, seed: int = 0) -> np.ndarray:
    """``count`` returns at one range in random directions, all with one reading."""
    direction = np.random.default_rng(seed).normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return np.column_stack([direction * radius, np.full(count, intensity)])


def frame(*shells: np.ndarray, **metadata: object) -> Scene:
    data = np.concatenate(shells).astype(np.float32)
    data = np.column_stack([data, np.arange(len(data), dtype=np.float32)])  # a foreign channel: the source row
    return Scene(PointCloud(data, ("x", "y", "z", "intensity", "row")), frame_id="f", metadata=metadata)


def kept_rows(mutant: Scene) -> np.ndarray:
    return np.rint(mutant.points.channel("row")).astype(np.int64)


def fog_params(mor: float, seed: int = 3, scale: float = 1.0) -> FogParams:
    return FogParams(alpha=math.log(20.0) / mor, tau_h_ns=20.0, threshold=0.5 / 255,
                     detection_threshold=HDL64E_DETECTION_THRESHOLD, intensity_scale=scale, seed=seed)


def lost_share(scene: Scene, mutant: Scene) -> float:
    return 1.0 - len(mutant.points) / len(scene.points)


# --------------------------------------------------------------------------- the power model
def test_a_zero_reading_is_a_return_at_or_above_the_detection_threshold():
    ranges = np.array([0.5, 5.0, 20.0, 40.0, 60.0, 80.0, 120.0, 150.0])
    for draw in (0.0, 0.5, 0.999):
        margin = power_margin(np.zeros(len(ranges)), ranges, scale=1.0, detection_threshold=0.4,
                              draws=np.full(len(ranges), draw))
        assert np.all(margin >= 1.0)
    # With no attenuation to speak of (MOR 10^9 m) fog deletes none of them, at any range.
    scene = frame(*(shell(500, r, 0.0, seed=i) for i, r in enumerate(ranges)))
    assert len(Fog().apply(scene, fog_params(1e9)).points) == len(scene.points)


def test_the_margin_follows_the_lidar_equation_and_the_range_specification():
    # HDL-64E: 10 % reflectivity detected at 50 m, so the detection floor at R is 0.4 (R/100)^2.
    # A resolved reading of 0.3 at 20 m: floor 0.4 * 0.04 = 0.016, margin 0.3 / 0.016 = 18.75;
    # at 50 m a reading of 0.1 is exactly at the floor (0.4 * 0.25 = 0.1): margin 1.
    # A reading of 0.1 at 60 m is below its floor 0.144, refuted by the detection: it is drawn
    # like a zero, 0.144 + 0.25 * (1 - 0.144) = 0.358 with draw 0.25, margin 0.358 / 0.144 = 2.486.
    margin = power_margin(np.array([0.3, 0.1, 0.1, 0.0]), np.array([20.0, 50.0, 60.0, 60.0]), scale=1.0,
                          detection_threshold=0.4, draws=np.array([0.9, 0.9, 0.25, 0.25]))
    np.testing.assert_allclose(margin, [18.75, 1.0, 0.358 / 0.144, 0.358 / 0.144], rtol=1e-9)


# --------------------------------------------------------------------------- fog: worked example
# Zero readings: the reflectivity is uniform on [rho_det, 1], rho_det = 0.4 (R/100)^2; fog of MOR V
# (alpha = ln 20 / V) leaves T = exp(-2 alpha R) of the power, so the return is lost when
# rho < rho_det / T, with probability p = rho_det (1/T - 1) / (1 - rho_det), capped at 1.
#   MOR 750 m, alpha = 2.9957 / 750 = 0.0039943 /m:
#     R = 5:  rho_det 0.001, T = exp(-0.039943) = 0.96084, p = 0.001 * 0.040757 / 0.999 = 0.0000408
#     R = 20: rho_det 0.016, T = exp(-0.15977) = 0.85234, p = 0.016 * 0.17324 / 0.984 = 0.002817
#     R = 40: rho_det 0.064, T = exp(-0.31954) = 0.72648, p = 0.064 * 0.37650 / 0.936 = 0.025744
#     R = 60: rho_det 0.144, T = exp(-0.47932) = 0.61921, p = 0.144 * 0.61496 / 0.856 = 0.103453
#   MOR 50 m, alpha = 2.9957 / 50 = 0.059915 /m:
#     R = 5:  T = exp(-0.59915) = 0.54928, p = 0.001 * 0.82057 / 0.999 = 0.000821
#     R = 20: T = exp(-2.3966) = 0.09103, p = 0.016 * 9.9855 / 0.984 = 0.16237
#     R = 40: T = exp(-4.7932) = 0.00829, p = 0.064 * 119.6 / 0.936 > 1: all lost
#     R = 60: T = 0.00075: all lost
WORKED = {750.0: {5.0: 0.0000408, 20.0: 0.002817, 40.0: 0.025744, 60.0: 0.103453},
          50.0: {5.0: 0.000821, 20.0: 0.16237, 40.0: 1.0, 60.0: 1.0}}
PER_RANGE = 40_000


@pytest.mark.parametrize("mor", sorted(WORKED))
def test_fog_loses_zero_intensity_returns_as_the_attenuation_of_their_power_says(mor):
    ranges = sorted(WORKED[mor])
    scene = frame(*(shell(PER_RANGE, r, 0.0, seed=i) for i, r in enumerate(ranges)))
    mutant = Fog().apply(scene, fog_params(mor))
    rows = kept_rows(mutant)
    assert np.all(mutant.points.intensity == 0)  # a zero stays a zero: no fog return, no brightening
    for i, r in enumerate(ranges):
        kept = np.count_nonzero((rows >= i * PER_RANGE) & (rows < (i + 1) * PER_RANGE))
        lost = 1.0 - kept / PER_RANGE
        p = WORKED[mor][r]
        sigma = math.sqrt(p * (1 - p) / PER_RANGE)
        assert abs(lost - p) <= 5 * sigma + 1e-9, (r, lost, p)


def test_fog_loses_a_resolved_reading_when_its_margin_is_spent():
    # At 60 m the floor is 0.144 and MOR 750 m leaves T = 0.61921 of the power: a reading of 0.2
    # (margin 0.2 / 0.144 = 1.389, times T = 0.860 < 1) is lost, one of 0.3 (2.083 * T = 1.290) kept.
    scene = frame(shell(200, 60.0, 0.2), shell(200, 60.0, 0.3, seed=1))
    rows = kept_rows(Fog().apply(scene, fog_params(750.0)))
    assert np.array_equal(rows, np.arange(200, 400))


def test_fog_loss_grows_with_range_and_with_falling_visibility():
    ranges = (5.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0)
    scene = frame(*(shell(20_000, r, 0.0, seed=i) for i, r in enumerate(ranges)))
    table = []
    for mor in (900.0, 600.0, 300.0, 150.0, 80.0, 40.0):
        rows = kept_rows(Fog().apply(scene, fog_params(mor)))
        table.append([1.0 - np.count_nonzero(rows // 20_000 == i) / 20_000 for i in range(len(ranges))])
    loss = np.array(table)
    assert np.all(np.diff(loss, axis=1) >= 0) and np.all(np.diff(loss, axis=0) >= 0)
    assert loss[0, -1] < 0.25  # the lightest fog: no cliff, most zeros at 70 m survive
    assert loss[0, 0] < 0.001 and loss[-1, -1] == 1.0  # 5 m at MOR 900 m: p = 3.4e-5; 70 m at 40 m: all


# --------------------------------------------------------------------------- real-like frames
def degraded(scene: Scene, mutant: Scene) -> tuple[float, float]:
    """(share lost, share lost or moved off its surface by more than 0.5 m)."""
    rows = kept_rows(mutant)
    before = np.linalg.norm(scene.points.xyz[rows].astype(np.float64), axis=1)
    after = np.linalg.norm(mutant.points.xyz.astype(np.float64), axis=1)
    lost = lost_share(scene, mutant)
    return lost, lost + float(np.count_nonzero(np.abs(after - before) > 0.5)) / len(scene.points)


@pytest.fixture(scope="module")
def real_like() -> Scene:
    scene = real_like_frame()
    return scene.with_points(scene.points.with_channel("row", np.arange(len(scene.points), dtype=np.float32)))


@pytest.mark.parametrize("operator", [Fog, Rain, WetGround])
def test_on_a_real_like_frame_the_lightest_weather_loses_under_one_percent_and_more_for_each_severity(
        operator, real_like):
    lost, hit = zip(*(degraded(real_like, operator.at_severity(s)(real_like, np.random.default_rng(0))[0])
                      for s in range(1, 6)), strict=True)
    assert lost[0] < 0.01
    assert np.all(np.diff(hit) > 0), hit  # lost or turned into a return from the air
    assert np.all(np.diff(lost) >= 0) and lost[4] > lost[0], lost


def test_on_a_real_like_frame_fog_no_longer_deletes_the_zeros_wholesale(real_like):
    # The old model gave every zero 4/3 of the threshold: at MOR 600-900 m every zero beyond
    # ~35 m (where exp(-2 alpha R) < 3/4) was lost, i.e. nearly 69 % of the 40-80 m bin.
    mutant, _ = Fog.at_severity(1)(real_like, np.random.default_rng(0))
    rows = kept_rows(mutant)
    ranges = np.linalg.norm(real_like.points.xyz, axis=1)
    zero_far = np.flatnonzero((real_like.points.intensity == 0) & (ranges > 40))
    assert np.isin(zero_far, rows).mean() > 0.75


# --------------------------------------------------------------------------- intensity scales
@pytest.mark.parametrize("operator", [Fog, Rain, WetGround])
def test_unit_and_byte_scales_give_the_same_result_declared_or_inferred(operator, real_like):
    byte = real_like.with_points(real_like.points.with_channel("intensity", real_like.points.intensity * 255.0))
    declared = byte.replace(metadata={"intensity_scale": 255.0})
    op = operator.at_severity(4)
    unit_mutant, unit_params = op(real_like, np.random.default_rng(2))
    for scene in (byte, declared):
        mutant, params = op(scene, np.random.default_rng(2))
        assert params.intensity_scale == 255.0
        assert np.array_equal(kept_rows(mutant), kept_rows(unit_mutant))
        np.testing.assert_allclose(mutant.points.xyz, unit_mutant.points.xyz, atol=1e-4)
        np.testing.assert_allclose(mutant.points.intensity, unit_mutant.points.intensity * 255.0, rtol=1e-4,
                                   atol=1e-3)
    assert unit_params.intensity_scale == 1.0


def test_a_declared_scale_wins_over_one_inferred_from_dark_values():
    # An 8-bit frame whose readings are all 0 or 1 (of 255) looks like [0, 1] data to the
    # inference: a reading of 1 would then be a white target. Declared, it is 1/255: dark.
    readings = np.tile([0.0, 1.0], 5_000)
    data = np.column_stack([shell(10_000, 60.0, 0.0)[:, :3], readings])
    dark = frame(data, intensity_scale=255.0)
    assert scene_intensity_scale(dark) == 255.0
    assert scene_intensity_scale(dark.replace(metadata={})) == 1.0
    params = Fog.at_severity(1).sample(np.random.default_rng(0), dark)
    assert params.intensity_scale == 255.0
    # As [0, 1] data the readings of 1 would be resolved and far above their floor (margin 6.9);
    # at 255 they are refuted (1/255 < 0.144) and treated like the zeros: some are lost.
    lost_ones = 1.0 - np.isin(np.flatnonzero(readings == 1.0), kept_rows(Fog().apply(dark, params))).mean()
    assert 0.02 < lost_ones < 0.25


def test_declared_scales_are_read_from_numbers_and_type_names():
    cloud = PointCloud(np.array([[1.0, 0.0, 0.0, 0.5]], np.float32))
    assert declared_intensity_scale(Scene(cloud, metadata={"intensity_scale": "uint16"})) == 65535.0
    assert declared_intensity_scale(Scene(cloud, metadata={"intensity_scale": 100})) == 100.0
    for unusable in ("bogus", -1.0, 0, True, None, float("nan")):
        assert declared_intensity_scale(Scene(cloud, metadata={"intensity_scale": unusable})) is None
    assert scene_intensity_scale(Scene(cloud)) == 1.0


@pytest.mark.parametrize("operator", [IntensityQuantisation, IntensitySaturation, Crosstalk])
def test_sensor_faults_use_the_declared_scale(operator):
    # Readings of at most 0.9 on a declared 0-255 scale: the inference alone would say 1.
    scene = frame(shell(1_000, 10.0, 0.9), intensity_scale=255.0)
    params = operator.at_severity(3).sample(np.random.default_rng(0), scene)
    if isinstance(params, CrosstalkParams):  # false returns of 0-10 % of full scale
        assert (params.intensity_low, params.intensity_high) == pytest.approx((0.0, 25.5))
    else:
        assert params.scale == 255.0
