"""Behaviour of the sensor-fault operators, and pins of the public tools' defects."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators import generator
from lidarfuzz.operators.lidar.sensor import (
    BeamMissing,
    CrossSensor,
    Crosstalk,
    FovLoss,
    GaussianJitter,
    ImpulseJitter,
    IntensityQuantisation,
    IntensitySaturation,
    MotionDistortion,
    MotionDistortionParams,
    RangeDegradation,
    SpatialMisalignment,
    UniformJitter,
    estimate_rings,
    time_of_azimuth,
)
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim import GenerationConfig, render_frames
from lidarfuzz.sim.sensor import SENSOR_PRESETS


@pytest.fixture(scope="module")
def hdl64() -> Scene:
    """One HDL-64E simulator frame (~120k points, every channel)."""
    return next(render_frames(GenerationConfig(frames=1, seed=0)))


def rng(trial: int = 0) -> np.random.Generator:
    return generator(0, "000000", 0, trial)


def rings(scene: Scene) -> np.ndarray:
    return scene.points.channel("ring").astype(np.int64)


def without(scene: Scene, *channels: str) -> Scene:
    return scene.with_points(scene.points.without_channels(channels))


def unit(xyz: np.ndarray) -> np.ndarray:
    xyz = xyz.astype(np.float64)
    return xyz / np.linalg.norm(xyz, axis=1, keepdims=True)


# --------------------------------------------------------------------------- beams
@pytest.mark.parametrize("k", [1, 16, 48])
def test_beam_missing_removes_exactly_k_distinct_rings(hdl64, k):
    # Robo3D draws the rings with replacement and so removes fewer than asked.
    mutant, params = BeamMissing(ratio_range=(k / 64, k / 64))(hdl64, rng(k))
    assert params.ring_source == "channel"
    assert len(params.rings) == len(set(params.rings)) == k
    before, after = rings(hdl64), rings(mutant)
    assert set(np.unique(before)) - set(np.unique(after)) == set(params.rings)
    assert len(mutant.points) == np.count_nonzero(~np.isin(before, params.rings))


def test_ring_estimate_from_elevation_matches_the_true_rings(hdl64, sample_scenes):
    for scene in (hdl64, sample_scenes[0]):
        assert np.mean(estimate_rings(scene.points.xyz) == rings(scene)) >= 0.95
    # Real sensors scatter each beam's elevation a little: 0.05° (a sixth of the HDL-64E spacing) still works.
    xyz = hdl64.points.xyz.astype(np.float64)
    horizontal = np.hypot(xyz[:, 0], xyz[:, 1])
    elevation = np.arctan2(xyz[:, 2], horizontal) + np.deg2rad(np.random.default_rng(0).normal(0, 0.05, len(xyz)))
    noisy = np.column_stack([xyz[:, :2], horizontal * np.tan(elevation)])
    assert np.mean(estimate_rings(noisy) == rings(hdl64)) >= 0.95


def test_beam_missing_without_a_ring_channel_removes_whole_estimated_rings(hdl64):
    op = BeamMissing(ratio_range=(0.25, 0.25))
    mutant, params = op(without(hdl64, "ring"), rng())
    assert params.ring_source == "elevation" and len(params.rings) == 16
    # The removed points are (nearly all) the points of 16 true rings.
    true = rings(hdl64)
    kept = np.isin(hdl64.points.data[:, :3].view(np.dtype((np.void, 12))).ravel(),
                   mutant.points.data[:, :3].copy().view(np.dtype((np.void, 12))).ravel())
    assert np.mean(np.isin(true, params.rings) == ~kept) >= 0.95
    unknown = hdl64.with_points(hdl64.points.with_channel("ring", np.full(len(hdl64.points), -1.0)))
    assert op(unknown, rng())[1].ring_source == "elevation"
    with pytest.raises(ValueError, match="ring channel"):
        op.apply(without(hdl64, "ring"), op(hdl64, rng())[1])


def test_cross_sensor_keeps_every_kth_ring_and_thins_azimuth(hdl64):
    mutant, _ = CrossSensor(beam_factor_range=(2.0, 2.0), azimuth_factor_range=(1, 1))(hdl64, rng())
    kept = np.unique(rings(mutant))
    assert len(kept) == 32 and np.all(np.diff(kept) == 2)
    assert len(mutant.points) == np.count_nonzero(np.isin(rings(hdl64), kept))
    mutant, _ = CrossSensor(beam_factor_range=(4 / 3, 4 / 3), azimuth_factor_range=(1, 1))(hdl64, rng())
    assert len(np.unique(rings(mutant))) == 48  # Robo3D's "light": 48 of 64 beams
    mutant, _ = CrossSensor(beam_factor_range=(1.0, 1.0), azimuth_factor_range=(2, 2))(hdl64, rng())
    per_ring_before = np.bincount(rings(hdl64), minlength=64)
    per_ring_after = np.bincount(rings(mutant), minlength=64)
    busy = per_ring_before > 500
    np.testing.assert_allclose(per_ring_after[busy] / per_ring_before[busy], 0.5, atol=0.08)


# --------------------------------------------------------------------------- crosstalk
def test_crosstalk_moves_a_share_of_returns_along_their_own_beam(hdl64):
    mutant, params = Crosstalk(ratio_range=(0.02, 0.02))(hdl64, rng())
    before, after = hdl64.points, mutant.points
    moved = np.any(before.xyz != after.xyz, axis=1)
    assert np.count_nonzero(moved) == round(0.02 * len(before))
    np.testing.assert_allclose(unit(after.xyz[moved]), unit(before.xyz[moved]), atol=1e-5)
    distance = np.linalg.norm(after.xyz[moved], axis=1)
    assert distance.min() >= params.range_low - 1e-3 and distance.max() <= params.range_high + 1e-3
    assert np.all(after.intensity[moved] <= 0.1 + 1e-6)
    assert np.all(after.channel("label")[moved] == 0) and np.all(after.channel("instance")[moved] == -1)
    for name in ("ring", "time"):
        assert np.array_equal(after.channel(name), before.channel(name))
    assert np.array_equal(after.data[~moved], before.data[~moved])


# --------------------------------------------------------------------------- FOV
def test_fov_loss_sector_is_in_the_x_forward_frame():
    # 3D_Corruptions_AD measures the azimuth from the y axis: its "front" is the left side.
    cloud = PointCloud(np.array([[10, 0, 0, 0.5], [0, 10, 0, 0.5], [-10, 0, 0, 0.5], [0, -10, 0, 0.5],
                                 [10, 3, 0, 0.5]], np.float32))
    mutant = FovLoss().apply(Scene(cloud), FovLoss.ParamsModel(center=0.0, width=60.0))
    assert mutant.points.xyz[:, :2].tolist() == [[0, 10], [-10, 0], [0, -10]]
    left = FovLoss().apply(Scene(cloud), FovLoss.ParamsModel(center=90.0, width=60.0))
    assert [0, 10] not in left.points.xyz[:, :2].tolist() and len(left.points) == 4


def test_fov_loss_on_a_frame_removes_ahead_and_keeps_the_left(hdl64):
    mutant = FovLoss().apply(hdl64, FovLoss.ParamsModel(center=0.0, width=90.0))
    az = np.degrees(np.arctan2(mutant.points.xyz[:, 1], mutant.points.xyz[:, 0]))
    assert np.all(np.abs(az) > 45.0)
    source_az = np.degrees(np.arctan2(hdl64.points.xyz[:, 1], hdl64.points.xyz[:, 0]))
    assert np.count_nonzero((az > 60) & (az < 120)) == np.count_nonzero((source_az > 60) & (source_az < 120)) > 0


# --------------------------------------------------------------------------- motion
def test_motion_distortion_shifts_by_v_t_and_leaves_t0_alone(hdl64):
    op = MotionDistortion()
    params = MotionDistortionParams(speed=20.0, yaw_rate=0.0, rotation_hz=10.0, time_source="channel")
    t = hdl64.points.channel("time").astype(np.float64).copy()
    t[::50] = 0.0  # an odd column count has no firing exactly at t = 0: make some
    hdl64 = hdl64.with_points(hdl64.points.with_channel("time", t))
    mutant = op.apply(hdl64, params)
    shift = mutant.points.xyz.astype(np.float64) - hdl64.points.xyz
    np.testing.assert_allclose(shift[:, 0], -20.0 * t, atol=2e-5)
    assert np.all(shift[:, 1:] == 0)
    assert np.all(shift[t == 0] == 0) and np.count_nonzero(t == 0) > 0
    assert np.array_equal(mutant.points.data[:, 3:], hdl64.points.data[:, 3:])
    turning = op.apply(hdl64, params.model_copy(update={"yaw_rate": 30.0}))
    assert np.all(turning.points.xyz[t == 0] == hdl64.points.xyz[t == 0])
    # A rotation about z keeps each point's distance from the axis once the translation is undone.
    back = turning.points.xyz.astype(np.float64)
    np.testing.assert_allclose(np.hypot(back[:, 0], back[:, 1]),
                               np.hypot(hdl64.points.xyz[:, 0] - 20.0 * t, hdl64.points.xyz[:, 1]), atol=1e-3)


def test_motion_distortion_estimates_time_from_azimuth_like_the_simulator(hdl64):
    xyz = hdl64.points.xyz
    azimuth = np.arctan2(xyz[:, 1].astype(np.float64), xyz[:, 0].astype(np.float64))
    estimated = time_of_azimuth(azimuth, 10.0)
    np.testing.assert_allclose(estimated, SENSOR_PRESETS["HDL-64E"].time_of_azimuth(azimuth), atol=1e-9)
    np.testing.assert_allclose(estimated, hdl64.points.channel("time"), atol=1e-6)
    assert time_of_azimuth(np.array([0.0]))[0] == 0 and time_of_azimuth(np.array([np.pi / 2]))[0] < 0
    mutant, params = MotionDistortion(speed_range=(20.0, 20.0))(without(hdl64, "time"), rng())
    assert params.time_source == "azimuth"
    zeros = hdl64.with_points(hdl64.points.with_channel("time", np.zeros(len(xyz))))  # a reader's filler
    assert MotionDistortion()(zeros, rng())[1].time_source == "azimuth"
    shift = mutant.points.xyz.astype(np.float64) - xyz
    np.testing.assert_allclose(shift[:, 0], -20.0 * hdl64.points.channel("time"), atol=1e-4)


# --------------------------------------------------------------------------- calibration
def test_spatial_misalignment_moves_points_but_not_labels(hdl64):
    op = SpatialMisalignment.at_severity(5)
    mutant, params = op(hdl64, rng())
    assert mutant.boxes == hdl64.boxes and mutant.roi == hdl64.roi and mutant.calib == hdl64.calib
    m = op.matrix(params)
    np.testing.assert_allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(m[:3, :3]) == pytest.approx(1.0)
    expected = hdl64.points.xyz.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    np.testing.assert_allclose(mutant.points.xyz, expected, atol=1e-4)
    assert not np.allclose(mutant.points.xyz, hdl64.points.xyz, atol=1e-3)
    assert np.array_equal(mutant.points.data[:, 3:], hdl64.points.data[:, 3:])


# --------------------------------------------------------------------------- range
def test_range_degradation_cuts_far_returns_and_adds_radial_noise(hdl64):
    mutant, params = RangeDegradation(range_factor_range=(0.5, 0.5), noise_range=(0.2, 0.2))(hdl64, rng())
    distance = np.linalg.norm(hdl64.points.xyz.astype(np.float64), axis=1)
    near = distance <= params.max_range
    assert len(mutant.points) == np.count_nonzero(near) < len(hdl64.points)
    before = hdl64.points.select(near)
    np.testing.assert_allclose(unit(mutant.points.xyz), unit(before.xyz), atol=1e-5)  # radial only
    error = np.linalg.norm(mutant.points.xyz.astype(np.float64), axis=1) - distance[near]
    close, far = distance[near] < 0.25 * params.max_range, distance[near] > 0.75 * params.max_range
    assert error[far].std() > 5 * error[close].std()
    assert error[far].std() == pytest.approx(0.2 * np.mean((distance[near][far] / params.max_range) ** 2), rel=0.15)
    assert np.array_equal(mutant.points.data[:, 3:], before.data[:, 3:])


# --------------------------------------------------------------------------- intensity
def test_intensity_quantisation_uses_n_levels_of_the_data_scale(hdl64):
    for factor, scale in ((1.0, 1.0), (255.0, 255.0)):
        scene = hdl64.with_points(hdl64.points.with_channel("intensity", hdl64.points.intensity * factor))
        mutant, params = IntensityQuantisation(levels_range=(8, 8))(scene, rng())
        assert params.scale == scale
        values = np.unique(mutant.points.intensity)
        assert len(values) <= 8
        steps = values / (scale / 7)
        np.testing.assert_allclose(steps, np.round(steps), atol=1e-4)
        assert np.abs(mutant.points.intensity - scene.points.intensity).max() <= scale / 7 + 1e-4
        assert np.array_equal(mutant.points.xyz, scene.points.xyz)
        assert np.array_equal(np.delete(mutant.points.data, 3, axis=1), np.delete(scene.points.data, 3, axis=1))


def test_intensity_saturation_clips_at_the_level(hdl64):
    mutant, params = IntensitySaturation(gain_range=(2.0, 2.0), level_range=(0.4, 0.4))(hdl64, rng())
    source, result = hdl64.points.intensity, mutant.points.intensity
    assert params.scale == 1.0 and result.max() == pytest.approx(0.4) and (source * 2 > 0.4).any()
    low = source * 2 < 0.4
    np.testing.assert_allclose(result[low], source[low] * 2, rtol=1e-6)
    assert np.array_equal(mutant.points.xyz, hdl64.points.xyz)
    scaled = hdl64.with_points(hdl64.points.with_channel("intensity", source * 255))
    assert IntensitySaturation(level_range=(0.4, 0.4))(scaled, rng())[0].points.intensity.max() == pytest.approx(102)


# --------------------------------------------------------------------------- jitter
@pytest.mark.parametrize("op", [GaussianJitter.at_severity(5), UniformJitter.at_severity(5),
                                ImpulseJitter.at_severity(5)], ids=lambda op: op.name)
def test_jitter_changes_positions_only(hdl64, op):
    # 3D_Corruptions_AD adds its noise to every column, intensity included.
    mutant, _ = op(hdl64, rng())
    assert np.array_equal(mutant.points.data[:, 3:], hdl64.points.data[:, 3:])
    assert mutant.points.channels == hdl64.points.channels
    assert not np.array_equal(mutant.points.xyz, hdl64.points.xyz)
    assert mutant.boxes == hdl64.boxes


def test_jitter_distributions(hdl64):
    xyz = hdl64.points.xyz.astype(np.float64)
    gauss, _ = GaussianJitter(sigma_range=(0.05, 0.05))(hdl64, rng())
    assert (gauss.points.xyz - xyz).std(axis=0) == pytest.approx([0.05] * 3, rel=0.03)
    box, _ = UniformJitter(amplitude_range=(0.05, 0.05))(hdl64, rng())
    offset = box.points.xyz - xyz
    assert np.abs(offset).max() <= 0.05 + 1e-5 and np.abs(offset).max() > 0.049
    impulse, _ = ImpulseJitter(ratio_range=(0.1, 0.1), offset_range=(0.5, 0.5))(hdl64, rng())
    offset = impulse.points.xyz - xyz
    moved = np.any(offset != 0, axis=1)
    assert np.count_nonzero(moved) == round(0.1 * len(xyz))
    np.testing.assert_allclose(np.abs(offset[moved]), 0.5, atol=1e-4)
