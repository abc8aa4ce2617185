"""The significance test of differential testing: one-sided Fisher exact, Holm-corrected.

Expected p-values are worked out from the hypergeometric distribution with math.comb, not
with scipy: with A's v_a of n_a and B's v_b of n_b frames violated (k = v_a + v_b in all),
under the null A's count X is hypergeometric (N = n_a + n_b, k, n_a) and
p = P(X >= v_a) = sum_{x >= v_a} C(k, x) C(N - k, n_a - x) / C(N, n_a).
"""

from __future__ import annotations

import math
from math import comb

import pytest

from lidarfuzz.oracles.significance import ALPHA, compare_many, compare_rates, holm, smallest_p, tarone_family


def test_nine_of_twenty_against_one_of_twenty_is_significant() -> None:
    # k = 10, N = 40: p = [C(10,9) C(30,11) + C(10,10) C(30,10)] / C(40,20) = 0.0041809
    expected = (comb(10, 9) * comb(30, 11) + comb(30, 10)) / comb(40, 20)
    row = compare_rates(9, 20, 1, 20)
    assert row.p_value == pytest.approx(expected, rel=1e-9)
    assert row.p_value == pytest.approx(0.0041809, abs=1e-7)
    assert row.significant and ALPHA == 0.05
    assert (row.rate_a, row.rate_b) == (0.45, 0.05) and row.difference == pytest.approx(0.40)


def test_two_of_twenty_against_one_of_twenty_is_the_floor() -> None:
    # k = 3: p = [C(3,2) C(37,18) + C(3,3) C(37,17)] / C(40,20) = 0.5 (the table is symmetric)
    expected = (comb(3, 2) * comb(37, 18) + comb(37, 17)) / comb(40, 20)
    row = compare_rates(2, 20, 1, 20)
    assert row.p_value == pytest.approx(expected) == pytest.approx(0.5)
    assert not row.significant


def test_a_below_b_is_never_significant_and_nothing_checked_is_untested() -> None:
    assert compare_rates(0, 20, 9, 20).p_value == pytest.approx(1.0)  # P(X >= 0) = 1
    untested = compare_rates(3, 10, 0, 0)
    assert math.isnan(untested.p_value) and not untested.tested and not untested.significant


def test_all_of_three_against_none_is_not_enough() -> None:
    # 3/3 vs 0/3: p = 1 / C(6, 3) = 0.05, not below α = 0.05 (too few frames to tell)
    assert compare_rates(3, 3, 0, 3).p_value == pytest.approx(1 / 20)
    assert not compare_rates(3, 3, 0, 3).significant


def test_holm_multiplies_by_the_rank_and_keeps_order() -> None:
    # m = 3 tested: 0.01 x 3 = 0.03; 0.03 x 2 = 0.06; max(0.06, 0.04 x 1) = 0.06; NaN untouched
    adjusted = holm([0.01, 0.04, 0.03, math.nan])
    assert adjusted[:3] == pytest.approx([0.03, 0.06, 0.06]) and math.isnan(adjusted[3])


def test_rows_that_could_never_be_significant_do_not_dilute_the_others() -> None:
    # 9/20 vs 1/20 alone: p = 0.00418 < 0.05. Beside it, 19 rows of 0/20 vs 0/20 can reach no
    # p below 1 (Tarone's untestable rows): k = 1 (one row can reach 0.05 / 1), so it stays
    # significant; Bonferroni or Holm over all 20 would give 20 x 0.00418 = 0.0836
    rows = compare_many([(9, 20, 1, 20)] + [(0, 20, 0, 20)] * 19)
    assert rows[0].p_value == pytest.approx(0.0041809, abs=1e-7)
    assert rows[0].p_adjusted == pytest.approx(rows[0].p_value) and rows[0].significant
    # 20 rows that each could reach p = 1/C(40,20) < 0.05/20 (10 violations on 20 + 20 checks):
    # k = 20, and 9/20 vs 1/20 needs 20 x 0.00418 = 0.0836: no longer significant
    crowded = compare_many([(9, 20, 1, 20)] + [(5, 20, 5, 20)] * 19)
    assert crowded[0].p_adjusted == pytest.approx(20 * crowded[0].p_value) and not crowded[0].significant


def test_the_smallest_p_the_margins_allow() -> None:
    assert smallest_p(0, 12, 0, 12) == 1.0
    # 7 violations on two sides of 12, all on A's: C(12, 7) / C(24, 7) = 792 / 346104
    assert smallest_p(3, 12, 4, 12) == pytest.approx(792 / 346104)
    # Tarone's k: the smallest k with at most k rows reaching 0.05 / k
    assert tarone_family([1.0] * 10 + [0.001]) == 1
    # k=1: 4 rows reach 0.05; k=2: 4 reach 0.025; k=3: 3 reach 0.0167
    assert tarone_family([0.001, 0.001, 0.001, 0.02]) == 3


def test_counts_out_of_range_are_refused() -> None:
    with pytest.raises(ValueError, match="A: violated 5 must be between 0 and checked 4"):
        compare_rates(5, 4, 0, 4)
