"""Neves, Delamaro & Masiero's Tables I–IV, by one command: field-test logs, heuristic base logs,
and the aggregated coverage of the AVG and HGT logs generated from them.

The paper replayed five field-test logs of its vehicle through its obstacle-avoidance program and
measured all-nodes and all-edges of the program's two main methods, ``process()`` and
``calculate()``. Here::

    .venv/bin/python experiments/neves_tables.py                      # 5 drive logs of 400 frames
    .venv/bin/python experiments/neves_tables.py --logs 2 --frames 100 --out /tmp/neves.md

1. the logs: ``--logs`` drive logs of the built-in simulator (``lidarfuzz gen --sequence --drive``:
   the ego vehicle stops, turns at a junction and drives on, with road users timed against it),
   seeds 0, 1, …, made under ``bench-out/neves/`` on first use; or ``--log PATH`` (repeatable) for
   your own (bags, MCAP, KITTI folders with timestamps);
2. the system: the built-in controller (``--sut``), its code under test the two methods playing the
   paper's ``process()`` and ``calculate()`` (``--target``);
3. per log: the field-test log (FT) replayed in order under coverage.py; its segments of ``--size``
   frames; each ``--heuristics`` entry's selection, written as a base log and replayed *on its own*
   (the system's state runs through the base log alone, as in the paper); and from each base, the
   ``--strategies`` logs (HGT: every frame raised by the paper's constant 10, inserted after its
   source; AVG: the average of two consecutive frames inserted between them), replayed too. A
   strategy column is the paper's aggregated coverage of the base and the generated log (the
   union of what either covered), so it is never below the base;
4. the tables, per method and criterion, rows per log and their average, and one of base-log sizes,
   go to ``--out`` (a markdown page).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = ROOT / "docs" / "experiments" / "neves_tables.md"
WORK = ROOT / "bench-out" / "neves"
#: The controller's methods in the roles of the paper's cObstacleAvoidance.process() and cVFH.calculate().
TARGETS = ("lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process",
           "lidarfuzz.suts.controller.vfh:VFH.calculate")
CRITERIA = (("node", "all-nodes"), ("edge", "all-edges"))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--logs", type=int, default=5, help="simulator drive logs to make (default 5)")
    parser.add_argument("--frames", type=int, default=400, help="frames per simulator log (default 400: 40 s)")
    parser.add_argument("--log", type=Path, action="append", default=[], metavar="PATH",
                        help="a log of your own instead of the simulator's (repeatable)")
    parser.add_argument("--sut", default="controller", help="a sequence system (lidarfuzz suts)")
    parser.add_argument("--target", action="append", default=None, metavar="CODE",
                        help="code under test, e.g. pkg.mod:Class.method (repeatable; default: the "
                             "controller's process() and VFH.calculate())")
    parser.add_argument("--size", type=int, default=5, help="frames per segment (default 5, the paper's)")
    parser.add_argument("--heuristics", nargs="+", default=["greedy_edges", "decision_change"],
                        help="heuristics building base logs (default: greedy_edges decision_change)")
    parser.add_argument("--strategies", nargs="+", default=["AVG", "HGT"], help="generation strategies")
    parser.add_argument("--seed", type=int, default=0, help="seeds the mutants (default 0)")
    parser.add_argument("--workers", type=int, default=2, help="processes making the simulator logs")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="the markdown page to write")
    return parser.parse_args(argv)


@dataclass(frozen=True)
class LogResult:
    """One log's row: the coverage of each column, and the base logs' sizes."""

    name: str
    frames: int
    segments: int
    covered: dict[str, frozenset]  # column -> requirements covered
    base_size: dict[str, tuple[int, int]]  # heuristic -> (segments, frames)
    seconds: float


def make_logs(args: argparse.Namespace) -> list[Path]:
    """The user's logs, or the simulator's drive logs (made once, kept under ``bench-out/neves``)."""
    if args.log:
        return list(args.log)
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset

    paths = []
    for seed in range(args.logs):
        path = WORK / f"drive-{seed}-{args.frames}"
        if not (path / "timestamps.txt").exists():
            start = time.perf_counter()
            generate_dataset(path, GenerationConfig(frames=args.frames, seed=seed, drive=True), workers=args.workers,
                             overwrite=True)
            print(f"made {path.name} in {time.perf_counter() - start:.0f} s", flush=True)
        paths.append(path)
    return paths


def run_log(path: Path, args: argparse.Namespace, targets: list[str]) -> LogResult:
    from lidarfuzz.structural.generate import generate_frames, strategy
    from lidarfuzz.structural.heuristics import select
    from lidarfuzz.structural.log_coverage import decision_signature, frame_coverage
    from lidarfuzz.structural.logs import open_log
    from lidarfuzz.structural.python_coverage import CoverageRecorder
    from lidarfuzz.structural.requirements import union
    from lidarfuzz.structural.segments import partition, segment_coverage
    from lidarfuzz.suts.registry import create_sequence

    start = time.perf_counter()
    log = open_log(path)
    recorder = CoverageRecorder(targets)
    covered: dict[str, frozenset] = {}
    sizes: dict[str, tuple[int, int]] = {}
    with create_sequence(args.sut) as system:
        def replay(frames: object) -> list[frozenset]:
            return frame_coverage(frames, system.step, recorder, reset=system.reset).covered  # type: ignore[arg-type]

        ft = frame_coverage(log, system.step, recorder, reset=system.reset)
        covered["FT"] = union(*ft.covered)
        segments = partition(log.frame_ids, args.size)
        per_segment = segment_coverage(segments, ft.covered)
        signatures = [decision_signature(o) for o in ft.outputs]
        for heuristic in args.heuristics:
            chosen = select(heuristic, segments, per_segment, signatures=signatures, seed=args.seed)
            picked = [segments[i] for i in chosen.log_order()]
            sizes[heuristic] = (len(picked), sum(len(s) for s in picked))
            positions = [p for s in picked for p in s.positions]
            base = union(*replay(list(log.frames(positions))))
            covered[f"{heuristic}-Base"] = base
            for name in args.strategies:
                frames = [scene for scene, _ in generate_frames(log, picked, strategy(name), seed=args.seed)]
                covered[f"{heuristic}-Agg-{name}"] = base | union(*replay(frames))
    return LogResult(path.name, len(log), len(segments), covered, sizes, time.perf_counter() - start)


def percent(value: float) -> str:
    return f"{100 * value:.0f} %"


def tables(results: list[LogResult], targets: list[str], columns: list[str]) -> list[str]:
    """One markdown table per target function and criterion (the paper's Tables I–IV form)."""
    from lidarfuzz.structural.python_coverage import requirements_of
    from lidarfuzz.structural.requirements import coverage_ratio, of_kind

    total = requirements_of(targets)
    functions = sorted({r.function for r in total})
    lines: list[str] = []
    number = 0
    for function in functions:
        for kind, criterion in CRITERIA:
            number += 1
            count = len(of_kind(total, kind, function))
            lines += [f"**Table {number}.** `{function.split(':')[-1]}`, {criterion} ({count} requirements)", "",
                      "| log | " + " | ".join(columns) + " |", "|---|" + "---:|" * len(columns)]
            sums = [0.0] * len(columns)
            for result in results:
                values = [coverage_ratio(result.covered[c], total, kind, function) for c in columns]
                sums = [a + b for a, b in zip(sums, values, strict=True)]
                lines.append(f"| {result.name} | " + " | ".join(percent(v) for v in values) + " |")
            lines.append("| **average** | " + " | ".join(f"**{percent(v / len(results))}**" for v in sums) + " |")
            lines.append("")
    return lines


def write_page(results: list[LogResult], args: argparse.Namespace, targets: list[str], seconds: float) -> None:
    columns = ["FT"] + [f"{h}-{kind}" for h in args.heuristics for kind in ["Base"] + [f"Agg-{s}" for s in
                                                                                    args.strategies]]
    command = " ".join(["python experiments/neves_tables.py", *sys.argv[1:]]).strip()
    lines = ["# Neves et al.'s Tables I–IV on the built-in controller", "",
             f"`{command}` — {len(results)} logs, {seconds:.0f} s. Columns as in the paper: the field-test log "
             "(FT), each heuristic's base log replayed on its own (Base), and the aggregated coverage of the base "
             "and each strategy's generated log (Agg-AVG, Agg-HGT: the union of what either covered).", "",
             *tables(results, targets, columns),
             "**Base-log sizes** (segments of the log / frames):", "",
             "| log | frames | segments | " + " | ".join(args.heuristics) + " |",
             "|---|---:|---:|" + "---:|" * len(args.heuristics)]
    for r in results:
        lines.append(f"| {r.name} | {r.frames} | {r.segments} | "
                     + " | ".join(f"{r.base_size[h][0]} / {r.base_size[h][1]}" for h in args.heuristics) + " |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    marker = "<!-- discussion -->"
    kept = ""
    if args.out.exists() and marker in args.out.read_text(encoding="utf-8"):
        kept = args.out.read_text(encoding="utf-8").split(marker, 1)[1]
    args.out.write_text("\n".join(lines) + "\n\n" + marker + kept, encoding="utf-8")
    print(f"wrote {args.out}")


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    targets = list(args.target or TARGETS)
    start = time.perf_counter()
    results = []
    for path in make_logs(args):
        result = run_log(path, args, targets)
        print(f"{result.name}: {result.frames} frames, {result.seconds:.0f} s", flush=True)
        results.append(result)
    write_page(results, args, targets, time.perf_counter() - start)


if __name__ == "__main__":
    main()
