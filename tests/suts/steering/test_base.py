"""The steering contract: the answer's JSON, validation (NaN, infinite, out of range), batching."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.base import FailureKind
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.guard import run_guarded
from lidarfuzz.suts.steering.base import DEFAULT_RANGE, Steering, SteeringSystem, checked_range, validate_steering


class Echo(SteeringSystem):
    """Answers the frame's top-left red value / 100 (so a test picks the answer by colouring a pixel)."""

    name = "echo"
    steering_range = (-1.0, 1.0)

    def detect(self, sample: ImageSample) -> Steering:
        return Steering(float(sample.image[0, 0, 0]) / 100.0)


class Fixed(SteeringSystem):
    """Answers whatever it was built with, through detect_batch only."""

    name = "fixed"

    def __init__(self, value: object) -> None:
        self.value = value

    def detect_batch(self, samples):  # type: ignore[no-untyped-def]
        return [Steering(self.value) for _ in samples]  # type: ignore[arg-type]


def frame(red: int) -> ImageSample:
    image = np.zeros((2, 2, 3), np.uint8)
    image[0, 0, 0] = red
    return ImageSample(image, frame_id=f"r{red}")


def test_to_dict_and_from_dict_round_trip() -> None:
    assert Steering(0.25).to_dict() == {"steering": 0.25}
    assert Steering.from_dict({"steering": -3}) == Steering(-3.0)
    assert Steering.from_dict(Steering(0.125).to_dict()) == Steering(0.125)


@pytest.mark.parametrize(("data", "kind", "text"), [
    ({"steering": "left"}, FailureKind.INVALID_OUTPUT, "'steering' must be a number"),
    ({"steering": True}, FailureKind.INVALID_OUTPUT, "'steering' must be a number"),
    ({"angle": 0.1}, FailureKind.INVALID_OUTPUT, "'steering' must be a number, got None"),
    ([0.1], FailureKind.INVALID_OUTPUT, "expected a JSON object, got list"),
    ({"error": "no model"}, FailureKind.CRASH, "reported an error: no model"),
])
def test_from_dict_rejects_what_is_no_answer(data: object, kind: FailureKind, text: str) -> None:
    with pytest.raises(SutError, match=text) as failure:
        Steering.from_dict(data, "w answer")
    assert failure.value.kind is kind


def test_validate_nan_infinite_and_out_of_range() -> None:
    system = Echo()
    assert system.validate(Steering(0.5)) is None
    assert system.validate(Steering(1.0)) is None  # the range is inclusive
    assert system.validate(Steering(float("nan"))) == "steering is not finite (nan)"
    assert system.validate(Steering(float("-inf"))) == "steering is not finite (-inf)"
    assert system.validate(Steering(1.5)) == "steering 1.5 is outside the declared range [-1, 1]"
    assert system.validate(0.5) == "expected a Steering answer, got float"
    # the default range is ±π/2
    assert (-math.pi / 2, math.pi / 2) == DEFAULT_RANGE
    assert validate_steering(Steering(1.6)) is not None and validate_steering(Steering(1.5)) is None


def test_run_guarded_turns_nan_and_out_of_range_into_invalid_output() -> None:
    nan = run_guarded(Fixed(float("nan")), frame(0))
    assert nan.failure is not None and nan.failure.kind is FailureKind.INVALID_OUTPUT
    assert nan.failure.message == "steering is not finite (nan)"
    far = run_guarded(Fixed(2.0), frame(0))  # beyond π/2
    assert far.failure is not None and far.failure.kind is FailureKind.INVALID_OUTPUT
    assert "outside the declared range" in far.failure.message
    ok = run_guarded(Echo(), frame(25))
    assert ok.ok and ok.output == Steering(0.25)


def test_detect_and_detect_batch_answer_through_each_other() -> None:
    frames = [frame(10), frame(40)]
    assert Echo().detect_batch(frames) == [Steering(0.1), Steering(0.4)]
    assert Fixed(0.3).detect(frames[0]) == Steering(0.3)

    class Neither(SteeringSystem):
        name = "neither"

    with pytest.raises(NotImplementedError, match="neither detect nor detect_batch"):
        Neither().detect(frames[0])


def test_checked_range() -> None:
    assert checked_range(None) == DEFAULT_RANGE
    assert checked_range([-0.5, 0.5]) == (-0.5, 0.5)
    for bad in ([0.5, -0.5], [0, float("inf")], [1], "ab"):
        with pytest.raises(ValueError, match="steering_range"):
            checked_range(bad)  # type: ignore[arg-type]
