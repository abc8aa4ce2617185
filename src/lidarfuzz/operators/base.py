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
import itertools
import math
import zlib
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Annotated, Any, ClassVar, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

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
    IMAGE = "image"  # a camera frame's pixels (and its depth map, moved with them)


#: Bounds of interval parameters that hold by definition, never tuned: a share of points (or of a
#: scale) lies in [0, 1]; a count, distance, standard deviation or magnitude is not negative; a scale
#: factor or a visibility is positive; a coarser sensor's spacing is at least 1; a sector is at most a
#: full turn. The params' JSON schema carries them, so a campaign is refused at the field (the web
#: form's inputs get them as min and max).
Share = Annotated[float, Field(ge=0, le=1)]
NonNegative = Annotated[float, Field(ge=0)]
Positive = Annotated[float, Field(gt=0)]
AtLeastOne = Annotated[float, Field(ge=1)]
Turn = Annotated[float, Field(ge=0, le=360)]
ShareRange = tuple[Share, Share]
NonNegativeRange = tuple[NonNegative, NonNegative]
PositiveRange = tuple[Positive, Positive]
AtLeastOneRange = tuple[AtLeastOne, AtLeastOne]
TurnRange = tuple[Turn, Turn]


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


def _direction(column: list[Any]) -> int:
    """+1 when a table column (severity 1 → 5) grows with severity, -1 when it shrinks, 0 when it is
    constant or cannot be read as either (not numbers, not monotone)."""
    if not column or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in column):
        return 0
    if column[-1] > column[0] and all(b >= a for a, b in itertools.pairwise(column)):
        return 1
    if column[-1] < column[0] and all(b <= a for a, b in itertools.pairwise(column)):
        return -1
    return 0


def _no_stronger(value: Any, limit: Any, table: list[Any]) -> bool:
    """``value`` is on the mild side of ``limit``, the direction read from ``table`` (severity 1 → 5).

    A number compares one way. A range ``(lo, hi)`` must lie in the mild region the harmless
    range bounds: on each side, the harmless end that moves outwards with severity bounds it (fog's
    visibility ``(600, 900)`` allows ``(700, 800)`` and anything above 600; a height offset
    ``(-0.2, 0.2)`` allows what lies between). Anything the table cannot place must equal ``limit``.
    """
    if value == limit:
        return True
    if isinstance(value, (tuple, list)) and isinstance(limit, (tuple, list)) and len(value) == len(limit) == 2:
        ends = [_direction([row[k] for row in table]) for k in (0, 1)]
        if ends == [0, 0] or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            return False
        lower = min(limit) if ends in ([-1, -1], [0, -1], [-1, 0]) else (limit[0] if ends == [-1, 1] else -math.inf)
        upper = max(limit) if ends in ([1, 1], [0, 1], [1, 0]) else (limit[1] if ends == [-1, 1] else math.inf)
        return lower <= min(value) and max(value) <= upper
    direction = _direction(table)
    if direction == 0 or isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    return value <= limit if direction > 0 else value >= limit


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
    #: The strongest severity at which a correct system should still find every object that keeps
    #: its evidence (0: at none). Relations that assume harmlessness (preservation, invariance,
    #: equivariance, DeepTest's, ground-truth recall) check this operator only up to here, and a
    #: config only when no stronger than this severity's (:meth:`harmless`).
    harmless_up_to: ClassVar[int] = 0
    #: Why: one sentence a report shows beside each check ("checked because …").
    harmless_because: ClassVar[str] = ""
    #: The sample type it takes: ``"lidar"`` (a :class:`~lidarfuzz.scene.scene.Scene`) or ``"camera"``
    #: (an :class:`~lidarfuzz.scene.image.ImageSample`). Catalogues, campaigns and the web app offer
    #: an operator only for data of its modality.
    modality: ClassVar[str] = "lidar"

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

    def harmless(self) -> bool:
        """True when this config is no stronger than severity :attr:`harmless_up_to`'s.

        A field's direction is read from the severity table (growing or shrinking from severity 1
        to 5; a range compares end by end); a field the table does not vary, or a config the table
        cannot place, must equal the harmless severity's value. Unknown: not harmless.
        """
        if self.harmless_up_to <= 0:
            return False
        mine = self.config.model_dump()
        limit = self.ConfigModel(**self.SEVERITIES[self.harmless_up_to]).model_dump()
        if mine == self.ConfigModel(**self.IDENTITY).model_dump():
            return True
        tables = [self.ConfigModel(**self.SEVERITIES[s]).model_dump() for s in sorted(self.SEVERITIES)]
        return all(_no_stronger(mine[name], limit[name], [t[name] for t in tables]) for name in mine)

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
