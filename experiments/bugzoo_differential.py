"""Does the default campaign show each bug-zoo variant against the correct pipeline?

Usage: ``.venv/bin/python experiments/bugzoo_differential.py [--frames 12] [--workers 2] [--out DIR] [--suts ...]``

For each variant of the classic pipeline (``lidarfuzz suts``) and for ``classic`` itself, one
campaign of the default operator set (``operators: auto``) with ``reference: classic``, on the
built-in world (HDL-64E simulator frames, generated under ``--out`` on first use). Prints, per
system, the rows of the comparison that are significantly above the reference (one-sided Fisher
exact test, Tarone-corrected, α = 0.05): the variant is *shown* when there is at least one; the
correct pipeline should show none. The reference's outputs come from the output cache after the
first campaign.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def main() -> None:
    from lidarfuzz.campaign.compare import compare_tasks
    from lidarfuzz.campaign.executor import ProcessExecutor
    from lidarfuzz.campaign.lifecycle import get_task
    from lidarfuzz.campaign.runner import run_task
    from lidarfuzz.campaign.spec import parse_campaign
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.cli.demo import build_world
    from lidarfuzz.store.store import Store
    from lidarfuzz.suts.bugzoo import BUGS

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("bench-out/bugzoo-differential"))
    parser.add_argument("--suts", nargs="+", metavar="SUT", help="only these systems (default: every variant and "
                                                                 "classic)")
    args = parser.parse_args()

    world, _ = build_world(args.out / "world", args.frames, 0)
    store = Store(args.out / f"ws-{int(time.time())}")
    print(f"default campaign with reference classic, {args.frames} simulator frames")
    for name in args.suts or [bug.name for bug in BUGS] + ["classic"]:
        start = time.perf_counter()
        task_id = create_task(store, parse_campaign({"dataset": str(world), "sut": name, "operators": "auto",
                                                     "reference": "classic"}))
        reference = get_task(store, task_id).options.references[0]
        for task in (reference, task_id):
            run_task(store, task, executor=ProcessExecutor(args.workers))
        comparison = compare_tasks(store, task_id, reference)
        rows = [r for r in comparison.significant if r.cls == ""]
        shown = ", ".join(f"{r.label} {r.relation} {r.violated_a}/{r.checked_a} vs {r.violated_b}/{r.checked_b} "
                          f"(p {r.p_adjusted:.2g})" for r in rows[:3]) or "nothing significant"
        print(f"{name:28s} {time.perf_counter() - start:5.0f} s  {shown}", flush=True)


if __name__ == "__main__":
    main()
