"""The self-contained HTML report of a task.

One file that works offline and prints: CSS inline, charts and pictures as base64 PNG data
URIs, a few lines of JavaScript to switch the AP table's difficulty and interpolation (with
JavaScript off, the table shows the default, moderate AP|R40). Everything shown comes from the
task summary (:func:`lidarfuzz.campaign.results.summarise`) — the pictures of findings, which
need the store and the data set, are drawn beforehand (:mod:`lidarfuzz.report.bev`) and passed in.

Example:
    >>> from lidarfuzz.campaign.results import summarise  # doctest: +SKIP
    >>> html = render_html(summarise(store, 1))  # doctest: +SKIP
"""

from __future__ import annotations

import base64
import math
from collections.abc import Iterable, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

from lidarfuzz.report.charts import ap_value, charts

DIFFICULTIES = ("easy", "moderate", "hard")
POINTS = ("R40", "R11")
METRICS = (("bbox", "bbox"), ("bev", "BEV"), ("3d", "3D"))
SUT_FAILURES = ("crash", "timeout", "invalid_output", "operator_error")
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
def _ap_tables(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One table per difficulty × interpolation; each subtask has rows bbox, BEV, 3D."""
    classes = [*summary.get("classes", ["Car", "Pedestrian", "Cyclist"]), "mAP"]
    subtasks = summary.get("subtasks", [])
    original = subtasks[0] if subtasks and subtasks[0].get("label") == "original" else None
    tables = []
    for difficulty in DIFFICULTIES:
        for points in POINTS:
            groups = []
            for entry in subtasks:
                ap = entry.get("ap")
                rows = []
                for metric, metric_name in METRICS:
                    cells = []
                    for cls in classes:
                        value = ap_value(ap, metric, cls, difficulty, points)
                        delta = None
                        if entry is not original and original is not None and value is not None:
                            clean = ap_value(original.get("ap"), metric, cls, difficulty, points)
                            delta = None if clean is None else value - clean
                        cells.append({"value": fmt_ap(value), "delta": None if delta is None else fmt_delta(delta),
                                      "worse": delta is not None and delta < -0.05,
                                      "better": delta is not None and delta > 0.05})
                    rows.append({"metric": metric_name, "cells": cells})
                if ap:
                    note = ""
                elif entry.get("status") != "done":
                    note = f"not evaluated yet ({entry.get('done', 0)}/{entry.get('total', 0)} frames)"
                else:
                    note = entry.get("ap_note") or "no AP: the data set has no labels"
                groups.append({"label": entry.get("label", ""), "note": note, "rows": rows})
            tables.append({"difficulty": difficulty, "points": points, "classes": classes, "groups": groups,
                           "default": difficulty == "moderate" and points == "R40"})
    return tables


def _worst_drop(summary: Mapping[str, Any]) -> dict[str, Any] | None:
    rows = [r for r in summary.get("delta_ap", []) if r["metric"] == "3d" and r["class"] == "mAP"
            and r["difficulty"] == "moderate" and r["delta"] is not None]
    return min(rows, key=lambda r: r["delta"]) if rows else None


def _headline(summary: Mapping[str, Any]) -> str:
    """The one-paragraph summary in plain language."""
    task = summary.get("task", {})
    subtasks = summary.get("subtasks", [])
    mutated = len(subtasks[1:])
    trials = int(task.get("trials") or 1)
    parts = [f"lidarfuzz tested {task.get('model', {}).get('name', '?')} on {task.get('dataset', {}).get('name', '?')}"
             f" with {_plural(int(task.get('frames') or 0), 'frame')} and {_plural(mutated, 'mutation subtask')} "
             f"(operator × severity, {_plural(trials, 'trial')} per frame)."]
    if task.get("status") != "done":
        parts.append(f"The task is {task.get('status')} ({task.get('done')} of {task.get('total')} units): "
                     f"the figures below cover what has finished.")
    clean = ap_value(subtasks[0].get("ap") if subtasks else None, "3d", "mAP", "moderate", "R40")
    if clean is not None:
        parts.append(f"On the original frames, 3D mAP (moderate, AP|R40) is {clean:.1f}.")
        worst = _worst_drop(summary)
        if worst is not None and worst["delta"] < 0:
            parts.append(f"The largest drop comes with {worst['label']}: {-worst['delta']:.1f} points, to "
                         f"{worst['corrupted']:.1f}.")
        elif worst is not None:
            parts.append("No mutation lowered it.")
    elif subtasks:
        parts.append("There is no AP: the data set has no labels, or the originals are not evaluated yet.")
    relations = [r for r in summary.get("violations", {}).get("relation", []) if r.get("violated")]
    if relations:
        top = max(relations, key=lambda r: (r["rate"] or 0.0, r["violated"]))
        per_op = [r for r in summary["violations"].get("relation_operator", [])
                  if r["relation"] == top["relation"] and r.get("violated")]
        text = (f"The most violated relation is {top['relation']}: {top['violated']} of {top['checked']} checked "
                f"frames ({fmt_pct(top['rate'])})")
        if len(per_op) > 1:
            worst_op = max(per_op, key=lambda r: (r["rate"] or 0.0, r["violated"]))
            text += f", most often under {worst_op['operator']} ({fmt_pct(worst_op['rate'])})"
        parts.append(text + ".")
    elif summary.get("violations", {}).get("relation"):
        parts.append("No metamorphic relation was violated.")
    by_kind = summary.get("findings", {}).get("by_kind", {})
    failures = {k: int(by_kind.get(k, 0)) for k in SUT_FAILURES[:3] if by_kind.get(k)}
    if failures:
        parts.append("The system failed on " + ", ".join(_plural(n, k.replace("_", " ")) for k, n in failures.items())
                     + " (see SUT failures).")
    else:
        parts.append("The system never crashed, timed out or returned invalid output.")
    return " ".join(parts)


def _robustness(summary: Mapping[str, Any]) -> dict[str, Any] | None:
    robustness = summary.get("robustness") or {}
    metrics = [(m, name) for m, name in METRICS if m in robustness]
    if not metrics:
        return None
    errors = [f"{name}: {robustness[m]['error']}" for m, name in metrics if "error" in robustness[m]]
    metrics = [(m, name) for m, name in metrics if "error" not in robustness[m]]
    with_ce = any(robustness[m].get("mCE") is not None for m, _ in metrics)
    operators: dict[str, dict[str, Any]] = {}
    for metric, _ in metrics:
        for row in robustness[metric].get("operators", []):
            entry = operators.setdefault(row["operator"], {"operator": row["operator"], "severities": row.get(
                "severities", []), "rr": {}, "ce": {}})
            entry["rr"][metric] = fmt_ratio(row.get("RR"))
            entry["ce"][metric] = fmt_ratio(row.get("CE"))
    order = [s["operator"] for s in summary.get("subtasks", [])]
    ranked = sorted(operators.values(), key=lambda e: order.index(e["operator"]) if e["operator"] in order
                    else len(order))
    first = robustness[metrics[0][0]] if metrics else {}
    return {"metrics": metrics, "with_ce": with_ce, "operators": ranked, "errors": errors,
            "clean": {m: fmt_ap(robustness[m].get("clean_ap")) for m, _ in metrics},
            "baseline_clean": {m: fmt_ap(robustness[m].get("baseline_clean_ap")) for m, _ in metrics},
            "mrr": {m: fmt_ratio(robustness[m].get("mRR")) for m, _ in metrics},
            "mce": {m: fmt_ratio(robustness[m].get("mCE")) for m, _ in metrics},
            "notes": sorted({n for m, _ in metrics for n in robustness[m].get("notes", [])}),
            "difficulty": first.get("difficulty", "moderate"), "points": first.get("points", "R40"),
            "cls": first.get("cls") or "mAP"}


def _cell(row: Mapping[str, Any] | None) -> dict[str, Any]:
    if row is None:
        return {"text": DASH, "counts": "", "level": -1}
    rate = _number(row.get("rate"))
    level = -1 if rate is None else min(4, int(rate * 5)) if row.get("violated") else 0
    return {"text": fmt_pct(rate), "counts": f"{row['violated']}/{row['checked']}", "level": level}


def _matrix(rows: Sequence[Mapping[str, Any]], row_key: str, col_key: str, row_order: Iterable[str],
            col_order: Iterable[str]) -> dict[str, Any]:
    lookup = {(r[row_key], r[col_key]): r for r in rows}
    row_names = [r for r in row_order if any(k[0] == r for k in lookup)]
    col_names = [c for c in col_order if any(k[1] == c for k in lookup)]
    return {"columns": col_names,
            "rows": [{"name": r, "cells": [_cell(lookup.get((r, c))) for c in col_names]} for r in row_names]}


def _violations(summary: Mapping[str, Any]) -> dict[str, Any]:
    violations = summary.get("violations", {})
    subtasks = summary.get("subtasks", [])[1:]
    from lidarfuzz.oracles.relations.registry import available

    # A relation whose plugin is gone has no description; a broken plugin is left out, with a warning.
    descriptions = {name: cls.description for name, cls in available().items()}
    relation_names = [r["relation"] for r in violations.get("relation", [])]
    operators = list(dict.fromkeys(s["operator"] for s in subtasks))
    labels = [s["label"] for s in subtasks]
    classes = [*summary.get("classes", []), ""]
    by_class = _matrix(violations.get("relation_class", []), "relation", "class", relation_names, classes)
    by_class["columns"] = [c or "frame-level" for c in by_class["columns"]]
    by_object = _matrix(violations.get("relation_class_objects", []), "relation", "class", relation_names, classes)
    by_object["columns"] = [c or "frame-level" for c in by_object["columns"]]
    return {
        "relations": [{**r, "rate_text": fmt_pct(r["rate"]), "description": descriptions.get(r["relation"], ""),
                       "level": _cell(r)["level"]} for r in violations.get("relation", [])],
        "by_operator": _matrix(violations.get("relation_operator", []), "operator", "relation", operators,
                               relation_names),
        "by_label": _matrix(violations.get("relation_label", []), "label", "relation", labels, relation_names),
        "by_class": by_class,
        "objects": by_object,
        "count_form": [{**r, "rate_text": fmt_pct(r["rate"])} for r in violations.get("count_form", [])],
        "regions": _regions(summary),
    }


#: What the regions named in ``outside_roi_scatter``'s params are, for the report's reader.
REGION_NAMES = {"frame_map": "the frame's own map", "dataset_map": "the data set's map",
                "estimated": "the drivable area estimated from the scan", "boxes": "outside the labelled boxes only",
                "roi": "the frame's map"}


def _regions(summary: Mapping[str, Any]) -> list[dict[str, str]]:
    """Per subtask whose mutants avoided a region (``outside_roi_scatter``): which, on how many frames."""
    out = []
    for entry in summary.get("subtasks", [])[1:]:
        regions = entry.get("regions") or {}
        if regions:
            text = ", ".join(f"{REGION_NAMES.get(name, name)} ({name}) on {_plural(int(n), 'frame')}"
                             for name, n in regions.items())
            out.append({"label": entry.get("label", ""), "text": text})
    return out


def _failures(summary: Mapping[str, Any]) -> dict[str, Any]:
    by_kind = summary.get("findings", {}).get("by_kind", {})
    kinds = [{"kind": k, "count": int(by_kind.get(k, 0))} for k in SUT_FAILURES]
    per_subtask = [{"label": s["label"], "failures": s.get("failures")} for s in summary.get("subtasks", [])
                   if s.get("failures")]
    return {"kinds": kinds, "total": sum(k["count"] for k in kinds[:3]), "per_subtask": per_subtask,
            "operator_errors": kinds[3]["count"]}


def _findings(summary: Mapping[str, Any], images: Mapping[int, bytes | str] | None) -> list[dict[str, Any]]:
    out = []
    for finding in summary.get("findings", {}).get("top", []):
        image = (images or {}).get(finding["id"])
        out.append({**finding, "magnitude_text": DASH if finding.get("magnitude") is None else
                    f"{finding['magnitude']:g}",
                    "image": data_uri(image) if isinstance(image, bytes) else None,
                    "note": image if isinstance(image, str) else ""})
    return out


def context(summary: Mapping[str, Any], *, images: Mapping[int, bytes | str] | None = None,
            chart_pngs: Mapping[str, bytes] | None = None, image_limit: int | None = None) -> dict[str, Any]:
    """Everything the template shows, formatted."""
    from lidarfuzz import __version__

    task = summary.get("task", {})
    drawn = charts(summary) if chart_pngs is None else chart_pngs
    subtasks = summary.get("subtasks", [])
    unfinished = task.get("status") != "done" or any(s.get("status") != "done" for s in subtasks)
    title = f"lidarfuzz report — task {task.get('id')}" + (f": {task['name']}" if task.get("name") else "")
    return {
        "title": title,
        "task": task,
        "fingerprint": (task.get("model", {}).get("fingerprint") or "")[:12],
        "times": {k: fmt_time(task.get(k)) for k in ("created_at", "started_at", "finished_at")},
        "run": summary.get("run") or {},
        "unfinished": unfinished,
        "headline": _headline(summary),
        "ap_tables": _ap_tables(summary),
        "ap_warnings": list(summary.get("ap_warnings", [])),
        "has_ap": any(s.get("ap") for s in subtasks),
        "charts": {name: data_uri(png) for name, png in drawn.items()},
        "robustness": _robustness(summary),
        "violations": _violations(summary),
        "failures": _failures(summary),
        "findings": _findings(summary, images),
        "findings_total": summary.get("findings", {}).get("total", 0),
        "image_limit": image_limit,
        "version": __version__,
        "generated": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "baseline": task.get("baseline"),
    }


def _environment() -> Any:
    from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape

    env = Environment(loader=PackageLoader("lidarfuzz.report", "templates"), autoescape=select_autoescape(
        ["html", "j2"], default_for_string=True, default=True), undefined=StrictUndefined, trim_blocks=True,
                      lstrip_blocks=True)
    env.filters.update(ap=fmt_ap, pct=fmt_pct, ratio=fmt_ratio, seconds=fmt_seconds)
    return env


def render_html(summary: Mapping[str, Any], *, images: Mapping[int, bytes | str] | None = None,
                chart_pngs: Mapping[str, bytes] | None = None, image_limit: int | None = None) -> str:
    """The report of ``summary`` as one HTML document.

    Args:
        summary: A task summary (:func:`lidarfuzz.campaign.results.summarise`).
        images: Pictures of findings by finding id: PNG bytes, or a note why there is none
            (:func:`lidarfuzz.report.bev.finding_images`).
        chart_pngs: Charts by name (``ap``, ``delta``, ``violations``); drawn here when None.
        image_limit: How many pictures were asked for (shown when findings have none).
    """
    template = _environment().get_template("report.html.j2")
    return template.render(**context(summary, images=images, chart_pngs=chart_pngs, image_limit=image_limit))


__all__ = ["context", "fmt_ap", "fmt_delta", "fmt_pct", "render_html"]
