"""DeepTest's Eq. 2 on steering outputs and Eq. 3 / Table 7 over a transformation, on a worked example.

Three labelled images, labels θ̂ = (0.10, −0.20, 0.00); the system predicts θ_o = (0.12, −0.25, 0.05)
on the originals, so MSE_orig = (0.02² + 0.05² + 0.05²) / 3 = 0.0054 / 3 = 0.0018. On the transformed
images it predicts θ_t = (0.15, −0.35, 0.00): squared errors against the labels (0.0025, 0.0225, 0).
With λ = 5 the limit is 0.009: only the second image violates. MSE_(trans) = 0.025 / 3 = 0.008333…,
|0.008333 − 0.0018| = 0.006533: Eq. 3 keeps the transformation at ε = 0.03, not at ε = 0.005.
Per λ = 1 … 10: at λ = 1 (limit 0.0018) images one and two are erroneous (0.0025 and 0.0225 exceed
it); from λ = 2 (limit 0.0036) only image two (0.0225 / 0.0018 = 12.5 > 10).
"""

from __future__ import annotations

from types import SimpleNamespace as NS  # noqa: N814

import pytest

from lidarfuzz.oracles.deeptest import erroneous_table, transformation_errors
from lidarfuzz.oracles.relations.base import Pair
from lidarfuzz.oracles.relations.steering import DeepTestSteering

LABELS = (0.10, -0.20, 0.00)
ORIGINAL = (0.12, -0.25, 0.05)
TRANSFORMED = (0.15, -0.35, 0.00)
MSE_ORIG = 0.0018


def outcomes(filtered: float = 1.0, epsilon: float = 0.03):
    relation = DeepTestSteering(lambda_=5.0, epsilon=epsilon)
    return [relation(Pair(NS(steering=label), NS(steering=label), NS(steering=o), NS(steering=t),
                          reference={"mse_orig": MSE_ORIG, "filtered": filtered}))
            for label, o, t in zip(LABELS, ORIGINAL, TRANSFORMED, strict=True)]


def test_eq2_compares_the_label_with_the_transformed_prediction():
    found = outcomes()
    assert [o.holds for o in found] == [True, False, True]
    assert found[1].stats["squared_errors"][0] == pytest.approx(0.0225)
    assert found[1].stats["label"] == -0.20 and found[1].stats["original_prediction"] == -0.25
    assert "0.009" in found[1].violations[0].message  # λ·MSE_orig = 5 × 0.0018


def test_an_unlabelled_image_is_not_judged():
    relation = DeepTestSteering()
    outcome = relation(Pair(NS(steering=None), NS(steering=None), NS(steering=0.0), NS(steering=1.0),
                            reference={"mse_orig": MSE_ORIG}))
    assert not outcome.applicable


def test_a_missing_mse_orig_is_a_violation_not_a_pass():
    relation = DeepTestSteering()
    outcome = relation(Pair(NS(steering=0.0), NS(steering=0.0), NS(steering=0.0), NS(steering=0.0)))
    assert not outcome.holds  # no MSE_orig: the limit is undefined, nothing passes silently


def test_eq3_and_table7_on_the_worked_example():
    errors = transformation_errors((o.stats, o.holds) for o in outcomes())
    assert errors is not None
    assert errors.mse == pytest.approx(0.025 / 3)
    assert errors.violated == 1
    assert errors.erroneous == (2, 1, 1, 1, 1, 1, 1, 1, 1, 1)
    assert errors.kept  # |0.008333 − 0.0018| ≤ 0.03
    table = erroneous_table([errors], epsilons=(0.005, 0.03))
    assert table.counts[4] == (0, 1)  # λ = 5: not kept at ε = 0.005, kept at 0.03
    assert table.counts[0] == (0, 2)


def test_a_composite_transformation_counts_at_every_epsilon():
    errors = transformation_errors((o.stats, o.holds) for o in outcomes(filtered=0.0, epsilon=0.001))
    assert errors is not None and not errors.filtered and errors.kept
    table = erroneous_table([errors], epsilons=(0.001, 0.005, 0.03))
    assert table.counts[4] == (1, 1, 1)
