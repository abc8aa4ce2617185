"""Weather operators: fog, rain, snow and wet ground behave as their physical models say."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators.lidar.weather import (
    FOG_OVERLAP,
    Fog,
    Rain,
    Snow,
    WetGround,
    fog_soft_response,
    ground_mask,
    ground_plane,
    infer_intensity_scale,
)
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim import GenerationConfig, render_frames


@pytest.fixture(scope="module")
def hdl64() -> Scene:
    """An HDL-64E frame whose points carry their original index in a foreign ``index`` channel."""
    scene = next(render_frames(GenerationConfig(frames=1, seed=0)))
    return scene.with_points(scene.points.with_channel("index", np.arange(len(scene.points))))


def rng(trial: int = 0) -> np.random.Generator:
    return np.random.default_rng(trial)


def origin(scene: Scene, mutant: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(original index, original range, new range) of every surviving point."""
    index = mutant.points.channel("index").astype(np.int64)
    before = np.linalg.norm(scene.points.xyz[index].astype(np.float64), axis=1)
    after = np.linalg.norm(mutant.points.xyz.astype(np.float64), axis=1)
    return index, before, after


def byte_scaled(scene: Scene) -> Scene:
    return scene.with_points(scene.points.with_channel("intensity", scene.points.intensity * 255.0))


# --------------------------------------------------------------------------- fog
def test_fog_gives_the_same_result_for_unit_and_byte_intensities(hdl64):
    # The public tool rounds attenuated intensities as if they were 0-255 integers: on [0, 1] data
    # every hard return rounds to 0 and nearly the whole cloud becomes fog. (MOR 50 m: the
    # simulator's darker intensities leave no fog return at 150 m visibility.)
    op = Fog(mor_range=(50.0, 50.0))
    unit, p_unit = op(hdl64, rng())
    byte, p_byte = op(byte_scaled(hdl64), rng())
    assert (p_unit.intensity_scale, p_byte.intensity_scale) == (1.0, 255.0)
    _, before, after = origin(hdl64, unit)
    fog_share = float(np.mean(after < before - 0.5))
    assert 0.0 < fog_share < 0.02
    assert np.array_equal(unit.points.channel("index"), byte.points.channel("index"))
    np.testing.assert_allclose(byte.points.xyz, unit.points.xyz, atol=1e-4)
    np.testing.assert_allclose(byte.points.intensity, unit.points.intensity * 255.0, rtol=1e-4, atol=1e-4)


def test_fog_attenuation_and_loss_grow_as_visibility_shrinks(hdl64):
    kept, mean_intensity = [], []
    for mor in (750.0, 150.0, 50.0):
        mutant = Fog(mor_range=(mor, mor)).apply(hdl64, Fog(mor_range=(mor, mor)).sample(rng(), hdl64))
        index, before, after = origin(hdl64, mutant)
        hard = np.abs(after - before) < 1e-3
        kept.append(len(mutant.points))
        ratio = mutant.points.intensity[hard] / np.maximum(hdl64.points.intensity[index[hard]], 1e-6)
        mean_intensity.append(float(np.mean(ratio[hdl64.points.intensity[index[hard]] > 0.01])))
        expected = np.exp(-2 * np.log(20) / mor * before[hard])
        bright = hdl64.points.intensity[index[hard]] > 0.05
        np.testing.assert_allclose(ratio[bright], expected[bright], rtol=1e-3)  # exp(-2 alpha R) on hard returns
    assert kept[0] > kept[1] > kept[2]
    assert mean_intensity[0] > mean_intensity[1] > mean_intensity[2]
    assert kept[2] < 0.995 * len(hdl64.points)


def test_fog_returns_are_near_the_sensor_and_keep_their_beam(hdl64):
    # MOR 40 m, the densest of severity 5: with the simulator's KITTI-like (darker) intensities
    # MOR 50 m leaves under a hundred fog returns to check.
    mutant, _ = Fog(mor_range=(40.0, 40.0))(hdl64, rng())
    assert np.all(np.isfinite(mutant.points.data))
    index, before, after = origin(hdl64, mutant)
    fog = after < before - 0.5
    assert fog.sum() > 100
    assert after[fog].max() < 15.0 and after[fog].min() >= FOG_OVERLAP[0]
    source, moved = hdl64.points, mutant.points
    for name in ("ring", "time"):
        assert np.array_equal(moved.channel(name), source.channel(name)[index])
    assert np.all(moved.channel("label")[fog] == 0) and np.all(moved.channel("instance")[fog] == -1)
    assert np.array_equal(moved.channel("label")[~fog], source.channel("label")[index[~fog]])
    # Moved along their own beam: same direction from the sensor.
    direction = source.xyz[index[fog]] / before[fog, None]
    np.testing.assert_allclose(moved.xyz[fog] / after[fog, None], direction, atol=1e-4)


def test_fog_soft_response_peaks_a_few_metres_out_and_attenuates_itself():
    r0, thin, where = fog_soft_response(np.log(20) / 500, 20e-9)
    _, dense, _ = fog_soft_response(np.log(20) / 50, 20e-9)
    assert np.all(thin >= 0) and thin[-1] > 0
    assert FOG_OVERLAP[0] <= where[-1] < 8.0
    assert np.all(np.diff(thin) >= -1e-15)  # more fog in front of a farther target, never less
    assert dense[-1] < thin[-1]  # per unit backscatter the denser fog attenuates its own return more
    assert thin[r0 < FOG_OVERLAP[0]].max() == 0  # no overlap of transmitter and receiver: no fog return


def test_intensity_scale_is_inferred_from_the_data(hdl64):
    assert infer_intensity_scale(hdl64.points) == 1.0
    assert infer_intensity_scale(byte_scaled(hdl64).points) == 255.0
    assert Fog(mor_range=(100.0, 100.0), intensity_scale=255.0).sample(rng(), hdl64).intensity_scale == 255.0


# --------------------------------------------------------------------------- rain and snow
def _clutter_and_loss(op, scene: Scene, trial: int = 0) -> tuple[int, int]:
    mutant = op.apply(scene, op.sample(rng(trial), scene))
    _, before, after = origin(scene, mutant)
    return int(np.sum(after < before - 0.5)), len(scene.points) - len(mutant.points)


def test_rain_clutter_and_loss_grow_with_the_rate(hdl64):
    results = [_clutter_and_loss(Rain(rate_range=(rate, rate)), hdl64) for rate in (1.0, 10.0, 60.0)]
    clutter, lost = zip(*results, strict=True)
    assert clutter[0] < clutter[1] < clutter[2]
    assert lost[0] <= lost[1] <= lost[2] and lost[2] > lost[0]


def test_rain_extinction_matches_the_literature():
    # About 1 dB/km at 1 mm/h, rising as R^0.6-0.7 (905 nm rain attenuation measurements).
    assert 1.5e-4 < Rain.extinction(1.0) < 4e-4
    assert 1e-3 < Rain.extinction(10.0) < 2.5e-3
    assert Rain.extinction(0.0) == 0.0


def test_rain_at_zero_rate_is_the_identity(hdl64):
    op = Rain(rate_range=(0.0, 0.0))
    params = op.sample(rng(), hdl64)
    assert params.is_identity() and op.apply(hdl64, params) is hdl64


def test_snow_gives_more_clutter_than_rain_at_equal_water_equivalent_rate(hdl64):
    # Gunn-Marshall flakes: about half the slope of Marshall-Palmer drops at the same rate, so many
    # more large particles; the model documents more extinction and more near returns.
    assert Snow.extinction(2.0) > 2 * Rain.extinction(2.0)
    snow, _ = _clutter_and_loss(Snow(rate_range=(2.0, 2.0)), hdl64)
    rain, _ = _clutter_and_loss(Rain(rate_range=(2.0, 2.0)), hdl64)
    assert snow > 1.5 * rain


@pytest.mark.parametrize("operator", [Rain, Snow])
def test_precipitation_returns_are_near_weak_and_keep_their_beam(operator, hdl64):
    mutant, _ = operator.at_severity(5)(hdl64, rng())
    assert np.all(np.isfinite(mutant.points.data))
    index, before, after = origin(hdl64, mutant)
    spurious = after < before - 0.5
    assert spurious.sum() > 50
    assert after[spurious].max() < 40.0 and after[spurious].min() >= 1.5
    assert mutant.points.intensity[spurious].max() < 0.05  # water/ice Fresnel reflectance is about 2 %
    for name in ("ring", "time"):
        assert np.array_equal(mutant.points.channel(name), hdl64.points.channel(name)[index])
    assert np.all(mutant.points.channel("instance")[spurious] == -1)
    # The rest stay on their surface, within the extra range noise.
    assert np.abs(after[~spurious] - before[~spurious]).max() < 0.5


# --------------------------------------------------------------------------- wet ground
def test_wet_ground_changes_only_ground_points(hdl64):
    mutant, _ = WetGround(wetness_range=(1.0, 1.0))(hdl64, rng())
    index = mutant.points.channel("index").astype(np.int64)
    ground = ground_mask(hdl64.points)
    source = hdl64.points.data[index]
    other = ~ground[index]
    assert np.array_equal(mutant.points.data[other], source[other])
    assert np.all(ground[np.setdiff1d(np.arange(len(hdl64.points)), index)])  # only ground drops out
    assert np.all(mutant.points.intensity[~other] <= source[~other, 3])
    # Every kept ground return with a reading above 0 gets darker; a reading of 0 (the simulator's
    # realistic receiver reports them, as KITTI does for 8-26 % of returns) cannot read lower.
    lit = ~other & (source[:, 3] > 0)
    assert np.mean(mutant.points.intensity[lit] < source[lit, 3]) > 0.99
    assert np.array_equal(mutant.points.xyz, source[:, :3])


def test_wet_ground_darkens_and_drops_far_ground_more_than_near(hdl64):
    op = WetGround(wetness_range=(1.0, 1.0))
    mutant = op.apply(hdl64, op.sample(rng(), hdl64))
    ground = ground_mask(hdl64.points)
    ranges = np.linalg.norm(hdl64.points.xyz, axis=1)
    index = mutant.points.channel("index").astype(np.int64)
    factor = mutant.points.intensity / np.maximum(hdl64.points.intensity[index], 1e-6)
    kept_ground = ground[index] & (hdl64.points.intensity[index] > 0.02)
    near = kept_ground & (ranges[index] < 8)
    far = kept_ground & (ranges[index] > 20)
    assert np.median(factor[far]) < 0.5 * np.median(factor[near])
    dropped = np.setdiff1d(np.flatnonzero(ground), index)
    assert len(dropped) > 0 and np.median(ranges[dropped]) > 20
    drop_share_near = np.isin(np.flatnonzero(ground & (ranges < 8)), dropped).mean()
    drop_share_far = np.isin(np.flatnonzero(ground & (ranges > 25)), dropped).mean()
    assert drop_share_far > drop_share_near


def test_wet_ground_without_labels_uses_the_ground_plane(hdl64):
    unlabelled = hdl64.with_points(hdl64.points.without_channels(["label"]))
    mutant, _ = WetGround.at_severity(5)(unlabelled, rng())
    index = mutant.points.channel("index").astype(np.int64)
    changed = mutant.points.intensity != unlabelled.points.intensity[index]
    assert changed.sum() > 0.2 * len(mutant.points)
    # The simulator's ground is not flat (grade, camber): judged by its labels and by the height
    # above the fitted plane rather than by z. The plane's 0.2 m band holds ground, not walls or cars.
    assert ground_mask(hdl64.points)[index][changed].mean() > 0.9
    normal, offset = ground_plane(unlabelled.points.xyz.astype(np.float64))
    height = unlabelled.points.xyz[index].astype(np.float64) @ normal - offset
    assert not changed[np.abs(height) > 0.25].any()
    # Most labelled ground is found by the plane too.
    near_ground = ground_mask(hdl64.points) & (np.linalg.norm(hdl64.points.xyz, axis=1) < 20)
    assert np.mean(ground_mask(unlabelled.points)[near_ground]) > 0.8


@pytest.mark.parametrize("operator", [Rain, Snow, WetGround])
def test_unit_and_byte_intensities_give_the_same_result(operator, hdl64):
    op = operator.at_severity(4)
    unit, p_unit = op(hdl64, rng(5))
    byte, p_byte = op(byte_scaled(hdl64), rng(5))
    assert (p_unit.intensity_scale, p_byte.intensity_scale) == (1.0, 255.0)
    assert np.array_equal(unit.points.channel("index"), byte.points.channel("index"))
    np.testing.assert_allclose(byte.points.xyz, unit.points.xyz, atol=1e-4)
    np.testing.assert_allclose(byte.points.intensity, unit.points.intensity * 255.0, rtol=1e-4, atol=1e-3)


def test_rain_attenuates_hard_returns_by_two_way_extinction(hdl64):
    op = Rain(rate_range=(20.0, 20.0), range_accuracy=0.0)
    mutant, _ = op(hdl64, rng())
    index, before, after = origin(hdl64, mutant)
    hard = np.abs(after - before) < 1e-3
    expected = hdl64.points.intensity[index[hard]] * np.exp(-2 * Rain.extinction(20.0) * before[hard])
    np.testing.assert_allclose(mutant.points.intensity[hard], expected, rtol=1e-5, atol=1e-7)
    assert np.all(mutant.points.intensity[hard] <= hdl64.points.intensity[index[hard]])
