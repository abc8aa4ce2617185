"""Generated logs: HGT after each source (2k a segment), AVG between sources (2k − 1), any operator seeded
as in campaigns, provenance recorded, written atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.io.atomic import OutputExistsError
from lidarfuzz.io.kitti import KittiWriter
from lidarfuzz.operators import get
from lidarfuzz.operators.base import generator
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.structural.generate import (
    GeneratedLog,
    GenerationError,
    expected_frames,
    operator_stream,
    strategy,
    write_generated_log,
)
from lidarfuzz.structural.logs import open_log
from lidarfuzz.structural.segments import partition


def _cloud(i: int) -> PointCloud:
    # 60 points on a 6 x 10 grid, 0.93 m apart (not whole numbers: the KITTI reader refuses those), at height
    # 0.1 * i; intensity 0.5; no ring channel
    x, y = np.meshgrid(np.arange(6.0), np.arange(10.0))
    xyz = np.column_stack([0.93 * x.ravel() + 5.17, 0.93 * y.ravel() - 4.71, np.full(60, 0.1 * i + 0.013)])
    return PointCloud(np.column_stack([xyz, np.full(60, 0.5)]).astype(np.float32))


@pytest.fixture
def five_frame_log(tmp_path: Path) -> Path:
    """Frames 000000..000004 at 0.0, 0.1, ... 0.4 s."""
    root = tmp_path / "parent"
    with KittiWriter(root) as writer:
        for i in range(5):
            writer.add(Scene(_cloud(i), frame_id=f"{i:06d}", timestamp=0.1 * i))
    return root


def test_frame_counts_per_segment():
    assert [expected_frames(5, arity) for arity in (0, 1, 2)] == [5, 10, 9]
    assert expected_frames(1, 2) == 1


def test_hgt_inserts_each_mutant_right_after_its_source(five_frame_log, tmp_path):
    log = open_log(five_frame_log)
    segments = partition(log.frame_ids, 2)  # frames 0-1, 2-3, 4
    made = write_generated_log(log, segments, strategy("HGT"), tmp_path / "hgt", heuristic="greedy_edges")
    # 2k frames per segment: 4 + 4 + 2
    assert len(made.frames) == 10
    assert [f.sources for f in made.frames] == [("000000",), ("000000",), ("000001",), ("000001",), ("000002",),
                                               ("000002",), ("000003",), ("000003",), ("000004",), ("000004",)]
    assert [f.operator is not None for f in made.frames] == [False, True] * 5
    assert made.frames[1].params == {"offset": 10.0} and made.frames[1].operator["name"] == "height_shift"
    assert [f.segment for f in made.frames] == [0, 0, 0, 0, 1, 1, 1, 1, 2, 2]
    generated = open_log(tmp_path / "hgt")
    assert generated.frame_ids == tuple(f"{i:06d}" for i in range(10))
    # copies keep their time; a mutant lies half-way to the next frame of its segment, after the last one of a
    # segment half its last gap later (0.1 + 0.05), and 1 us after the only frame of a one-frame segment
    assert generated.timestamps is not None
    np.testing.assert_allclose(generated.timestamps, [0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.400001])
    source, mutant = generated.frame(2), generated.frame(3)  # frame 000001 (z = 0.113) and its mutant (z = 10.113)
    np.testing.assert_allclose(source.points.xyz[:, 2], 0.113, atol=1e-6)
    np.testing.assert_allclose(mutant.points.xyz[:, 2], 10.113, atol=1e-5)
    np.testing.assert_allclose(mutant.points.xyz[:, :2], source.points.xyz[:, :2])
    assert GeneratedLog.read(tmp_path / "hgt") == made
    assert (made.parent, made.heuristic, made.strategy, made.segments) == (str(five_frame_log), "greedy_edges",
                                                                             "HGT", (0, 1, 2))


def test_avg_inserts_each_average_between_its_sources_without_rings(five_frame_log, tmp_path):
    log = open_log(five_frame_log)
    segments = partition(log.frame_ids, 2)
    # segments 2 (frame 4) and 0 (frames 0, 1), given out of order: written in the log's order
    made = write_generated_log(log, [segments[2], segments[0]], strategy("AVG"), tmp_path / "avg")
    # 2k - 1 frames: 3 for segment 0, 1 for segment 2
    assert [f.sources for f in made.frames] == [("000000",), ("000000", "000001"), ("000001",), ("000004",)]
    assert made.frames[1].params == {"correspondence": "nearest", "radius": 0.5}
    generated = open_log(tmp_path / "avg")
    assert generated.timestamps is not None
    np.testing.assert_allclose(generated.timestamps, [0.0, 0.05, 0.1, 0.4])
    # frames 0 and 1 are the same grid 0.1 m apart in z (grid points 0.93 m apart): every point pairs with the
    # one above it, at z = (0.013 + 0.113) / 2 = 0.063
    combined = generated.frame(1)
    assert len(combined.points) == 60
    np.testing.assert_allclose(combined.points.xyz[:, 2], 0.063, atol=1e-6)


def test_any_operator_is_a_unary_strategy_seeded_as_in_campaigns(five_frame_log, tmp_path):
    from lidarfuzz.campaign.plan import operator_stream as campaign_stream

    assert operator_stream("uniform_point_deletion") == campaign_stream("uniform_point_deletion")
    log = open_log(five_frame_log)
    segments = partition(log.frame_ids)  # one segment of 5
    chosen = strategy("uniform_point_deletion", severity=5)
    first = write_generated_log(log, segments, chosen, tmp_path / "a", seed=4)
    again = write_generated_log(log, segments, chosen, tmp_path / "b", seed=4)
    other = write_generated_log(log, segments, chosen, tmp_path / "c", seed=5)
    assert len(first.frames) == 10
    assert [f.params for f in first.frames] == [f.params for f in again.frames]
    assert [f.params for f in first.frames] != [f.params for f in other.frames]
    # the mutant of frame 000002 is what the campaign engine's generator draws for it
    operator = get("uniform_point_deletion").at_severity(5)
    expected, params = operator(log.frame(2), generator(4, "000002", campaign_stream("uniform_point_deletion"), 0))
    assert first.frames[5].sources == ("000002",) and first.frames[5].params == params.model_dump(mode="json")
    assert len(open_log(tmp_path / "a").frame(5).points) == len(expected.points)


def test_a_failure_on_a_frame_leaves_no_folder(five_frame_log, tmp_path):
    log = open_log(five_frame_log)
    chosen = strategy("HGT")
    calls = []

    def fails_on_the_third(sample, params):
        calls.append(sample.frame_id)
        if len(calls) == 3:
            raise RuntimeError("out of memory")
        return sample

    chosen.operator.apply = fails_on_the_third  # type: ignore[union-attr, method-assign]
    out = tmp_path / "out"
    with pytest.raises(GenerationError, match=r"strategy HGT failed in segment s000001 .*out of memory"):
        write_generated_log(log, partition(log.frame_ids, 2), chosen, out)
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["parent"]  # no temporary folder left either


def test_refusals(five_frame_log, tmp_path):
    log = open_log(five_frame_log)
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "x").write_text("keep")
    with pytest.raises(OutputExistsError):
        write_generated_log(log, partition(log.frame_ids), strategy("HGT"), tmp_path / "taken")
    assert (tmp_path / "taken" / "x").read_text() == "keep"
    with pytest.raises(GenerationError, match=r"--strategy 'warp': unknown operator 'warp'"):
        strategy("warp")
    with pytest.raises(GenerationError, match="no segments"):
        write_generated_log(log, [], strategy("none"), tmp_path / "none")
    with pytest.raises(GenerationError, match="lies outside the log of 5 frames"):
        write_generated_log(log, partition([f"{i}" for i in range(9)], 3)[2:], strategy("none"), tmp_path / "n")


def test_a_parent_without_a_clock_gives_a_log_timed_at_10_hz(tmp_path):
    root = tmp_path / "posed"
    with KittiWriter(root) as writer:
        for i in range(3):
            writer.add(Scene(_cloud(i), frame_id=f"{i:06d}", pose=np.eye(4)))
    log = open_log(root)
    assert log.order == "frame_ids"
    write_generated_log(log, partition(log.frame_ids), strategy("none"), tmp_path / "base")
    generated = open_log(tmp_path / "base")
    assert generated.timestamps is not None
    np.testing.assert_allclose(generated.timestamps, [0.0, 0.1, 0.2])


def test_the_generate_command_writes_the_chosen_segments(five_frame_log, tmp_path):
    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app
    from lidarfuzz.store.store import Store
    from lidarfuzz.structural.stored import get_log

    runner = CliRunner()
    out = tmp_path / "hgt"
    # segments of 2: s000000 = frames 0-1, s000002 = frame 4; HGT doubles each: 4 + 2 frames
    result = runner.invoke(app, ["logs", "generate", str(five_frame_log), "--strategy", "HGT", "--size", "2",
                                 "--segments", "s000002,0", "--heuristic", "budget", "--out", str(out),
                                 "--record", "hgt", "--workspace", str(tmp_path / "ws")])
    assert result.exit_code == 0, result.output
    made = GeneratedLog.read(out)
    assert made.segments == (0, 2) and len(made.frames) == 6 and made.heuristic == "budget"
    store = Store(tmp_path / "ws")
    with store.session() as s:
        child = get_log(s, "hgt")
        assert child.parent is not None and child.parent.name == "parent" and child.frame_count == 6
    store.close()
    bad = runner.invoke(app, ["logs", "generate", str(five_frame_log), "--strategy", "HGT", "--segments", "9",
                              "--out", str(tmp_path / "bad")])
    assert bad.exit_code != 0 and "is not a segment of this log" in bad.output
    assert not (tmp_path / "bad").exists()
