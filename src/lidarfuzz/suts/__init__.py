"""Systems under test: the contract, spec strings, adapters, and the built-in pipelines."""

from lidarfuzz.suts.base import Failure, FailureKind, SutResult, SystemUnderTest, validate_detections
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.guard import IsolatedSut, run_guarded
from lidarfuzz.suts.registry import available, create

__all__ = [
    "Failure",
    "FailureKind",
    "IsolatedSut",
    "SutError",
    "SutResult",
    "SystemUnderTest",
    "available",
    "create",
    "run_guarded",
    "validate_detections",
]
