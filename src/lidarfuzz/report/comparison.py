"""The report's differential-testing section: the system's violation rates beside a reference
system's or a baseline task's (:class:`lidarfuzz.campaign.compare.TaskComparison`), the rows
significantly above, the units where they disagree, and recall and AP by group.

:func:`comparisons_for` finds what a task is compared with (``--baseline``, or the reference
tasks its campaign created) and says why a comparison could not be made;
:func:`comparison_view` formats one for ``comparison.html.j2``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lidarfuzz.campaign.compare import TaskComparison
    from lidarfuzz.store.store import Store

DASH = "–"
#: Disagreeing units the HTML lists (the JSON beside it has every one the comparison keeps).
SHOWN_DISAGREEMENTS = 30


def comparisons_for(store: Store, task_id: int, baseline: int | None = None) -> tuple[list[TaskComparison],
                                                                                       list[str]]:
    """The comparisons of task ``task_id`` with ``baseline`` (when given) or else with the reference
    tasks its campaign created, and a note for each that could not be made (not finished, not comparable)."""
    from lidarfuzz.campaign.compare import compare_tasks, references_of
    from lidarfuzz.store.errors import StoreError

    others = [baseline] if baseline is not None else references_of(store, task_id)
    done, notes = [], []
    for other in others:
        try:
            done.append(compare_tasks(store, task_id, other))
        except StoreError as exc:
            notes.append(f"no comparison with task {other}: {exc}")
    return done, notes


def _pct(value: float) -> str:
    return DASH if math.isnan(value) else f"{100 * value:.1f}%"


def _p(value: float) -> str:
    if math.isnan(value):
        return DASH
    return f"{value:.2g}" if value < 0.01 else f"{value:.3f}"


def _ap(value: float) -> str:
    return DASH if math.isnan(value) else f"{value:.1f}"


def comparison_view(comparison: TaskComparison) -> dict[str, Any]:
    """What ``comparison.html.j2`` shows of one comparison, formatted: the rows with a violation
    on either side (every row of a relation is counted in the caption)."""
    rows = [r for r in comparison.rows if r.violated_a or r.violated_b]
    return {
        "a": comparison.a, "b": comparison.b, "test": comparison.test, "correction": comparison.correction,
        "alpha": f"{comparison.alpha:g}", "rows_total": len(comparison.rows),
        "rows": [{"label": r.label, "relation": r.relation, "cls": r.cls or "any",
                  "a": f"{r.violated_a}/{r.checked_a}", "rate_a": _pct(r.rate_a),
                  "b": f"{r.violated_b}/{r.checked_b}", "rate_b": _pct(r.rate_b),
                  "p": _p(r.p_value), "p_adjusted": _p(r.p_adjusted), "significant": r.significant} for r in rows],
        "significant": len(comparison.significant),
        "disagreements_total": comparison.disagreements_total,
        "by_side": comparison.disagreements_by_side,
        "disagreements": comparison.disagreements[:SHOWN_DISAGREEMENTS],
        "breakdown": [{"scope": g.scope, "dimension": g.dimension, "group": g.group, "objects": g.objects,
                       "recall_a": _pct(g.recall_a), "recall_b": _pct(g.recall_b),
                       "worse": g.recall_a < g.recall_b, "ap_bev_a": _ap(g.ap_bev_a), "ap_bev_b": _ap(g.ap_bev_b),
                       "ap_3d_a": _ap(g.ap_3d_a), "ap_3d_b": _ap(g.ap_3d_b)} for g in comparison.breakdown],
        "breakdown_rule": comparison.breakdown_rule, "breakdown_ap": comparison.breakdown_ap,
    }


__all__ = ["comparison_view", "comparisons_for"]
