"""The sequence contract: decisions and their validation, replay's failure handling, the Python and worker
adapters (the worker protocol's reset, end to end through examples/suts/sequence_worker.py), spec strings."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import FailureKind
from lidarfuzz.suts.controller import ObstacleAvoidance
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.registry import SutSpecError, available_sequences, create, create_sequence
from lidarfuzz.suts.sequence import (
    Decision,
    PythonSequence,
    SequenceSystem,
    WorkerSequence,
    replay,
    validate_decision,
)
from lidarfuzz.suts.sequence_guard import IsolatedSequence
from tests.suts.controller_scenes import log

ROOT = Path(__file__).resolve().parents[2]
WORKER = f"{sys.executable} {ROOT / 'examples' / 'suts' / 'sequence_worker.py'}"


def empty_frames(n: int) -> list[Scene]:
    return [Scene(PointCloud(np.zeros((0, 4))), frame_id=f"{i:06d}") for i in range(n)]


class Counter(SequenceSystem):
    """Speed = number of frames seen since the reset; raises on frame ids listed in ``fail``."""

    name = "counter"

    def __init__(self, fail: tuple[str, ...] = (), speed_of: float | None = None) -> None:
        self.fail, self.speed_of = fail, speed_of
        self.seen = 0

    def reset(self) -> None:
        self.seen = 0

    def step(self, frame: Scene) -> Decision:
        self.seen += 1
        if frame.frame_id in self.fail:
            raise RuntimeError(f"lost track at {frame.frame_id}")
        speed = self.speed_of if self.speed_of is not None and frame.frame_id == "000001" else float(self.seen)
        return Decision(steering=0.0, speed=speed)


class DuckController:
    """Not a SequenceSystem: an object with reset and step returning the protocol's dict."""

    def __init__(self, speed: float = 1.0) -> None:
        self.speed, self.steps = speed, 0

    def reset(self) -> None:
        self.steps = 0

    def step(self, frame: Scene) -> dict[str, object]:
        self.steps += 1
        return {"steering": 0.1, "speed": self.speed * self.steps, "emergency_stop": False}


def duck_factory(speed: float = 2.0) -> DuckController:
    return DuckController(speed)


def test_decision_validation_names_what_is_wrong() -> None:
    assert validate_decision(Decision(0.1, 3.0)) is None
    assert "negative" in (validate_decision(Decision(0.0, -0.5)) or "")
    assert "not finite" in (validate_decision(Decision(math.nan, 1.0)) or "")
    assert "not finite" in (validate_decision(Decision(0.0, math.inf)) or "")
    # |0.6| > the limit 0.5
    assert "beyond the limit" in (validate_decision(Decision(-0.6, 1.0), max_steering=0.5) or "")
    assert validate_decision(Decision(-0.5, 1.0), max_steering=0.5) is None
    assert "path" in (validate_decision(Decision(0.0, 1.0, path=((1.0, math.nan),))) or "")
    assert "expected a Decision" in (validate_decision({"steering": 0.0}) or "")


def test_decision_json_round_trip_and_bad_fields() -> None:
    decision = Decision(0.25, 4.0, True, path=((2.0, 0.5), (4.0, 1.0)))
    assert Decision.from_dict(decision.to_dict()) == decision
    with pytest.raises(SutError, match="'speed' must be a number") as bad:
        Decision.from_dict({"steering": 0.0, "speed": "fast"})
    assert bad.value.kind is FailureKind.INVALID_OUTPUT
    with pytest.raises(SutError, match="'emergency_stop' must be true or false"):
        Decision.from_dict({"steering": 0.0, "speed": 1.0, "emergency_stop": "yes"})
    with pytest.raises(SutError, match="reported an error") as crash:
        Decision.from_dict({"error": "no map"})
    assert crash.value.kind is FailureKind.CRASH


def test_replay_resets_steps_in_order_and_goes_on_after_a_crash() -> None:
    system = Counter(fail=("000001",))
    first = replay(system, empty_frames(4))
    # step 1 raised: a crash of that step; its state (seen = 2) carries on, so step 2 answers 3
    assert [r.ok for r in first] == [True, False, True, True]
    assert first[1].failure is not None and first[1].failure.kind is FailureKind.CRASH
    assert "lost track at 000001" in first[1].failure.message
    assert [r.decision.speed for r in first if r.decision is not None] == [1.0, 3.0, 4.0]
    # a second log starts from a reset: 1, 2, 3 again, not 5, 6, 7
    again = replay(Counter(), empty_frames(3))
    assert [r.decision.speed for r in again if r.decision is not None] == [1.0, 2.0, 3.0]
    assert all(r.stepped for r in first)


def test_replay_turns_an_invalid_decision_and_a_late_one_into_failures() -> None:
    results = replay(Counter(speed_of=-1.0), empty_frames(3))
    assert results[1].failure is not None and results[1].failure.kind is FailureKind.INVALID_OUTPUT
    assert "negative" in results[1].failure.message and results[2].ok
    # an in-process step cannot be cut off; one slower than the timeout (0 s) is a timeout, decision discarded
    late = replay(Counter(), empty_frames(2), timeout=0.0)
    assert all(r.failure is not None and r.failure.kind is FailureKind.TIMEOUT and r.decision is None for r in late)


def test_python_adapter_takes_duck_typed_objects_classes_and_factories() -> None:
    wrapped = PythonSequence(DuckController(1.5))
    results = replay(wrapped, empty_frames(2))
    assert [r.decision.speed for r in results if r.decision] == [1.5, 3.0]
    assert wrapped.name == "DuckController" and len(wrapped.fingerprint()) == 16
    made = create_sequence("tests.suts.test_sequence:duck_factory?speed=0.5")
    assert [r.decision.speed for r in replay(made, empty_frames(2)) if r.decision] == [0.5, 1.0]
    assert isinstance(create_sequence("tests.suts.test_sequence:Counter"), Counter)
    with pytest.raises(SutSpecError, match="no step"):
        create_sequence("tests.suts.test_sequence:empty_frames?n=1")
    with pytest.raises(TypeError, match="needs a step"):
        PythonSequence(42)


def test_specs_name_the_controller_and_refuse_the_wrong_kind() -> None:
    assert {"controller", "controller-bug-linear-stop", "controller-bug-sticky-block",
            "controller-bug-left-sector"} <= set(available_sequences())
    controller = create_sequence("controller?cruise_speed=6")
    assert isinstance(controller, ObstacleAvoidance) and controller.settings.cruise_speed == 6
    with pytest.raises(SutSpecError, match="cruise_speed"):
        create_sequence("controller?cruise_speed=-1")
    with pytest.raises(SutSpecError, match="consumes logs in order"):
        create("controller")
    with pytest.raises(SutSpecError, match="not subprocess:"):
        create_sequence("subprocess:./x {points} {output}")
    # identity: configuration is part of the fingerprint
    assert controller.fingerprint() != create_sequence("controller").fingerprint()


def test_worker_protocol_end_to_end_with_a_reset_per_log() -> None:
    frames = log((), (), ((6.0, 6.2, -3.0, 3.0),), (), ())
    expected = replay(ObstacleAvoidance(initial_speed=2.0), frames)
    with create_sequence(f"worker:{WORKER} --option initial_speed=2.0", timeout=30) as worker:
        assert isinstance(worker, WorkerSequence)
        first = replay(worker, frames)
        second = replay(worker, frames)
    # the same decisions as in process; speeds by hand: 2.0 + 0.15 = 2.15, 2.30, then the wall 6 m ahead
    # is beyond the stopping distance 2.3²/8 + 2 = 2.66 m but within slow_enter (15 m): slow, target 3 m/s
    assert [r.decision for r in first] == [r.decision for r in expected]
    assert [round(r.decision.speed, 6) for r in first if r.decision][:2] == [2.15, 2.3]
    # the reset cleared the program's state: the second log repeats the first exactly
    assert [r.decision for r in second] == [r.decision for r in first]


def test_worker_failures_error_goes_on_death_ends_the_log() -> None:
    frames = empty_frames(5)
    with WorkerSequence(f"{WORKER} --fail-on 1:error --fail-on 2:garbage --fail-on 3:crash", timeout=30) as worker:
        results = replay(worker, frames)
        # an error answer is a crash of that step and the program lives on; garbage is an invalid output and
        # the program is stopped (a line that is not the answer may have shifted every later one: the worker
        # protocol restarts it), so steps 3 and 4 are not stepped, with the failure that ended the log
        assert [r.failure.kind if r.failure else None for r in results] == [
            None, FailureKind.CRASH, FailureKind.INVALID_OUTPUT, FailureKind.INVALID_OUTPUT, FailureKind.INVALID_OUTPUT]
        assert [r.stepped for r in results] == [True, True, True, False, False]
        assert results[4].failure is not None and "died at step 2" in results[4].failure.message
        assert not worker.alive
        # the next log starts the program again
        assert [r.ok for r in replay(worker, frames[:1])] == [True]


class Stalling(SequenceSystem):
    """Hangs on frame 000001; otherwise counts frames as its speed."""

    name = "stalling"

    def reset(self) -> None:
        self.seen = 0

    def step(self, frame: Scene) -> Decision:
        self.seen += 1
        if frame.frame_id == "000001":
            time.sleep(60)
        return Decision(0.0, float(self.seen))


def test_an_isolated_python_system_is_cut_off_at_the_timeout() -> None:
    with IsolatedSequence("tests.suts.test_sequence:Stalling") as system:
        assert system.name == "stalling" and len(system.fingerprint()) == 16
        start = time.perf_counter()
        results = replay(system, empty_frames(3), timeout=1.0)
        assert time.perf_counter() - start < 10
        # step 1 hangs: killed after 1 s (timeout), the process and its state are gone: step 2 is not stepped
        assert results[0].ok and results[0].decision is not None and results[0].decision.speed == 1.0
        assert results[1].failure is not None and results[1].failure.kind is FailureKind.TIMEOUT
        assert not results[2].stepped and not system.alive


@pytest.mark.parametrize("name", sorted(available_sequences()))
def test_every_registered_sequence_system_keeps_the_contract(name: str) -> None:
    # deterministic and reset per log, an empty cloud is a decision (blind), inputs left untouched,
    # a stable fingerprint
    frames = [*log((), ((5.0, 5.2, -3.0, 3.0),), ((6.0, 7.0, 1.3, 3.0),)), *empty_frames(1)]
    before = [f.points.data.copy() for f in frames]
    system = create_sequence(f"{name}?initial_speed=8.0")
    first, second = replay(system, frames), replay(system, frames)
    assert all(r.ok for r in first), [r.failure for r in first if r.failure]
    assert [r.decision for r in first] == [r.decision for r in second]
    assert all(np.array_equal(f.points.data, b) for f, b in zip(frames, before, strict=True))
    assert system.fingerprint() == create_sequence(f"{name}?initial_speed=8.0").fingerprint()
