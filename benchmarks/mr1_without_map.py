"""MR1 (``preservation``) violation rates of the correct ``classic`` pipeline under ``outside_roi_scatter``
on frames without a map, at n = 10, 100 and 1000 scattered points.

Usage: ``.venv/bin/python benchmarks/mr1_without_map.py [--frames 12] [--trials 3] [--real DIR] [--real-trials 10]``

Frames: simulator frames (HDL-64E, rendered here) with their map removed and their intensities mapped
by rank onto the distribution of real KITTI scans (9 % read 0:
:func:`lidarfuzz.sim.realism.real_intensities`, as ``tests/operators/test_roi_estimate.py`` does),
and — when ``--real`` names a KITTI folder (by default ``../shared/realdata/kitti`` when present) —
those real frames as they are. Configurations:

* ``boxes``: the region before the estimate (outside the labelled boxes grown by 1 m);
* ``estimated, no map for the SUT``: the points avoid the estimated region, the pipeline has no map;
* ``estimated, the SUT's map too``: the frames carry the estimate as their map
  (:func:`lidarfuzz.scene.drivable.with_estimated_roi`), as a data set loaded with it would;
* ``frame_map`` (simulator only): the frames keep the simulator's own map.

A violated mutant is one where an object the pipeline found in the original is not matched in the
mutant (the relation's defaults); the count form is Zhou & Sun's |O| > |O'|.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

from lidarfuzz.operators import generator
from lidarfuzz.operators.lidar.points import OutsideRoiScatter
from lidarfuzz.oracles.relations.base import Pair
from lidarfuzz.oracles.relations.detection import Preservation
from lidarfuzz.scene.drivable import with_estimated_roi
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim.realism import real_intensities
from lidarfuzz.suts.classic.pipeline import ClassicPipeline

COUNTS = (10, 100, 1000)
REAL_DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "realdata" / "kitti"


def rates(frames: list[Scene], region: str, trials: int) -> dict[int, tuple[int, int, int]]:
    """Per n: (violated, count form violated, checked)."""
    sut, relation = ClassicPipeline(), Preservation()
    out = {}
    originals = [sut.detect(scene) for scene in frames]
    for n in COUNTS:
        op = OutsideRoiScatter(count_range=(n, n), region=region)  # type: ignore[arg-type]
        violated = count_form = checked = 0
        for scene, before in zip(frames, originals, strict=True):
            for trial in range(trials):
                mutant, _ = op(scene, generator(0, scene.frame_id, n, trial))
                outcome = relation.check(Pair(scene, mutant, before, sut.detect(mutant)))
                violated += not outcome.holds
                count_form += not outcome.stats["count_holds"]
                checked += 1
        out[n] = (violated, count_form, checked)
    return out


def table(name: str, configurations: list[tuple[str, Callable[[], list[Scene]], str]], trials: int) -> None:
    print(f"\n### {name}\n")
    print("| configuration | " + " | ".join(f"n = {n}" for n in COUNTS) + " |")
    print("|---|" + "---:|" * len(COUNTS))
    for label, frames, region in configurations:
        start = time.perf_counter()
        figures = rates(frames(), region, trials)
        cells = [f"{100 * v / c:.1f} % ({v}/{c}; count form {f})" for v, f, c in (figures[n] for n in COUNTS)]
        print(f"| {label} | " + " | ".join(cells) + f" |  <!-- {time.perf_counter() - start:.0f} s -->", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--real", type=Path, default=REAL_DEFAULT if REAL_DEFAULT.is_dir() else None)
    parser.add_argument("--real-trials", type=int, default=10)
    args = parser.parse_args()
    from lidarfuzz.sim import GenerationConfig, render_frames

    simulated = list(render_frames(GenerationConfig(frames=args.frames, seed=args.seed)))
    unmapped = [real_intensities(s.replace(roi=None, metadata={})) for s in simulated]
    print(f"# MR1 of the classic pipeline under outside_roi_scatter, frames without a map "
          f"({args.frames} simulator frames x {args.trials} trials)")
    table("simulator frames, map removed, real intensity statistics", [
        ("boxes (before the estimate)", lambda: unmapped, "boxes"),
        ("estimated, no map for the SUT", lambda: unmapped, "auto"),
        ("estimated, the SUT's map too", lambda: [with_estimated_roi(s) for s in unmapped], "auto"),
        ("frame_map (the simulator's own map)", lambda: [real_intensities(s) for s in simulated], "auto"),
    ], args.trials)
    if args.real is None:
        print("\n(no real frames: pass --real DIR, a KITTI folder)")
        return
    from lidarfuzz.io.open import open_dataset

    dataset = open_dataset(args.real)
    real = [dataset.load(frame_id) for frame_id in dataset.frame_ids()]
    table(f"real frames ({args.real}, {len(real)} frames x {args.real_trials} trials)", [
        ("boxes (before the estimate)", lambda: real, "boxes"),
        ("estimated, no map for the SUT", lambda: real, "auto"),
        ("estimated, the SUT's map too", lambda: [with_estimated_roi(s) for s in real], "auto"),
    ], args.real_trials)


if __name__ == "__main__":
    main()
