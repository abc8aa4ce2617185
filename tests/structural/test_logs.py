"""Logs: data sets with order, and one-line refusals for those without."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.io.atomic import write_text
from lidarfuzz.io.frames import write_frame
from lidarfuzz.io.kitti import KittiWriter
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.structural.logs import NotALogError, open_log


def _scene(frame_id: str, timestamp: float | None = None, pose: bool = False) -> Scene:
    return Scene(PointCloud(np.full((4, 4), 1.0 + int(frame_id), np.float32)), frame_id=frame_id,
                 timestamp=timestamp, pose=np.eye(4) if pose else None)


def _kitti(root: Path, stamps: list[float | None], pose: bool = False) -> Path:
    with KittiWriter(root) as writer:
        for i, t in enumerate(stamps):
            writer.add(_scene(f"{i:06d}", t, pose))
    return root


def test_a_kitti_log_is_ordered_by_its_timestamps(tmp_path):
    # stamps 0.3, 0.1, 0.2 for frames 0, 1, 2: replay order 1, 2, 0
    log = open_log(_kitti(tmp_path / "log", [0.3, 0.1, 0.2]))
    assert log.frame_ids == ("000001", "000002", "000000") and log.order == "timestamps"
    assert log.timestamps is not None and log.timestamps.tolist() == [0.1, 0.2, 0.3]
    assert len(log) == 3 and [s.frame_id for s in log] == ["000001", "000002", "000000"]
    assert log.frame(0).timestamp == 0.1


def test_a_kitti_folder_with_poses_only_is_a_sequence_in_frame_id_order(tmp_path):
    log = open_log(_kitti(tmp_path / "log", [None, None, None], pose=True))
    assert log.order == "frame_ids" and log.timestamps is None
    assert log.frame_ids == ("000000", "000001", "000002")


def test_a_bag_keeps_its_container_order(tmp_path):
    from lidarfuzz.io.logs import write_log

    out = tmp_path / "drive.mcap"
    write_log(out, [_scene("0", 5.0), _scene("1", 5.1)])
    log = open_log(out)
    assert log.order == "container" and log.frame_ids == ("000000", "000001")
    assert log.timestamps is not None and log.timestamps.tolist() == [5.0, 5.1]


def test_a_kitti_folder_without_timestamps_or_poses_is_refused_naming_what_is_missing(tmp_path):
    root = _kitti(tmp_path / "plain", [None, None])
    with pytest.raises(NotALogError) as caught:
        open_log(root)
    message = str(caught.value)
    assert str(root) in message and "timestamps.txt" in message and "\n" not in message


def test_a_folder_of_frames_is_refused(tmp_path):
    folder = tmp_path / "frames"
    for i in range(2):
        write_frame(folder / f"{i:06d}.pcd", _scene(f"{i}"))
    with pytest.raises(NotALogError, match=r"frames.*not a log: a folder of frame files has no timestamps"):
        open_log(folder)
    with pytest.raises(NotALogError, match="one frame file"):
        open_log(folder / "000000.pcd")


def test_a_malformed_timestamps_file_is_a_data_error(tmp_path):
    root = _kitti(tmp_path / "log", [0.1, 0.2])
    write_text(root / "timestamps.txt", "000000 0.1\n000001 soon\n", overwrite=True)
    with pytest.raises(Exception, match=r"timestamps.txt:2: not a number"):
        open_log(root)


def test_replaying_a_log_gives_coverage_per_frame_and_keeps_going_after_a_failure():
    from types import SimpleNamespace

    from lidarfuzz.structural.log_coverage import frame_coverage
    from lidarfuzz.structural.requirements import Requirement

    class Recorder:
        """Covers node <frame number>; frame 2 raises after covering node 99."""

        last: frozenset = frozenset()

        def record(self, function, *args):
            frame = args[0]
            self.last = frozenset({Requirement("m:f", "node", int(frame.frame_id))})
            if frame.frame_id == "2":
                self.last = frozenset({Requirement("m:f", "node", 99)})
            return function(*args), self.last

    def step(frame):
        if frame.frame_id == "2":
            raise RuntimeError("lost the ground\nsecond line")
        return SimpleNamespace(steering=0.0, speed=1.0, emergency_stop=False)

    resets = []
    frames = [_scene(str(i), 0.1 * i) for i in range(4)]
    replay = frame_coverage(frames, step, Recorder(), reset=lambda: resets.append(1))
    assert resets == [1]
    assert [sorted(r.source for r in c) for c in replay.covered] == [[0], [1], [99], [3]]
    assert replay.failures == {2: "RuntimeError: lost the ground"} and replay.outputs[2] is None


def test_a_real_recorder_sees_which_branches_each_frame_takes():
    from types import SimpleNamespace

    from lidarfuzz.structural.log_coverage import decision_signature, frame_coverage
    from lidarfuzz.structural.python_coverage import CoverageRecorder

    recorder = CoverageRecorder(["lidarfuzz.structural.log_coverage:decision_signature"])
    # frames 0, 1: cruising straight; 2: an emergency stop; 3: cruising straight again
    decisions = {"0": (0.0, 8.0, False), "1": (0.0, 9.0, False), "2": (0.0, 8.0, True), "3": (0.01, 7.0, False)}

    def step(frame):
        steering, speed, stop = decisions[frame.frame_id]
        return decision_signature(SimpleNamespace(steering=steering, speed=speed, emergency_stop=stop))

    replay = frame_coverage([_scene(str(i), 0.1 * i) for i in range(4)], step, recorder)
    assert replay.outputs == [("cruise", 0), ("cruise", 0), ("stop", 0), ("cruise", 0)]
    assert replay.covered[0] == replay.covered[1] == replay.covered[3] != replay.covered[2]
    assert replay.covered[0] and replay.covered[2]


def test_two_logs_compared_as_the_paper_does():
    from lidarfuzz.structural.log_coverage import compare_logs
    from lidarfuzz.structural.requirements import Requirement

    n = [Requirement("m:f", "node", i) for i in range(1, 5)]
    e = [Requirement("m:f", "edge", i, i + 1) for i in range(1, 6)]
    total = frozenset(n + e)
    # base L': nodes 1, 2 and edge 1; generated L'' (per frame): nodes 2, 3 and edges 1, 2, 3.
    # nodes: 2/4 and 2/4, together 3/4, aggregated |{3}| / 4; edges: 1/5 and 3/5, together 3/5, aggregated 2/5
    nodes, edges = compare_logs(frozenset({n[0], n[1], e[0]}), [frozenset({n[1], e[0]}), frozenset({n[2], e[1], e[2]})],
                                total)
    assert (nodes.total, nodes.base, nodes.generated, nodes.together, nodes.aggregated) == (4, 0.5, 0.5, 0.75, 0.25)
    assert nodes.new == frozenset({n[2]})
    assert (edges.total, edges.base, edges.generated, edges.together, edges.aggregated) == (5, 0.2, 0.6, 0.6, 0.4)
