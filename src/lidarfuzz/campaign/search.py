"""Coverage-guided campaigns: the ``guided`` and ``fuzz`` kinds on the campaign engine.

A search task has two subtasks: the seed frames (``original``: the SUT's outputs and
coverage on the data as it is) and the search (``guided`` or ``fuzz``: every generated
test, one frame result each, ``trial`` = the test's number; a minimised test is stored
under ``trial`` + :data:`MINIMISED`). Each step of the search — its tests, their findings,
the counters and the search's whole state (coverage bit sets, stack or queue, known
signatures) — is committed in one transaction, so ``lidarfuzz resume`` continues an
interrupted search exactly where it stopped and gives the same tests as an uninterrupted
run. ``lidarfuzz cancel``, the heartbeat, reports and ``lidarfuzz replay`` work as for any
campaign: a test's operator is a ``sequence`` of its chain, with exact params.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from sqlalchemy import func, insert, select, update

from lidarfuzz.campaign.codec import encode_boxes, json_safe
from lidarfuzz.campaign.runner import (
    CancelledError,
    ProgressEvent,
    RunOutcome,
    RunStats,
    _now,
    _set_status,
    mark_running,
)
from lidarfuzz.campaign.tasks import ORIGINAL, get_task
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.search.algorithms import SearchConfig, TestRecord, make_search
from lidarfuzz.store.models import Finding, FrameResult, Status, Subtask, Task
from lidarfuzz.store.store import Store

KINDS = ("guided", "fuzz")
#: Trials of minimised tests: MINIMISED × (1 + variant) + the test's number.
MINIMISED = 1_000_000


class SearchSetupError(LidarfuzzError, ValueError):
    """A search that cannot start (no torch module, no profile for a criterion that needs one)."""


def coverage_profile(module: Any) -> Any:
    """The training profile of a module: the cache (``$LIDARFUZZ_CACHE/profiles``) or the
    profiles shipped beside built-in weights; None when there is none."""
    from lidarfuzz.coverage import ProfileStore, module_fingerprint
    from lidarfuzz.suts.learned.sut import WEIGHTS_DIR

    return ProfileStore(extra=[WEIGHTS_DIR]).get(module_fingerprint(module))


def torch_module(sut: Any) -> Any:
    module = getattr(sut, "module", None)
    if module is None or not hasattr(module, "named_modules"):
        raise SearchSetupError(
            f"coverage-guided search needs a SUT built on a torch.nn.Module exposed as `.module` "
            f"({type(sut).__name__} has none); e.g. --sut pillars")
    return module


def build_criteria(specs: tuple[str, ...], module: Any) -> list[Any]:
    from lidarfuzz.coverage import make_criteria

    needs = [s for s in specs if s.split(":")[0].lower() in ("kmnc", "nbc", "snac")]
    profile = coverage_profile(module) if needs else None
    if needs and profile is None:
        raise SearchSetupError(
            f"criteria {needs} need a training profile of this model's neurons and none is stored; "
            "build one with `lidarfuzz profile SUT DATA`, or drop them (--criteria nc:0.2,tknc:2)")
    return make_criteria(list(specs), profile)


class _SearchRun:
    def __init__(self, store: Store, task: Task, progress: Callable[[ProgressEvent], None] | None,
                 stop: Any) -> None:
        from lidarfuzz.coverage import ActivationRecorder
        from lidarfuzz.oracles.relations.registry import from_spec
        from lidarfuzz.search.evaluate import SearchEvaluator
        from lidarfuzz.store.inventory import open_registered
        from lidarfuzz.suts.registry import create

        self.store, self.task, self.progress, self.stop = store, task, progress, stop
        self.config = SearchConfig.model_validate(task.options["search"])
        subs = {sub.name: sub for sub in task.subtasks}
        self.original, self.sub = subs[ORIGINAL], subs[self.config.kind]
        self.sut = create(task.model.spec, **task.model.options)
        self.sut.load()
        module = torch_module(self.sut)
        self.criteria = build_criteria(self.config.criteria, module)
        relations = [from_spec(spec) for spec in self.sub.results.get("relation_specs", [])]
        self.evaluator = SearchEvaluator(open_registered(task.dataset), self.sut, relations,
                                         ActivationRecorder(module), keep_share=self.config.keep_share)
        self.search = make_search(self.config, task.options["frame_ids"], self.criteria, task.seed)
        state = self.sub.results.get("state")
        if state:
            self.search.load_state_dict(state)
        self.stats = RunStats()
        self.connection = store.engine.connect()
        self._last_check = 0.0

    def _replay(self, record: TestRecord, relation: dict[str, Any] | None) -> dict[str, Any]:
        task, e = self.task, record.evaluation
        return {"dataset": task.dataset.path, "frame_id": e.frame_id, "trial": record.index, "seed": task.seed,
                "op_index": 0, "operator": e.spec if e.chain else None, "params": e.params if e.chain else {},
                "sut": task.model.spec, "options": task.model.options, "fingerprint": task.model.fingerprint,
                "relation": relation, "operator_relation": "invariant" if e.valid and e.chain else None}

    def commit(self, records: list[TestRecord]) -> None:
        specs = {spec["name"]: spec for spec in self.sub.results.get("relation_specs", [])}
        state = json_safe(self.search.state_dict())
        with self.connection.begin():
            counts = {self.original.id: 0, self.sub.id: 0}
            for record in records:
                e = record.evaluation
                sub = self.original if record.role == "seed" else self.sub
                trial = 0 if record.role == "seed" else record.index
                if record.role == "minimised":
                    trial = MINIMISED * (1 + record.variant) + record.index
                boxes, labels = encode_boxes(e.output) if e.output is not None else (None, [])
                gt_boxes, gt_labels = encode_boxes(e.scene.boxes) if e.scene is not None else (None, [])
                row_id = self.connection.execute(insert(FrameResult).returning(FrameResult.id), {
                    "subtask_id": sub.id, "frame_id": e.frame_id, "trial": trial,
                    "params": json_safe(record.params()) if record.role != "seed" else json_safe(
                        {"role": "seed", "gains": record.gains, "coverage": record.coverage}),
                    "boxes": boxes, "labels": labels, "gt_boxes": gt_boxes, "gt_labels": gt_labels,
                    "failure": e.failure, "relations": json_safe(e.relations), "seconds": e.seconds,
                    "cached": False, "created_at": _now()}).scalar_one()
                counts[sub.id] += 0 if record.role == "minimised" else 1
                rows = []
                if e.failure is not None:
                    rows.append(dict(kind=e.failure["kind"], cls="", magnitude=None, message=e.failure["message"],
                                     detail={"detail": e.failure.get("detail", ""), "test": record.index},
                                     replay=self._replay(record, None)))
                for finding in record.findings:
                    rows.append(dict(**finding, replay=self._replay(record, specs.get(finding["kind"]))))
                for row in rows:
                    self.connection.execute(insert(Finding), {**row, "task_id": self.task.id,
                                                              "frame_result_id": row_id})
                self.stats.units += 1
                self.stats.sut += e.seconds
                self.stats.failures += int(e.failure is not None)
            results = dict(self.sub.results)
            results["state"] = state
            results["search"] = json_safe({"coverage": self.search.coverage(), "stats": self.search.stats})
            self.sub.results = results
            for sub_id, n in counts.items():
                self.connection.execute(update(Subtask).where(Subtask.id == sub_id).values(
                    done=Subtask.done + n, status=Status.RUNNING))
            self.connection.execute(update(Subtask).where(Subtask.id == self.sub.id).values(results=results))
            self.connection.execute(update(Task).where(Task.id == self.task.id).values(
                done=Task.done + sum(counts.values()), heartbeat_at=_now()))

    def check(self) -> None:
        if self.stop is not None and self.stop.is_set():
            raise CancelledError
        now = time.monotonic()
        if now - self._last_check < 0.5:
            return
        self._last_check = now
        status = self.connection.execute(select(Task.status).where(Task.id == self.task.id)).scalar_one()
        self.connection.rollback()
        if status == Status.CANCELLED:
            raise CancelledError

    def execute(self) -> None:
        total = self.task.total
        while not self.search.finished:
            self.check()
            records = self.search.step(self.evaluator)
            if not records and self.search.finished:
                break
            self.commit(records)
            done = self.connection.execute(select(Task.done).where(Task.id == self.task.id)).scalar_one()
            self.connection.rollback()
            if self.progress is not None:
                label = "seeds" if records and records[0].role == "seed" else self.config.kind
                self.progress(ProgressEvent(done, total, self.sub.id, label, done, total))

    def close(self) -> None:
        self.connection.close()
        self.sut.close()


def finish_subtasks(store: Store, task_id: int, search_results: dict[str, Any] | None) -> None:
    """Evaluate both subtasks (AP over the generated tests too) and mark them done."""
    from lidarfuzz.campaign.results import evaluate_subtask
    from lidarfuzz.store.inventory import open_registered

    task = get_task(store, task_id)
    dataset = open_registered(task.dataset)

    def calibration(frame_id: str) -> Any:
        load_calib = getattr(dataset, "load_calib", None)
        return load_calib(frame_id) if load_calib else dataset.load(frame_id).calib

    with store.session() as s:
        for sub in s.scalars(select(Subtask).where(Subtask.task_id == task_id)):
            rows = list(s.execute(select(FrameResult.frame_id, FrameResult.boxes, FrameResult.labels,
                                         FrameResult.gt_boxes, FrameResult.gt_labels, FrameResult.failure,
                                         FrameResult.relations, FrameResult.seconds, FrameResult.cached).where(
                FrameResult.subtask_id == sub.id, FrameResult.trial < MINIMISED)))
            results = dict(sub.results)
            results.update(evaluate_subtask(rows, calibration, unlabelled=task.options.get("unlabelled_frames", ())))
            sub.results = json_safe(results)
            sub.total = sub.done = int(s.scalar(select(func.count()).select_from(FrameResult).where(
                FrameResult.subtask_id == sub.id, FrameResult.trial < MINIMISED)) or 0)
            sub.status = Status.DONE
        row = s.get(Task, task_id)
        assert row is not None
        row.total = row.done = sum(sub.done for sub in row.subtasks)


def run_search_task(store: Store, task_id: int, *, progress: Callable[[ProgressEvent], None] | None = None,
                    stop: Any = None) -> RunOutcome:
    """Run (or resume) a ``guided`` or ``fuzz`` task to its budget."""
    from lidarfuzz.campaign.results import summarise

    mark_running(store, task_id, below_trial=MINIMISED)  # counts what is stored: a crashed step committed nothing
    task = get_task(store, task_id)
    started = time.perf_counter()
    status = Status.DONE
    run: _SearchRun | None = None
    try:
        run = _SearchRun(store, task, progress, stop)
        run.execute()
        finish_subtasks(store, task_id, None)
        summary = summarise(store, task_id)
        summary["search"] = json_safe({"kind": run.config.kind, "coverage": run.search.coverage(),
                                       "stats": run.search.stats, "signatures": run.search.known})
        run.stats.wall = time.perf_counter() - started
        summary["run"] = run.stats.to_dict()
        with store.session() as s:
            row = s.get(Task, task_id)
            assert row is not None
            row.summary, row.status, row.finished_at = json_safe(summary), Status.DONE, _now()
        stats = run.stats
    except CancelledError:
        status = Status.CANCELLED
        _set_status(store, task_id, Status.CANCELLED, "")
        stats = run.stats if run else RunStats()
    except KeyboardInterrupt:
        _set_status(store, task_id, Status.PENDING, "interrupted; lidarfuzz resume finishes it")
        raise
    except BaseException as exc:
        _set_status(store, task_id, Status.FAILED, f"{type(exc).__name__}: {exc}")
        raise
    finally:
        if run is not None:
            run.close()
    stats.wall = time.perf_counter() - started
    return RunOutcome(task_id, status, stats)
