"""The fuzzing harness in CI: a small seeded run over every file target, which must find no escape.

The big run (10,000+ cases per format) is ``python benchmarks/fuzz_files.py``; its figures are in
docs/reliability.md. Here each target gets :data:`CI_CASES` cases through the Python API and a few
targets one case each through the command line.
"""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

from tests.fuzz import harness, selftest_targets, targets_points
from tests.fuzz.harness import ESCAPES, Target, cli_failure, fuzz, mutate, shrink

#: Cases per target in CI: about 40 targets (frames, and every other user file) at 60 cases fit
#: well under a minute on 2 cores; the benchmark runs 10,000 per target.
CI_CASES = 60
SLOW_CASES = 2000


def all_targets() -> list[tuple[str, Target]]:
    """``(module, target)`` for the frame targets and, when present, the other user files' targets."""
    pairs = [("tests.fuzz.targets_points", t) for t in targets_points.TARGETS]
    try:
        files = importlib.import_module("tests.fuzz.targets_files")
    except ImportError:
        return pairs
    return pairs + [("tests.fuzz.targets_files", t) for t in files.TARGETS]


def _escapes(reports: list[harness.TargetReport]) -> list[str]:
    return [f"{r.name} case {e['index']}: {e['outcome']} {e.get('type', '')} at {e.get('where', '?')}: "
            f"{e.get('message', '')[:200]} ({e.get('saved', 'not saved')})" for r in reports for e in r.escapes]


def test_ci_budget_run_finds_no_escape(tmp_path):
    reports = fuzz(all_targets(), cases=CI_CASES, seed=23, time_limit=20.0, results=tmp_path, shrink_budget=30)
    assert _escapes(reports) == []
    assert all(report.cases == CI_CASES for report in reports)
    frames = {t.name for t in targets_points.TARGETS}
    for report in (r for r in reports if r.name in frames):
        # a frame target whose cases are all refused (or all read) does not exercise its reader
        assert report.counts["ok"] > 0 and report.counts["refused"] > 0, (report.name, report.counts)


@pytest.mark.parametrize("name", ["laz", "pcd-binary_compressed"])
def test_cli_cases_exit_cleanly(tmp_path, name):
    target = next(t for t in targets_points.TARGETS if t.name == name)
    reports = fuzz([("tests.fuzz.targets_points", target)], cases=0, seed=23, cli_cases=1, results=tmp_path)
    assert reports[0].cli_cases == 1
    assert reports[0].cli_escapes == []


@pytest.mark.slow
def test_bigger_run_finds_no_escape(tmp_path):
    reports = fuzz(all_targets(), cases=SLOW_CASES, seed=2023, time_limit=20.0, results=tmp_path, cli_cases=3)
    assert _escapes(reports) == []
    assert [e for r in reports for e in r.cli_escapes] == []


# ----------------------------------------------------------------------------- the harness itself
def test_each_outcome_is_recognised(tmp_path):
    # one target per outcome (selftest_targets); the hang target sleeps an hour against a 3 s limit
    pairs = [("tests.fuzz.selftest_targets", t) for t in selftest_targets.TARGETS]
    reports = {r.name: r for r in fuzz(pairs, cases=1, time_limit=3.0, results=tmp_path, shrink_budget=1)}
    for outcome in harness.OUTCOMES:
        assert reports[f"selftest-{outcome}"].counts[outcome] == 1, (outcome, reports[f"selftest-{outcome}"].counts)
    foreign = reports["selftest-foreign"].escapes[0]
    assert foreign["type"] == "builtins.TypeError"
    assert foreign["where"].startswith("io/formats/bin.py:")
    assert reports["selftest-abort"].escapes[0]["type"] == "SIGABRT"
    saved = sorted((tmp_path / "selftest-abort").iterdir())
    assert [p.suffix for p in saved] == [".bin", ".json"]
    assert "tests.fuzz.harness reproduce" in saved[1].read_text()
    assert set(ESCAPES) == {"foreign", "hang", "abort", "memory"}


def test_cases_are_reproducible_and_varied():
    seeds = [bytes(range(200)), b"VERSION 0.7\nWIDTH 10\nPOINTS 10\n"]
    first = [mutate(seeds, 1, "t", i) for i in range(50)]
    assert first == [mutate(seeds, 1, "t", i) for i in range(50)]  # same seed, target, index: same bytes
    assert first != [mutate(seeds, 2, "t", i) for i in range(50)]
    assert len(set(first)) > 40  # 50 cases, almost all different


def test_shrink_keeps_the_outcome():
    # the outcome needs b"X" and b"Y" in order: the smallest input holding it is b"XY"
    data = b"a" * 300 + b"X" + b"b" * 200 + b"Y" + b"c" * 100
    assert shrink(data, lambda d: b"X" in d and b"Y" in d[d.index(b"X"):], budget=500) == b"XY"


@pytest.mark.parametrize(("returncode", "stderr", "stdout", "escape"), [
    (2, "error: x.pcd: field 'COUNT': too many\n", "", None),
    (0, "", "", None),
    (1, "lidarfuzz: warning: odd\nerror: one line\n", "", None),
    (1, "", "1 problem(s):\n  error: x.laz: ...\n", None),  # info's report of an unreadable frame
    (1, "", "", "exit code 1 without a word"),
    (134, "", "", "exit code 134"),
    (-6, "", "", "exit code -6"),
    (1, "Traceback (most recent call last):\n  File ...\nValueError: x\n", "", "a traceback on stderr"),
    (2, "Usage: lidarfuzz info\n╭─ Error ─╮\n│ bad │\n", "", "an error of 3 lines, not one"),
])
def test_cli_failure_rules(returncode, stderr, stdout, escape):
    assert cli_failure(returncode, stderr, stdout) == escape


def test_a_saved_case_reproduces(tmp_path):
    case = tmp_path / "frame.pcd"
    case.write_bytes(b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1000000\nWIDTH 0\nHEIGHT 1\n"
                     b"POINTS 0\nDATA ascii\n")
    assert harness.main(["reproduce", "--target", "pcd-ascii", str(case)]) == 0  # refused: not an escape
    assert Path(case).exists()
