"""A structural task's figures: what its report, ``report.json`` and the web app show.

Built from the task's stored units alone (:mod:`lidarfuzz.campaign.structural`: each replayed
log's frame result holds its covered requirements), so an unfinished task shows what exists.

The tables have the form of Neves et al.'s Tables I–IV: one per chosen function and criterion
(all-nodes, all-edges), plus one over every target; rows are the field-test logs and an average;
columns are the FT log, each heuristic's base log L′ and, per strategy, the aggregated coverage
of L′ and the generated L″ together (COV of NC′ ∪ NC″). ``aggregated`` lists, per field-test
log, heuristic, strategy and criterion, COV of L′, of L″, of both, and COV_Ag = |NC″ − NC′| / total
(the requirements only the generated log reached).

Example (a log covering one of two nodes, its base the other one):
    >>> from lidarfuzz.structural.requirements import Requirement
    >>> a, b = Requirement("m:f", "node", 1), Requirement("m:f", "node", 4)
    >>> ratio({a}, {a, b}, "node", "m:f"), ratio(set(), set(), "node", None)
    (0.5, None)
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from pydantic import Field
from sqlalchemy import select

from lidarfuzz.store.contracts import Contract, Number
from lidarfuzz.store.models import Finding, FrameResult, Subtask, Task
from lidarfuzz.store.store import Store
from lidarfuzz.structural.requirements import Covered, Kind, Requirement, of_kind


class LogEntry(Contract):
    """One replayed log of the task."""

    name: str
    role: str  # field_test, base or generated
    ft: int
    heuristic: str = ""
    strategy: str = ""
    path: str = ""
    frames: int = 0
    failures: int = 0
    selection: dict[str, Any] = Field(default_factory=dict)
    relations: dict[str, dict[str, int]] = Field(default_factory=dict)
    covered: dict[str, list[str]] = Field(default_factory=dict)


class TableRow(Contract):
    log: str
    values: list[Number | None]


class CoverageTable(Contract):
    """One of Tables I–IV: a function (``""``: every target) and a criterion."""

    function: str
    criterion: str
    total: int
    columns: list[str]
    rows: list[TableRow]
    average: list[Number | None]


class AggregatedRow(Contract):
    ft: int
    log: str
    heuristic: str
    strategy: str
    criterion: str
    base: Number
    generated: Number
    together: Number
    aggregated: Number
    new: int


class ReductionRow(Contract):
    """How close a base log comes to its field-test log, and at what size."""

    ft: int
    log: str
    heuristic: str
    segments: int
    frames: int
    log_segments: int
    log_frames: int
    nodes: Number
    edges: Number
    log_nodes: Number
    log_edges: Number


class StructuralSummary(Contract):
    targets: list[str]
    functions: list[str]
    segment_size: int
    heuristics: list[str]
    strategies: list[str]
    fingerprint: str
    total: dict[str, list[str]]
    logs: list[LogEntry]
    tables: list[CoverageTable]
    aggregated: list[AggregatedRow]
    reduction: list[ReductionRow]
    relations: dict[str, dict[str, int]]
    findings: dict[str, int]


def ratio(covered: Iterable[Requirement], total: Iterable[Requirement], kind: Kind,
          function: str | None) -> float | None:
    """COV of ``kind`` (of ``function``; every function when None); None when there is nothing to cover."""
    every = of_kind(total, kind, function)
    if not every:
        return None
    return len(of_kind(covered, kind, function) & every) / len(every)


def columns(heuristics: Iterable[str], strategies: Iterable[str]) -> list[tuple[str, str, str]]:
    """The table's columns as (title, heuristic, strategy): the FT log, then per heuristic its base and
    its aggregated logs."""
    out = [("FT log", "", "")]
    for heuristic in heuristics:
        out.append((f"{heuristic} base", heuristic, ""))
        out.extend((f"{heuristic} agg {name}", heuristic, name) for name in strategies)
    return out


def _mean(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return sum(known) / len(known) if known else None


def build(store: Store, task: Task, config: Any) -> StructuralSummary:
    """The figures of structural task ``task`` (its settings: ``config``, a
    :class:`~lidarfuzz.campaign.structural.StructuralConfig`) from what the store holds now."""
    from lidarfuzz.structural.stored import from_labels

    total = from_labels(config.total)
    functions = sorted({r.function for r in total})
    with store.session() as s:
        rows = s.execute(select(FrameResult.output).join(Subtask).where(Subtask.task_id == task.id)
                         .order_by(FrameResult.trial, Subtask.id)).all()
        found = s.execute(select(Finding.kind).where(Finding.task_id == task.id)).scalars().all()
    logs = [LogEntry(name=o["log"], role=o["role"], ft=o["ft"], heuristic=o["heuristic"], strategy=o["strategy"],
                     path=o["path"], frames=o["frames"], failures=len(o["failures"]), selection=o["selection"],
                     relations=o["relations"], covered=o["covered"]) for (o,) in rows if o]
    covered: dict[tuple[int, str, str], Covered] = {(e.ft, e.heuristic, e.strategy): from_labels(e.covered)
                                                    for e in logs}
    names = {e.ft: Path(e.path).name for e in logs if e.role == "field_test"}
    labels = [names.get(i, Path(p).name) for i, p in enumerate(config.logs)]
    titled = columns(config.heuristics, config.strategies)
    kinds: tuple[Kind, Kind] = ("node", "edge")
    tables = []
    for function in [*functions, ""]:
        for kind in kinds:
            table_rows = []
            for ft, label in enumerate(labels):
                values: list[float | None] = []
                for _, heuristic, strategy in titled:
                    mine = covered.get((ft, heuristic, strategy))
                    if mine is not None and strategy:
                        base = covered.get((ft, heuristic, ""))
                        mine = mine | base if base is not None else None
                    values.append(None if mine is None else ratio(mine, total, kind, function or None))
                table_rows.append(TableRow(log=label, values=values))
            average = [_mean([r.values[i] for r in table_rows]) for i in range(len(titled))]
            tables.append(CoverageTable(function=function, criterion=kind,
                                        total=len(of_kind(total, kind, function or None)),
                                        columns=[t for t, _, _ in titled], rows=table_rows, average=average))
    aggregated = []
    for (ft, heuristic, strategy), generated in sorted(covered.items()):
        base = covered.get((ft, heuristic, ""))
        if not strategy or base is None:
            continue
        for kind in kinds:
            every = of_kind(total, kind)
            new = (of_kind(generated, kind) - of_kind(base, kind)) & every
            aggregated.append(AggregatedRow(
                ft=ft, log=labels[ft], heuristic=heuristic, strategy=strategy, criterion=kind,
                base=ratio(base, total, kind, None) or 0.0, generated=ratio(generated, total, kind, None) or 0.0,
                together=ratio(base | generated, total, kind, None) or 0.0,
                aggregated=len(new) / len(every) if every else 0.0, new=len(new)))
    reduction = []
    for entry in logs:
        if entry.role != "base" or not entry.selection:
            continue
        full = covered.get((entry.ft, "", ""), frozenset())
        mine = covered[(entry.ft, entry.heuristic, "")]
        reduction.append(ReductionRow(
            ft=entry.ft, log=labels[entry.ft], heuristic=entry.heuristic,
            segments=len(entry.selection["segments"]), frames=entry.selection["frames"],
            log_segments=entry.selection["log_segments"], log_frames=entry.selection["log_frames"],
            nodes=ratio(mine, total, "node", None) or 0.0, edges=ratio(mine, total, "edge", None) or 0.0,
            log_nodes=ratio(full, total, "node", None) or 0.0, log_edges=ratio(full, total, "edge", None) or 0.0))
    relations: dict[str, dict[str, int]] = {}
    for entry in logs:
        for name, counts in entry.relations.items():
            into = relations.setdefault(name, {"checked": 0, "violated": 0})
            into["checked"] += counts["checked"]
            into["violated"] += counts["violated"]
    kinds_found: dict[str, int] = {}
    for kind_name in found:
        kinds_found[kind_name] = kinds_found.get(kind_name, 0) + 1
    return StructuralSummary(targets=list(config.targets), functions=functions, segment_size=config.segment_size,
                             heuristics=list(config.heuristics), strategies=list(config.strategies),
                             fingerprint=task.model.fingerprint, total=config.total, logs=logs, tables=tables,
                             aggregated=aggregated, reduction=reduction, relations=relations,
                             findings=dict(sorted(kinds_found.items())))


__all__ = ["AggregatedRow", "CoverageTable", "LogEntry", "ReductionRow", "StructuralSummary", "TableRow", "build",
           "columns", "ratio"]
