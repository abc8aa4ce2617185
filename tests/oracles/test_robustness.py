"""Robustness scores with hand-worked numbers."""

from __future__ import annotations

import math

import pytest

from lidarfuzz.oracles.kitti_eval import DIFFICULTIES, METRICS, KittiEvalResult
from lidarfuzz.oracles.relations.base import RelationOutcome, Violation
from lidarfuzz.oracles.robustness import (
    RelationRecord,
    corruption_error,
    count_form_rates,
    delta_ap,
    resilience_rate,
    robustness_summary,
    violation_rates,
)


def result(car: float, ped: float | None = None) -> KittiEvalResult:
    """Every metric, difficulty and sampling at ``car`` for Car (and ``ped`` for Pedestrian)."""
    values = {"Car": car} if ped is None else {"Car": car, "Pedestrian": ped}
    ap = {m: {c: {d: {"R11": v, "R40": v} for d in DIFFICULTIES} for c, v in values.items()} for m in METRICS}
    return KittiEvalResult(ap=ap, overlaps={}, num_frames=1)


def test_delta_ap_absolute_and_relative() -> None:
    rows = delta_ap(result(80, 0), {("fog", 1): result(60, 10), ("fog", 2): result(40, 0)})
    row = next(r for r in rows if (r.operator, r.severity, r.metric, r.cls, r.difficulty, r.points)
               == ("fog", 2, "3d", "Car", "moderate", "R40"))
    assert (row.clean, row.corrupted, row.delta, row.relative) == (80, 40, -40, -0.5)
    ped = next(r for r in rows if r.cls == "Pedestrian" and r.severity == 1)
    assert ped.delta == 10 and math.isnan(ped.relative)
    assert len(rows) == 2 * 4 * 2 * 3 * 2  # severities × metrics × classes × difficulties × samplings


def test_corruption_error_and_resilience_by_hand() -> None:
    # CE = (0.4 + 0.5 + 0.6) / (0.5 + 0.6 + 0.7) = 1.5 / 1.8
    assert corruption_error([60, 50, 40], [50, 40, 30]) == pytest.approx(1.5 / 1.8)
    # RR = (60 + 50 + 40) / (3 · 80)
    assert resilience_rate([60, 50, 40], 80) == pytest.approx(0.625)
    assert math.isnan(resilience_rate([0.0], 0.0))
    assert math.isnan(corruption_error([50], [100]))
    with pytest.raises(ValueError):
        corruption_error([1, 2], [1])


def test_summary_with_a_baseline() -> None:
    model = {("fog", 1): result(60), ("fog", 2): result(40), ("snow", 1): result(70), ("snow", 2): result(70)}
    base = {("fog", 1): result(50), ("fog", 2): result(30), ("snow", 1): result(60), ("snow", 2): result(40)}
    s = robustness_summary(result(80), model, baseline_clean=result(70), baseline_corrupted=base)
    fog, snow = s.operators
    assert fog.operator == "fog" and fog.ap == (60, 40) and fog.severities == (1, 2)
    assert fog.resilience == pytest.approx(100 / 160)  # (60 + 40) / (2 · 80)
    assert fog.corruption_error == pytest.approx((0.4 + 0.6) / (0.5 + 0.7))
    assert snow.resilience == pytest.approx(140 / 160)
    assert snow.corruption_error == pytest.approx((0.3 + 0.3) / (0.4 + 0.6))
    assert s.mean_resilience == pytest.approx((100 / 160 + 140 / 160) / 2)
    assert s.mean_corruption_error == pytest.approx((1.0 / 1.2 + 0.6) / 2)
    assert s.baseline_clean_ap == 70
    assert s.to_dict()["mRR"] == pytest.approx(s.mean_resilience)


def test_summary_without_baseline_uses_map_and_checks_inputs() -> None:
    s = robustness_summary(result(80, 40), {("fog", 1): result(40, 20)})
    assert s.clean_ap == 60 and s.operators[0].ap == (30,) and s.operators[0].resilience == 0.5
    assert math.isnan(s.mean_corruption_error) and s.to_dict()["mCE"] is None
    with pytest.raises(ValueError, match="no results for operator"):
        robustness_summary(result(80), {("fog", 1): result(40)}, baseline_corrupted={("snow", 1): result(1)})
    with pytest.raises(ValueError, match="severities"):
        robustness_summary(result(80), {("fog", 1): result(40)}, baseline_corrupted={("fog", 2): result(1)})


def outcome(violations: list[Violation], checked: dict[str, int], applicable: bool = True, **stats: float):
    return RelationOutcome("preservation", not violations, tuple(violations), checked, stats, applicable)


def missing(cls: str, index: int, kind: str = "missing") -> Violation:
    return Violation("preservation", kind, cls, source_index=index)


RECORDS = [
    # frame 0: two cars checked, car #1 lost (reported twice: two violation kinds, one object)
    RelationRecord("preservation", "noise", 1, "0", outcome([missing("Car", 1), missing("Car", 1, "drift")],
                                                            {"Car": 2}, count_holds=0.0)),
    # frame 1: a car and a pedestrian checked, the pedestrian lost
    RelationRecord("preservation", "noise", 1, "1", outcome([missing("Pedestrian", 0)], {"Car": 1, "Pedestrian": 1},
                                                            count_holds=1.0)),
    # frame 2: all fine
    RelationRecord("preservation", "noise", 2, "2", outcome([], {"Car": 3}, count_holds=1.0)),
    # not applicable: counts nowhere
    RelationRecord("preservation", "noise", 2, "3", outcome([missing("Car", 0)], {"Car": 5}, applicable=False)),
]


def test_violation_rates_per_frame_and_per_object() -> None:
    frames = {(r.get("operator"), r.get("severity")): (r.checked, r.violated) for r in violation_rates(RECORDS)}
    assert frames == {("noise", 1): (2, 2), ("noise", 2): (1, 0)}
    objects = {r.get("severity"): (r.checked, r.violated) for r in violation_rates(RECORDS, by=("severity",),
                                                                                     per="object")}
    assert objects == {1: (4, 2), 2: (3, 0)}  # car #1 counted once
    by_class = {r.get("class"): (r.checked, r.violated, r.rate)
                for r in violation_rates(RECORDS, by=("relation", "class"), per="frame")}
    assert by_class == {"Car": (3, 1, 1 / 3), "Pedestrian": (1, 1, 1.0)}
    with pytest.raises(ValueError, match="cannot group"):
        violation_rates(RECORDS, by=("weather",))


def test_count_form_rates() -> None:
    rates = count_form_rates(RECORDS, by=("severity",))
    assert [(r.get("severity"), r.checked, r.violated) for r in rates] == [(1, 2, 1), (2, 1, 0)]
    assert rates[0].to_dict()["rate"] == 0.5
