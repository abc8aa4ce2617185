"""The campaign store's tables, in the spirit of the thesis's: data sets, models (systems under
test), tasks, subtasks (operator × severity), per-frame results and findings.

Everything a finding needs to be replayed is stored with it: the task's seed, the operator's
spec and concrete params, the frame id, and the system's fingerprint. JSON columns hold
specs, params, summaries and relation outcomes; boxes (detections and the mutants' ground
truth) are stored compactly as float32 arrays with their labels, read and written as one value
(:class:`lidarfuzz.store.boxes.StoredBoxes`). ``sut_outputs`` caches what a system (by fingerprint)
said about an input (by content
digest), so unchanged inputs are never run twice.

Structural testing adds Neves et al.'s meta-model: logs (field-test or generated, with parent,
heuristic and strategy), their segments, and coverage records per log or segment and system
fingerprint (:mod:`lidarfuzz.store.log_contracts`, recorded by :mod:`lidarfuzz.structural.stored`).
"""

from __future__ import annotations

import enum
from datetime import UTC, datetime
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    Boolean,
    CheckConstraint,
    DateTime,
    Enum,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    UniqueConstraint,
    false,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, composite, mapped_column, relationship

from lidarfuzz.store.boxes import StoredBoxes
from lidarfuzz.store.contracts import (
    FailureRecord,
    FindingReplay,
    OutcomeRecord,
    SubtaskInputs,
    SubtaskResults,
    TaskOptions,
    TaskSummary,
)
from lidarfuzz.store.log_contracts import CoveredLabels, GenerationRecord
from lidarfuzz.store.types import ContractJSON, SafeJSON


def now() -> datetime:
    return datetime.now(UTC)


class Base(DeclarativeBase):
    type_annotation_map: ClassVar[dict[Any, Any]] = {dict[str, Any]: SafeJSON, list[Any]: SafeJSON}


class Status(enum.StrEnum):
    PENDING = "pending"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"


def _status() -> Enum:
    return Enum(Status, name="status", native_enum=False, length=16, values_callable=lambda e: [m.value for m in e])


class Dataset(Base):
    __tablename__ = "datasets"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    path: Mapped[str] = mapped_column(Text)
    format: Mapped[str] = mapped_column(String(40))
    frame_count: Mapped[int] = mapped_column(Integer)
    notes: Mapped[str] = mapped_column(Text, default="")
    added_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)
    # how to read it (lidarfuzz.io.options.DatasetOptions: layout, allow_unlabelled, intensity_scale,
    # roi_map), honoured wherever it is opened again
    options: Mapped[dict[str, Any]] = mapped_column(default=dict, server_default="{}")


class Model(Base):
    """A registered system under test."""

    __tablename__ = "models"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    spec: Mapped[str] = mapped_column(Text)
    options: Mapped[dict[str, Any]] = mapped_column(default=dict)
    fingerprint: Mapped[str] = mapped_column(String(64))
    notes: Mapped[str] = mapped_column(Text, default="")
    added_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)


class Task(Base):
    __tablename__ = "tasks"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), default="")
    dataset_id: Mapped[int] = mapped_column(ForeignKey("datasets.id", ondelete="RESTRICT"))
    model_id: Mapped[int] = mapped_column(ForeignKey("models.id", ondelete="RESTRICT"))
    operators: Mapped[list[Any]] = mapped_column(default=list)  # the campaign's: [{"name", "severities", "config"}]
    relations: Mapped[list[Any]] = mapped_column(default=list)  # the campaign's choice: ["auto"] or names / specs
    seed: Mapped[int] = mapped_column(Integer, default=0)
    status: Mapped[Status] = mapped_column(_status(), default=Status.PENDING)
    done: Mapped[int] = mapped_column(Integer, default=0)
    total: Mapped[int] = mapped_column(Integer, default=0)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    summary: Mapped[TaskSummary | None] = mapped_column(ContractJSON(TaskSummary, derived=True), nullable=False,
                                                        default=JSON.NULL)  # JSON null until it is done
    options: Mapped[TaskOptions] = mapped_column(ContractJSON(TaskOptions), default=TaskOptions, server_default="{}")
    error: Mapped[str] = mapped_column(Text, default="", server_default="")
    worker: Mapped[str] = mapped_column(String(200), default="",
                                        server_default="")  # host:pid of the process running it
    heartbeat_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    tags: Mapped[list[Any]] = mapped_column(default=list, server_default="[]")  # the user's labels, strings
    notes: Mapped[str] = mapped_column(Text, default="", server_default="")
    #: the list's sortable figures once the task is done (None before): {"map", "delta_map",
    #: "violations", "failures"}; written with the summary
    headline: Mapped[dict[str, Any] | None] = mapped_column(SafeJSON(none_as_null=True), nullable=True, default=None)

    dataset: Mapped[Dataset] = relationship()
    model: Mapped[Model] = relationship()
    subtasks: Mapped[list[Subtask]] = relationship(back_populates="task", cascade="all, delete-orphan",
                                                   order_by="Subtask.id")


class Subtask(Base):
    """One operator at one severity (severity 0 with no operator: the originals)."""

    __tablename__ = "subtasks"
    __table_args__ = (UniqueConstraint("task_id", "operator_key", "severity"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    task_id: Mapped[int] = mapped_column(ForeignKey("tasks.id", ondelete="CASCADE"), index=True)
    operator_key: Mapped[str] = mapped_column(String(64))  # stable hash of the operator spec ("original" for none)
    operator: Mapped[dict[str, Any]] = mapped_column(default=dict)  # the spec
    name: Mapped[str] = mapped_column(String(100), default="",
                                      server_default="")  # the operator's name ("original" for none)
    op_index: Mapped[int] = mapped_column(Integer, default=0,
                                          server_default="0")  # its mutants' seed stream (keyed by the operator)
    severity: Mapped[int] = mapped_column(Integer)  # 0: the originals, or an operator given an explicit config
    status: Mapped[Status] = mapped_column(_status(), default=Status.PENDING)
    done: Mapped[int] = mapped_column(Integer, default=0)
    total: Mapped[int] = mapped_column(Integer, default=0)
    plan: Mapped[SubtaskInputs] = mapped_column(ContractJSON(SubtaskInputs), default=SubtaskInputs,
                                                server_default="{}")  # what it checks
    state: Mapped[dict[str, Any] | None] = mapped_column(SafeJSON(none_as_null=True), nullable=True,
                                                          default=None)  # the kind's, to resume (a search's)
    results: Mapped[SubtaskResults] = mapped_column(ContractJSON(SubtaskResults), default=SubtaskResults)
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)  # its first unit ran
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)  # its figures written

    task: Mapped[Task] = relationship(back_populates="subtasks")


class FrameResult(Base):
    """The outcome of one work unit: (subtask, frame, trial), committed as soon as it exists."""

    __tablename__ = "frame_results"
    __table_args__ = (UniqueConstraint("subtask_id", "frame_id", "trial"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    subtask_id: Mapped[int] = mapped_column(ForeignKey("subtasks.id", ondelete="CASCADE"), index=True)
    frame_id: Mapped[str] = mapped_column(String(200))
    trial: Mapped[int] = mapped_column(Integer, default=0)
    params: Mapped[dict[str, Any]] = mapped_column(default=dict)  # the operator's concrete params
    boxes: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)  # the detections (None: the SUT failed)
    labels: Mapped[list[Any]] = mapped_column(default=list)
    gt_boxes: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)  # the mutant's ground truth
    gt_labels: Mapped[list[Any]] = mapped_column(default=list, server_default="[]")
    detections: Mapped[StoredBoxes] = composite(StoredBoxes, "boxes", "labels")  # both columns, one value
    # what a system that does not answer in boxes returned (a steering angle, a controller's
    # commands), as its task kind's own contract dumps it; None for a detector
    output: Mapped[dict[str, Any] | None] = mapped_column(SafeJSON(none_as_null=True), nullable=True, default=None)
    ground_truth: Mapped[StoredBoxes] = composite(StoredBoxes, "gt_boxes", "gt_labels")
    cached: Mapped[bool] = mapped_column(Boolean, default=False,
                                         server_default=false())  # the output came from sut_outputs
    failure: Mapped[FailureRecord | None] = mapped_column(ContractJSON(FailureRecord, none_as_null=True),
                                                          nullable=True)  # SQL NULL: none
    relations: Mapped[list[OutcomeRecord]] = mapped_column(ContractJSON(list[OutcomeRecord]), default=list)
    seconds: Mapped[float] = mapped_column(Float, default=0.0)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)


class Finding(Base):
    """A violation, crash, timeout or invalid output, with what it takes to replay it."""

    __tablename__ = "findings"

    id: Mapped[int] = mapped_column(primary_key=True)
    task_id: Mapped[int] = mapped_column(ForeignKey("tasks.id", ondelete="CASCADE"), index=True)
    frame_result_id: Mapped[int] = mapped_column(ForeignKey("frame_results.id", ondelete="CASCADE"), index=True)
    kind: Mapped[str] = mapped_column(String(40), index=True)  # relation name, or crash / timeout / invalid_output
    cls: Mapped[str] = mapped_column(String(40), default="")
    magnitude: Mapped[float | None] = mapped_column(Float, nullable=True)
    message: Mapped[str] = mapped_column(Text, default="")
    detail: Mapped[dict[str, Any]] = mapped_column(default=dict)
    replay: Mapped[FindingReplay] = mapped_column(ContractJSON(FindingReplay))  # seed, operator, params, frame, ...


class SutOutput(Base):
    """What a system (by fingerprint) returned for an input (by content digest)."""

    __tablename__ = "sut_outputs"
    __table_args__ = (UniqueConstraint("fingerprint", "digest"),
                      Index("ix_sut_outputs_source", "fingerprint", "source"))

    id: Mapped[int] = mapped_column(primary_key=True)
    fingerprint: Mapped[str] = mapped_column(String(64))
    digest: Mapped[str] = mapped_column(String(64))
    # the content digest of the frame the input was made from (for an original, its own digest):
    # a worker reads a frame's cached outputs in one query; None for rows of older versions
    source: Mapped[str | None] = mapped_column(String(64), nullable=True)
    boxes: Mapped[bytes] = mapped_column(LargeBinary)
    labels: Mapped[list[Any]] = mapped_column(default=list)
    output: Mapped[StoredBoxes] = composite(StoredBoxes, "boxes", "labels")
    seconds: Mapped[float] = mapped_column(Float, default=0.0)


# -- Neves et al.'s meta-model: logs, their segments, and code coverage ----------------------
class LogKind(enum.StrEnum):
    FIELD_TEST = "field_test"
    GENERATED = "generated"


class Log(Base):
    """A log: recorded in a field test, or generated from a parent log by a heuristic and a strategy."""

    __tablename__ = "logs"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    kind: Mapped[LogKind] = mapped_column(Enum(LogKind, name="log_kind", native_enum=False, length=16,
                                               values_callable=lambda e: [m.value for m in e]))
    dataset_id: Mapped[int | None] = mapped_column(ForeignKey("datasets.id", ondelete="SET NULL"), nullable=True)
    path: Mapped[str] = mapped_column(Text)
    format: Mapped[str] = mapped_column(String(40))
    frame_count: Mapped[int] = mapped_column(Integer)
    parent_id: Mapped[int | None] = mapped_column(ForeignKey("logs.id", ondelete="RESTRICT"), nullable=True,
                                                  index=True)
    heuristic: Mapped[str] = mapped_column(String(40), default="")  # which chose its segments ("" by hand)
    strategy: Mapped[str] = mapped_column(String(100), default="")  # HGT, AVG, an operator, none
    generation: Mapped[GenerationRecord | None] = mapped_column(ContractJSON(GenerationRecord, none_as_null=True),
                                                                nullable=True)  # SQL NULL for a field-test log
    added_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)

    parent: Mapped[Log | None] = relationship(remote_side=[id])
    segments: Mapped[list[Segment]] = relationship(back_populates="log", cascade="all, delete-orphan",
                                                   order_by="(Segment.size, Segment.index)")


class Segment(Base):
    """Frames ``first_frame``..``last_frame`` (positions in replay order) of a log cut into ``size``-frame segments."""

    __tablename__ = "log_segments"
    __table_args__ = (UniqueConstraint("log_id", "size", "index"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    log_id: Mapped[int] = mapped_column(ForeignKey("logs.id", ondelete="CASCADE"), index=True)
    size: Mapped[int] = mapped_column(Integer)
    index: Mapped[int] = mapped_column(Integer)
    first_frame: Mapped[int] = mapped_column(Integer)
    last_frame: Mapped[int] = mapped_column(Integer)
    first_frame_id: Mapped[str] = mapped_column(String(200))
    last_frame_id: Mapped[str] = mapped_column(String(200))

    log: Mapped[Log] = relationship(back_populates="segments")


class CoverageRecord(Base):
    """What a log or one segment of it covered of a target (module, class or function) under a
    criterion, for one version of the system (its fingerprint)."""

    __tablename__ = "coverage_records"
    __table_args__ = (CheckConstraint("(log_id IS NULL) <> (segment_id IS NULL)", name="ck_coverage_log_or_segment"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    log_id: Mapped[int | None] = mapped_column(ForeignKey("logs.id", ondelete="CASCADE"), nullable=True, index=True)
    segment_id: Mapped[int | None] = mapped_column(ForeignKey("log_segments.id", ondelete="CASCADE"), nullable=True,
                                                   index=True)
    fingerprint: Mapped[str] = mapped_column(String(64))
    criterion: Mapped[str] = mapped_column(String(16))  # node or edge
    target: Mapped[str] = mapped_column(String(500))
    covered: Mapped[CoveredLabels] = mapped_column(ContractJSON(CoveredLabels), default=dict)
    covered_count: Mapped[int] = mapped_column(Integer)
    total_count: Mapped[int] = mapped_column(Integer)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)


# -- the thesis's first experiment: people judge original/mutant pairs -----------------------
class Rating(Base):
    """One rater's verdict on one original/mutant pair (the thesis's Table 6-7 experiment): the pair
    is the mutant's frame result (its original is the same frame of the task's originals). A rater
    rates a pair once: rating it again replaces the verdict, keeping when it was first rated."""

    __tablename__ = "ratings"
    __table_args__ = (UniqueConstraint("frame_result_id", "rater"),
                      CheckConstraint("verdict IN ('same', 'similar', 'different')", name="ck_rating_verdict"))

    id: Mapped[int] = mapped_column(primary_key=True)
    task_id: Mapped[int] = mapped_column(ForeignKey("tasks.id", ondelete="CASCADE"), index=True)
    frame_result_id: Mapped[int] = mapped_column(ForeignKey("frame_results.id", ondelete="CASCADE"), index=True)
    rater: Mapped[str] = mapped_column(String(100))
    verdict: Mapped[str] = mapped_column(String(16))
    first_rated_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)
    rated_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)  # the latest verdict's time


# -- one runner per task: the claim ``run_task`` holds while it runs (lidarfuzz.store.claims) -------------
class TaskClaim(Base):
    """Which process runs a task now: at most one row per task (its primary key), taken by a
    compare-and-set on ``token`` and renewed by a heartbeat; a claim whose process is gone (same
    host) or whose heartbeat stopped is taken over (:mod:`lidarfuzz.store.claims`)."""

    __tablename__ = "task_claims"

    task_id: Mapped[int] = mapped_column(ForeignKey("tasks.id", ondelete="CASCADE"), primary_key=True)
    token: Mapped[str] = mapped_column(String(64))  # this claim's own id: only its holder renews or releases it
    host: Mapped[str] = mapped_column(String(255))
    pid: Mapped[int] = mapped_column(Integer)
    claimed_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)
    renewed_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=now)
