"""The system-under-test contract: ``detect(sample) -> output``, a lifecycle, an identity.

A system under test (SUT) is anything lidarfuzz runs on originals and mutants: a learned
3D detector, an ONNX export, a whole perception stack behind a subprocess. Nothing here
assumes LiDAR: a SUT maps a sample to an output. For 3D detection the output is a
:class:`~lidarfuzz.scene.boxes.Boxes3D` in the sample's LiDAR frame (centre origin,
``[x, y, z, l, w, h, yaw]``) with a class and a score per box; conventions of other
tools are converted at the edge (:mod:`lidarfuzz.suts.conventions`).

Identity: ``name``, ``version`` and a ``fingerprint`` — a hash of the name, version,
configuration, weight files and code (:mod:`lidarfuzz.suts.code`) — so that outputs on
unchanged inputs can be cached and a result always says exactly which system produced it.

Failures are results, not crashes of lidarfuzz: :mod:`lidarfuzz.suts.guard` turns an
exception, a dead process, a hang or an invalid output into a :class:`Failure`.
"""

from __future__ import annotations

import enum
import hashlib
import json
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np

from lidarfuzz.scene.boxes import Boxes3D

S = TypeVar("S")
O = TypeVar("O")  # noqa: E741 - the output type


class FailureKind(enum.StrEnum):
    CRASH = "crash"
    TIMEOUT = "timeout"
    INVALID_OUTPUT = "invalid_output"


@dataclass(frozen=True)
class Failure:
    """Why a SUT produced no usable output on one sample.

    Attributes:
        kind: crash (exception, non-zero exit, killed process), timeout, or invalid_output.
        message: One line for tables.
        detail: Traceback, stderr tail or the offending values.
    """

    kind: FailureKind
    message: str
    detail: str = ""

    def to_dict(self) -> dict[str, str]:
        return {"kind": self.kind.value, "message": self.message, "detail": self.detail}


@dataclass(frozen=True)
class SutResult(Generic[O]):
    """The outcome of one call: an output or a failure, and the wall time it took."""

    output: O | None
    failure: Failure | None
    seconds: float

    @property
    def ok(self) -> bool:
        return self.failure is None


def hash_files(paths: Sequence[str | Path]) -> list[str]:
    """SHA-256 of each file (1 MiB at a time)."""
    out = []
    for path in paths:
        digest = hashlib.sha256()
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
        out.append(digest.hexdigest())
    return out


class SystemIdentity:
    """What identifies a system under test, per-frame or sequence: ``name``, ``version``, its
    configuration, weight files and code, and the ``fingerprint`` hashing them.

    Class attributes:
        name: Short name used in reports (instances may override it).
        version: Version of the system (bump it when its behaviour changes).
    """

    name: ClassVar[str] = "sut"
    version: ClassVar[str] = "0"

    def config(self) -> Mapping[str, Any]:
        """JSON-able configuration; part of the fingerprint."""
        return {}

    def weight_files(self) -> Sequence[Path]:
        """Files whose content determines the output (weights, models); hashed into the fingerprint."""
        return ()

    def code_objects(self) -> Sequence[Any]:
        """The Python classes, functions or modules whose source computes the output (default:
        the system's class, its base classes with it); their code is part of the fingerprint."""
        return (type(self),)

    def code(self) -> Mapping[str, str]:
        """What identifies the code behind the output: ``{module, file or distribution: digest or
        version}`` by the rule of :mod:`lidarfuzz.suts.code` (programs add their executable and
        script files)."""
        from lidarfuzz.suts.code import python_code

        return python_code(self.code_objects())

    def fingerprint(self) -> str:
        """A stable hash of name, version, configuration, weight files and code (hex, 16 chars).

        The code is :meth:`code`: for a Python system, the source files of the modules defining
        its class and base classes (every ``.py`` file of the package for lidarfuzz's own
        systems, e.g. all of ``lidarfuzz/suts/`` for the classic pipeline and its bug zoo), the
        version of a third-party distribution they come from; for a program, its executable
        and script files. A system whose code changed has another fingerprint even when its
        name and version did not, so a campaign never serves it the old code's cached outputs.
        """
        payload = {
            "name": self.name,
            "version": self.version,
            "config": self.config(),
            "weights": hash_files(self.weight_files()),
            "code": dict(self.code()),
        }
        text = json.dumps(payload, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


class SystemUnderTest(SystemIdentity, ABC, Generic[S, O]):
    """A system under test. Subclasses implement :meth:`detect`; the rest has defaults.

    Class attributes:
        name: Short name used in reports (instances may override it).
        version: Version of the system (bump it when its behaviour changes).
        classes: The output classes it may emit; anything else is an invalid output.
            None accepts any class.
    """

    classes: ClassVar[tuple[str, ...] | None] = ("Car", "Pedestrian", "Cyclist")

    def profile_dirs(self) -> Sequence[Path]:
        """Read-only folders holding training profiles of the system's network (neuron coverage
        criteria that need one look there after the cache), e.g. the folder its weights ship in."""
        return ()

    def load(self) -> None:
        """Acquire resources (weights, processes). Called once before the first sample."""

    def close(self) -> None:
        """Release them. The SUT may be loaded again afterwards."""

    @abstractmethod
    def detect(self, sample: S) -> O:
        """The system's output on one sample."""

    def detect_batch(self, samples: Sequence[S]) -> list[O]:
        """Outputs on several samples (override when the system batches natively)."""
        return [self.detect(s) for s in samples]

    def validate(self, output: O) -> str | None:
        """A description of what is wrong with an output, or None when it is valid."""
        if isinstance(output, Boxes3D):
            return validate_detections(output, self.classes)
        return None

    def __enter__(self) -> SystemUnderTest[S, O]:
        self.load()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} v{self.version}>"


def validate_detections(boxes: Any, classes: Sequence[str] | None) -> str | None:
    """Problems of a detection output: wrong type, NaN or infinite values, sizes not
    positive, missing or non-finite scores, unknown classes."""
    if not isinstance(boxes, Boxes3D):
        return f"expected Boxes3D detections, got {type(boxes).__name__}"
    if len(boxes) == 0:
        return None
    geometry = boxes.as_array()
    bad = ~np.all(np.isfinite(geometry), axis=1)
    if bad.any():
        return f"{int(bad.sum())} box(es) with NaN or infinite geometry (first: #{int(np.argmax(bad))})"
    small = ~np.all(boxes.sizes > 0, axis=1)
    if small.any():
        i = int(np.argmax(small))
        return f"{int(small.sum())} box(es) with a size <= 0 (first: #{i}, size {boxes.sizes[i].tolist()})"
    if not np.all(np.isfinite(boxes.scores)):
        return "every detection needs a finite score"
    if classes is not None:
        unknown = sorted(set(boxes.labels.astype(str).tolist()) - set(classes))
        if unknown:
            return f"unknown class(es) {unknown}; expected one of {list(classes)}"
    return None
