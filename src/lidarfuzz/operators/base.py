"""The operator contract: configuration, concrete parameters, sampling, pure application.

An operator turns one sample (a LiDAR :class:`~lidarfuzz.scene.scene.Scene` for the
built-in ones; nothing here assumes LiDAR) into a test case. Three frozen pieces:

* ``Config`` — how concrete parameters are drawn: fixed values and ``*_range``
  intervals. ``Operator.at_severity(s)`` builds the documented config of severity
  ``s`` (0 is the identity, 1–5 increasingly strong); ``Operator(**fields)`` any other,
  for fuzzing with free continuous parameters.
* ``Params`` — concrete, JSON-able values drawn by :meth:`Operator.sample` from a
  ``numpy.random.Generator``; randomness that acts per point (which points are
  deleted, where noise lands) is carried as an integer ``seed`` inside the params,
  so :meth:`Operator.apply` is a pure function of (sample, params) and every mutant
  replays exactly from its stored params.
* the operator itself: a name (and aliases), a family, the ``targets`` it changes,
  and the metamorphic ``relation`` it supports — *invariant* (a correct detector
  finds the same objects), *equivariant* (detections follow the transform T the
  operator exposes through :meth:`Operator.transform`), or *degrading* (accuracy may
  drop; only a bound applies).

Randomness comes only from generators derived with :func:`seed_sequence`; there is no
global RNG anywhere.
"""

from __future__ import annotations

import enum
import zlib
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict

S = TypeVar("S")


class Relation(enum.StrEnum):
    """What a correct system under test should do on an operator's output."""

    INVARIANT = "invariant"
    EQUIVARIANT = "equivariant"
    DEGRADING = "degrading"


class Target(enum.StrEnum):
    """Parts of a sample an operator may change."""

    POINTS = "points"
    BOXES = "boxes"
    CALIB = "calib"
    MAP = "map"


class Config(BaseModel):
    """Base of operator configurations (frozen; unknown keys are errors)."""

    model_config = ConfigDict(frozen=True, extra="forbid")


class Params(BaseModel):
    """Base of concrete parameters (frozen, JSON-able)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    def is_identity(self) -> bool:
        """True when applying these params changes nothing (severity 0)."""
        return False


def stable_id(value: str | int) -> int:
    """A process- and platform-independent integer for a frame id (``hash`` is salted per process)."""
    if isinstance(value, int) or (isinstance(value, str) and value.isdigit()):
        return int(value)
    return zlib.crc32(str(value).encode("utf-8"))


def seed_sequence(campaign_seed: int, frame_id: str | int, operator_index: int, trial: int) -> np.random.SeedSequence:
    """The seed of one test case: identical across processes and machines."""
    return np.random.SeedSequence([int(campaign_seed), stable_id(frame_id), int(operator_index), int(trial)])


def generator(campaign_seed: int, frame_id: str | int, operator_index: int, trial: int) -> np.random.Generator:
    return np.random.default_rng(seed_sequence(campaign_seed, frame_id, operator_index, trial))


def draw_seed(rng: np.random.Generator) -> int:
    """An integer seed for per-point randomness, stored in params."""
    return int(rng.integers(0, 2**63 - 1))


def uniform(rng: np.random.Generator, interval: tuple[float, float]) -> float:
    lo, hi = interval
    return float(lo) if lo == hi else float(rng.uniform(lo, hi))


CfgT = TypeVar("CfgT", bound=Config)
ParT = TypeVar("ParT", bound=Params)


class Operator(ABC, Generic[S, CfgT, ParT]):
    """One perturbation. Subclasses set the class attributes and implement ``sample`` and ``apply``.

    Class attributes:
        name: Registry name (snake case).
        aliases: Other names (e.g. the thesis's abbreviations).
        family: Grouping for reports (``noise``, ``deletion``, ``geometric``, ``intensity``,
            ``weather``, ``sensor``, ``object``, ``log``).
        relation: The metamorphic relation the operator supports.
        targets: What it changes.
        ConfigModel / ParamsModel: its pydantic models.
        SEVERITIES: Severity 1–5 → config fields (the documented table).
    """

    name: ClassVar[str]
    aliases: ClassVar[tuple[str, ...]] = ()
    family: ClassVar[str]
    relation: ClassVar[Relation]
    targets: ClassVar[frozenset[Target]]
    ConfigModel: ClassVar[type[Config]]
    ParamsModel: ClassVar[type[Params]]
    SEVERITIES: ClassVar[Mapping[int, Mapping[str, Any]]]
    IDENTITY: ClassVar[Mapping[str, Any]]  # config fields of severity 0
    #: True when the severity table's configs draw no randomness (e.g. a mirror): every seed
    #: then gives the same mutant.
    deterministic: ClassVar[bool] = False

    def __init__(self, config: CfgT | None = None, **fields: Any) -> None:
        if config is not None and fields:
            raise TypeError("pass a config or fields, not both")
        self.config: CfgT = config if config is not None else self.ConfigModel(**fields)  # type: ignore[assignment]

    @classmethod
    def at_severity(cls, severity: int) -> Operator[S, CfgT, ParT]:
        """The operator configured as the severity table says (0 = identity)."""
        if severity == 0:
            return cls(**cls.IDENTITY)
        if severity not in cls.SEVERITIES:
            raise ValueError(f"{cls.name}: severity must be one of 0, {', '.join(map(str, cls.SEVERITIES))}")
        return cls(**cls.SEVERITIES[severity])

    @abstractmethod
    def sample(self, rng: np.random.Generator, sample: S) -> ParT:
        """Draw concrete params for ``sample`` (the sample may shape them, e.g. its extent)."""

    @abstractmethod
    def apply(self, sample: S, params: ParT) -> S:
        """Apply concrete params; pure: never modifies ``sample``."""

    def __call__(self, sample: S, rng: np.random.Generator) -> tuple[S, ParT]:
        params = self.sample(rng, sample)
        return self.apply(sample, params), params

    def transform(self, params: ParT) -> NDArray[np.float64] | None:
        """For equivariant operators: the 4×4 map T from source to follow-up LiDAR frame."""
        return None

    def parse_params(self, data: Mapping[str, Any]) -> ParT:
        return self.ParamsModel.model_validate(dict(data))  # type: ignore[return-value]

    def spec(self) -> dict[str, Any]:
        """JSON-able description that rebuilds this operator (see :func:`~lidarfuzz.operators.registry.from_spec`)."""
        return {"name": self.name, "config": self.config.model_dump(mode="json")}

    def __repr__(self) -> str:
        fields = ", ".join(f"{k}={v!r}" for k, v in self.config.model_dump().items())
        return f"{type(self).__name__}({fields})"
