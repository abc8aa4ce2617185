"""Read/write throughput of every frame format and log type on a 120k-point HDL-64E-like frame.

Usage: ``python benchmarks/io.py [--repeat 21] [--points 120000]``

Prints a Markdown table: median time over ``--repeat`` runs, throughput in million
points per second, and the ratio against a baseline measured in the same run —
``numpy.fromfile`` on the ``.bin`` (what most tools do to read KITTI scans). Reads
include lidarfuzz's validation (size check, NaN/Inf scan, channel mapping).
Frames hold x, y, z, intensity unless the row says otherwise.
Targets (issue 2): ``.bin`` read < 1 ms; PCD binary read within 3× of the ``.bin`` read.
"""

from __future__ import annotations

import argparse
import itertools
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pypcd4

from lidarfuzz.io import open_dataset, read_frame, write_frame
from lidarfuzz.io.formats import bin as bin_format
from lidarfuzz.io.logs import write_log
from lidarfuzz.scene import PointCloud, Scene
from lidarfuzz.sim import GenerationConfig, render_frames


def median_ms(fn: Callable[[], object], repeat: int) -> float:
    fn()  # warm the page cache and imports
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def frame_of(points: int, seed: int = 0) -> Scene:
    """A simulated frame resampled to exactly ``points`` points, x, y, z, intensity, ring, time."""
    scene = next(render_frames(GenerationConfig(frames=1, seed=seed)))
    rng = np.random.default_rng(seed)
    index = rng.choice(len(scene.points), size=points, replace=points > len(scene.points))
    cloud = scene.points.select(np.sort(index))
    keep = ("x", "y", "z", "intensity", "ring", "time")
    cloud = PointCloud(cloud.data[:, [cloud.index(c) for c in keep]], keep)
    return scene.replace(points=cloud, boxes=scene.boxes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=21)
    parser.add_argument("--points", type=int, default=120_000)
    parser.add_argument("--log-frames", type=int, default=10)
    args = parser.parse_args()

    scene = frame_of(args.points)
    xyzi = scene.replace(points=PointCloud(scene.points.data[:, :4]))
    work = Path(tempfile.mkdtemp(prefix="lidarfuzz-bench-io-"))
    rows: list[tuple[str, float, float]] = []
    try:
        bin_path = work / "frame.bin"
        bin_format.write(bin_path, xyzi)
        baseline = median_ms(lambda: np.fromfile(bin_path, dtype=np.float32).reshape(-1, 4), args.repeat)

        def add(name: str, ms: float) -> None:
            rows.append((name, ms, ms / baseline))

        add("baseline: numpy.fromfile .bin", baseline)
        add("read .bin (memory-mapped)", median_ms(lambda: bin_format.read(bin_path), args.repeat))
        add("read .bin + touch every value", median_ms(lambda: float(bin_format.read(bin_path).points.data.sum()),
                                                       args.repeat))
        cases: list[tuple[str, str, dict[str, object]]] = [
            ("bin", ".bin", {}),
            ("pcd binary", ".pcd", {"encoding": "binary"}),
            ("pcd binary_compressed", ".pcd", {"encoding": "binary_compressed"}),
            ("pcd ascii", ".pcd", {"encoding": "ascii"}),
            ("ply", ".ply", {}),
            ("las", ".las", {}),
            ("laz", ".laz", {}),
            ("npy", ".npy", {}),
            ("npz (full scene)", ".npz", {}),
            ("pcd binary, 6 channels (+ ring, time)", ".pcd", {"encoding": "binary"}),
        ]
        slow = {"pcd ascii", "laz"}
        for i, (name, suffix, options) in enumerate(cases):
            source = scene if "6 channels" in name or suffix == ".npz" else xyzi
            path = work / f"w{i}{suffix}"
            repeat = max(3, args.repeat // 4) if name in slow else args.repeat
            counter = itertools.count()

            def write(suffix: str = suffix, source: Scene = source, options: dict[str, object] = options,
                      counter: Iterator[int] = counter, i: int = i) -> None:
                write_frame(work / f"w{i}-{next(counter)}{suffix}", source, **options)

            add(f"write {name}", median_ms(write, repeat))
            write_frame(path, source, **options)
            add(f"read {name}", median_ms(lambda path=path: read_frame(path), repeat))
        add("read pcd binary via pypcd4 alone (reference)",
            median_ms(lambda: pypcd4.PointCloud.from_path(work / "w1.pcd").numpy(), args.repeat))

        scenes = [frame_of(args.points, seed).replace(timestamp=0.1 * seed, frame_id=f"{seed:06d}")
                  for seed in range(args.log_frames)]
        for kind, name in (("ros1", "log.bag"), ("mcap", "log.mcap"), ("ros2", "log-ros2")):
            path = work / name
            start = time.perf_counter()
            write_log(path, scenes, kind=kind)
            add(f"write {kind} log (per frame)", (time.perf_counter() - start) * 1e3 / len(scenes))

            def read_all(path: Path = path) -> None:
                for _ in open_dataset(path):
                    pass

            add(f"read {kind} log (per frame, streamed)",
                median_ms(read_all, max(3, args.repeat // 4)) / len(scenes))
    finally:
        shutil.rmtree(work, ignore_errors=True)

    print(f"I/O on a {args.points:,}-point frame (median of {args.repeat} runs; logs: {args.log_frames} frames)\n")
    print("| operation | median (ms) | Mpoints/s | × baseline |")
    print("|---|---:|---:|---:|")
    for name, ms, ratio in rows:
        print(f"| {name} | {ms:.3f} | {args.points / ms / 1e3:.1f} | {ratio:.2f} |")


if __name__ == "__main__":
    main()
