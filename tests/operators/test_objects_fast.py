"""The object operators' point index answers exactly what a scan of every point answers (issue 25):
the grid and azimuth buckets only narrow the search, a derived index (a frame with an object
inserted) maps its parent's answers, a frame grown by insertions reads as the cloud written out
after each, and the per-cloud cache never serves another cloud's index."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from lidarfuzz.operators.lidar.common import intensity_scale
from lidarfuzz.operators.lidar.objects import support
from lidarfuzz.operators.lidar.objects.support import _INDEX_FROM, _Grown, _Pts
from lidarfuzz.scene.points import PointCloud


def scan_near(pts: _Pts, cx: float, cy: float, reach: float) -> np.ndarray:
    index = np.flatnonzero(np.abs(pts.x - np.float32(cx)) <= reach)
    return index[np.abs(pts.y[index] - cy) <= reach]


def scan_wedge(pts: _Pts, centre: float, half_width: float) -> np.ndarray:
    c, s = np.float32(np.cos(centre)), np.float32(np.sin(centre))
    along = pts.x * c + pts.y * s
    cos2 = np.float32(np.cos(half_width) ** 2)
    index = np.flatnonzero(along >= 0)
    return index[along[index] ** 2 >= (pts.x[index] ** 2 + pts.y[index] ** 2) * cos2]


def cloud(rng: np.random.Generator, n: int) -> PointCloud:
    """A frame-like cloud (ranges 1–80 m, some points on cell and bin edges, at the origin, NaN)."""
    r, az = rng.uniform(1.0, 80.0, n), rng.uniform(-np.pi, np.pi, n)
    data = np.zeros((n, 4), np.float32)
    data[:, 0], data[:, 1], data[:, 2] = r * np.cos(az), r * np.sin(az), rng.normal(-1.5, 0.5, n)
    data[:, 3] = rng.uniform(0.0, 1.0, n)
    data[:50, :2] = np.round(data[:50, :2])  # exactly on grid lines
    data[50:53, :2] = 0.0  # at the sensor: inside every azimuth test
    data[53, 0] = np.nan
    return PointCloud(data, ("x", "y", "z", "intensity"))


@pytest.mark.parametrize("seed", range(5))
def test_index_queries_equal_full_scans(seed: int) -> None:
    rng = np.random.default_rng(seed)
    points = cloud(rng, 3 * _INDEX_FROM)
    pts = _Pts.of(points)
    for _ in range(40):
        cx, cy, reach = *rng.uniform(-90, 90, 2), float(rng.uniform(0.1, 20.0))
        assert np.array_equal(pts.near(cx, cy, reach), scan_near(pts, cx, cy, reach))
        centre, half = float(rng.uniform(-np.pi, np.pi)), float(rng.uniform(0.0, 1.5))
        assert np.array_equal(pts.wedge(centre, half), scan_wedge(pts, centre, half))
    # across the ±π seam
    assert np.array_equal(pts.wedge(np.pi - 0.01, 0.1), scan_wedge(pts, np.pi - 0.01, 0.1))


def test_derived_index_equals_its_own_scan() -> None:
    rng = np.random.default_rng(3)
    parent_cloud = cloud(rng, 3 * _INDEX_FROM)
    parent = _Pts.of(parent_cloud)
    kept = rng.random(len(parent_cloud)) > 0.1
    kept[-1] = False  # the last point removed: the kept count must not be read off it
    new = cloud(rng, 300).data
    grown = PointCloud(np.concatenate([parent_cloud.data[kept], new]), parent_cloud.channels)
    derived = _Pts.derive(parent, kept, new[:, :3])
    whole = _Pts(grown.xyz)  # the same points, indexed from scratch
    assert len(derived) == len(whole)
    assert np.array_equal(derived.columns, whole.columns, equal_nan=True)
    for _ in range(30):
        cx, cy, reach = *rng.uniform(-90, 90, 2), float(rng.uniform(0.1, 20.0))
        assert np.array_equal(derived.near(cx, cy, reach), scan_near(whole, cx, cy, reach))
        centre, half = float(rng.uniform(-np.pi, np.pi)), float(rng.uniform(0.0, 1.5))
        assert np.array_equal(derived.wedge(centre, half), scan_wedge(whole, centre, half))


def test_grown_frame_reads_as_the_written_cloud() -> None:
    """A frame grown object by object, never written out, gives the rows, intensity scale and
    final cloud that compacting the frame after each insertion gives."""
    rng = np.random.default_rng(6)
    frame = cloud(rng, 2 * _INDEX_FROM)
    grown, written = _Grown.start(frame), frame.data
    for step in range(3):
        keep = rng.random(len(grown)) > 0.05
        keep[int(np.argmax(written[:, 3]))] = step != 1  # once, the brightest point goes
        rows = cloud(rng, 100).data * np.float32(1.0 + step)  # intensities above 1: another scale
        grown, written = grown.grow(keep, rows), np.concatenate([written[keep], rows])
        index = np.sort(rng.choice(len(grown), 500, replace=False))
        assert np.array_equal(grown.rows(index), written[index], equal_nan=True)
        assert grown.intensity_scale() == intensity_scale(written[:, 3])
        assert np.array_equal(grown.pts.columns, np.ascontiguousarray(written[:, :3].T), equal_nan=True)
    assert np.array_equal(grown.cloud().data, written, equal_nan=True)
    assert grown.dropped.nbytes + grown.added.nbytes < frame.data.nbytes / 4  # the changes, not a copy


def test_cache_is_per_cloud() -> None:
    rng = np.random.default_rng(4)
    first = cloud(rng, _INDEX_FROM)
    same_values = PointCloud(first.data.copy(), first.channels)
    assert _Pts.of(first) is _Pts.of(first)
    assert _Pts.of(same_values) is not _Pts.of(first)


@pytest.mark.parametrize("drop_farthest", [False, True])
@pytest.mark.parametrize("new_farther", [False, True])
def test_derived_max_range_equals_the_scan(drop_farthest: bool, new_farther: bool) -> None:
    rng = np.random.default_rng(5)
    data = cloud(rng, 2 * _INDEX_FROM).data.copy()
    data[53] = data[54]  # no NaN: ranges compare
    parent_cloud = PointCloud(data, ("x", "y", "z", "intensity"))
    parent = _Pts.of(parent_cloud)
    farthest = parent.farthest()[1]
    kept = rng.random(len(data)) > 0.05
    kept[farthest] = not drop_farthest
    new = cloud(rng, 200).data.copy()
    new[53] = new[54]
    if new_farther:
        new[7, :3] = (200.0, 0.0, 0.0)
    grown = PointCloud(np.concatenate([data[kept], new]), parent_cloud.channels)
    derived = _Pts.derive(parent, kept, new[:, :3])
    assert derived.max_range() == _Pts(grown.xyz).max_range()
    grown_again = PointCloud(np.concatenate([grown.data[1:], new[:3]]), grown.channels)
    again = np.ones(len(grown), bool)
    again[0] = False
    assert _Pts.derive(derived, again, new[:3, :3]).max_range() == _Pts(grown_again.xyz).max_range()


# ---------------------------------------------------------------------------------------------------
# The place search's and the z-buffer's faster helpers compute what the code they replaced computed
# (issue 25: object insertion with a fresh seed per call, as a campaign calls it). Each reference
# below is the former code, verbatim.


def former_lowest_per_cell(dx: np.ndarray, dy: np.ndarray, z: np.ndarray, cell: float) -> np.ndarray:
    ix, iy = np.floor(dx / cell).astype(np.int64), np.floor(dy / cell).astype(np.int64)
    key = (ix - ix.min(initial=0)) * (int(iy.max(initial=0) - iy.min(initial=0)) + 1) + (iy - iy.min(initial=0))
    order = np.lexsort((z, key))
    first = np.ones(len(order), bool)
    first[1:] = key[order][1:] != key[order][:-1]
    return order[first]


def former_wedge_of(xyz: np.ndarray, ring: np.ndarray | None, index: np.ndarray, centre: float) -> support._Wedge:
    az, elev, depth = support._spherical(xyz, centre)
    ring_of_row = None
    if ring is not None and len(index) and np.all(ring >= 0):
        rings, inverse = np.unique(ring, return_inverse=True)
        order = np.lexsort((elev, inverse))
        starts = np.searchsorted(inverse[order], np.arange(len(rings)))
        ends = np.append(starts[1:], len(order))
        ring_elev = elev[order][(starts + ends) // 2]
        by_elev = np.argsort(ring_elev, kind="stable")
        elevations, ring_of_row = ring_elev[by_elev], rings[by_elev].astype(np.float64)
        rank = np.empty(len(rings), np.intp)
        rank[by_elev] = np.arange(len(rings))
        row = rank[inverse]
    elif len(index):
        order = np.argsort(elev)
        starts = np.concatenate([[0], np.flatnonzero(np.diff(elev[order]) > np.deg2rad(0.08)) + 1])
        if len(starts) > 256:
            edges = np.linspace(elev.min(), elev.max() + 1e-9, 129)
            row = np.clip(np.searchsorted(edges, elev, side="right") - 1, 0, 127)
            elevations = (edges[:-1] + edges[1:]) / 2
        else:
            cluster = np.zeros(len(elev), np.intp)
            cluster[order] = np.cumsum(np.isin(np.arange(len(elev)), starts)) - 1
            row = cluster
            elevations = np.bincount(cluster, elev) / np.bincount(cluster)
    else:
        row, elevations = np.zeros(0, np.intp), np.deg2rad(np.array([-25.0, 3.0]))
    az_step = np.deg2rad(0.2)
    if len(index) > 1:
        order = np.lexsort((az, row))
        gaps = np.diff(az[order])[np.diff(row[order]) == 0]
        gaps = gaps[gaps > 1e-5]
        if len(gaps) >= 8:
            az_step = float(np.median(gaps))
    col = np.floor(az / az_step).astype(np.intp)
    return support._Wedge(index, np.asarray(row, np.intp), col, depth, np.asarray(elevations, np.float64),
                          ring_of_row, az_step, centre)


def former_silhouette(key: np.ndarray, depth: np.ndarray, shape: tuple[int, int],
                      size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    from scipy import ndimage

    nearest = np.full(shape[0] * shape[1], np.inf)
    np.minimum.at(nearest, key, depth)
    image = np.where(np.isfinite(nearest), nearest, 0.0).reshape(shape)
    filled = ndimage.binary_closing(image > 0, structure=np.ones(size, bool), border_value=0) | (image > 0)
    occluder = np.where(image > 0, image, ndimage.maximum_filter(image, size=size)).ravel()
    return filled.ravel() & (occluder > 0), occluder


def same_array(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    """Equal dtype, shape and bytes (so signed zeros and NaN payloads count too)."""
    if a is None or b is None:
        return a is None and b is None
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def assert_same_wedge(got: support._Wedge, want: support._Wedge) -> None:
    for field in ("index", "row", "col", "depth", "elevations", "ring_of_row"):
        assert same_array(getattr(got, field), getattr(want, field)), field
    assert got.az_step == want.az_step and got.centre == want.centre


def lowest_cases(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Ground rings with ties (equal heights in a cell, points on cell edges, ±0), NaN and inf."""
    cases = []
    for n in (0, 1, 2, 7, 300, 5000):
        dx, dy = rng.uniform(-14.0, 14.0, n), rng.uniform(-14.0, 14.0, n)
        z = np.round(rng.normal(-1.7, 0.3, n), 2)  # many equal heights
        dx[: n // 5] = np.round(dx[: n // 5] * 2) / 2  # on the cell edges
        cases.append((dx, dy, z))
        signed = z.copy()
        signed[: n // 3] = np.where(rng.random(n // 3) < 0.5, 0.0, -0.0)
        cases.append((dx, dy, signed))
        for bad in (np.nan, np.inf):
            if n:
                for column in range(3):
                    spoiled = [dx.copy(), dy.copy(), z.copy()]
                    spoiled[column][rng.integers(0, n)] = bad
                    cases.append((spoiled[0], spoiled[1], spoiled[2]))
    wide = rng.uniform(-200.0, 200.0, (2, 4000))  # more cells than the counting sort takes
    cases.append((wide[0], wide[1], rng.normal(0.0, 1.0, 4000)))
    return cases


def test_lowest_per_cell_is_the_two_key_sort() -> None:
    rng = np.random.default_rng(25)
    for dx, dy, z in lowest_cases(rng):
        for cell in (0.5, 0.37):
            with np.errstate(invalid="ignore", over="ignore"):  # the NaN and inf cases' keys
                assert same_array(support._lowest_per_cell(dx, dy, z, cell), former_lowest_per_cell(dx, dy, z, cell))


def wedge_cases(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray | None, float]]:
    """Wedges of a spinning scan (rings in scan order, shuffled, with gaps, one huge ring id, a
    fractional ring, signed-zero elevations, equal azimuths) and of clouds without rings."""
    cases: list[tuple[np.ndarray, np.ndarray | None, float]] = []
    for n in (1, 2, 9, 400, 6000):
        rings = rng.integers(0, 64, n).astype(np.float32)
        elevation = np.deg2rad(-24.0 + rings * 0.42 + rng.normal(0.0, 0.01, n))
        azimuth = rng.uniform(-0.3, 0.3, n)
        azimuth[: n // 4] = np.round(azimuth[: n // 4], 3)  # equal azimuths
        distance = rng.uniform(2.0, 60.0, n)
        xyz = np.column_stack([distance * np.cos(elevation) * np.cos(azimuth),
                               distance * np.cos(elevation) * np.sin(azimuth),
                               distance * np.sin(elevation)]).astype(np.float32)
        xyz[: n // 10, 2] = np.where(rng.random(n // 10) < 0.5, 0.0, -0.0)
        centre = float(rng.uniform(-np.pi, np.pi))
        turned = xyz.copy()
        turned[:, 0] = np.float32(np.cos(centre)) * xyz[:, 0] - np.float32(np.sin(centre)) * xyz[:, 1]
        turned[:, 1] = np.float32(np.sin(centre)) * xyz[:, 0] + np.float32(np.cos(centre)) * xyz[:, 1]
        gapped = np.where(rings % 7 == 3, rings + 100, rings).astype(np.float32)
        huge = rings.copy()
        huge[0] = 40000.0
        fractional = rings.copy()
        fractional[-1] = 2.5
        for ring in (rings, gapped, huge, fractional, None, -rings - 1):
            cases.append((turned, ring, centre))
        order = np.argsort(rings, kind="stable")  # a scan in ring order
        cases.append((turned[order], rings[order], centre))
    return cases


def test_wedge_of_is_as_before() -> None:
    rng = np.random.default_rng(26)
    for xyz, ring, centre in wedge_cases(rng):
        index = np.arange(len(xyz)) * 3
        assert_same_wedge(support._wedge_of(xyz, ring, index, centre), former_wedge_of(xyz, ring, index, centre))


def silhouette_cases(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray, tuple[int, int], tuple[int, int]]]:
    """Objects in the middle of the range image and against each of its edges, with holes,
    several points per pixel, zero and non-finite depths, and every closing size."""
    cases = []
    for shape in ((64, 80), (16, 40), (5, 7)):
        for size in ((2, 2), (3, 2), (2, 3), (5, 5), (15, 15)):
            for where in ("middle", "top", "bottom", "left", "right", "all", "empty"):
                rows, cols = shape
                n = 0 if where == "empty" else int(rng.integers(1, 200))
                r0 = {"top": 0, "all": 0, "bottom": max(rows - 6, 0)}.get(where, rows // 3)
                c0 = {"left": 0, "all": 0, "right": max(cols - 9, 0)}.get(where, cols // 3)
                height, width = (rows, cols) if where == "all" else (min(6, rows - r0), min(9, cols - c0))
                row = r0 + rng.integers(0, height, n)
                col = c0 + rng.integers(0, width, n)
                depth = rng.uniform(3.0, 40.0, n)
                if n > 4:
                    depth[:2] = [0.0, np.nan]
                cases.append((row * cols + col, depth, shape, size))
    return cases


def test_silhouette_on_the_object_crop_is_as_before() -> None:
    rng = np.random.default_rng(27)
    for key, depth, shape, size in silhouette_cases(rng):
        with np.errstate(invalid="ignore"):  # the NaN depth
            covered, occluder = support._silhouette(key, depth, shape, size)
            want_covered, want_occluder = former_silhouette(key, depth, shape, size)
        assert same_array(covered, want_covered) and same_array(occluder, want_occluder), (shape, size)


def test_footprint_is_bev_corners() -> None:
    from lidarfuzz.scene.geometry import bev_corners

    rng = np.random.default_rng(28)
    boxes = np.column_stack([rng.uniform(-80, 80, (500, 3)), rng.uniform(0.2, 12.0, (500, 3)),
                             rng.uniform(-4 * np.pi, 4 * np.pi, 500)])
    boxes[:20, 6] = [0.0, -0.0, np.pi, -np.pi, np.pi / 2, *rng.uniform(-1, 1, 15)]
    for box in boxes:
        assert same_array(support._footprint(box), bev_corners(box[None])[0])


def test_pick_draws_as_choice() -> None:
    from lidarfuzz.operators.lidar.objects.insertion import _pick

    for seed in range(300):
        entries = np.flatnonzero(np.random.default_rng(seed).random(1 + seed % 97) < 0.7)
        if not len(entries):
            continue
        ours, theirs = np.random.default_rng([seed, 1]), np.random.default_rng([seed, 1])
        for _ in range(5):
            assert _pick(ours, entries) == theirs.choice(entries)
        assert ours.bit_generator.state == theirs.bit_generator.state


def test_truncation_is_camera_labels() -> None:
    from lidarfuzz.operators.lidar.objects.insertion import _truncation
    from lidarfuzz.scene.labels import camera_labels
    from lidarfuzz.sim.dataset import GenerationConfig, render_frames

    calib = next(iter(render_frames(GenerationConfig(frames=1, seed=11)))).calib
    assert calib is not None
    rng = np.random.default_rng(29)
    azimuth, distance = rng.uniform(-np.pi, np.pi, 400), rng.uniform(0.5, 60.0, 400)
    boxes = np.column_stack([distance * np.cos(azimuth), distance * np.sin(azimuth), rng.uniform(-2, 0, 400),
                             rng.uniform(0.3, 8.0, (400, 3)), rng.uniform(-np.pi, np.pi, 400)])
    seen = set()
    for box in boxes:
        want = float(camera_labels(calib, box).truncation[0])
        assert _truncation(calib, box) == want
        seen.add("none" if want == 0.0 else "out" if want == 1.0 else "part")
    assert seen == {"none", "out", "part"}  # the cases the shortcut takes and those it does not


@pytest.mark.parametrize("name", ["object_insertion", "object_placement"])
def test_helpers_on_simulator_frames_are_as_before(monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    """Every ground ring, wedge and silhouette that inserting objects into simulator frames (an
    HDL-64E with rings, a VLP-16 sequence) asks for gives what the former code gives."""
    from lidarfuzz.operators.base import generator
    from lidarfuzz.operators.registry import available
    from tests.operators.golden import frames

    calls: dict[str, list[tuple[object, ...]]] = {"lowest": [], "wedge": [], "silhouette": []}
    helpers = {"lowest": support._lowest_per_cell, "wedge": support._wedge_of, "silhouette": support._silhouette}

    def recording(kind: str) -> Any:
        def call(*args: Any) -> Any:
            calls[kind].append(args)
            return helpers[kind](*args)
        return call

    monkeypatch.setattr(support, "_lowest_per_cell", recording("lowest"))
    monkeypatch.setattr(support, "_wedge_of", recording("wedge"))
    monkeypatch.setattr(support, "_silhouette", recording("silhouette"))
    for scene in frames().values():
        op = available()[name].at_severity(5)
        for trial in range(3):
            op(scene, generator(3, scene.frame_id, 0, trial))
    assert all(len(found) >= 3 for found in calls.values()), {k: len(v) for k, v in calls.items()}
    for dx, dy, z, cell in calls["lowest"]:
        assert same_array(helpers["lowest"](dx, dy, z, cell), former_lowest_per_cell(dx, dy, z, cell))
    for xyz, ring, index, centre in calls["wedge"]:
        assert_same_wedge(helpers["wedge"](xyz, ring, index, centre), former_wedge_of(xyz, ring, index, centre))
    for key, depth, shape, size in calls["silhouette"]:
        got, want = helpers["silhouette"](key, depth, shape, size), former_silhouette(key, depth, shape, size)
        assert same_array(got[0], want[0]) and same_array(got[1], want[1])
