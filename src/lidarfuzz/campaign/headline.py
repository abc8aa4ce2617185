"""A finished task's headline figures: what the web app's task list shows and sorts by.

:func:`headline` reads them from the task's summary when it is written
(:func:`lidarfuzz.campaign.lifecycle.finish`) and stores them in ``tasks.headline``, a small JSON
column the list sorts on in SQL (reading every task's summary, tens of kB each, would not keep a
list of 1,000 tasks fast). Tasks finished before the column existed get theirs from their stored
summary the first time the list is read (:func:`fill_headlines`).

The figures:

* ``map``: the originals' mAP, 3D, moderate, AP|R40 (percent), the KITTI figure papers quote;
* ``delta_map``: the worst (lowest) ΔmAP over the mutant subtasks, same metric: the mutant's mAP
  minus the originals' (negative: the operator hurt); the worst, not the mean, since a task's
  operators and severities differ in kind and one harmful setting is what an engineer looks for;
* ``violations``: violated checks summed over every relation and mutant subtask (frame level);
  ``checked`` the checks made, ``violation_rate`` their ratio;
* ``failures``: the system under test's failures (crashes, timeouts, invalid outputs) over every
  subtask; lidarfuzz's own errors are not counted;
* ``ap_warnings``: how many small-sample warnings the task's AP carries (one frame, or classes with
  fewer objects than KITTI's figures need: :func:`lidarfuzz.campaign.results.ap_warnings`), so the
  list can flag an mAP that rests on little.

A figure the task does not have (a camera or structural task has no AP) is None.
"""

from __future__ import annotations

import math
import weakref
from typing import Any

from sqlalchemy import select

from lidarfuzz.campaign.plan import ORIGINAL
from lidarfuzz.store.contracts import TaskSummary
from lidarfuzz.store.models import Status, Task
from lidarfuzz.store.store import Store

#: The metric, difficulty and interpolation of ``map`` and ``delta_map``.
HEADLINE_METRIC = ("3d", "moderate", "R40")
#: The keys of a headline, in the list's order.
HEADLINE_KEYS = ("map", "delta_map", "violations", "checked", "violation_rate", "failures", "ap_warnings")


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def _original_map(summary: TaskSummary) -> float | None:
    metric, difficulty, points = HEADLINE_METRIC
    for entry in summary.subtasks:
        if entry.operator == ORIGINAL and entry.ap is not None:
            return _finite(entry.ap.map.get(metric, {}).get(difficulty, {}).get(points))
    return None


def _worst_delta(summary: TaskSummary) -> float | None:
    metric, difficulty, _ = HEADLINE_METRIC  # the summary's ΔAP rows are AP|R40
    deltas = [row.delta for row in summary.delta_ap
              if row.metric == metric and row.cls == "mAP" and row.difficulty == difficulty]
    finite = [d for d in deltas if d is not None and math.isfinite(d)]
    return min(finite) if finite else None


def headline(summary: TaskSummary | None) -> dict[str, Any]:
    """The list's figures of a finished task (see the module's docstring); all None without a summary.

    Example:
        >>> headline(None)["map"] is None
        True
    """
    empty: dict[str, Any] = dict.fromkeys(HEADLINE_KEYS)
    if summary is None:
        return empty
    violated = sum(row.violated for row in summary.violations.relation)
    checked = sum(row.checked for row in summary.violations.relation)
    failures = sum(entry.failures for entry in summary.subtasks)
    return {**empty, "map": _original_map(summary), "delta_map": _worst_delta(summary),
            "violations": violated if checked else None, "checked": checked,
            "violation_rate": violated / checked if checked else None, "failures": failures,
            "ap_warnings": len(summary.ap_warnings)}


#: The stores :func:`fill_headlines` went through already (once per opened store is enough: from then
#: on :func:`~lidarfuzz.campaign.lifecycle.finish` writes a task's headline with its summary).
_FILLED: weakref.WeakSet[Store] = weakref.WeakSet()


def fill_headlines(store: Store, *, again: bool = False) -> int:
    """Give every finished task without a headline one, from its stored summary (tasks finished by
    a version before the column; an unreadable summary gives a headline of Nones, so it is not read
    again). Done once per opened store unless ``again``: the query reads every task's row, summary
    included, which a list shown every two seconds should not pay. Returns how many were filled."""
    if store in _FILLED and not again:
        return 0
    _FILLED.add(store)
    with store.session() as s:
        ids = list(s.scalars(select(Task.id).where(Task.status == Status.DONE, Task.headline.is_(None))))
        for task_id in ids:
            task = s.get(Task, task_id)
            if task is not None:
                task.headline = headline(task.summary)
                s.flush()
                s.expunge(task)  # its summary can be large: do not keep a thousand of them
    return len(ids)


__all__ = ["HEADLINE_KEYS", "HEADLINE_METRIC", "fill_headlines", "headline"]
