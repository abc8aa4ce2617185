"""Coverage of a log replayed in order, decision signatures, and two logs compared as Neves et al. do.

:func:`frame_coverage` replays a log frame by frame through a system's ``step`` under a coverage
recorder (anything with ``record(function, *args) -> (result, Covered)`` and ``last``, such as
:class:`lidarfuzz.structural.python_coverage.CoverageRecorder`) and returns one ``Covered`` per
frame — what segments, heuristics and comparisons take. A step that raises is counted as a
failure; what it covered before raising still counts (a crash reached that code).

:func:`decision_signature` turns a decision (anything with ``steering``, ``speed`` and
``emergency_stop``) into the coarse signature the ``decision_change`` heuristic compares between
frames: the speed state (``stop`` for an emergency stop or a speed below ``stopped`` m/s,
``slow`` below ``cruise`` m/s, else ``cruise``) and the steering's sign (``-1``, ``0`` within
``deadband`` radians of straight, ``+1``).

:func:`compare_logs` gives, per criterion, COV of the base log L' and of the generated log L'', the
coverage of both together, and the aggregated coverage COV_Ag = |NC'' − NC'| / total: what the
generated log reached that the base did not (Section IV).

Example:
    >>> from types import SimpleNamespace
    >>> decision_signature(SimpleNamespace(steering=0.2, speed=8.0, emergency_stop=False))
    ('cruise', 1)
    >>> decision_signature(SimpleNamespace(steering=-0.01, speed=8.0, emergency_stop=True))
    ('stop', 0)
"""

from __future__ import annotations

import shlex
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Protocol

from lidarfuzz.scene.scene import Scene
from lidarfuzz.structural.logs import OrderedLog
from lidarfuzz.structural.requirements import Covered, Kind, Requirement, aggregated, coverage_ratio, of_kind, union


class Recorder(Protocol):
    """What :func:`frame_coverage` needs of a coverage recorder."""

    last: Covered

    def record(self, function: Callable[..., Any], *args: Any) -> tuple[Any, Covered]: ...


@dataclass(frozen=True)
class FrameCoverage:
    """A log's replay: per frame what was covered and what the system returned (``None`` where it raised).

    Attributes:
        covered: One ``Covered`` per frame, in replay order.
        outputs: The step's result per frame.
        failures: Positions of the frames whose step raised, with the error's one-line message.
    """

    covered: list[Covered]
    outputs: list[Any]
    failures: dict[int, str]


def frame_coverage(log: OrderedLog | Iterable[Scene], step: Callable[[Scene], Any], recorder: Recorder, *,
                   reset: Callable[[], Any] | None = None) -> FrameCoverage:
    """Replay ``log`` in order through ``step`` (after ``reset``, when given) under ``recorder``."""
    if reset is not None:
        reset()
    covered: list[Covered] = []
    outputs: list[Any] = []
    failures: dict[int, str] = {}
    for position, frame in enumerate(log):
        try:
            output, mine = recorder.record(step, frame)
        except Exception as exc:  # the system's failure: recorded, the replay goes on
            output, mine = None, recorder.last
            failures[position] = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        covered.append(mine)
        outputs.append(output)
    return FrameCoverage(covered, outputs, failures)


def decision_signature(decision: Any, *, deadband: float = 0.05, stopped: float = 0.1,
                       cruise: float = 5.0) -> tuple[str, int]:
    """``(speed state, steering sign)`` of a decision (see the module docstring); ``("failed", 0)`` for None."""
    if decision is None:
        return "failed", 0
    speed, steering = float(decision.speed), float(decision.steering)
    if decision.emergency_stop or speed < stopped:
        state = "stop"
    elif speed < cruise:
        state = "slow"
    else:
        state = "cruise"
    if abs(steering) <= deadband:
        return state, 0
    return state, 1 if steering > 0 else -1


@dataclass(frozen=True)
class CriterionComparison:
    """One criterion (all-nodes or all-edges) of two logs: ratios over the target's requirements."""

    kind: Kind
    total: int
    base: float
    generated: float
    together: float
    aggregated: float
    new: Covered


def compare_logs(base: Covered | Sequence[Covered], generated: Covered | Sequence[Covered],
                 total: Iterable[Requirement]) -> tuple[CriterionComparison, CriterionComparison]:
    """All-nodes and all-edges of a base log and a generated one (each a ``Covered`` or per-frame ones)."""
    def whole(covered: Covered | Sequence[Covered]) -> Covered:
        return covered if isinstance(covered, frozenset) else union(*covered)

    every = frozenset(total)
    a, b = whole(base), whole(generated)
    rows = []
    kinds: tuple[Kind, Kind] = ("node", "edge")
    for kind in kinds:
        new = (of_kind(b, kind) - of_kind(a, kind)) & of_kind(every, kind)
        rows.append(CriterionComparison(kind, len(of_kind(every, kind)), coverage_ratio(a, every, kind),
                                        coverage_ratio(b, every, kind), coverage_ratio(a | b, every, kind),
                                        aggregated(a, b, every, kind), frozenset(new)))
    return rows[0], rows[1]


def measured_system(spec: str, targets: Iterable[str], *, options: dict[str, Any] | None = None,
                    gcov: str | PathLike[str] | None = None,
                    source_root: str | PathLike[str] | None = None) -> tuple[Any, Any, str]:
    """The sequence system ``spec`` names (with ``options``), the recorder measuring ``targets`` in
    it, and the system's fingerprint. A Python system runs in this process under
    :class:`~lidarfuzz.structural.python_coverage.CoverageRecorder`; a ``worker:`` Python program
    behind :mod:`~lidarfuzz.structural.worker_coverage`'s wrapper, its answers carrying what each
    step covered; with ``gcov`` (a compiled ``worker:`` program's build folder) its gcov data per
    step (:class:`~lidarfuzz.structural.gcov.GcovRecorder`; targets are files or ``file:function``).
    The fingerprint is always the unwrapped system's.

    Raises:
        LidarfuzzError: A ``worker:`` program that is not Python (without ``gcov``), ``gcov`` for a
            system that is no ``worker:``, or a target that does not exist.
        SutSpecError: A spec naming no sequence system.
    """
    from lidarfuzz.errors import LidarfuzzError
    from lidarfuzz.structural.python_coverage import CoverageRecorder
    from lidarfuzz.structural.worker_coverage import WorkerRecorder, wrap_command
    from lidarfuzz.suts.registry import create_sequence

    targets = list(targets)
    options = dict(options or {})
    system = create_sequence(spec, **options)
    fingerprint = system.fingerprint()
    scheme, _, command = spec.strip().partition(":")
    if gcov is not None:
        from lidarfuzz.structural.gcov import GcovRecorder

        if scheme != "worker":
            raise LidarfuzzError(f"--gcov measures a compiled worker: program, not {spec!r}")
        return system, GcovRecorder(system, gcov, source_root if source_root is not None else gcov, targets), \
            fingerprint
    if scheme != "worker":
        return system, CoverageRecorder(targets), fingerprint
    words = [w for w in shlex.split(command) if not Path(w).name.startswith("python")]
    name = Path(words[1] if words[:1] == ["-m"] and len(words) > 1 else words[0]).stem if words else "worker"
    wrapped = create_sequence(f"worker:{wrap_command(command, targets)}", **{"name": name, **options})
    return wrapped, WorkerRecorder(wrapped, targets), fingerprint


__all__ = ["CriterionComparison", "FrameCoverage", "Recorder", "compare_logs", "decision_signature",
           "frame_coverage", "measured_system"]
