"""The ``camera`` task kind: DeepTest on a steering system — transformations, Eq. 2 and 3, Algorithm 1.

A camera task tests a steering system (:mod:`lidarfuzz.suts.steering`) on an image data set
(:mod:`lidarfuzz.io.images`) the way Tian et al. (ICSE 2018) test theirs:

1. **originals** — every frame once; ``MSE_orig`` is the system's mean squared error against the
   frames' labels over this original data set (kept in the originals' subtask ``state``);
2. **transformations** — one subtask per image transformation × severity (or explicit config),
   ``trials`` transformed images per frame, each judged by Eq. 2 (``deeptest_steering``:
   ``(label − θ_t)² ≤ λ · MSE_orig``). When a transformation's subtask is complete its
   ``MSE_(trans, param)`` is known, and Eq. 3 (``|MSE_(trans, param) − MSE_orig| ≤ ε``) decides
   whether its violations count: each violation of a kept transformation becomes a finding. Fog and
   rain are composite in the paper and never filtered. The outcomes of every image are stored as
   produced, so the λ × ε table (Table 7) is computed from them for any λ and ε of its grid;
3. **guided** (when ``search.budget`` > 0) — Algorithm 1 over the transformations
   (:mod:`lidarfuzz.search.images`) guided by neuron coverage of the system's network, each test
   judged by Eq. 2 unfiltered, as the paper reports its guided search; the search state is
   committed with every test, so an interrupted search resumes exactly.

Eq. 2 is checked on every transformation, whatever its severity: the paper's own filter for a
transformation that changes what the right answer is, is Eq. 3 — measured on the data, not
assumed. Everything runs in the task's process (an image and a small network take milliseconds;
there is no per-frame work worth a process pool). The lifecycle (resume, cancel, heartbeat,
failures) is the shared one (:mod:`lidarfuzz.campaign.lifecycle`).

Example campaign::

    kind: camera
    dataset: sim-camera         # a KITTI folder with image_2/, a Udacity folder, images + CSV, a bag
    sut: dave2                  # a built-in steering network, a torch/ONNX model, a worker
    operators: [{name: image_brightness, severities: [1, 3, 5]}, {name: image_fog, severities: [2]}]
    relations: [{name: deeptest_steering, config: {lambda: 5, epsilon: 0.03}}]
    search: {budget: 100, criteria: ["nc:0.2"], max_failed_tries: 5}
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy import func, insert, select, update

from lidarfuzz.campaign.lifecycle import ProgressEvent, RunOptions, RunStats, Watch, get_task, now
from lidarfuzz.campaign.plan import ORIGINAL, KindPlan, SubtaskPlan, operator_stream
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.operators.base import generator
from lidarfuzz.store.contracts import FailureRecord, OutcomeRecord, SearchProgress, SearchSummary, SubtaskResults
from lidarfuzz.store.models import Finding, FrameResult, Model, Status, Subtask, Task
from lidarfuzz.store.store import Store

if TYPE_CHECKING:
    from lidarfuzz.campaign.spec import CampaignSpec
    from lidarfuzz.store.contracts import TaskSummary

#: DeepTest's nine transformations (Table 2/4): what a camera campaign runs when it lists none.
DEFAULT_TRANSFORMATIONS: tuple[str, ...] = (
    "image_brightness", "image_contrast", "image_translation", "image_scale", "image_shear", "image_rotation",
    "image_blur", "image_fog", "image_rain",
)
#: The seven simple transformations DeepTest's guided search combines (RQ2/RQ3).
SEARCH_POOL: tuple[str, ...] = DEFAULT_TRANSFORMATIONS[:7]
#: Composite transformations in the paper: Eq. 3 does not filter them.
UNFILTERED: frozenset[str] = frozenset({"image_fog", "image_rain"})
DEFAULT_SEVERITIES: tuple[int, ...] = (1, 3, 5)
GUIDED: Literal["guided"] = "guided"
BLOCK = 16  # frames per committed block


class CameraSetupError(LidarfuzzError, ValueError):
    """A camera campaign that cannot run (a LiDAR operator, a relation that reads no steering)."""


class CameraSearch(BaseModel):
    """The guided search of a camera task (its campaign's ``search`` section)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    budget: int = Field(0, ge=0, description="tests Algorithm 1 generates after the transformations (0: no search)")
    criteria: tuple[str, ...] = Field(("nc:0.2", "tknc:2"), description="coverage criteria tracked")
    guide: str = Field("nc", description="the criterion whose increase keeps a test")
    operators: tuple[str, ...] = Field(SEARCH_POOL, description="the transformations the search combines")
    max_failed_tries: int = Field(5, ge=0, description="failed tries before the next image")
    max_chain: int = Field(6, ge=2, description="most transformations in one test")

    def search_config(self) -> Any:
        from lidarfuzz.search.algorithms import SearchConfig

        return SearchConfig.model_validate({
            "kind": "guided", "operators": self.operators, "budget": max(self.budget, 1), "criteria": self.criteria,
            "guide": self.guide, "max_failed_tries": self.max_failed_tries, "max_chain": self.max_chain,
            "minimise": False})


def camera_search(spec: CampaignSpec) -> CameraSearch:
    return CameraSearch.model_validate(dict(spec.search))


def camera_relations(choice: Any) -> list[dict[str, Any]]:
    """The relation specs a camera task checks: ``deeptest_steering`` for ``auto``, else the listed
    relations, each of which must read a steering system's output."""
    from lidarfuzz.oracles.relations.registry import from_spec

    if choice == "auto":
        return [from_spec({"name": "deeptest_steering"}).spec()]
    chosen = [from_spec(item if isinstance(item, str) else item.model_dump()) for item in choice]
    wrong = [r.name for r in chosen if type(r).output != "steering"]
    if wrong:
        raise CameraSetupError(f"relations: {wrong} judge detections or decisions, not a steering system's angle; "
                               "a camera campaign checks deeptest_steering")
    return [r.spec() for r in chosen]


def _choices(spec: CampaignSpec) -> list[tuple[str, list[int], dict[str, Any] | None]]:
    if not spec.operators:
        return [(name, list(DEFAULT_SEVERITIES), None) for name in DEFAULT_TRANSFORMATIONS]
    return [(c.name, list(c.severities), c.config) for c in spec.operators]


def check_spec(spec: CampaignSpec) -> None:
    """Refuse LiDAR operators, relations that read no steering and a bad search section."""
    from lidarfuzz.operators.registry import get

    lidar = [name for name, _, _ in _choices(spec) if get(name).modality != "camera"]
    if lidar:
        raise ValueError(f"operators {lidar} mutate LiDAR frames; a camera campaign takes image transformations "
                         f"({', '.join(DEFAULT_TRANSFORMATIONS)})")
    camera_relations(spec.relations)
    search = camera_search(spec)
    if search.budget:
        pool = [name for name in search.operators if get(name).modality != "camera"]
        if pool:
            raise ValueError(f"search.operators: {pool} are not image transformations")
        search.search_config()


def plan(spec: CampaignSpec, model: Model, frame_ids: list[str]) -> KindPlan:
    """One subtask per transformation × severity, then the guided search's when it has a budget."""
    from lidarfuzz.operators.registry import get

    relations = camera_relations(spec.relations)
    units = len(frame_ids) * spec.trials
    subtasks = []
    for name, severities, config in _choices(spec):
        cls = get(name)
        stream = operator_stream(cls.name, config)
        if config is not None:
            subtasks.append(SubtaskPlan(cls.name, cls(**config).spec(), units, 0, stream, relations))
            continue
        for severity in severities:
            subtasks.append(SubtaskPlan(cls.name, cls.at_severity(severity).spec(), units, severity, stream,
                                        relations))
    search = camera_search(spec)
    options = search.model_dump(mode="json")
    if search.budget:
        subtasks.append(SubtaskPlan(GUIDED, {"name": GUIDED, "search": options}, search.budget,
                                    relations=relations))
    return KindPlan(subtasks, options)


def steering_record(output: Any) -> dict[str, Any] | None:
    """A steering output as a frame result stores it."""
    return None if output is None else {"steering": float(output.steering)}


class _Stored:
    """A steering output read back from the store (what relations read: ``.steering``)."""

    def __init__(self, record: dict[str, Any]) -> None:
        self.steering = float(record["steering"])


class _CameraRun:
    def __init__(self, store: Store, task: Task, progress: Callable[[ProgressEvent], None] | None,
                 stop: Any) -> None:
        from lidarfuzz.oracles.relations.registry import from_spec
        from lidarfuzz.store.inventory import open_registered
        from lidarfuzz.suts.registry import create_camera

        self.store, self.task, self.progress = store, task, progress
        self.watch = Watch(store, task.id, stop)
        self.config = CameraSearch.model_validate(task.options.kind_options)
        self.subtasks = sorted(task.subtasks, key=lambda sub: sub.id)
        self.original = next(sub for sub in self.subtasks if sub.name == ORIGINAL)
        self.dataset = open_registered(task.dataset)
        self.sut = create_camera(task.model.spec, **task.model.options)
        self.sut.load()
        self.relations = {sub.id: [from_spec(spec) for spec in sub.plan.relation_specs] for sub in self.subtasks}
        self.stats = RunStats()
        self.connection = store.engine.connect()
        self.frames = list(task.options.frame_ids)
        self.outputs: dict[str, Any] = {}  # frame → its original output (None: the system failed)
        self.mse_orig = math.nan

    # -- running the system -------------------------------------------------------------
    def run_sut(self, sample: Any) -> tuple[Any, FailureRecord | None, float]:
        """The system's output on one sample, or its failure (a crash or an invalid output)."""
        start = time.perf_counter()
        try:
            output = self.sut.detect(sample)
        except Exception as exc:  # the system's crash is a result
            return None, FailureRecord(kind="crash", message=f"{type(exc).__name__}: {exc}"), \
                time.perf_counter() - start
        seconds = time.perf_counter() - start
        problem = self.sut.validate(output)
        if problem is not None:
            return None, FailureRecord(kind="invalid_output", message=problem), seconds
        return output, None, seconds

    # -- bookkeeping --------------------------------------------------------------------
    def _done(self) -> set[tuple[int, str, int]]:
        rows = self.connection.execute(select(FrameResult.subtask_id, FrameResult.frame_id, FrameResult.trial).join(
            Subtask).where(Subtask.task_id == self.task.id)).all()
        self.connection.rollback()
        return {(int(a), str(b), int(c)) for a, b, c in rows}

    def _insert(self, sub: Subtask, frame_id: str, trial: int, output: Any, failure: FailureRecord | None,
                relations: list[OutcomeRecord], params: dict[str, Any], seconds: float) -> int:
        row_id = self.connection.execute(insert(FrameResult).returning(FrameResult.id), {
            "subtask_id": sub.id, "frame_id": frame_id, "trial": trial, "params": params,
            "boxes": None, "labels": [], "gt_boxes": None, "gt_labels": [], "output": steering_record(output),
            "failure": failure, "relations": relations, "seconds": seconds, "cached": False,
            "created_at": now()}).scalar_one()
        if failure is not None:
            self.connection.execute(insert(Finding), {
                "task_id": self.task.id, "frame_result_id": row_id, "kind": failure.kind, "cls": "",
                "magnitude": None, "message": failure.message, "detail": {"detail": failure.detail},
                "replay": self._replay(sub, frame_id, trial, params, None)})
        self.stats.units += 1
        self.stats.sut += seconds
        self.stats.failures += int(failure is not None and failure.kind != "operator_error")
        return int(row_id)

    def _replay(self, sub: Subtask, frame_id: str, trial: int, params: dict[str, Any],
                relation: dict[str, Any] | None) -> dict[str, Any]:
        task = self.task
        operator = None if sub.name == ORIGINAL else (params.get("operator") if sub.name == GUIDED else sub.operator)
        values = params.get("params", {}) if sub.name == GUIDED else params
        return {"dataset": task.dataset.path, "frame_id": frame_id, "trial": trial, "seed": task.seed,
                "op_index": sub.op_index, "operator": operator, "params": values if operator else {},
                "sut": task.model.spec, "options": task.model.options, "fingerprint": task.model.fingerprint,
                "relation": relation, "operator_relation": "invariant" if operator else None}

    def _count(self, counts: dict[int, int]) -> None:
        for sub_id, n in counts.items():
            self.connection.execute(update(Subtask).where(Subtask.id == sub_id).values(
                done=Subtask.done + n, status=Status.RUNNING,
                started_at=func.coalesce(Subtask.started_at, now())))  # set once: its first unit
        self.connection.execute(update(Task).where(Task.id == self.task.id).values(
            done=Task.done + sum(counts.values()), heartbeat_at=now()))

    def _progress(self, sub: Subtask, label: str) -> None:
        if self.progress is None:
            return
        done = self.connection.execute(select(Task.done).where(Task.id == self.task.id)).scalar_one()
        sub_done = self.connection.execute(select(Subtask.done).where(Subtask.id == sub.id)).scalar_one()
        self.connection.rollback()
        self.progress(ProgressEvent(done, self.task.total, sub.id, label, sub_done, sub.total))

    # -- 1. the originals ---------------------------------------------------------------
    def run_originals(self, done: set[tuple[int, str, int]]) -> None:
        todo = [f for f in self.frames if (self.original.id, f, 0) not in done]
        for start in range(0, len(todo), BLOCK):
            self.watch.check()
            with self.connection.begin():
                for frame_id in todo[start:start + BLOCK]:
                    output, failure, seconds = self.run_sut(self.dataset.load(frame_id))
                    self._insert(self.original, frame_id, 0, output, failure, [], {}, seconds)
                self._count({self.original.id: len(todo[start:start + BLOCK])})
            self._progress(self.original, ORIGINAL)

    def load_originals(self) -> None:
        """The originals' outputs and MSE_orig (over the frames with a label and an output)."""
        from lidarfuzz.oracles.relations.steering import label_of

        rows = self.connection.execute(select(FrameResult.frame_id, FrameResult.output).where(
            FrameResult.subtask_id == self.original.id, FrameResult.trial == 0)).all()
        self.connection.rollback()
        self.outputs = {str(f): (_Stored(o) if o else None) for f, o in rows}
        state = dict(self.original.state or {})
        if "mse_orig" in state:
            self.mse_orig = math.nan if state["mse_orig"] is None else float(state["mse_orig"])
            return
        errors = []
        for frame_id in self.frames:
            label, output = label_of(self.dataset.load(frame_id)), self.outputs.get(frame_id)
            if label is not None and output is not None:
                errors.append((label - output.steering) ** 2)
        self.mse_orig = sum(errors) / len(errors) if errors else math.nan
        state = {"mse_orig": None if math.isnan(self.mse_orig) else self.mse_orig, "labelled": len(errors)}
        with self.connection.begin():
            self.connection.execute(update(Subtask).where(Subtask.id == self.original.id).values(state=state))
        self.original.state = state

    # -- 2. the transformations ---------------------------------------------------------
    def judge(self, sub: Subtask, source: Any, follow: Any, output: Any, operator: Any) -> list[OutcomeRecord]:
        from lidarfuzz.oracles.relations.base import Pair

        source_output = self.outputs.get(source.frame_id)
        if output is None:
            return []
        reference = {"mse_orig": self.mse_orig, "filtered": 0.0 if sub.name in UNFILTERED else 1.0}
        pair = Pair(source, follow, source_output, output, operator_relation=operator.relation,
                    reference=reference, basis=operator.harmless_because)
        return [OutcomeRecord.of(relation(pair)) for relation in self.relations[sub.id]]

    def run_transformations(self, done: set[tuple[int, str, int]]) -> None:
        from lidarfuzz.operators.registry import from_spec

        subs = [sub for sub in self.subtasks if sub.name not in (ORIGINAL, GUIDED)]
        operators = {sub.id: from_spec(sub.operator) for sub in subs}
        trials = self.task.options.trials
        for start in range(0, len(self.frames), BLOCK):
            block = self.frames[start:start + BLOCK]
            work = [(f, sub, t) for f in block for sub in subs for t in range(trials) if (sub.id, f, t) not in done]
            if not work:
                continue
            self.watch.check()
            samples = {f: self.dataset.load(f) for f in {f for f, _, _ in work}}
            counts: dict[int, int] = {}
            with self.connection.begin():
                for frame_id, sub, trial in work:
                    operator, source = operators[sub.id], samples[frame_id]
                    rng = generator(self.task.seed, frame_id, sub.op_index, trial)
                    try:
                        params = operator.sample(rng, source)
                        follow = operator.apply(source, params)
                    except Exception as exc:  # lidarfuzz's own error, never the system's
                        error = FailureRecord(kind="operator_error", message=f"{type(exc).__name__}: {exc}")
                        self._insert(sub, frame_id, trial, None, error, [], {}, 0.0)
                    else:
                        stored = params.model_dump(mode="json")
                        output, failure, seconds = self.run_sut(follow)
                        outcomes = self.judge(sub, source, follow, output, operator)
                        self._insert(sub, frame_id, trial, output, failure, outcomes, stored, seconds)
                    counts[sub.id] = counts.get(sub.id, 0) + 1
                self._count(counts)
            self._progress(subs[0], "transformations")
        for sub in subs:
            self.finish(sub)

    def finish(self, sub: Subtask) -> None:
        """A complete transformation's figures (its MSE, Eq. 3) and, when Eq. 3 keeps it at the
        relation's ε, a finding per violating image; once (a finished subtask is left alone)."""
        from lidarfuzz.campaign.results import deeptest_errors
        from lidarfuzz.oracles.robustness import RelationRecord

        status = self.connection.execute(select(Subtask.status).where(Subtask.id == sub.id)).scalar_one()
        self.connection.rollback()
        if status == Status.DONE:
            return
        rows = self.connection.execute(select(FrameResult.id, FrameResult.frame_id, FrameResult.trial,
                                              FrameResult.params, FrameResult.failure, FrameResult.relations,
                                              FrameResult.seconds).where(FrameResult.subtask_id == sub.id)).all()
        self.connection.rollback()
        records = [RelationRecord(o.relation, sub.name, sub.severity, f, outcome_of(o))
                   for _, f, _, _, _, relations, _ in rows for o in relations or []]
        errors = deeptest_errors(records)
        results = SubtaskResults(
            frames=len(rows), failures=sum(1 for r in rows if r.failure and r.failure.kind != "operator_error"),
            tool_errors=_tool_errors(r.failure for r in rows), sut_seconds=float(sum(r.seconds or 0 for r in rows)),
            deeptest=errors)
        specs = {spec["name"]: spec for spec in sub.plan.relation_specs}
        with self.connection.begin():
            if errors is not None and errors.kept:
                for row_id, frame_id, trial, params, _, relations, _ in rows:
                    for outcome in relations or []:
                        if not outcome.applicable or outcome.holds:
                            continue
                        worst = max(outcome.violations, key=lambda v: v.magnitude or 0.0, default=None)
                        self.connection.execute(insert(Finding), {
                            "task_id": self.task.id, "frame_result_id": row_id, "kind": outcome.relation, "cls": "",
                            "magnitude": worst.magnitude if worst else None,
                            "message": worst.message if worst else outcome.relation,
                            "detail": {"stats": outcome.stats, "kept_by_eq3": True},
                            "replay": self._replay(sub, frame_id, trial, params, specs.get(outcome.relation))})
            self.connection.execute(update(Subtask).where(Subtask.id == sub.id).values(
                results=results, status=Status.DONE, finished_at=now()))

    # -- 3. the guided search -----------------------------------------------------------
    def run_search(self) -> None:
        sub = next((s for s in self.subtasks if s.name == GUIDED), None)
        if sub is None or math.isnan(self.mse_orig):
            return
        from lidarfuzz.campaign.coverage_search import build_criteria, profile_dirs, torch_module
        from lidarfuzz.coverage import ActivationRecorder
        from lidarfuzz.search.images import ImageGuidedSearch, ImageSearchEvaluator

        module = torch_module(self.sut)
        config = self.config.search_config()
        criteria = build_criteria(config.criteria, module, profile_dirs(self.sut))
        evaluator = ImageSearchEvaluator(self.dataset, self.sut, self.relations[sub.id], ActivationRecorder(module),
                                         mse_orig=self.mse_orig)
        search = ImageGuidedSearch(config, self.frames, criteria, self.task.seed)
        state = self.connection.execute(select(Subtask.state).where(Subtask.id == sub.id)).scalar_one()
        self.connection.rollback()
        if state:
            search.load_state_dict(state)
        specs = {spec["name"]: spec for spec in sub.plan.relation_specs}
        while not search.finished:
            self.watch.check()
            records = search.step(evaluator)
            if not records and search.finished:
                break
            with self.connection.begin():
                n = 0
                if records and records[0].role == "seed":  # DeepTest's baseline: the seed images' coverage
                    state = {**dict(self.original.state or {}), "seed_coverage": search.coverage()}
                    self.connection.execute(update(Subtask).where(Subtask.id == self.original.id).values(
                        state=state))
                    self.original.state = state
                for record in records:
                    if record.role == "seed":
                        continue  # the originals' subtask holds the seed images already
                    e = record.evaluation
                    params = record.params()
                    row_id = self._insert(sub, e.frame_id, record.index, e.output, e.failure, e.relations, params,
                                          e.seconds)
                    for finding in record.findings:
                        self.connection.execute(insert(Finding), {
                            **finding, "task_id": self.task.id, "frame_result_id": row_id,
                            "replay": self._replay(sub, e.frame_id, record.index, params,
                                                   specs.get(finding["kind"]))})
                    n += 1
                results = SubtaskResults(search=SearchProgress(coverage=search.coverage(), stats=search.stats))
                self.connection.execute(update(Subtask).where(Subtask.id == sub.id).values(
                    results=results, state=search.state_dict()))
                self._count({sub.id: n})
            self._progress(sub, GUIDED)
        self.search_summary = SearchSummary(kind=GUIDED, coverage=search.coverage(), stats=search.stats,
                                            signatures=search.known)
        self.finish_search(sub)

    def finish_search(self, sub: Subtask) -> None:
        from lidarfuzz.campaign.results import deeptest_errors
        from lidarfuzz.oracles.robustness import RelationRecord

        rows = self.connection.execute(select(FrameResult.frame_id, FrameResult.failure, FrameResult.relations,
                                              FrameResult.seconds).where(FrameResult.subtask_id == sub.id)).all()
        current = self.connection.execute(select(Subtask.results).where(Subtask.id == sub.id)).scalar_one()
        self.connection.rollback()
        records = [RelationRecord(o.relation, GUIDED, 0, f, outcome_of(o)) for f, _, relations, _ in rows
                   for o in relations or []]
        results = current.model_copy(update={
            "frames": len(rows), "failures": sum(1 for r in rows if r.failure and r.failure.kind != "operator_error"),
            "tool_errors": _tool_errors(r.failure for r in rows),
            "sut_seconds": float(sum(r.seconds or 0 for r in rows)), "deeptest": deeptest_errors(records)})
        with self.connection.begin():
            self.connection.execute(update(Subtask).where(Subtask.id == sub.id).values(
                results=results, status=Status.DONE, total=len(rows), done=len(rows), finished_at=now()))

    # -- the run ------------------------------------------------------------------------
    search_summary: SearchSummary | None = None

    def execute(self) -> None:
        done = self._done()
        self.run_originals(done)
        self.load_originals()
        with self.connection.begin():
            failures = self.connection.execute(select(FrameResult.failure).where(
                FrameResult.subtask_id == self.original.id)).scalars().all()
            self.connection.execute(update(Subtask).where(Subtask.id == self.original.id).values(
                status=Status.DONE, finished_at=func.coalesce(Subtask.finished_at, now()),
                results=SubtaskResults(frames=len(self.frames),
                                                           failures=sum(1 for f in failures if f is not None))))
        self.run_transformations(done)
        self.run_search()

    def summary(self) -> TaskSummary:
        from lidarfuzz.campaign.results import summarise

        with self.store.session() as s:
            row = s.get(Task, self.task.id)
            assert row is not None
            row.total = row.done = sum(sub.done for sub in row.subtasks)
        summary = summarise(self.store, self.task.id)
        summary.search = self.search_summary
        return summary

    def close(self) -> None:
        self.connection.close()
        self.watch.close()
        self.sut.close()


def outcome_of(record: OutcomeRecord) -> Any:
    from lidarfuzz.campaign.results import outcome_from_record

    return outcome_from_record(record)


def _tool_errors(failures: Iterable[FailureRecord | None]) -> dict[str, int]:
    out: dict[str, int] = {}
    for failure in failures:
        if failure is not None and failure.kind == "operator_error":
            out[failure.kind] = out.get(failure.kind, 0) + 1
    return out


# -- replaying a finding -----------------------------------------------------------------
def finding_pair(store: Any, finding_id: int, datasets: dict[str, Any] | None = None) -> dict[str, Any]:
    """A camera finding's original and transformed image (rebuilt from the stored params: no random
    number is drawn again), the label and the system's steering on both, as recorded."""
    from lidarfuzz.operators.registry import from_spec
    from lidarfuzz.store.inventory import open_registered

    with store.session() as s:
        row = s.execute(select(Finding, FrameResult, Subtask, Task).join(
            FrameResult, Finding.frame_result_id == FrameResult.id).join(
            Subtask, FrameResult.subtask_id == Subtask.id).join(Task, Subtask.task_id == Task.id).where(
            Finding.id == finding_id)).first()
        if row is None:
            raise LidarfuzzError(f"no finding {finding_id}")
        finding, result, _, task = row
        dataset_row = task.dataset
        original_output = s.scalar(select(FrameResult.output).join(Subtask).where(
            Subtask.task_id == task.id, Subtask.name == "original", FrameResult.frame_id == result.frame_id,
            FrameResult.trial == 0))
        replay, output, kind = dict(finding.replay or {}), result.output, finding.kind
        key = str(dataset_row.id)
        cache = datasets if datasets is not None else {}
        if key not in cache:
            cache[key] = open_registered(dataset_row)
        dataset = cache[key]
    sample = dataset.load(result.frame_id)
    transformed = sample
    operator = replay.get("operator")
    if operator:
        op = from_spec(operator)
        transformed = op.apply(sample, op.parse_params(replay.get("params") or {}))
    return {"original": sample, "transformed": transformed, "label": sample.steering, "kind": kind,
            "before": (original_output or {}).get("steering"), "after": (output or {}).get("steering"),
            "operator": (operator or {}).get("name", "original"), "frame_id": result.frame_id}



#: Largest difference of two steering answers (the label's unit) for them to be the same.
STEERING_TOLERANCE = 1e-6


@dataclass(frozen=True)
class SteeringReplay:
    """A camera finding run again: the original and transformed image rebuilt (the stored params,
    no random number drawn), the system rebuilt from its spec, each image answered twice.

    Attributes:
        finding: What was recorded (id, task, kind, message, frame, operator).
        fingerprint_recorded / fingerprint_now: The system's identity then and now.
        label: The image's label (None: unlabelled).
        recorded / now / again: Steering on (original, transformed) as recorded, now, and a second time
            now (None where the system failed or there is no transformed image).
        outcomes_now: The relation checked on the answers of now.
        failure_now: The system's failure now, if it failed.
    """

    finding: dict[str, Any]
    fingerprint_recorded: str
    fingerprint_now: str
    label: float | None
    recorded: tuple[float | None, float | None]
    now: tuple[float | None, float | None]
    again: tuple[float | None, float | None]
    outcomes_now: list[OutcomeRecord]
    failure_now: FailureRecord | None

    @staticmethod
    def _same(a: tuple[float | None, float | None], b: tuple[float | None, float | None]) -> bool:
        return all((x is None and y is None) or (x is not None and y is not None and abs(x - y) <= STEERING_TOLERANCE)
                   for x, y in zip(a, b, strict=True))

    @property
    def same_system(self) -> bool:
        return self.fingerprint_now == self.fingerprint_recorded

    @property
    def outputs_match(self) -> bool:
        return self._same(self.recorded, self.now)

    @property
    def deterministic(self) -> bool:
        return self._same(self.now, self.again)

    @property
    def violated_now(self) -> bool:
        if self.finding["relation"]:
            return any(o.applicable and not o.holds for o in self.outcomes_now)
        return self.failure_now is not None and self.failure_now.kind == self.finding["kind"]

    @property
    def reproduced(self) -> bool:
        return self.outputs_match and self.violated_now

    @property
    def verdict(self) -> str:
        if self.reproduced:
            return "reproduced"
        reasons = []
        if not self.outputs_match:
            reasons.append(f"steering differs from the record ({self.recorded} recorded, {self.now} now)")
        if not self.violated_now:
            reasons.append("the relation is not violated now" if self.finding["relation"]
                           else "the system does not fail the same way now")
        if not self.deterministic:
            reasons.append("the system answers differently to the same image (non-deterministic or stateful)")
        if not self.same_system:
            reasons.append("the system changed since (another fingerprint)")
        return "not reproduced: " + "; ".join(reasons)


def replay_camera(store: Store, finding_id: int) -> SteeringReplay:
    """Re-run a camera task's finding in this process, twice, and compare with the record."""
    from lidarfuzz.oracles.relations.base import Pair
    from lidarfuzz.oracles.relations.registry import from_spec as relation_from_spec
    from lidarfuzz.suts.registry import create_camera

    pair = finding_pair(store, finding_id)
    with store.session() as s:
        finding = s.get(Finding, finding_id)
        assert finding is not None
        row = s.get(FrameResult, finding.frame_result_id)
        assert row is not None
        sub = s.get(Subtask, row.subtask_id)
        task = s.get(Task, finding.task_id)
        assert sub is not None and task is not None
        original_state = next((x.state for x in task.subtasks if x.name == ORIGINAL), {}) or {}
        replay = finding.replay
        info = {"id": finding.id, "task_id": task.id, "kind": finding.kind, "message": finding.message,
                "frame_id": row.frame_id, "trial": row.trial, "subtask": sub.name, "severity": sub.severity,
                "relation": replay.relation}
    system = create_camera(replay.sut, **dict(replay.options))
    system.load()
    try:
        runs = []
        for _ in range(2):
            answers: list[float | None] = []
            failure: FailureRecord | None = None
            outputs: list[Any] = []
            for image in (pair["original"], pair["transformed"] if replay.operator else None):
                if image is None:
                    answers.append(None)
                    outputs.append(None)
                    continue
                output: Any = None
                try:
                    output = system.detect(image)
                    problem = system.validate(output)
                    if problem is not None:
                        failure, output = FailureRecord(kind="invalid_output", message=problem), None
                except Exception as exc:  # the system's crash is a result
                    failure, output = FailureRecord(kind="crash", message=f"{type(exc).__name__}: {exc}"), None
                outputs.append(output)
                answers.append(None if output is None else float(output.steering))
            runs.append((tuple(answers), outputs, failure))
        fingerprint_now = system.fingerprint()
    finally:
        system.close()
    (now, outputs, failure), (again, _, _) = runs
    outcomes: list[OutcomeRecord] = []
    if replay.relation and outputs[1] is not None:
        mse = original_state.get("mse_orig")
        reference = {"mse_orig": math.nan if mse is None else float(mse),
                     "filtered": 0.0 if sub.name in UNFILTERED or sub.name == GUIDED else 1.0}
        relation = relation_from_spec(replay.relation)
        outcomes.append(OutcomeRecord.of(relation(Pair(pair["original"], pair["transformed"], outputs[0], outputs[1],
                                                       reference=reference))))
    recorded = (pair["before"], pair["after"] if replay.operator else None)
    return SteeringReplay(info, replay.fingerprint, fingerprint_now, pair["label"],
                          (None if recorded[0] is None else float(recorded[0]),
                           None if recorded[1] is None else float(recorded[1])),
                          now, again, outcomes, failure)  # type: ignore[arg-type]


# -- the kind's hooks (lidarfuzz.campaign.lifecycle.KindImplementation) ----------------
counted_below: int | None = None


def start(store: Store, task: Task, options: RunOptions) -> _CameraRun:
    return _CameraRun(store, task, options.progress, options.stop)


def describe(task: Task) -> str:
    config = CameraSearch.model_validate(task.options.kind_options)
    transformations = sum(1 for sub in task.subtasks if sub.name not in (ORIGINAL, GUIDED))
    search = f", then a guided search of {config.budget} tests" if config.budget else ""
    return f"camera: {len(task.options.frame_ids)} images × {transformations} transformation settings{search}"


def kind_summary(store: Store, task: Task) -> dict[str, Any]:
    """MSE_orig and how many labelled images it is over (the rest is in the shared tables)."""
    task = get_task(store, task.id)
    original = next(sub for sub in task.subtasks if sub.name == ORIGINAL)
    state = dict(original.state or {})
    return {"modality": "camera", "mse_orig": state.get("mse_orig"), "labelled": state.get("labelled", 0),
            "images": len(task.options.frame_ids), "seed_coverage": state.get("seed_coverage", {})}


__all__ = ["DEFAULT_TRANSFORMATIONS", "GUIDED", "SEARCH_POOL", "STEERING_TOLERANCE", "UNFILTERED", "CameraSearch",
           "CameraSetupError", "SteeringReplay", "camera_relations", "check_spec", "counted_below", "describe",
           "finding_pair", "kind_summary", "plan", "replay_camera", "start"]
