"""All-nodes and all-edges of compiled programs, from gcov data read by gcovr.

A program built with ``--coverage`` (gcc or clang: ``gcc --coverage -O0 -o prog prog.c``)
writes a ``.gcno`` file (its control-flow graph) when compiled and adds its counts to a
``.gcda`` file when it exits normally. gcovr turns them into JSON (``gcovr --json``): per
source line its function, execution count and branch outcomes. That JSON names no block
and no branch destination (gcc before 14 writes neither), so the two criteria are mapped onto
what it does give:

* **node** — an executable line of a function (gcov's unit of execution), covered when its
  count is above zero. ``Requirement(function, "node", line)``.
* **edge** — one outcome of a conditional branch on a line (gcov's ``branch n``: taken or fall
  through, a ``switch`` case, an exception path in C++), covered when it was taken.
  ``Requirement(function, "edge", line, n + 1)``: for compiled code the target is gcov's branch
  number plus one, not a line, because gcov does not say where the outcome leads.

``function`` is ``file:function`` with the file relative to the source root. Unconditional
jumps have no outcome to count, so a straight-line function has nodes and no edge.

Counts accumulate over runs until the ``.gcda`` files are removed (:func:`reset`), and a
program writes them only at exit: coverage per frame of a compiled system means one run (or
one worker session) per frame; coverage per log, one session per log.

Example (a program built with ``--coverage`` in ``build/`` from sources in ``src/``)::

    reset("build")
    ...  # run the program through its worker protocol, then close it
    total, covered = collect("build", "src")
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from collections.abc import Callable, Sequence
from os import PathLike
from pathlib import Path
from typing import Any

from lidarfuzz.errors import LidarfuzzError, MissingDependencyError
from lidarfuzz.structural.requirements import Covered, Requirement

StrPath = str | PathLike[str]


def _gcovr_json(build_dir: Path, source_root: Path, gcov: str | None) -> dict[str, Any]:
    if importlib.util.find_spec("gcovr") is None:
        raise MissingDependencyError("gcovr", "gcov", "Code coverage of compiled systems")
    command = [sys.executable, "-m", "gcovr", "--json", "-", "--root", str(source_root), str(build_dir)]
    if gcov:
        command[4:4] = ["--gcov-executable", gcov]
    result = subprocess.run(command, capture_output=True, text=True, cwd=build_dir)
    if result.returncode != 0:
        last = (result.stderr.strip().splitlines() or ["no message"])[-1]
        raise LidarfuzzError(f"{build_dir}: gcovr failed (exit {result.returncode}): {last}")
    data: dict[str, Any] = json.loads(result.stdout)
    return data


def requirements_from_report(report: dict[str, Any]) -> tuple[Covered, Covered]:
    """``(every requirement, those covered)`` of a gcovr JSON report (the mapping in the module docstring)."""
    total: set[Requirement] = set()
    covered: set[Requirement] = set()
    for source in report.get("files", []):
        for line in source.get("lines", []):
            name = line.get("function_name")
            if name is None:
                continue  # a line outside any function (a global's initialiser)
            function = f"{source['file']}:{name}"
            number = int(line["line_number"])
            node = Requirement(function, "node", number)
            total.add(node)
            if line.get("count", 0) > 0:
                covered.add(node)
            for branch in line.get("branches", []):
                edge = Requirement(function, "edge", number, int(branch["branchno"]) + 1)
                total.add(edge)
                if branch.get("count", 0) > 0:
                    covered.add(edge)
    return frozenset(total), frozenset(covered)


def gcda_files(build_dir: StrPath) -> list[Path]:
    """The gcov count files under a build folder."""
    return sorted(Path(build_dir).rglob("*.gcda"))


def reset(build_dir: StrPath) -> int:
    """Remove the ``.gcda`` files (start counting from zero); how many were removed."""
    files = gcda_files(build_dir)
    for path in files:
        path.unlink()
    return len(files)


def requirements(build_dir: StrPath, source_root: StrPath, *, gcov: str | None = None) -> Covered:
    """Every node and edge of a program built with ``--coverage`` (its ``.gcno`` files; no run needed)."""
    build, root = Path(build_dir), Path(source_root)
    if not any(build.rglob("*.gcno")):
        raise LidarfuzzError(f"{build}: no gcov notes (.gcno): build the program with --coverage")
    return requirements_from_report(_gcovr_json(build, root, gcov))[0]


def collect(build_dir: StrPath, source_root: StrPath, *, gcov: str | None = None) -> tuple[Covered, Covered]:
    """``(every requirement, those covered)`` by the runs since the last :func:`reset`.

    Args:
        build_dir: Where the program was built (its ``.gcno`` and ``.gcda`` files).
        source_root: The sources' root: only files under it count, named relative to it.
        gcov: The gcov program matching the compiler (e.g. ``llvm-cov gcov`` for clang).
    """
    build, root = Path(build_dir), Path(source_root)
    if not build.is_dir():
        raise LidarfuzzError(f"{build}: no such build folder")
    if not gcda_files(build):
        raise LidarfuzzError(f"{build}: no gcov data (.gcda): build the program with --coverage and let it "
                             "exit normally after a run before collecting")
    total, covered = requirements_from_report(_gcovr_json(build, root, gcov))
    if not total:
        raise LidarfuzzError(f"{build}: gcov data names no source file under {root}")
    return total, covered


def selected(requirements: Covered, targets: Sequence[str]) -> Covered:
    """The requirements of the targets: ``file`` (every function of a source file, relative to the
    source root) or ``file:function``; all of them when there is no target.

        >>> r = [Requirement("a.c:f", "node", 3), Requirement("a.c:g", "node", 9), Requirement("b.c:f", "node", 1)]
        >>> sorted(x.function for x in selected(frozenset(r), ["a.c:g", "b.c"]))
        ['a.c:g', 'b.c:f']
    """
    if not targets:
        return requirements
    return frozenset(r for r in requirements
                     if any(r.function == t or r.function.startswith(f"{t}:") for t in targets))


class GcovRecorder:
    """The per-step recorder (:class:`~lidarfuzz.structural.log_coverage.Recorder`) of a compiled
    program served over the worker protocol and built with ``--coverage``.

    Every request (and reset) carries ``"gcov_dump": true``; the program answers it only after
    writing its counts and clearing them (``__gcov_dump(); __gcov_reset();`` — as
    ``examples/suts/c_controller/controller.c`` does when built with ``-DLIDARFUZZ_GCOV``; a weak
    declaration of ``__gcov_dump`` would not pull it from the static libgcov). Before each step the ``.gcda`` files are
    removed, so what gcovr reads after the answer is that step's alone.

    Args:
        system: The :class:`~lidarfuzz.suts.sequence.WorkerSequence` running the program.
        build_dir: Where the program was built (its ``.gcno``; the ``.gcda`` appear there).
        source_root: The sources' root (requirements are named relative to it).
        targets: ``file`` or ``file:function`` names to keep (all when empty).
        gcov: The gcov program matching the compiler.

    Raises:
        LidarfuzzError: No ``.gcno`` under ``build_dir``, or a target naming nothing.
    """

    def __init__(self, system: Any, build_dir: StrPath, source_root: StrPath, targets: Sequence[str] = (),
                 *, gcov: str | None = None) -> None:
        self.system, self.build, self.root, self.gcov = system, Path(build_dir), Path(source_root), gcov
        self.targets = list(targets)
        self.total = selected(requirements(self.build, self.root, gcov=gcov), self.targets)
        if not self.total:
            raise LidarfuzzError(f"{self.build}: no function of {', '.join(self.targets)} in the gcov notes "
                                 f"(targets are file or file:function names relative to {self.root})")
        system.request_extra = {**getattr(system, "request_extra", {}), "gcov_dump": True}
        self.last: Covered = frozenset()

    def requirements(self) -> Covered:
        return self.total

    def record(self, function: Callable[..., Any], *args: Any) -> tuple[Any, Covered]:
        reset(self.build)
        try:
            result = function(*args)
        finally:
            if gcda_files(self.build):
                self.last = selected(collect(self.build, self.root, gcov=self.gcov)[1], self.targets)
            else:
                self.last = frozenset()
        if not self.last and not gcda_files(self.build):
            raise LidarfuzzError(f"{self.build}: the program wrote no gcov data for this step: build it with "
                                 "--coverage and have it call __gcov_dump() before answering a request with "
                                 '"gcov_dump": true (docs/structural.md)')
        return result, self.last


__all__ = ["GcovRecorder", "collect", "gcda_files", "requirements", "requirements_from_report", "reset", "selected"]
