"""Machine-readable exports of a task: the summary as JSON, flat CSV tables, and JUnit XML.

CSV files (stdlib :mod:`csv`, one header row, ``""`` for a missing figure):

``ap.csv``
    One row per subtask × metric (``bbox``, ``bev``, ``3d``, ``aos``) × class (and ``mAP``)
    × difficulty × interpolation (``R11``, ``R40``): KITTI AP in percent.
``delta_ap.csv``
    The summary's ΔAP rows: mutant − original AP|R40 per subtask × metric × class × difficulty.
``violations.csv``
    One row per subtask × relation × class: frames checked and violated (``per`` =
    ``frame``) and objects checked and violated (``per`` = ``object``); class ``*`` is the
    relation over all classes, class ``""`` a frame-level relation (DeepTest's).
``findings.csv``
    Every finding of the task from the store (not only the summary's top ones), in unit order
    (subtask, frame, trial; a unit's findings as its run found them).

Identical runs give byte-identical CSV files, whatever the number of workers or the order units
finished in: results are stored in unit order (so findings are numbered alike), figures are
computed over frames in frame order, and rows are listed in unit order. The JSON summary and
JUnit XML also hold the run's own record — when it ran and how fast, how many outputs came from the
cache — which differs between runs by nature; :func:`without_run_record` leaves it out (it is
what two runs' JSON are compared on).

JUnit XML (``junit.xml``) turns gates (:mod:`lidarfuzz.report.gates`) into test cases a CI
system understands: one ``<testcase>`` per gate, with a ``<failure>`` listing the offending
figures when it fails and an ``<error>`` when it matched nothing. Every report also has the
test case ``task finished``, failing while the task is unfinished (its figures are partial).
With no gate given, the cases are: ``failures>0`` (fails on any crash, timeout or invalid
output of the system under test) and, always passing, one per subtask (its AP drop) and one
per relation (its violations) for information — metamorphic relations are violated now and
then by almost any real detector, so failing on them needs a threshold the user picks
(e.g. ``violation_rate:*>0.2``).
"""

from __future__ import annotations

import csv
import json
import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy import select

from lidarfuzz.campaign.tasks import subtask_label
from lidarfuzz.report.gates import Gate, GateResult, evaluate
from lidarfuzz.store.models import Finding, FrameResult, Subtask
from lidarfuzz.store.store import Store

if TYPE_CHECKING:
    from lidarfuzz.store.contracts import TaskSummary

AP_COLUMNS = ("subtask_id", "label", "operator", "severity", "metric", "class", "difficulty", "points", "ap")
DELTA_COLUMNS = ("label", "operator", "severity", "metric", "class", "difficulty", "clean", "corrupted", "delta")
VIOLATION_COLUMNS = ("label", "operator", "severity", "relation", "class", "per", "checked", "violated", "rate")
FINDING_COLUMNS = ("id", "kind", "class", "operator", "severity", "label", "frame_id", "trial", "magnitude",
                   "message", "replay")


def write_json(summary: TaskSummary, path: str | Path) -> Path:
    """The summary's JSON form (``report.json``: :meth:`TaskSummary.dump`, ``null`` for an undefined
    figure); ``TaskSummary.model_validate`` reads it back."""
    path = Path(path)
    path.write_text(json.dumps(summary.dump(), indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
    return path


def write_csv(rows: Iterable[Mapping[str, Any]], columns: Sequence[str], path: str | Path) -> Path:
    path = Path(path)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(columns), extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: "" if row.get(k) is None else row.get(k) for k in columns})
    return path


def ap_rows(summary: TaskSummary) -> list[dict[str, Any]]:
    """Every AP figure of every evaluated subtask (see ``ap.csv`` above; None: undefined)."""
    rows = []
    for entry in summary.subtasks:
        ap = entry.ap
        if ap is None:
            continue
        base = {"subtask_id": entry.id, "label": entry.label, "operator": entry.operator,
                "severity": entry.severity}
        for metric, classes in ap.ap.items():
            tables = {**classes, "mAP": ap.map.get(metric, {})}
            for cls, table in tables.items():
                for difficulty, values in table.items():
                    for points, value in values.items():
                        rows.append({**base, "metric": metric, "class": cls, "difficulty": difficulty,
                                     "points": points, "ap": value if math.isfinite(value) else None})
    return rows


def violation_rows(summary: TaskSummary) -> list[dict[str, Any]]:
    """Violation counts per subtask × relation × class (see ``violations.csv`` above)."""
    rows = []
    for entry in summary.subtasks[1:]:
        base = {"label": entry.label, "operator": entry.operator, "severity": entry.severity}
        for rates, per, total in ((entry.violations_total, "frame", True), (entry.violations, "frame", False),
                                  (entry.violations_per_object, "object", False)):
            for rate in rates:
                cls = "*" if total else rate.cls or ""
                rows.append({**base, "relation": rate.relation, "class": cls, "per": per,
                             "checked": rate.checked, "violated": rate.violated, "rate": rate.rate})
    return rows


def finding_rows(store: Store, task_id: int) -> list[dict[str, Any]]:
    """Every finding of task ``task_id``, in unit order (subtask, frame, trial, then as found)."""
    with store.session() as s:
        rows = s.execute(select(Finding, FrameResult.frame_id, FrameResult.trial, Subtask.name, Subtask.severity)
                         .join(FrameResult, Finding.frame_result_id == FrameResult.id)
                         .join(Subtask, FrameResult.subtask_id == Subtask.id)
                         .where(Finding.task_id == task_id)
                         .order_by(Subtask.id, FrameResult.frame_id, FrameResult.trial, Finding.id)).all()
        return [{"id": f.id, "kind": f.kind, "class": f.cls, "operator": name, "severity": severity,
                 "label": subtask_label(name, severity), "frame_id": frame_id, "trial": trial,
                 "magnitude": f.magnitude, "message": f.message, "replay": f"lidarfuzz replay {f.id}"}
                for f, frame_id, trial, name, severity in rows]


#: The summary's fields that record the run rather than its results (see the module docstring):
#: the task's times, and per subtask its times, the system's seconds and the cache's hits.
RUN_RECORD_TASK = ("created_at", "started_at", "finished_at")
RUN_RECORD_SUBTASK = ("started_at", "finished_at", "sut_seconds", "cached")


def without_run_record(data: Mapping[str, Any]) -> dict[str, Any]:
    """A summary's JSON form (:meth:`TaskSummary.dump`) less the run's own record: what identical
    runs must agree on to the last byte."""
    out = {key: value for key, value in data.items() if key != "run"}
    if isinstance(out.get("task"), Mapping):
        out["task"] = {k: v for k, v in out["task"].items() if k not in RUN_RECORD_TASK}
    if isinstance(out.get("subtasks"), list):
        out["subtasks"] = [{k: v for k, v in entry.items() if k not in RUN_RECORD_SUBTASK}
                           if isinstance(entry, Mapping) else entry for entry in out["subtasks"]]
    return out


def write_csvs(summary: TaskSummary, out_dir: str | Path, findings: Iterable[Mapping[str, Any]],
               ) -> dict[str, Path]:
    """``ap.csv``, ``delta_ap.csv``, ``violations.csv`` and ``findings.csv`` in ``out_dir``."""
    out = Path(out_dir)
    return {
        "ap": write_csv(ap_rows(summary), AP_COLUMNS, out / "ap.csv"),
        "delta_ap": write_csv((row.dump() for row in summary.delta_ap), DELTA_COLUMNS, out / "delta_ap.csv"),
        "violations": write_csv(violation_rows(summary), VIOLATION_COLUMNS, out / "violations.csv"),
        "findings": write_csv(findings, FINDING_COLUMNS, out / "findings.csv"),
    }


def junit_from_results(summary: TaskSummary, results: Sequence[GateResult]) -> str:
    """JUnit XML of already checked gates."""
    task = summary.task
    name = f"lidarfuzz task {task.id}" + (f" ({task.name})" if task.name else "")
    failures = sum(r.status == "failed" for r in results)
    errors = sum(r.status == "error" for r in results)
    counts = {"tests": str(len(results)), "failures": str(failures), "errors": str(errors)}
    root = ET.Element("testsuites", {"name": "lidarfuzz", **counts})
    suite = ET.SubElement(root, "testsuite", {"name": name, **counts, "skipped": "0",
                                              "timestamp": task.finished_at or task.started_at or ""})
    properties = ET.SubElement(suite, "properties")
    for key, value in (("task", task.id), ("status", task.status), ("dataset", task.dataset.path),
                       ("sut", task.model.spec), ("fingerprint", task.model.fingerprint), ("seed", task.seed)):
        ET.SubElement(properties, "property", {"name": key, "value": "" if value is None else str(value)})
    for result in results:
        case = ET.SubElement(suite, "testcase", {"classname": f"lidarfuzz.{result.group}", "name": result.name,
                                                "time": "0"})
        if result.status == "failed":
            failure = ET.SubElement(case, "failure", {"message": result.message, "type": "gate"})
            failure.text = "\n".join(result.rows) or result.message
        elif result.status == "error":
            error = ET.SubElement(case, "error", {"message": result.message, "type": "gate"})
            error.text = result.message
        if result.details:
            out = ET.SubElement(case, "system-out")
            out.text = "\n".join(result.details)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode", xml_declaration=True) + "\n"


def junit_xml(summary: TaskSummary, gates: Iterable[Gate | str] = ()) -> str:
    """JUnit XML of ``gates`` (rules or :class:`Gate`) checked against ``summary``; see the module docstring.

    Raises:
        GateError: When a rule does not parse.
    """
    return junit_from_results(summary, evaluate(summary, gates))


__all__ = ["RUN_RECORD_SUBTASK", "RUN_RECORD_TASK", "ap_rows", "finding_rows", "junit_from_results", "junit_xml",
           "violation_rows", "without_run_record", "write_csv", "write_csvs", "write_json"]
