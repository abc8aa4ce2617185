"""A steering program over the worker protocol, end to end through examples/suts/steering_worker.py:
answers worked out by hand, crash, timeout, error and invalid answers as failures."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.base import FailureKind
from lidarfuzz.suts.guard import run_guarded
from lidarfuzz.suts.registry import create_camera
from lidarfuzz.suts.steering.base import Steering
from lidarfuzz.suts.steering.worker import WorkerSteering

ROOT = Path(__file__).resolve().parents[3]
WORKER = f"{sys.executable} {ROOT / 'examples' / 'suts' / 'steering_worker.py'}"


def frame(frame_id: str, right: int = 255) -> ImageSample:
    """4×6: the bottom-right quarter ``right``, the rest 0."""
    image = np.zeros((4, 6, 3), np.uint8)
    image[2:, 3:] = right
    return ImageSample(image, frame_id=frame_id)


@pytest.mark.parametrize("image_format", ["png", "raw"])
def test_answers_match_the_hand_computed_rule(image_format: str) -> None:
    # bottom half: left quarter mean 0, right quarter mean 255 → 0.5 · (255 − 0) / 255 = 0.5;
    # with the right quarter 51: 0.5 · 51 / 255 = 0.1
    with WorkerSteering(WORKER, image_format=image_format, timeout=30) as system:  # type: ignore[arg-type]
        assert system.detect(frame("a")) == Steering(0.5)
        assert system.detect_batch([frame("b", 51), frame("c", 0)]) == [Steering(0.1), Steering(0.0)]


def test_failures_are_results_and_the_program_is_restarted() -> None:
    command = (f"{WORKER} --fail-on crash:crash --fail-on hang:hang --fail-on garbage:garbage "
               "--fail-on error:error --fail-on nan:nan --fail-on huge:huge")
    with WorkerSteering(command, timeout=2) as system:
        crash = run_guarded(system, frame("crash"))
        assert crash.failure is not None and crash.failure.kind is FailureKind.CRASH
        assert "exit code 3" in crash.failure.message and "crashing as asked" in crash.failure.detail
        assert run_guarded(system, frame("after-crash")).output == Steering(0.5)  # restarted
        hang = run_guarded(system, frame("hang"))
        assert hang.failure is not None and hang.failure.kind is FailureKind.TIMEOUT
        assert "no answer within 2 s" in hang.failure.message
        assert run_guarded(system, frame("after-hang")).output == Steering(0.5)
        assert system.restarts == 2
        garbage = run_guarded(system, frame("garbage"))
        assert garbage.failure is not None and garbage.failure.kind is FailureKind.INVALID_OUTPUT
        assert system.restarts == 3  # a line that is not the answer restarts it: later answers stay paired
        error = run_guarded(system, frame("error"))
        assert error.failure is not None and error.failure.kind is FailureKind.CRASH
        assert "failing as asked" in error.failure.message
        nan = run_guarded(system, frame("nan"))
        assert nan.failure is not None and nan.failure.kind is FailureKind.INVALID_OUTPUT
        assert nan.failure.message == "steering is not finite (nan)"
        huge = run_guarded(system, frame("huge"))
        assert huge.failure is not None and huge.failure.kind is FailureKind.INVALID_OUTPUT
        assert "outside the declared range" in huge.failure.message
        assert system.restarts == 3  # answers the program survived (error, NaN, out of range) restart nothing


def test_spec_and_fingerprint() -> None:
    system = create_camera(f"worker:{WORKER} --gain 1", timeout=5, steering_range=[-2, 2])
    assert isinstance(system, WorkerSteering)
    assert system.name == Path(sys.executable).name and system.timeout == 5
    assert system.steering_range == (-2.0, 2.0)
    other = create_camera(f"worker:{WORKER} --gain 2")
    assert system.fingerprint() != other.fingerprint()  # the command is part of the configuration
    assert any("steering_worker.py" in key for key in system.code())  # the script's source is hashed
    with pytest.raises(ValueError, match="image_format"):
        WorkerSteering(WORKER, image_format="jpeg")  # type: ignore[arg-type]
