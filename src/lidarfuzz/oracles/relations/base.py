"""The metamorphic-relation contract: a (source, follow-up) pair in, an outcome with violations out.

A relation compares what the system under test said about a source sample with what it
said about a follow-up (the mutant), and, where a relation needs it, the ground truth.
Nothing here assumes LiDAR: a pair carries the two samples, the two outputs and the map
``T`` from source to follow-up frame when the operator exposes one; the built-in relations
for 3D detection read :class:`~lidarfuzz.scene.boxes.Boxes3D` outputs.

Every relation is a small class with a name, a frozen pydantic config and a ``check``
method; relations are found through the ``lidarfuzz.relations`` entry points, as operators
are, so users add their own.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict

from lidarfuzz.operators.base import Relation as OperatorRelation

S = TypeVar("S")
O = TypeVar("O")  # noqa: E741 - the output type of the system under test


class RelationConfig(BaseModel):
    """Base of relation parameters (frozen; unknown keys are errors)."""

    model_config = ConfigDict(frozen=True, extra="forbid")


@dataclass(frozen=True)
class Violation:
    """One broken expectation: which objects, how badly.

    Attributes:
        relation: Name of the relation that was violated.
        kind: What went wrong, e.g. ``missing`` (a source object has no match in the
            follow-up), ``drift``, ``score_drop``, ``count``, ``regression``, ``lost_gt``.
        cls: Class of the object involved (``""`` for frame-level violations).
        source_index: Index of the object in the source output (-1 when none).
        follow_index: Index of the matched object in the follow-up output (-1 when none).
        gt_index: Index of the ground-truth object involved (-1 when none).
        magnitude: How far the expectation was missed, in the unit named by ``measure``.
        measure: What ``magnitude`` measures (``iou``, ``metres``, ``score``, ``count``, ...).
        range_m: Distance of the object from the sensor in metres (NaN when not known).
        message: One readable sentence.
        evidence: What a reviewer needs to judge it: the object's points before, kept and added
            (:mod:`~lidarfuzz.oracles.relations.evidence`), its best partner's IoU.
    """

    relation: str
    kind: str
    cls: str = ""
    source_index: int = -1
    follow_index: int = -1
    gt_index: int = -1
    magnitude: float = float("nan")
    measure: str = ""
    range_m: float = float("nan")
    message: str = ""
    evidence: Mapping[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out = {k: (None if isinstance(v, float) and np.isnan(v) else v) for k, v in self.__dict__.items()}
        out["evidence"] = dict(self.evidence)
        return out


@dataclass(frozen=True)
class RelationOutcome:
    """The result of checking one relation on one pair.

    Attributes:
        relation: The relation's name.
        holds: True when there is no violation.
        violations: What broke.
        checked: Objects checked per class (denominators of per-class violation rates).
        stats: Relation-specific figures (e.g. the count form of MR1: ``n_source``,
            ``n_follow``, ``count_holds``).
        applicable: False when the relation does not apply to this pair (e.g. equivariance
            for an operator without a transform); such outcomes count in no rate.
        basis: Why the relation was checked here: the assumption that held ("checked because …").
        skipped: Objects left unchecked because the assumption failed for them, by reason
            (e.g. ``lost most of its points``).
    """

    relation: str
    holds: bool
    violations: tuple[Violation, ...] = ()
    checked: Mapping[str, int] = field(default_factory=dict)
    stats: Mapping[str, Any] = field(default_factory=dict)
    applicable: bool = True
    basis: str = ""
    skipped: Mapping[str, int] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "relation": self.relation,
            "holds": self.holds,
            "applicable": self.applicable,
            "violations": [v.to_dict() for v in self.violations],
            "checked": dict(self.checked),
            "stats": dict(self.stats),
            "basis": self.basis,
            "skipped": dict(self.skipped),
        }


@dataclass(frozen=True)
class Pair(Generic[S, O]):
    """A source sample and its follow-up with the system's outputs on both.

    Attributes:
        source: The original sample.
        follow: The mutant.
        source_output: What the system under test returned on ``source``.
        follow_output: What it returned on ``follow``.
        operator_relation: The relation the operator that made ``follow`` supports
            (invariant, equivariant or degrading); None when unknown (e.g. a chain).
        transform: The 4×4 map from the source to the follow-up frame, for equivariant
            operators (:meth:`~lidarfuzz.operators.base.Operator.transform`).
        reference: Dataset-level figures a relation may need (e.g. DeepTest's ``mse_orig``).
        basis: Why the operator is expected to be harmless here (its ``harmless_because``), which
            the outcome repeats as its basis.
    """

    source: S
    follow: S
    source_output: O
    follow_output: O
    operator_relation: OperatorRelation | None = None
    transform: NDArray[np.float64] | None = None
    reference: Mapping[str, float] = field(default_factory=dict)
    basis: str = ""


CfgT = TypeVar("CfgT", bound=RelationConfig)


class MetamorphicRelation(ABC, Generic[S, O, CfgT]):
    """One relation. Subclasses set ``name``, ``ConfigModel`` and ``applies_to`` and implement ``check``.

    Class attributes:
        name: Registry name (snake case).
        description: One line for listings.
        applies_to: The operator relations this relation is meaningful for; a pair whose
            operator relation is not in it gets an outcome with ``applicable=False``.
        assumes_harmless: The relation expects the mutation to be harmless, so a campaign checks
            it only where the operator is meant to be (:meth:`Operator.harmless`).
        assumption: What the relation assumes, in one sentence (listings and reports show it).
        output: What outputs it reads: ``detections`` (:class:`~lidarfuzz.scene.boxes.Boxes3D`) or
            ``decisions`` (a sequence system's steering and speed); campaigns choose relations by
            default among those reading their system's kind of output.
    """

    name: ClassVar[str]
    description: ClassVar[str] = ""
    output: ClassVar[str] = "detections"
    assumes_harmless: ClassVar[bool] = False
    assumption: ClassVar[str] = ""
    ConfigModel: ClassVar[type[RelationConfig]]
    applies_to: ClassVar[frozenset[OperatorRelation]] = frozenset(OperatorRelation)

    def __init__(self, config: CfgT | None = None, **fields: Any) -> None:
        if config is not None and fields:
            raise TypeError("pass a config or fields, not both")
        self.config: CfgT = config if config is not None else self.ConfigModel(**fields)  # type: ignore[assignment]

    def applicable(self, pair: Pair[S, O]) -> bool:
        return pair.operator_relation is None or pair.operator_relation in self.applies_to

    def __call__(self, pair: Pair[S, O]) -> RelationOutcome:
        if not self.applicable(pair):
            return RelationOutcome(self.name, holds=True, applicable=False)
        return self.check(pair)

    @abstractmethod
    def check(self, pair: Pair[S, O]) -> RelationOutcome:
        """Check the relation on an applicable pair."""

    def spec(self) -> dict[str, Any]:
        """JSON-able description that rebuilds this relation."""
        return {"name": self.name, "config": self.config.model_dump(mode="json", by_alias=True)}

    def __repr__(self) -> str:
        fields = ", ".join(f"{k}={v!r}" for k, v in self.config.model_dump().items())
        return f"{type(self).__name__}({fields})"
