"""Failures are results: running a SUT so that crashes, hangs and garbage become :class:`Failure` records.

* :func:`run_guarded` calls a SUT in this process: an exception becomes ``crash`` (with its
  traceback), a :class:`SutError` keeps its kind (adapters raise it for a non-zero exit or
  a killed subprocess), and an output that fails :meth:`SystemUnderTest.validate` becomes
  ``invalid_output``.
* :class:`IsolatedSut` hosts any SUT, named by its spec, in a worker process. A hang is cut
  off after ``timeout`` seconds by killing the worker (``timeout``), a worker that dies —
  segfault, ``os._exit``, out of memory — is a ``crash``; either way the next call starts a
  fresh worker, so a campaign goes on. The worker runs fenced as programs under test do
  (:mod:`lidarfuzz.suts.processes`): in a session of its own, under ``memory_limit`` (address
  space, default 8 GiB; a leak ends as the system's ``MemoryError``, a ``crash``), and a stopped
  worker takes every process it started with it (:func:`stop_served`).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import time
import traceback
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.suts.base import Failure, FailureKind, SutResult, SystemUnderTest
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.processes import MAX_BOXES, MEMORY_LIMIT, Limits, apply_limits, kill_all_groups
from lidarfuzz.suts.registry import create


def _failure_of(exc: BaseException) -> Failure:
    if isinstance(exc, SutError):
        return exc.failure()
    if isinstance(exc, MemoryError):  # past the worker's memory_limit, or the machine's memory
        detail = "".join(traceback.format_exception(exc))[-8000:]
        return Failure(FailureKind.CRASH, f"out of memory (MemoryError{f': {exc}' if str(exc) else ''})", detail)
    message = f"{type(exc).__name__}: {exc}".splitlines()[0][:500]
    return Failure(FailureKind.CRASH, message, "".join(traceback.format_exception(exc))[-8000:])


def run_guarded(sut: SystemUnderTest[Any, Any], sample: Any) -> SutResult[Any]:
    """One call of ``sut.detect`` that never raises for a failure of the SUT itself; more
    detections than the system's ``max_boxes`` (default 10,000) are an ``invalid_output``."""
    start = time.perf_counter()
    try:
        output = sut.detect(sample)
    except Exception as exc:  # the system under test's failure is a result
        return SutResult(None, _failure_of(exc), time.perf_counter() - start)
    elapsed = time.perf_counter() - start
    limit = getattr(sut, "max_boxes", MAX_BOXES)
    if isinstance(output, Boxes3D) and len(output) > limit:
        message = f"{len(output)} detections, more than max_boxes={limit} (a SUT option)"
        return SutResult(None, Failure(FailureKind.INVALID_OUTPUT, message), elapsed)
    problem = sut.validate(output)
    if problem is not None:
        return SutResult(None, Failure(FailureKind.INVALID_OUTPUT, problem), elapsed)
    return SutResult(output, None, elapsed)


def _serve(spec: str, conn: Connection, options: dict[str, Any] | None = None) -> None:
    """Worker process: build the SUT from its spec, then answer samples until told to stop."""
    try:
        sut = create(spec, **(options or {}))
        sut.load()
        conn.send(("ready", sut.name, sut.version, sut.fingerprint(), sut.classes))
    except Exception as exc:
        conn.send(("error", _failure_of(exc)))
        return
    while True:
        try:
            message = conn.recv()
        except EOFError:
            break
        if message is None:
            break
        try:
            conn.send(("ok", sut.detect(message)))
        except Exception as exc:
            conn.send(("error", _failure_of(exc)))
    sut.close()


def _stop_on_term(signum: int, frame: Any) -> None:
    """A served worker told to stop: the programs its system started go with it."""
    kill_all_groups()
    os._exit(128 + signum)


def _fenced(serve: Callable[..., None], memory_limit: int | None, spec: str, conn: Connection,
            options: Any) -> None:
    """The served worker's entry: its own session (so that :func:`stop_served` kills what it
    starts), its memory limit, then ``serve``."""
    os.setsid()
    apply_limits(Limits(memory=memory_limit))
    signal.signal(signal.SIGTERM, _stop_on_term)
    try:
        serve(spec, conn, options)
    finally:
        kill_all_groups()


def stop_served(process: Any, grace: float = 1.0) -> None:
    """Stop a worker of :func:`spawn_served` and everything it started: ``SIGTERM`` (it kills the
    programs its system started), then ``SIGKILL`` to its whole process group after ``grace`` s."""
    if process.is_alive():
        with contextlib.suppress(ProcessLookupError, OSError):
            os.kill(process.pid, signal.SIGTERM)
        process.join(grace)
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, signal.SIGKILL)  # its group: the worker leads it (setsid)
    if process.is_alive():
        process.kill()
    process.join()


def spawn_served(serve: Callable[..., None], spec: str, options: Any, name: str,
                 start_timeout: float, memory_limit: int | None = MEMORY_LIMIT,
                 ) -> tuple[Any, Any, tuple[Any, Any, Any, Any]]:
    """Start ``serve(spec, connection, options)`` in a spawned process — in a session of its
    own, its address space limited to ``memory_limit`` bytes (None: unlimited) — and wait for it
    to load the system: (the process, the parent's end of the pipe, the system's identity as sent).

    Raises:
        SutError: ``timeout`` when it is not ready within ``start_timeout``; ``crash`` when it
            dies loading or reports that it could not load.
    """
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe()
    process = ctx.Process(target=_fenced, args=(serve, memory_limit, spec, child, options), daemon=True, name=name)
    process.start()
    child.close()
    if not parent.poll(start_timeout):
        stop_served(process)
        raise SutError(FailureKind.TIMEOUT, f"{spec}: not ready after {start_timeout:g} s")
    try:
        reply = parent.recv()
    except EOFError:
        process.join(5)
        code = process.exitcode
        stop_served(process)
        raise SutError(FailureKind.CRASH, f"{spec}: died while loading (exit code {code})") from None
    if reply[0] == "error":
        stop_served(process)
        failure: Failure = reply[1]
        raise SutError(failure.kind, f"{spec}: could not load: {failure.message}", failure.detail)
    return process, parent, (reply[1], reply[2], reply[3], reply[4])


def ask_served(conn: Any, process: Any, message: Any, timeout: float, kill: Callable[[], None], *,
               who: str, after: str) -> Any:
    """Send ``message`` to a system served by :func:`spawn_served` and return its answer.

    Raises:
        SutError: ``crash`` when the process died (``kill`` then cleans up), ``timeout`` when it
            did not answer within ``timeout`` (``kill`` stops it), or the failure it reported.
    """
    try:
        conn.send(message)
    except (BrokenPipeError, OSError):
        code = process.exitcode
        kill()
        raise SutError(FailureKind.CRASH, f"{who} died (exit code {code})") from None
    if not conn.poll(timeout):
        kill()
        raise SutError(FailureKind.TIMEOUT, f"no answer within {timeout:g} s; {after}")
    try:
        reply = conn.recv()
    except EOFError:
        process.join(5)
        code = process.exitcode
        kill()
        raise SutError(FailureKind.CRASH, f"{who} died (exit code {code})") from None
    if reply[0] == "error":
        failure: Failure = reply[1]
        raise SutError(failure.kind, failure.message, failure.detail)
    return reply[1]


class IsolatedSut(SystemUnderTest[Any, Any]):
    """A SUT (given by its spec string) running in its own worker process, with a timeout.

    Args:
        spec: What :func:`lidarfuzz.suts.registry.create` builds in the worker.
        timeout: Seconds one sample may take; the worker is killed beyond it.
        start_timeout: Seconds the worker may take to import and load the SUT.
        options: Keyword options for :func:`~lidarfuzz.suts.registry.create`.
        memory_limit: The worker's address space (bytes or a size such as ``"4GiB"``; default
            8 GiB; 0 or None: unlimited, e.g. for a system on a GPU, whose driver reserves more
            address space than that).
    """

    def __init__(self, spec: str, *, timeout: float = 60.0, start_timeout: float = 120.0,
                 options: dict[str, Any] | None = None, memory_limit: int | str | None = MEMORY_LIMIT) -> None:
        self.spec = spec
        self.options = dict(options or {})
        self.timeout = timeout
        self.start_timeout = start_timeout
        self.memory_limit = Limits.of(memory_limit).memory
        boxes = self.options.get("max_boxes", MAX_BOXES)  # the hosted system's limit, checked here too
        self.max_boxes = boxes if isinstance(boxes, int) and not isinstance(boxes, bool) else MAX_BOXES
        self._process: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None
        self._identity: tuple[str, str, str, tuple[str, ...] | None] | None = None
        self.restarts = 0

    # identity comes from the hosted SUT (read-only properties where the base has class
    # attributes; mypy reports the override on the def line)
    @property
    def name(self) -> str:  # type: ignore[override]
        return self._ensure_identity()[0]

    @property
    def version(self) -> str:  # type: ignore[override]
        return self._ensure_identity()[1]

    @property
    def classes(self) -> tuple[str, ...] | None:  # type: ignore[override]
        return self._ensure_identity()[3]

    def fingerprint(self) -> str:
        return self._ensure_identity()[2]

    def config(self) -> dict[str, Any]:
        return {"spec": self.spec, "options": self.options, "timeout": self.timeout}

    def _ensure_identity(self) -> tuple[str, str, str, tuple[str, ...] | None]:
        if self._identity is None:
            self.load()
        assert self._identity is not None
        return self._identity

    def load(self) -> None:
        if self._process is not None and self._process.is_alive():
            return
        self._process, self._conn, self._identity = spawn_served(_serve, self.spec, self.options,
                                                                 f"sut:{self.spec}", self.start_timeout,
                                                                 self.memory_limit)

    def _kill(self) -> None:
        if self._process is not None:
            stop_served(self._process)
        if self._conn is not None:
            self._conn.close()
        self._process = self._conn = None
        self.restarts += 1

    def detect(self, sample: Any) -> Any:
        self.load()
        assert self._conn is not None and self._process is not None
        return ask_served(self._conn, self._process, sample, self.timeout, self._kill, who="worker process",
                          after="worker restarted")

    def detect_batch(self, samples: Sequence[Any]) -> list[Any]:
        return [self.detect(s) for s in samples]

    def close(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(BrokenPipeError, OSError):
                self._conn.send(None)
        if self._process is not None:
            self._process.join(5)
            stop_served(self._process)  # what it started too, whether it exited or not
        if self._conn is not None:
            self._conn.close()
        self._process = self._conn = None
