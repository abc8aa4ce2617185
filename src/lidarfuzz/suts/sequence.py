"""Systems that consume logs in order: ``reset()``, then ``step(frame) -> Decision`` for every frame.

The per-frame contract (:class:`~lidarfuzz.suts.base.SystemUnderTest`) maps one sample to
one output and keeps no state. Planners and controllers do keep state — their speed, the
last steering, a hysteresis — so their outputs mean something only on a log replayed in
order. A :class:`SequenceSystem` is reset at the start of each log and stepped frame by
frame; each step answers a :class:`Decision` (steering, speed, emergency stop, optionally
the obstacles it saw and the path it chose).

Identity and failures are the per-frame contract's: a name, a version and a fingerprint of
name, version, configuration and code (:mod:`lidarfuzz.suts.code`); a crash, a timeout or an
invalid decision is a :class:`~lidarfuzz.suts.base.Failure` of that step
(:func:`replay`), never a crash of lidarfuzz.

Adapters: any Python object with ``step`` (and optionally ``reset``, ``load``, ``close``),
named as ``module:callable`` — a :class:`SequenceSystem` subclass, or a class or factory
returning a system — (:class:`PythonSequence`), and programs in any language over the
worker protocol with a reset message (:class:`WorkerSequence`, ``worker:COMMAND``; the
protocol is in :mod:`lidarfuzz.suts.external`). Spec strings are read by
:func:`lidarfuzz.suts.registry.create_sequence`.

Example:
    >>> import numpy as np
    >>> from lidarfuzz.scene.points import PointCloud
    >>> from lidarfuzz.scene.scene import Scene
    >>> class Creep(SequenceSystem):
    ...     name = "creep"
    ...     def reset(self) -> None:
    ...         self.speed = 0.0
    ...     def step(self, frame: Scene) -> Decision:
    ...         self.speed += 1.0
    ...         return Decision(steering=0.0, speed=self.speed)
    >>> frames = [Scene(PointCloud(np.zeros((0, 4))), frame_id=f"{i:06d}") for i in range(3)]
    >>> [r.decision.speed for r in replay(Creep(), frames)]
    [1.0, 2.0, 3.0]
"""

from __future__ import annotations

import json
import math
import time
import traceback
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import Failure, FailureKind, SystemIdentity, validate_detections
from lidarfuzz.suts.code import program_code
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.external import PointsFormat, WorkerSut, parse_response
from lidarfuzz.suts.processes import MAX_ANSWER_BYTES, MEMORY_LIMIT

#: The steering limit (radians) of a decision unless the system declares its own.
MAX_STEERING = math.pi / 2


@dataclass(frozen=True)
class Decision:
    """What a sequence system decided on one frame.

    Attributes:
        steering: Steering angle in radians, left positive (the LiDAR frame's +y side).
        speed: Commanded speed in m/s (≥ 0).
        emergency_stop: True when the system brakes as hard as it can.
        obstacles: The obstacles it saw, as boxes in the frame's LiDAR frame (None: not reported).
        path: The path it chose, ``(x, y)`` points in the LiDAR frame (empty: not reported).
    """

    steering: float
    speed: float
    emergency_stop: bool = False
    obstacles: Boxes3D | None = None
    path: tuple[tuple[float, float], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The decision as the worker protocol's JSON (obstacles as a ``detections`` list)."""
        out: dict[str, Any] = {"steering": self.steering, "speed": self.speed, "emergency_stop": self.emergency_stop}
        if self.obstacles is not None:
            boxes = self.obstacles
            out["obstacles"] = [{"label": str(label), "box": [float(v) for v in row], "score": float(score)}
                                for row, label, score in zip(boxes.as_array(), boxes.labels, boxes.scores,
                                                             strict=True)]
        if self.path:
            out["path"] = [[float(x), float(y)] for x, y in self.path]
        return out

    @classmethod
    def from_dict(cls, data: Any, where: str = "decision") -> Decision:
        """A decision from the protocol's JSON (``steering``, ``speed``, optionally
        ``emergency_stop``, ``obstacles``, ``path``).

        Raises:
            SutError: ``crash`` for ``{"error": ...}``, ``invalid_output`` for anything else
                that is not a decision, naming the field.
        """
        if not isinstance(data, Mapping):
            raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: expected a JSON object, got {type(data).__name__}")
        if "error" in data:
            raise SutError(FailureKind.CRASH, f"{where}: the system reported an error: {data['error']}")
        values: dict[str, float] = {}
        for key in ("steering", "speed"):
            value = data.get(key)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: '{key}' must be a number, got {value!r}")
            values[key] = float(value)
        stop = data.get("emergency_stop", False)
        if not isinstance(stop, bool):
            raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: 'emergency_stop' must be true or false, got {stop!r}")
        obstacles = None
        if data.get("obstacles") is not None:
            obstacles = parse_response({"detections": data["obstacles"]}, None, f"{where} 'obstacles'")
        path: list[tuple[float, float]] = []
        for point in data.get("path") or []:
            if not (isinstance(point, Sequence) and len(point) == 2
                    and all(isinstance(v, int | float) and not isinstance(v, bool) for v in point)):
                raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: 'path' must be [[x, y], ...], got {point!r}")
            path.append((float(point[0]), float(point[1])))
        return cls(values["steering"], values["speed"], stop, obstacles, tuple(path))


def validate_decision(decision: Any, max_steering: float = MAX_STEERING) -> str | None:
    """What is wrong with a decision, or None: wrong type, a number that is not finite, a
    negative speed, a steering beyond ``max_steering``, invalid obstacle boxes or path."""
    if not isinstance(decision, Decision):
        return f"expected a Decision, got {type(decision).__name__}"
    if not math.isfinite(decision.steering):
        return f"steering is not finite ({decision.steering})"
    if not math.isfinite(decision.speed):
        return f"speed is not finite ({decision.speed})"
    if decision.speed < 0:
        return f"speed {decision.speed:g} m/s is negative"
    if abs(decision.steering) > max_steering:
        return f"steering {decision.steering:.4g} rad is beyond the limit of ±{max_steering:.4g} rad"
    if not isinstance(decision.emergency_stop, bool):
        return f"emergency_stop must be a bool, got {type(decision.emergency_stop).__name__}"
    if decision.obstacles is not None:
        problem = validate_detections(decision.obstacles, None)
        if problem is not None:
            return f"obstacles: {problem}"
    if decision.path and not np.all(np.isfinite(np.asarray(decision.path, dtype=np.float64))):
        return "path has a point that is not finite"
    return None


class SequenceSystem(SystemIdentity, ABC):
    """A system under test that consumes a log in order. Subclasses implement :meth:`reset`
    and :meth:`step`; identity (:class:`~lidarfuzz.suts.base.SystemIdentity`: name, version,
    configuration, weights, code, fingerprint) and lifecycle have the per-frame contract's defaults.

    Class attributes:
        name: Short name used in reports (instances may override it).
        version: Version of the system (bump it when its behaviour changes).
        max_steering: Largest steering magnitude (rad) a valid decision may have.
    """

    name: ClassVar[str] = "sequence"
    version: ClassVar[str] = "0"
    max_steering: ClassVar[float] = MAX_STEERING

    @property
    def alive(self) -> bool:
        """False once the system can no longer continue this log (its program died or was killed,
        losing its state); :meth:`reset` brings it back for the next log."""
        return True

    def set_timeout(self, seconds: float) -> None:
        """Cut a step off after ``seconds`` (systems in another process; in-process systems cannot
        be interrupted, :func:`replay` discards their late decisions instead)."""

    def load(self) -> None:
        """Acquire resources. Called once before the first log."""

    def close(self) -> None:
        """Release them."""

    @abstractmethod
    def reset(self) -> None:
        """Clear every state carried between frames; called at the start of each log."""

    @abstractmethod
    def step(self, frame: Scene) -> Decision:
        """The decision on the next frame of the log."""

    def validate(self, decision: Any) -> str | None:
        """A description of what is wrong with a decision, or None when it is valid."""
        return validate_decision(decision, self.max_steering)

    def __enter__(self) -> SequenceSystem:
        self.load()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} v{self.version}>"


@dataclass(frozen=True)
class StepResult:
    """The outcome of one step of a replay.

    Attributes:
        index: Position of the frame in the log.
        frame_id: The frame's id.
        decision: The decision, or None when the step failed.
        failure: Why there is no decision.
        seconds: Wall time of the step.
        stepped: False when the frame was never given to the system (it had died, or its reset
            failed, before this frame).
    """

    index: int
    frame_id: str
    decision: Decision | None
    failure: Failure | None
    seconds: float
    stepped: bool = True

    @property
    def ok(self) -> bool:
        return self.failure is None


def failure_of(exc: BaseException) -> Failure:
    """The failure an exception of the system stands for (a :class:`SutError` keeps its kind)."""
    if isinstance(exc, SutError):
        return exc.failure()
    message = f"{type(exc).__name__}: {exc}".splitlines()[0][:500]
    return Failure(FailureKind.CRASH, message, "".join(traceback.format_exception(exc))[-8000:])


def step_guarded(system: SequenceSystem, frame: Scene, index: int = 0, timeout: float | None = None) -> StepResult:
    """One step that never raises for a failure of the system itself (as
    :func:`lidarfuzz.suts.guard.run_guarded` for one detection): an exception is a ``crash``, a
    :class:`SutError` keeps its kind, a step longer than ``timeout`` a ``timeout`` (its decision
    discarded), a decision failing :meth:`SequenceSystem.validate` an ``invalid_output``."""
    start = time.perf_counter()
    try:
        decision = system.step(frame)
    except Exception as exc:  # the system under test's failure is a result
        return StepResult(index, frame.frame_id, None, failure_of(exc), time.perf_counter() - start)
    elapsed = time.perf_counter() - start
    if timeout is not None and elapsed > timeout:
        failure = Failure(FailureKind.TIMEOUT, f"step took {elapsed:.3g} s, over the limit of {timeout:g} s")
        return StepResult(index, frame.frame_id, None, failure, elapsed)
    problem = system.validate(decision)
    if problem is not None:
        return StepResult(index, frame.frame_id, None, Failure(FailureKind.INVALID_OUTPUT, problem), elapsed)
    return StepResult(index, frame.frame_id, decision, None, elapsed)


def replay(system: SequenceSystem, frames: Iterable[Scene], *, timeout: float | None = None) -> list[StepResult]:
    """Reset the system, then step it through every frame in order; one result per frame.

    Failures are per step, as the per-frame guard makes them: an exception is a ``crash`` of that
    step, a wrong decision an ``invalid_output``, a step over ``timeout`` seconds a ``timeout``.
    What was chosen for the steps after a failure:

    * the log **goes on** after a failure the system survives (an exception in ``step``, an
      ``{"error": …}`` or garbage answer from a program that is still running): the system keeps
      whatever state the failed step left, as a controller that threw on one frame would on the
      vehicle, and the next frame is stepped;
    * the log **stops** when the system is dead (:attr:`SequenceSystem.alive` is False: its
      program exited, or was killed for a timeout): its state is lost, so decisions on the rest of
      the log would answer another log than the one replayed. Each remaining frame gets a result
      with ``stepped=False`` and the failure that ended the log;
    * a reset that fails leaves every frame unstepped with the reset's failure.

    ``timeout`` is passed to systems in another process (:meth:`SequenceSystem.set_timeout`, which
    kill a hung program: :class:`WorkerSequence`, and any system hosted by
    :class:`~lidarfuzz.suts.sequence_guard.IsolatedSequence`); in-process systems cannot be
    interrupted, so a step that returns late is a ``timeout`` with its decision discarded (a
    decision that comes too late is no decision).
    """
    if timeout is not None:
        system.set_timeout(timeout)
    results: list[StepResult] = []
    ended: Failure | None = None
    try:
        system.reset()
    except Exception as exc:  # a reset that fails is the system's failure too
        failure = failure_of(exc)
        ended = Failure(failure.kind, f"not stepped: the reset failed: {failure.message}", failure.detail)
    for index, frame in enumerate(frames):
        if ended is not None:
            results.append(StepResult(index, frame.frame_id, None, ended, 0.0, stepped=False))
            continue
        result = step_guarded(system, frame, index, timeout)
        results.append(result)
        if result.failure is not None and not system.alive:
            ended = Failure(result.failure.kind, f"not stepped: the system died at step {index} "
                                                 f"({result.failure.message})")
    return results


# -- adapters -------------------------------------------------------------------------------

class PythonSequence(SequenceSystem):
    """Any Python object with ``step(frame)`` (and optionally ``reset``, ``load``, ``close``) as a
    sequence system. ``step`` may return a :class:`Decision` or its JSON-like dict
    (:meth:`Decision.from_dict`).

    Args:
        target: The object (a plain function is taken as a stateless ``step``).
        name: Report name (default: the object's class or function name).
        version: Its version (part of the fingerprint).
        max_steering: Steering limit of a valid decision (rad).
        config: Extra JSON-able configuration for the fingerprint.
    """

    def __init__(self, target: Any, *, name: str | None = None, version: str = "0",
                 max_steering: float = MAX_STEERING, config: Mapping[str, Any] | None = None) -> None:
        step = getattr(target, "step", None)
        if not callable(step):
            if isinstance(target, type) or not callable(target):
                raise TypeError(f"{target!r} is not a sequence system: it needs a step(frame) method")
            step = target
        self.target = target
        self._step: Callable[[Scene], Any] = step
        default = getattr(target, "__qualname__", None) or type(target).__name__
        self.name = name or str(default)  # type: ignore[misc]
        self.version = version  # type: ignore[misc]
        self.max_steering = max_steering  # type: ignore[misc]
        self._config = dict(config or {})

    def config(self) -> dict[str, Any]:
        kind = self.target if callable(self.target) and not hasattr(self.target, "step") else type(self.target)
        return {"target": f"{kind.__module__}:{kind.__qualname__}", **self._config}

    def code_objects(self) -> tuple[Any, ...]:
        return type(self), self.target

    def load(self) -> None:
        loader = getattr(self.target, "load", None)
        if callable(loader):
            loader()

    def close(self) -> None:
        closer = getattr(self.target, "close", None)
        if callable(closer):
            closer()

    def reset(self) -> None:
        resetter = getattr(self.target, "reset", None)
        if callable(resetter):
            resetter()

    def step(self, frame: Scene) -> Decision:
        output = self._step(frame)
        if isinstance(output, Decision):
            return output
        return Decision.from_dict(output, f"{self.name} decision")


class WorkerSequence(SequenceSystem):
    """A program in any language serving a log over the worker protocol with resets
    (:mod:`lidarfuzz.suts.external`): ``{"reset": true}`` before each log, one frame request per
    step, a decision JSON per answer.

    Args:
        command: The command line (no placeholders).
        name: Report name (default: the program's file name).
        version: Its version.
        timeout: Seconds per step (and per reset).
        points_format: ``bin`` or ``pcd``.
        max_steering: Steering limit of a valid decision (rad).
        cwd: Working directory.
        memory_limit, cpu_limit, max_answer_bytes: The program's limits, as for
            :class:`~lidarfuzz.suts.external.WorkerSut`.
    """

    def __init__(self, command: str, *, name: str | None = None, version: str = "0", timeout: float = 60.0,
                 points_format: PointsFormat = "bin", max_steering: float = MAX_STEERING,
                 cwd: str | None = None, memory_limit: int | str | None = MEMORY_LIMIT,
                 cpu_limit: float | None = None, max_answer_bytes: int | str = MAX_ANSWER_BYTES) -> None:
        self.worker = WorkerSut(command, name=name, version=version, timeout=timeout, points_format=points_format,
                                cwd=cwd, memory_limit=memory_limit, cpu_limit=cpu_limit,
                                max_answer_bytes=max_answer_bytes)
        self.name = self.worker.name  # type: ignore[misc]
        self.version = version  # type: ignore[misc]
        self.max_steering = max_steering  # type: ignore[misc]
        self._index = 0
        self.last_answer: Any = None  # the program's last answer as read (extra fields kept, e.g. coverage)
        self.request_extra: dict[str, Any] = {}  # fields sent with every request and reset (e.g. gcov_dump)

    def config(self) -> dict[str, Any]:
        return {**self.worker.config(), "max_steering": self.max_steering}

    def code(self) -> dict[str, str]:
        """The adapter's Python code, the program's executable and every file its arguments name."""
        return {**super().code(), **program_code(self.worker.argv, self.worker.cwd)}

    @property
    def alive(self) -> bool:
        return self.worker.running

    def set_timeout(self, seconds: float) -> None:
        self.worker.timeout = seconds

    def load(self) -> None:
        self.worker.load()

    def close(self) -> None:
        self.worker.close()

    def reset(self) -> None:
        """Start the program if it is not running, then send it the reset message."""
        self._index = 0
        self.worker.reset_state(self.request_extra)

    def step(self, frame: Scene) -> Decision:
        request = {**self.worker.frame_request(frame), **self.request_extra, "index": self._index,
                   "timestamp": frame.timestamp,
                   "metadata": json.loads(json.dumps(dict(frame.metadata), default=str))}
        self._index += 1
        self.last_answer = self.worker.exchange(request)
        return Decision.from_dict(self.last_answer, f"{self.name} answer")
