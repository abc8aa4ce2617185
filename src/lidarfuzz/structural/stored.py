"""Logs, segments and coverage in the store (Neves et al.'s meta-model, :mod:`lidarfuzz.store.models`).

A field-test log is recorded with its path and frame count; a generated one with its parent, the
heuristic that chose its segments and the strategy that made its frames, and every frame's
provenance (:class:`~lidarfuzz.store.log_contracts.GenerationRecord`). A partition is recorded once
per log and segment size. Coverage is recorded per log or per segment, system fingerprint,
criterion (``node`` or ``edge``) and target, its requirements as labels grouped by function
(:func:`to_labels`, read back exactly by :func:`from_labels`).

Example:
    >>> from lidarfuzz.structural.requirements import Requirement
    >>> covered = {Requirement("m:f", "node", 3), Requirement("m:f", "edge", -1, 3)}
    >>> to_labels(covered)
    {'m:f': ['-1->3', '3']}
    >>> from_labels(to_labels(covered)) == frozenset(covered)
    True
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from sqlalchemy import select
from sqlalchemy.orm import Session

from lidarfuzz.store.errors import ConflictError, NotFoundError
from lidarfuzz.store.log_contracts import (
    CoverageSummary,
    CoveredLabels,
    Criterion,
    GeneratedFrameRecord,
    GenerationRecord,
    LogSummary,
    SegmentSummary,
)
from lidarfuzz.store.models import CoverageRecord, Log, LogKind, Segment
from lidarfuzz.structural.generate import GeneratedLog
from lidarfuzz.structural.logs import OrderedLog
from lidarfuzz.structural.requirements import Covered, Requirement, of_kind
from lidarfuzz.structural.segments import Segment as LogSegment


def to_labels(covered: Iterable[Requirement]) -> CoveredLabels:
    """Requirements as labels grouped by function: ``"12"`` a node, ``"12->15"`` an edge (raw lines), sorted."""
    out: dict[str, list[str]] = {}
    for r in sorted(covered):
        out.setdefault(r.function, []).append(str(r.source) if r.kind == "node" else f"{r.source}->{r.target}")
    return {f: sorted(labels) for f, labels in sorted(out.items())}


def from_labels(labels: CoveredLabels) -> Covered:
    """The requirements :func:`to_labels` stored.

    Raises:
        ValueError: A label that is neither ``N`` nor ``N->M`` (naming the function and label).
    """
    out: set[Requirement] = set()
    for function, items in labels.items():
        for label in items:
            source, arrow, target = label.partition("->")
            try:
                out.add(Requirement(function, "edge", int(source), int(target)) if arrow
                        else Requirement(function, "node", int(source)))
            except ValueError:
                raise ValueError(f"covered: {function}: label {label!r} is neither a line nor line->line") from None
    return frozenset(out)


def record_log(session: Session, log: OrderedLog, name: str, *, dataset_id: int | None = None) -> Log:
    """Record a field-test log (refused when the name is taken)."""
    _free(session, name)
    row = Log(name=name, kind=LogKind.FIELD_TEST, dataset_id=dataset_id, path=str(log.path), format=log.format,
              frame_count=len(log), heuristic="", strategy="")
    session.add(row)
    session.flush()
    return row


def record_generated(session: Session, generated: GeneratedLog, name: str, parent: Log) -> Log:
    """Record a generated log with its parent, heuristic, strategy and per-frame provenance."""
    _free(session, name)
    generation = GenerationRecord(seed=generated.seed, segment_size=generated.segment_size,
                                  segments=list(generated.segments),
                                  frames=[GeneratedFrameRecord(position=f.position, frame_id=f.frame_id,
                                                               segment=f.segment, sources=list(f.sources),
                                                               operator=f.operator, params=f.params)
                                          for f in generated.frames])
    row = Log(name=name, kind=LogKind.GENERATED, path=generated.path, format="kitti",
              frame_count=len(generated.frames), parent=parent, heuristic=generated.heuristic or "",
              strategy=generated.strategy, generation=generation)
    session.add(row)
    session.flush()
    return row


def _free(session: Session, name: str) -> None:
    if session.scalar(select(Log.id).where(Log.name == name)) is not None:
        raise ConflictError(f"a log named {name!r} is already recorded")


def record_segments(session: Session, log: Log, segments: Sequence[LogSegment]) -> list[Segment]:
    """Record a partition of ``log`` (idempotent: the same partition again returns the rows there are).

    Raises:
        ConflictError: A partition at the same size that differs from the one recorded.
    """
    if not segments:
        return []
    size = max(len(s) for s in segments)
    rows = [Segment(log_id=log.id, size=size, index=s.index, first_frame=s.first, last_frame=s.last,
                    first_frame_id=s.frame_ids[0], last_frame_id=s.frame_ids[-1]) for s in segments]
    there = list(session.scalars(select(Segment).where(Segment.log_id == log.id, Segment.size == size)
                                 .order_by(Segment.index)))
    if there:
        def key(s: Segment) -> tuple[int, int, int, str, str]:
            return s.index, s.first_frame, s.last_frame, s.first_frame_id, s.last_frame_id

        if [key(s) for s in there] != [key(s) for s in rows]:
            raise ConflictError(f"log {log.name!r}: a different partition at size {size} is already recorded")
        return there
    session.add_all(rows)
    session.flush()
    return rows


def record_coverage(session: Session, *, fingerprint: str, criterion: Criterion, target: str,
                    covered: Iterable[Requirement], total: Iterable[Requirement], log: Log | None = None,
                    segment: Segment | None = None) -> CoverageRecord:
    """Record what a log or one segment (exactly one of them) covered of ``total`` under ``criterion``."""
    if (log is None) == (segment is None):
        raise ValueError("record_coverage: give a log or a segment, not both or neither")
    every = of_kind(total, criterion)
    mine = of_kind(covered, criterion) & every
    row = CoverageRecord(log_id=log.id if log is not None else None,
                         segment_id=segment.id if segment is not None else None, fingerprint=fingerprint,
                         criterion=criterion, target=target, covered=to_labels(mine), covered_count=len(mine),
                         total_count=len(every))
    session.add(row)
    session.flush()
    return row


def get_log(session: Session, name: str) -> Log:
    row = session.scalar(select(Log).where(Log.name == name))
    if row is None:
        raise NotFoundError(f"no log named {name!r}")
    return row


def log_summary(row: Log) -> LogSummary:
    return LogSummary(id=row.id, name=row.name, kind=row.kind.value, path=row.path,  # type: ignore[arg-type]
                      format=row.format, frame_count=row.frame_count, dataset_id=row.dataset_id,
                      parent_id=row.parent_id, heuristic=row.heuristic, strategy=row.strategy,
                      segment_sizes=sorted({s.size for s in row.segments}))


def segment_summary(row: Segment) -> SegmentSummary:
    return SegmentSummary(log_id=row.log_id, size=row.size, index=row.index, first_frame=row.first_frame,
                          last_frame=row.last_frame, first_frame_id=row.first_frame_id,
                          last_frame_id=row.last_frame_id)


def coverage_summary(row: CoverageRecord) -> CoverageSummary:
    ratio = row.covered_count / row.total_count if row.total_count else float("nan")
    return CoverageSummary(log_id=row.log_id, segment_id=row.segment_id, fingerprint=row.fingerprint,
                           criterion=row.criterion, target=row.target,  # type: ignore[arg-type]
                           covered_count=row.covered_count, total_count=row.total_count, ratio=ratio)


__all__ = [
    "coverage_summary", "from_labels", "get_log", "log_summary", "record_coverage", "record_generated",
    "record_log", "record_segments", "segment_summary", "to_labels",
]
