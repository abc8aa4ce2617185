"""Hostile systems under test through real campaigns: what lidarfuzz records, and what it survives.

Each kind of ``tests/suts/hostile_worker.py`` (a detector misbehaving on frame ``000001``, correct
elsewhere: one Car at ``x = 10 + frame number``) runs as ``worker:`` — or, for the rows marked
one-shot, ``subprocess:`` — through a small campaign: 3 frames × (original, ``rotate_z``) = 6
results, under ``memory_limit=256MiB`` and a 2 s timeout. Each campaign runs in a fresh Python
process, whose peak RSS is lidarfuzz's memory; after it exits, ``/proc`` is searched for any
process of the hostile program (an orphan). A result whose box is not its own frame's is
*shifted* (the escape of issue 23: a stray stdout line put the previous frame's answer on 8 of
12 results).

    python benchmarks/hostile_systems.py              # print the table
    python benchmarks/hostile_systems.py --write-doc  # and rewrite docs/reliability.md's `systems`
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
HOSTILE = ROOT / "tests" / "suts" / "hostile_worker.py"
BAD = "000001"
LIMITS = {"memory_limit": "256MiB", "timeout": 2, "name": "hostile"}

# (row name, kind, one-shot?, extra options)
ROWS: list[tuple[str, str, bool, dict[str, Any]]] = [
    ("correct (baseline)", "none", False, {}),
    ("crash", "crash", False, {}),
    ("segfault", "segfault", False, {}),
    ("abort", "abort", False, {}),
    ("exit 0 early", "exit0", False, {}),
    ("hang", "hang", False, {}),
    ("slow (3 s)", "slow", False, {}),
    ("leak", "leak", False, {}),
    ("fork, child lingers", "fork-linger", False, {}),
    ("fork, child holds the pipes, parent dies", "fork-holds-pipe", False, {}),
    ("stray stdout line", "stray", False, {}),
    ("garbage", "garbage", False, {}),
    ("huge line (64 MiB)", "huge", False, {}),
    ("100,000 boxes", "boxes100k", False, {}),
    ("100,000 boxes, max_answer_bytes=16MiB", "boxes100k", False, {"max_answer_bytes": "16MiB"}),
    ("NaN box", "nan", False, {}),
    ("infinite box", "inf", False, {}),
    ("negative size", "negative", False, {}),
    ("wrong id", "wrong-id", False, {}),
    ("no id (protocol before ids)", "no-id", False, {}),
    ("no newline", "no-newline", False, {}),
    ("one-shot: fork, child holds stderr", "fork-holds-pipe", True, {}),
    ("one-shot: fork, child lingers", "fork-linger", True, {}),
    ("one-shot: hang", "hang", True, {}),
    ("one-shot: leak", "leak", True, {}),
]


def make_data(folder: Path) -> Path:
    """Three frames of 200 random points (the hostile program never reads them)."""
    import numpy as np

    (folder / "velodyne").mkdir(parents=True)
    for i in range(3):
        np.random.default_rng(i).normal(size=(200, 4)).astype(np.float32).tofile(folder / "velodyne" / f"{i:06d}.bin")
    return folder


def one(kind: str, oneshot: bool, options: dict[str, Any], data: Path, workspace: Path) -> dict[str, Any]:
    """Run one campaign in this process; its figures."""
    from sqlalchemy import select

    from lidarfuzz.campaign.executor import InlineExecutor
    from lidarfuzz.campaign.runner import run_task
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.store import Finding, FrameResult, Store
    from lidarfuzz.store.boxes import StoredBoxes

    program = f"{sys.executable} {HOSTILE} {kind} --on {BAD}"
    sut = f"subprocess:{program} --oneshot {{points}} {{output}} {{frame_id}}" if oneshot else f"worker:{program}"
    store = Store(workspace)
    spec = parse_campaign({"dataset": str(data), "sut": sut, "operators": [{"name": "rotate_z", "severities": [3]}]})
    start = time.perf_counter()
    task_id = create_task(store, spec, sut_options={**LIMITS, **options})
    outcome = run_task(store, task_id, executor=InlineExecutor())
    seconds = time.perf_counter() - start
    failures: dict[str, int] = {}
    messages: list[str] = []
    shifted = wrong_frame_failures = 0
    with store.session() as s:
        rows = s.execute(select(FrameResult.frame_id, FrameResult.boxes, FrameResult.labels,
                                FrameResult.failure)).all()
        findings = s.scalars(select(Finding.kind)).all()
    for frame_id, boxes, labels, failure in rows:
        if failure is not None:
            failures[failure.kind] = failures.get(failure.kind, 0) + 1
            messages.append(failure.message)
            wrong_frame_failures += frame_id != BAD
        elif StoredBoxes(boxes, labels).boxes().centers[0][0] != 10 + int(frame_id):
            shifted += 1
    store.close()
    system_findings = sum(1 for k in findings if k in ("crash", "timeout", "invalid_output"))
    return {"status": str(outcome.status), "results": len(rows), "failures": failures, "shifted": shifted,
            "other_frames_failed": wrong_frame_failures, "findings": system_findings,
            "message": messages[0] if messages else "", "seconds": seconds,
            "peak_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}


def orphans(kind: str) -> int:
    """Live processes of the hostile program of ``kind`` (none should outlive its campaign)."""
    count = 0
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode("utf-8", "replace")
            state = (entry / "stat").read_text().rpartition(")")[2].split()[0]
        except OSError:
            continue
        if f"{HOSTILE.name} {kind} " in cmdline and state != "Z":
            count += 1
    return count


def run_row(kind: str, oneshot: bool, options: dict[str, Any], data: Path, workspace: Path) -> dict[str, Any]:
    command = [sys.executable, __file__, "--one", kind, "--data", str(data), "--workspace", str(workspace),
               "--options", json.dumps(options)] + (["--oneshot"] if oneshot else [])
    done = subprocess.run(command, capture_output=True, text=True, timeout=600, check=False)
    if done.returncode != 0:
        return {"error": f"exit {done.returncode}: {done.stderr[-500:]}"}
    figures: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    time.sleep(0.2)  # killed processes finish dying
    figures["orphans"] = orphans(kind)
    return figures


def recorded(figures: dict[str, Any]) -> str:
    if "error" in figures:
        return f"lidarfuzz failed: {figures['error']}"
    if not figures["failures"]:
        return "nothing (correct answers)"
    kinds = ", ".join(f"{n} `{k}`" for k, n in sorted(figures["failures"].items()))
    message = figures["message"].replace("|", "\\|")
    message = message if len(message) <= 110 else message[:107] + "…"
    return f"{kinds}: {message}"


def table(rows: list[tuple[str, str, bool, dict[str, Any], dict[str, Any]]]) -> str:
    from tests.suts.hostile_worker import KINDS

    lines = ["| system | what it does on frame 000001 | what lidarfuzz recorded | frames affected | other frames "
             "failed / shifted | lidarfuzz peak RSS | orphans left |",
             "|---|---|---|---:|---:|---:|---:|"]
    for name, kind, _, _, figures in rows:
        if "error" in figures:
            lines.append(f"| {name} | {KINDS[kind]} | {recorded(figures)} | – | – | – | – |")
            continue
        affected = sum(figures["failures"].values())
        lines.append(f"| {name} | {KINDS[kind]} | {recorded(figures)} | {affected} of {figures['results']} | "
                     f"{figures['other_frames_failed']} / {figures['shifted']} | "
                     f"{figures['peak_rss'] / 2**20:.0f} MiB | {figures['orphans']} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write-doc", action="store_true", help="rewrite docs/reliability.md's systems section")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    parser.add_argument("--data", help=argparse.SUPPRESS)
    parser.add_argument("--workspace", help=argparse.SUPPRESS)
    parser.add_argument("--options", default="{}", help=argparse.SUPPRESS)
    parser.add_argument("--oneshot", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        figures = one(args.one, args.oneshot, json.loads(args.options), Path(args.data), Path(args.workspace))
        print(json.dumps(figures))
        return 0
    sys.path.insert(0, str(ROOT))
    results = []
    with tempfile.TemporaryDirectory(prefix="lidarfuzz-hostile-") as tmp:
        data = make_data(Path(tmp) / "data")
        for i, (name, kind, oneshot, options) in enumerate(ROWS):
            figures = run_row(kind, oneshot, options, data, Path(tmp) / f"ws{i}")
            results.append((name, kind, oneshot, options, figures))
            print(f"{name:45s} {recorded(figures)[:90]}  orphans={figures.get('orphans')}  "
                  f"rss={figures.get('peak_rss', 0) / 2**20:.0f} MiB  {figures.get('seconds', 0):.1f} s", flush=True)
    markdown = table(results)
    bad = [r for r in results if "error" in r[4] or r[4]["orphans"] or r[4]["shifted"] or r[4]["other_frames_failed"]]
    peak = max(r[4].get("peak_rss", 0) for r in results)
    summary = (f"{len(results)} hostile systems ({len({r[1] for r in results}) - 1} kinds of misbehaviour, worker "
               f"and one-shot), each through a campaign of 6 results with frame 000001 misbehaving, "
               f"`memory_limit=256MiB`, a 2 s timeout: {len(results) - len(bad)} of {len(results)} with no "
               f"result shifted onto another frame, no other frame failed and no orphan process; lidarfuzz's "
               f"peak RSS at most {peak / 2**20:.0f} MiB.")
    print()
    print(summary)
    print(markdown)
    if args.write_doc:
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from reliability_doc import provenance, write_section

        command = "python benchmarks/hostile_systems.py --write-doc"
        write_section("systems", "\n\n".join([provenance(command), summary, markdown,
                                               "CI runs the same systems through the SUT guard, plus one campaign "
                                               "(`tests/suts/test_hostile_systems.py`)."]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
