"""Neves et al.'s meta-model in the store: field-test and generated logs, segments, coverage records —
on SQLite and PostgreSQL."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import select, text
from sqlalchemy.exc import IntegrityError

from lidarfuzz.io.kitti import KittiWriter
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.store.errors import ConflictError, NotFoundError
from lidarfuzz.store.models import CoverageRecord, Log, LogKind, Segment
from lidarfuzz.store.store import Store
from lidarfuzz.structural.generate import strategy, write_generated_log
from lidarfuzz.structural.logs import OrderedLog, open_log
from lidarfuzz.structural.requirements import Requirement
from lidarfuzz.structural.segments import partition
from lidarfuzz.structural.stored import (
    coverage_summary,
    from_labels,
    get_log,
    log_summary,
    record_coverage,
    record_generated,
    record_log,
    record_segments,
    segment_summary,
    to_labels,
)


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Store]:
    where = tmp_path / "ws" if request.param == "sqlite" else request.getfixturevalue("fresh_postgres_url")
    opened = Store(where)
    yield opened
    opened.close()


@pytest.fixture
def log(tmp_path: Path) -> OrderedLog:
    """Seven frames at 10 Hz (grid points 0.93 m apart, so the KITTI reader takes them for a scan)."""
    x, y = np.meshgrid(np.arange(4.0), np.arange(8.0))
    root = tmp_path / "drive"
    with KittiWriter(root) as writer:
        for i in range(7):
            xyz = np.column_stack([0.93 * x.ravel() + 3.1, 0.93 * y.ravel() - 2.9, np.full(32, 0.07 * i + 0.01)])
            writer.add(Scene(PointCloud(np.column_stack([xyz, np.full(32, 0.3)]).astype(np.float32)),
                             frame_id=f"{i:06d}", timestamp=0.1 * i))
    return open_log(root)


def test_labels_round_trip_and_are_grouped_by_function():
    covered = {Requirement("a:f", "node", 4), Requirement("a:f", "edge", 4, -2), Requirement("b:g", "node", 10)}
    assert to_labels(covered) == {"a:f": ["4", "4->-2"], "b:g": ["10"]}
    assert from_labels(to_labels(covered)) == frozenset(covered)
    with pytest.raises(ValueError, match=r"covered: a:f: label 'x' is neither"):
        from_labels({"a:f": ["x"]})


def test_a_field_test_log_its_segments_and_coverage(store: Store, log: OrderedLog):
    n = [Requirement("m:f", "node", line) for line in (1, 2, 3, 4)]
    e = [Requirement("m:f", "edge", a, b) for a, b in ((1, 2), (2, 3), (2, 4))]
    total = frozenset(n + e)
    with store.session() as s:
        row = record_log(s, log, "drive-1")
        segments = record_segments(s, row, partition(log.frame_ids, 3))  # frames 0-2, 3-5, 6
        assert record_segments(s, row, partition(log.frame_ids, 3)) == segments  # the same again: the same rows
        record_coverage(s, log=row, fingerprint="abc", criterion="node", target="m:f", covered=n[:3] + e[:1],
                        total=total)
        record_coverage(s, segment=segments[2], fingerprint="abc", criterion="edge", target="m:f",
                        covered=[n[0], e[2]], total=total)
    with store.session() as s:
        row = get_log(s, "drive-1")
        summary = log_summary(row)
        assert (summary.kind, summary.frame_count, summary.format, summary.segment_sizes) == ("field_test", 7,
                                                                                             "kitti", [3])
        assert [(g.index, g.first_frame, g.last_frame, g.last_frame_id) for g in row.segments] == [
            (0, 0, 2, "000002"), (1, 3, 5, "000005"), (2, 6, 6, "000006")]
        assert segment_summary(row.segments[2]).first_frame_id == "000006"
        records = list(s.scalars(select(CoverageRecord).order_by(CoverageRecord.id)))
        # the log: nodes 1, 2, 3 of 4 (the edge given is not a node); the last segment: edge 2->4 of 3
        assert coverage_summary(records[0]).model_dump(exclude={"log_id", "segment_id"}) == {
            "fingerprint": "abc", "criterion": "node", "target": "m:f", "covered_count": 3, "total_count": 4,
            "ratio": 0.75}
        assert records[0].covered == {"m:f": ["1", "2", "3"]}
        assert from_labels(records[1].covered) == frozenset({e[2]}) and records[1].segment_id == row.segments[2].id
        assert (records[1].covered_count, records[1].total_count) == (1, 3)
    with store.session() as s, pytest.raises(ConflictError, match="a different partition at size 3"):
        record_segments(s, get_log(s, "drive-1"), partition(list(log.frame_ids[1:]), 3))
    with store.session() as s, pytest.raises(ConflictError, match="already recorded"):
        record_log(s, log, "drive-1")
    with store.session() as s, pytest.raises(NotFoundError, match="no log named 'drive-9'"):
        get_log(s, "drive-9")


def test_a_generated_log_keeps_its_parent_heuristic_strategy_and_provenance(store: Store, log: OrderedLog,
                                                                            tmp_path: Path):
    segments = partition(log.frame_ids)  # 0-4, 5-6
    made = write_generated_log(log, [segments[1]], strategy("AVG"), tmp_path / "avg", heuristic="greedy_edges")
    with store.session() as s:
        parent = record_log(s, log, "drive-1")
        record_generated(s, made, "drive-1-avg", parent)
    with store.session() as s:
        child = get_log(s, "drive-1-avg")
        assert child.kind is LogKind.GENERATED and child.parent is not None and child.parent.name == "drive-1"
        assert (child.heuristic, child.strategy, child.frame_count) == ("greedy_edges", "AVG", 3)  # 2k - 1, k = 2
        assert child.generation is not None and child.generation.segments == [1]
        assert [f.sources for f in child.generation.frames] == [["000005"], ["000005", "000006"], ["000006"]]
        assert log_summary(child).parent_id == child.parent.id
        # a parent with children cannot be deleted from under them
        with pytest.raises(IntegrityError):
            s.execute(text("DELETE FROM logs WHERE name = 'drive-1'"))
            s.flush()
        s.rollback()


def test_coverage_belongs_to_a_log_or_a_segment_never_both(store: Store, log: OrderedLog):
    with store.session() as s:
        row = record_log(s, log, "drive-1")
        segment = record_segments(s, row, partition(log.frame_ids))[0]
        with pytest.raises(ValueError, match="a log or a segment"):
            record_coverage(s, fingerprint="f", criterion="node", target="t", covered=[], total=[])
        with pytest.raises(IntegrityError):  # the table refuses it too
            s.add(CoverageRecord(log_id=row.id, segment_id=segment.id, fingerprint="f", criterion="node",
                                 target="t", covered={}, covered_count=0, total_count=0))
            s.flush()
        s.rollback()
    with store.session() as s:
        row = record_log(s, log, "drive-2")
        empty = record_coverage(s, log=row, fingerprint="f", criterion="edge", target="t", covered=[], total=[])
        assert math.isnan(coverage_summary(empty).ratio) and coverage_summary(empty).dump()["ratio"] is None
        # deleting a log deletes its segments and coverage
        record_segments(s, row, partition(log.frame_ids))
    with store.session() as s:
        s.delete(get_log(s, "drive-2"))
    with store.session() as s:  # drive-1 was rolled back with the refused row; drive-2 took its rows with it
        assert list(s.scalars(select(Log))) == []
        assert list(s.scalars(select(Segment))) == [] and list(s.scalars(select(CoverageRecord))) == []
