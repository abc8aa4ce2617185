"""The campaign engine's overhead as a share of SUT time, and its throughput.

Usage: ``.venv/bin/python benchmarks/campaign.py [--frames N] [--repeat R] [--workers W]``

Baseline, measured in the same run: a bare loop doing the same test work with no engine —
load each frame, draw and apply each operator, run the classic pipeline on the original and
on every mutant, check the same relations — and nothing else. The campaign does that work
through the engine (work units, the executor, a store transaction per result with its
findings, the progress counters, the output cache, per-subtask AP). Engine overhead is
``(campaign − AP evaluation − bare loop) / SUT time`` on one core (inline executor), in CPU
time (this process's, every thread) and in wall time, each run's bare loop and campaign
back to back, median and range of ``--repeat`` runs; the AP evaluation at the end of each
subtask is left out (the bare loop computes no AP). The campaign's CPU time is taken around
``run_task`` alone: creating the store and the task is not part of a run. Throughput is
frames × operators per second with the process pool of ``--workers`` processes. BLAS/OpenMP
are held to one thread per process, set before numpy loads; the load average is printed.

Targets: overhead ≤ 5 % of SUT time (issue 7), ≤ 2 % (issue 25).
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


def load() -> str:
    return ", ".join(f"{v:.2f}" for v in os.getloadavg())


OPERATORS = ("gaussian_noise_addition", "uniform_point_deletion", "rotate_z", "intensity_scaling", "fog",
             "beam_missing", "object_translate")
SEVERITY = 3


def bare_loop(data: Path, frames: list[str]) -> tuple[float, float, float]:
    """(wall seconds, CPU seconds, SUT seconds) of the test work without the engine."""
    dataset = open_kitti(data)
    sut = create("classic")
    operators = [get(name).at_severity(SEVERITY) for name in OPERATORS]
    relations = [[from_spec(spec) for spec in relations_for(op, "auto")] for op in operators]
    sut_time = 0.0
    start, cpu = time.perf_counter(), time.process_time()
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
    return time.perf_counter() - start, time.process_time() - cpu, sut_time


def campaign(data: Path, frames: int, executor: object) -> tuple[float, float, float, dict[str, float]]:
    """(wall seconds, CPU seconds, SUT seconds, stage seconds) of the same work as a campaign in a
    fresh store (the times are ``run_task``'s)."""
    folder = Path(tempfile.mkdtemp(prefix="lf-bench-"))
    try:
        store = Store(folder)
        spec = parse_campaign({"dataset": str(data), "sut": "classic", "frames": frames,
                               "operators": [{"name": n, "severities": [SEVERITY]} for n in OPERATORS]})
        task_id = create_task(store, spec)
        start, cpu = time.perf_counter(), time.process_time()
        outcome = run_task(store, task_id, executor=executor)  # type: ignore[arg-type]
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
        stats = outcome.stats
        assert stats.cached == 0 and stats.failures == 0
        stages = {**stats.stages, "store": stats.store, "evaluate": stats.evaluate}
        store.close()
        return wall, cpu, stats.sut, stages
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
    print(f"load average before: {load()}\n")
    campaign(args.data, len(frames), InlineExecutor())  # imports and first-use costs, not timed
    bare, inline = [], []
    for _ in range(args.repeat):
        bare.append(bare_loop(args.data, frames))
        inline.append(campaign(args.data, len(frames), InlineExecutor()))
    med = statistics.median
    sut = med(c[2] for c in inline)
    stages = {k: med(c[3].get(k, 0.0) for c in inline) for k in inline[0][3]}
    evaluate = stages.get("evaluate", 0.0)
    print("| one core (inline executor), median of runs | wall (s) | CPU (s) | CPU per unit (ms) |")
    print("|---|---:|---:|---:|")
    print(f"| bare loop (baseline: load, mutate, detect, relations) | {med(b[0] for b in bare):.2f} | "
          f"{med(b[1] for b in bare):.2f} | {1000 * med(b[1] for b in bare) / units:.1f} |")
    print(f"| campaign (`run_task`) | {med(c[0] for c in inline):.2f} | {med(c[1] for c in inline):.2f} | "
          f"{1000 * med(c[1] for c in inline) / units:.1f} |")
    print(f"| of which SUT | {sut:.2f} | | {1000 * sut / units:.1f} |")
    print(f"| of which AP evaluation (not in the baseline) | {evaluate:.2f} | | {1000 * evaluate / units:.1f} |")
    for stage, what in (("store", "store commits"), ("cache", "input digests and cache look-ups")):
        seconds = stages.get(stage, 0.0)
        print(f"| of which {what} | {seconds:.3f} | | {1000 * seconds / units:.2f} |")
    for column, what in ((1, "CPU"), (0, "wall")):
        shares = sorted(100 * (c[column] - c[3].get("evaluate", 0.0) - b[column]) / c[2]
                        for b, c in zip(bare, inline, strict=True))
        print(f"\nengine overhead against the bare loop, {what} time: **{med(shares):.1f} %** of SUT time "
              f"(runs: {', '.join(f'{x:.1f}' for x in shares)}; campaign − AP evaluation − bare loop; "
              f"targets ≤ 5 %, ≤ 2 %)", end="")
    per_unit = med(1000 * (c[1] - c[3].get("evaluate", 0.0) - b[1]) / units for b, c in zip(bare, inline, strict=True))
    print(f"\nengine CPU per unit: {per_unit:.2f} ms (the same median in absolute terms: the share it is of a "
          f"system's time falls as the system gets slower; this one took {1000 * sut / units:.1f} ms a unit)", end="")
    work = sum(stages.get(k, 0.0) for k in ("load", "mutate", "detect", "relations", "evaluate"))
    own = med(c[0] for c in inline) - work
    print(f"\nengine's own time inside the campaign: {own:.2f} s = {100 * own / sut:.1f} % of SUT time "
          f"(wall − load, mutate, detect, relations, AP; store, cache and bookkeeping)")
    print(f"load average after: {load()}")

    pool = [campaign(args.data, len(frames), ProcessExecutor(args.workers)) for _ in range(args.repeat)]
    pool_wall = statistics.median(p[0] for p in pool)
    camp_wall = med(c[0] for c in inline)
    tests = len(frames) * len(OPERATORS)
    print(f"\nthroughput: {tests / camp_wall:.1f} frames × operators per second on one core (inline), "
          f"{tests / pool_wall:.1f} with {args.workers} worker processes "
          f"({pool_wall:.2f} s, start-up included; {camp_wall / pool_wall:.2f}× inline)")


if __name__ == "__main__":
    main()
