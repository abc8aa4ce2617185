"""The simple operators' faster helpers compute what the code they replaced computed (issue 25).

``test_bit_identity.py`` compares whole operator outputs on two frames; these tests compare each
helper with the expression it replaced, as that expression, on inputs chosen to reach its corner
cases (ties, signed zeros, NaN, points at the edge of a region, near-equal farthest ranges).
"""

from __future__ import annotations

import json
import threading
from typing import Any

import numpy as np
import pytest

from lidarfuzz.operators import available
from lidarfuzz.operators.lidar.common import (
    COLUMN_BLOCK,
    SCRATCH_KEEP_LIMIT,
    copy_with_maximum,
    in_axis_box,
    intensity_scale,
    mod_period,
    release_scratch,
    scene_intensity_scale,
    scratch,
)
from lidarfuzz.operators.lidar.geometric import CHUNK, transformed_points
from lidarfuzz.operators.lidar.points import (
    EXTENT_BLOCK,
    RegionIntensityParams,
    RegionIntensityScaling,
    _extent,
    _farthest_in_plane,
    _in_column,
    _planar_squares_and_extents,
    _z_extent,
)
from lidarfuzz.operators.lidar.power import effective_reflectivity, power_draw_stream, power_draws
from lidarfuzz.operators.lidar.returns import (
    BLOCK,
    DualReturn,
    DualReturnParams,
    _falling_within_rings,
    _narrow_rings,
    far_neighbour,
    range_and_azimuth,
    ring_azimuth_order,
)
from lidarfuzz.operators.lidar.sensor import (
    MOTION_BLOCK,
    SQUARED_BLOCK,
    CrossSensor,
    CrossSensorParams,
    MotionDistortion,
    MotionDistortionParams,
    _present_rings,
    _ring_mask,
    _rings_for,
    _squared_ranges,
    azimuth_rad,
    farthest_range,
    farthest_range_and_intensity_scale,
    time_of_azimuth,
)
from lidarfuzz.operators.lidar.weather import _BLOCK as WEATHER_BLOCK
from lidarfuzz.operators.lidar.weather import _GAUSS_NODES as GAUSS_NODES
from lidarfuzz.operators.lidar.weather import _GAUSS_WEIGHTS as GAUSS_WEIGHTS
from lidarfuzz.operators.lidar.weather import _GROUND_BLOCK as WET_BLOCK
from lidarfuzz.operators.lidar.weather import _PARTICLE_REACH as PARTICLE_REACH
from lidarfuzz.operators.lidar.weather import _TABLE_NODES_PER_DECADE as TABLE_NODES_PER_DECADE
from lidarfuzz.operators.lidar.weather import _TABLE_RANGE_STEP as TABLE_RANGE_STEP
from lidarfuzz.operators.lidar.weather import (
    FOG_OVERLAP,
    MIN_DIAMETER,
    SPEED_OF_LIGHT,
    WATER_INDEX,
    Rain,
    Snow,
    WetGround,
    WetGroundParams,
    _fresnel,
    _ground,
    _interp_near,
    _rescaled,
    cutoff_range,
    fog_soft_response,
    ground_plane,
    particle_table,
)
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.geometry import box_corners
from lidarfuzz.scene.labels import MIN_DEPTH, camera_labels, image_boxes, image_coverage
from lidarfuzz.scene.points import CHANNEL_DEFAULTS, STANDARD_CHANNELS, PointCloud
from lidarfuzz.scene.scene import Scene
from tests.operators.golden import GOLDEN, simd_features


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


@pytest.mark.parametrize("n", [300, COLUMN_BLOCK, 2 * COLUMN_BLOCK + 17])
def test_in_column_is_in_axis_box(n: int) -> None:
    """Including points exactly on the region's faces (the float32 comparison decides), NaN
    coordinates, a cloud of one block, and blocks that end inside and outside the region; the
    cloud as operators pass it (the strided x, y, z of an N×C array)."""
    rng = np.random.default_rng(9)
    data = rng.uniform(-20, 20, (n, 5)).astype(np.float32)
    xyz = data[:, :3]
    center, size = (1.5, -2.25, 0.0), (4.0, 4.0, 50.0)
    xyz[:100, 0] = np.float32(center[0] + size[0] / 2)  # on the faces
    xyz[100:200, 1] = np.float32(center[1] - size[1] / 2)
    xyz[200:210, 0], xyz[210:220, 1], xyz[220:230, 2] = np.nan, np.nan, np.nan
    xyz[-300:] = (1.5, -2.25, 0.0)  # the last block ends inside the region
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
                                         "a tie", "a NaN", "a late tie", "a late NaN"])
def test_far_neighbour_is_as_before(arrangement: str) -> None:
    """The scan-order path (no azimuth sort), the sorted path (rings out of order, ties, NaN; the
    late ones in the last ring, found by the scan-order path's last block of ring-sorted positions
    after the others passed) and the lexsort path (rings beyond int16) all give what the lexsort
    code gave."""
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
    elif arrangement == "a late tie":
        first, second = np.flatnonzero(ring == 15)[-2:]
        data[second, :2] = data[first, :2]  # the last ring's last two firings at one azimuth
    elif arrangement == "a late NaN":
        data[np.flatnonzero(ring == 15)[-1], 1] = np.nan
    cloud = PointCloud(data, cloud.channels)
    narrow = _narrow_rings(ring)
    if narrow is None:  # which path the arrangement takes
        assert arrangement == "wide rings"
    elif arrangement != "unknown rings":  # (the unknown ones: from several rings of a column)
        by_ring = np.argsort(narrow, kind="stable")
        _, azimuth = range_and_azimuth(cloud.data)
        assert _falling_within_rings(narrow[by_ring], azimuth[by_ring]) == (arrangement == "scan order")
        if arrangement.startswith("a late"):
            assert _falling_within_rings(narrow[by_ring][:-BLOCK], azimuth[by_ring][:-BLOCK])
    for edge_m, max_gap_deg in [(1.0, 1.0), (0.3, 0.1), (5.0, 3.0)]:
        expected = far_neighbour_as_before(cloud, ring, edge_m, max_gap_deg)
        assert np.array_equal(far_neighbour(cloud, ring, edge_m, max_gap_deg), expected)
    assert (expected >= 0).sum() > 100  # edges were there to find


@pytest.mark.parametrize("n", [1, 2 * BLOCK + 1_234, 200_000])
def test_range_and_azimuth_are_the_whole_arrays(n: int) -> None:
    """Block by block (several blocks and a shorter last one) as on the whole N×3 float64 copy:
    the einsum's sum of three squares bit for bit (200k points: thousands of rows where another
    order of the additions rounds differently), with zeros, ±0, infinities, NaN, subnormal and
    overflowing squares."""
    rng = np.random.default_rng(13)
    cloud = random_cloud(rng, n)
    if n > 100:
        data = cloud.data.copy()
        data[60:70, 0], data[70:80, 1], data[80:90, 2] = np.inf, -np.inf, np.nan
        data[90:95, :3], data[95:100, :3] = 1e-30, np.float32(3e38)
        cloud = PointCloud(data, cloud.channels)
    xyz = cloud.xyz.astype(np.float64)
    distance, azimuth = range_and_azimuth(cloud.data)
    reference = np.sqrt(np.einsum("ij,ij->i", xyz, xyz))
    if simd_features() == json.loads(GOLDEN.read_text())["simd"]:
        assert distance.tobytes() == reference.tobytes()
        assert azimuth.tobytes() == np.arctan2(xyz[:, 1], xyz[:, 0]).tobytes()
    else:  # einsum's order of the three additions (and arctan2's last bit) are the CPU's: one rounding
        np.testing.assert_allclose(distance, reference, rtol=4.5e-16, equal_nan=True)
        np.testing.assert_allclose(azimuth, np.arctan2(xyz[:, 1], xyz[:, 0]), rtol=4.5e-16, equal_nan=True)


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


@pytest.mark.parametrize("nan", [False, True])
@pytest.mark.parametrize("n", [1, COLUMN_BLOCK - 1, COLUMN_BLOCK, 2 * COLUMN_BLOCK + 17])
def test_copy_with_maximum_is_a_copy_and_the_column_maximum(n: int, nan: bool) -> None:
    rng = np.random.default_rng(n)
    data = rng.normal(0.0, 100.0, (n, 6)).astype(np.float32)
    if nan:
        data[n // 2, 3] = np.nan
    copy, top = copy_with_maximum(data, 3)
    assert copy.tobytes() == data.tobytes() and copy is not data
    expected = float(data[:, 3].max())
    assert top == expected or (np.isnan(top) and np.isnan(expected))


@pytest.mark.parametrize("case", ["inferred", "8-bit", "declared", "nan"])
def test_farthest_range_and_intensity_scale_in_one_pass(case: str) -> None:
    rng = np.random.default_rng(3)
    data = np.column_stack([rng.normal(0.0, 40.0, (3 * SQUARED_BLOCK + 5, 3)),
                            rng.random(3 * SQUARED_BLOCK + 5)]).astype(np.float32)
    if case == "8-bit":
        data[:, 3] *= 200.0
        data[SQUARED_BLOCK + 1, 3] = 254.5  # the maximum in a middle block
    if case == "nan":
        data[2 * SQUARED_BLOCK, 3] = np.nan
    metadata = {"intensity_scale": "uint16"} if case == "declared" else {}
    scene = Scene(PointCloud(data), metadata=metadata)
    farthest, scale = farthest_range_and_intensity_scale(scene)
    assert farthest == farthest_range(scene.points)
    expected = scene_intensity_scale(scene)  # declared, else intensity_scale of the whole column
    assert scale == expected or (np.isnan(scale) and np.isnan(expected))
    if case == "8-bit":
        assert scale == intensity_scale(scene.points.intensity) == 255.0


def former_camera_labels(calib: KittiCalibration, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(truncation, bbox2d, alpha) as camera_labels computed them before: the corners projected
    through P2 for their depth alone, then projected again by boxes_to_image; every box's
    in-front pixels gathered."""
    inside, front_uv = image_coverage(calib, boxes)
    b = np.asarray(boxes, np.float64).reshape(-1, 7)
    n = len(b)
    out = np.full((n, 4), np.nan)
    _, depth = calib.rect_to_image(calib.lidar_to_rect(box_corners(b).reshape(-1, 3)))
    in_front = np.all(depth.reshape(n, 8) > MIN_DEPTH, axis=1)
    if in_front.any():
        out[in_front] = calib.boxes_to_image(b[in_front])
    height, width = calib.image_shape
    for i in np.flatnonzero(~in_front):
        if len(front_uv[i]):
            lo, hi = front_uv[i].min(axis=0), front_uv[i].max(axis=0)
            out[i] = [np.clip(lo[0], 0, width - 1), np.clip(lo[1], 0, height - 1),
                      np.clip(hi[0], 0, width - 1), np.clip(hi[1], 0, height - 1)]
    with np.errstate(invalid="ignore"):
        flat = ~((out[:, 2] > out[:, 0]) & (out[:, 3] > out[:, 1]))
    out[flat] = np.nan
    truncation = np.clip(1.0 - inside, 0.0, 1.0).round(2)
    truncation[~np.isfinite(out).all(axis=1)] = 1.0
    return truncation, out, calib.alpha(b)


def test_camera_labels_project_the_corners_once_with_the_same_results() -> None:
    """Boxes ahead, beside, behind and across the camera plane (the volume-sample branch)."""
    rng = np.random.default_rng(11)
    calib = KittiCalibration.default()
    n = 400
    centers = np.column_stack([rng.uniform(-10.0, 60.0, n), rng.uniform(-30.0, 30.0, n), rng.uniform(-2.0, 1.0, n)])
    centers[:40, 0] = rng.uniform(-1.5, 1.5, 40)  # straddling the camera plane
    sizes = np.column_stack([rng.uniform(0.5, 6.0, n), rng.uniform(0.5, 3.0, n), rng.uniform(0.5, 3.0, n)])
    boxes = np.column_stack([centers, sizes, rng.uniform(-np.pi, np.pi, n)])
    fields = camera_labels(calib, boxes)
    truncation, bbox2d, alpha = former_camera_labels(calib, boxes)
    assert fields.truncation.tobytes() == truncation.tobytes()
    assert fields.bbox2d.tobytes() == bbox2d.tobytes()
    assert fields.alpha.tobytes() == alpha.tobytes()
    assert image_boxes(calib, boxes, image_coverage(calib, boxes)[1]).tobytes() == bbox2d.tobytes()
    assert (~np.isfinite(bbox2d).all(axis=1)).any() and np.isfinite(bbox2d).all(axis=1).any()  # both kinds reached
    assert camera_labels(calib, np.zeros((0, 7))).bbox2d.shape == (0, 4)


def former_rescaled(cloud: PointCloud, keep: np.ndarray, ranges: np.ndarray, new_range: np.ndarray,
                    intensity: np.ndarray, in_air: np.ndarray) -> PointCloud:
    """weather._rescaled as it was, allocating its temporaries after the output."""
    rows = np.flatnonzero(keep)
    data = np.take(cloud.data, rows, axis=0)
    source = np.flatnonzero(keep & (new_range != ranges))
    if 4 * len(source) > len(rows):
        kept_ranges, kept_new = np.take(ranges, rows), np.take(new_range, rows)
        for start in range(0, len(rows), WEATHER_BLOCK):
            block = slice(start, min(start + WEATHER_BLOCK, len(rows)))
            factor = np.divide(kept_new[block], kept_ranges[block], out=np.ones(block.stop - block.start),
                               where=kept_ranges[block] > 0)
            moved_rows = data[block]
            for axis in range(3):
                moved_rows[:, axis] = moved_rows[:, axis] * factor
    elif len(source):
        moved = np.searchsorted(rows, source)
        factor = np.divide(new_range[source], ranges[source], out=np.ones(len(source)), where=ranges[source] > 0)
        data[moved, :3] = data[moved, :3] * factor[:, None]
    data[:, 3] = np.take(intensity, rows)
    air = np.searchsorted(rows, np.flatnonzero(in_air & keep))
    for name in ("label", "instance"):
        if cloud.has(name) and len(air):
            data[air, cloud.index(name)] = CHANNEL_DEFAULTS[name]
    return PointCloud(data, cloud.channels)


@pytest.mark.parametrize("moved_share", [0.0, 0.1, 1.0])
def test_rescaled_with_temporaries_first_is_as_before(moved_share: float) -> None:
    rng = np.random.default_rng(5)
    n = 2 * WEATHER_BLOCK + 123
    xyz = rng.normal(0.0, 20.0, (n, 3))
    xyz[:50] = 0.0  # range 0: factor 1
    data = np.column_stack([xyz, rng.random(n), rng.integers(0, 64, n), rng.random(n), rng.integers(0, 20, n),
                            rng.integers(-1, 9, n)]).astype(np.float32)
    cloud = PointCloud(data, (*STANDARD_CHANNELS, "ring", "time", "label", "instance"))
    ranges = np.sqrt((xyz * xyz).sum(axis=1))
    new_range = np.where(rng.random(n) < moved_share, ranges * rng.uniform(0.2, 1.0, n), ranges)
    keep, in_air, intensity = rng.random(n) < 0.9, rng.random(n) < 0.05, rng.random(n)
    new = _rescaled(cloud, keep, ranges, new_range, intensity, in_air)
    assert new.data.tobytes() == former_rescaled(cloud, keep, ranges, new_range, intensity, in_air).data.tobytes()


# --------------------------------------------------------------------------- second round (issue 25)
def test_power_draws_in_blocks_are_one_draw() -> None:
    """Block after block from :func:`power_draw_stream`: the numbers of one ``power_draws``."""
    whole = power_draws(123, 50_000)
    stream = power_draw_stream(123)
    parts = [stream.random(k) for k in (1, 16_383, 16_384, 17_232)]
    assert np.concatenate(parts).tobytes() == whole.tobytes()


def wet_ground_cloud(rng: np.random.Generator, n: int, *, labelled: bool) -> PointCloud:
    """A frame-like cloud: ground (labelled or flat) and other points, with the readings the power
    model treats apart: zeros, sub-step readings, bright ones, points at the origin."""
    xyz = rng.normal(0.0, 25.0, (n, 3))
    ground = rng.random(n) < 0.6
    xyz[ground, 2] = rng.normal(-1.7, 0.03, int(ground.sum()))
    xyz[~ground, 2] = -1.2 + np.abs(xyz[~ground, 2]) / 5  # above it: the fitted plane is the ground
    xyz[:20] = 0.0  # range 0: the 1e-6 floor
    intensity = rng.random(n)
    intensity[rng.random(n) < 0.3] = 0.0
    intensity[rng.random(n) < 0.05] = 0.002  # under one quantisation step
    columns = [xyz, intensity]
    channels: tuple[str, ...] = STANDARD_CHANNELS
    if labelled:
        label = np.where(ground, rng.choice([1, 2, 3, 4, 16], n), rng.choice([0, 5, 7, 11], n))
        columns.append(label)
        channels = (*STANDARD_CHANNELS, "label")
    return PointCloud(np.column_stack(columns).astype(np.float32), channels)


def former_wet_ground(sample: Scene, params: WetGroundParams) -> Scene:
    """WetGround.apply before the blocks: whole-array temporaries, the draws in one call."""
    cloud = sample.points
    index, normal = _ground(cloud)
    if len(index) == 0:
        return sample
    rows = np.take(cloud.data, index, axis=0)
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
    wet = rows[:, 3] * factor.astype(np.float32)
    lost = rho * factor < floor
    if lost.any():
        keep = np.ones(len(cloud), bool)
        keep[index[lost]] = False
        data = np.compress(keep, cloud.data, axis=0)
        kept = ~lost
        data[index[kept] - np.cumsum(lost)[kept], 3] = wet[kept]
    else:
        data = cloud.data.copy()
        data[index, 3] = wet
    return sample.with_points(PointCloud(data, cloud.channels))


@pytest.mark.parametrize("labelled", [True, False])
@pytest.mark.parametrize("wetness", [0.0001, 0.6, 1.0])
@pytest.mark.parametrize("n", [5, WET_BLOCK - 1, 3 * WET_BLOCK + 77])
def test_wet_ground_in_blocks_is_as_before(labelled: bool, wetness: float, n: int) -> None:
    """Block by block (ground rows on both sides of block edges), with and without lost returns
    (a trace of water loses none), labelled ground and the fitted plane."""
    cloud = wet_ground_cloud(np.random.default_rng(n), n, labelled=labelled)
    sample = Scene(points=cloud)
    params = WetGroundParams(wetness=wetness, detection_threshold=0.4, intensity_scale=1.0, seed=99)
    new = WetGround().apply(sample, params).points.data
    assert new.tobytes() == former_wet_ground(sample, params).points.data.tobytes()
    if n > WET_BLOCK and wetness == 1.0:
        assert len(new) < n  # the dropping path is the one compared


def former_region_intensity(sample: Scene, params: RegionIntensityParams) -> Scene:
    """RegionIntensityScaling.apply before the intensity maximum was read during the copy."""
    cloud = sample.points
    inside = in_axis_box(cloud.xyz, params.center, params.size)
    if not inside.any():
        return sample
    limit = scene_intensity_scale(sample)
    data = cloud.data.copy()
    rows = np.flatnonzero(inside)
    scaled = data[rows, 3].astype(np.float64)
    scaled *= params.factor
    data[rows, 3] = np.clip(scaled, 0.0, limit, out=scaled)
    return sample.with_points(PointCloud(data, cloud.channels))


@pytest.mark.parametrize("case", ["[0, 1]", "8-bit", "declared", "nan"])
def test_region_intensity_scaling_is_as_before(case: str) -> None:
    rng = np.random.default_rng(21)
    cloud = random_cloud(rng, 2 * COLUMN_BLOCK + 5)
    data = cloud.data.copy()
    if case == "8-bit":
        data[:, 3] *= 255
    if case == "nan":
        data[7, 3] = np.nan
    metadata = {"intensity_scale": 255} if case == "declared" else {}
    sample = Scene(points=PointCloud(data, cloud.channels), metadata=metadata)
    for factor in (0.3, 4.0):
        params = RegionIntensityParams(center=(5.0, -3.0, 0.0), size=(30.0, 30.0, 200.0), factor=factor)
        new = RegionIntensityScaling().apply(sample, params).points.data
        assert new.tobytes() == former_region_intensity(sample, params).points.data.tobytes()


def former_cross_sensor(sample: Scene, params: CrossSensorParams) -> Scene:
    """CrossSensor.apply before the known rings were tested once."""
    cloud = sample.points
    ring = _rings_for(cloud, params.ring_source)
    keep = np.ones(len(cloud), bool)
    if params.beam_factor > 1 and (ring >= 0).any():
        top = int(ring.max()) + 1
        kept_rings = np.unique(np.floor(np.arange(params.beam_phase, top, params.beam_factor)).astype(np.int64))
        keep &= _ring_mask(ring, kept_rings, unknown=True)
    if params.azimuth_factor > 1:
        columns = int(np.bincount(ring[ring >= 0]).max()) if (ring >= 0).any() else len(cloud)
        turns = np.subtract(np.pi, np.arctan2(cloud.xyz[:, 1], cloud.xyz[:, 0]))
        turns = np.mod(turns, 2.0 * np.pi)
        turns /= 2.0 * np.pi
        turns *= columns
        keep &= np.mod(np.floor(turns).astype(np.int64), params.azimuth_factor) == int(
            params.azimuth_phase * params.azimuth_factor)
    return sample.with_points(cloud.select(keep))


@pytest.mark.parametrize("rings", ["all known", "some unknown", "none known"])
def test_cross_sensor_is_as_before(rings: str) -> None:
    rng = np.random.default_rng(13)
    n = 20_000
    ring = rng.integers(0, 64, n)
    if rings == "some unknown":
        ring[rng.random(n) < 0.1] = -1
    if rings == "none known":
        ring[:] = -1
    xyz = rng.normal(0.0, 20.0, (n, 3))
    cloud = PointCloud(np.column_stack([xyz, rng.random(n), ring]).astype(np.float32), (*STANDARD_CHANNELS, "ring"))
    sample = Scene(points=cloud)
    for beam, azimuth in [(2.0, 3), (4 / 3, 1), (1.0, 2)]:
        params = CrossSensorParams(beam_factor=beam, beam_phase=0.4, azimuth_factor=azimuth, azimuth_phase=0.5,
                                   ring_source="channel")
        new = CrossSensor().apply(sample, params).points.data
        assert new.tobytes() == former_cross_sensor(sample, params).points.data.tobytes()


def former_motion_distortion(sample: Scene, params: MotionDistortionParams) -> Scene:
    """MotionDistortion.apply before the rotation read x and y into contiguous buffers."""
    cloud = sample.points
    if params.time_source == "channel":
        t = cloud.channel("time")
    else:
        t = time_of_azimuth(azimuth_rad(cloud.xyz), params.rotation_hz).astype(np.float32)
    source = cloud.data
    data = np.empty_like(source)
    speed = np.float32(params.speed)
    turn = np.float32(-np.deg2rad(params.yaw_rate))
    block = min(MOTION_BLOCK, len(source))
    for start in range(0, len(source), block):
        rows = data[start:start + block]
        np.copyto(rows, source[start:start + block])
        times, x, y = t[start:start + len(rows)], rows[:, 0], rows[:, 1]
        x -= times * speed
        if params.yaw_rate == 0:
            continue
        angle = times * turn
        c, s = np.cos(angle), np.sin(angle)
        moved = x.copy()
        new_x = c * moved - s * y
        new_y = s * moved + c * y
        x[:] = new_x
        y[:] = new_y
    return sample.with_points(PointCloud(data, cloud.channels))


@pytest.mark.parametrize("time_source", ["channel", "azimuth"])
@pytest.mark.parametrize("yaw_rate", [0.0, -35.0, 12.5])
def test_motion_distortion_is_as_before(time_source: str, yaw_rate: float) -> None:
    rng = np.random.default_rng(17)
    n = 2 * MOTION_BLOCK + 321
    xyz = rng.normal(0.0, 25.0, (n, 3))
    xyz[:30] = 0.0
    xyz[30:60] = -0.0
    data = np.column_stack([xyz, rng.random(n), rng.uniform(-0.05, 0.05, n)]).astype(np.float32)
    sample = Scene(points=PointCloud(data, (*STANDARD_CHANNELS, "time")))
    params = MotionDistortionParams(speed=13.7, yaw_rate=yaw_rate, rotation_hz=10.0, time_source=time_source)
    new = MotionDistortion().apply(sample, params).points.data
    assert new.tobytes() == former_motion_distortion(sample, params).points.data.tobytes()


def former_ground_plane(xyz: np.ndarray) -> tuple[np.ndarray, float]:
    """ground_plane before its rows were picked with np.compress (boolean indexing)."""
    xyz = xyz[:: max(1, len(xyz) // 4000)]
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


@pytest.mark.parametrize("case", ["flat ground", "tilted", "no inliers after the first fit", "subsampled"])
def test_ground_plane_is_as_before(case: str) -> None:
    rng = np.random.default_rng(23)
    n = 9_000 if case == "subsampled" else 3_000
    xyz = rng.uniform(-40, 40, (n, 3))
    xyz[: n // 2, 2] = rng.normal(-1.7, 0.05, n // 2)
    if case == "tilted":
        xyz[: n // 2, 2] += 0.03 * xyz[: n // 2, 0]
    if case == "no inliers after the first fit":
        xyz[:, 2] = rng.normal(0.0, 1e4, n)  # (almost) nothing within 0.2 m of any plane: the loop breaks
    normal, offset = ground_plane(xyz)
    former_normal, former_offset = former_ground_plane(xyz)
    assert normal.tobytes() == former_normal.tobytes() and offset == former_offset


def former_dual_return(sample: Scene, params: DualReturnParams) -> Scene:
    """DualReturn.apply before the output came first and the neighbours came as pairs."""
    cloud = sample.points
    n = len(cloud)
    count = round(params.ratio * n)
    picked = np.zeros(n, bool)
    picked[np.random.default_rng(params.seed).choice(n, size=count, replace=False)] = True
    chosen = np.flatnonzero(picked)
    behind = far_neighbour(cloud, _rings_for(cloud, params.ring_source), params.edge_m, params.max_gap_deg)[chosen]
    data = np.repeat(cloud.data, picked.view(np.uint8) + np.uint8(1), axis=0)
    distinct = np.flatnonzero(behind >= 0)
    second, far = cloud.data[chosen[distinct]], cloud.data[behind[distinct]]
    xyz = second[:, :3].astype(np.float64)
    scale = np.linalg.norm(far[:, :3].astype(np.float64), axis=1) / np.maximum(np.linalg.norm(xyz, axis=1), 1e-9)
    second[:, :3] = xyz * scale[:, None]
    second[:, 3] = far[:, 3] * params.behind_share
    data[chosen[distinct] + 1 + distinct] = second
    return sample.with_points(cloud.with_data(data))


@pytest.mark.parametrize("arrangement", ["scan order", "shuffled"])
@pytest.mark.parametrize("ratio", [0.05, 0.6, 1.0])
def test_dual_return_is_as_before(arrangement: str, ratio: float) -> None:
    """Both neighbour paths (in scan order, block by block; sorted), few and all firings doubled."""
    rng = np.random.default_rng(31)
    cloud, _ = scan_cloud(rng, 16, 1_500)
    if arrangement == "shuffled":
        cloud = PointCloud(cloud.data[rng.permutation(len(cloud))], cloud.channels)
    sample = Scene(points=cloud)
    params = DualReturnParams(ratio=ratio, edge_m=1.0, max_gap_deg=1.0, behind_share=0.5, ring_source="channel",
                              seed=5)
    new = DualReturn().apply(sample, params).points.data
    assert new.tobytes() == former_dual_return(sample, params).points.data.tobytes()
    assert len(new) == len(cloud) + round(ratio * len(cloud))
    assert (far_neighbour(cloud, _rings_for(cloud, "channel"), 1.0, 1.0) >= 0).sum() > 100  # distinct ones exist


def _fog_soft_response_before(alpha: float, tau_h: float, step: float = 0.05) -> tuple[Any, Any, Any]:
    """fog_soft_response as it was before the pulse kernel was cached (the reference)."""
    width = SPEED_OF_LIGHT * tau_h
    r1, r2 = FOG_OVERLAP
    n_r0 = int(np.ceil((r2 + width + 1.0) / step)) + 1
    n = n_r0 + int(np.ceil(width / step)) + 1
    r = np.arange(n) * step
    overlap = np.clip((r - r1) / (r2 - r1), 0.0, 1.0)
    g = np.divide(overlap * np.exp(-2.0 * alpha * r), r**2, out=np.zeros(n), where=r > 0)
    lag = r[:, None] - r[None, :]
    in_pulse = (lag >= 0) & (lag <= width)
    weights = np.where(in_pulse, np.sin(np.pi * np.clip(lag, 0, width) / width) ** 2, 0.0) * g[None, :] * step
    cumulative = np.cumsum(weights, axis=1)
    j = np.arange(n)[:, None]
    m = np.arange(n_r0)[None, :]
    seen = cumulative[j, np.minimum(j, m)]
    best = np.argmax(seen, axis=0)
    integral = seen[best, np.arange(n_r0)]
    distance = np.maximum(r[best] - width / 2, r1)
    return r[:n_r0].astype(np.float64), np.asarray(integral, np.float64), np.asarray(distance, np.float64)


@pytest.mark.parametrize(("tau_h", "step"), [(20e-9, 0.05), (10e-9, 0.05), (35e-9, 0.1)])
def test_fog_soft_response_with_the_cached_pulse_kernel_is_the_former_table(tau_h: float, step: float) -> None:
    """Every severity's MOR range (40–900 m) and beyond, several pulse widths and grid steps:
    the same bytes, the kernel shared between visibilities (a campaign draws a new one per frame)."""
    for mor in (40.0, 61.3, 150.0, 199.99, 250.0, 600.0, 900.0, 5000.0):
        alpha = float(np.log(20.0) / mor)
        for now, before in zip(fog_soft_response(alpha, tau_h, step), _fog_soft_response_before(alpha, tau_h, step),
                               strict=True):
            assert now.tobytes() == before.tobytes()


# --------------------------------------------------------------------------- scratch arrays, particle table (h26)
def test_scratch_is_reused_per_name_and_thread_and_grown() -> None:
    """One array per (name, dtype) and thread: the same memory on the next call, a longer one when a
    longer cloud comes, another thread's its own, none kept beyond the limit, dropped on release."""
    release_scratch()
    first = scratch("test.values", 1_000)
    assert first.shape == (1_000,) and first.dtype == np.float64
    assert np.shares_memory(scratch("test.values", 400), first)  # a shorter request: the same memory
    assert not np.shares_memory(scratch("test.values", 1_000, bool), first)  # another dtype: another array
    assert not np.shares_memory(scratch("test.other", 1_000), first)
    grown = scratch("test.values", 5_000)
    assert grown.shape == (5_000,) and not np.shares_memory(grown, first)
    assert np.shares_memory(scratch("test.values", 10), grown)
    elsewhere: list[np.ndarray] = []
    thread = threading.Thread(target=lambda: elsewhere.append(scratch("test.values", 5_000)))
    thread.start()
    thread.join()
    assert not np.shares_memory(elsewhere[0], grown)
    huge = scratch("test.huge", SCRATCH_KEEP_LIMIT + 1, bool)
    assert not np.shares_memory(scratch("test.huge", SCRATCH_KEEP_LIMIT + 1, bool), huge)  # not kept
    release_scratch()
    assert not np.shares_memory(scratch("test.values", 10), grown)
    release_scratch()


def test_power_draws_into_a_buffer_are_the_same_numbers() -> None:
    out = np.full(60_000, np.nan)
    assert power_draws(77, 50_000, out=out[:50_000]).tobytes() == power_draws(77, 50_000).tobytes()
    assert np.isnan(out[50_000:]).all()


@pytest.mark.parametrize("name", ["fog", "rain", "snow"])
def test_weather_outputs_are_fresh_and_independent_of_stale_scratch(name: str) -> None:
    """An operator's result does not depend on what an earlier call (of any weather operator) left
    in this thread's scratch arrays — the same bytes as on a thread that never used them — and
    does not share memory with them: the next call cannot change it."""
    from lidarfuzz.sim.dataset import GenerationConfig, render_frames

    scene = next(iter(render_frames(GenerationConfig(frames=1, seed=3, sensor="VLP-16"))))
    op = available()[name].at_severity(5)
    params = op.sample(np.random.default_rng(9), scene)
    fresh: list[bytes] = []

    def on_a_new_thread() -> None:
        release_scratch()
        fresh.append(op.apply(scene, params).points.data.tobytes())

    thread = threading.Thread(target=on_a_new_thread)
    thread.start()
    thread.join()
    for other in ("fog", "rain", "snow"):  # leave other contents behind, on a longer cloud too
        longer = scene.with_points(PointCloud(np.concatenate([scene.points.data] * 2), scene.points.channels))
        available()[other].at_severity(3)(longer, np.random.default_rng(1))
    result = op.apply(scene, params).points.data
    assert result.tobytes() == fresh[0]
    kept = result.copy()
    op.apply(scene, op.sample(np.random.default_rng(10), scene))
    assert result.tobytes() == kept.tobytes()
    pool = _scratch_arrays()
    assert pool and not any(np.shares_memory(result, array) for array in pool)


def _scratch_arrays() -> list[np.ndarray]:
    from lidarfuzz.operators.lidar import common

    return list(getattr(common._scratch, "pool", {}).values())


def former_particle_table(n0: float, lam: float, alpha: float, rho_p: float, theta: float, min_range: float,
                          p_min: float) -> np.ndarray | None:
    """weather.particle_table's counts as built before: every cell of the grid integrated (most of
    them past their bar's cut-off, where the exponentials underflow), then those zeroed."""
    end = max(PARTICLE_REACH, min_range)
    edge = max(min_range, TABLE_RANGE_STEP)
    bar_high = rho_p / (edge * edge * np.exp(2.0 * alpha * edge))
    if end <= min_range or bar_high <= p_min:
        return None
    n_bars = max(int(np.ceil(np.log10(bar_high / p_min) * TABLE_NODES_PER_DECADE)) + 1, 2)
    log_bars = np.linspace(np.log(p_min), np.log(bar_high), n_bars)
    n_ranges = int(np.ceil((end - min_range) / TABLE_RANGE_STEP)) + 1
    ranges = min_range + np.arange(n_ranges, dtype=np.float64) * TABLE_RANGE_STEP
    bars = np.exp(log_bars)
    r_max = cutoff_range(bars, alpha, rho_p)
    root = np.sqrt(bars / rho_p)
    left = ranges[:-1]
    cells = np.zeros((n_bars, n_ranges - 1))
    for node, weight in zip(GAUSS_NODES, GAUSS_WEIGHTS, strict=True):
        r = left + node * TABLE_RANGE_STEP
        d_need = np.maximum(np.multiply.outer(root, 1e3 * theta * r * r * np.exp(alpha * r)), MIN_DIAMETER)
        cells += (weight * TABLE_RANGE_STEP) * (r * r) * np.exp(-lam * d_need)
    full = ranges[None, 1:] <= r_max[:, None]
    partial_row = np.flatnonzero((r_max > ranges[0]) & (r_max < ranges[-1]))
    partial_col = np.searchsorted(ranges, r_max[partial_row], side="right") - 1
    cells[~full] = 0.0
    start = left[partial_col]
    width = np.maximum(r_max[partial_row] - start, 0.0)
    partial = np.zeros(len(partial_row))
    for node, weight in zip(GAUSS_NODES, GAUSS_WEIGHTS, strict=True):
        r = start + node * width
        d_need = np.maximum(root[partial_row] * 1e3 * theta * r * r * np.exp(alpha * r), MIN_DIAMETER)
        partial += weight * width * r * r * np.exp(-lam * d_need)
    cells[partial_row, partial_col] = partial
    cells *= np.pi * theta**2 / 4.0 * n0 / lam
    counts = np.zeros((n_bars, n_ranges))
    np.cumsum(cells, axis=1, out=counts[:, 1:])
    return counts


@pytest.mark.parametrize("cls", [Rain, Snow], ids=lambda cls: cls.name)
@pytest.mark.parametrize(("min_range", "detection_threshold", "divergence"),
                         [(1.5, 0.4, 3e-3), (0.0, 0.4, 3e-3), (1.5, 0.05, 3e-3), (3.0, 0.025, 1e-3), (0.5, 0.4, 6e-3)])
def test_particle_table_inside_the_cut_offs_is_the_whole_grid_build(cls: Any, min_range: float,
                                                                    detection_threshold: float,
                                                                    divergence: float) -> None:
    """Each severity's rate range (its ends and rates drawn inside), several sensors: the same bytes
    as integrating every cell and zeroing those past the cut-off."""
    rng = np.random.default_rng(17)
    for low, high in (severity["rate_range"] for severity in cls.SEVERITIES.values()):
        for rate in (low, high, *rng.uniform(low, high, 3)):
            n0, lam = cls.distribution(rate)
            args = (n0, lam, cls.extinction(rate), cls.particle_reflectance, float(np.tan(divergence)), min_range,
                    detection_threshold / 100.0**2)
            table, before = particle_table.__wrapped__(*args), former_particle_table(*args)
            assert table is not None and before is not None
            assert table.counts.tobytes() == before.tobytes()


def former_interp_near(ranges: np.ndarray, grid: np.ndarray, tables: tuple[np.ndarray, ...]) -> list[np.ndarray]:
    """weather._interp_near as it was: np.interp on the ranges within the grid, the last value beyond."""
    near = np.flatnonzero(ranges < grid[-1])
    results = []
    for table in tables:
        values = np.full(len(ranges), table[-1])
        values[near] = np.interp(ranges[near], grid, table)
        results.append(values)
    return results


@pytest.mark.parametrize(("tau_h", "step"), [(20e-9, 0.05), (10e-9, 0.05), (35e-9, 0.1), (20e-9, 0.02), (20e-9, 0.07)])
def test_interp_near_on_the_uniform_grid_is_np_interp(tau_h: float, step: float) -> None:
    """The fog tables of every severity's visibilities, at random ranges, at every node and the
    floats on either side of it (where the cell found from the step must be corrected), at 0 and
    the grid's end, and at ranges no frame should have (inf, NaN, huge)."""
    rng = np.random.default_rng(23)
    for mor in (40.0, 55.5, 100.0, 199.99, 450.0, 900.0, 5000.0):
        grid, *tables = fog_soft_response(float(np.log(20.0) / mor), tau_h, step)
        ranges = np.concatenate([rng.uniform(0.0, 1.2 * grid[-1], 20_000), grid, np.nextafter(grid, 0.0),
                                 np.nextafter(grid, np.inf), [0.0, 0.9, 1.0, 5e-324, np.inf, np.nan, 1e30]])
        rng.shuffle(ranges)
        for now, before in zip(_interp_near(ranges, grid, tuple(tables)),
                               former_interp_near(ranges, grid, tuple(tables)), strict=True):
            assert now.tobytes() == before.tobytes()
        assert _interp_near(np.array([grid[-1], 50.0]), grid, (tables[0],))[0].tolist() == [tables[0][-1]] * 2


@pytest.mark.parametrize("step", [0.05, 0.02, 0.07])
def test_interp_near_corrects_the_cell_both_ways(step: float) -> None:
    """Longer uniform grids, where ``r / step`` truncates to the cell below as well as above."""
    grid = np.arange(400) * step
    table = np.random.default_rng(29).random(400)
    ranges = np.concatenate([grid, np.nextafter(grid, 0.0), np.nextafter(grid, np.inf)])
    assert (np.take(grid, np.minimum((ranges * (1.0 / step)).astype(np.intp) + 1, 399)) <= ranges).any()  # reached
    assert _interp_near(ranges, grid, (table,))[0].tobytes() == former_interp_near(ranges, grid, (table,))[0].tobytes()
