"""Uploads are inspected in a worker process, never in the server's: a native reader that
aborts (the LAZ library's SIGABRT on a corrupt chunk table), exhausts memory or hangs on a
hostile file takes down that worker, not ``lidarfuzz serve``. The worker is started once (a
fresh interpreter, ``spawn``) and reused; it runs under an address-space limit, and an
inspection that passes its time limit kills it. A worker that dies or is killed makes the
upload a 422 saying so; the next upload starts a new one.

What the worker sends back is what :func:`lidarfuzz.io.inspect.inspect_source` found, as the
upload's problems (each naming its file relative to the upload) and the report.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

#: The worker's address-space limit (bytes) and an inspection's time limit (seconds), by default
MEMORY = 4 << 30
SECONDS = 3600.0


def relative(text: str, root: Path) -> str:
    """``text`` with the upload's folder ``root`` taken out (messages never show the server's folders)."""
    for base in (root, root.resolve()):
        text = text.replace(f"{base}/", "").replace(str(base), ".")
    return text


def inspect_upload(root: Path, base: Path, options: Any = None) -> tuple[list[dict[str, Any]], Any]:
    """Inspect an upload here (in the worker): its problems, each ``{severity, file, line,
    message}`` relative to ``base``, and the report (None when the source cannot be opened)."""
    from lidarfuzz.errors import DataFormatError
    from lidarfuzz.io.inspect import inspect_source

    try:
        report = inspect_source(root, options=options)
    except DataFormatError as exc:
        return [{"severity": "error", "file": relative(str(exc.path), base), "line": exc.line,
                 "message": relative(exc.message, base)}], None
    problems = [{"severity": p.severity, "file": relative(p.path, base), "line": p.line,
                 "message": relative(p.message, base)} for p in report.problems]
    if report.frames == 0:
        problems.append({"severity": "error", "file": ".", "line": None, "message": "no frames to test"})
    return problems, report


def _limit_memory(memory: int | None) -> None:
    if memory is None:
        return
    try:
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
    except (ImportError, ValueError, OSError):  # not on this platform, or a lower hard limit: keep it
        pass


Work = Callable[[Path, Path, Any], tuple[list[dict[str, Any]], Any]]


def _serve(conn: Connection, memory: int | None, work: Work) -> None:
    """The worker's loop: one ``(root, base, options)`` in, ``work``'s ``("ok", result)`` or
    ``("error", message)`` out, until the pipe closes."""
    _limit_memory(memory)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C stops the server, which ends this worker
    while True:
        try:
            root, base, options = conn.recv()
        except (EOFError, OSError):
            return
        try:
            reply: tuple[str, Any] = ("ok", work(root, base, options))
        except MemoryError:
            reply = ("error", f"inspecting it needed more than the limit of {(memory or 0) >> 20} MiB of memory")
        except Exception as exc:  # any reader's failure is the upload's problem, said in one line
            reply = ("error", f"inspecting it failed: {type(exc).__name__}: {exc}"[:500])
        try:
            conn.send(reply)
        except Exception as exc:  # e.g. a report that cannot be pickled
            conn.send(("error", f"inspecting it failed: {type(exc).__name__}: {exc}"[:500]))


def _death(code: int | None) -> str:
    """How the worker ended, in words."""
    if code is not None and code < 0:
        try:
            return f"killed by signal {-code} ({signal.Signals(-code).name})"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exited with status {code}"


class UploadInspector:
    """One inspection at a time in a reused worker process.

    Args:
        memory: The worker's address-space limit in bytes (None: none).
        seconds: An inspection's time limit (None: none); past it the worker is killed.
        work: What the worker runs (a module-level function, :func:`inspect_upload`).
    """

    def __init__(self, memory: int | None = MEMORY, seconds: float | None = SECONDS,
                 work: Work = inspect_upload) -> None:
        self.memory, self.seconds, self.work = memory, seconds, work
        self._lock = threading.Lock()
        self._process: Any = None
        self._conn: Connection | None = None
        self.started = 0  # workers started so far (a test counts the restarts)

    def _start(self) -> Connection:
        context = multiprocessing.get_context("spawn")
        parent, child = context.Pipe()
        self._process = context.Process(target=_serve, args=(child, self.memory, self.work), daemon=True,
                                        name="lidarfuzz-upload-inspector")
        self._process.start()
        child.close()
        self._conn = parent
        self.started += 1
        return parent

    def _stop(self) -> int | None:
        """Kill the worker (if alive) and return its exit code."""
        process, self._process = self._process, None
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if process is None:
            return None
        if process.is_alive():
            process.kill()
        process.join(10)
        return process.exitcode  # type: ignore[no-any-return]

    def inspect(self, root: Path, base: Path, options: Any = None) -> tuple[list[dict[str, Any]], Any]:
        """:func:`inspect_upload` in the worker: the problems and the report, or one error
        problem when the worker died, ran out of time or failed."""
        with self._lock:
            conn = self._conn if self._conn is not None and self._process.is_alive() else self._start()
            try:
                conn.send((root, base, options))
                ready = conn.poll(self.seconds)
                if not ready:
                    self._stop()
                    return _failed(f"inspecting it took longer than the limit of {self.seconds:g} s; "
                                   "nothing was recorded"), None
                kind, payload = conn.recv()
            except (EOFError, OSError, BrokenPipeError):
                code = self._stop()
                return _failed(f"a reader crashed on a file of this upload (the inspecting process was "
                               f"{_death(code)}; a corrupt compressed file?); nothing was recorded, and the "
                               "server is unaffected"), None
        if kind == "ok":
            return payload  # type: ignore[no-any-return]
        return _failed(str(payload)), None

    def close(self) -> None:
        """Stop the worker."""
        with self._lock:
            self._stop()


def _failed(message: str) -> list[dict[str, Any]]:
    return [{"severity": "error", "file": ".", "line": None, "message": message}]


_shared: dict[tuple[int | None, float | None], UploadInspector] = {}
_shared_lock = threading.Lock()


def inspector(memory: int | None = MEMORY, seconds: float | None = SECONDS) -> UploadInspector:
    """The process's inspector for these limits (one worker serves every app of the process)."""
    with _shared_lock:
        found = _shared.get((memory, seconds))
        if found is None:
            found = _shared[(memory, seconds)] = UploadInspector(memory, seconds)
        return found


__all__ = ["MEMORY", "SECONDS", "UploadInspector", "inspect_upload", "inspector", "relative"]
