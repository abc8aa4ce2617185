"""Segments: partitions of a log and their coverage."""

from __future__ import annotations

import pytest

from lidarfuzz.structural.requirements import Requirement
from lidarfuzz.structural.segments import DEFAULT_SIZE, partition, segment_coverage

IDS = [f"{i:06d}" for i in range(12)]


def test_twelve_frames_in_fives_give_two_full_segments_and_a_short_last_one():
    # 12 = 5 + 5 + 2: frames 0-4, 5-9, 10-11
    segments = partition(IDS)
    assert DEFAULT_SIZE == 5
    assert [(s.id, s.first, s.last, len(s)) for s in segments] == [
        ("s000000", 0, 4, 5), ("s000001", 5, 9, 5), ("s000002", 10, 11, 2)]
    assert segments[2].frame_ids == ("000010", "000011")
    assert partition(IDS) == segments  # stable


def test_sizes_that_divide_and_extremes():
    assert [len(s) for s in partition(IDS, 4)] == [4, 4, 4]
    assert [len(s) for s in partition(IDS, 1)] == [1] * 12
    assert [len(s) for s in partition(IDS, 50)] == [12]


@pytest.mark.parametrize("size", [0, -3, 2.5, True])
def test_a_bad_size_is_one_line_naming_the_field(size):
    with pytest.raises(ValueError, match=r"^segment size: expected a whole number of frames >= 1"):
        partition(IDS, size)


def test_no_frames_is_refused():
    with pytest.raises(ValueError, match="frame_ids"):
        partition([])


def test_segment_coverage_is_the_union_of_its_frames():
    n = [Requirement("m:f", "node", line) for line in (1, 2, 3)]
    e = Requirement("m:f", "edge", 1, 2)
    # frames 0..4: {n1}, {n1, e}, {}, {n2}, {n3}; size 2 -> segments {0,1}, {2,3}, {4}
    per_frame = [frozenset({n[0]}), frozenset({n[0], e}), frozenset(), frozenset({n[1]}), frozenset({n[2]})]
    segments = partition(IDS[:5], 2)
    assert segment_coverage(segments, per_frame) == [frozenset({n[0], e}), frozenset({n[1]}), frozenset({n[2]})]
    with pytest.raises(ValueError, match=r"per_frame: expected one coverage set per frame of the log \(5\), got 4"):
        segment_coverage(segments, per_frame[:4])


def test_the_partition_command_lists_and_records_segments(tmp_path):
    import json

    import numpy as np
    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app
    from lidarfuzz.io.kitti import KittiWriter
    from lidarfuzz.scene.points import PointCloud
    from lidarfuzz.scene.scene import Scene
    from lidarfuzz.store.store import Store
    from lidarfuzz.structural.stored import get_log

    root = tmp_path / "drive"
    with KittiWriter(root) as writer:
        for i in range(7):  # 7 frames at 10 Hz; size 3 -> frames 0-2, 3-5, 6
            xyz = np.random.default_rng(i).uniform(-20, 20, (40, 3))
            writer.add(Scene(PointCloud(np.column_stack([xyz, np.full(40, 0.2)]).astype(np.float32)),
                             frame_id=f"{i:06d}", timestamp=0.1 * i))
    runner = CliRunner()
    result = runner.invoke(app, ["logs", "partition", str(root), "--size", "3", "--json", "--record", "drive",
                                 "--workspace", str(tmp_path / "ws")])
    assert result.exit_code == 0, result.output
    listed = json.loads(result.output)
    assert [(s["id"], s["first"], s["last"], s["frames"]) for s in listed] == [
        ("s000000", 0, 2, 3), ("s000001", 3, 5, 3), ("s000002", 6, 6, 1)]
    assert listed[1]["start_s"] == pytest.approx(0.3) and listed[1]["end_s"] == pytest.approx(0.5)
    store = Store(tmp_path / "ws")
    with store.session() as s:
        assert [(g.size, g.index, g.first_frame_id) for g in get_log(s, "drive").segments] == [
            (3, 0, "000000"), (3, 1, "000003"), (3, 2, "000006")]
    store.close()
    refused = runner.invoke(app, ["logs", "partition", str(root / "velodyne")])
    assert refused.exit_code != 0
