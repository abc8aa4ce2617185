"""The simple operators' faster helpers compute what the code they replaced computed (issue 25).

``test_bit_identity.py`` compares whole operator outputs on two frames; these tests compare each
helper with the expression it replaced, as that expression, on inputs chosen to reach its corner
cases (ties, signed zeros, NaN, points at the edge of a region, near-equal farthest ranges).
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators.lidar.common import (
    COLUMN_BLOCK,
    copy_with_maximum,
    in_axis_box,
    intensity_scale,
    mod_period,
    scene_intensity_scale,
)
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
from lidarfuzz.operators.lidar.sensor import (
    SQUARED_BLOCK,
    _present_rings,
    _squared_ranges,
    farthest_range,
    farthest_range_and_intensity_scale,
)
from lidarfuzz.operators.lidar.weather import _BLOCK as WEATHER_BLOCK
from lidarfuzz.operators.lidar.weather import _rescaled
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.geometry import box_corners
from lidarfuzz.scene.labels import MIN_DEPTH, camera_labels, image_boxes, image_coverage
from lidarfuzz.scene.points import CHANNEL_DEFAULTS, STANDARD_CHANNELS, PointCloud
from lidarfuzz.scene.scene import Scene


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
