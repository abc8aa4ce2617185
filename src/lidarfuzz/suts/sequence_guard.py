"""A sequence system in a worker process, so that a hang is cut off and a dead interpreter is a result.

:class:`IsolatedSequence` is to :class:`~lidarfuzz.suts.sequence.SequenceSystem` what
:class:`~lidarfuzz.suts.guard.IsolatedSut` is to a detector: it builds the system named by a spec
(:func:`~lidarfuzz.suts.registry.create_sequence`) in a spawned process and forwards ``reset`` and
``step`` to it. A step that takes longer than ``timeout`` kills the process (``timeout``), a process
that dies — segfault, ``os._exit``, out of memory — is a ``crash``; either way the system is dead
for the rest of the log (:func:`~lidarfuzz.suts.sequence.replay` leaves the remaining frames
unstepped) and the next :meth:`~IsolatedSequence.reset` starts a fresh process. An exception in
the system's ``step`` is that step's ``crash``; the process lives on with its state.
"""

from __future__ import annotations

import contextlib
import multiprocessing
from multiprocessing.connection import Connection
from typing import Any

from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import FailureKind
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.guard import ask_served, spawn_served, stop_served
from lidarfuzz.suts.registry import create_sequence
from lidarfuzz.suts.sequence import Decision, SequenceSystem, failure_of


def _serve(spec: str, conn: Connection, options: dict[str, Any]) -> None:
    """Worker process: build the system, then answer ``("reset", None)`` and ``("step", frame)``."""
    try:
        system = create_sequence(spec, **options)
        system.load()
        conn.send(("ready", system.name, system.version, system.fingerprint(), system.max_steering))
    except Exception as exc:
        conn.send(("error", failure_of(exc)))
        return
    while True:
        try:
            message = conn.recv()
        except EOFError:
            break
        if message is None:
            break
        kind, payload = message
        try:
            if kind == "reset":
                system.reset()
                conn.send(("ok", None))
            else:
                conn.send(("ok", system.step(payload)))
        except Exception as exc:
            conn.send(("error", failure_of(exc)))
    system.close()


class IsolatedSequence(SequenceSystem):
    """A sequence system (given by its spec) running in its own process, with a timeout per step.

    Args:
        spec: What :func:`~lidarfuzz.suts.registry.create_sequence` builds in the process.
        timeout: Seconds one step (or reset) may take; the process is killed beyond it.
        start_timeout: Seconds the process may take to import and load the system.
        options: Keyword options for :func:`~lidarfuzz.suts.registry.create_sequence`.
    """

    def __init__(self, spec: str, *, timeout: float = 60.0, start_timeout: float = 120.0,
                 options: dict[str, Any] | None = None) -> None:
        self.spec = spec
        self.options = dict(options or {})
        self.timeout = timeout
        self.start_timeout = start_timeout
        self._process: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None
        self._identity: tuple[str, str, str, float] | None = None

    # identity comes from the hosted system (read-only properties where the base has class attributes)
    @property
    def name(self) -> str:  # type: ignore[override]
        return self._ensure_identity()[0]

    @property
    def version(self) -> str:  # type: ignore[override]
        return self._ensure_identity()[1]

    @property
    def max_steering(self) -> float:  # type: ignore[override]
        return self._ensure_identity()[3]

    def fingerprint(self) -> str:
        return self._ensure_identity()[2]

    def config(self) -> dict[str, Any]:
        return {"spec": self.spec, "options": self.options, "timeout": self.timeout}

    def _ensure_identity(self) -> tuple[str, str, str, float]:
        if self._identity is None:
            self.load()
        assert self._identity is not None
        return self._identity

    @property
    def alive(self) -> bool:
        return self._process is not None and self._process.is_alive()

    def set_timeout(self, seconds: float) -> None:
        self.timeout = seconds

    def load(self) -> None:
        if self.alive:
            return
        self._process, self._conn, self._identity = spawn_served(_serve, self.spec, self.options,
                                                                 f"sequence:{self.spec}", self.start_timeout)

    def _kill(self) -> None:
        if self._process is not None:
            stop_served(self._process)  # the host and every program its system started
        if self._conn is not None:
            self._conn.close()
        self._process = self._conn = None

    def _call(self, kind: str, payload: Any) -> Any:
        if not self.alive or self._conn is None or self._process is None:
            raise SutError(FailureKind.CRASH, "the system's process is not running (it died earlier in this log)")
        return ask_served(self._conn, self._process, (kind, payload), self.timeout, self._kill,
                          who="the system's process", after="the process was killed")

    def reset(self) -> None:
        """Start the process if it is not running (a fresh one after a death), then reset the system."""
        self.load()
        self._call("reset", None)

    def step(self, frame: Scene) -> Decision:
        decision: Decision = self._call("step", frame)
        return decision

    def close(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(BrokenPipeError, OSError):
                self._conn.send(None)
        if self._process is not None:
            self._process.join(5)
            stop_served(self._process)  # still running, or programs its system started still are
        if self._conn is not None:
            self._conn.close()
        self._process = self._conn = None
