"""``/api/compare``: two or more tasks side by side (the web app's ``#/compare?tasks=3,5``).

The AP table is shown for any tasks: AP at moderate difficulty (AP|R40, per class and mAP) of each
operator × severity, and ΔAP against each task's own originals — AP of one operator and severity
on two systems (or before and after retraining) means something even when the mutants are not
identical. It is not tested for significance: each figure is one evaluation, with no sampling
distribution here.

Violation rates are tested where the mutants are identical (same data set, frames, seed, trials
and operator configurations: :func:`lidarfuzz.campaign.compare.check_comparable`): each task
against the first (the baseline), two-sided, as two one-sided Fisher exact tests (is it worse?
is it better?) at α/2 each, each corrected by Tarone's Bonferroni over its rows
(:func:`lidarfuzz.campaign.compare.compare_tasks`). Tasks that are not comparable get a one-line
reason instead of the test.
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query, status

from lidarfuzz.campaign.compare import compare_tasks
from lidarfuzz.campaign.plan import ORIGINAL, subtask_label
from lidarfuzz.campaign.tasks import get_task
from lidarfuzz.oracles.significance import ALPHA
from lidarfuzz.store.errors import ConflictError
from lidarfuzz.store.models import Status, Task
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.routes.tasks import _moderate, _sample_warnings
from lidarfuzz.web.security.ids import check_id

router = APIRouter(tags=["compare"])
Web = Annotated[WebContext, Depends(web)]

#: How many tasks one comparison shows at most (the table grows by a column group per task).
MAX_COMPARED = 6
TESTED = ("Violation rates: each task against the first (the baseline), two-sided at α = 0.05 (one-sided Fisher "
          "exact tests for worse and for better at α/2 each, Tarone's Bonferroni over each direction's rows), only "
          "where the tasks ran identical mutants. AP and ΔAP (moderate, AP|R40; ΔAP against each task's own "
          "originals) are shown side by side for any tasks but not tested: each is one evaluation.")


def _task_ids(text: str) -> list[int]:
    """``tasks=3,5,7`` as ids: two to :data:`MAX_COMPARED`, distinct (a 422 naming ``tasks``)."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not all(p.isascii() and p.isdigit() and len(p) <= 20 for p in parts):  # not '²', nor 5,000 digits
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"query: field 'tasks': {text[:60]!r} is not a list of task ids (e.g. 3,5)")
    ids = list(dict.fromkeys(check_id(int(p), "query: field 'tasks'") for p in parts))
    if not 2 <= len(ids) <= MAX_COMPARED:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"query: field 'tasks': name 2 to {MAX_COMPARED} different tasks, not {len(ids)}")
    return ids


def _labels(task: Task) -> dict[int, str]:
    """Subtask id → its label, made unique within the task as :mod:`lidarfuzz.campaign.compare` does
    (two configurations of one operator: the key's start appended)."""
    seen: defaultdict[str, int] = defaultdict(int)
    out = {}
    for sub in task.subtasks:
        label = subtask_label(sub.name, sub.severity)
        seen[label] += 1
        out[sub.id] = label if seen[label] == 1 else f"{label} #{sub.operator_key[:6]}"
    return out


def _delta(ap: dict[str, dict[str, float | None]] | None,
           clean: dict[str, dict[str, float | None]] | None) -> dict[str, dict[str, float | None]] | None:
    """ΔAP (mutant − originals) per metric and class, where both have a figure."""
    if ap is None or clean is None:
        return None
    out: dict[str, dict[str, float | None]] = {}
    for metric, row in ap.items():
        base = clean.get(metric, {})
        out[metric] = {cls: (value - b if value is not None and (b := base.get(cls)) is not None else None)
                       for cls, value in row.items()}
    return out


def _cells(task: Task) -> dict[str, dict[str, Any]]:
    """Label → what the AP and rate tables show of that subtask of ``task``."""
    labels = _labels(task)
    clean = next((_moderate(s.results.ap) for s in task.subtasks if s.name == ORIGINAL), None)
    out = {}
    for sub in task.subtasks:
        ap = _moderate(sub.results.ap)
        out[labels[sub.id]] = {
            "ap": ap, "delta": None if sub.name == ORIGINAL else _delta(ap, clean),
            "ap_note": sub.results.ap_note, "sample_warnings": _sample_warnings(sub.results.ap),
            "status": sub.status.value,
            "violations": [r.model_dump(mode="json", by_alias=True) for r in sub.results.violations_total]}
    return out


def _reason(a: Task, b: Task) -> str | None:
    """Why task A's violation rates cannot be tested against B's (None: they can be, so far). The
    checks that name a server path or a command are made here, in the page's words; the rest are
    :func:`~lidarfuzz.campaign.compare.check_comparable`'s, called by :func:`compare_tasks`."""
    for task in (a, b):
        if task.status != Status.DONE:
            return (f"task {task.id} is {task.status.value} ({task.done}/{task.total} units): only finished tasks "
                    "are tested")
    for task in (a, b):
        if task.options.kind != "mutation":  # a search draws its own tests; a camera task has no boxes to compare
            return (f"task {task.id} is a {task.options.kind} task: violation rates are tested between detection "
                    "campaigns (operators × severities)")
    if a.dataset.path != b.dataset.path:
        return f"different data sets: task {a.id} ran {a.dataset.name!r}, task {b.id} {b.dataset.name!r}"
    return None


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _rate_rows(store: Any, task_id: int, baseline: int) -> list[dict[str, Any]]:
    """The frame-level rows (and objects lost) of ``task_id`` against ``baseline``, both directions at α/2."""
    worse = compare_tasks(store, task_id, baseline, alpha=ALPHA / 2, breakdown=False)
    better = compare_tasks(store, baseline, task_id, alpha=ALPHA / 2, breakdown=False)
    reverse = {(r.label, r.relation, r.cls): r for r in better.rows}
    rows = []
    for row in worse.rows:
        if row.cls:
            continue  # the per-class rows are in the report's comparison; the page shows the frame level
        other = reverse.get((row.label, row.relation, row.cls))
        verdict = "worse" if row.significant else "better" if other is not None and other.significant else None
        rows.append({"label": row.label, "relation": row.relation, "violated": row.violated_a,
                     "checked": row.checked_a, "violated_baseline": row.violated_b, "checked_baseline": row.checked_b,
                     "difference": _finite(row.difference), "p_worse": _finite(row.p_adjusted),
                     "p_better": _finite(other.p_adjusted) if other is not None else None, "significant": verdict})
    return rows


def _pair(store: Any, task: Task, baseline: Task) -> dict[str, Any]:
    reason = _reason(task, baseline)
    rows: list[dict[str, Any]] = []
    if reason is None:
        try:
            rows = _rate_rows(store, task.id, baseline.id)
        except ConflictError as exc:
            reason = str(exc).removeprefix("not comparable: ")
    return {"task": task.id, "baseline": baseline.id, "comparable": reason is None, "reason": reason, "rows": rows}


@router.get("/compare")
def compare(ctx: Web, tasks: Annotated[str, Query(description="task ids, comma-separated: the first is the "
                                                              "baseline", examples=["3,5"])]) -> dict[str, Any]:
    """Tasks side by side: AP and ΔAP of every operator × severity, violation rates, and each task's
    rates tested against the first's where the mutants are identical (``tested`` says what is)."""
    ids = _task_ids(tasks)
    rows = [get_task(ctx.store, task_id) for task_id in ids]  # 404 naming a missing one
    cells = [_cells(task) for task in rows]
    labels = list(dict.fromkeys(label for table in cells for label in table))
    return {
        "tasks": [{"id": t.id, "name": t.name, "status": t.status.value, "dataset": t.dataset.name,
                   "model": t.model.name, "frames": len(t.options.frame_ids), "seed": t.seed} for t in rows],
        "baseline": ids[0], "alpha": ALPHA, "tested": TESTED,
        "rows": [{"label": label, "cells": [table.get(label) for table in cells]} for label in labels],
        "pairs": [_pair(ctx.store, task, rows[0]) for task in rows[1:]],
    }
