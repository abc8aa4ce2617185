"""The simple operators' faster helpers compute what the code they replaced computed (issue 25).

``test_bit_identity.py`` compares whole operator outputs on two frames; these tests compare each
helper with the expression it replaced, as that expression, on inputs chosen to reach its corner
cases (ties, signed zeros, NaN, points at the edge of a region, near-equal farthest ranges).
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators.lidar.common import in_axis_box
from lidarfuzz.operators.lidar.geometric import CHUNK, transformed_points
from lidarfuzz.operators.lidar.points import _in_column, _z_extent
from lidarfuzz.operators.lidar.returns import ring_azimuth_order
from lidarfuzz.operators.lidar.sensor import _present_rings, farthest_range
from lidarfuzz.scene.points import STANDARD_CHANNELS, PointCloud


def cloud_of(xyz: np.ndarray, rng: np.random.Generator) -> PointCloud:
    intensity = rng.random(len(xyz))
    return PointCloud(np.column_stack([xyz, intensity]).astype(np.float32), STANDARD_CHANNELS[:4])


def random_cloud(rng: np.random.Generator, n: int) -> PointCloud:
    xyz = rng.normal(0.0, 30.0, (n, 3))
    xyz[: n // 50] = 0.0  # exact zeros: products with 0 and ±0 sums
    xyz[n // 50: n // 25] = -0.0
    return cloud_of(xyz, rng)


def rotation(roll: float, pitch: float, yaw: float, offset: tuple[float, float, float]) -> np.ndarray:
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    m = np.eye(4)
    m[:3, :3] = (np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
                 @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]]))
    m[:3, 3] = offset
    return m


def matrix_product(cloud: PointCloud, m: np.ndarray) -> np.ndarray:
    """What the operators computed before: one float64 product of the whole cloud, rounded once."""
    return (cloud.xyz.astype(np.float64) @ m[:3, :3].T + m[:3, 3]).astype(np.float32)


@pytest.mark.parametrize("kind", ["rotate_z", "translate", "height", "misalignment"])
def test_transformed_points_match_the_matrix_product(kind: str) -> None:
    """Column-wise float64 sums against BLAS's product: both compute Σ x_k·m_ik + t_i in float64 and
    round once to float32. Skipping exact-zero coefficients changes no float64 value (x·0 = ±0,
    and s ± 0 = s; a ±0 sum becomes +0 when the offset, even 0, is added, as in the product). The
    one freedom BLAS has is a fused multiply-add, whose float64 result differs from two roundings
    by at most one float64 ulp; after rounding to float32 (29 bits coarser) that flips the float32
    value only when the sum lies within 2⁻⁵² relative of a float32 rounding boundary — chance
    about 2⁻²⁸ per value — and then by one float32 ulp. Hence: at most 1 ulp, and (on the 30
    transforms × 3 · 20,000 values here, expectation ≪ 1) at most 3 values differing at all."""
    rng = np.random.default_rng(25)
    cloud = random_cloud(rng, 2 * CHUNK + 3_617)  # blocks of CHUNK and a shorter last one
    differing = 0
    for _ in range(30):
        angle = rng.uniform(-np.pi, np.pi)
        if kind == "rotate_z":
            m = rotation(0.0, 0.0, angle, (0.0, 0.0, 0.0))
        elif kind == "translate":
            m = rotation(0.0, 0.0, 0.0, tuple(rng.normal(0, 5, 3)))
        elif kind == "height":
            m = rotation(0.0, 0.0, 0.0, (0.0, 0.0, rng.normal(0, 0.5)))
        else:
            m = rotation(*rng.normal(0, 0.01, 3), tuple(rng.normal(0, 0.05, 3)))
        expected = matrix_product(cloud, m)
        got = transformed_points(cloud, m)
        np.testing.assert_array_max_ulp(got.xyz, expected, maxulp=1)
        differing += int((got.xyz.view(np.uint32) != expected.view(np.uint32)).sum())
        assert np.array_equal(got.data[:, 3:], cloud.data[:, 3:])  # other channels untouched
    assert differing <= 3


def test_a_pure_scaling_keeps_negative_zero() -> None:
    """global_scale computed x · f (no offset): −0 · f is −0, which the offset-free path keeps."""
    rng = np.random.default_rng(3)
    cloud = random_cloud(rng, 1_000)
    m = np.diag([1.37, 1.37, 1.37, 1.0])
    expected = (cloud.xyz.astype(np.float64) * 1.37).astype(np.float32)
    got = transformed_points(cloud, m, offset=False).xyz
    assert np.array_equal(got.view(np.uint32), expected.view(np.uint32))
    assert np.signbit(got[cloud.xyz == 0]).sum() == np.signbit(cloud.xyz[cloud.xyz == 0]).sum() > 0


def test_farthest_range_is_the_full_float64_maximum() -> None:
    """The candidates' float64 norms give the whole cloud's maximum exactly, also when many points
    lie within float32 rounding of the farthest one (directions differ, ranges nearly equal)."""
    rng = np.random.default_rng(11)
    for _ in range(50):
        direction = rng.normal(size=(5_000, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        ranges = rng.uniform(1.0, 80.0, 5_000)
        ranges[:200] = 80.0 * (1 + rng.uniform(-3e-7, 3e-7, 200))  # a crowd at the float32 resolution
        cloud = cloud_of(direction * ranges[:, None], rng)
        expected = float(np.linalg.norm(cloud.xyz.astype(np.float64), axis=1).max())
        assert farthest_range(cloud) == expected


def test_farthest_range_with_non_finite_points_is_as_before() -> None:
    rng = np.random.default_rng(2)
    xyz = rng.normal(size=(100, 3))
    xyz[7] = [np.nan, 0.0, 0.0]
    cloud = cloud_of(xyz, rng)
    assert np.isnan(farthest_range(cloud))
    xyz[7] = [np.inf, 0.0, 0.0]
    assert farthest_range(cloud_of(xyz, rng)) == np.inf


@pytest.mark.parametrize("rings", [np.array([3, 3, -1, 0, 63, 5, 5]), np.array([-1, -1]), np.array([], np.int64),
                                   np.array([70_000, 1, 1])])
def test_present_rings_are_the_distinct_known_ones(rings: np.ndarray) -> None:
    rings = rings.astype(np.int64)
    got = _present_rings(rings)
    expected = np.unique(rings[rings >= 0])
    assert got.dtype == expected.dtype and np.array_equal(got, expected)


def test_ring_azimuth_order_is_lexsort() -> None:
    """Ties (the same ring and azimuth: index order), NaN azimuths, unknown rings (−1), rings
    in scan order (falling azimuth, one run) and shuffled."""
    rng = np.random.default_rng(5)
    n = 20_000
    ring = rng.integers(-1, 64, n)
    azimuth = rng.choice(np.linspace(-np.pi, np.pi, 500), n)  # many exact ties
    azimuth[rng.integers(0, n, 20)] = np.nan
    assert np.array_equal(ring_azimuth_order(ring, azimuth), np.lexsort((azimuth, ring)))
    scan_ring = np.repeat(np.arange(64), 300)
    scan_azimuth = np.tile(np.linspace(np.pi, -np.pi, 300), 64)
    assert np.array_equal(ring_azimuth_order(scan_ring, scan_azimuth), np.lexsort((scan_azimuth, scan_ring)))
    wide = np.array([40_000, 2, 40_000, 2])  # beyond int16: lexsort itself
    assert np.array_equal(ring_azimuth_order(wide, np.zeros(4)), np.lexsort((np.zeros(4), wide)))


def test_in_column_is_in_axis_box() -> None:
    """Including points exactly on the region's faces (the float32 comparison decides)."""
    rng = np.random.default_rng(9)
    xyz = rng.uniform(-20, 20, (30_000, 3)).astype(np.float32)
    center, size = (1.5, -2.25, 0.0), (4.0, 4.0, 50.0)
    xyz[:100, 0] = np.float32(center[0] + size[0] / 2)  # on the faces
    xyz[100:200, 1] = np.float32(center[1] - size[1] / 2)
    assert np.array_equal(_in_column(xyz, center, size), in_axis_box(xyz, center, size))
    assert np.array_equal(_in_column(xyz[:0], center, size), in_axis_box(xyz[:0], center, size))


def test_z_extent_is_cloud_extents_z() -> None:
    from lidarfuzz.operators.lidar.common import cloud_extent

    cloud = random_cloud(np.random.default_rng(4), 1_000)
    lo, hi = cloud_extent(cloud)
    assert _z_extent(cloud) == (float(lo[2]), float(hi[2]))
