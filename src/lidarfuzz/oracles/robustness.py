"""Robustness scores across operators and severities.

* ΔAP — per operator × severity × metric × class × difficulty × recall sampling: the
  corrupted AP minus the clean AP (percentage points) and relative to the clean AP.
* Robo3D's corruption error and resilience rate, per corruption ``i`` with severities ``s``
  (AP as a fraction):

  ``CE_i = Σ_s (1 − AP_i,s) / Σ_s (1 − AP_baseline,i,s)``, ``mCE`` the mean over corruptions;

  ``RR_i = Σ_s AP_i,s / (S · AP_clean)``, ``mRR`` the mean over corruptions. The baseline
  system of CE is the user's choice.
* Violation rates of metamorphic relations per relation, operator, severity and class, per
  frame (the form of Zhou & Sun's table: the share of frames where the relation broke) or
  per object; and the share of frames breaking MR1's count form ``|O| <= |O'|``.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

from lidarfuzz.oracles.kitti_eval import DIFFICULTIES, KittiEvalResult
from lidarfuzz.oracles.relations.base import RelationOutcome

NAN = float("nan")
POINTS: tuple[str, ...] = ("R11", "R40")
GROUP_KEYS: tuple[str, ...] = ("relation", "operator", "severity", "class")


# -- ΔAP -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DeltaAP:
    operator: str
    severity: int
    metric: str
    cls: str
    difficulty: str
    points: str
    clean: float
    corrupted: float
    delta: float
    relative: float


def delta_ap(clean: KittiEvalResult, corrupted: Mapping[tuple[str, int], KittiEvalResult]) -> list[DeltaAP]:
    """ΔAP rows for every (operator, severity) result against the clean one (AP in percent).

    ``relative`` is ``delta / clean`` (NaN when the clean AP is 0).
    """
    rows = []
    for (operator, severity), result in sorted(corrupted.items()):
        for metric, by_class in clean.ap.items():
            for cls, by_difficulty in by_class.items():
                for difficulty in DIFFICULTIES:
                    for points in POINTS:
                        c = by_difficulty[difficulty][points]
                        m = result.ap[metric][cls][difficulty][points]
                        d = m - c
                        rows.append(
                            DeltaAP(operator, severity, metric, cls, difficulty, points, c, m, d, d / c if c else NAN)
                        )
    return rows


# -- Robo3D's CE and RR ------------------------------------------------------------------------
def corruption_error(model_ap: Sequence[float], baseline_ap: Sequence[float]) -> float:
    """``Σ_s (1 − AP_s) / Σ_s (1 − AP_baseline,s)`` with AP given in percent per severity.

    Example:
        >>> round(corruption_error([60, 50, 40], [50, 40, 30]), 4)  # (0.4+0.5+0.6)/(0.5+0.6+0.7)
        0.8333
    """
    if len(model_ap) != len(baseline_ap):
        raise ValueError(f"{len(model_ap)} model severities but {len(baseline_ap)} baseline severities")
    denominator = sum(1.0 - b / 100.0 for b in baseline_ap)
    return sum(1.0 - m / 100.0 for m in model_ap) / denominator if denominator else NAN


def resilience_rate(ap: Sequence[float], clean_ap: float) -> float:
    """``Σ_s AP_s / (S · AP_clean)``.

    Example:
        >>> round(resilience_rate([60, 50, 40], 80), 4)  # 150 / (3 · 80)
        0.625
    """
    if not ap:
        raise ValueError("no severities")
    return sum(ap) / (len(ap) * clean_ap) if clean_ap else NAN


def _score(result: KittiEvalResult, metric: str, cls: str | None, difficulty: str, points: str) -> float:
    if cls is None:
        return result.mean_ap(metric, difficulty, points)
    return result.get(metric, cls, difficulty, points)


@dataclass(frozen=True)
class OperatorRobustness:
    operator: str
    severities: tuple[int, ...]
    ap: tuple[float, ...]
    resilience: float
    corruption_error: float = NAN
    baseline_ap: tuple[float, ...] = ()


@dataclass(frozen=True)
class RobustnessSummary:
    """Per-operator RR (and CE when a baseline is given), their means, and what was scored."""

    metric: str
    cls: str | None
    difficulty: str
    points: str
    clean_ap: float
    operators: tuple[OperatorRobustness, ...]
    mean_resilience: float
    mean_corruption_error: float = NAN
    baseline_clean_ap: float = NAN
    notes: tuple[str, ...] = field(default=())

    def rows(self) -> list[dict[str, Any]]:
        return [
            {
                "operator": o.operator,
                "severities": list(o.severities),
                "ap": list(o.ap),
                "RR": o.resilience,
                "CE": o.corruption_error,
                "baseline_ap": list(o.baseline_ap),
            }
            for o in self.operators
        ]

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["operators"] = self.rows()
        out["mRR"], out["mCE"] = self.mean_resilience, self.mean_corruption_error
        return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in out.items()}


def _by_operator(results: Mapping[tuple[str, int], KittiEvalResult]) -> dict[str, dict[int, KittiEvalResult]]:
    grouped: dict[str, dict[int, KittiEvalResult]] = defaultdict(dict)
    for (operator, severity), result in results.items():
        grouped[operator][severity] = result
    return grouped


def _mean(values: Iterable[float]) -> float:
    finite = [v for v in values if not math.isnan(v)]
    return sum(finite) / len(finite) if finite else NAN


def robustness_summary(
    model_clean: KittiEvalResult,
    model_corrupted: Mapping[tuple[str, int], KittiEvalResult],
    *,
    baseline_clean: KittiEvalResult | None = None,
    baseline_corrupted: Mapping[tuple[str, int], KittiEvalResult] | None = None,
    metric: str = "3d",
    cls: str | None = None,
    difficulty: str = "moderate",
    points: str = "R40",
) -> RobustnessSummary:
    """RR per operator and mRR; CE and mCE too when the baseline system's results are given.

    Args:
        model_clean: The system's AP on the originals.
        model_corrupted: Its AP per (operator, severity).
        baseline_clean: The baseline system's AP on the originals (for the record).
        baseline_corrupted: The baseline's AP per (operator, severity): every operator of the
            model with the same severities.
        metric, cls, difficulty, points: What AP is scored; ``cls=None`` is the mAP over classes.
    """
    clean = _score(model_clean, metric, cls, difficulty, points)
    model = _by_operator(model_corrupted)
    baseline = _by_operator(baseline_corrupted) if baseline_corrupted is not None else None
    if baseline is not None:
        missing = sorted(set(model) - set(baseline))
        if missing:
            raise ValueError(f"the baseline has no results for operator(s) {', '.join(missing)}")
    rows = []
    for operator in sorted(model):
        severities = tuple(sorted(model[operator]))
        ap = tuple(_score(model[operator][s], metric, cls, difficulty, points) for s in severities)
        ce = NAN
        base_ap: tuple[float, ...] = ()
        if baseline is not None:
            if tuple(sorted(baseline[operator])) != severities:
                raise ValueError(
                    f"operator {operator}: model severities {list(severities)} but baseline "
                    f"{sorted(baseline[operator])}"
                )
            base_ap = tuple(_score(baseline[operator][s], metric, cls, difficulty, points) for s in severities)
            ce = corruption_error(ap, base_ap)
        rows.append(OperatorRobustness(operator, severities, ap, resilience_rate(ap, clean), ce, base_ap))
    return RobustnessSummary(
        metric=metric,
        cls=cls,
        difficulty=difficulty,
        points=points,
        clean_ap=clean,
        operators=tuple(rows),
        mean_resilience=_mean(r.resilience for r in rows),
        mean_corruption_error=_mean(r.corruption_error for r in rows) if baseline is not None else NAN,
        baseline_clean_ap=_score(baseline_clean, metric, cls, difficulty, points) if baseline_clean else NAN,
    )


# -- violation rates ----------------------------------------------------------------------------
@dataclass(frozen=True)
class RelationRecord:
    """One relation checked on one (source, follow-up) pair."""

    relation: str
    operator: str
    severity: int
    frame_id: str
    outcome: RelationOutcome


@dataclass(frozen=True)
class ViolationRate:
    key: tuple[tuple[str, Any], ...]
    checked: int
    violated: int

    @property
    def rate(self) -> float:
        return self.violated / self.checked if self.checked else NAN

    def get(self, name: str) -> Any:
        return dict(self.key)[name]

    def to_dict(self) -> dict[str, Any]:
        rate = self.rate
        return {**dict(self.key), "checked": self.checked, "violated": self.violated,
                "rate": None if math.isnan(rate) else rate}


def _check_keys(by: Sequence[str]) -> None:
    unknown = [k for k in by if k not in GROUP_KEYS]
    if unknown:
        raise ValueError(f"cannot group by {unknown}; choose from {list(GROUP_KEYS)}")


def _object_id(v: Any) -> tuple[str, int]:
    return ("source", v.source_index) if v.source_index >= 0 else ("gt", v.gt_index) if v.gt_index >= 0 else (
        "follow", v.follow_index)


def violation_rates(
    records: Iterable[RelationRecord],
    by: Sequence[str] = ("relation", "operator", "severity"),
    per: Literal["frame", "object"] = "frame",
) -> list[ViolationRate]:
    """How often relations broke, grouped by any of relation, operator, severity and class.

    ``per="frame"``: pairs checked and pairs with a violation (by class: a pair counts for a
    class when objects of it were checked, as violated when one of its violations is of it).
    ``per="object"``: objects checked (``outcome.checked``) and distinct objects violated.
    Outcomes of relations that did not apply count nowhere.
    """
    _check_keys(by)
    checked: dict[tuple[tuple[str, Any], ...], int] = defaultdict(int)
    violated: dict[tuple[tuple[str, Any], ...], int] = defaultdict(int)
    for record in records:
        outcome = record.outcome
        if not outcome.applicable:
            continue
        base = {"relation": record.relation, "operator": record.operator, "severity": record.severity}
        classes: set[str | None] = {None}
        if "class" in by:
            classes = {c for c, n in outcome.checked.items() if n > 0}
            classes |= {v.cls for v in outcome.violations}
        for cls in classes:
            key = tuple((k, cls if k == "class" else base[k]) for k in by)
            mine = [v for v in outcome.violations if cls is None or v.cls == cls]
            if per == "frame":
                checked[key] += 1
                violated[key] += int(bool(mine))
            else:
                if cls is None:
                    checked[key] += sum(outcome.checked.values())
                else:
                    checked[key] += outcome.checked.get(cls, 0)
                violated[key] += len({(v.cls, *_object_id(v)) for v in mine})
    return [ViolationRate(key, checked[key], violated[key]) for key in sorted(checked, key=_sort_key)]


def _sort_key(key: tuple[tuple[str, Any], ...]) -> tuple[str, ...]:
    return tuple(f"{v:08d}" if isinstance(v, int) else str(v) for _, v in key)


def count_form_rates(
    records: Iterable[RelationRecord], by: Sequence[str] = ("operator", "severity")
) -> list[ViolationRate]:
    """Share of pairs breaking MR1's count form ``|O| <= |O'|`` (outcomes with ``stats["count_holds"]``)."""
    _check_keys(by)
    if "class" in by:
        raise ValueError("the count form is per frame, not per class")
    checked: dict[tuple[tuple[str, Any], ...], int] = defaultdict(int)
    violated: dict[tuple[tuple[str, Any], ...], int] = defaultdict(int)
    for record in records:
        if not record.outcome.applicable or "count_holds" not in record.outcome.stats:
            continue
        base = {"relation": record.relation, "operator": record.operator, "severity": record.severity}
        key = tuple((k, base[k]) for k in by)
        checked[key] += 1
        violated[key] += int(not record.outcome.stats["count_holds"])
    return [ViolationRate(key, checked[key], violated[key]) for key in sorted(checked, key=_sort_key)]
