"""The detection campaign (kind ``mutation``): every frame through each operator × severity.

Order: the originals first (their outputs are the source side of every relation), then each
operator × severity in the task's order. When a subtask checks DeepTest's relation, every original
runs before any mutant: its ``MSE_orig`` is over the whole original data set, so it is computed
from the stored originals and passed in the relation's config (stored with each finding, so a
replay judges by the same limit); each verdict is then final when it is stored. When a subtask
completes, DeepTest's ε filter (Eq. 3) judges it as a whole, and the findings of a subtask it drops
say that they are not counted as erroneous behaviours (the report's Table 7 does not count them).

A result is one transaction: its frame result, its findings, the cache entry and the counters,
so a kill at any instant leaves whole results and counters that agree with them (and
:func:`~lidarfuzz.campaign.lifecycle.recount` re-derives the counters anyway on every start).
Units are keyed by (subtask, frame, trial) under a unique constraint: a resumed task runs exactly
the units that have no result, and nothing is counted twice. Results are stored in the order the
units are planned (:func:`~lidarfuzz.campaign.executor.in_unit_order`), whatever finishes first, so
identical runs number their results and findings alike and a resumed run goes on where a killed one
stopped. A unit with a data fault (:data:`~lidarfuzz.campaign.work.DATA_FAULT`: its frame could not be
read) counts as done but is run again by every resume: its new result replaces the fault in place, in
the same transaction, and its subtask's figures are computed again. Units run on an
:class:`~lidarfuzz.campaign.executor.Executor`; this process is the single writer.

The hooks of :class:`~lidarfuzz.campaign.lifecycle.KindImplementation` are at the end; the
lifecycle around them (status, heartbeat, cancel) is :mod:`lidarfuzz.campaign.lifecycle`.
"""

from __future__ import annotations

import importlib
import json
import math
import threading
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Iterator
from typing import TYPE_CHECKING, Any

from sqlalchemy import bindparam, delete, func, insert, literal, select, update
from sqlalchemy.exc import IntegrityError

from lidarfuzz.campaign.executor import Executor, ProcessExecutor, in_unit_order
from lidarfuzz.campaign.lifecycle import ProgressEvent, RunOptions, RunStats, Watch, now
from lidarfuzz.campaign.plan import (
    ORIGINAL,
    KindPlan,
    SubtaskPlan,
    operator_stream,
    relations_for,
    subtask_label,
    unchecked_relations,
)
from lidarfuzz.campaign.work import DATA_FAULT, NOT_THE_SYSTEM, UnitResult, WorkContext, WorkUnit
from lidarfuzz.store.boxes import StoredBoxes
from lidarfuzz.store.contracts import TaskSummary, ViolationRecord
from lidarfuzz.store.errors import StoreError
from lidarfuzz.store.models import Finding, FrameResult, Model, Status, Subtask, SutOutput, Task
from lidarfuzz.store.prepared import Prepared
from lidarfuzz.store.store import Store

if TYPE_CHECKING:
    from lidarfuzz.campaign.spec import CampaignSpec

CACHE_EVERY = 0.5  # seconds between writes of the outputs waiting for the cache (_Run._cache_due)
#: The columns a result's row is written with, and a finding's (see :meth:`_Run.commit`).
RESULT_COLUMNS = ("subtask_id", "frame_id", "trial", "params", "boxes", "labels", "gt_boxes", "gt_labels",
                  "failure", "relations", "seconds", "cached", "created_at")
FINDING_COLUMNS = ("task_id", "frame_result_id", "kind", "cls", "magnitude", "message", "detail", "replay")
BLOCK = 16  # frames per block (see _Run._units); a worker's scene cache holds one block
#: Every stored result counts towards progress.
counted_below: int | None = None


class _Run:
    def __init__(self, store: Store, task: Task, executor: Executor,
                 progress: Callable[[ProgressEvent], None] | None, stop: threading.Event | None) -> None:
        self.store, self.task, self.executor = store, task, executor
        self.progress = progress
        self.watch = Watch(store, task.id, stop)
        self.stats = RunStats()
        self.subtasks = {sub.id: sub for sub in task.subtasks}
        self.done = {sub.id: sub.done for sub in task.subtasks}
        self.task_done = task.done
        self.frame_ids: list[str] = list(task.options.frame_ids)
        self.trials = task.options.trials
        self._calibs: dict[str, Any] = {}
        self._connection = store.engine.connect()  # one for every commit: no pool check-out per result
        # statements built once (building one costs more than running it)
        # the hot path's statements compiled once and run on the driver's cursor (see store.prepared)
        dialect = store.engine.dialect
        self._insert_result = Prepared(insert(FrameResult).returning(FrameResult.id), dialect, RESULT_COLUMNS)
        self._insert_finding = Prepared(insert(Finding), dialect, FINDING_COLUMNS)
        self._bump_subtask = Prepared(update(Subtask).where(Subtask.id == bindparam("subtask")).values(
            done=Subtask.done + bindparam("n"), status=Status.RUNNING,
            started_at=func.coalesce(Subtask.started_at, bindparam("now"))),  # set once: its first unit
            dialect, ("subtask", "n", "now"))
        self._bump_task = Prepared(update(Task).where(Task.id == bindparam("task")).values(
            done=Task.done + bindparam("n")), dialect, ("task", "n"))
        # Outputs not yet in the cache (see _cache_due).
        self._uncached: list[dict[str, Any]] = []
        self._cached_at = time.monotonic()
        self._started: set[int] = set()  # subtasks whose first result this run has stored
        if dialect.name not in ("sqlite", "postgresql"):
            raise StoreError(f"campaigns run on SQLite or PostgreSQL, not {dialect.name}")
        dialect_insert = importlib.import_module(f"sqlalchemy.dialects.{dialect.name}").insert
        self._cache_insert: Any = dialect_insert(SutOutput).on_conflict_do_nothing()  # a concurrent twin: fine
        self._dataset: Any = None
        self._mse_orig: dict[str, float] = {}  # DeepTest's MSE_orig by relation spec (see _with_mse_orig)
        self._faults: dict[tuple[int, str, int], int] = {}  # data faults to run again: unit key → result id
        self._faults_left: Counter[int] = Counter()  # how many of them each subtask has
        self._replace_result = update(FrameResult).where(FrameResult.id == bindparam("row"))
        self._drop_findings = delete(Finding).where(Finding.frame_result_id == bindparam("row"))

    # -- units ------------------------------------------------------------------------
    def _finished_keys(self) -> set[tuple[int, str, int]]:
        """The units with a result, less those with a data fault (kept in ``_faults``, to run again);
        a subtask with a data fault is open again (its figures are computed anew when it completes)."""
        done, faulted = set(), set()
        with self.store.session() as s:
            rows = s.execute(select(FrameResult.id, FrameResult.subtask_id, FrameResult.frame_id, FrameResult.trial,
                                    FrameResult.failure).join(Subtask).where(Subtask.task_id == self.task.id))
            for row_id, sub_id, frame_id, trial, failure in rows:
                if failure is not None and failure.kind == DATA_FAULT:
                    self._faults[(sub_id, frame_id, trial)] = row_id
                    self._faults_left[sub_id] += 1
                    faulted.add(sub_id)
                else:
                    done.add((sub_id, frame_id, trial))
            if faulted:
                s.execute(update(Subtask).where(Subtask.id.in_(faulted), Subtask.status == Status.DONE).values(
                    status=Status.RUNNING, finished_at=None))
        return done

    def _waiting(self, sub_id: int) -> bool:
        """Whether a data fault of subtask ``sub_id`` waits to run again in this run."""
        return self._faults_left[sub_id] > 0

    def _sources(self, original: Subtask) -> dict[str, tuple[StoredBoxes, bool, str]]:
        """The originals' outputs by frame, whether the system failed on each, and its data fault's
        message ("" for none)."""
        with self.store.session() as s:
            rows = s.execute(select(FrameResult.frame_id, FrameResult.detections, FrameResult.failure).where(
                FrameResult.subtask_id == original.id))
            return {f: (detections, failure is not None,
                        failure.message if failure is not None and failure.kind == DATA_FAULT else "")
                    for f, detections, failure in rows}

    def _units(self, subtasks: Iterable[Subtask], done: set[tuple[int, str, int]],
               sources: dict[str, tuple[StoredBoxes, bool, str]],
               block: list[str]) -> Iterator[WorkUnit]:
        """Pending units of ``subtasks`` on a block of frames, subtask by subtask."""
        for sub in subtasks:
            is_original = sub.name == ORIGINAL
            trials = 1 if is_original else self.trials
            relations = tuple(self._with_mse_orig(spec) for spec in sub.plan.relation_specs) if not is_original \
                else ()
            label = subtask_label(sub.name, sub.severity)
            for frame_id in block:
                for trial in range(trials):
                    if (sub.id, frame_id, trial) in done:
                        continue
                    if is_original:
                        yield WorkUnit(sub.id, frame_id, trial, None, sub.op_index, self.task.seed, label)
                        continue
                    output, failed, fault = sources.get(frame_id, (None, True, ""))
                    yield WorkUnit(sub.id, frame_id, trial, sub.operator, sub.op_index, self.task.seed, label,
                                   relations, output, failed, source_fault=fault)

    # -- DeepTest's MSE_orig ----------------------------------------------------------
    @staticmethod
    def _needs_mse_orig(spec: dict[str, Any]) -> bool:
        return spec.get("name") == "deeptest_tolerance" and (spec.get("config") or {}).get("mse_orig") is None

    def _compute_mse_orig(self, original: Subtask, subtasks: Iterable[Subtask]) -> None:
        """DeepTest's MSE_orig of every ``deeptest_tolerance`` spec the subtasks check, from all the
        stored originals (a frame the system failed on has no output and is left out)."""
        from lidarfuzz.oracles.relations.detection import DeepTestTolerance

        specs = {json.dumps(spec, sort_keys=True): spec for sub in subtasks for spec in sub.plan.relation_specs
                 if self._needs_mse_orig(spec)}
        if not specs:
            return
        with self.store.session() as s:
            rows = s.execute(select(FrameResult.ground_truth, FrameResult.detections, FrameResult.failure).where(
                FrameResult.subtask_id == original.id)).all()
        frames = [(truth.boxes(), detections.boxes()) for truth, detections, failure in rows
                  if failure is None and not detections.missing]
        for key, spec in specs.items():
            value, _ = DeepTestTolerance(**(spec.get("config") or {})).mse_orig_of(frames)
            if math.isfinite(value):  # no object found on any original: the relation has nothing to scale
                self._mse_orig[key] = value

    def _with_mse_orig(self, spec: dict[str, Any]) -> dict[str, Any]:
        """``spec`` with the data set's MSE_orig in its config, when it is DeepTest's and one is known."""
        if not self._needs_mse_orig(spec):
            return spec
        value = self._mse_orig.get(json.dumps(spec, sort_keys=True))
        return spec if value is None else {**spec, "config": {**(spec.get("config") or {}), "mse_orig": value}}

    # -- results ----------------------------------------------------------------------
    def _replay(self, result: UnitResult, relation: dict[str, Any] | None = None) -> dict[str, Any]:
        unit = self.task
        return {"dataset": unit.dataset.path, "frame_id": result.unit.frame_id, "trial": result.unit.trial,
                "seed": unit.seed, "op_index": result.unit.op_index, "operator": result.unit.operator,
                "params": result.params, "sut": unit.model.spec, "options": unit.model.options,
                "fingerprint": unit.model.fingerprint, "relation": relation}

    def _findings(self, result: UnitResult, frame_result_id: int) -> list[dict[str, Any]]:
        """Rows of the findings table: a failure, and per violated relation one per class."""
        findings = []
        failure = result.failure
        if failure is not None and failure.kind not in NOT_THE_SYSTEM:  # nor lidarfuzz's errors nor data faults
            findings.append(dict(task_id=self.task.id, frame_result_id=frame_result_id, cls="", magnitude=None,
                                 kind=failure.kind, message=failure.message, detail={"detail": failure.detail},
                                 replay=self._replay(result)))
        specs = {spec["name"]: spec for spec in result.unit.relations}
        for outcome in result.relations:
            if outcome.holds or not outcome.violations:
                continue
            by_class: dict[str, list[ViolationRecord]] = defaultdict(list)
            for violation in outcome.violations:
                by_class[violation.cls].append(violation)
            for cls, violations in sorted(by_class.items()):
                first = violations[0].message
                more = f" (and {len(violations) - 1} more)" if len(violations) > 1 else ""
                findings.append(dict(task_id=self.task.id, frame_result_id=frame_result_id,
                                     kind=outcome.relation, cls=cls, magnitude=float(len(violations)),
                                     message=first + more, detail={"violations": [v.dump() for v in violations]},
                                     replay=self._replay(result, specs.get(outcome.relation))))
        return findings

    def _cache_due(self, sub_id: int, *, last: bool) -> bool:
        """Whether this result's transaction also writes the outputs waiting for the cache: at a
        subtask's first and last result (``last``), else at most every :data:`CACHE_EVERY` seconds.

        A cache insert per result costs half the result's own insert, and the cache only saves
        work: cache rows a killed run never wrote mean the system runs on those inputs again.
        The counters are not deferred: every result is committed whole, with its counters.
        """
        if last or sub_id not in self._started:
            return True
        return time.monotonic() - self._cached_at >= CACHE_EVERY

    def flush_cache(self) -> None:
        """Write the outputs still waiting for the cache (the end of a run, or a stop)."""
        if self._uncached:
            with self._connection.begin():
                self._connection.execute(self._cache_insert, self._uncached)
        self._uncached = []
        self._cached_at = time.monotonic()

    def commit(self, result: UnitResult) -> bool:
        """Store one result with its findings and counters in one transaction (SQLAlchemy Core:
        the ORM's unit of work costs more than the insert), with the outputs waiting for the cache
        when they are due (see :meth:`_cache_due`); False when it was stored already."""
        start = time.perf_counter()
        unit = result.unit
        replaced = self._faults.get(result.key)  # a data fault run again: its row is rewritten in place
        uncached = list(self._uncached)
        detections = result.detections
        if detections is not None and not detections.missing and not result.cached and result.input_key:
            uncached.append({"fingerprint": self.task.model.fingerprint, "digest": result.input_key,
                             "source": result.input_source, **detections.columns(), "seconds": result.seconds})
        due = self._cache_due(unit.subtask_id, last=replaced is None and self.done[
            unit.subtask_id] + 1 >= self.subtasks[unit.subtask_id].total)
        try:
            connection = self._connection
            with connection.begin():
                values = {"params": result.params, **result.box_columns(), "failure": result.failure,
                          "relations": result.relations, "seconds": result.seconds, "cached": result.cached,
                          "created_at": now()}
                if replaced is not None:
                    connection.execute(self._drop_findings, {"row": replaced})
                    connection.execute(self._replace_result, {"row": replaced, **values})
                    row_id = replaced
                else:
                    row_id = self._insert_result.execute(connection, {
                        "subtask_id": unit.subtask_id, "frame_id": unit.frame_id, "trial": unit.trial,
                        **values})
                self._insert_finding.execute_many(connection, self._findings(result, row_id))
                if replaced is None:  # a replaced fault was counted already
                    self._bump_subtask.execute(connection, {"subtask": unit.subtask_id, "n": 1,
                                                            "now": values["created_at"]})
                    self._bump_task.execute(connection, {"task": self.task.id, "n": 1})
                if due and uncached:
                    connection.execute(self._cache_insert, uncached)
        except IntegrityError:
            return False  # another run stored this unit first
        finally:
            self.stats.store += time.perf_counter() - start
        if due:
            self._started.add(unit.subtask_id)
            self._uncached, self._cached_at = [], time.monotonic()
        else:
            self._uncached = uncached
        if replaced is not None:
            del self._faults[result.key]
            self._faults_left[unit.subtask_id] -= 1
        else:
            self.done[unit.subtask_id] += 1
            self.task_done += 1
        self.stats.units += 1
        self.stats.cached += int(result.cached)
        self.stats.failures += int(result.failure is not None)
        self.stats.sut += result.seconds
        for stage, seconds in result.timings.items():
            self.stats.stages[stage] += seconds
        return True

    def consume(self, units: Iterable[WorkUnit]) -> None:
        """Run ``units``, storing their results in the units' order (see the module docstring)."""
        for result in in_unit_order(self.executor, units):
            self.commit(result)
            sub = self.subtasks[result.unit.subtask_id]
            if self.progress is not None:
                self.progress(ProgressEvent(self.task_done, self.task.total, sub.id,
                                            subtask_label(sub.name, sub.severity), self.done[sub.id], sub.total))
            if self.done[sub.id] >= sub.total and not self._waiting(sub.id):
                self.finish(sub)
            self.watch.check()

    def finish(self, sub: Subtask) -> None:
        """A complete subtask: its AP and relation figures, then done."""
        from lidarfuzz.campaign.results import evaluate_subtask
        from lidarfuzz.operators.registry import from_spec

        start = time.perf_counter()
        with self.store.session() as s:
            row = s.get(Subtask, sub.id)
            assert row is not None
            if row.status == Status.DONE:
                return
            rows = list(s.execute(select(FrameResult.frame_id, FrameResult.detections, FrameResult.ground_truth,
                                         FrameResult.failure, FrameResult.relations, FrameResult.seconds,
                                         FrameResult.cached, FrameResult.params).where(
                FrameResult.subtask_id == sub.id).order_by(FrameResult.frame_id, FrameResult.trial)))
            operator = from_spec(row.operator) if row.operator else None
            row.results = evaluate_subtask(rows, self.calibration, operator=operator,
                                           unlabelled=self.task.options.unlabelled_frames)
            deeptest = row.results.deeptest
            if deeptest is not None and deeptest.mse_orig_from == "data set" and not deeptest.kept:
                note = (f"not counted as an erroneous behaviour: DeepTest's ε filter drops this transformation "
                        f"(|MSE_t − MSE_orig| = |{deeptest.mse:.3g} − {deeptest.mse_orig:.3g}| > ε = "
                        f"{deeptest.configured_epsilon:g}); ")
                s.execute(update(Finding).where(
                    Finding.kind == "deeptest_tolerance",
                    Finding.frame_result_id.in_(select(FrameResult.id).where(FrameResult.subtask_id == sub.id)),
                ).values(message=literal(note) + Finding.message).execution_options(synchronize_session=False))
            row.status, row.finished_at = Status.DONE, now()
        self.stats.evaluate += time.perf_counter() - start

    def open_dataset(self) -> Any:
        """The task's data set in this process, opened once (at the start of :meth:`execute`, while its
        files are as the workers found them: a file deleted later is a data fault of its units, not a
        reason to stop the evaluation of the others)."""
        if self._dataset is None:
            from lidarfuzz.io.open import open_dataset
            from lidarfuzz.io.options import DatasetOptions

            self._dataset = open_dataset(self.task.dataset.path,
                                         options=DatasetOptions.from_stored(self.task.dataset.options))
        return self._dataset

    def calibration(self, frame_id: str) -> Any:
        if frame_id not in self._calibs:
            self.open_dataset()
            load_calib = getattr(self._dataset, "load_calib", None)
            self._calibs[frame_id] = load_calib(frame_id) if load_calib else self._dataset.load(frame_id).calib
        return self._calibs[frame_id]

    def close(self) -> None:
        try:
            self.executor.close()
        finally:
            try:
                self.flush_cache()
            finally:
                self._connection.close()
                self.watch.close()

    # -- the whole run ------------------------------------------------------------------
    def execute(self) -> None:
        """A block of frames at a time: the block's originals (the sources of its relations), then
        every subtask over the block. Workers keep a block of frames loaded, so each frame is
        loaded about once per worker, and the subtasks still advance in turn."""
        subs = sorted(self.subtasks.values(), key=lambda x: (x.name != ORIGINAL, x.id))
        original = subs[0]
        self.open_dataset()
        done = self._finished_keys()
        blocks = [self.frame_ids[start:start + BLOCK] for start in range(0, len(self.frame_ids), BLOCK)]
        originals_first = any(self._needs_mse_orig(spec) for sub in subs[1:] for spec in sub.plan.relation_specs)
        if originals_first:  # DeepTest's MSE_orig is over every original (see the module docstring)
            for block in blocks:
                self.consume(self._units([original], done, {}, block))
            if any(fault for _, _, fault in self._sources(original).values()):
                self.flush_cache()
                return  # MSE_orig would miss an original: the mutants wait for a resume that reads it
            self._compute_mse_orig(original, subs[1:])
        for block in blocks:
            if not originals_first:
                self.consume(self._units([original], done, {}, block))
            sources = self._sources(original)
            self.consume(self._units(subs[1:], done, sources, block))
        self.flush_cache()
        for sub in subs:
            if self.done[sub.id] >= sub.total and not self._waiting(sub.id):
                self.finish(sub)

    def summary(self) -> TaskSummary:
        from lidarfuzz.campaign.results import summarise

        start = time.perf_counter()
        summary = summarise(self.store, self.task.id)
        self.stats.evaluate += time.perf_counter() - start
        return summary


# -- the kind's hooks (lidarfuzz.campaign.lifecycle.KindImplementation) ----------------
def check_spec(spec: CampaignSpec) -> None:
    if spec.search:
        from lidarfuzz.campaign.kinds import TASK_KINDS

        searches = " and ".join(kind.name for kind in TASK_KINDS if kind.module == "lidarfuzz.campaign.coverage_search")
        raise ValueError(f"search: only {searches} campaigns take a search section")


def plan(spec: CampaignSpec, model: Model, frame_ids: list[str]) -> KindPlan:
    """One subtask per operator × severity (or per operator with an explicit config), in the
    campaign's order, each with the relations that apply to its operator."""
    from lidarfuzz.operators.registry import get

    subtasks = []
    for choice in spec.operators:
        cls = get(choice.name)
        units = len(frame_ids) * spec.trials
        stream = operator_stream(cls.name, choice.config)
        if choice.config is not None:
            op = cls(**choice.config)
            subtasks.append(SubtaskPlan(cls.name, op.spec(), units, 0, stream, relations_for(op, spec.relations),
                                        unchecked_relations(op, spec.relations)))
            continue
        for severity in choice.severities:
            op = cls.at_severity(severity)
            subtasks.append(SubtaskPlan(cls.name, op.spec(), units, severity, stream,
                                        relations_for(op, spec.relations), unchecked_relations(op, spec.relations)))
    return KindPlan(subtasks)


def start(store: Store, task: Task, options: RunOptions) -> _Run:
    in_memory = store.url.startswith("sqlite://") and store.url in ("sqlite://", "sqlite:///:memory:")
    stored = task.options
    context = WorkContext(task.dataset.path, task.model.spec, dict(task.model.options), task.model.fingerprint,
                          store_url=None if in_memory else store.url, isolate=stored.isolate,
                          timeout=stored.timeout, save_mutants=stored.save_mutants,
                          dataset_options=dict(task.dataset.options or {}))
    executor = options.executor or ProcessExecutor(options.workers)
    try:
        run = _Run(store, task, executor, options.progress, options.stop)
    except BaseException:
        executor.close()
        raise
    try:
        executor.open(context)
    except BaseException:
        run.close()
        raise
    return run


def describe(task: Task) -> str:
    return f"{len(task.subtasks) - 1} operator × severity subtasks"


__all__ = ["BLOCK", "check_spec", "counted_below", "describe", "plan", "start"]
