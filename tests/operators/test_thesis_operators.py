"""The thesis's operators against chapter 3.2's definitions: RRPD deletes a random share of its
region, UNA's noise is uniform, RIM raises or lowers. Expected values are worked out by hand in
the comments."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from lidarfuzz.operators import generator
from lidarfuzz.operators.lidar.points import (
    RandomRegionPointDeletion,
    RegionDeletionParams,
    RegionIntensityParams,
    RegionIntensityScaling,
    UniformNoiseAddition,
    UniformNoiseParams,
)
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


def rng(trial: int = 0) -> np.random.Generator:
    return generator(3, "000000", 0, trial)


def grid_scene(count: int = 1000, intensity: float = 0.5) -> Scene:
    """``count`` points on a line inside the unit cube at the origin, intensity constant."""
    xyz = np.column_stack([np.linspace(-0.4, 0.4, count), np.zeros(count), np.zeros(count)])
    return Scene(PointCloud(np.column_stack([xyz, np.full(count, intensity)]).astype(np.float32)))


# --------------------------------------------------------------------------- RRPD
def test_rrpd_deletes_a_binomial_share_of_the_region():
    scene = grid_scene(1000)
    op = RandomRegionPointDeletion()
    params = RegionDeletionParams(center=(0.0, 0.0, 0.0), size=(1.0, 1.0, 1.0), share=0.5, seed=11)
    deleted = 1000 - len(op.apply(scene, params).points)
    # Binomial(1000, 0.5): mean 500, std sqrt(1000 * 0.25) = 15.8; 5 std either side is 421..579.
    assert 421 <= deleted <= 579
    assert op.apply(scene, params).points == op.apply(scene, params).points  # from params alone


def test_rrpd_share_one_deletes_the_whole_region_and_nothing_outside():
    # 1000 points spaced 0.8/999 m over x in [-0.4, 0.4]; the region x in [-0.1, 0.1] holds the
    # points with |x| <= 0.1: index k with |-0.4 + k*0.8/999| <= 0.1, k = 375..624 → 250 points.
    scene = grid_scene(1000)
    op = RandomRegionPointDeletion()
    old = RegionDeletionParams(center=(0.0, 0.0, 0.0), size=(0.2, 1.0, 1.0))  # params stored before the share
    assert old.share == 1.0
    kept = op.apply(scene, old).points
    assert len(kept) == 750
    assert np.all(np.abs(kept.xyz[:, 0]) > 0.1)


def test_rrpd_severity_table_draws_a_share_from_its_range():
    shares = [RandomRegionPointDeletion.at_severity(3).sample(rng(t), grid_scene(50)).share for t in range(20)]
    assert all(0.4 <= s <= 0.7 for s in shares) and len(set(shares)) == 20
    with pytest.raises(ValidationError, match="share_range"):
        RandomRegionPointDeletion(share_range=(0.5, 1.5))


# --------------------------------------------------------------------------- UNA
def test_una_uniform_noise_is_bounded_with_variance_a_squared_over_three():
    scene = grid_scene(1000)
    a = 0.3
    params = UniformNoiseParams(ratio=20.0, jitter=a, distribution="uniform", seed=5)  # 20 000 noise points
    mutant = UniformNoiseAddition().apply(scene, params)
    added = mutant.points.xyz[1000:].astype(np.float64)
    assert len(added) == 20000
    # y and z of every base point are 0, so the added y, z are the offsets themselves
    offsets = added[:, 1:]
    assert np.all(np.abs(offsets) <= a + 1e-6)
    # uniform on [-a, a]: variance a²/3 = 0.03; the sample variance of 20 000 draws has a relative
    # standard error of about sqrt(0.8 / 20000) = 0.6 %, so 5 % is far outside chance
    assert np.allclose(offsets.var(axis=0), a * a / 3, rtol=0.05)


def test_una_gaussian_option_and_old_params_keep_gaussian_offsets():
    assert UniformNoiseAddition().config.distribution == "uniform"
    old = UniformNoiseParams.model_validate({"ratio": 20.0, "jitter": 0.1, "seed": 5})  # stored before the option
    assert old.distribution == "gaussian"
    offsets = UniformNoiseAddition().apply(grid_scene(1000), old).points.xyz[1000:, 1:].astype(np.float64)
    # Gaussian with std 0.1: about 0.27 % of draws beyond 3 std (0.3), which uniform[-0.1, 0.1] never gives
    assert np.abs(offsets).max() > 0.1
    assert np.allclose(offsets.std(axis=0), 0.1, rtol=0.05)
    op = UniformNoiseAddition(distribution="gaussian")
    assert op.sample(rng(), grid_scene(10)).distribution == "gaussian"


# --------------------------------------------------------------------------- RIM
def test_rim_raises_where_the_factor_is_above_one_and_clips_at_the_full_scale():
    # intensities 0.2 and 0.6 in a [0, 1] frame; a factor 2.5 gives 0.5 and 1.5 → clipped to 1.0
    cloud = PointCloud(np.array([[0, 0, 0, 0.2], [0.1, 0, 0, 0.6], [5, 5, 0, 0.6]], np.float32))
    scene = Scene(cloud)
    params = RegionIntensityParams(center=(0.0, 0.0, 0.0), size=(1.0, 1.0, 1.0), factor=2.5)
    out = RegionIntensityScaling().apply(scene, params).points.intensity
    assert np.allclose(out, [0.5, 1.0, 0.6])  # the point outside the region keeps 0.6


def test_rim_direction_lower_raise_and_both():
    scene = grid_scene(20)
    lower = RegionIntensityScaling(factor_range=(0.4, 0.4), direction="lower")
    high = RegionIntensityScaling(factor_range=(0.4, 0.4), direction="raise")
    assert lower.sample(rng(), scene).factor == 0.4
    assert high.sample(rng(), scene).factor == pytest.approx(2.5)  # 1 / 0.4
    # "both": even odds; 40 draws are all one way with chance 2 * 0.5**40
    factors = {round(RegionIntensityScaling.at_severity(3).sample(rng(t), scene).factor, 6) for t in range(40)}
    assert factors == {0.4, 2.5}
    with pytest.raises(ValidationError, match="factor_range"):
        RegionIntensityScaling(factor_range=(0.0, 0.5), direction="both")
