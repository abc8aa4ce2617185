"""Gates: thresholds a CI pipeline fails on, checked against a task's summary.

Grammar (one rule per gate; spaces around ``>`` allowed; every gate fails when its number is
*strictly greater* than the threshold)::

    ap_drop:METRIC:CLASS:SUBTASK[:DIFFICULTY] > POINTS
    violations:RELATION[:SUBTASK] > FRAMES
    violation_rate:RELATION[:SUBTASK] > RATE
    failures[:KIND] > COUNT

``ap_drop``
    Original AP minus the mutant's AP, in AP points (KITTI AP|R40, the difficulty
    ``moderate`` unless given). METRIC is ``bbox``, ``bev`` or ``3d``; CLASS is ``Car``,
    ``Pedestrian``, ``Cyclist``, ``mAP`` (the mean over classes) or ``*`` (each class and
    mAP). Each matching (subtask, class) is checked on its own.
``violations`` / ``violation_rate``
    Violated frames (an integer) or the share of checked frames that were violated (a
    number in [0, 1], or a percentage such as ``5%``) of a relation, summed over the matching
    subtasks; RELATION may be ``*`` (each relation on its own).
``failures``
    Frames on which the system under test crashed, timed out or returned invalid output;
    KIND narrows it to ``crash``, ``timeout``, ``invalid_output``, or one of lidarfuzz's own
    errors, ``operator_error`` (an operator failing) or ``oracle_error`` (a relation failing),
    or ``data_error`` (a frame that could not be read), which are not counted otherwise.

SUBTASK is a subtask's label (``fog@3``, ``fog (config)``), an operator's name (``fog``: all
its severities) or ``*`` (all; the default).

A gate whose selection matches nothing (a misspelt relation, a task without labels, a
subtask not evaluated yet) is an *error*, never a silent pass.

Example:
    >>> gate = parse_gate("ap_drop:3d:Car:fog@3>10")
    >>> gate.kind, gate.metric, gate.cls, gate.subtask, gate.difficulty, gate.threshold
    ('ap_drop', '3d', 'Car', 'fog@3', 'moderate', 10.0)
    >>> parse_gate("violation_rate:preservation:fog > 5%").threshold
    0.05
"""

from __future__ import annotations

import math
import re
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, TypeVar

from lidarfuzz.errors import LidarfuzzError

if TYPE_CHECKING:
    from lidarfuzz.store.contracts import TaskSummary

GateKind = Literal["ap_drop", "violations", "violation_rate", "failures"]
KINDS: tuple[GateKind, ...] = ("ap_drop", "violations", "violation_rate", "failures")
AP_METRICS = ("bbox", "bev", "3d")
METRIC_NAMES = {"bbox": "bbox", "bev": "BEV", "3d": "3D"}
CLASSES = ("Car", "Pedestrian", "Cyclist", "mAP")
DIFFICULTIES = ("easy", "moderate", "hard")
SUT_FAILURES = ("crash", "timeout", "invalid_output")
FAILURE_KINDS = (*SUT_FAILURES, "operator_error", "oracle_error", "data_error")
GRAMMAR = ("ap_drop:METRIC:CLASS:SUBTASK[:DIFFICULTY]>POINTS, violations:RELATION[:SUBTASK]>FRAMES, "
           "violation_rate:RELATION[:SUBTASK]>RATE or failures[:KIND]>COUNT")
_RULE = re.compile(r"^\s*(?P<lhs>[^<>=]+?)\s*>\s*(?P<value>[^<>=]+?)\s*$")


class GateError(LidarfuzzError, ValueError):
    """A gate rule that does not follow the grammar."""


@dataclass(frozen=True)
class Gate:
    """One parsed rule (see the module docstring for the grammar)."""

    text: str
    kind: GateKind
    threshold: float
    metric: str = "3d"
    cls: str = "mAP"
    subtask: str = "*"
    difficulty: str = "moderate"
    relation: str = "*"
    failure_kind: str = "*"


@dataclass(frozen=True)
class GateResult:
    """A gate checked against one summary: ``passed``, ``failed`` or ``error``."""

    name: str
    status: Literal["passed", "failed", "error"]
    message: str
    rows: tuple[str, ...] = ()  # the offending (or, for information, the measured) figures
    group: str = "gates"
    informational: bool = False
    details: tuple[str, ...] = ()  # every measured figure

    @property
    def passed(self) -> bool:
        return self.status == "passed"


_Option = TypeVar("_Option", bound=str)


def _bad(text: str, why: str) -> GateError:
    return GateError(f"gate {text!r}: {why} (grammar: {GRAMMAR})")


def _choice(text: str, what: str, value: str, allowed: Iterable[_Option]) -> _Option:
    options = list(allowed)
    for option in options:
        if value.lower() == option.lower():
            return option
    raise _bad(text, f"unknown {what} {value!r}; expected one of {', '.join(options)}")


def parse_gate(text: str) -> Gate:
    """Parse one rule.

    Raises:
        GateError: (a :class:`~lidarfuzz.errors.LidarfuzzError`) naming the rule and what is wrong.
    """
    match = _RULE.match(text)
    if match is None:
        if re.search(r"(>=|<|=)", text):
            raise _bad(text, "only '>' is supported (the gate fails when the figure is greater)")
        raise _bad(text, "expected RULE>THRESHOLD, e.g. ap_drop:3d:Car:fog@3>10")
    parts = [p.strip() for p in match["lhs"].split(":")]
    if any(not p for p in parts):
        raise _bad(text, "an empty field between ':'")
    raw = match["value"]
    kind = _choice(text, "gate kind", parts[0], KINDS)
    percent = raw.endswith("%")
    try:
        threshold = float(raw[:-1] if percent else raw)
    except ValueError:
        raise _bad(text, f"the threshold {raw!r} is not a number") from None
    if threshold < 0:
        raise _bad(text, "the threshold must not be negative")
    if percent and kind != "violation_rate":
        raise _bad(text, "a percentage threshold is only meaningful for violation_rate")
    args = parts[1:]
    if kind == "ap_drop":
        if len(args) not in (3, 4):
            raise _bad(text, "ap_drop takes METRIC:CLASS:SUBTASK[:DIFFICULTY]")
        metric = _choice(text, "metric", args[0], AP_METRICS)
        cls = "*" if args[1] == "*" else _choice(text, "class", args[1], CLASSES)
        difficulty = _choice(text, "difficulty", args[3], DIFFICULTIES) if len(args) == 4 else "moderate"
        return Gate(text.strip(), "ap_drop", threshold, metric=metric, cls=cls, subtask=args[2],
                    difficulty=difficulty)
    if kind in ("violations", "violation_rate"):
        if len(args) not in (1, 2):
            raise _bad(text, f"{kind} takes RELATION[:SUBTASK]")
        if kind == "violations" and (percent or threshold != int(threshold) or "." in raw):
            raise _bad(text, "violations counts frames (a whole number); for a share use violation_rate:...>0.05")
        if kind == "violation_rate":
            threshold = threshold / 100.0 if percent else threshold
            if threshold > 1:
                raise _bad(text, "a rate is a number in [0, 1] or a percentage such as 5%")
        return Gate(text.strip(), kind, threshold, relation=args[0], subtask=args[1] if len(args) == 2 else "*")
    if len(args) > 1:
        raise _bad(text, "failures takes at most one KIND")
    if threshold != int(threshold):
        raise _bad(text, "failures counts frames (a whole number)")
    failure_kind = _choice(text, "failure kind", args[0], ("*", *FAILURE_KINDS)) if args else "*"
    return Gate(text.strip(), "failures", threshold, failure_kind=failure_kind)


def parse_gates(rules: Iterable[Gate | str]) -> list[Gate]:
    return [rule if isinstance(rule, Gate) else parse_gate(rule) for rule in rules]


# -- evaluation ---------------------------------------------------------------------------
def _matches(selector: str, label: str, operator: str) -> bool:
    return selector in ("*", label, operator)


def _labels(summary: TaskSummary) -> str:
    labels = [s.label for s in summary.subtasks[1:]]
    return ", ".join(labels) if labels else "none"


def _ap_drop(summary: TaskSummary, gate: Gate) -> GateResult:
    rows = [r for r in summary.delta_ap
            if r.metric == gate.metric and r.difficulty == gate.difficulty
            and (gate.cls == "*" or r.cls == gate.cls) and _matches(gate.subtask, r.label, r.operator)]
    if not rows:
        known = {s.label for s in summary.subtasks} | {s.operator for s in summary.subtasks}
        if gate.subtask != "*" and gate.subtask not in known:
            why = f"no subtask {gate.subtask!r} in this task (subtasks: {_labels(summary)})"
        else:
            why = "no AP figures to compare (the data set has no labels, or the subtasks are not evaluated yet)"
        return GateResult(gate.text, "error", why)
    measured, offending = [], []
    for r in rows:
        if not math.isfinite(r.delta):  # undefined: no objects of the class to score
            continue
        drop = -r.delta
        metric = METRIC_NAMES.get(r.metric, r.metric)
        line = (f"{r.cls} {metric} AP ({r.difficulty}, R40) under {r.label}: "
                f"{r.clean:.1f} → {r.corrupted:.1f} (drop {drop:.1f})")
        measured.append(line)
        if drop > gate.threshold:
            offending.append(line)
    if offending:
        return GateResult(gate.text, "failed", f"{len(offending)} AP drop(s) above {gate.threshold:g} points",
                          tuple(offending), details=tuple(measured))
    return GateResult(gate.text, "passed", f"every AP drop is at most {gate.threshold:g} points",
                      details=tuple(measured))


def _violations(summary: TaskSummary, gate: Gate) -> GateResult:
    checked: dict[str, int] = defaultdict(int)
    violated: dict[str, int] = defaultdict(int)
    any_subtask = False
    for entry in summary.subtasks[1:]:
        if not _matches(gate.subtask, entry.label, entry.operator):
            continue
        any_subtask = True
        for row in entry.violations_total:
            # a subtask's totals are grouped by relation, so each row names one
            if row.relation is not None and gate.relation in ("*", row.relation):
                checked[row.relation] += row.checked
                violated[row.relation] += row.violated
    if not any_subtask:
        return GateResult(gate.text, "error", f"no subtask {gate.subtask!r} in this task "
                                              f"(subtasks: {_labels(summary)})")
    if not checked:
        known = sorted({r.relation or "" for r in summary.violations.relation})
        return GateResult(gate.text, "error", f"relation {gate.relation!r} was not checked on "
                                              f"{gate.subtask!r} (checked: {', '.join(known) or 'none'})")
    where = "" if gate.subtask == "*" else f" under {gate.subtask}"
    measured, offending = [], []
    for relation in sorted(checked):
        n, v = checked[relation], violated[relation]
        rate = v / n if n else 0.0
        line = f"{relation}{where}: {v} of {n} frames violated ({100 * rate:.1f}%)"
        measured.append(line)
        figure = v if gate.kind == "violations" else rate
        if figure > gate.threshold:
            offending.append(line)
    limit = f"{gate.threshold:g} frames" if gate.kind == "violations" else f"{100 * gate.threshold:g}%"
    if offending:
        return GateResult(gate.text, "failed", f"violations above {limit}", tuple(offending), details=tuple(measured))
    return GateResult(gate.text, "passed", f"violations at most {limit}", details=tuple(measured))


def _failures(summary: TaskSummary, gate: Gate) -> GateResult:
    by_kind = dict(summary.findings.by_kind)
    for entry in summary.subtasks:  # lidarfuzz's own errors are not findings: counted per subtask
        for kind, n in entry.tool_errors.items():
            by_kind[kind] = by_kind.get(kind, 0) + n
    kinds = SUT_FAILURES if gate.failure_kind == "*" else (gate.failure_kind,)
    counts = {k: int(by_kind.get(k, 0)) for k in kinds}
    total = sum(counts.values())
    line = ", ".join(f"{k}: {n}" for k, n in counts.items())
    if total > gate.threshold:
        return GateResult(gate.text, "failed", f"{total} failure(s), more than {gate.threshold:g}", (line,))
    return GateResult(gate.text, "passed", f"{total} failure(s)", details=(line,))


def check_gate(summary: TaskSummary, gate: Gate | str) -> GateResult:
    """Check one gate against a task summary."""
    gate = gate if isinstance(gate, Gate) else parse_gate(gate)
    if gate.kind == "ap_drop":
        return _ap_drop(summary, gate)
    if gate.kind in ("violations", "violation_rate"):
        return _violations(summary, gate)
    return _failures(summary, gate)


def _finished(summary: TaskSummary) -> GateResult:
    task = summary.task
    status, done, total = task.status, task.done, task.total
    if status == "done":
        return GateResult("task finished", "passed", f"{done} of {total} units", group="task")
    return GateResult("task finished", "failed", f"the task is {status} ({done} of {total} units): the figures "
                      f"are partial", (f"status {status}, {done} of {total} units",), group="task")


def default_results(summary: TaskSummary) -> list[GateResult]:
    """What is checked when no gate is given: no SUT failure (``failures>0``), and, for
    information only (always passing), each subtask's AP drop and each relation's violations."""
    results = [check_gate(summary, Gate("failures>0", "failures", 0.0))]
    for entry in summary.subtasks[1:]:
        rows = [r for r in summary.delta_ap if r.label == entry.label and r.metric in AP_METRICS
                and r.cls == "mAP" and r.difficulty == "moderate"]
        lines = tuple(f"{METRIC_NAMES[r.metric]} mAP (moderate, R40): {r.clean:.1f} → {r.corrupted:.1f} "
                      f"({r.delta:+.1f})" for r in rows if math.isfinite(r.delta))
        message = "; ".join(lines) if lines else "no AP (no labels, or not evaluated yet)"
        results.append(GateResult(f"ap {entry.label}", "passed", message, group="ap", informational=True,
                                  details=lines))
    for rate in summary.violations.relation:
        share = "–" if rate.rate is None else f"{100 * rate.rate:.1f}%"
        message = f"{rate.violated} of {rate.checked} frames violated ({share})"
        results.append(GateResult(f"relation {rate.relation}", "passed", message, group="relations",
                                  informational=True, details=(message,)))
    return results


def evaluate(summary: TaskSummary, gates: Iterable[Gate | str] = ()) -> list[GateResult]:
    """The task-finished check, then each gate's result (or the default set when none is given)."""
    parsed = parse_gates(gates)
    results = [_finished(summary)]
    if parsed:
        results += [check_gate(summary, gate) for gate in parsed]
    else:
        results += default_results(summary)
    return results


__all__ = ["Gate", "GateError", "GateResult", "check_gate", "default_results", "evaluate", "parse_gate", "parse_gates"]
