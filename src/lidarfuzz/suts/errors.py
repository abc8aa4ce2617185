"""The exception adapters raise when the system under test failed in a known way.

It lives below both the adapters that raise it (:mod:`lidarfuzz.suts.external`) and
the guard that turns it into a :class:`~lidarfuzz.suts.base.Failure`
(:mod:`lidarfuzz.suts.guard`), so that neither imports the other.
"""

from __future__ import annotations

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.suts.base import Failure, FailureKind


class SutError(LidarfuzzError):
    """Raised by adapters when the system under test failed in a known way."""

    def __init__(self, kind: FailureKind, message: str, detail: str = "") -> None:
        super().__init__(message)
        self.kind = kind
        self.message = message
        self.detail = detail

    def failure(self) -> Failure:
        return Failure(self.kind, self.message, self.detail)
