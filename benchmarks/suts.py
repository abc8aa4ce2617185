"""Systems under test on the simulator's val split: KITTI AP and time per frame (one core).

Usage: ``.venv/bin/python benchmarks/suts.py [--frames N] [--seed S] [--data DIR] [--sut SPEC ...]``

Generates (once; later runs reuse it) a simulator data set of ``--frames`` HDL-64E frames
(about 120k points each) in KITTI layout, runs each SUT on the val split (the last half),
keeps detections in the camera's field of view (as OpenPCDet does before evaluation, since
KITTI labels only exist there), and prints KITTI AP (Car, Pedestrian, Cyclist; BEV and 3D;
moderate; R40 and R11) and the median and 90th-percentile time per frame. For the classic
pipeline the time of each stage is printed too, as shares of the whole: the baseline every
stage is measured against in the same run. BLAS and OpenMP are held to one thread; the
learned ``pillars`` detector uses PyTorch's own pool of ``threads`` (default 2).

Targets: (issue 6) classic Car BEV AP|R40 @0.7 moderate ≥ 60; ≤ 50 ms per frame on one core.
(issue 8) ``pillars`` beats classic's 3D AP|R40 moderate on every class; ≤ 150 ms per
120k-point frame on 2 cores. Run both: ``--sut classic --sut pillars``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from lidarfuzz.io.kitti import open_kitti  # noqa: E402
from lidarfuzz.oracles.kitti_eval import KittiFrame, evaluate_kitti  # noqa: E402
from lidarfuzz.scene.boxes import Boxes3D  # noqa: E402
from lidarfuzz.scene.scene import Scene  # noqa: E402
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset, is_complete  # noqa: E402
from lidarfuzz.suts.registry import create  # noqa: E402

CLASSES = ("Car", "Pedestrian", "Cyclist")


def in_camera_view(dets: Boxes3D, scene: Scene) -> Boxes3D:
    if len(dets) == 0 or scene.calib is None:
        return dets
    return dets.select(scene.calib.in_view(dets.centers))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data", type=Path, default=Path("bench-out/classic-data"))
    parser.add_argument("--sut", action="append", default=None, help="SUT spec (repeatable; default: classic)")
    args = parser.parse_args()
    config = GenerationConfig(frames=args.frames, seed=args.seed, val_fraction=0.5)
    if not is_complete(args.data, config):
        print(f"generating {args.frames} frames into {args.data} ...", flush=True)
        generate_dataset(args.data, config, workers=2, overwrite=True)
    dataset = open_kitti(args.data)
    val = (args.data / "ImageSets" / "val.txt").read_text().split()
    scenes = [dataset.load(frame_id) for frame_id in val]
    points = statistics.median(len(s.points) for s in scenes)
    print(f"# {len(scenes)} val frames of {args.data} (seed {args.seed}), median {points:,.0f} points per frame")
    for spec in args.sut or ["classic"]:
        sut = create(spec)
        frames, times, stages = [], [], {}
        with sut:
            sut.detect(scenes[0])  # warm-up
            for scene in scenes:
                start = time.perf_counter()
                dets = sut.detect(scene)
                times.append(time.perf_counter() - start)
                for stage, seconds in getattr(getattr(sut, "times", None), "seconds", {}).items():
                    stages.setdefault(stage, []).append(seconds)
                frames.append(KittiFrame(scene.boxes, in_camera_view(dets, scene), scene.calib))
        result = evaluate_kitti(frames)
        ms = np.array(times) * 1000
        print(f"\n## {sut.name} v{sut.version} ({spec})\n")
        print("| class | BEV R40 | 3D R40 | BEV R11 | 3D R11 |")
        print("|---|---:|---:|---:|---:|")
        for cls in CLASSES:
            row = [result.get(m, cls, "moderate", p) for p in ("R40", "R11") for m in ("bev", "3d")]
            print(f"| {cls} (moderate) | " + " | ".join(f"{v:.1f}" for v in row) + " |")
        threads = getattr(getattr(sut, "options", None), "threads", 1)
        cores = "one core" if threads == 1 else f"{threads} threads"
        print(f"\ntime per frame: median {np.median(ms):.1f} ms, p90 {np.percentile(ms, 90):.1f} ms ({cores})")
        if stages:
            total = sum(np.median(v) for v in stages.values())
            print("\n| stage | median ms | share |")
            print("|---|---:|---:|")
            for stage, values in stages.items():
                print(f"| {stage} | {np.median(values) * 1000:.1f} | {np.median(values) / total:.0%} |")


if __name__ == "__main__":
    main()
