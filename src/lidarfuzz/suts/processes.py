"""Programs under test run fenced: their own session, resource limits, and every descendant killed.

A system under test is someone else's program; lidarfuzz must outlive whatever it does. Every
program :mod:`lidarfuzz.suts.external` starts (and the worker process of
:class:`~lidarfuzz.suts.guard.IsolatedSut`) runs

* in a **session of its own** (``setsid`` before ``exec``), so that its process group holds it
  and every child it forks: :func:`kill_group` kills them all with one ``killpg`` on a timeout,
  a restart and at the end. A program that starts a session of its own (a daemon) escapes
  this; nothing short of a cgroup can follow it;
* under **resource limits** (:class:`Limits`), set with ``prlimit`` the moment the program has
  started (not by Python code between ``fork`` and ``exec``: in a process with threads, such code
  can wait forever on a lock another thread held at the fork, and ``Popen`` with it): address space
  (``memory_limit``, default 8 GiB: a leak ends as the program's ``MemoryError`` or failed
  ``malloc``, a ``crash`` named *out of memory*, never as lidarfuzz swapping), optionally CPU
  seconds (``cpu_limit``), and on lidarfuzz's side the size of an answer it reads
  (``max_answer_bytes``) and the number of boxes it accepts (``max_boxes``).

Groups that are still alive are killed when the interpreter exits (:func:`kill_all_groups` runs
at exit), so a caller that forgets ``close()`` leaves no orphan either.
"""

from __future__ import annotations

import atexit
import contextlib
import math
import os
import re
import resource
import signal
import subprocess
import threading
from dataclasses import dataclass
from typing import IO, Any

#: Default address-space limit of a program under test (bytes).
MEMORY_LIMIT = 8 << 30
#: Default limit on one answer line (worker) or output file (one-shot), bytes.
MAX_ANSWER_BYTES = 4 << 20
#: Default limit on detections in one answer.
MAX_BOXES = 10_000

_UNITS = {"": 1, "b": 1, "k": 1 << 10, "kb": 1 << 10, "kib": 1 << 10, "m": 1 << 20, "mb": 1 << 20,
          "mib": 1 << 20, "g": 1 << 30, "gb": 1 << 30, "gib": 1 << 30, "t": 1 << 40, "tb": 1 << 40, "tib": 1 << 40}
_OUT_OF_MEMORY = re.compile(r"MemoryError|bad_alloc|Cannot allocate memory|out of memory|Out of memory|"
                            r"memory exhausted|Unable to allocate")


def parse_size(value: Any, field: str, *, allow_none: bool = True) -> int | None:
    """Bytes from ``8589934592``, ``"8GiB"``, ``"512M"``, ``"64k"`` (binary units); ``None``,
    ``0`` or ``"none"`` mean no limit where ``allow_none``.

    Raises:
        ValueError: One line naming ``field`` for anything else.

    >>> parse_size("512MiB", "memory_limit")
    536870912
    """
    if value is None or (isinstance(value, str) and value.strip().lower() in ("none", "off", "")):
        number: float = 0
    elif isinstance(value, bool):
        raise ValueError(f"{field}: expected a size such as 8GiB or a number of bytes, got {value!r}")
    elif isinstance(value, int | float):
        number = float(value)
    elif isinstance(value, str):
        match = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]+)?)\s*([A-Za-z]*)\s*", value)
        unit = match.group(2).lower() if match else ""
        if match is None or unit not in _UNITS:
            raise ValueError(f"{field}: expected a size such as 8GiB, 512M or a number of bytes, got {value!r}")
        number = float(match.group(1)) * _UNITS[unit]
    else:
        raise ValueError(f"{field}: expected a size such as 8GiB or a number of bytes, got {type(value).__name__}")
    if not math.isfinite(number) or number < 0:
        raise ValueError(f"{field}: expected a size >= 0, got {value!r}")
    if number == 0:
        if not allow_none:
            raise ValueError(f"{field}: must be greater than 0")
        return None
    return int(number)


def format_size(size: int) -> str:
    """``268435456`` → ``256 MiB``."""
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if size >= scale:
            return f"{size / scale:g} {unit}"
    return f"{size} B"


@dataclass(frozen=True)
class Limits:
    """What a program under test may use (see the module docstring).

    Attributes:
        memory: Address space per process, bytes (None: unlimited).
        cpu: CPU seconds per process (None: unlimited); past it the kernel stops the program.
        answer_bytes: Longest answer line or output file lidarfuzz reads.
        boxes: Most detections accepted in one answer.
    """

    memory: int | None = MEMORY_LIMIT
    cpu: float | None = None
    answer_bytes: int = MAX_ANSWER_BYTES
    boxes: int = MAX_BOXES

    @classmethod
    def of(cls, memory_limit: Any = MEMORY_LIMIT, cpu_limit: Any = None, max_answer_bytes: Any = MAX_ANSWER_BYTES,
           max_boxes: Any = MAX_BOXES) -> Limits:
        """Limits from a SUT spec's options (``memory_limit="2GiB"``, ``cpu_limit=30``, …).

        Raises:
            ValueError: One line naming the option that is not a valid value.
        """
        if cpu_limit is not None and (isinstance(cpu_limit, bool) or not isinstance(cpu_limit, int | float)
                                      or not math.isfinite(cpu_limit) or cpu_limit <= 0):
            raise ValueError(f"cpu_limit: expected seconds > 0 or none, got {cpu_limit!r}")
        if isinstance(max_boxes, bool) or not isinstance(max_boxes, int) or max_boxes < 0:
            raise ValueError(f"max_boxes: expected a whole number >= 0, got {max_boxes!r}")
        answer = parse_size(max_answer_bytes, "max_answer_bytes", allow_none=False)
        assert answer is not None  # allow_none=False
        return cls(parse_size(memory_limit, "memory_limit"), None if cpu_limit is None else float(cpu_limit),
                   answer, max_boxes)

    def describe(self) -> str:
        memory = "unlimited" if self.memory is None else format_size(self.memory)
        cpu = "unlimited" if self.cpu is None else f"{self.cpu:g} s"
        return f"memory_limit {memory}, cpu_limit {cpu}"


def _lowered(which: int, wanted: int) -> tuple[int, int]:
    """(soft, hard) at most ``wanted`` and never above the current hard limit (which only root may raise)."""
    _, hard = resource.getrlimit(which)
    value = wanted if hard == resource.RLIM_INFINITY else min(wanted, hard)
    return value, value


def apply_limits(limits: Limits, pid: int = 0) -> None:
    """Set the resource limits of process ``pid`` (0: this one, e.g. a worker process at its start).

    Raises:
        ProcessLookupError: ``pid`` has already exited.
    """
    if limits.memory is not None:
        resource.prlimit(pid, resource.RLIMIT_AS, _lowered(resource.RLIMIT_AS, limits.memory))
    if limits.cpu is not None:
        seconds = max(1, math.ceil(limits.cpu))
        soft, _ = _lowered(resource.RLIMIT_CPU, seconds)
        _, hard = _lowered(resource.RLIMIT_CPU, seconds + 1)  # SIGXCPU first, SIGKILL a second later
        resource.prlimit(pid, resource.RLIMIT_CPU, (soft, hard))


# -- the groups this process started --------------------------------------------------------
_GROUPS: set[int] = set()
_GROUPS_LOCK = threading.Lock()


def start(argv: list[str], limits: Limits, *, cwd: str | None, stdin: Any, stdout: Any,
          stderr: Any) -> subprocess.Popen[bytes]:
    """Start ``argv`` in a new session under ``limits`` (binary, unbuffered streams).

    The limits are set on the running program as soon as ``Popen`` returns (it returns once the
    program's ``exec`` succeeded), which is before the program's start-up code could fork a child
    of its own. No Python code runs between ``fork`` and ``exec`` (no ``preexec_fn``): with
    threads in this process (a system's stderr readers, a web server's), such code can block
    forever on a lock another thread held at the moment of the fork — tracemalloc's, an
    allocator's — and ``Popen`` waits for it.

    Raises:
        OSError: The program cannot be started.
    """
    process = subprocess.Popen(argv, stdin=stdin, stdout=stdout, stderr=stderr, cwd=cwd, bufsize=0,
                               start_new_session=True, close_fds=True)
    with _GROUPS_LOCK:
        _GROUPS.add(process.pid)
    with contextlib.suppress(ProcessLookupError):  # gone already: its exit is read as usual
        apply_limits(limits, process.pid)
    return process


def kill_group(process: subprocess.Popen[bytes] | None) -> None:
    """Kill the program and every process of its group (children it forked), then reap it.

    The group is killed before the leader is reaped: while the leader's pid is not reaped, it
    cannot be reused by another process group."""
    if process is None:
        return
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, signal.SIGKILL)
    with contextlib.suppress(ProcessLookupError):
        process.kill()
    process.wait()
    with _GROUPS_LOCK:
        _GROUPS.discard(process.pid)
    for stream in (process.stdin, process.stdout, process.stderr):
        if stream is not None:
            with contextlib.suppress(OSError):
                stream.close()


def kill_all_groups() -> None:
    """Kill every process group this process started and has not killed yet (at exit, or when
    an :class:`~lidarfuzz.suts.guard.IsolatedSut` worker is told to stop)."""
    with _GROUPS_LOCK:
        groups = sorted(_GROUPS)
        _GROUPS.clear()
    for group in groups:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(group, signal.SIGKILL)


atexit.register(kill_all_groups)


def group_members(group: int) -> list[int]:
    """Live (not zombie) processes of process group ``group``, read from ``/proc`` (Linux)."""
    members = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as handle:
                stat = handle.read().decode("utf-8", "replace")
        except OSError:
            continue
        fields = stat.rpartition(")")[2].split()  # after the command name, which may hold spaces
        if len(fields) > 2 and fields[0] != "Z" and fields[2] == str(group):
            members.append(int(entry))
    return members


class StreamTail:
    """Drains a program's stream (stderr) on a thread, keeping its last ``keep`` bytes: a program
    never blocks on a full pipe, and lidarfuzz never holds more than ``keep`` bytes of it."""

    def __init__(self, stream: IO[bytes], keep: int = 8192) -> None:
        self.keep = keep
        self._data = bytearray()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._drain, args=(stream.fileno(),), daemon=True)
        self._thread.start()

    def _drain(self, fd: int) -> None:
        while True:
            try:
                chunk = os.read(fd, 1 << 16)
            except OSError:
                return
            if not chunk:
                return
            with self._lock:
                self._data += chunk
                if len(self._data) > 2 * self.keep:
                    del self._data[:-self.keep]

    def text(self, wait: float = 0.0) -> str:
        """What was kept, decoded (``wait``: seconds to let the stream reach its end first)."""
        if wait:
            self._thread.join(wait)
        with self._lock:
            return bytes(self._data[-self.keep:]).decode("utf-8", "replace")


def death(name: str, code: int, tail: str, limits: Limits) -> tuple[str, bool]:
    """How a program ended, for a failure message, and whether that is a timeout (its CPU limit).

    >>> death("det", -11, "", Limits())
    ('det: killed by signal 11 (SIGSEGV)', False)
    """
    if code < 0:
        try:
            label = f" ({signal.Signals(-code).name})"
        except ValueError:
            label = ""
        how = f"killed by signal {-code}{label}"
    else:
        how = f"exit code {code}"
    if limits.cpu is not None and code == -signal.SIGXCPU:
        return f"{name}: used more than its cpu_limit of {limits.cpu:g} CPU seconds ({how})", True
    if limits.memory is not None and _OUT_OF_MEMORY.search(tail):
        return f"{name}: out of memory ({how}; memory_limit {format_size(limits.memory)})", False
    return f"{name}: {how}", False
