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

from lidarfuzz.structural.python_coverage import RecorderConfig

TARGET = "tests.structural.sample_code"


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--calls", type=int, default=20)
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


if __name__ == "__main__":
    main()
