"""The steering contract of the camera modality: ``detect(ImageSample) -> Steering``.

A steering system maps one camera frame (:class:`~lidarfuzz.scene.image.ImageSample`, RGB
uint8) to one steering angle, in the units of the data set's labels (the built-in world's
front-wheel angle in radians, left positive; the Udacity sets' steering-wheel angle). It is a
:class:`~lidarfuzz.suts.base.SystemUnderTest` like the LiDAR detectors: same identity and
fingerprint, same lifecycle, and failures are results — :func:`lidarfuzz.suts.guard.run_guarded`
turns an exception into a ``crash`` and an answer that fails :meth:`SteeringSystem.validate`
(not a number, NaN, infinite, outside the declared range) into an ``invalid_output``.

Example:
    >>> class Straight(SteeringSystem):
    ...     name = "straight"
    ...     def detect(self, sample: ImageSample) -> Steering:
    ...         return Steering(0.0)
    >>> Straight().validate(Steering(float("nan")))
    'steering is not finite (nan)'
    >>> Steering.from_dict({"steering": 0.25}).to_dict()
    {'steering': 0.25}
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.base import FailureKind, SystemUnderTest
from lidarfuzz.suts.errors import SutError

#: The range of a valid steering angle unless a system declares its own: ±π/2 (radians; wider
#: than any front-wheel angle, and than the Udacity sets' steering-wheel angles of about ±2 rad).
DEFAULT_RANGE = (-math.pi / 2, math.pi / 2)


@dataclass(frozen=True)
class Steering:
    """A steering system's answer on one frame.

    Attributes:
        steering: The angle, in the units of the labels the system was trained on.
    """

    steering: float

    def to_dict(self) -> dict[str, float]:
        """``{"steering": angle}``: the worker protocol's answer, and what results store."""
        return {"steering": self.steering}

    @classmethod
    def from_dict(cls, data: Any, where: str = "answer") -> Steering:
        """A steering answer from its JSON (``{"steering": number}``).

        Raises:
            SutError: ``crash`` for ``{"error": ...}``, ``invalid_output`` for anything else that
                is not an answer (naming the field).
        """
        if not isinstance(data, Mapping):
            raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: expected a JSON object, got {type(data).__name__}")
        if "error" in data:
            raise SutError(FailureKind.CRASH, f"{where}: the system reported an error: {data['error']}")
        value = data.get("steering")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: 'steering' must be a number, got {value!r}")
        return cls(float(value))


def validate_steering(output: Any, steering_range: tuple[float, float] = DEFAULT_RANGE) -> str | None:
    """What is wrong with a steering answer, or None: not a :class:`Steering`, an angle that is
    not a finite number, or one outside ``steering_range`` (inclusive)."""
    if not isinstance(output, Steering):
        return f"expected a Steering answer, got {type(output).__name__}"
    value = output.steering
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"steering must be a number, got {type(value).__name__}"
    if not math.isfinite(value):
        return f"steering is not finite ({value})"
    low, high = steering_range
    if not low <= value <= high:
        return f"steering {value:.6g} is outside the declared range [{low:.6g}, {high:.6g}]"
    return None


class SteeringSystem(SystemUnderTest[ImageSample, Steering]):
    """A system under test that steers from one camera frame. Subclasses implement
    :meth:`detect` or :meth:`detect_batch` (networks batch natively: override the latter and
    :meth:`detect` answers through it).

    Class attributes:
        name: Short name used in reports (instances may override it).
        version: Version of the system.
        steering_range: (low, high) of a valid angle, inclusive; anything else is an invalid
            output (instances may override it).
    """

    modality: ClassVar[str] = "camera"
    classes: ClassVar[tuple[str, ...] | None] = None
    steering_range: ClassVar[tuple[float, float]] = DEFAULT_RANGE

    def detect(self, sample: ImageSample) -> Steering:
        """The steering angle on one frame (default: :meth:`detect_batch` of that frame)."""
        if type(self).detect_batch is SteeringSystem.detect_batch:
            raise NotImplementedError(f"{type(self).__name__} implements neither detect nor detect_batch")
        return self.detect_batch([sample])[0]

    def detect_batch(self, samples: Sequence[ImageSample]) -> list[Steering]:
        """Steering angles on several frames (default: :meth:`detect` of each)."""
        return [self.detect(s) for s in samples]

    def validate(self, output: Any) -> str | None:
        """Not a :class:`Steering`, not finite, or outside :attr:`steering_range`: invalid."""
        return validate_steering(output, self.steering_range)


def checked_range(value: Sequence[float] | None) -> tuple[float, float]:
    """A declared steering range as (low, high), or :data:`DEFAULT_RANGE` for None.

    Raises:
        ValueError: not two finite numbers with low < high (naming ``steering_range``).
    """
    if value is None:
        return DEFAULT_RANGE
    try:
        low, high = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"steering_range must be [low, high], got {value!r}") from None
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise ValueError(f"steering_range must be two finite numbers with low < high, got [{low}, {high}]")
    return low, high
