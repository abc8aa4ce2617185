"""Search-based log generation towards uncovered code (lidarfuzz.structural.search), on a toy
system whose rare branches need high points (tests/structural/toy_sequence.py)."""

from __future__ import annotations

import inspect
import json
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.structural.generate import GeneratedLog
from lidarfuzz.structural.log_coverage import frame_coverage
from lidarfuzz.structural.logs import OrderedLog, open_log
from lidarfuzz.structural.python_coverage import CoverageRecorder
from lidarfuzz.structural.requirements import Requirement, union
from lidarfuzz.structural.search import (
    Candidate,
    LogSearchError,
    SearchResult,
    SearchSettings,
    checkpoint_path,
    search_log,
)
from tests.structural.toy_sequence import HeightLadder, flat_log

STEP = "tests.structural.toy_sequence:HeightLadder.step"
POOL = ("height_shift", "intensity_scaling")
# seed 2 climbs the whole ladder by its 66th candidate (seeds 0-7 at 150 candidates: 5 of 8 do)
SETTINGS = SearchSettings(operators=POOL, budget=70, seed=2, size=4)


def _line(text: str) -> int:
    lines, first = inspect.getsourcelines(HeightLadder.step)
    return first + next(i for i, line in enumerate(lines) if text in line)


def _node(text: str) -> Requirement:
    return Requirement(STEP, "node", _line(text))


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> OrderedLog:
    return open_log(flat_log(tmp_path_factory.mktemp("toy") / "log"))


@pytest.fixture(scope="module")
def searched(log: OrderedLog, tmp_path_factory: pytest.TempPathFactory) -> tuple[SearchResult, Path]:
    out = tmp_path_factory.mktemp("searched") / "out"
    return search_log(log, HeightLadder(), [STEP], SETTINGS, out, system_spec="ladder"), out


def test_the_search_climbs_to_the_top_where_random_sampling_cannot(
        log: OrderedLog, searched: tuple[SearchResult, Path]) -> None:
    result, _ = searched
    # HeightLadder.step by hand: blocks [z, if z > 1.1] [run += 1, if run >= 2] [sustained] [top]
    # [run = 0, if z > 0.6] [mid] [if z > 0.25] [low] [ground]: 9 nodes; edges entry->z, z->run+=1,
    # z->run=0, run+=1->sustained, run+=1->top, sustained->exit, top->exit, run=0->mid, run=0->if 0.25,
    # mid->exit, if 0.25->low, if 0.25->ground, low->exit, ground->exit: 14 edges
    assert len(result.total) == 23
    # the flat log takes z, run = 0, if z > 0.25, ground: 4 nodes and 5 edges
    assert len(result.start) == 9
    assert result.covered == result.total  # low, mid, top and two top frames in a row: everything
    assert {_node('"sustained"'), _node('"top"'), _node('"mid"'), _node('"low"')} <= result.new
    assert result.stats["replays"] == 70 and result.stats["kept"] == len(result.kept) == 3
    # every kept candidate mutated the unit the one before it inserted: built on one another
    assert [m.source for m in result.kept][1:] == [f"c{m.candidate}" for m in result.kept][:-1]
    assert result.per_function()[STEP]["node"] == sorted(
        str(_line(t)) for t in ('"sustained"', "self.run += 1", '"top"', '"mid"', '"low"'))

    baseline = search_log(log, HeightLadder(), [STEP], SearchSettings(operators=POOL, budget=70, seed=2, size=4,
                                                                      strategy="random"))
    # random sampling: two operators on the log's own frames move them at most 0.5 + 0.5 m: never above 1.1 m
    assert not {_node('"sustained"'), _node('"top"'), _node("self.run += 1")} & baseline.covered
    assert len(baseline.covered) <= 9 + 3 + 3 < len(result.covered)  # at most low and mid (a node, two edges each)


def test_the_written_log_covers_what_the_summary_lists(log: OrderedLog, searched: tuple[SearchResult, Path]) -> None:
    result, out = searched
    written = open_log(out)
    manifest = GeneratedLog.read(out)
    assert len(written) == result.frames == 12 + 4 * 3  # each kept candidate inserted a mutated copy of 4 frames
    assert manifest.heuristic == "search" and manifest.strategy == "search"
    stamps = written.timestamps
    assert stamps is not None and bool(np.all(np.diff(stamps) > 0))
    assert written.frame_ids == tuple(f"{i:06d}" for i in range(len(written)))  # by timestamp: the search's order
    system = HeightLadder()
    replayed = union(*frame_coverage(written, system.step, CoverageRecorder([STEP]), reset=system.reset).covered)
    assert replayed == result.covered
    mutated = [f for f in manifest.frames if f.operator is not None]
    assert len(mutated) == 12
    last = mutated[-1]  # the last unit: three kept chains of two operators, flattened with exact params
    assert len(last.operator["operators"]) == len(last.params["steps"]) == 6
    summary = json.loads(checkpoint_path(out).read_text())["summary"]
    assert summary["coverage"]["node"] == {"total": 9, "start": 4, "covered": 9}
    assert {entry["requirement"] for entry in summary["found_by"]} == {r.label() for r in result.new}


def test_same_arguments_same_search(log: OrderedLog, searched: tuple[SearchResult, Path]) -> None:
    result, _ = searched
    again = search_log(log, HeightLadder(), [STEP], SETTINGS)
    assert [(m.candidate, m.source, m.spec, m.params) for m in again.kept] == \
        [(m.candidate, m.source, m.spec, m.params) for m in result.kept]
    other = search_log(log, HeightLadder(), [STEP], SearchSettings(operators=POOL, budget=70, seed=3, size=4))
    assert [m.params for m in other.kept] != [m.params for m in result.kept]


def test_an_interrupted_search_resumes_to_the_same_log(log: OrderedLog, searched: tuple[SearchResult, Path],
                                                       tmp_path: Path) -> None:
    result, whole = searched
    out = tmp_path / "out"
    seen: list[Candidate] = []

    def interrupt(candidate: Candidate) -> None:
        seen.append(candidate)
        if len(seen) == 64:  # after the second kept candidate (63), before the third (65)
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        search_log(log, HeightLadder(), [STEP], SETTINGS, out, system_spec="ladder", on_candidate=interrupt)
    assert not out.exists() and json.loads(checkpoint_path(out).read_text())["next_index"] == 64
    with pytest.raises(LogSearchError, match="made with seed 2, this run has 5"):
        search_log(log, HeightLadder(), [STEP], SearchSettings(operators=POOL, budget=70, seed=5, size=4), out,
                   system_spec="ladder")
    resumed = search_log(log, HeightLadder(), [STEP], SETTINGS, out, system_spec="ladder")
    assert resumed.stats["replays"] == 70 and resumed.stats["restore_replays"] == 1
    assert [(m.candidate, m.spec, m.params) for m in resumed.kept] == \
        [(m.candidate, m.spec, m.params) for m in result.kept]
    assert resumed.found.keys() == result.found.keys()
    a, b = GeneratedLog.read(out).to_json(), GeneratedLog.read(whole).to_json()
    assert {**a, "path": None} == {**b, "path": None}
    for frame_id in open_log(out).frame_ids:
        assert np.array_equal(open_log(out).dataset.load(frame_id).points.data,
                              open_log(whole).dataset.load(frame_id).points.data)


def test_bad_settings_and_outputs(log: OrderedLog, tmp_path: Path) -> None:
    with pytest.raises(LogSearchError, match="--operators: unknown operator"):
        SearchSettings(operators=("nothing",))
    with pytest.raises(LogSearchError, match="--operators: image_fog is a camera operator"):
        SearchSettings(operators=("fog", "image_fog"))
    with pytest.raises(LogSearchError, match="--budget"):
        SearchSettings(budget=-1)
    with pytest.raises(LogSearchError, match="--max-severity"):
        SearchSettings(max_severity=6)
    taken = tmp_path / "taken"
    taken.mkdir()
    with pytest.raises(LogSearchError, match="exists and is no output of this search"):
        search_log(log, HeightLadder(), [STEP], SearchSettings(operators=POOL, budget=1), taken)


def test_cli_logs_search(log: OrderedLog, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app

    out = tmp_path / "found"
    args = ["logs", "search", str(log.path), "--sut", "tests.structural.toy_sequence:HeightLadder", "--target", STEP,
            "--operators", ",".join(POOL), "--size", "4", "--seed", "2", "--out", str(out)]
    first = CliRunner().invoke(app, [*args, "--budget", "10"])
    assert first.exit_code == 0, first.output
    assert "candidate 0: s000000 + height_shift+height_shift covers 3 new requirement(s)" in first.output
    assert "candidate 6" not in first.output  # seed 2 keeps candidates 0, 63 and 65
    # the same arguments with a larger budget go on from candidate 10
    workspace = ["--workspace", str(tmp_path / "ws"), "--record", "climbed"]
    more = CliRunner().invoke(app, [*args, "--budget", "70", "--json", *workspace])
    assert more.exit_code == 0, more.output
    summary = json.loads(more.output)
    assert summary["stats"]["candidates"] == 70 and summary["stats"]["restore_replays"] == 1
    assert {entry["candidate"] for entry in summary["found_by"]} == {0, 63, 65}
    assert summary["coverage"]["node"]["covered"] == 9 and summary["frames"] == 24
    from lidarfuzz.store.store import Store
    from lidarfuzz.structural.stored import get_log

    with Store(tmp_path / "ws").session() as session:
        row = get_log(session, "climbed")
        assert (row.heuristic, row.strategy, row.frame_count) == ("search", "search", 24)
        assert row.parent is not None and row.parent.name == "log"
    bad = CliRunner().invoke(app, [*args, "--operators", "nothing"])
    assert bad.exit_code != 0 and "--operators: unknown operator(s) ['nothing']" in str(bad.exception)
