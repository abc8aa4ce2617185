"""The object operators' point index answers exactly what a scan of every point answers (issue 25):
the grid and azimuth buckets only narrow the search, a derived index (a frame with an object
inserted) maps its parent's answers, a frame grown by insertions reads as the cloud written out
after each, and the per-cloud cache never serves another cloud's index."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators.lidar.common import intensity_scale
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
