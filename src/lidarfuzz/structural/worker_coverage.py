"""Code coverage of a Python program served over the worker protocol, per request.

A ``worker:`` system is a program of its own: lidarfuzz's in-process recorder cannot see its
code. This module runs such a program (unchanged) under coverage.py and attributes what it
executes to the request being answered::

    python -m lidarfuzz.structural.worker_coverage --target pkg.mod:Class.method -- program.py [ARGS]

The program reads its requests from standard input and writes one answer line per request, as the
worker protocol says (:mod:`lidarfuzz.suts.external`, :mod:`lidarfuzz.suts.sequence`). The wrapper
stands between it and the real streams: reading a request line opens a unit (a coverage.py dynamic
context), writing the answer line closes it, and the answer — a JSON object; not the ``{"ok":
true}`` to a reset — gains a ``"covered"`` field: the requirements executed in between, as
``[function, kind, source, target]`` rows (:class:`~lidarfuzz.structural.requirements.Requirement`).
Everything else the program writes passes through untouched. :class:`WorkerRecorder` reads the field
back on lidarfuzz's side, so a log replayed through a worker gives the same per-frame coverage as in
process.

Only Python programs can be measured this way; a compiled program is measured from its gcov data
(:mod:`lidarfuzz.structural.gcov`).
"""

from __future__ import annotations

import argparse
import io
import json
import runpy
import shlex
import sys
from collections.abc import Callable, Iterable
from os import PathLike
from pathlib import Path
from typing import Any, TextIO

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.structural.python_coverage import CoverageRecorder
from lidarfuzz.structural.requirements import Covered, Requirement

StrPath = str | PathLike[str]

COVERED = "covered"


class _Requests(io.TextIOBase):
    """The program's standard input: each line read opens a unit of coverage."""

    def __init__(self, stream: TextIO, on_request: Callable[[str], None]) -> None:
        self.stream, self.on_request = stream, on_request

    def readable(self) -> bool:
        return True

    def readline(self, size: int | None = -1) -> str:  # type: ignore[override]
        line = self.stream.readline()
        if line.strip():
            self.on_request(line)
        return line

    def __iter__(self) -> _Requests:  # type: ignore[override]
        return self

    def __next__(self) -> str:  # type: ignore[override]
        line = self.readline()
        if not line:
            raise StopIteration
        return line


class _Answers(io.TextIOBase):
    """The program's standard output: each whole line written closes the unit and carries its coverage."""

    def __init__(self, stream: TextIO, on_answer: Callable[[str], str]) -> None:
        self.stream, self.on_answer = stream, on_answer
        self.pending = ""

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        self.pending += text
        while "\n" in self.pending:
            line, self.pending = self.pending.split("\n", 1)
            self.stream.write(self.on_answer(line) + "\n")
            self.stream.flush()
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


class _Units:
    """Opens a unit per request and closes it into the answer line."""

    def __init__(self, recorder: CoverageRecorder) -> None:
        self.recorder = recorder
        self.open = False
        self.reset = False

    def request(self, line: str) -> None:
        if self.open:
            self.recorder.end()  # a request left unanswered: its coverage has no answer to go in
        try:
            data = json.loads(line)
        except json.JSONDecodeError:
            data = None
        self.reset = isinstance(data, dict) and data.get("reset") is True  # answered {"ok": true}, nothing more
        self.recorder.begin()
        self.open = True

    def answer(self, line: str) -> str:
        if not self.open:
            return line
        covered = self.recorder.end()
        self.open = False
        try:
            data = json.loads(line)
        except json.JSONDecodeError:
            return line  # not an answer lidarfuzz can read anyway: passed on as it is
        if not isinstance(data, dict) or self.reset:
            return line
        data[COVERED] = [[r.function, r.kind, r.source, r.target] for r in sorted(covered)]
        return json.dumps(data)


def covered_from(answer: Any, where: str = "answer") -> Covered:
    """The requirements a wrapped worker's answer carries (empty when it carries none).

    Raises:
        LidarfuzzError: A ``covered`` field that is not a list of ``[function, kind, source, target]``.
    """
    if not isinstance(answer, dict) or COVERED not in answer:
        return frozenset()
    rows = answer[COVERED]
    out = set()
    for row in rows if isinstance(rows, list) else [rows]:
        if not (isinstance(row, list) and len(row) == 4 and isinstance(row[0], str) and row[1] in ("node", "edge")
                and all(isinstance(v, int) and not isinstance(v, bool) for v in row[2:])):
            raise LidarfuzzError(f"{where}: 'covered' must hold [function, kind, source, target] rows, got {row!r}")
        out.add(Requirement(row[0], row[1], row[2], row[3]))
    return frozenset(out)


def wrap_command(command: str, targets: Iterable[str]) -> str:
    """The ``worker:`` command measuring ``command``'s Python code: the wrapper in front of it.

    A leading Python interpreter (``python3 program.py``) is the wrapper's own; ``-m module`` is
    kept. A command that does not run a Python program is refused.

        >>> wrap_command("python3 examples/suts/sequence_worker.py --option a=1", ["m:f"])  # doctest: +ELLIPSIS
        '... -m lidarfuzz.structural.worker_coverage --target m:f -- examples/suts/sequence_worker.py --option a=1'
    """
    argv = shlex.split(command)
    if argv and Path(argv[0]).name.startswith("python"):
        argv = argv[1:]
    if not argv or not (argv[0].endswith(".py") or argv[0] == "-m"):
        raise LidarfuzzError(f"worker {command!r}: only a Python program (a .py file or -m module) can be measured "
                             "with coverage.py; build a compiled one with --coverage and read its gcov data")
    flags = [part for target in targets for part in ("--target", target)]
    return shlex.join([sys.executable, "-m", "lidarfuzz.structural.worker_coverage", *flags, "--", *argv])


class WorkerRecorder:
    """The :class:`~lidarfuzz.structural.log_coverage.Recorder` of a wrapped worker: the coverage
    of a step is what the program's answer carried (``system.last_answer``)."""

    def __init__(self, system: Any, targets: Iterable[str]) -> None:
        from lidarfuzz.structural.python_coverage import CodeModel

        self.system = system
        self.model = CodeModel.of(targets)
        self.last: Covered = frozenset()

    def requirements(self) -> Covered:
        return self.model.requirements()

    def record(self, function: Callable[..., Any], *args: Any) -> tuple[Any, Covered]:
        self.system.last_answer = None
        try:
            result = function(*args)
        finally:
            self.last = covered_from(self.system.last_answer, f"{self.system.name} answer")
        return result, self.last


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m lidarfuzz.structural.worker_coverage",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--target", action="append", required=True, help="code to cover (repeatable)")
    parser.add_argument("program", nargs=argparse.REMAINDER, help="-- program.py [ARGS] or -- -m module [ARGS]")
    args = parser.parse_args(argv)
    program = args.program[1:] if args.program[:1] == ["--"] else args.program
    if not program:
        parser.error("no program given after --")
    units = _Units(CoverageRecorder(args.target))
    sys.stdin = _Requests(sys.__stdin__ or sys.stdin, units.request)  # type: ignore[assignment]
    sys.stdout = _Answers(sys.__stdout__ or sys.stdout, units.answer)  # type: ignore[assignment]
    try:
        if program[0] == "-m":
            sys.argv = program[1:]
            runpy.run_module(program[1], run_name="__main__", alter_sys=True)
        else:
            sys.argv = program
            sys.path.insert(0, str(Path(program[0]).resolve().parent))
            runpy.run_path(program[0], run_name="__main__")
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        sys.stdout.flush()
    return 0


__all__ = ["COVERED", "WorkerRecorder", "covered_from", "main", "wrap_command"]

if __name__ == "__main__":
    sys.exit(main())
