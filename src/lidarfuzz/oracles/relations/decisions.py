"""Metamorphic relations on decisions: what a system that consumes logs in order (a controller,
:mod:`lidarfuzz.suts.sequence`) commands, frame by frame.

Outputs are read by their attributes — ``steering`` (rad, left positive), ``speed`` (m/s),
``obstacles`` (boxes or None) — so the relations need nothing from the systems' package.

* ``steering_tolerance`` — DeepTest's relaxed relation in the form ``(θ_mutant − θ_orig)² ≤
  λ · MSE_orig``. ``θ_orig`` and ``θ_mutant`` are the steering decided at the same step of the
  original log and of its mutant (each replayed from a reset). ``MSE_orig`` is the mean squared
  error of the original log's steering against its **label** — a recorded steering in each
  frame's metadata (``"steering"``), as DeepTest's Udacity frames carry the driver's angle —
  computed with :meth:`DecisionTolerance.mse_orig_of` and given as the config's ``mse_orig`` or
  ``pair.reference["mse_orig_steering"]``. **Without labels** (field logs of a controller rarely
  record what it should have done) the documented alternative is an absolute tolerance: the
  check becomes ``(θ_mutant − θ_orig)² ≤ tolerance²`` (0.05 rad by default, about 3°), and the
  outcome says which limit was used (``stats["limit_from"]``).
* ``speed_tolerance`` — the same for the commanded speed (label ``"speed"`` in the metadata;
  absolute tolerance 0.5 m/s).
  Both expect the mutation to be harmless, so they are checked for invariant operators at a
  harmless setting, and for the mirror flip (``global_flip``: ``T`` maps ``y`` to ``−y``) with the
  steering expected mirrored (``−θ_orig``) and the speed unchanged; other scene-moving operators
  change where the road goes, so no expected decision is known and the pair is not applicable.
* ``safety`` — the controller never commands a speed higher than the previous step's while an
  obstacle in its corridor is nearer than the stopping distance ``v² / (2·a_max) + margin`` at
  the previous step's speed ``v``. A pair here is two **consecutive steps of one log**
  (:func:`consecutive_pairs`): the source is the step before, the follow-up the step checked.
  The obstacles are the frame's ground-truth boxes when it has any, else the obstacles the
  system reported with its decision; a frame with neither is not checked (not applicable). It
  holds for any log, original or mutant, so it applies to every operator.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any, ClassVar

import numpy as np
from pydantic import ConfigDict, Field

from lidarfuzz.operators.base import Relation as OperatorRelation
from lidarfuzz.oracles.relations.base import MetamorphicRelation, Pair, RelationConfig, RelationOutcome, Violation
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import box_corners

MIRROR_Y = np.diag([1.0, -1.0, 1.0, 1.0])


def is_decision(output: Any) -> bool:
    """Whether an output reads as a decision (numeric ``steering`` and ``speed``)."""
    return all(isinstance(getattr(output, key, None), int | float) for key in ("steering", "speed"))


class DecisionToleranceConfig(RelationConfig):
    lambda_: float = Field(default=5.0, gt=0.0, alias="lambda", description="λ: allowed multiple of MSE_orig")
    mse_orig: float | None = Field(
        default=None, ge=0.0, description="MSE_orig of the original log against its labels (set from the log)")
    tolerance: float = Field(default=0.05, gt=0.0,
                             description="without labels: the largest difference from the original's decision")

    model_config = ConfigDict(frozen=True, extra="forbid", populate_by_name=True)


class SpeedToleranceConfig(DecisionToleranceConfig):
    tolerance: float = Field(default=0.5, gt=0.0,
                             description="without labels: the largest difference from the original's speed (m/s)")


class DecisionTolerance(MetamorphicRelation[Any, Any, DecisionToleranceConfig]):
    """DeepTest's relaxed relation on one quantity of a decision (see the module docstring)."""

    quantity: ClassVar[str] = "steering"
    unit: ClassVar[str] = "rad"
    output: ClassVar[str] = "decisions"
    assumes_harmless: ClassVar[bool] = True
    applies_to: ClassVar[frozenset[OperatorRelation]] = frozenset({OperatorRelation.INVARIANT,
                                                                   OperatorRelation.EQUIVARIANT})

    def applicable(self, pair: Pair[Any, Any]) -> bool:
        if not (super().applicable(pair) and is_decision(pair.source_output) and is_decision(pair.follow_output)):
            return False
        return self._mirrored(pair) is not None

    @staticmethod
    def _mirrored(pair: Pair[Any, Any]) -> bool | None:
        """False when the follow-up shows the same scene, True when it is mirrored left to right,
        None when the operator moved the scene otherwise (no expected decision)."""
        if pair.transform is None:
            return False if pair.operator_relation is not OperatorRelation.EQUIVARIANT else None
        matrix = np.asarray(pair.transform, dtype=np.float64)
        if np.allclose(matrix, np.eye(4), atol=1e-9):
            return False
        if np.allclose(matrix, MIRROR_Y, atol=1e-9):
            return True
        return None

    def expected(self, pair: Pair[Any, Any]) -> float:
        """The follow-up's expected value: the original's, mirrored for a flipped steering."""
        value = float(getattr(pair.source_output, self.quantity))
        return -value if self.quantity == "steering" and self._mirrored(pair) else value

    def check(self, pair: Pair[Any, Any]) -> RelationOutcome:
        cfg = self.config
        key = f"mse_orig_{self.quantity}"
        if key in pair.reference:
            mse_orig, origin = float(pair.reference[key]), "labels"
        elif cfg.mse_orig is not None:
            mse_orig, origin = float(cfg.mse_orig), "labels"
        else:
            mse_orig, origin = float("nan"), "tolerance"
        limit = cfg.lambda_ * mse_orig if origin == "labels" else cfg.tolerance**2
        expected = self.expected(pair)
        actual = float(getattr(pair.follow_output, self.quantity))
        error = (actual - expected) ** 2
        violations: tuple[Violation, ...] = ()
        if not error <= limit:  # a NaN error is a violation too
            how = (f"λ·MSE_orig = {cfg.lambda_:g} × {mse_orig:.3g}" if origin == "labels"
                   else f"the tolerance² = {cfg.tolerance:g}²")
            violations = (Violation(
                relation=self.name, kind="deviation", magnitude=error, measure=f"squared {self.quantity} difference",
                message=f"{self.quantity} {actual:.4g} {self.unit} against {expected:.4g} expected: squared "
                        f"difference {error:.3g} exceeds {how} = {limit:.3g}"),)
        basis = "the mirrored scene: steering mirrored, speed unchanged" if self._mirrored(pair) else \
            "the same scene: the same decision within the limit"
        return RelationOutcome(
            self.name, holds=not violations, violations=violations, checked={"": 1},
            stats={"expected": expected, "actual": actual, "squared_error": error, "limit": limit,
                   "limit_from": origin, "mse_orig": mse_orig, "lambda": cfg.lambda_},
            basis=pair.basis or basis,
        )

    def mse_orig_of(self, frames: Iterable[Any], decisions: Iterable[Any]) -> tuple[float, int]:
        """MSE_orig of a log: the mean squared error of the decisions' quantity against each
        frame's label (``metadata[quantity]``), over the frames that have a finite label and a
        decision; (NaN, 0) when none has.

        Example:
            >>> from types import SimpleNamespace as NS
            >>> frames = [NS(metadata={"steering": 0.1}), NS(metadata={}), NS(metadata={"steering": -0.2})]
            >>> decisions = [NS(steering=0.2, speed=1.0), NS(steering=0.0, speed=1.0), NS(steering=-0.2, speed=1.0)]
            >>> mse, n = SteeringTolerance().mse_orig_of(frames, decisions)
            >>> round(mse, 4), n  # ((0.2 - 0.1)² + 0²) / 2
            (0.005, 2)
        """
        errors = []
        for frame, decision in zip(frames, decisions, strict=True):
            label = getattr(frame, "metadata", {}).get(self.quantity)
            if decision is None or isinstance(label, bool) or not isinstance(label, int | float):
                continue
            if math.isfinite(label):
                errors.append((float(getattr(decision, self.quantity)) - float(label)) ** 2)
        return (float(np.mean(errors)), len(errors)) if errors else (float("nan"), 0)


class SteeringTolerance(DecisionTolerance):
    """(θ_mutant − θ_orig)² ≤ λ·MSE_orig on the steering (DeepTest's form; an absolute tolerance without labels)."""

    name: ClassVar[str] = "steering_tolerance"
    description: ClassVar[str] = "(steering_mutant - steering_orig)^2 <= lambda * MSE_orig (or tolerance^2 unlabelled)"
    assumption: ClassVar[str] = ("the transformation is harmless at this setting, so the steering may move at most as "
                                 "much as λ times the original log's error against its labels")
    ConfigModel = DecisionToleranceConfig


class SpeedTolerance(DecisionTolerance):
    """(v_mutant − v_orig)² ≤ λ·MSE_orig on the commanded speed (an absolute tolerance without labels)."""

    name: ClassVar[str] = "speed_tolerance"
    quantity: ClassVar[str] = "speed"
    unit: ClassVar[str] = "m/s"
    description: ClassVar[str] = "(speed_mutant - speed_orig)^2 <= lambda * MSE_orig (or tolerance^2 unlabelled)"
    assumption: ClassVar[str] = ("the transformation is harmless at this setting, so the speed may move at most as "
                                 "much as λ times the original log's error against its labels")
    ConfigModel = SpeedToleranceConfig


class SafetyConfig(RelationConfig):
    max_decel: float = Field(default=4.0, gt=0.0, description="a_max: braking deceleration (m/s²)")
    stop_margin: float = Field(default=2.0, ge=0.0, description="added to v²/(2·a_max) (m)")
    corridor_half_width: float = Field(default=1.25, gt=0.0, description="half width of the corridor ahead (m)")
    speed_slack: float = Field(default=1e-6, ge=0.0, description="speed increases up to this are not counted (m/s)")


def corridor_distance(boxes: Boxes3D, half_width: float) -> float:
    """Distance ahead of the nearest box whose footprint overlaps the corridor ``|y| < half_width``
    in front of the sensor: its nearest corner's ``x`` (0 when it reaches behind the sensor; inf
    when there is none).

    Example:
        >>> boxes = Boxes3D.create([[6.0, 0.5, -1.0], [3.0, 5.0, -1.0]], [[2, 1, 1.5]] * 2, [0, 0], ["Car"] * 2)
        >>> corridor_distance(boxes, 1.25)  # the second box is 4.5 m to the left
        5.0
    """
    boxes = boxes.select(boxes.has_geometry)
    if len(boxes) == 0:
        return math.inf
    corners = box_corners(boxes.as_array())[:, :4, :2]
    x_low, x_high = corners[..., 0].min(axis=1), corners[..., 0].max(axis=1)
    y_low, y_high = corners[..., 1].min(axis=1), corners[..., 1].max(axis=1)
    ahead = (x_high > 0.0) & (y_low < half_width) & (y_high > -half_width)
    return float(np.maximum(x_low[ahead], 0.0).min()) if ahead.any() else math.inf


class Safety(MetamorphicRelation[Any, Any, SafetyConfig]):
    """Never faster than the step before while an obstacle in the corridor is nearer than the stopping distance."""

    name: ClassVar[str] = "safety"
    output: ClassVar[str] = "decisions"
    description: ClassVar[str] = ("no speed-up while an obstacle in the corridor is nearer than v^2/(2 a_max) + "
                                  "margin (consecutive steps)")
    assumption: ClassVar[str] = ("the pair is two consecutive steps of one log, and the frame's obstacles are known: "
                                 "its ground-truth boxes, else those the system reported")
    ConfigModel = SafetyConfig

    def applicable(self, pair: Pair[Any, Any]) -> bool:
        return super().applicable(pair) and is_decision(pair.source_output) and is_decision(pair.follow_output)

    def check(self, pair: Pair[Any, Any]) -> RelationOutcome:
        cfg = self.config
        truth = getattr(pair.follow, "boxes", None)
        reported = getattr(pair.follow_output, "obstacles", None)
        if isinstance(truth, Boxes3D) and truth.has_geometry.any():
            boxes, origin = truth, "ground truth"
        elif isinstance(reported, Boxes3D):
            boxes, origin = reported, "reported by the system"
        else:
            return RelationOutcome(self.name, holds=True, applicable=False,
                                   basis="not checked: the frame has no ground-truth boxes and the system "
                                         "reported no obstacles")
        before, after = float(pair.source_output.speed), float(pair.follow_output.speed)
        nearest = corridor_distance(boxes, cfg.corridor_half_width)
        stopping = before * before / (2.0 * cfg.max_decel) + cfg.stop_margin
        violations: tuple[Violation, ...] = ()
        if nearest < stopping and after > before + cfg.speed_slack:
            violations = (Violation(
                relation=self.name, kind="speed_up", magnitude=after - before, measure="m/s", range_m=nearest,
                message=f"speed {before:.3g} → {after:.3g} m/s with an obstacle {nearest:.3g} m ahead in the corridor, "
                        f"nearer than the stopping distance {stopping:.3g} m"),)
        return RelationOutcome(
            self.name, holds=not violations, violations=violations, checked={"": 1},
            stats={"nearest": nearest, "stopping_distance": stopping, "speed_before": before, "speed_after": after,
                   "obstacles_from": origin},
            basis=f"consecutive steps; obstacles {origin}",
        )


def consecutive_pairs(frames: Sequence[Any], decisions: Sequence[Any]) -> list[Pair[Any, Any]]:
    """The (step k − 1, step k) pairs of one log for :class:`Safety`, skipping steps without a
    decision on either side (failed steps)."""
    if len(frames) != len(decisions):
        raise ValueError(f"consecutive_pairs: {len(frames)} frames but {len(decisions)} decisions")
    return [Pair(frames[k - 1], frames[k], decisions[k - 1], decisions[k])
            for k in range(1, len(frames)) if decisions[k - 1] is not None and decisions[k] is not None]
