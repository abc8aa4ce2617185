"""Composition: a sequence of operators, one of several, or one applied with a probability.

A composite is an operator: it samples concrete params for its children (recording
which ones ran), serialises with :meth:`spec` and replays exactly from its params.
Rebuilding one from its spec needs its children rebuilt first, by name: that is the
registry's job (:func:`lidarfuzz.operators.registry.from_spec`), which hands them to
:meth:`from_children`; so this module knows no registry.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import Config, Operator, Params, Relation, Target


class _NoConfig(Config):
    pass


class Step(Params):
    """One child's concrete params (``None`` when the child did not run)."""

    operator: str
    params: dict[str, Any] | None


class CompositeParams(Params):
    steps: list[Step] = Field(default_factory=list)

    def is_identity(self) -> bool:
        return all(step.params is None for step in self.steps)


def _weakest(relations: Sequence[Relation]) -> Relation:
    order = [Relation.INVARIANT, Relation.EQUIVARIANT, Relation.DEGRADING]
    return max(relations, key=order.index) if relations else Relation.INVARIANT


class _Composite(Operator[Any, _NoConfig, CompositeParams]):
    family: ClassVar[str] = "composite"
    ConfigModel: ClassVar[type[Config]] = _NoConfig
    ParamsModel: ClassVar[type[Params]] = CompositeParams
    SEVERITIES: ClassVar[dict[int, dict[str, Any]]] = {}
    IDENTITY: ClassVar[dict[str, Any]] = {}
    relation: ClassVar[Relation] = Relation.DEGRADING
    targets: ClassVar[frozenset[Target]] = frozenset(Target)

    def __init__(self, operators: Sequence[Operator[Any, Any, Any]]) -> None:
        super().__init__(_NoConfig())
        if not operators:
            raise ValueError(f"{self.name} needs at least one operator")
        self.operators = list(operators)

    @property
    def composite_relation(self) -> Relation:
        return _weakest([op.relation for op in self.operators])

    def _children_spec(self) -> list[dict[str, Any]]:
        return [op.spec() for op in self.operators]

    def apply(self, sample: Any, params: CompositeParams) -> Any:
        if len(params.steps) != len(self.operators):
            raise ValueError(f"{self.name}: params have {len(params.steps)} steps for {len(self.operators)} operators")
        for op, step in zip(self.operators, params.steps, strict=True):
            if step.operator != op.name:
                raise ValueError(f"{self.name}: params for {step.operator!r} given to {op.name!r}")
            if step.params is not None:
                sample = op.apply(sample, op.parse_params(step.params))
        return sample

    def transform(self, params: CompositeParams) -> NDArray[np.float64] | None:
        """The map from the input's frame to the output's: the transforms of the children that ran,
        composed in the order they ran (a child that moves nothing counts as the identity). None when
        no child moved the frame, or when one claims to (equivariant) but exposes no transform.

            >>> from lidarfuzz.operators.lidar.geometric import RotateZ
            >>> from lidarfuzz.operators.lidar.sensor import GaussianJitter
            >>> chain = Compose([RotateZ(), GaussianJitter(), RotateZ()])
            >>> steps = [Step(operator="rotate_z", params={"angle": 30.0}), Step(operator="gaussian_jitter",
            ...          params=None), Step(operator="rotate_z", params={"angle": 60.0})]
            >>> chain.transform(CompositeParams(steps=steps)).round(6)[:2, :2].tolist()  # 30° + 60° = 90°
            [[0.0, -1.0], [1.0, 0.0]]
        """
        total: NDArray[np.float64] | None = None
        for op, step in zip(self.operators, params.steps, strict=True):
            if step.params is None:
                continue
            moved = op.transform(op.parse_params(step.params))
            if moved is None:
                if op.relation == Relation.EQUIVARIANT:
                    return None  # the frame moved by an unknown map
                continue
            total = moved if total is None else moved @ total
        return total

    @classmethod
    def from_children(cls, children: list[Operator[Any, Any, Any]], spec: dict[str, Any]) -> _Composite:
        """The composite a :meth:`spec` describes, given its ``operators`` already rebuilt."""
        raise NotImplementedError


class Compose(_Composite):
    """Every child in order; each sees the previous one's output."""

    name: ClassVar[str] = "sequence"

    def sample(self, rng: np.random.Generator, sample: Any) -> CompositeParams:
        steps = []
        for op in self.operators:
            params = op.sample(rng, sample)
            steps.append(Step(operator=op.name, params=params.model_dump(mode="json")))
            sample = op.apply(sample, params)  # later children sample on the mutated sample
        return CompositeParams(steps=steps)

    def spec(self) -> dict[str, Any]:
        return {"name": self.name, "operators": self._children_spec()}

    @classmethod
    def from_children(cls, children: list[Operator[Any, Any, Any]], spec: dict[str, Any]) -> Compose:
        return cls(children)


class OneOf(_Composite):
    """One child, picked with the given weights (uniform by default)."""

    name: ClassVar[str] = "one_of"

    def __init__(self, operators: Sequence[Operator[Any, Any, Any]], weights: Sequence[float] | None = None) -> None:
        super().__init__(operators)
        w = np.ones(len(self.operators)) if weights is None else np.asarray(weights, dtype=np.float64)
        if w.shape != (len(self.operators),) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError("one_of: one non-negative weight per operator, not all zero")
        self.weights = (w / w.sum()).tolist()

    def sample(self, rng: np.random.Generator, sample: Any) -> CompositeParams:
        chosen = int(rng.choice(len(self.operators), p=self.weights))
        steps = [Step(operator=op.name, params=op.sample(rng, sample).model_dump(mode="json") if i == chosen else None)
                 for i, op in enumerate(self.operators)]
        return CompositeParams(steps=steps)

    def spec(self) -> dict[str, Any]:
        return {"name": self.name, "operators": self._children_spec(), "weights": self.weights}

    @classmethod
    def from_children(cls, children: list[Operator[Any, Any, Any]], spec: dict[str, Any]) -> OneOf:
        return cls(children, spec.get("weights"))


class Maybe(_Composite):
    """The child with probability ``p``, otherwise nothing."""

    name: ClassVar[str] = "maybe"

    def __init__(self, operator: Operator[Any, Any, Any], p: float = 0.5) -> None:
        super().__init__([operator])
        if not 0.0 <= p <= 1.0:
            raise ValueError("maybe: p must lie in [0, 1]")
        self.p = float(p)

    def sample(self, rng: np.random.Generator, sample: Any) -> CompositeParams:
        op = self.operators[0]
        runs = bool(rng.random() < self.p)
        return CompositeParams(steps=[Step(operator=op.name,
                                           params=op.sample(rng, sample).model_dump(mode="json") if runs else None)])

    def spec(self) -> dict[str, Any]:
        return {"name": self.name, "operators": self._children_spec(), "p": self.p}

    @classmethod
    def from_children(cls, children: list[Operator[Any, Any, Any]], spec: dict[str, Any]) -> Maybe:
        if len(children) != 1:
            raise ValueError("maybe wraps exactly one operator")
        return cls(children[0], spec.get("p", 0.5))


#: Composite operators by the name their spec carries.
COMPOSITES: dict[str, type[_Composite]] = {"sequence": Compose, "one_of": OneOf, "maybe": Maybe}
