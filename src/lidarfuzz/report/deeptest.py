"""DeepTest's Table 7 in a report: erroneous mutants per λ (rows) and ε (columns).

The view model of the HTML report's DeepTest section (``templates/deeptest.html.j2``) and the lines
``lidarfuzz report`` prints, both from the task summary's
:class:`~lidarfuzz.store.contracts.DeepTestTable` (:func:`lidarfuzz.campaign.results.deeptest_table`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lidarfuzz.store.contracts import DeepTestTable

DASH = "–"


def fmt_mse(value: float | None) -> str:
    """An MSE in m², three significant digits; undefined as a dash."""
    if value is None or math.isnan(value) or math.isinf(value):
        return DASH
    return f"{value:.3g}"


def _column(table: DeepTestTable, value: float) -> int | None:
    """Index of ``value`` among the table's ε values (None when it is not on the grid)."""
    return next((i for i, v in enumerate(table.epsilons) if math.isclose(v, value)), None)


def deeptest_view(table: DeepTestTable | None, *, steering: bool = False) -> dict[str, Any] | None:
    """What the report's DeepTest section shows (None: no subtask checked ``deeptest_tolerance``);
    ``steering``: a camera task's (errors of steering angles against labels, not of object centres)."""
    if table is None:
        return None
    lam, eps = table.configured_lambda, table.configured_epsilon
    eps_at = _column(table, eps)
    rows = []
    for value, counts, unfiltered in zip(table.lambdas if table.counts else [], table.counts, table.unfiltered,
                                         strict=True):
        rows.append({"lambda": f"{value:g}", "counts": counts, "unfiltered": unfiltered,
                     "configured": math.isclose(value, lam)})
    return {
        "steering": steering,
        "mse_orig": fmt_mse(table.mse_orig),
        "lambda": f"{lam:g}" if math.isfinite(lam) else DASH,
        "epsilon": f"{eps:g}" if math.isfinite(eps) else DASH,
        "epsilons": [f"{e:g}" for e in table.epsilons],
        "configured_column": eps_at,
        "rows": rows,
        "transformations": [{"label": t.label, "mse": fmt_mse(t.mse), "difference": fmt_mse(t.difference),
                             "objects": t.objects, "mutants": t.mutants, "violated": t.violated, "kept": t.kept,
                             "filtered": t.filtered}
                            for t in table.transformations],
        "notes": list(table.notes),
    }


def deeptest_lines(table: DeepTestTable | None) -> list[str]:
    """Table 7 as plain text lines (``lidarfuzz report``); empty without a table."""
    view = deeptest_view(table)
    if view is None:
        return []
    lines = [f"DeepTest (Eq. 2, 3): MSE_orig = {view['mse_orig']} m² over the original data set; "
             f"the relation's λ = {view['lambda']}, ε = {view['epsilon']}"]
    if view["rows"]:
        width = max(6, *(len(e) for e in view["epsilons"]))
        lines.append("erroneous mutants, Table 7 form (λ rows, ε columns; 'none': no ε filter):")
        lines.append("λ".rjust(4) + "".join(e.rjust(width + 1) for e in [*view["epsilons"], "none"]))
        for row in view["rows"]:
            lines.append(row["lambda"].rjust(4) + "".join(str(n).rjust(width + 1)
                                                         for n in [*row["counts"], row["unfiltered"]]))
    for t in view["transformations"]:
        verdict = "kept" if t["kept"] else "dropped"
        lines.append(f"  {t['label']}: MSE_t {t['mse']} (MSE_t − MSE_orig {t['difference']}) over {t['objects']} "
                     f"objects; {t['violated']}/{t['mutants']} mutants violate Eq. 2; {verdict} by ε = "
                     f"{view['epsilon']}")
    lines.extend(f"  note: {note}" for note in view["notes"])
    return lines


__all__ = ["deeptest_lines", "deeptest_view", "fmt_mse"]
