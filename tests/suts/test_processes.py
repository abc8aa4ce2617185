"""Programs under test start fenced (suts/processes.py): limits on the running program, and no
Python code between fork and exec."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
import tracemalloc
from pathlib import Path

from lidarfuzz.suts.processes import Limits, kill_group, start


def _limits_of(pid: int) -> dict[str, str]:
    """The soft limits the kernel holds for ``pid`` (``/proc/PID/limits``), by name."""
    rows = Path(f"/proc/{pid}/limits").read_text().splitlines()[1:]
    return {row[:26].strip(): row[26:47].strip() for row in rows}


def test_a_started_program_runs_under_its_memory_and_cpu_limits() -> None:
    process = start([sys.executable, "-c", "import sys; sys.stdin.read()"], Limits(memory=3 << 30, cpu=5),
                    cwd=None, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        limits = _limits_of(process.pid)
    finally:
        kill_group(process)
    assert limits["Max address space"] == str(3 << 30)
    assert limits["Max cpu time"] == "5"  # soft: SIGXCPU at 5 s (the hard limit, a second later, kills)


def test_starting_programs_never_hangs_while_other_threads_come_and_go() -> None:
    # The CI hang this guards against: Popen with a preexec_fn runs Python in the child between
    # fork and exec; a thread ending at the moment of the fork (a system's stderr reader) can hold
    # tracemalloc's lock there, and the child (and Popen, waiting for its exec) waits forever.
    # With a preexec_fn it hung after 1,062 starts beside four churning threads; without, 40,000 ran.
    stop = threading.Event()

    def churn() -> None:
        while not stop.is_set():
            thread = threading.Thread(target=lambda: None)
            thread.start()
            thread.join()

    churners = [threading.Thread(target=churn, daemon=True) for _ in range(4)]
    done = threading.Event()

    def starts() -> None:
        for _ in range(2000):
            kill_group(start(["true"], Limits(), cwd=None, stdin=None, stdout=None, stderr=None))
        done.set()

    tracemalloc.start()
    try:
        for churner in churners:
            churner.start()
        starter = threading.Thread(target=starts, daemon=True)
        started = time.monotonic()
        starter.start()
        assert done.wait(60), "starting a program hung"
    finally:
        stop.set()
        tracemalloc.stop()
    assert time.monotonic() - started < 60
