"""Structural testing's cost: code coverage overhead per call, as a ratio to the plain call.

Usage: ``.venv/bin/python benchmarks/structural.py [--repeat R] [--calls K]``

For each function, the same inputs are run plain and under
:class:`~lidarfuzz.structural.python_coverage.CoverageRecorder` (coverage.py's C tracer,
``branch=True``, the function's module as the target, requirements mapped per call). A run is
``--calls`` calls; the figure is the median over ``--repeat`` runs of the time per call, and
the ratio is recorded ÷ plain, both measured in this run. "traced" is coverage.py's tracer alone
(start, call, stop; no data read): what any coverage.py measurement costs. The last column is the other way
coverage.py offers to separate calls — start, stop, read and ``erase()`` the data around each
call — which the recorder does not use because it costs more (see the table).

Functions (tests/structural/sample_code.py): ``ground_height``, numpy-heavy (a 120,000-point
cloud: most time in numpy, few Python lines), and ``steer``, branchy pure Python (200
obstacles: every line traced). Target (issue 20): ≤ 3× per frame of a system under test.

Then the built-in controller (``lidarfuzz.suts.controller``, the whole package as the target) on
a simulator drive log (``--controller-frames`` HDL-64E frames, made under ``bench-out/`` on first
use): the log replayed plain (reset, then every frame in order) and under the recorder; per frame,
median of ``--repeat`` replays.

Last, segment selection on a ``--log-frames`` frame log (default 2,500, VLP-16 so that it is made
in minutes; made on first use): the controller's per-frame coverage of the whole log (one replay,
timed), then each heuristic's selection from its segments of 5, median of ``--repeat``. Target
(issue 20): < 10 s.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the sample code lives under tests/

from coverage.control import Coverage
from tests.structural import sample_code

from lidarfuzz.structural.python_coverage import CoverageRecorder, RecorderConfig

TARGET = "tests.structural.sample_code"
CONTROLLER = "lidarfuzz.suts.controller"
WORK = Path(__file__).resolve().parents[1] / "bench-out" / "structural"


def cases() -> list[tuple[str, Callable[..., Any], tuple[Any, ...]]]:
    """``(name, function, arguments)`` with fixed inputs (seeded)."""
    rng = np.random.default_rng(0)
    cloud = np.column_stack([rng.uniform(-60, 60, (120_000, 2)), rng.normal(-1.6, 0.3, 120_000),
                             rng.uniform(0, 1, 120_000)]).astype(np.float32)
    obstacles = [(float(d), float(b)) for d, b in zip(rng.uniform(-1, 40, 200), rng.uniform(-1, 1, 200), strict=True)]
    return [("ground_height (numpy, 120k points)", sample_code.ground_height, (cloud,)),
            ("steer (branchy Python, 200 obstacles)", sample_code.steer, (obstacles, 8.0))]


def per_call(run: Callable[[], object], calls: int, repeat: int) -> float:
    """Median over ``repeat`` runs of the seconds per call of ``calls`` calls."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        for _ in range(calls):
            run()
        times.append((time.perf_counter() - start) / calls)
    return statistics.median(times)


def traced_only(function: Callable[..., Any], args: tuple[Any, ...]) -> Callable[[], object]:
    """coverage.py's C tracer around the call and nothing else (the data is never read)."""
    cov = Coverage(branch=True, data_file=None, config_file=False, include=[str(Path(sample_code.__file__).resolve())])

    def run() -> object:
        cov.start()
        try:
            return function(*args)
        finally:
            cov.stop()

    return run


def erase_per_call(function: Callable[..., Any], args: tuple[Any, ...]) -> Callable[[], object]:
    """The alternative: start, stop, read the arcs and erase coverage.py's data around every call."""
    filename = str(Path(sample_code.__file__).resolve())
    cov = Coverage(branch=True, data_file=None, config_file=False, include=[filename])
    cov.set_option("run:disable_warnings", ["no-data-collected"])

    def run() -> object:
        cov.start()
        try:
            function(*args)
        finally:
            cov.stop()
        arcs = cov.get_data().arcs(filename)
        cov.erase()
        return arcs

    return run


def drive_log(frames: int, sensor: str) -> Path:
    """A simulator drive log of ``frames`` frames (made once under ``bench-out/structural``)."""
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset

    path = WORK / f"drive-{sensor}-{frames}"
    if not (path / "timestamps.txt").exists():
        start = time.perf_counter()
        generate_dataset(path, GenerationConfig(frames=frames, seed=0, drive=True, sensor=sensor), overwrite=True)
        print(f"(made {path.name} in {time.perf_counter() - start:.0f} s)")
    return path


def controller(frames: int, repeat: int) -> None:
    """The controller's replay of a drive log, plain and under the recorder, per frame."""
    from lidarfuzz.structural.log_coverage import frame_coverage
    from lidarfuzz.structural.logs import open_log
    from lidarfuzz.suts.controller import ObstacleAvoidance

    scenes = list(open_log(drive_log(frames, "HDL-64E")))
    system = ObstacleAvoidance()
    recorder = CoverageRecorder([CONTROLLER])

    def plain() -> None:
        system.reset()
        for scene in scenes:
            system.step(scene)

    def recorded() -> None:
        frame_coverage(scenes, system.step, recorder, reset=system.reset)

    plain()  # warm
    a = per_call(plain, 1, repeat) / len(scenes)
    b = per_call(recorded, 1, repeat) / len(scenes)
    points = statistics.median(len(s.points) for s in scenes)
    print(f"{f'controller.step ({points:,.0f} points)':<40} {a * 1e3:9.3f} {'':>10} {'':>6} {b * 1e3:12.3f} "
          f"{b / a:5.2f}x")


def selection(frames: int, repeat: int) -> None:
    """Each heuristic's selection from a ``frames``-frame log's segments of 5."""
    from lidarfuzz.structural.heuristics import HEURISTICS, select
    from lidarfuzz.structural.log_coverage import decision_signature, frame_coverage
    from lidarfuzz.structural.logs import open_log
    from lidarfuzz.structural.segments import partition, segment_coverage
    from lidarfuzz.suts.controller import ObstacleAvoidance

    log = open_log(drive_log(frames, "VLP-16"))
    system = ObstacleAvoidance()
    start = time.perf_counter()
    replay = frame_coverage(log, system.step, CoverageRecorder([CONTROLLER]), reset=system.reset)
    replayed = time.perf_counter() - start
    segments = partition(log.frame_ids, 5)
    per_segment = segment_coverage(segments, replay.covered)
    signatures = [decision_signature(o) for o in replay.outputs]
    print(f"\nselection on a {len(log):,}-frame log ({len(segments)} segments of 5); the replay under coverage "
          f"took {replayed:.1f} s ({replayed / len(log) * 1e3:.1f} ms a frame)")
    print(f"{'heuristic':<18} {'seconds':>8} {'segments':>9} {'frames':>7}")
    for name in HEURISTICS:
        def run(name: str = name) -> object:
            return select(name, segments, per_segment, frames=100, signatures=signatures, seed=0)

        seconds = per_call(run, 1, repeat)
        chosen = run()
        print(f"{name:<18} {seconds:8.3f} {len(chosen):9d} {chosen.frames:7d}")  # type: ignore[attr-defined]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--controller-frames", type=int, default=50)
    parser.add_argument("--log-frames", type=int, default=2500)
    options = parser.parse_args()
    recorder = RecorderConfig((TARGET,)).build()
    print(f"{'function':<40} {'plain ms':>9} {'traced ms':>10} {'ratio':>6} {'recorded ms':>12} {'ratio':>6} "
          f"{'erase/call ms':>14} {'ratio':>6}")
    for name, function, args in cases():
        per_call(lambda f=function, a=args: f(*a), 2, 1)  # warm caches (imports, numpy)
        plain = per_call(lambda f=function, a=args: f(*a), options.calls, options.repeat)
        traced = per_call(traced_only(function, args), options.calls, options.repeat)
        recorded = per_call(lambda f=function, a=args: recorder.record(f, *a), options.calls, options.repeat)
        erased = per_call(erase_per_call(function, args), options.calls, options.repeat)
        print(f"{name:<40} {plain * 1e3:9.3f} {traced * 1e3:10.3f} {traced / plain:5.2f}x "
              f"{recorded * 1e3:12.3f} {recorded / plain:5.2f}x "
              f"{erased * 1e3:14.3f} {erased / plain:5.2f}x")
    controller(options.controller_frames, options.repeat)
    selection(options.log_frames, options.repeat)


if __name__ == "__main__":
    main()
