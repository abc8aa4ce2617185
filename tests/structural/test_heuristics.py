"""Discriminatory-segment heuristics on coverage matrices whose answers are worked out by hand."""

from __future__ import annotations

import itertools

import pytest

from lidarfuzz.structural.heuristics import (
    budget,
    closeness,
    decision_change,
    decision_changes,
    greedy_edges,
    greedy_nodes,
    random_segments,
    select,
)
from lidarfuzz.structural.requirements import Requirement, union
from lidarfuzz.structural.segments import partition


def edges(*lines: int) -> frozenset[Requirement]:
    return frozenset(Requirement("m:f", "edge", n, n + 1) for n in lines)


def nodes(*lines: int) -> frozenset[Requirement]:
    return frozenset(Requirement("m:f", "node", n) for n in lines)


def test_greedy_edges_finds_the_optimum_when_it_is_reachable():
    # S0 {1}, S1 {1,2,3}, S2 {4}, S3 {3,4,5}, S4 {}: S1 and S3 both add 3 first (tie: S1, the earlier),
    # then S3 adds {4,5}; nothing is left. No single segment holds all five: two is the optimum.
    matrix = [edges(1), edges(1, 2, 3), edges(4), edges(3, 4, 5), frozenset()]
    chosen = greedy_edges(matrix)
    assert chosen.segments == (1, 3)
    assert [s.score for s in chosen.steps] == [3, 2]
    assert [s.added for s in chosen.steps] == [edges(1, 2, 3), edges(4, 5)]
    assert chosen.covered == union(*matrix)


def test_greedy_is_not_optimal_on_the_documented_case():
    # A {1,2,3,4}, B {1,2,5}, C {3,4,6}: greedy takes A (4 new), then B and C (1 new each): 3 segments;
    # B and C alone cover {1..6}: the optimum is 2.
    matrix = [edges(1, 2, 3, 4), edges(1, 2, 5), edges(3, 4, 6)]
    chosen = greedy_edges(matrix)
    assert chosen.segments == (0, 1, 2) and [s.score for s in chosen.steps] == [4, 1, 1]
    everything = union(*matrix)
    smallest = min(len(c) for k in range(1, 4) for c in itertools.combinations(range(3), k)
                   if union(*(matrix[i] for i in c)) == everything)
    assert smallest == 2 < len(chosen)


def test_ties_go_to_the_earliest_segment_and_identical_segments_are_taken_once():
    matrix = [edges(7, 8), edges(7, 8), edges(7, 8)]
    assert greedy_edges(matrix).segments == (0,)
    assert greedy_edges([frozenset(), frozenset()]).segments == ()


def test_nodes_and_edges_choose_differently():
    # S0: nodes {1, 2}, edge {1}; S1: node {1}, edges {1, 2, 3}.
    s0, s1 = nodes(1, 2) | edges(1), nodes(1) | edges(1, 2, 3)
    by_nodes, by_edges = greedy_nodes([s0, s1]), greedy_edges([s0, s1])
    assert by_nodes.segments == (0,) and by_nodes.steps[0].score == 2  # S1 adds no new node
    assert by_edges.segments == (1,) and by_edges.steps[0].score == 3  # S0 adds no new edge
    assert by_edges.steps[0].added == s1  # what it added: every requirement, nodes too


def test_the_budget_counts_frames():
    # sizes 5, 5, 5, 2; S0 {1,2,3}, S1 {4,5,6,7}, S2 {1,2,3,4,5}, S3 {8,9}
    matrix = [edges(1, 2, 3), edges(4, 5, 6, 7), edges(1, 2, 3, 4, 5), edges(8, 9)]
    sizes = [5, 5, 5, 2]
    # 10 frames: S2 (+5, 5 left), then S1 {6,7} and S3 {8,9} tie at +2: S1 (0 left); S3 no longer fits.
    ten = budget(matrix, sizes, 10)
    assert ten.segments == (2, 1) and ten.frames == 10 and [s.score for s in ten.steps] == [5, 2]
    # 12 frames: the same, then S3 (2 frames) fits the 2 left.
    assert budget(matrix, sizes, 12).segments == (2, 1, 3)
    # 4 frames: only the short S3 fits.
    assert budget(matrix, sizes, 4).segments == (3,)
    with pytest.raises(ValueError, match="budget: expected a whole number of frames >= 1"):
        budget(matrix, sizes, 0)


def test_decision_changes_are_counted_per_segment_a_boundary_change_for_the_later_one():
    segments = partition([f"{i:06d}" for i in range(12)])  # frames 0-4, 5-9, 10-11
    go, slow, left = ("keep", 0), ("slow", 0), ("keep", 1)
    signatures = [go, go, slow, go, go, go, go, go, go, go, left, left]
    # changes at frame 2 (go -> slow) and 3 (slow -> go), both in segment 0; at 10 (go -> left): segment 2
    assert decision_changes(segments, signatures) == [2, 0, 1]
    coverage = [edges(1), edges(2), edges(1, 3)]
    chosen = decision_change(segments, signatures, coverage)
    assert chosen.segments == (0, 2) and [s.score for s in chosen.steps] == [2, 1]
    assert [s.added for s in chosen.steps] == [edges(1), edges(3)]
    assert chosen.log_order() == (0, 2) and chosen.frames == 5 + 2
    # without coverage the steps still say how many changes each holds
    assert decision_change(segments, signatures).steps[1].added == frozenset()
    # ties (one change each): the earlier segment first
    tied = [go] * 4 + [slow] + [slow] * 4 + [go] + [go, go]
    assert decision_changes(segments, tied) == [1, 1, 0]  # frames 4 and 9 change
    assert decision_change(segments, tied).segments == (0, 1)
    with pytest.raises(ValueError, match=r"signatures: expected one decision signature per frame of the log \(12\)"):
        decision_changes(segments, signatures[:-1])


def test_the_random_baseline_is_seeded_and_matches_the_reference_size():
    matrix = [edges(i, i + 20) for i in range(20)]
    segments = partition([f"{i:06d}" for i in range(100)])  # 20 segments of 5
    a = random_segments(matrix, 6, seed=3)
    assert a == random_segments(matrix, 6, seed=3)  # same seed, same draw
    assert len(set(a.segments)) == 6 and all(0 <= i < 20 for i in a.segments)
    draws = {random_segments(matrix, 6, seed=s).segments for s in range(10)}
    assert len(draws) > 1  # the seed matters (10 seeds drawing the same 6 of 20 in the same order: ~never)
    assert a.covered == union(*(matrix[i] for i in a.segments))
    # the reference (greedy on edges) needs all 20 segments here (each has 2 edges no other has)
    assert len(select("random", segments, matrix, seed=1)) == len(greedy_edges(matrix)) == 20
    small = [edges(1, 2), edges(1), edges(3)] + [frozenset()] * 17
    assert len(select("random", segments, small, seed=1)) == 2  # greedy: S0, then S2
    with pytest.raises(ValueError, match="count: expected 0 to 20 segments, got 21"):
        random_segments(matrix, 21, seed=0)


def test_select_names_what_is_missing():
    segments = partition(["a", "b"], 1)
    with pytest.raises(ValueError, match="heuristic 'h9': choose one of"):
        select("h9", segments, [frozenset(), frozenset()])
    with pytest.raises(ValueError, match="budget needs frames"):
        select("budget", segments, [frozenset(), frozenset()])
    with pytest.raises(ValueError, match="greedy_edges needs coverage"):
        select("greedy_edges", segments)
    with pytest.raises(ValueError, match="decision_change needs signatures"):
        select("decision_change", segments)


def test_closeness_compares_the_reduced_log_with_the_full_one():
    # total: nodes 1-4, edges 1-10. Segments (5, 5, 2 frames): S0 nodes {1,2} edges {1,2}; S1 node {3} edges {3};
    # S2 edges {4}. Full log: 3/4 nodes, 4/10 edges. The budget of 7 frames takes S0 (+2 edges, 5 frames, 2 left),
    # then S2 (+1, 2 frames): nodes {1,2} = 2/4, edges {1,2,4} = 3/10, 7 of 12 frames, 2 of 3 segments.
    total = nodes(1, 2, 3, 4) | edges(*range(1, 11))
    matrix = [nodes(1, 2) | edges(1, 2), nodes(3) | edges(3), edges(4)]
    segments = partition([f"{i}" for i in range(12)])
    chosen = budget(matrix, [len(s) for s in segments], 7)
    assert chosen.segments == (0, 2)
    near = closeness(chosen, matrix, segments, total)
    assert (near.segments, near.frames, near.log_segments, near.log_frames) == (2, 7, 3, 12)
    assert (near.nodes, near.edges, near.log_nodes, near.log_edges) == (0.5, 0.3, 0.75, 0.4)
    # without a total, ratios are of what the full log covers: nodes 2/3, edges 3/4
    relative = closeness(chosen, matrix, segments)
    assert relative.nodes == pytest.approx(2 / 3) and relative.edges == 0.75 and relative.log_edges == 1.0


def test_the_select_and_compare_commands_replay_the_controller(kitti_log, tmp_path):
    import json

    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app

    runner = CliRunner()
    target = "lidarfuzz.suts.controller.vfh"
    result = runner.invoke(app, ["logs", "select", str(kitti_log), "--sut", "controller", "--target", target,
                                 "--size", "1", "--json", "--out", str(tmp_path / "base"), "--record", "sample",
                                 "--workspace", str(tmp_path / "ws")])
    assert result.exit_code == 0, result.output
    chosen = json.loads(result.output[result.output.index("{"):])
    from sqlalchemy import select as query

    from lidarfuzz.store.models import CoverageRecord
    from lidarfuzz.store.store import Store
    from lidarfuzz.structural.stored import coverage_summary

    store = Store(tmp_path / "ws")
    with store.session() as s:
        records = [coverage_summary(r) for r in s.scalars(query(CoverageRecord).order_by(CoverageRecord.id))]
    store.close()
    # per criterion: the log's row, then one per segment (3 segments of 1 frame): 2 x (1 + 3) rows
    assert [(r.criterion, r.log_id is not None) for r in records] == [
        ("node", True), ("node", False), ("node", False), ("node", False),
        ("edge", True), ("edge", False), ("edge", False), ("edge", False)]
    assert records[4].ratio == pytest.approx(chosen["log_edges"]) and records[0].target == target
    # the log covers the union of its segments': at least each one's, at most their sum
    segment_counts = [r.covered_count for r in records[5:]]
    assert max(segment_counts) <= records[4].covered_count <= sum(segment_counts)
    assert chosen["log_segments"] == 3 and chosen["log_frames"] == 3
    assert chosen["frames"] == len(chosen["steps"]) >= 1  # one frame a segment
    assert chosen["edges"] == chosen["log_edges"] > 0  # greedy on edges keeps every edge the log covers
    assert [s["added_edges"] for s in chosen["steps"]] == sorted((s["added_edges"] for s in chosen["steps"]),
                                                                 reverse=True)
    # the base log against itself: nothing new, together = either
    compared = runner.invoke(app, ["logs", "compare", str(tmp_path / "base"), str(tmp_path / "base"), "--sut",
                                   "controller", "--target", target, "--json"])
    assert compared.exit_code == 0, compared.output
    rows = json.loads(compared.output[compared.output.index("["):])
    assert [r["criterion"] for r in rows] == ["all-nodes", "all-edges"]
    assert all(r["aggregated"] == 0 and r["new"] == [] and r["base"] == r["generated"] == r["together"] for r in rows)
    assert rows[1]["base"] == pytest.approx(chosen["edges"])
    refused = runner.invoke(app, ["logs", "select", str(kitti_log), "--sut", "controller", "--target", target,
                                  "--heuristic", "budget"])
    assert refused.exit_code != 0 and "frame budget" in refused.output
