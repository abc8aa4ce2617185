"""The big fuzzing run over every file a user can hand lidarfuzz (issue 23's hostile files).

Usage: ``python benchmarks/fuzz_files.py [--cases 10000] [--targets NAME ...] [--cli-cases 20]
[--seed 23] [--time-limit 10] [--results DIR] [--jobs N] [--write-doc]``

Each target (tests/fuzz/targets_points.py: frame formats; tests/fuzz/targets_files.py, when
present: every other user file) gets ``--cases`` seeded mutations of valid files made by
lidarfuzz's own writers, read through the Python API in a persistent child under a 4 GiB
address-space limit and ``--time-limit`` seconds per case; ``--cli-cases`` of them also go
through the target's command line. Prints one row per target (cases, ok, refused, foreign, hang,
abort, memory, cases/s); escapes are shrunk and saved under ``--results`` with a command that
reproduces each. ``--jobs N`` fuzzes N targets at once, each in its own process (the cases of a
target depend only on the seed and the target, so the figures are those of a run with one job).
``--write-doc`` rewrites the ``files`` section of docs/reliability.md.

The targets (issue 23): 0 foreign exceptions, 0 hangs, 0 aborts over ≥ 10,000 cases per format.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks.reliability_doc import provenance, write_section  # noqa: E402
from tests.fuzz.harness import DEFAULT_MEMORY, ESCAPES, OUTCOMES, Target, TargetReport, fuzz, table  # noqa: E402

MODULES = ("tests.fuzz.targets_points", "tests.fuzz.targets_files")


def targets(names: list[str] | None) -> list[tuple[str, Target]]:
    """``(module, target)`` pairs of every target module that imports, filtered by ``names``."""
    pairs: list[tuple[str, Target]] = []
    for module in MODULES:
        try:
            found = importlib.import_module(module).TARGETS
        except ImportError as exc:
            print(f"# {module} not loaded: {exc}", file=sys.stderr)
            continue
        pairs += [(module, t) for t in found if not names or t.name in names]
    unknown = set(names or ()) - {t.name for _, t in pairs}
    if unknown:
        raise SystemExit(f"unknown target(s): {', '.join(sorted(unknown))}")
    return pairs


def _one_line(text: object, limit: int) -> str:
    return " ⏎ ".join(line.strip() for line in str(text).splitlines() if line.strip())[:limit]


def summary(reports: list[TargetReport], args: argparse.Namespace) -> str:
    """The section's Markdown: what was tried, the table, the escapes found."""
    cases = sum(r.cases for r in reports)
    escaped = sum(r.escaped for r in reports)
    cli = sum(r.cli_cases for r in reports)
    cli_escapes = sum(len(r.cli_escapes) for r in reports)
    lines = [
        f"{cases:,} mutated files over {len(reports)} targets ({args.cases:,} per target; seed {args.seed}), "
        f"read through the Python API in a child limited to {DEFAULT_MEMORY >> 30} GiB of address space and "
        f"{args.time_limit:g} s per case; {cli:,} of them also through the command line. Mutations of valid "
        "files written by lidarfuzz's own writers: byte flips, truncations, insertions, deletions, splices "
        "between seeds, extreme integers (0, −1, 2³¹, 2³²−1, 2⁶³, 10¹²) over binary header fields and over "
        "the numbers of text (with 1e308, nan, inf, 400-digit numbers), very long lines, deep nesting.",
        "",
        f"**{escaped:,} escapes** (foreign exception, hang, abort, memory) through the API; "
        f"**{cli_escapes:,}** through the command line (exit ≥ 128, a traceback, or an error that is not one line).",
        "",
        table(reports),
    ]
    found = [(r.name, e) for r in reports for e in r.escapes]
    if found:
        lines += ["", "Escapes (shrunk cases saved by the run):", ""]
        lines += [f"- {name} case {e['index']}: {e['outcome']} {e.get('type', '')} at {e.get('where', '?')}: "
                  f"{_one_line(e.get('message', ''), 160)}" for name, e in found[:40]]
    found_cli = [(r.name, e) for r in reports for e in r.cli_escapes]
    if found_cli:
        lines += ["", "Command-line escapes:", ""]
        lines += [f"- {name} case {e['index']}: {_one_line(e.get('message', ''), 200)}" for name, e in found_cli[:20]]
    return "\n".join(lines)


def _fuzz_one(module: str, name: str, args: argparse.Namespace) -> TargetReport:
    """One target's run in a process of ``--jobs`` (targets hold functions, so they travel by name)."""
    target = next(t for t in importlib.import_module(module).TARGETS if t.name == name)
    return fuzz([(module, target)], cases=args.cases, seed=args.seed, time_limit=args.time_limit,
                results=args.results, cli_cases=args.cli_cases)[0]


def run_all(pairs: list[tuple[str, Target]], args: argparse.Namespace,
            progress: Callable[[TargetReport], None]) -> list[TargetReport]:
    """Every target's report, in the targets' order, ``args.jobs`` targets at a time."""
    if args.jobs <= 1:
        return fuzz(pairs, cases=args.cases, seed=args.seed, time_limit=args.time_limit,
                    results=args.results, cli_cases=args.cli_cases, progress=progress)
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(_fuzz_one, module, target.name, args) for module, target in pairs]
        reports = []
        for future in futures:
            reports.append(future.result())
            progress(reports[-1])
    return reports


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=10_000)
    parser.add_argument("--targets", nargs="*", help="target names (default: all)")
    parser.add_argument("--cli-cases", type=int, default=20)
    parser.add_argument("--seed", type=int, default=23)
    parser.add_argument("--time-limit", type=float, default=10.0)
    parser.add_argument("--results", type=Path, default=Path("fuzz-results"))
    parser.add_argument("--jobs", type=int, default=1, help="targets fuzzed at once (default 1)")
    parser.add_argument("--write-doc", action="store_true")
    args = parser.parse_args()
    command = "python benchmarks/fuzz_files.py " + " ".join(sys.argv[1:])
    started = time.monotonic()
    header = "| target | cases | " + " | ".join(OUTCOMES) + " | cases/s | CLI cases | CLI escapes |"
    print(header, flush=True)

    def progress(report: TargetReport) -> None:
        print(table([report]).splitlines()[-1], flush=True)
        for escape in report.escapes[:5]:
            print(f"#   {escape['outcome']} {escape.get('type', '')} {escape.get('where', '')}: "
                  f"{str(escape.get('message', ''))[:150]} -> {escape.get('saved', '')}", flush=True)

    reports = run_all(targets(args.targets), args, progress)
    print(f"\n{table(reports)}\n\n{time.monotonic() - started:.0f} s in all")
    if args.write_doc:
        write_section("files", provenance(command) + "\n\n" + summary(reports, args))
        print("docs/reliability.md: files section rewritten")
    return 1 if any(r.counts[o] for r in reports for o in ESCAPES) else 0


if __name__ == "__main__":
    sys.exit(main())
