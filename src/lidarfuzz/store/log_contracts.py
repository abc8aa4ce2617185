"""What the store holds about logs, segments and code coverage, typed (Neves et al.'s meta-model):
the contracts between the structural engine, the store, the CLI and the web app.

=============================  ==========================  =========================================
column / listing               contract                    written by
=============================  ==========================  =========================================
``Log.generation``             :class:`GenerationRecord`   recording a generated log (its provenance)
``CoverageRecord.covered``     :data:`CoveredLabels`       recording coverage of a log or a segment
a log in a listing             :class:`LogSummary`         :func:`lidarfuzz.structural.stored.summaries`
a segment in a listing         :class:`SegmentSummary`     idem
a coverage record              :class:`CoverageSummary`    idem
=============================  ==========================  =========================================

Covered requirements are stored compactly as labels grouped by function: ``{"pkg.mod:f": ["12",
"15", "12->15", "-10->12"]}`` — a node is its first line, an edge ``source->target`` with the raw
line numbers (negative: the function's entry or exit, as coverage.py writes arcs), so the set reads
back exactly (:mod:`lidarfuzz.structural.stored` converts).

Example:
    >>> GeneratedFrameRecord(position=1, frame_id="000001", segment=0, sources=["000000"],
    ...                      operator={"name": "height_shift"}, params={"offset": 10.0}).dump()["sources"]
    ['000000']
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import Field

from lidarfuzz.store.contracts import Contract, Number

#: A log's kind: recorded in the field (FTLog) or generated from one (GeneratedLog).
LogKindName = Literal["field_test", "generated"]
#: The criteria coverage is recorded for: all-nodes, all-edges.
Criterion = Literal["node", "edge"]
#: Covered requirements: function → labels within it (see the module docstring).
CoveredLabels = dict[str, list[str]]


class GeneratedFrameRecord(Contract):
    """Where one frame of a generated log comes from (:class:`lidarfuzz.structural.generate.Provenance`)."""

    position: int = Field(ge=0)
    frame_id: str
    segment: int = Field(ge=0)
    sources: list[str] = Field(min_length=1, max_length=2)
    operator: dict[str, Any] | None = None
    params: dict[str, Any] = Field(default_factory=dict)


class GenerationRecord(Contract):
    """How a generated log was made: the parent's segments it came from and every frame's provenance."""

    seed: int = 0
    segment_size: int = Field(ge=1)
    segments: list[int] = Field(default_factory=list)
    frames: list[GeneratedFrameRecord] = Field(default_factory=list)


class LogSummary(Contract):
    """A log as the CLI and the web app list it."""

    id: int
    name: str
    kind: LogKindName
    path: str
    format: str
    frame_count: int
    dataset_id: int | None = None
    parent_id: int | None = None
    heuristic: str = ""
    strategy: str = ""
    segment_sizes: list[int] = Field(default_factory=list)


class SegmentSummary(Contract):
    """One segment of a log's partition at ``size`` frames."""

    log_id: int
    size: int
    index: int
    first_frame: int
    last_frame: int
    first_frame_id: str
    last_frame_id: str


class CoverageSummary(Contract):
    """One coverage record: what a log (or a segment) covered of a target, for a system version."""

    log_id: int | None = None
    segment_id: int | None = None
    fingerprint: str
    criterion: Criterion
    target: str
    covered_count: int
    total_count: int
    ratio: Number = math.nan  # covered ÷ total; undefined (null) with no requirements


__all__ = ["CoverageSummary", "CoveredLabels", "Criterion", "GeneratedFrameRecord", "GenerationRecord",
           "LogKindName", "LogSummary", "SegmentSummary"]
