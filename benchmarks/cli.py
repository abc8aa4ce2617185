"""Start-up cost of the command line: CPU time of a child process, per command.

Usage: ``.venv/bin/python benchmarks/cli.py [--repeat N]``

Each command runs ``--repeat`` times as a fresh child process (the interpreter of this venv,
``-c "from lidarfuzz.cli.app import main; main()" ARGS``, as the ``lidarfuzz`` script does);
its CPU time is the child's user + system time (``os.wait4``), so other processes on the
machine do not count, and the table shows the median. Baselines, measured in the same run:
``python -c pass`` (the interpreter alone) and ``python -c "import typer"`` (the CLI
framework alone). ``info`` reads a small KITTI ``.bin`` frame this script writes to a
temporary folder. Byte-compiled files are written by a warm-up run of each command first.

Target (issue 18): ``lidarfuzz --help`` under 0.3 s of CPU.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

CLI = "from lidarfuzz.cli.app import main; main()"


def cpu_seconds(argv: list[str]) -> float:
    """User + system CPU seconds of one child process running ``argv`` (its output discarded)."""
    process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode not in (0, 1):  # info exits 1 on an error-level problem; that still measures
        raise SystemExit(f"{' '.join(argv)} exited with {process.returncode}")
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="Runs per command (the median is shown).")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        frame = Path(tmp) / "000000.bin"
        rng = np.random.default_rng(0)
        cloud = np.column_stack([rng.uniform(-40, 40, (2000, 2)), rng.uniform(-2, 2, 2000), rng.uniform(0, 1, 2000)])
        cloud.astype("<f4").tofile(frame)
        python = [sys.executable]
        rows = [
            ("python -c pass", [*python, "-c", "pass"]),
            ('python -c "import typer"', [*python, "-c", "import typer"]),
            ("lidarfuzz --help", [*python, "-c", CLI, "--help"]),
            ("lidarfuzz info FRAME.bin", [*python, "-c", CLI, "info", str(frame)]),
            ("lidarfuzz operators", [*python, "-c", CLI, "operators"]),
        ]
        for _, argv in rows:  # warm-up: .pyc files written, file cache filled
            cpu_seconds(argv)
        times: dict[str, list[float]] = {label: [] for label, _ in rows}
        for _ in range(args.repeat):  # interleaved, so drifts of the machine hit every row alike
            for label, argv in rows:
                times[label].append(cpu_seconds(argv))
    bare = statistics.median(times["python -c pass"])
    typer_only = statistics.median(times['python -c "import typer"'])
    print(f"CPU time (user + sys) of a child process, median of {args.repeat} runs; Python {sys.version.split()[0]}")
    print()
    print("| command | CPU s | over `python -c pass` | × `import typer` |")
    print("| --- | ---: | ---: | ---: |")
    for label, _ in rows:
        median = statistics.median(times[label])
        print(f"| `{label}` | {median:.3f} | {median - bare:+.3f} | {median / typer_only:.2f} |")


if __name__ == "__main__":
    main()
