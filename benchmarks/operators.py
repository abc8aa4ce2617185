"""CPU time per mutation operator on a 120k-point HDL-64E frame (one core, one BLAS thread).

Usage: ``.venv/bin/python benchmarks/operators.py [--repeat N] [--severity S] [--only NAME,...] [--scale]``

Every registered LiDAR operator is configured at the given severity (default 3); each
timing is ``sample`` + ``apply`` on the same simulator frame, with a fresh seed on every call
(trial 0, 1, 2, ...), after one warm-up. A campaign calls an operator once per frame and trial:
repeating one seed would time memoised work as free (object insertion keeps, per frame, the
occlusion and ground work its ``sample`` did for its ``apply``, keyed by the placements; with
one seed every call after the first found it done, and the table said 5 ms for 18). The table
gives the median CPU time (``time.process_time``: the machine is shared, so wall time
measures the neighbours too) with its min–max spread, and the median wall time beside it.
Baseline measured in the same run: copying the frame's point array
(``numpy.ndarray.copy``), the least any operator that returns a new cloud must do.

Targets (issue 25, CPU time on one core): rain and snow ≤ 15 ms, fog ≤ 6 ms, the object
operators ≤ 5 ms, every other operator ≤ 1 ms; no operator superlinear up to 2M points.

``--scale`` adds, per operator, the CPU time at 30k, 123k, 492k and 2M points — clouds
built from the frame (every 4th point for the smallest; 4 and 16 copies of it, each
shifted by a few centimetres, for the larger ones; the channels stay those of the frame)
— and the exponent fitted to them (the slope of log time against log points), flagging
the operators above 1.15 as superlinear.

BLAS and OpenMP are pinned to one thread before numpy is imported: a matrix product on a
120k×3 array otherwise wakes a thread per core, which costs more than it saves and
bills every core's time to the operator.
"""

from __future__ import annotations

import os

# Before numpy loads: OpenBLAS and OpenMP read these once, when the library starts.
for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_variable] = "1"

import argparse  # noqa: E402
import contextlib  # noqa: E402
import itertools  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402

from lidarfuzz.operators import available, generator  # noqa: E402
from lidarfuzz.scene.points import PointCloud  # noqa: E402
from lidarfuzz.scene.scene import Scene  # noqa: E402
from lidarfuzz.sim import GenerationConfig, render_frames  # noqa: E402

WEATHER_TARGETS_MS = {"rain": 15.0, "snow": 15.0, "fog": 6.0}
OBJECT_TARGET_MS = 5.0
SIMPLE_TARGET_MS = 1.0
#: an exponent above this, fitted from 30k to 2M points, is called superlinear
SUPERLINEAR = 1.15
#: point-count multipliers of the frame for --scale: 30k, 123k, 492k, 2M on the HDL-64E frame
SCALES = (0.25, 1, 4, 16)


def target_ms(name: str, family: str) -> float:
    """Issue 25's CPU-time target for an operator."""
    if name in WEATHER_TARGETS_MS:
        return WEATHER_TARGETS_MS[name]
    return OBJECT_TARGET_MS if family == "object" else SIMPLE_TARGET_MS


@dataclass(frozen=True)
class Timing:
    """CPU and wall times of repeated runs, milliseconds."""

    cpu: list[float]
    wall: list[float]

    @property
    def cpu_ms(self) -> float:
        return statistics.median(self.cpu)

    @property
    def wall_ms(self) -> float:
        return statistics.median(self.wall)

    @property
    def spread(self) -> str:
        return f"{min(self.cpu):.2f}–{max(self.cpu):.2f}"


def fresh_calls(op: object, frame: Scene, stream: int) -> Callable[[], object]:
    """``op`` on ``frame``, each call with the next trial's generator of seed stream ``stream``."""
    trials = itertools.count()
    return lambda: op(frame, generator(0, frame.frame_id, stream, next(trials)))  # type: ignore[operator]


def measure(fn: Callable[[], object], repeat: int) -> Timing:
    """Median-ready CPU and wall times of ``repeat`` calls after one warm-up."""
    fn()
    cpu, wall = [], []
    for _ in range(repeat):
        cpu_start, wall_start = time.process_time(), time.perf_counter()
        fn()
        cpu.append((time.process_time() - cpu_start) * 1e3)
        wall.append((time.perf_counter() - wall_start) * 1e3)
    return Timing(cpu, wall)


def blas_threads() -> str:
    """The thread count each loaded BLAS/OpenMP library runs, as threadpoolctl reports it."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        return "threadpoolctl not installed; " + ", ".join(
            f"{v}={os.environ.get(v)}" for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS"))
    pools = threadpool_info()
    return ", ".join(f"{p['internal_api']} {p['num_threads']}" for p in pools) or "no BLAS/OpenMP pool loaded"


def load_average() -> str:
    with contextlib.suppress(OSError):
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    return "unknown"


def scaled(scene: Scene, factor: float) -> Scene:
    """The frame with ``factor`` times its points: every 1/factor-th point below 1, else
    ``factor`` copies, copy k shifted by (1, 0.7, 0) · k centimetres (the ring, time and label
    channels copied as they are)."""
    data = scene.points.data
    if factor < 1:
        return scene.replace(points=PointCloud(data[:: round(1 / factor)], scene.points.channels))
    copies = int(factor)
    tiled = np.tile(data, (copies, 1))
    shift = np.repeat(np.arange(copies, dtype=np.float32), len(data)) * np.float32(0.01)
    tiled[:, 0] += shift
    tiled[:, 1] += np.float32(0.7) * shift
    return scene.replace(points=PointCloud(tiled, scene.points.channels))


def exponent(counts: list[int], times_ms: list[float]) -> float:
    """Slope of log time against log points (least squares)."""
    slope, _ = np.polyfit(np.log(counts), np.log(np.maximum(times_ms, 1e-6)), 1)
    return float(slope)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=11)
    parser.add_argument("--severity", type=int, default=3)
    parser.add_argument("--only", default="", help="comma-separated operator names (default: every LiDAR operator)")
    parser.add_argument("--scale", action="store_true", help="also time each operator at 30k, 123k, 492k and 2M "
                                                             "points and fit the exponent")
    parser.add_argument("--scale-repeat", type=int, default=3, help="runs per size with --scale")
    args = parser.parse_args()
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core, as the targets say

    print(f"# load average before: {load_average()}; {time.strftime('%Y-%m-%d %H:%M:%S %Z')}")
    scene = next(render_frames(GenerationConfig(frames=1, seed=0)))
    print(f"# Operators on one HDL-64E simulator frame ({len(scene.points):,} points, {len(scene.boxes)} boxes), "
          f"severity {args.severity}, median of {args.repeat}, one core; BLAS threads: {blas_threads()}\n")
    baseline = measure(lambda: scene.points.data.copy(), args.repeat)
    print("| operator | family | CPU median (ms) | CPU min–max | wall median (ms) | × baseline | target (CPU) | met |")
    print("|---|---|---:|---:|---:|---:|---:|---|")
    print(f"| baseline: copy the point array | — | {baseline.cpu_ms:.3f} | {baseline.spread} | {baseline.wall_ms:.3f} "
          f"| 1.0 | | |")
    lidar = {name: cls for name, cls in available().items() if cls.modality == "lidar"}  # camera: benchmarks/camera.py
    only = {name.strip() for name in args.only.split(",") if name.strip()}
    unknown = only - set(lidar)
    if unknown:
        parser.error(f"--only: no LiDAR operator named {', '.join(sorted(unknown))}; known: {', '.join(sorted(lidar))}")
    chosen = [(trial, name, cls) for trial, (name, cls) in
              enumerate(sorted(lidar.items(), key=lambda kv: (kv[1].family, kv[0]))) if not only or name in only]
    for trial, name, cls in chosen:
        timing = measure(fresh_calls(cls.at_severity(args.severity), scene, trial), args.repeat)
        target = target_ms(name, cls.family)
        print(f"| {name} | {cls.family} | {timing.cpu_ms:.2f} | {timing.spread} | {timing.wall_ms:.2f} | "
              f"{timing.cpu_ms / baseline.cpu_ms:.0f} | ≤ {target:g} | "
              f"{'yes' if timing.cpu_ms <= target else '**no**'} |", flush=True)
    if not only or "outside_roi_scatter" in only:
        # a frame without a map: outside_roi_scatter estimates the drivable region from the scan
        from lidarfuzz.scene.drivable import estimate_drivable

        unmapped = scene.replace(roi=None)
        scatter = available()["outside_roi_scatter"].at_severity(args.severity)
        for label, target, fn in [
            ("drivable-region estimate (frame without a map)", 30.0, lambda: estimate_drivable(unmapped)),
            ("outside_roi_scatter, frame without a map", 40.0, fresh_calls(scatter, unmapped, 0)),
        ]:
            timing = measure(fn, args.repeat)
            print(f"| {label} | noise | {timing.cpu_ms:.2f} | {timing.spread} | {timing.wall_ms:.2f} | "
                  f"{timing.cpu_ms / baseline.cpu_ms:.0f} | ≤ {target:g} | "
                  f"{'yes' if timing.cpu_ms <= target else '**no**'} |", flush=True)

    if args.scale:
        frames = [scaled(scene, factor) for factor in SCALES]
        counts = [len(frame.points) for frame in frames]
        print(f"\n# CPU time (ms, median of {args.scale_repeat}) against points; exponent: slope of log time "
              f"against log points over all sizes (superlinear above {SUPERLINEAR}), and over the last step "
              f"alone (where the arrays leave the CPU's caches: compare with the baseline's)\n")
        print("| operator | " + " | ".join(f"{n / 1000:,.0f}k" for n in counts) +
              " | exponent | last step | exponent of time ÷ copy time | superlinear |")
        print("|---|" + "---:|" * (len(counts) + 3) + "---|")
        copy_times = [measure(lambda frame=frame: frame.points.data.copy(), args.scale_repeat).cpu_ms
                      for frame in frames]

        def scale_row(label: str, times: list[float]) -> None:
            slope, last = exponent(counts, times), exponent(counts[-2:], times[-2:])
            relative = exponent(counts, [t / c for t, c in zip(times, copy_times, strict=True)])
            print(f"| {label} | " + " | ".join(f"{t:.2f}" for t in times) + f" | {slope:.2f} | {last:.2f} | "
                  f"{relative:+.2f} | {'**yes**' if slope > SUPERLINEAR else 'no'} |", flush=True)

        scale_row("baseline: copy the point array", copy_times)
        for trial, name, cls in chosen:
            op = cls.at_severity(args.severity)
            times = []
            for frame in frames:
                times.append(measure(fresh_calls(op, frame, trial), args.scale_repeat).cpu_ms)
            scale_row(name, times)
    print(f"\nnumpy {np.__version__}; {os.cpu_count()} CPUs on the machine; BLAS threads at the end: {blas_threads()}")
    print(f"# load average after: {load_average()}; {time.strftime('%Y-%m-%d %H:%M:%S %Z')}")


if __name__ == "__main__":
    main()
