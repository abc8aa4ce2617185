"""The simple operators' faster helpers compute what the code they replaced computed (issue 25).

``test_bit_identity.py`` compares whole operator outputs on two frames; these tests compare each
helper with the expression it replaced, as that expression, on inputs chosen to reach its corner
cases (ties, signed zeros, NaN, points at the edge of a region, near-equal farthest ranges).
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators.lidar.common import in_axis_box, mod_period
from lidarfuzz.operators.lidar.geometric import CHUNK, transformed_points
from lidarfuzz.operators.lidar.points import (
    EXTENT_BLOCK,
    _extent,
    _farthest_in_plane,
    _in_column,
    _planar_squares_and_extents,
    _z_extent,
)
from lidarfuzz.operators.lidar.returns import (
    BLOCK,
    _falling_within_rings,
    _narrow_rings,
    far_neighbour,
    range_and_azimuth,
    ring_azimuth_order,
)
from lidarfuzz.operators.lidar.sensor import SQUARED_BLOCK, _present_rings, _squared_ranges, farthest_range
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
                                   np.array([70_000, 1, 1]), np.array([-5, 2, 2, -1])])
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


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("period", [360.0, 2.0 * np.pi])
def test_mod_period_is_np_mod(dtype: type, period: float) -> None:
    """Bit for bit, on [−p, 2p) and its edges (±0, ±p, 2p less one ulp, values a rounding away from
    p), in place and not; values outside that interval (NaN, ±inf, 2p and beyond) take np.mod."""
    rng = np.random.default_rng(8)
    p = dtype(period)
    values = rng.uniform(-float(p), 2 * float(p), 50_000).astype(dtype)
    edges = [0.0, -0.0, -p, p, np.nextafter(p, dtype(0)), np.nextafter(p, dtype(3 * p)),
             np.nextafter(2 * p, dtype(0)), np.nextafter(-p, dtype(0)), np.nextafter(dtype(0), dtype(-1))]
    values[: len(edges)] = edges
    expected = np.mod(values, period)
    got = mod_period(values, period)
    assert got.dtype == expected.dtype and got.tobytes() == expected.tobytes()
    in_place = values.copy()
    assert mod_period(in_place, period, out=in_place) is in_place and in_place.tobytes() == expected.tobytes()
    for outside in (np.nan, np.inf, -np.inf, 2 * float(p), -2 * float(p), 1e9):
        wide = values.copy()
        wide[-1] = outside
        with np.errstate(invalid="ignore"):  # np.mod(±inf) is NaN, with a warning
            np.testing.assert_array_equal(mod_period(wide, period), np.mod(wide, period))
    assert mod_period(np.zeros(0, dtype), period).shape == (0,)


def far_neighbour_as_before(cloud: PointCloud, ring: np.ndarray, edge_m: float, max_gap_deg: float) -> np.ndarray:
    """far_neighbour as it was computed before the scan-order path: a full float64 copy, lexsort,
    the next neighbour first and the previous one when farther still."""
    n = len(cloud)
    result = np.full(n, -1, np.int64)
    xyz = cloud.xyz.astype(np.float64)
    distance = np.sqrt(np.einsum("ij,ij->i", xyz, xyz))
    azimuth = np.arctan2(xyz[:, 1], xyz[:, 0])
    order = np.lexsort((azimuth, ring))
    ring_s, az_s, dist_s = ring[order], azimuth[order], distance[order]
    adjacent = (ring_s[1:] == ring_s[:-1]) & (ring_s[1:] >= 0) & (np.diff(az_s) <= np.radians(max_gap_deg))
    best = np.full(n, -1, np.int64)
    best_range = dist_s + edge_m
    farther = adjacent & (dist_s[1:] > best_range[:-1])
    best[:-1][farther] = np.flatnonzero(farther) + 1
    best_range[:-1][farther] = dist_s[1:][farther]
    farther = adjacent & (dist_s[:-1] > best_range[1:])
    best[1:][farther] = np.flatnonzero(farther)
    has = best >= 0
    result[order[has]] = order[best[has]]
    return result


def scan_cloud(rng: np.random.Generator, rings: int, columns: int) -> tuple[PointCloud, np.ndarray]:
    """A spinning sensor's frame in firing order: column by column (azimuth falling), each column's
    rings in turn; ranges jump between a near and a far surface so that edges exist, some
    neighbours are more than a degree apart (gaps of sky), and a few firings have no return."""
    azimuth = np.repeat(np.pi - (np.arange(columns) + 0.5) * (2 * np.pi / columns), rings)
    azimuth += rng.uniform(-1e-4, 1e-4, len(azimuth))  # per-ring offsets, well under half a column
    ring = np.tile(np.arange(rings), columns)
    distance = np.where(rng.random(len(ring)) < 0.3, rng.uniform(2, 8, len(ring)), rng.uniform(10, 60, len(ring)))
    elevation = np.radians(-20 + 0.5 * ring)
    xyz = np.c_[distance * np.cos(elevation) * np.cos(azimuth), distance * np.cos(elevation) * np.sin(azimuth),
                distance * np.sin(elevation)]
    present = rng.random(len(ring)) > 0.1
    data = np.c_[xyz, rng.random(len(ring)), ring][present].astype(np.float32)
    return PointCloud(data, ("x", "y", "z", "intensity", "ring")), ring[present].astype(np.int64)


@pytest.mark.parametrize("arrangement", ["scan order", "reversed", "shuffled", "unknown rings", "wide rings",
                                         "a tie", "a NaN"])
def test_far_neighbour_is_as_before(arrangement: str) -> None:
    """The scan-order path (no azimuth sort), the sorted path (rings out of order, ties, NaN) and
    the lexsort path (rings beyond int16) all give what the lexsort code gave."""
    rng = np.random.default_rng(12)
    cloud, ring = scan_cloud(rng, 16, 1_500)
    data = cloud.data.copy()
    if arrangement == "reversed":
        data, ring = data[::-1].copy(), ring[::-1].copy()
    elif arrangement == "shuffled":
        order = rng.permutation(len(ring))
        data, ring = data[order], ring[order]
    elif arrangement == "unknown rings":
        ring[::7] = -1
    elif arrangement == "wide rings":
        ring = ring * 5_000
    elif arrangement == "a tie":
        first, second = np.flatnonzero(ring == 0)[:2]
        data[second, :2] = data[first, :2]  # ring 0's first two firings at one azimuth
    elif arrangement == "a NaN":
        data[5, 0] = np.nan
    cloud = PointCloud(data, cloud.channels)
    narrow = _narrow_rings(ring)
    if narrow is None:  # which path the arrangement takes
        assert arrangement == "wide rings"
    elif arrangement != "unknown rings":  # (the unknown ones: from several rings of a column)
        by_ring = np.argsort(narrow, kind="stable")
        _, azimuth = range_and_azimuth(cloud.data)
        assert _falling_within_rings(narrow[by_ring], azimuth[by_ring]) == (arrangement == "scan order")
    for edge_m, max_gap_deg in [(1.0, 1.0), (0.3, 0.1), (5.0, 3.0)]:
        expected = far_neighbour_as_before(cloud, ring, edge_m, max_gap_deg)
        assert np.array_equal(far_neighbour(cloud, ring, edge_m, max_gap_deg), expected)
    assert (expected >= 0).sum() > 100  # edges were there to find


def test_range_and_azimuth_are_the_whole_arrays() -> None:
    """Block by block (several blocks and a shorter last one) as on the whole N×3 float64 copy."""
    rng = np.random.default_rng(13)
    cloud = random_cloud(rng, 2 * BLOCK + 1_234)
    xyz = cloud.xyz.astype(np.float64)
    distance, azimuth = range_and_azimuth(cloud.data)
    assert distance.tobytes() == np.sqrt(np.einsum("ij,ij->i", xyz, xyz)).tobytes()
    assert azimuth.tobytes() == np.arctan2(xyz[:, 1], xyz[:, 0]).tobytes()


def test_farthest_in_plane_is_the_full_hypot_maximum() -> None:
    """Also with a crowd of points within float32 rounding of the farthest planar range, and with
    NaN or infinite coordinates (the full computation)."""
    rng = np.random.default_rng(14)
    for _ in range(50):
        angle = rng.uniform(-np.pi, np.pi, 5_000)
        ranges = rng.uniform(1.0, 80.0, 5_000)
        ranges[:200] = 80.0 * (1 + rng.uniform(-3e-7, 3e-7, 200))
        xyz = np.c_[ranges * np.cos(angle), ranges * np.sin(angle), rng.normal(0, 2, 5_000)]
        cloud = cloud_of(xyz, rng)
        assert _farthest_in_plane(cloud) == float(np.hypot(cloud.xyz[:, 0], cloud.xyz[:, 1]).max())
    for bad in (np.nan, np.inf, 3e20):
        xyz[7, 1] = bad
        cloud = cloud_of(xyz, rng)
        expected = float(np.hypot(cloud.xyz[:, 0], cloud.xyz[:, 1]).max())
        assert _farthest_in_plane(cloud) == expected or (np.isnan(expected) and np.isnan(_farthest_in_plane(cloud)))


def test_squared_ranges_in_blocks_are_the_column_sums() -> None:
    rng = np.random.default_rng(15)
    cloud = random_cloud(rng, 2 * SQUARED_BLOCK + 77)
    x, y, z = (cloud.xyz[:, i] for i in range(3))
    assert _squared_ranges(cloud).tobytes() == ((x * x + y * y) + z * z).tobytes()
    assert _squared_ranges(random_cloud(rng, 0)).shape == (0,)


@pytest.mark.parametrize("nan", [False, True])
def test_extents_in_one_pass_are_the_column_reductions(nan: bool) -> None:
    """_extent against cloud_extent, and the planar squares and z / intensity extents against
    the whole columns' arithmetic and reductions, over several blocks and a shorter last one."""
    from lidarfuzz.operators.lidar.common import cloud_extent

    rng = np.random.default_rng(16)
    cloud = random_cloud(rng, 2 * EXTENT_BLOCK + 555)
    if nan:
        data = cloud.data.copy()
        data[EXTENT_BLOCK + 3, 2] = np.nan  # z of a point in the second block
        cloud = PointCloud(data, cloud.channels)
    low, high = _extent(cloud)
    expected_low, expected_high = cloud_extent(cloud)
    np.testing.assert_array_equal(low, expected_low)
    np.testing.assert_array_equal(high, expected_high)
    squared, extents = _planar_squares_and_extents(cloud)
    x, y, z, intensity = (cloud.data[:, i] for i in range(4))
    assert squared.tobytes() == (x * x + y * y).tobytes()
    np.testing.assert_array_equal(extents, [z.min(), z.max(), intensity.min(), intensity.max()])
    assert _farthest_in_plane(cloud, squared) == _farthest_in_plane(cloud) == float(np.hypot(x, y).max())
