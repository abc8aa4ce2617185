"""Is one system's violation rate significantly above another's?

A relation violated on 9 of 20 frames by the system under test and on 1 of 20 by a reference
(a correct system, or the previous version) is a finding about the system; 2 of 20 against
1 of 20 is the floor. :func:`compare_rates` decides with a **one-sided Fisher exact test**
(``scipy.stats.fisher_exact(..., alternative="greater")`` on the 2 × 2 table of violated and
not violated frames): exact at the small counts a campaign has (a z-test's normal approximation
is not), and never significant when A's rate is not above B's. The threshold is
:data:`ALPHA` = 0.05.

A comparison tests many rows at once (operator × severity × relation × class), so
:func:`compare_many` controls the family-wise error with **Tarone's modified Bonferroni
correction** (Tarone 1990, for discrete tests): a row whose counts could not give a small
p-value whatever their split between A and B (no violation on either side, or one) cannot be
significant, so it does not count in the family. With ``k`` the smallest number such that at most
``k`` rows could reach ``α / k``, a row is significant when ``k × p < α``. A campaign's many rows
where neither system violates anything then cost a real finding nothing, where plain Bonferroni
or Holm over every row would drown it. :func:`holm` is kept for callers that want it.

Example:
    >>> row = compare_rates(9, 20, 1, 20)
    >>> round(row.p_value, 4), row.significant
    (0.0042, True)
    >>> compare_rates(2, 20, 1, 20).significant
    False
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

#: Significance threshold of every comparison lidarfuzz reports.
ALPHA = 0.05
#: The test, as reports name it.
TEST_NAME = "one-sided Fisher exact test (A's rate > B's)"
#: The multiple-comparison correction over a comparison's rows, as reports name it.
CORRECTION_NAME = "Tarone's Bonferroni over the rows that could be significant"


@dataclass(frozen=True)
class RateComparison:
    """A's and B's violation counts and whether A's rate is significantly higher.

    Attributes:
        violated_a, checked_a: A's violating and checked frames.
        violated_b, checked_b: B's.
        p_value: The one-sided Fisher exact p-value (NaN when either side checked nothing).
        p_adjusted: After Tarone's correction over a family of rows (``p_value`` when alone).
        alpha: The threshold.
        significant: ``p_adjusted < alpha``.
    """

    violated_a: int
    checked_a: int
    violated_b: int
    checked_b: int
    p_value: float
    p_adjusted: float
    alpha: float = ALPHA

    @property
    def rate_a(self) -> float:
        return self.violated_a / self.checked_a if self.checked_a else math.nan

    @property
    def rate_b(self) -> float:
        return self.violated_b / self.checked_b if self.checked_b else math.nan

    @property
    def difference(self) -> float:
        """A's rate minus B's (NaN when either is undefined)."""
        return self.rate_a - self.rate_b

    @property
    def tested(self) -> bool:
        return not math.isnan(self.p_value)

    @property
    def significant(self) -> bool:
        return self.tested and self.p_adjusted < self.alpha


def fisher_greater(violated_a: int, checked_a: int, violated_b: int, checked_b: int) -> float:
    """One-sided p-value of "A violates more often than B" (NaN when a side checked nothing)."""
    for name, violated, checked in (("A", violated_a, checked_a), ("B", violated_b, checked_b)):
        if not 0 <= violated <= checked:
            raise ValueError(f"{name}: violated {violated} must be between 0 and checked {checked}")
    if checked_a == 0 or checked_b == 0:
        return math.nan
    from scipy.stats import fisher_exact  # scipy's import takes a while: only when testing

    table = [[violated_a, checked_a - violated_a], [violated_b, checked_b - violated_b]]
    return float(fisher_exact(table, alternative="greater").pvalue)


def compare_rates(violated_a: int, checked_a: int, violated_b: int, checked_b: int, *,
                  alpha: float = ALPHA) -> RateComparison:
    """One row on its own (no correction)."""
    p = fisher_greater(violated_a, checked_a, violated_b, checked_b)
    return RateComparison(violated_a, checked_a, violated_b, checked_b, p, p, alpha)


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjusted p-values (NaN entries are not tested and stay NaN).

    With ``m`` tested p-values sorted ascending, the ``k``-th (from 0) becomes
    ``max_{j <= k} min(1, (m - j) p_(j))``.

    Example:
        >>> [round(p, 6) for p in holm([0.01, 0.04, 0.03, float("nan")])]  # m = 3: 3 x 0.01, 2 x 0.03, max(0.06, 0.04)
        [0.03, 0.06, 0.06, nan]
    """
    tested = sorted((p, i) for i, p in enumerate(p_values) if not math.isnan(p))
    out = [math.nan] * len(p_values)
    m = len(tested)
    running = 0.0
    for rank, (p, index) in enumerate(tested):
        running = max(running, min(1.0, (m - rank) * p))
        out[index] = running
    return out


def smallest_p(violated_a: int, checked_a: int, violated_b: int, checked_b: int) -> float:
    """The smallest one-sided p-value these margins allow: every violation on A's side (NaN when a
    side checked nothing). 0 of 12 against 0 of 12 can reach no less than 1; 7 violations among
    two sides of 12 no less than C(12, 7) / C(24, 7) = 0.0023."""
    total = violated_a + violated_b
    most = min(total, checked_a)
    return fisher_greater(most, checked_a, total - most, checked_b) if total - most <= checked_b else math.nan


def tarone_family(smallest: Sequence[float], alpha: float = ALPHA) -> int:
    """Tarone's ``k``: the smallest number of rows such that at most ``k`` of them can reach ``α / k``
    (NaN rows never can). At least 1."""
    reachable = sorted(p for p in smallest if not math.isnan(p))
    for k in range(1, len(reachable) + 1):
        if sum(p <= alpha / k for p in reachable) <= k:
            return k
    return max(len(reachable), 1)


def compare_many(counts: Sequence[tuple[int, int, int, int]], *, alpha: float = ALPHA) -> list[RateComparison]:
    """Rows of ``(violated_a, checked_a, violated_b, checked_b)``, corrected together by Tarone's
    modified Bonferroni: ``p_adjusted = min(1, k p)`` with ``k`` from :func:`tarone_family`."""
    rows = [compare_rates(*c, alpha=alpha) for c in counts]
    k = tarone_family([smallest_p(*c) for c in counts], alpha)
    return [replace(r, p_adjusted=r.p_value if math.isnan(r.p_value) else min(1.0, k * r.p_value)) for r in rows]


__all__ = ["ALPHA", "CORRECTION_NAME", "TEST_NAME", "RateComparison", "compare_many", "compare_rates",
           "fisher_greater", "holm", "smallest_p", "tarone_family"]
