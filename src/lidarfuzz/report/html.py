"""The self-contained HTML report of a task.

One file that works offline and prints: CSS inline, charts and pictures as base64 PNG data
URIs, a few lines of JavaScript to switch the AP table's difficulty and interpolation (with
JavaScript off, the table shows the default, moderate AP|R40). Everything shown comes from the
task summary (:func:`lidarfuzz.campaign.results.summarise`) — the pictures of findings, which
need the store and the data set, are drawn beforehand (:mod:`lidarfuzz.report.bev`) and passed in.
A summary read back from JSON (``report.json``) is validated first:
``render_html(TaskSummary.model_validate(data))``.

Example:
    >>> from lidarfuzz.campaign.results import summarise  # doctest: +SKIP
    >>> html = render_html(summarise(store, 1))  # doctest: +SKIP
"""

from __future__ import annotations

import base64
import math
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from lidarfuzz.report.charts import ap_value, charts
from lidarfuzz.report.deeptest import deeptest_view

if TYPE_CHECKING:
    from lidarfuzz.campaign.compare import TaskComparison
    from lidarfuzz.campaign.ratings import RatingTally
    from lidarfuzz.store.contracts import DeltaRow, RateRow, TaskSummary

DIFFICULTIES = ("easy", "moderate", "hard")
POINTS = ("R40", "R11")
METRICS = (("bbox", "bbox"), ("bev", "BEV"), ("3d", "3D"))
SUT_FAILURES = ("crash", "timeout", "invalid_output")
DASH = "–"


# -- formatting ---------------------------------------------------------------------------
def _number(value: Any) -> float | None:
    if value is None or isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(number) or math.isinf(number) else number


def fmt_ap(value: Any) -> str:
    """AP to one decimal; None or NaN as a dash."""
    number = _number(value)
    return DASH if number is None else f"{number:.1f}"


def fmt_delta(value: Any) -> str:
    number = _number(value)
    if number is None:
        return DASH
    if abs(number) < 0.05:
        return "±0.0"
    return f"{number:+.1f}".replace("-", "−")


def fmt_pct(value: Any) -> str:
    """A rate in [0, 1] as a percentage."""
    number = _number(value)
    return DASH if number is None else f"{100 * number:.1f}%"


def fmt_ratio(value: Any) -> str:
    number = _number(value)
    return DASH if number is None else f"{number:.3f}"


def fmt_seconds(value: Any) -> str:
    number = _number(value)
    if number is None:
        return DASH
    return f"{number:.1f} s" if number < 120 else f"{number / 60:.1f} min"


def fmt_time(value: Any) -> str:
    if not value:
        return DASH
    try:
        return datetime.fromisoformat(str(value)).strftime("%Y-%m-%d %H:%M:%S")
    except ValueError:
        return str(value)


def data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _plural(n: int, word: str, many: str | None = None) -> str:
    return f"{n} {word if n == 1 else (many or word + 's')}"


# -- the view model -----------------------------------------------------------------------
def _ap_tables(summary: TaskSummary) -> list[dict[str, Any]]:
    """One table per difficulty × interpolation; each subtask has rows bbox, BEV, 3D."""
    classes = [*summary.classes, "mAP"]
    subtasks = summary.subtasks
    original = subtasks[0] if subtasks and subtasks[0].label == "original" else None
    tables = []
    for difficulty in DIFFICULTIES:
        for points in POINTS:
            groups = []
            for entry in subtasks:
                ap = entry.ap
                rows = []
                for metric, metric_name in METRICS:
                    cells = []
                    for cls in classes:
                        value = ap_value(ap, metric, cls, difficulty, points)
                        delta = None
                        if entry is not original and original is not None and value is not None:
                            clean = ap_value(original.ap, metric, cls, difficulty, points)
                            delta = None if clean is None else value - clean
                        cells.append({"value": fmt_ap(value), "delta": None if delta is None else fmt_delta(delta),
                                      "worse": delta is not None and delta < -0.05,
                                      "better": delta is not None and delta > 0.05})
                    rows.append({"metric": metric_name, "cells": cells})
                if ap is not None:
                    note = ""
                elif entry.status != "done":
                    note = f"not evaluated yet ({entry.done}/{entry.total} frames)"
                else:
                    note = entry.ap_note or "no AP: the data set has no labels"
                groups.append({"label": entry.label, "note": note, "rows": rows})
            tables.append({"difficulty": difficulty, "points": points, "classes": classes, "groups": groups,
                           "default": difficulty == "moderate" and points == "R40"})
    return tables


def _worst_drop(summary: TaskSummary) -> DeltaRow | None:
    rows = [r for r in summary.delta_ap if r.metric == "3d" and r.cls == "mAP" and r.difficulty == "moderate"
            and math.isfinite(r.delta)]
    return min(rows, key=lambda r: r.delta) if rows else None


def _headline(summary: TaskSummary) -> str:
    """The one-paragraph summary in plain language."""
    from lidarfuzz.report.structural import headline as structural_headline

    structural = structural_headline(summary)
    if structural is not None:
        return structural
    from lidarfuzz.report.camera import headline as camera_headline

    camera = camera_headline(summary)
    if camera is not None:
        return camera
    task = summary.task
    subtasks = summary.subtasks
    mutated = len(subtasks[1:])
    trials = task.trials or 1
    parts = [f"lidarfuzz tested {task.model.name} on {task.dataset.name}"
             f" with {_plural(task.frames, 'frame')} and {_plural(mutated, 'mutation subtask')} "
             f"(operator × severity, {_plural(trials, 'trial')} per frame)."]
    if task.status != "done":
        parts.append(f"The task is {task.status} ({task.done} of {task.total} units): "
                     f"the figures below cover what has finished.")
    clean = ap_value(subtasks[0].ap if subtasks else None, "3d", "mAP", "moderate", "R40")
    if clean is not None:
        parts.append(f"On the original frames, 3D mAP (moderate, AP|R40) is {clean:.1f}.")
        worst = _worst_drop(summary)
        if worst is not None and worst.delta < 0:
            parts.append(f"The largest drop comes with {worst.label}: {-worst.delta:.1f} points, to "
                         f"{worst.corrupted:.1f}.")
        elif worst is not None:
            parts.append("No mutation lowered it.")
    elif subtasks:
        parts.append("There is no AP: the data set has no labels, or the originals are not evaluated yet.")
    relations = [r for r in summary.violations.relation if r.violated]
    if relations:
        top = max(relations, key=lambda r: (r.rate or 0.0, r.violated))
        per_op = [r for r in summary.violations.relation_operator if r.relation == top.relation and r.violated]
        text = (f"The most violated relation is {top.relation}: {top.violated} of {top.checked} checked "
                f"frames ({fmt_pct(top.rate)})")
        if len(per_op) > 1:
            worst_op = max(per_op, key=lambda r: (r.rate or 0.0, r.violated))
            text += f", most often under {worst_op.operator} ({fmt_pct(worst_op.rate)})"
        parts.append(text + ".")
    elif summary.violations.relation:
        parts.append("No metamorphic relation was violated.")
    by_kind = summary.findings.by_kind
    failures = {k: int(by_kind.get(k, 0)) for k in SUT_FAILURES[:3] if by_kind.get(k)}
    if failures:
        parts.append("The system failed on " + ", ".join(_plural(n, k.replace("_", " ")) for k, n in failures.items())
                     + " (see SUT failures).")
    else:
        parts.append("The system never crashed, timed out or returned invalid output.")
    tool: dict[str, int] = defaultdict(int)
    for entry in subtasks:
        for kind, n in entry.tool_errors.items():
            tool[kind] += n
    if any(tool.values()):
        causes = (("operator_error", "where a mutation operator failed"), ("oracle_error", "where a relation failed"))
        said = [f"{_plural(n, 'frame')} {what}" for kind, what in causes if (n := tool.get(kind, 0))]
        if said:
            parts.append("lidarfuzz's own errors, not the system's: " + " and ".join(said) + " (see SUT failures).")
        if faults := tool.get("data_error", 0):
            parts.append(f"Not the system's either: {_plural(faults, 'unit')} whose frame could not be read (data "
                         "faults, left out of AP: restore the files and resume the task).")
    return " ".join(parts)


def _robustness(summary: TaskSummary) -> dict[str, Any] | None:
    robustness = summary.robustness
    metrics = [(m, name) for m, name in METRICS if m in robustness]
    if not metrics:
        return None
    errors = [f"{name}: {robustness[m].error}" for m, name in metrics if robustness[m].error is not None]
    metrics = [(m, name) for m, name in metrics if robustness[m].error is None]
    with_ce = any(_number(robustness[m].mCE) is not None for m, _ in metrics)
    operators: dict[str, dict[str, Any]] = {}
    for metric, _ in metrics:
        for row in robustness[metric].operators:
            entry = operators.setdefault(row.operator, {"operator": row.operator, "severities": row.severities,
                                                        "rr": {}, "ce": {}})
            entry["rr"][metric] = fmt_ratio(row.RR)
            entry["ce"][metric] = fmt_ratio(row.CE)
    order = [s.operator for s in summary.subtasks]
    ranked = sorted(operators.values(), key=lambda e: order.index(e["operator"]) if e["operator"] in order
                    else len(order))
    first = robustness[metrics[0][0]] if metrics else None
    return {"metrics": metrics, "with_ce": with_ce, "operators": ranked, "errors": errors,
            "clean": {m: fmt_ap(robustness[m].clean_ap) for m, _ in metrics},
            "baseline_clean": {m: fmt_ap(robustness[m].baseline_clean_ap) for m, _ in metrics},
            "mrr": {m: fmt_ratio(robustness[m].mRR) for m, _ in metrics},
            "mce": {m: fmt_ratio(robustness[m].mCE) for m, _ in metrics},
            "notes": sorted({n for m, _ in metrics for n in robustness[m].notes}),
            "difficulty": first.difficulty if first is not None else "moderate",
            "points": first.points if first is not None else "R40",
            "cls": (first.cls if first is not None else None) or "mAP"}


def _cell(row: RateRow | None) -> dict[str, Any]:
    if row is None:
        return {"text": DASH, "counts": "", "level": -1}
    rate = _number(row.rate)
    level = -1 if rate is None else min(4, int(rate * 5)) if row.violated else 0
    return {"text": fmt_pct(rate), "counts": f"{row.violated}/{row.checked}", "level": level}


def _group(row: RateRow, key: str) -> Any:
    """The value of grouping key ``key`` (``relation``, ``operator``, ``label``, ``class``) of ``row``."""
    return row.cls if key == "class" else getattr(row, key)


def _matrix(rows: Sequence[RateRow], row_key: str, col_key: str, row_order: Iterable[str],
            col_order: Iterable[str]) -> dict[str, Any]:
    lookup = {(_group(r, row_key), _group(r, col_key)): r for r in rows}
    row_names = [r for r in row_order if any(k[0] == r for k in lookup)]
    col_names = [c for c in col_order if any(k[1] == c for k in lookup)]
    return {"columns": col_names,
            "rows": [{"name": r, "cells": [_cell(lookup.get((r, c))) for c in col_names]} for r in row_names]}


def _violations(summary: TaskSummary) -> dict[str, Any]:
    violations = summary.violations
    subtasks = summary.subtasks[1:]
    from lidarfuzz.oracles.relations.registry import available

    # A relation whose plugin is gone has no description; a broken plugin is left out, with a warning.
    descriptions = {name: cls.description for name, cls in available().items()}
    relation_names = [r.relation or "" for r in violations.relation]
    operators = list(dict.fromkeys(s.operator for s in subtasks))
    labels = [s.label for s in subtasks]
    classes = [*summary.classes, ""]
    by_class = _matrix(violations.relation_class, "relation", "class", relation_names, classes)
    by_class["columns"] = [c or "frame-level" for c in by_class["columns"]]
    by_object = _matrix(violations.relation_class_objects, "relation", "class", relation_names, classes)
    by_object["columns"] = [c or "frame-level" for c in by_object["columns"]]
    return {
        "relations": [{"relation": r.relation, "checked": r.checked, "violated": r.violated,
                       "rate_text": fmt_pct(r.rate), "description": descriptions.get(r.relation or "", ""),
                       "level": _cell(r)["level"]} for r in violations.relation],
        "by_operator": _matrix(violations.relation_operator, "operator", "relation", operators, relation_names),
        "by_label": _matrix(violations.relation_label, "label", "relation", labels, relation_names),
        "by_class": by_class,
        "objects": by_object,
        "count_form": [{"label": r.label, "checked": r.checked, "violated": r.violated, "rate_text": fmt_pct(r.rate)}
                       for r in violations.count_form],
        "regions": _regions(summary),
    }


#: What the regions named in ``outside_roi_scatter``'s params are, for the report's reader.
REGION_NAMES = {"frame_map": "the frame's own map", "dataset_map": "the data set's map",
                "estimated": "the drivable area estimated from the scan", "boxes": "outside the labelled boxes only",
                "roi": "the frame's map"}


def _regions(summary: TaskSummary) -> list[dict[str, str]]:
    """Per subtask whose mutants avoided a region (``outside_roi_scatter``): which, on how many frames."""
    out = []
    for entry in summary.subtasks[1:]:
        regions = entry.regions or {}
        if regions:
            text = ", ".join(f"{REGION_NAMES.get(name, name)} ({name}) on {_plural(int(n), 'frame')}"
                             for name, n in regions.items())
            out.append({"label": entry.label, "text": text})
    return out


def _failures(summary: TaskSummary) -> dict[str, Any]:
    by_kind = summary.findings.by_kind
    kinds = [{"kind": k, "count": int(by_kind.get(k, 0))} for k in SUT_FAILURES]
    per_subtask = [{"label": s.label, "failures": s.failures} for s in summary.subtasks if s.failures]
    tool = {"operator_error": 0, "oracle_error": 0}
    for entry in summary.subtasks:
        for kind, n in entry.tool_errors.items():
            tool[kind] = tool.get(kind, 0) + n
    return {"kinds": kinds, "total": sum(k["count"] for k in kinds), "per_subtask": per_subtask,
            "operator_errors": tool["operator_error"], "oracle_errors": tool["oracle_error"],
            "data_faults": tool.get("data_error", 0)}


def _findings(summary: TaskSummary, images: Mapping[int, bytes | str] | None) -> list[dict[str, Any]]:
    out = []
    for finding in summary.findings.top:
        image = (images or {}).get(finding.id)
        magnitude = _number(finding.magnitude)
        out.append({"id": finding.id, "kind": finding.kind, "cls": finding.cls, "label": finding.label,
                    "frame_id": finding.frame_id, "trial": finding.trial, "message": finding.message,
                    "replay": finding.replay, "magnitude_text": DASH if magnitude is None else f"{magnitude:g}",
                    "image": data_uri(image) if isinstance(image, bytes) else None,
                    "note": image if isinstance(image, str) else ""})
    return out


def context(summary: TaskSummary, *, images: Mapping[int, bytes | str] | None = None,
            chart_pngs: Mapping[str, bytes] | None = None, image_limit: int | None = None,
            comparisons: Sequence[TaskComparison] = (), comparison_notes: Sequence[str] = (),
            ratings: RatingTally | None = None) -> dict[str, Any]:
    """Everything the template shows, formatted."""
    from lidarfuzz import __version__
    from lidarfuzz.report.camera import is_camera
    from lidarfuzz.report.comparison import comparison_view
    from lidarfuzz.report.ratings import ratings_view
    from lidarfuzz.report.structural import structural_view

    task = summary.task
    camera = is_camera(summary)
    drawn = {} if camera else charts(summary) if chart_pngs is None else chart_pngs
    subtasks = summary.subtasks
    unfinished = task.status != "done" or any(s.status != "done" for s in subtasks)
    title = f"lidarfuzz report — task {task.id}" + (f": {task.name}" if task.name else "")
    return {
        "title": title,
        "task": task,
        "fingerprint": task.model.fingerprint[:12],
        "times": {"created_at": fmt_time(task.created_at), "started_at": fmt_time(task.started_at),
                  "finished_at": fmt_time(task.finished_at)},
        "run": summary.run,
        "unfinished": unfinished,
        "headline": _headline(summary),
        "ap_tables": _ap_tables(summary),
        "ap_warnings": list(summary.ap_warnings),
        "has_ap": any(s.ap is not None for s in subtasks),
        "charts": {name: data_uri(png) for name, png in drawn.items()},
        "robustness": _robustness(summary),
        "violations": _violations(summary),
        "deeptest": deeptest_view(summary.deeptest, steering=camera),
        "camera": camera,
        "structural": structural_view(summary),
        "failures": _failures(summary),
        "findings": _findings(summary, images),
        "findings_total": summary.findings.total,
        "image_limit": image_limit,
        "version": __version__,
        "generated": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "baseline": task.baseline,
        "comparisons": [comparison_view(c) for c in comparisons],
        "comparison_notes": list(comparison_notes),
        "ratings": ratings_view(ratings),
    }


def _environment() -> Any:
    from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape

    env = Environment(loader=PackageLoader("lidarfuzz.report", "templates"), autoescape=select_autoescape(
        ["html", "j2"], default_for_string=True, default=True), undefined=StrictUndefined, trim_blocks=True,
                      lstrip_blocks=True)
    env.filters.update(ap=fmt_ap, pct=fmt_pct, ratio=fmt_ratio, seconds=fmt_seconds)
    return env


def render_html(summary: TaskSummary, *, images: Mapping[int, bytes | str] | None = None,
                chart_pngs: Mapping[str, bytes] | None = None, image_limit: int | None = None,
                comparisons: Sequence[TaskComparison] = (), comparison_notes: Sequence[str] = (),
                ratings: RatingTally | None = None) -> str:
    """The report of ``summary`` as one HTML document.

    Args:
        summary: A task summary (:func:`lidarfuzz.campaign.results.summarise`).
        images: Pictures of findings by finding id: PNG bytes, or a note why there is none
            (:func:`lidarfuzz.report.bev.finding_images`).
        chart_pngs: Charts by name (``ap``, ``delta``, ``violations``); drawn here when None.
        image_limit: How many pictures were asked for (shown when findings have none).
        comparisons: Comparisons with reference or baseline tasks (:mod:`lidarfuzz.report.comparison`).
        comparison_notes: Why a comparison that was asked for could not be made.
        ratings: Raters' verdicts on the task's pairs (:func:`lidarfuzz.campaign.ratings.tally`):
            the thesis's Table 6-7 section, shown when there are any.
    """
    template = _environment().get_template("report.html.j2")
    return template.render(**context(summary, images=images, chart_pngs=chart_pngs, image_limit=image_limit,
                                     comparisons=comparisons, comparison_notes=comparison_notes, ratings=ratings))


__all__ = ["context", "fmt_ap", "fmt_delta", "fmt_pct", "render_html"]
