"""The campaign engine's overhead as a share of SUT time, and its throughput.

Usage: ``.venv/bin/python benchmarks/campaign.py [--frames N] [--repeat R] [--workers W]``

Baseline, measured in the same run: a bare loop doing the same test work with no engine —
load each frame, draw and apply each operator, run the classic pipeline on the original and
on every mutant, check the same relations — and nothing else. The campaign does that work
through the engine (work units, the executor, a store transaction per result with its
findings and counters, the output cache, progress, per-subtask AP). Engine overhead is
``(campaign time − bare-loop time) / SUT time`` on one core (inline executor), median of
``--repeat`` runs; the AP evaluation at the end of each subtask is listed apart (the bare
loop computes no AP). Throughput is frames × operators per second with the process pool
of ``--workers`` processes. BLAS/OpenMP are held to one thread per process.

Target (issue 7): overhead ≤ 5 % of SUT time.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from lidarfuzz.campaign.executor import InlineExecutor, ProcessExecutor  # noqa: E402
from lidarfuzz.campaign.runner import run_task  # noqa: E402
from lidarfuzz.campaign.spec import parse_campaign  # noqa: E402
from lidarfuzz.campaign.tasks import create_task, relations_for  # noqa: E402
from lidarfuzz.io.kitti import open_kitti  # noqa: E402
from lidarfuzz.operators.base import generator  # noqa: E402
from lidarfuzz.operators.registry import get  # noqa: E402
from lidarfuzz.oracles.relations.base import Pair  # noqa: E402
from lidarfuzz.oracles.relations.registry import from_spec  # noqa: E402
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, is_complete  # noqa: E402
from lidarfuzz.store import Store  # noqa: E402
from lidarfuzz.suts.registry import create  # noqa: E402

OPERATORS = ("gaussian_noise_addition", "uniform_point_deletion", "rotate_z", "intensity_scaling", "fog",
             "beam_missing", "object_translate")
SEVERITY = 3


def bare_loop(data: Path, frames: list[str]) -> tuple[float, float]:
    """(wall seconds, SUT seconds) of the test work without the engine."""
    dataset = open_kitti(data)
    sut = create("classic")
    operators = [get(name).at_severity(SEVERITY) for name in OPERATORS]
    relations = [[from_spec(spec) for spec in relations_for(op, "auto")] for op in operators]
    sut_time = 0.0
    start = time.perf_counter()
    for frame_id in frames:
        scene = dataset.load(frame_id)
        t = time.perf_counter()
        source_output = sut.detect(scene)
        sut_time += time.perf_counter() - t
        for index, (op, checks) in enumerate(zip(operators, relations, strict=True)):
            mutant, params = op(scene, generator(0, frame_id, index, 0))
            t = time.perf_counter()
            output = sut.detect(mutant)
            sut_time += time.perf_counter() - t
            pair = Pair(scene, mutant, source_output, output, op.relation, op.transform(params))
            for relation in checks:
                relation(pair)
    return time.perf_counter() - start, sut_time


def campaign(data: Path, frames: int, executor: object) -> tuple[float, float, dict[str, float]]:
    """(wall seconds, SUT seconds, stage seconds) of the same work as a campaign in a fresh store."""
    folder = Path(tempfile.mkdtemp(prefix="lf-bench-"))
    try:
        store = Store(folder)
        spec = parse_campaign({"dataset": str(data), "sut": "classic", "frames": frames,
                               "operators": [{"name": n, "severities": [SEVERITY]} for n in OPERATORS]})
        task_id = create_task(store, spec)
        start = time.perf_counter()
        outcome = run_task(store, task_id, executor=executor)  # type: ignore[arg-type]
        wall = time.perf_counter() - start
        stats = outcome.stats
        assert stats.cached == 0 and stats.failures == 0
        stages = {**stats.stages, "store": stats.store, "evaluate": stats.evaluate}
        store.close()
        return wall, stats.sut, stages
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--data", type=Path, default=Path("bench-out/campaign-data"))
    args = parser.parse_args()
    config = GenerationConfig(frames=args.frames, seed=0)
    if not is_complete(args.data, config):
        print(f"generating {args.frames} frames into {args.data} ...", flush=True)
        generate_dataset(args.data, config, workers=args.workers, overwrite=True)
    frames = list(open_kitti(args.data).frame_ids())
    units = len(frames) * (1 + len(OPERATORS))
    print(f"# {len(frames)} frames × (original + {len(OPERATORS)} operators at severity {SEVERITY}) = {units} units, "
          f"classic pipeline, {args.repeat} runs each\n")
    bare, inline = [], []
    for _ in range(args.repeat):
        bare.append(bare_loop(args.data, frames))
        inline.append(campaign(args.data, len(frames), InlineExecutor()))
    bare_wall = statistics.median(b[0] for b in bare)
    sut = statistics.median(c[1] for c in inline)
    camp_wall = statistics.median(c[0] for c in inline)
    stages = {k: statistics.median(c[2].get(k, 0.0) for c in inline) for k in inline[0][2]}
    evaluate = stages.get("evaluate", 0.0)
    overhead = camp_wall - evaluate - bare_wall
    print("| one core (inline executor) | seconds | per unit (ms) |")
    print("|---|---:|---:|")
    print(f"| bare loop (baseline: load, mutate, detect, relations) | {bare_wall:.2f} | "
          f"{1000 * bare_wall / units:.1f} |")
    print(f"| campaign | {camp_wall:.2f} | {1000 * camp_wall / units:.1f} |")
    print(f"| of which SUT | {sut:.2f} | {1000 * sut / units:.1f} |")
    print(f"| of which AP evaluation (not in the baseline) | {evaluate:.2f} | {1000 * evaluate / units:.1f} |")
    for stage, what in (("store", "store commits"), ("cache", "cache look-ups")):
        seconds = stages.get(stage, 0.0)
        print(f"| of which {what} | {seconds:.2f} | {1000 * seconds / units:.1f} |")
    work = sum(stages.get(k, 0.0) for k in ("load", "mutate", "detect", "relations", "evaluate"))
    own = camp_wall - work
    print(f"\nengine overhead against the bare loop: {overhead:.2f} s = {100 * overhead / sut:.1f} % of SUT time "
          f"(campaign − AP evaluation − bare loop; target ≤ 5 %)")
    print(f"engine's own time inside the campaign: {own:.2f} s = {100 * own / sut:.1f} % of SUT time "
          f"(wall − load, mutate, detect, relations, AP; store, cache and bookkeeping)")

    pool = [campaign(args.data, len(frames), ProcessExecutor(args.workers)) for _ in range(args.repeat)]
    pool_wall = statistics.median(p[0] for p in pool)
    tests = len(frames) * len(OPERATORS)
    print(f"\nthroughput: {tests / camp_wall:.1f} frames × operators per second on one core (inline), "
          f"{tests / pool_wall:.1f} with {args.workers} worker processes "
          f"({pool_wall:.2f} s, start-up included; {camp_wall / pool_wall:.2f}× inline)")


if __name__ == "__main__":
    main()
