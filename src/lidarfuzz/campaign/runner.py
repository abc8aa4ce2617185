"""Running a task: every pending unit through an executor, every result committed as it arrives.

Order: the originals first (their outputs are the source side of every relation), then each
operator × severity in the task's order. A result is one transaction: its frame result, its
findings, the cache entry and the counters, so a kill at any instant leaves whole results and
counters that agree with them (and :func:`recount` re-derives the counters anyway on every
start). Units are keyed by (subtask, frame, trial) under a unique constraint: a resumed task
runs exactly the units that have no result, and nothing is counted twice.

Cancelling is cooperative: ``lidarfuzz cancel`` (or the web app) sets the task's status in
the store; the runner looks at it twice a second and stops, keeping what is done.
"""

from __future__ import annotations

import importlib
import os
import socket
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import bindparam, func, insert, select, update
from sqlalchemy.exc import IntegrityError

from lidarfuzz.campaign.codec import json_safe
from lidarfuzz.campaign.executor import Executor, ProcessExecutor
from lidarfuzz.campaign.tasks import ORIGINAL, get_task, subtask_label
from lidarfuzz.campaign.work import UnitResult, WorkContext, WorkUnit
from lidarfuzz.store.models import Finding, FrameResult, Status, Subtask, SutOutput, Task
from lidarfuzz.store.store import Store, StoreError

CHECK_EVERY = 0.5  # seconds between looks at the task's status (cancel) and heartbeats
BLOCK = 16  # frames per block (see _Run._units); a worker's scene cache holds one block


@dataclass(frozen=True)
class ProgressEvent:
    task_done: int
    task_total: int
    subtask_id: int
    label: str
    subtask_done: int
    subtask_total: int


@dataclass
class RunStats:
    """Where the time of one run went (seconds, summed over units; wall is elapsed)."""

    units: int = 0
    cached: int = 0
    failures: int = 0
    wall: float = 0.0
    sut: float = 0.0
    stages: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    store: float = 0.0  # committing results
    evaluate: float = 0.0  # AP and summaries at the end of subtasks

    def to_dict(self) -> dict[str, Any]:
        return {"units": self.units, "cached": self.cached, "failures": self.failures, "wall": self.wall,
                "sut": self.sut, "stages": dict(self.stages), "store": self.store, "evaluate": self.evaluate}


@dataclass(frozen=True)
class RunOutcome:
    task_id: int
    status: Status
    stats: RunStats


class CancelledError(Exception):
    """The task was cancelled while running."""


def _now() -> datetime:
    return datetime.now(UTC)


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def mark_running(store: Store, task_id: int, *, below_trial: int | None = None) -> None:
    """Claim a task for this process (status, worker, heartbeat, start time), then recount it."""
    with store.session() as s:
        row = s.get(Task, task_id)
        assert row is not None
        row.status, row.error, row.worker, row.heartbeat_at = Status.RUNNING, "", worker_name(), _now()
        row.started_at = row.started_at or _now()
        row.finished_at = None
    recount(store, task_id, below_trial=below_trial)


def recount(store: Store, task_id: int, *, below_trial: int | None = None) -> None:
    """Counters and subtask states from the results actually stored (only trials below
    ``below_trial`` count, when given: a search's minimised copies are extra rows)."""
    with store.session() as s:
        task = s.get(Task, task_id)
        assert task is not None
        query = select(FrameResult.subtask_id, func.count()).join(Subtask).where(Subtask.task_id == task_id)
        if below_trial is not None:
            query = query.where(FrameResult.trial < below_trial)
        counts = dict(s.execute(query.group_by(FrameResult.subtask_id)).all())
        for sub in task.subtasks:
            sub.done = int(counts.get(sub.id, 0))
            if sub.done >= sub.total and sub.status != Status.DONE:
                sub.status = Status.RUNNING  # complete but not evaluated: finished below
            elif sub.done < sub.total:
                sub.status = Status.RUNNING if sub.done else Status.PENDING
        task.done = sum(sub.done for sub in task.subtasks)


class _Run:
    def __init__(self, store: Store, task: Task, executor: Executor,
                 progress: Callable[[ProgressEvent], None] | None, stop: threading.Event | None) -> None:
        self.store, self.task, self.executor = store, task, executor
        self.progress, self.stop = progress, stop
        self.stats = RunStats()
        self.subtasks = {sub.id: sub for sub in task.subtasks}
        self.done = {sub.id: sub.done for sub in task.subtasks}
        self.task_done = task.done
        self._last_check = time.monotonic()
        options = task.options
        self.frame_ids: list[str] = list(options.get("frame_ids", []))
        self.trials = int(options.get("trials", 1))
        self._calibs: dict[str, Any] = {}
        self._connection = store.engine.connect()  # one for every commit: no pool check-out per result
        # statements built once (building one costs more than running it)
        self._insert_result = insert(FrameResult).returning(FrameResult.id)
        self._insert_finding = insert(Finding)
        self._bump_subtask = update(Subtask).where(Subtask.id == bindparam("subtask")).values(
            done=Subtask.done + 1, status=Status.RUNNING)
        self._bump_task = update(Task).where(Task.id == bindparam("task")).values(
            done=Task.done + 1, heartbeat_at=bindparam("now"))
        dialect = store.engine.dialect.name
        if dialect not in ("sqlite", "postgresql"):
            raise StoreError(f"campaigns run on SQLite or PostgreSQL, not {dialect}")
        dialect_insert = importlib.import_module(f"sqlalchemy.dialects.{dialect}").insert
        self._cache_insert: Any = dialect_insert(SutOutput).on_conflict_do_nothing()  # a concurrent twin: fine
        self._dataset: Any = None

    # -- units ------------------------------------------------------------------------
    def _finished_keys(self) -> set[tuple[int, str, int]]:
        with self.store.session() as s:
            rows = s.execute(select(FrameResult.subtask_id, FrameResult.frame_id, FrameResult.trial).join(
                Subtask).where(Subtask.task_id == self.task.id))
            return {(a, b, c) for a, b, c in rows}

    def _sources(self, original: Subtask) -> dict[str, tuple[bytes | None, tuple[str, ...], bool]]:
        with self.store.session() as s:
            rows = s.execute(select(FrameResult.frame_id, FrameResult.boxes, FrameResult.labels,
                                    FrameResult.failure).where(FrameResult.subtask_id == original.id))
            return {f: (b, tuple(labels), failure is not None) for f, b, labels, failure in rows}

    def _units(self, subtasks: Iterable[Subtask], done: set[tuple[int, str, int]],
               sources: dict[str, tuple[bytes | None, tuple[str, ...], bool]],
               block: list[str]) -> Iterator[WorkUnit]:
        """Pending units of ``subtasks`` on a block of frames, subtask by subtask."""
        for sub in subtasks:
            is_original = sub.name == ORIGINAL
            trials = 1 if is_original else self.trials
            relations = tuple(sub.results.get("relation_specs", [])) if not is_original else ()
            label = subtask_label(sub.name, sub.severity)
            for frame_id in block:
                for trial in range(trials):
                    if (sub.id, frame_id, trial) in done:
                        continue
                    if is_original:
                        yield WorkUnit(sub.id, frame_id, trial, None, sub.op_index, self.task.seed, label)
                        continue
                    blob, labels, failed = sources.get(frame_id, (None, (), True))
                    yield WorkUnit(sub.id, frame_id, trial, sub.operator, sub.op_index, self.task.seed, label,
                                   relations, blob, labels, failed)

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
        if result.failure is not None:
            findings.append(dict(task_id=self.task.id, frame_result_id=frame_result_id, cls="", magnitude=None,
                                 kind=result.failure["kind"], message=result.failure["message"],
                                 detail={"detail": result.failure.get("detail", "")},
                                 replay=self._replay(result)))
        specs = {spec["name"]: spec for spec in result.unit.relations}
        for outcome in result.relations:
            if outcome["holds"] or not outcome["violations"]:
                continue
            by_class: dict[str, list[dict[str, Any]]] = defaultdict(list)
            for violation in outcome["violations"]:
                by_class[violation["cls"]].append(violation)
            for cls, violations in sorted(by_class.items()):
                first = violations[0]["message"]
                more = f" (and {len(violations) - 1} more)" if len(violations) > 1 else ""
                findings.append(dict(task_id=self.task.id, frame_result_id=frame_result_id,
                                     kind=outcome["relation"], cls=cls, magnitude=float(len(violations)),
                                     message=first + more, detail={"violations": violations},
                                     replay=self._replay(result, specs.get(outcome["relation"]))))
        return findings

    def commit(self, result: UnitResult) -> bool:
        """Store one result with its findings and counters in one transaction (SQLAlchemy Core:
        the ORM's unit of work costs more than the insert); False when it was stored already."""
        start = time.perf_counter()
        unit = result.unit
        fingerprint = self.task.model.fingerprint
        try:
            connection = self._connection
            with connection.begin():
                row_id = connection.execute(self._insert_result, {
                    "subtask_id": unit.subtask_id, "frame_id": unit.frame_id, "trial": unit.trial,
                    "params": result.params, "boxes": result.boxes, "labels": result.labels,
                    "gt_boxes": result.gt_boxes, "gt_labels": result.gt_labels, "failure": result.failure,
                    "relations": result.relations, "seconds": result.seconds, "cached": result.cached,
                    "created_at": _now()}).scalar_one()
                findings = self._findings(result, row_id)
                if findings:
                    connection.execute(self._insert_finding, findings)
                if result.boxes is not None and not result.cached and result.input_key:
                    connection.execute(self._cache_insert, {
                        "fingerprint": fingerprint, "digest": result.input_key, "boxes": result.boxes,
                        "labels": result.labels, "seconds": result.seconds})
                connection.execute(self._bump_subtask, {"subtask": unit.subtask_id})
                connection.execute(self._bump_task, {"task": self.task.id, "now": _now()})
        except IntegrityError:
            return False  # another run stored this unit first
        finally:
            self.stats.store += time.perf_counter() - start
        self.done[unit.subtask_id] += 1
        self.task_done += 1
        self.stats.units += 1
        self.stats.cached += int(result.cached)
        self.stats.failures += int(result.failure is not None)
        self.stats.sut += result.seconds
        for stage, seconds in result.timings.items():
            self.stats.stages[stage] += seconds
        return True

    def _check(self) -> None:
        if self.stop is not None and self.stop.is_set():
            raise CancelledError
        now = time.monotonic()
        if now - self._last_check < CHECK_EVERY:
            return
        self._last_check = now
        with self.store.session() as s:
            status = s.scalar(select(Task.status).where(Task.id == self.task.id))
            if status == Status.CANCELLED:
                raise CancelledError
            s.execute(update(Task).where(Task.id == self.task.id).values(heartbeat_at=_now()))

    def consume(self, results: Iterator[UnitResult]) -> None:
        for result in results:
            self.commit(result)
            sub = self.subtasks[result.unit.subtask_id]
            if self.progress is not None:
                self.progress(ProgressEvent(self.task_done, self.task.total, sub.id,
                                            subtask_label(sub.name, sub.severity), self.done[sub.id], sub.total))
            if self.done[sub.id] >= sub.total:
                self.finish(sub)
            self._check()

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
            rows = list(s.execute(select(FrameResult.frame_id, FrameResult.boxes, FrameResult.labels,
                                         FrameResult.gt_boxes, FrameResult.gt_labels, FrameResult.failure,
                                         FrameResult.relations, FrameResult.seconds, FrameResult.cached,
                                         FrameResult.params).where(FrameResult.subtask_id == sub.id)))
            results = dict(row.results)
            operator = from_spec(row.operator) if row.operator else None
            results.update(evaluate_subtask(rows, self.calibration, operator=operator,
                                            unlabelled=self.task.options.get("unlabelled_frames", ())))
            row.results = json_safe(results)
            row.status = Status.DONE
        self.stats.evaluate += time.perf_counter() - start

    def calibration(self, frame_id: str) -> Any:
        if frame_id not in self._calibs:
            if self._dataset is None:
                from lidarfuzz.io.open import open_dataset
                from lidarfuzz.io.options import DatasetOptions

                self._dataset = open_dataset(self.task.dataset.path,
                                             options=DatasetOptions.from_stored(self.task.dataset.options))
            load_calib = getattr(self._dataset, "load_calib", None)
            self._calibs[frame_id] = load_calib(frame_id) if load_calib else self._dataset.load(frame_id).calib
        return self._calibs[frame_id]

    def close(self) -> None:
        self._connection.close()

    # -- the whole run ------------------------------------------------------------------
    def execute(self) -> None:
        """A block of frames at a time: the block's originals (the sources of its relations), then
        every subtask over the block. Workers keep a block of frames loaded, so each frame is
        loaded about once per worker, and the subtasks still advance in turn."""
        subs = sorted(self.subtasks.values(), key=lambda x: (x.name != ORIGINAL, x.id))
        original = subs[0]
        done = self._finished_keys()
        for start in range(0, len(self.frame_ids), BLOCK):
            block = self.frame_ids[start:start + BLOCK]
            self.consume(self.executor.run(self._units([original], done, {}, block)))
            sources = self._sources(original)
            self.consume(self.executor.run(self._units(subs[1:], done, sources, block)))
        for sub in subs:
            if self.done[sub.id] >= sub.total:
                self.finish(sub)


def run_task(store: Store, task_id: int, *, executor: Executor | None = None, workers: int | None = None,
             progress: Callable[[ProgressEvent], None] | None = None,
             stop: threading.Event | None = None) -> RunOutcome:
    """Run (or resume) task ``task_id`` to its end, committing every result as it is produced.

    Args:
        store: The campaign store.
        executor: Where units run (default: a :class:`ProcessExecutor` of ``workers`` processes).
        progress: Called after every committed result.
        stop: Set it to stop the run cleanly (as ``lidarfuzz cancel`` does from outside).
    """
    from lidarfuzz.campaign.results import summarise

    task = get_task(store, task_id)
    if task.status == Status.DONE:
        return RunOutcome(task_id, Status.DONE, RunStats())
    if task.options.get("kind") in ("guided", "fuzz"):
        from lidarfuzz.campaign.search import run_search_task

        return run_search_task(store, task_id, progress=progress, stop=stop)
    mark_running(store, task_id)
    task = get_task(store, task_id)
    in_memory = store.url.startswith("sqlite://") and store.url in ("sqlite://", "sqlite:///:memory:")
    options = task.options
    context = WorkContext(task.dataset.path, task.model.spec, dict(task.model.options), task.model.fingerprint,
                          store_url=None if in_memory else store.url, isolate=bool(options.get("isolate")),
                          timeout=float(options.get("timeout", 60.0)), save_mutants=options.get("save_mutants"),
                          dataset_options=dict(task.dataset.options or {}))
    executor = executor or ProcessExecutor(workers)
    run = _Run(store, task, executor, progress, stop)
    started = time.perf_counter()
    status = Status.DONE
    try:
        executor.open(context)
        run.execute()
        start = time.perf_counter()
        summary = summarise(store, task_id)
        run.stats.evaluate += time.perf_counter() - start
        run.stats.wall = time.perf_counter() - started
        summary["run"] = run.stats.to_dict()
        with store.session() as s:
            row = s.get(Task, task_id)
            assert row is not None
            row.summary, row.status, row.finished_at = json_safe(summary), Status.DONE, _now()
    except CancelledError:
        status = Status.CANCELLED
        _set_status(store, task_id, Status.CANCELLED, "")
    except KeyboardInterrupt:
        status = Status.PENDING
        _set_status(store, task_id, Status.PENDING, "interrupted; lidarfuzz resume finishes it")
        raise
    except BaseException as exc:
        status = Status.FAILED
        _set_status(store, task_id, Status.FAILED, f"{type(exc).__name__}: {exc}")
        raise
    finally:
        executor.close()
        run.close()
        run.stats.wall = time.perf_counter() - started
    return RunOutcome(task_id, status, run.stats)


def _set_status(store: Store, task_id: int, status: Status, error: str) -> None:
    with store.session() as s:
        row = s.get(Task, task_id)
        if row is None:
            raise StoreError(f"task {task_id} vanished while running")
        row.status, row.error = status, error
        for sub in row.subtasks:
            if sub.status == Status.RUNNING and sub.done < sub.total:
                sub.status = Status.PENDING if status != Status.FAILED else sub.status


__all__ = ["CancelledError", "ProgressEvent", "RunOutcome", "RunStats", "mark_running", "recount", "run_task"]
