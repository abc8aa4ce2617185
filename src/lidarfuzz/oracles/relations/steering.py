"""DeepTest's relaxed metamorphic relation on a steering system's image outputs, as the paper defines it.

Tian et al. (ICSE 2018, Eq. 2): a transformed image ``t`` of a labelled image ``i`` passes when

    (θ̂_i − θ_t)² ≤ λ · MSE_orig,        MSE_orig = 1/n · Σ_i (θ̂_i − θ_o,i)²

where ``θ̂_i`` is the image's **label** (the recorded steering), ``θ_t`` the system's prediction on
the transformed image and ``θ_o,i`` its prediction on the original; ``MSE_orig`` is the system's
mean squared error over the **original data set** (the camera task computes it from its originals'
subtask before any transformation is judged and passes it as ``pair.reference["mse_orig"]``).
The comparison is against the label, not against the original prediction: an image the system
already got wrong may stay as wrong without a violation, up to the error the system makes anyway.

Eq. 3, ``|MSE_(trans, param) − MSE_orig| ≤ ε``, is a property of a whole transformation (all its
images at one parameter), so it is applied where a transformation's outcomes are gathered
(:mod:`lidarfuzz.oracles.deeptest`); each outcome carries what that needs (``stats``:
``squared_errors``, ``mse_orig``, ``lambda``, ``epsilon``). The paper does not filter composite
transformations (rain, fog, the guided search's chains): those outcomes say ``filtered: false``.

A frame without a label is not judged (not applicable): Eq. 2 needs the label, and no default
stands in for it.

Example:
    >>> from types import SimpleNamespace as NS
    >>> relation = DeepTestSteering(lambda_=5.0)
    >>> pair = Pair(NS(steering=0.10), NS(steering=0.10), NS(steering=0.12), NS(steering=0.30),
    ...             reference={"mse_orig": 0.004})
    >>> outcome = relation(pair)  # (0.10 − 0.30)² = 0.04 > 5 × 0.004 = 0.02
    >>> outcome.holds, round(outcome.stats["squared_errors"][0], 6)
    (False, 0.04)
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

from pydantic import ConfigDict, Field

from lidarfuzz.operators.base import Relation as OperatorRelation
from lidarfuzz.oracles.relations.base import MetamorphicRelation, Pair, RelationConfig, RelationOutcome, Violation


class DeepTestSteeringConfig(RelationConfig):
    model_config = ConfigDict(frozen=True, extra="forbid", populate_by_name=True)

    lambda_: float = Field(default=5.0, gt=0.0, alias="lambda", description="λ of Eq. 2: allowed multiple of MSE_orig")
    epsilon: float = Field(default=0.03, gt=0.0, description="ε of Eq. 3: how far a transformation's MSE may move "
                                                             "from MSE_orig and its violations still count")
    mse_orig: float | None = Field(default=None, ge=0.0,
                                   description="MSE_orig over the original data set (the camera task sets it)")


def label_of(sample: Any) -> float | None:
    """A sample's finite steering label, or None."""
    value = getattr(sample, "steering", None)
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


class DeepTestSteering(MetamorphicRelation[Any, Any, DeepTestSteeringConfig]):
    """Eq. 2 on one transformed image (see the module docstring)."""

    name: ClassVar[str] = "deeptest_steering"
    description: ClassVar[str] = "DeepTest Eq. 2: (label − prediction on the transformed image)² ≤ λ · MSE_orig"
    output: ClassVar[str] = "steering"
    assumes_harmless: ClassVar[bool] = True
    assumption: ClassVar[str] = ("the transformation keeps the correct steering angle (DeepTest's assumption for "
                                 "its transformations at their parameters)")
    ConfigModel: ClassVar[type[DeepTestSteeringConfig]] = DeepTestSteeringConfig
    applies_to: ClassVar[frozenset[OperatorRelation]] = frozenset({OperatorRelation.INVARIANT})

    def applicable(self, pair: Pair[Any, Any]) -> bool:
        return super().applicable(pair) and label_of(pair.source) is not None

    def mse_orig(self, pair: Pair[Any, Any]) -> float:
        if "mse_orig" in pair.reference:
            return float(pair.reference["mse_orig"])
        return float(self.config.mse_orig) if self.config.mse_orig is not None else math.nan

    def check(self, pair: Pair[Any, Any]) -> RelationOutcome:
        cfg = self.config
        label = label_of(pair.source)
        assert label is not None  # applicable() saw it
        predicted = float(pair.follow_output.steering)
        original = float(pair.source_output.steering) if pair.source_output is not None else math.nan
        mse_orig = self.mse_orig(pair)
        limit = cfg.lambda_ * mse_orig
        error = (label - predicted) ** 2
        violations: tuple[Violation, ...] = ()
        if not error <= limit:  # NaN (no MSE_orig, or a NaN prediction) violates too
            violations = (Violation(
                relation=self.name, kind="deviation", magnitude=error, measure="squared steering error",
                message=f"steering {predicted:.4g} against the label {label:.4g} (original image: {original:.4g}): "
                        f"squared error {error:.3g} exceeds λ·MSE_orig = {cfg.lambda_:g} × {mse_orig:.3g} = "
                        f"{limit:.3g}"),)
        filtered = bool(pair.reference.get("filtered", 1.0))
        return RelationOutcome(
            self.name, holds=not violations, violations=violations, checked={"": 1},
            stats={"label": label, "prediction": predicted, "original_prediction": original,
                   "squared_errors": [error], "mse_orig": mse_orig, "mse_orig_from": "data set",
                   "lambda": cfg.lambda_, "epsilon": cfg.epsilon, "filtered": filtered},
            basis=pair.basis or "the transformation keeps the correct steering angle",
        )


__all__ = ["DeepTestSteering", "DeepTestSteeringConfig", "label_of"]
