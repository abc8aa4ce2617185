"""Failures are results: running a SUT so that crashes, hangs and garbage become :class:`Failure` records.

* :func:`run_guarded` calls a SUT in this process: an exception becomes ``crash`` (with its
  traceback), a :class:`SutError` keeps its kind (adapters raise it for a non-zero exit or
  a killed subprocess), and an output that fails :meth:`SystemUnderTest.validate` becomes
  ``invalid_output``.
* :class:`IsolatedSut` hosts any SUT, named by its spec, in a worker process. A hang is cut
  off after ``timeout`` seconds by killing the worker (``timeout``), a worker that dies —
  segfault, ``os._exit``, out of memory — is a ``crash``; either way the next call starts a
  fresh worker, so a campaign goes on.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import time
import traceback
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any

from lidarfuzz.suts.base import Failure, FailureKind, SutResult, SystemUnderTest
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.registry import create


def _failure_of(exc: BaseException) -> Failure:
    if isinstance(exc, SutError):
        return exc.failure()
    message = f"{type(exc).__name__}: {exc}".splitlines()[0][:500]
    return Failure(FailureKind.CRASH, message, "".join(traceback.format_exception(exc))[-8000:])


def run_guarded(sut: SystemUnderTest[Any, Any], sample: Any) -> SutResult[Any]:
    """One call of ``sut.detect`` that never raises for a failure of the SUT itself."""
    start = time.perf_counter()
    try:
        output = sut.detect(sample)
    except Exception as exc:  # the system under test's failure is a result
        return SutResult(None, _failure_of(exc), time.perf_counter() - start)
    elapsed = time.perf_counter() - start
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


def spawn_served(serve: Callable[..., None], spec: str, options: Any, name: str,
                 start_timeout: float) -> tuple[Any, Any, tuple[Any, Any, Any, Any]]:
    """Start ``serve(spec, connection, options)`` in a spawned process and wait for it to load
    the system: (the process, the parent's end of the pipe, the system's identity as sent).

    Raises:
        SutError: ``timeout`` when it is not ready within ``start_timeout``; ``crash`` when it
            dies loading or reports that it could not load.
    """
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe()
    process = ctx.Process(target=serve, args=(spec, child, options), daemon=True, name=name)
    process.start()
    child.close()
    if not parent.poll(start_timeout):
        process.kill()
        process.join()
        raise SutError(FailureKind.TIMEOUT, f"{spec}: not ready after {start_timeout:g} s")
    try:
        reply = parent.recv()
    except EOFError:
        process.join()
        raise SutError(FailureKind.CRASH, f"{spec}: died while loading (exit code {process.exitcode})") from None
    if reply[0] == "error":
        process.join()
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
    """

    def __init__(self, spec: str, *, timeout: float = 60.0, start_timeout: float = 120.0,
                 options: dict[str, Any] | None = None) -> None:
        self.spec = spec
        self.options = dict(options or {})
        self.timeout = timeout
        self.start_timeout = start_timeout
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
                                                                 f"sut:{self.spec}", self.start_timeout)

    def _kill(self) -> None:
        if self._process is not None:
            self._process.kill()
            self._process.join()
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
            if self._process.is_alive():
                self._process.kill()
                self._process.join()
        if self._conn is not None:
            self._conn.close()
        self._process = self._conn = None
