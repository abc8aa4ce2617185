"""What the store holds in its JSON columns, typed: the contracts between the engine, the store,
the reports, the CLI, the web API and its front end.

Every JSON column of a task is one of these models (the store validates on load and dumps on
save through :class:`lidarfuzz.store.types.ContractJSON`), so a reader gets attributes, not
string keys, and a writer cannot store a shape no reader expects:

=====================  ======================================  ====================================
column                 contract                                written by
=====================  ======================================  ====================================
``Task.options``       :class:`TaskOptions`                    creating a task
``Subtask.plan``       :class:`SubtaskInputs`                  creating a task (relations to check)
``Subtask.state``      the kind's own (a search's queue)       the kind, while it runs
``Subtask.results``    :class:`SubtaskResults`                 the kind, when the subtask completes
``FrameResult.failure``  :class:`FailureRecord`                a unit the SUT (or operator) failed
``FrameResult.relations``  :class:`OutcomeRecord` each         a unit whose relations were checked
``Finding.replay``     :class:`FindingReplay`                  a finding, with what replays it
``Task.summary``       :class:`TaskSummary`                    the task's end (every report reads it)
=====================  ======================================  ====================================

Numbers that may be undefined are :data:`Number`: NaN in Python (arithmetic and ``math.isnan``
work), ``null`` in JSON (which has no NaN; PostgreSQL refuses it) — converted here, once, in both
directions. The web front end reads :func:`summary_schema` rather than guessing shapes.

Example:
    >>> record = ViolationRecord(relation="MR1", kind="missing", magnitude=float("nan"))
    >>> record.model_dump(mode="json")["magnitude"] is None
    True
    >>> math.isnan(ViolationRecord.model_validate({"relation": "MR1", "kind": "missing",
    ...                                            "magnitude": None}).magnitude)
    True
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import (
    AliasChoices,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainSerializer,
    SerializerFunctionWrapHandler,
    model_serializer,
)


def _nan_if_none(value: Any) -> Any:
    return math.nan if value is None else value


def _none_if_nan(value: float) -> float | None:
    return None if math.isnan(value) or math.isinf(value) else value


#: Fields called ``class`` in JSON are ``cls`` in Python; either name is accepted.
CLASS = AliasChoices("class", "cls")

#: A float that may be undefined: NaN in Python, null in JSON.
Number = Annotated[float, BeforeValidator(_nan_if_none), PlainSerializer(_none_if_nan, return_type=float | None)]


class Contract(BaseModel):
    """Base of the contracts: unknown keys are errors (a typo in a writer is caught at once);
    ``class`` is spelt ``cls`` in Python and ``class`` in JSON."""

    model_config = ConfigDict(extra="forbid", validate_by_name=True, validate_by_alias=True, ser_json_inf_nan="null")

    def dump(self) -> dict[str, Any]:
        """The JSON form (what the store and the web API hold)."""
        return self.model_dump(mode="json", by_alias=True)


# -- a unit's outcome -------------------------------------------------------------------
#: Failures that are lidarfuzz's own (an operator or a relation raised), never the system's: they are
#: counted apart (``tool_errors``) and never become findings against the system under test.
TOOL_ERRORS = ("operator_error", "oracle_error")


class FailureRecord(Contract):
    """Why a unit has no usable output: the SUT crashed, timed out or returned an invalid output
    (:class:`lidarfuzz.suts.base.Failure`), the operator failed on the frame (``operator_error``) or
    a relation raised (``oracle_error``); the last two are :data:`TOOL_ERRORS`."""

    kind: str
    message: str = ""
    detail: str = ""


class ViolationRecord(Contract):
    """One broken expectation (:class:`lidarfuzz.oracles.relations.base.Violation`) as stored."""

    relation: str
    kind: str
    cls: str = ""
    source_index: int = -1
    follow_index: int = -1
    gt_index: int = -1
    magnitude: Number = math.nan
    measure: str = ""
    range_m: Number = math.nan
    message: str = ""
    evidence: dict[str, Number] = Field(default_factory=dict)

    @classmethod
    def of(cls, violation: Any) -> ViolationRecord:
        """From a :class:`~lidarfuzz.oracles.relations.base.Violation` (or any object with its fields)."""
        return cls.model_validate({name: getattr(violation, name) for name in cls.model_fields
                                   if hasattr(violation, name)})


class OutcomeRecord(Contract):
    """One relation checked on one pair (:class:`lidarfuzz.oracles.relations.base.RelationOutcome`)."""

    relation: str
    holds: bool
    applicable: bool = True
    violations: list[ViolationRecord] = Field(default_factory=list)
    checked: dict[str, int] = Field(default_factory=dict)
    stats: dict[str, Any] = Field(default_factory=dict)
    basis: str = ""
    skipped: dict[str, int] = Field(default_factory=dict)

    @classmethod
    def of(cls, outcome: Any) -> OutcomeRecord:
        """From a :class:`~lidarfuzz.oracles.relations.base.RelationOutcome`."""
        return cls(relation=outcome.relation, holds=outcome.holds, applicable=outcome.applicable,
                   violations=[ViolationRecord.of(v) for v in outcome.violations], checked=dict(outcome.checked),
                   stats=dict(outcome.stats), basis=getattr(outcome, "basis", ""),
                   skipped=dict(getattr(outcome, "skipped", {})))


class FindingReplay(Contract):
    """What it takes to replay a finding exactly (``lidarfuzz replay``): the frame and trial, the
    seed and operator (spec and concrete params: no random number is drawn again), the system and
    its fingerprint then, and the relation that was violated.

    Attributes:
        dataset: The data set's path.
        options: The system's options.
        op_index: The seed stream of its mutants (keyed by the operator's spec; the operator's place
            in the campaign for tasks planned before that).
        operator: The operator spec (None: the finding is on an original).
        relation: The violated relation's spec (None: a failure).
        operator_relation: Overrides the operator's own relation kind (a search's valid tests are
            checked as invariant).
    """

    dataset: str
    frame_id: str
    trial: int = 0
    seed: int = 0
    op_index: int = 0
    operator: dict[str, Any] | None = None
    params: dict[str, Any] = Field(default_factory=dict)
    sut: str
    options: dict[str, Any] = Field(default_factory=dict)
    fingerprint: str
    relation: dict[str, Any] | None = None
    operator_relation: str | None = None


# -- what a task is told --------------------------------------------------------------------
class PilotNote(Contract):
    """What a campaign's pilot (:mod:`lidarfuzz.campaign.pilot`) changed: the pilot's task, the
    system it ran (the reference, or the system itself), its frames and the campaign's, and the
    operator settings dropped or lowered, each with the floor that left it no room."""

    task_id: int
    system: str
    frames: int
    campaign_frames: int
    dropped: list[str] = Field(default_factory=list)
    lowered: list[str] = Field(default_factory=list)


class TaskOptions(Contract):
    """How a task runs, fixed when it is created.

    Attributes:
        kind: Its row in :data:`lidarfuzz.campaign.kinds.TASK_KINDS`.
        frame_ids: The frames it tests (fixed then, so a resume tests the same ones).
        trials: Mutants per frame and operator configuration.
        isolate: The SUT runs in a child process (crashes and hangs are findings, not ours).
        timeout: Seconds the SUT may take on one input.
        save_mutants: Folder where mutants are written as a KITTI data set (None: not saved).
        unlabelled_frames: Frames without labels in a labelled data set (run, left out of AP).
        kind_options: The kind's own options, validated by its module (a search's config).
        references: Tasks of reference systems a campaign created beside this one, on the same
            frames, operators and seed (``reference:`` in the campaign; compared in its report).
        reference_of: On such a reference task: the task it is the reference of.
        pilot: What the campaign's pilot dropped or lowered (None: no pilot ran).
    """

    kind: str = "mutation"
    frame_ids: list[str] = Field(default_factory=list)
    trials: int = 1
    isolate: bool = False
    timeout: float = 60.0
    save_mutants: str | None = None
    unlabelled_frames: list[str] = Field(default_factory=list)
    kind_options: dict[str, Any] = Field(default_factory=dict)
    references: list[int] = Field(default_factory=list)
    reference_of: int | None = None
    pilot: PilotNote | None = None


class SubtaskInputs(Contract):
    """What a subtask checks, fixed when the task is planned: the relation specs
    (``{"name", "config"}``) its results are checked against, and the relations left unchecked
    with the reason (its operator is not meant to be harmless at this setting)."""

    relation_specs: list[dict[str, Any]] = Field(default_factory=list)
    unchecked: dict[str, str] = Field(default_factory=dict)

    @property
    def relation_names(self) -> list[str]:
        return [str(spec["name"]) for spec in self.relation_specs]


# -- a subtask's figures --------------------------------------------------------------------
#: metric → class → difficulty → interpolation (R11, R40) → AP in percent.
APTable = dict[str, dict[str, dict[str, dict[str, Number]]]]


class APRecord(Contract):
    """KITTI AP of one subtask (:class:`lidarfuzz.oracles.kitti_eval.KittiEvalResult`)."""

    ap: APTable
    map: dict[str, dict[str, dict[str, Number]]] = Field(default_factory=dict)
    overlaps: dict[str, dict[str, float]] = Field(default_factory=dict)
    num_frames: int = 0
    num_objects: dict[str, dict[str, int]] = Field(default_factory=dict)
    warnings: list[str] = Field(default_factory=list)

    @classmethod
    def of(cls, result: Any) -> APRecord:
        """From a :class:`~lidarfuzz.oracles.kitti_eval.KittiEvalResult`."""
        return cls.model_validate(result.to_dict())


class APExcluded(Contract):
    """Frames left out of AP (no label file) and why."""

    frames: int
    examples: list[str]
    reason: str


class RateRow(Contract):
    """A violation rate of one group: the grouping keys it has (relation, operator, severity,
    label, class; absent when not grouped by), what was checked and what was violated."""

    relation: str | None = None
    operator: str | None = None
    severity: int | None = None
    label: str | None = None
    cls: str | None = Field(default=None, validation_alias=CLASS, serialization_alias="class")
    checked: int
    violated: int
    rate: float | None = None

    @model_serializer(mode="wrap")
    def _grouped_only(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        keys = {"relation", "operator", "severity", "label", "class", "cls"}
        return {k: v for k, v in handler(self).items() if k not in keys or v is not None}


class SearchProgress(Contract):
    """What a coverage-guided search reached: coverage per criterion and its counters."""

    coverage: dict[str, Number] = Field(default_factory=dict)
    stats: dict[str, int] = Field(default_factory=dict)


class DeepTestErrors(Contract):
    """``deeptest_tolerance`` over one subtask's mutants (one transformation, DeepTest's Eq. 2 and 3;
    :class:`lidarfuzz.oracles.deeptest.TransformationErrors`)."""

    mse_orig: Number = math.nan
    mse_orig_from: str = "data set"
    mse: Number = math.nan
    objects: int = 0
    mutants: int = 0
    violated: int = 0
    lambdas: list[float] = Field(default_factory=list)
    erroneous: list[int] = Field(default_factory=list)
    configured_lambda: Number = math.nan
    configured_epsilon: Number = math.nan
    filtered: bool = True  # False: a composite transformation (fog, rain, a search's chains), never filtered by Eq. 3
    kept: bool = False


class SubtaskResults(Contract):
    """A complete subtask's figures (:func:`lidarfuzz.campaign.results.evaluate_subtask`), and a
    search's progress while it runs. Empty while the subtask is incomplete."""

    frames: int = 0
    failures: int = 0
    tool_errors: dict[str, int] = Field(default_factory=dict)
    cached: int = 0
    sut_seconds: float = 0.0
    ap: APRecord | None = None
    ap_note: str | None = None
    ap_excluded: APExcluded | None = None
    violations: list[RateRow] = Field(default_factory=list)
    violations_per_object: list[RateRow] = Field(default_factory=list)
    violations_total: list[RateRow] = Field(default_factory=list)
    count_form: list[RateRow] = Field(default_factory=list)
    regions: dict[str, int] | None = None
    search: SearchProgress | None = None
    deeptest: DeepTestErrors | None = None


# -- the task's summary ---------------------------------------------------------------------
#: A task's or subtask's status (the values of :class:`lidarfuzz.store.models.Status`, which
#: imports this module): an ``enum`` in the JSON Schema the web front end reads.
StatusName = Literal["pending", "running", "done", "failed", "cancelled"]


class SubtaskSummary(SubtaskResults):
    """One subtask in the summary: what it is, how far it got, and its figures."""

    id: int
    label: str
    operator: str
    family: str = ""
    relation_kind: str = ""
    severity: int = 0
    config: dict[str, Any] = Field(default_factory=dict)
    status: StatusName = "pending"
    done: int = 0
    total: int = 0
    relations: list[str] = Field(default_factory=list)


class DeltaRow(Contract):
    """ΔAP of one subtask for one metric, class (or ``mAP``) and difficulty."""

    label: str
    operator: str
    severity: int
    metric: str
    cls: str = Field(validation_alias=CLASS, serialization_alias="class")
    difficulty: str
    clean: Number
    corrupted: Number
    delta: Number


class OperatorRobustnessRow(Contract):
    operator: str
    severities: list[int]
    ap: list[Number]
    RR: Number
    CE: Number = math.nan
    baseline_ap: list[Number] = Field(default_factory=list)


class RobustnessRecord(Contract):
    """Robo3D's resilience (and corruption error against a baseline) for one metric
    (:class:`lidarfuzz.oracles.robustness.RobustnessSummary`), or why there is none."""

    error: str | None = None
    metric: str = ""
    cls: str | None = None
    difficulty: str = ""
    points: str = ""
    clean_ap: Number = math.nan
    operators: list[OperatorRobustnessRow] = Field(default_factory=list)
    mean_resilience: Number = math.nan
    mean_corruption_error: Number = math.nan
    baseline_clean_ap: Number = math.nan
    notes: list[str] = Field(default_factory=list)
    mRR: Number = math.nan
    mCE: Number = math.nan

    @model_serializer(mode="wrap")
    def _error_alone(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        data: dict[str, Any] = handler(self)
        return {"error": self.error} if self.error is not None else {k: v for k, v in data.items() if k != "error"}


class ViolationTables(Contract):
    """Violation rates of the whole task, grouped several ways."""

    relation: list[RateRow] = Field(default_factory=list)
    relation_operator: list[RateRow] = Field(default_factory=list)
    relation_label: list[RateRow] = Field(default_factory=list)
    relation_class: list[RateRow] = Field(default_factory=list)
    relation_operator_class: list[RateRow] = Field(default_factory=list)
    relation_class_objects: list[RateRow] = Field(default_factory=list)
    count_form: list[RateRow] = Field(default_factory=list)


class DeepTestRow(Contract):
    """One transformation in DeepTest's table: its MSE, and whether Eq. 3 keeps it at the relation's ε."""

    label: str
    operator: str
    severity: int = 0
    mse: Number = math.nan
    difference: Number = math.nan
    objects: int = 0
    mutants: int = 0
    violated: int = 0
    kept: bool = False
    filtered: bool = True  # False: composite (fog, rain, a search's chains): never filtered by Eq. 3


class DeepTestTable(Contract):
    """DeepTest's Table 7 for a task (:class:`lidarfuzz.oracles.deeptest.ErroneousTable`): mutants
    erroneous at each λ (rows) over the transformations Eq. 3 keeps at each ε (columns), and with no
    filter; with the data set's MSE_orig and the relation's own λ and ε."""

    mse_orig: Number = math.nan
    configured_lambda: Number = math.nan
    configured_epsilon: Number = math.nan
    lambdas: list[float] = Field(default_factory=list)
    epsilons: list[float] = Field(default_factory=list)
    counts: list[list[int]] = Field(default_factory=list)
    unfiltered: list[int] = Field(default_factory=list)
    transformations: list[DeepTestRow] = Field(default_factory=list)
    notes: list[str] = Field(default_factory=list)


class TopFinding(Contract):
    id: int
    kind: str
    cls: str = Field(default="", validation_alias=CLASS, serialization_alias="class")
    magnitude: float | None = None
    message: str = ""
    operator: str
    severity: int
    label: str
    frame_id: str
    trial: int = 0
    replay: str


class FindingsSummary(Contract):
    total: int = 0
    by_kind: dict[str, int] = Field(default_factory=dict)
    top: list[TopFinding] = Field(default_factory=list)


class DatasetRef(Contract):
    name: str
    path: str
    format: str


class ModelRef(Contract):
    name: str
    spec: str
    options: dict[str, Any] = Field(default_factory=dict)
    fingerprint: str


class TaskInfo(Contract):
    """The task as the summary describes it."""

    id: int
    name: str = ""
    status: StatusName
    dataset: DatasetRef
    model: ModelRef
    seed: int = 0
    trials: int = 1
    frames: int = 0
    relations: list[Any] = Field(default_factory=list)
    unlabelled_frames: int = 0
    created_at: str | None = None
    started_at: str | None = None
    finished_at: str | None = None
    done: int = 0
    total: int = 0
    baseline: int | None = None
    pilot: PilotNote | None = None


class RunTimings(Contract):
    """Where one run's time went (:class:`lidarfuzz.campaign.lifecycle.RunStats`), in seconds."""

    units: int = 0
    cached: int = 0
    failures: int = 0
    wall: float = 0.0
    sut: float = 0.0
    stages: dict[str, float] = Field(default_factory=dict)
    store: float = 0.0
    evaluate: float = 0.0


class SearchSummary(SearchProgress):
    """A search task's end: its kind, coverage, counters and the violation signatures it knows."""

    kind: Literal["guided", "fuzz"]
    signatures: dict[str, Any] = Field(default_factory=dict)


class TaskSummary(Contract):
    """Everything a report shows about a finished task (:func:`lidarfuzz.campaign.results.summarise`)."""

    task: TaskInfo
    classes: list[str]
    subtasks: list[SubtaskSummary]
    delta_ap: list[DeltaRow] = Field(default_factory=list)
    ap_warnings: list[str] = Field(default_factory=list)
    robustness: dict[str, RobustnessRecord] = Field(default_factory=dict)
    violations: ViolationTables = Field(default_factory=ViolationTables)
    findings: FindingsSummary = Field(default_factory=FindingsSummary)
    run: RunTimings | None = None
    search: SearchSummary | None = None
    deeptest: DeepTestTable | None = None
    kind_summary: dict[str, Any] = Field(default_factory=dict)
    """What a task kind reports beyond the shared tables, as its own module's contract dumps it
    (a new kind adds its figures here without changing this contract)."""


def summary_schema() -> dict[str, Any]:
    """The JSON Schema of :class:`TaskSummary` as the web API sends it."""
    return TaskSummary.model_json_schema(mode="serialization", by_alias=True)


__all__ = ["APExcluded", "APRecord", "APTable", "Contract", "DatasetRef", "DeepTestErrors", "DeepTestRow",
    "DeepTestTable", "DeltaRow", "FailureRecord", "FindingReplay", "FindingsSummary", "ModelRef", "Number",
    "OperatorRobustnessRow", "OutcomeRecord", "PilotNote", "RateRow", "RobustnessRecord", "RunTimings",
    "SearchProgress", "SearchSummary", "StatusName", "SubtaskInputs", "SubtaskResults", "SubtaskSummary", "TaskInfo",
    "TaskOptions", "TaskSummary", "TopFinding", "ViolationRecord", "ViolationTables", "summary_schema"]
