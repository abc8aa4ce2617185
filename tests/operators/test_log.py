"""Log operators (Neves et al.): AVG and mutants interleaved into logs."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.operators import get
from lidarfuzz.operators.lidar.log import FrameAverage, interleave


def test_average_of_a_frame_with_itself_is_the_frame(sample_scenes):
    frame = sample_scenes[0]
    combined = FrameAverage().apply(frame, frame)
    assert len(combined.points) <= len(frame.points)
    # Every combined point is an original one (cells hold one point each; duplicates in a cell drop).
    original = {tuple(row) for row in frame.points.data.tolist()}
    assert {tuple(row) for row in combined.points.data.tolist()} <= original
    assert combined.boxes.allclose(frame.boxes)


def test_average_of_two_frames_is_their_midpoint(sample_scenes):
    a, b = sample_scenes[0], sample_scenes[1]
    combined = FrameAverage().apply(a, b)
    assert combined.timestamp == pytest.approx((a.timestamp + b.timestamp) / 2)
    np.testing.assert_allclose(combined.pose[:3, 3], (a.pose[:3, 3] + b.pose[:3, 3]) / 2)
    # Boxes of the same track sit half-way.
    for i, track in enumerate(combined.boxes.track_ids):
        ja = np.flatnonzero(a.boxes.track_ids == track)
        jb = np.flatnonzero(b.boxes.track_ids == track)
        if len(jb) and combined.boxes.has_geometry[i]:
            np.testing.assert_allclose(combined.boxes.centers[i], (a.boxes.centers[ja[0]] + b.boxes.centers[jb[0]]) / 2)
    # A matched cell's point is the mean of the two frames' points in that cell.
    avg = FrameAverage()
    columns = avg.column_count(a.points, b.points)
    cell_a, cell_b = avg.cells(a.points, columns), avg.cells(b.points, columns)
    shared = np.intersect1d(cell_a, cell_b)
    assert len(shared) > 0.5 * len(np.unique(cell_a))
    assert len(combined.points) < len(a.points) + len(b.points)


def test_interleave_builds_the_logs_neves_et_al_use(sample_scenes):
    hgt = get("HGT").at_severity(3)
    log = list(interleave(sample_scenes, hgt, seed=1))
    assert [s.frame_id for s in log] == ["000000", "000000m", "000001", "000001m", "000002", "000002m"]
    stamps = [s.timestamp for s in log]
    assert stamps == sorted(stamps)
    assert not np.allclose(log[1].points.xyz, log[0].points.xyz)
    averaged = list(interleave(sample_scenes, FrameAverage()))
    assert [s.frame_id for s in averaged] == ["000000", "000000+000001", "000001", "000001+000002", "000002"]
    assert [s.timestamp for s in averaged] == sorted(s.timestamp for s in averaged)


def test_cells_need_rings(sample_scenes):
    frame = sample_scenes[0]
    bare = frame.points.without_channels(["ring"])
    with pytest.raises(ValueError, match="ring"):
        FrameAverage().cells(bare, 10)


def test_average_without_rings_pairs_mutual_nearest_neighbours():
    from lidarfuzz.scene.points import PointCloud
    from lidarfuzz.scene.scene import Scene

    # First frame: (0,0,0) (10,0,0) (20,0,0); second: (0.2,0,0) (10,0,0.4) (30,0,0), intensity 0.
    # Mutual nearest within 0.5 m: (0,0,0)~(0.2,0,0) at 0.2 m and (10,0,0)~(10,0,0.4) at 0.4 m, averaged to
    # (0.1,0,0) and (10,0,0.2); (20,0,0) and (30,0,0) have no partner within 0.5 m and are kept as they are.
    a = Scene(PointCloud(np.array([[0, 0, 0, 0], [10, 0, 0, 0], [20, 0, 0, 0]], np.float32)), frame_id="a",
              timestamp=0.0)
    b = Scene(PointCloud(np.array([[0.2, 0, 0, 0], [10, 0, 0.4, 0], [30, 0, 0, 0]], np.float32)), frame_id="b",
              timestamp=0.1)
    combined = FrameAverage().apply(a, b)
    rows = sorted(map(tuple, np.round(combined.points.xyz.astype(np.float64), 4).tolist()))
    assert rows == [(0.1, 0.0, 0.0), (10.0, 0.0, 0.2), (20.0, 0.0, 0.0), (30.0, 0.0, 0.0)]
    assert combined.metadata["frame_average_correspondence"] == "nearest"
    assert combined.timestamp == pytest.approx(0.05)
    # A tighter radius pairs only the first two points (0.2 m apart).
    assert len(FrameAverage(radius=0.3).apply(a, b).points) == 5


def test_average_of_real_frames_without_rings(sample_scenes):
    a, b = (s.replace(points=s.points.without_channels(["ring"])) for s in sample_scenes[:2])
    combined = FrameAverage().apply(a, b)
    pairs = len(a.points) + len(b.points) - len(combined.points)
    assert 0 < pairs <= min(len(a.points), len(b.points))
    assert combined.metadata["frame_average_correspondence"] == "nearest"


def test_an_interleaved_log_that_fails_midway_leaves_no_folder(kitti_log, tmp_path):
    from lidarfuzz.operators.mutate import mutate_log

    hgt = get("HGT").at_severity(3)
    calls = []

    def fails_on_the_second(sample, params):
        calls.append(sample.frame_id)
        if len(calls) == 2:
            raise RuntimeError("disk gone")
        return sample

    hgt.apply = fails_on_the_second
    # one line naming the operator and the last frame written (frame 000000, its mutant, frame 000001;
    # the second call makes the mutant of 000001); the cause is kept as __cause__
    with pytest.raises(LidarfuzzError, match="height_shift failed after frame 000001: RuntimeError: disk gone"):
        mutate_log(kitti_log, tmp_path / "out", hgt)
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    # without rings AVG now writes the whole log: 3 frames and the 2 averages between them
    bare = tmp_path / "bare"
    from lidarfuzz.io import open_dataset, write_kitti

    write_kitti(bare, [s.replace(points=s.points.without_channels(["ring"])) for s in open_dataset(kitti_log)])
    result = mutate_log(bare, tmp_path / "avg", FrameAverage())
    assert result.frames == 5
