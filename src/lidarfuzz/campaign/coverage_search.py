"""Coverage-guided searches: the ``guided`` and ``fuzz`` task kinds on the campaign engine
(the search algorithms themselves are :mod:`lidarfuzz.search`).

A search task has two subtasks: the seed frames (``original``: the SUT's outputs and
coverage on the data as it is) and the search (``guided`` or ``fuzz``: every generated
test, one frame result each, ``trial`` = the test's number; a minimised test is stored
under ``trial`` + :data:`MINIMISED`). Each step of the search — its tests, their findings,
the counters and the search's whole state (coverage bit sets, stack or queue, known
signatures) — is committed in one transaction, so ``lidarfuzz resume`` continues an
interrupted search exactly where it stopped and gives the same tests as an uninterrupted
run. ``lidarfuzz cancel``, the heartbeat, reports and ``lidarfuzz replay`` work as for any
campaign: a test's operator is a ``sequence`` of its chain, with exact params.

The engine knows no particular system: a criterion that needs a training profile finds it in
the profile cache or in the folders the SUT names through ``profile_dirs()`` (see
:func:`profile_dirs`). The hooks of :class:`~lidarfuzz.campaign.lifecycle.KindImplementation`
are at the end; the lifecycle around them is :mod:`lidarfuzz.campaign.lifecycle`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy import func, insert, select, update

from lidarfuzz.campaign.lifecycle import ProgressEvent, RunOptions, RunStats, Watch, get_task, now
from lidarfuzz.campaign.plan import ORIGINAL, KindPlan, SubtaskPlan, relations_for_kind
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.search.algorithms import SearchConfig, TestRecord, make_search
from lidarfuzz.store.boxes import StoredBoxes
from lidarfuzz.store.contracts import SearchProgress, SearchSummary, TaskSummary
from lidarfuzz.store.errors import ConflictError
from lidarfuzz.store.models import Finding, FrameResult, Model, Status, Subtask, Task
from lidarfuzz.store.store import Store

if TYPE_CHECKING:
    from lidarfuzz.campaign.spec import CampaignSpec

#: Trials of minimised tests: MINIMISED × (1 + variant) + the test's number.
MINIMISED = 1_000_000


class SearchSetupError(LidarfuzzError, ValueError):
    """A search that cannot start (no torch module, no profile for a criterion that needs one)."""


def profile_dirs(sut: Any) -> list[Path]:
    """Read-only folders where ``sut`` keeps training profiles of its module (e.g. shipped beside
    its weights): what its ``profile_dirs()`` returns (:meth:`SystemUnderTest.profile_dirs`); none
    for an object without that method (a search may run any module-backed object)."""
    offered = getattr(sut, "profile_dirs", None)
    return [Path(folder) for folder in offered()] if callable(offered) else []


def coverage_profile(module: Any, folders: list[Path] | tuple[Path, ...] = ()) -> Any:
    """The training profile of a module: the cache (``$LIDARFUZZ_CACHE/profiles``), then
    ``folders`` (a SUT's :func:`profile_dirs`); None when there is none."""
    from lidarfuzz.coverage import ProfileStore, module_fingerprint

    return ProfileStore(extra=folders).get(module_fingerprint(module))


def torch_module(sut: Any) -> Any:
    module = getattr(sut, "module", None)
    if module is None or not hasattr(module, "named_modules"):
        raise SearchSetupError(
            f"coverage-guided search needs a SUT built on a torch.nn.Module exposed as `.module` "
            f"({type(sut).__name__} has none); e.g. --sut pillars")
    return module


def build_criteria(specs: tuple[str, ...], module: Any, folders: list[Path] | tuple[Path, ...] = ()) -> list[Any]:
    """Coverage criteria from their specs; those that need a training profile (KMNC, NBC, SNAC)
    get the module's, from the cache or ``folders``."""
    from lidarfuzz.coverage import make_criteria

    needs = [s for s in specs if s.split(":")[0].lower() in ("kmnc", "nbc", "snac")]
    profile = coverage_profile(module, folders) if needs else None
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

        self.store, self.task, self.progress = store, task, progress
        self.watch = Watch(store, task.id, stop)
        self.config = SearchConfig.model_validate(task.options.kind_options)
        subs = {sub.name: sub for sub in task.subtasks}
        self.original, self.sub = subs[ORIGINAL], subs[self.config.kind]
        self.sut = create(task.model.spec, **task.model.options)
        self.sut.load()
        module = torch_module(self.sut)
        self.criteria = build_criteria(self.config.criteria, module, profile_dirs(self.sut))
        relations = [from_spec(spec) for spec in self.sub.plan.relation_specs]
        self.evaluator = SearchEvaluator(open_registered(task.dataset), self.sut, relations,
                                         ActivationRecorder(module), keep_share=self.config.keep_share)
        self.search = make_search(self.config, task.options.frame_ids, self.criteria, task.seed)
        state = self.sub.state
        if state:
            self.search.load_state_dict(state)
        self.stats = RunStats()
        self.connection = store.engine.connect()

    def _replay(self, record: TestRecord, relation: dict[str, Any] | None) -> dict[str, Any]:
        task, e = self.task, record.evaluation
        return {"dataset": task.dataset.path, "frame_id": e.frame_id, "trial": record.index, "seed": task.seed,
                "op_index": 0, "operator": e.spec if e.chain else None, "params": e.params if e.chain else {},
                "sut": task.model.spec, "options": task.model.options, "fingerprint": task.model.fingerprint,
                "relation": relation, "operator_relation": "invariant" if e.valid and e.chain else None}

    def commit(self, records: list[TestRecord]) -> None:
        specs = {spec["name"]: spec for spec in self.sub.plan.relation_specs}
        state = self.search.state_dict()
        with self.connection.begin():
            counts = {self.original.id: 0, self.sub.id: 0}
            for record in records:
                e = record.evaluation
                sub = self.original if record.role == "seed" else self.sub
                trial = 0 if record.role == "seed" else record.index
                if record.role == "minimised":
                    trial = MINIMISED * (1 + record.variant) + record.index
                detections = StoredBoxes.of(e.output)
                ground_truth = StoredBoxes.of(e.scene.boxes if e.scene is not None else None)
                row_id = self.connection.execute(insert(FrameResult).returning(FrameResult.id), {
                    "subtask_id": sub.id, "frame_id": e.frame_id, "trial": trial,
                    "params": record.params() if record.role != "seed" else {
                        "role": "seed", "gains": record.gains, "coverage": record.coverage},
                    **detections.columns(), **ground_truth.columns("gt_boxes", "gt_labels"),
                    "failure": e.failure, "relations": e.relations, "seconds": e.seconds,
                    "cached": False, "created_at": now()}).scalar_one()
                counts[sub.id] += 0 if record.role == "minimised" else 1
                rows = []
                if e.failure is not None:
                    rows.append(dict(kind=e.failure.kind, cls="", magnitude=None, message=e.failure.message,
                                     detail={"detail": e.failure.detail, "test": record.index},
                                     replay=self._replay(record, None)))
                for finding in record.findings:
                    rows.append(dict(**finding, replay=self._replay(record, specs.get(finding["kind"]))))
                for row in rows:
                    self.connection.execute(insert(Finding), {**row, "task_id": self.task.id,
                                                              "frame_result_id": row_id})
                self.stats.units += 1
                self.stats.sut += e.seconds
                self.stats.failures += int(e.failure is not None)
            results = self.sub.results.model_copy(update={"search": SearchProgress(
                coverage=self.search.coverage(), stats=self.search.stats)})
            self.sub.results, self.sub.state = results, state
            for sub_id, n in counts.items():
                self.connection.execute(update(Subtask).where(Subtask.id == sub_id).values(
                    done=Subtask.done + n, status=Status.RUNNING))
            self.connection.execute(update(Subtask).where(Subtask.id == self.sub.id).values(
                results=results, state=state))
            self.connection.execute(update(Task).where(Task.id == self.task.id).values(
                done=Task.done + sum(counts.values()), heartbeat_at=now()))

    def execute(self) -> None:
        total = self.task.total
        while not self.search.finished:
            self.watch.check()
            records = self.search.step(self.evaluator)
            if not records and self.search.finished:
                break
            self.commit(records)
            done = self.connection.execute(select(Task.done).where(Task.id == self.task.id)).scalar_one()
            self.connection.rollback()
            if self.progress is not None:
                label = "seeds" if records and records[0].role == "seed" else self.config.kind
                self.progress(ProgressEvent(done, total, self.sub.id, label, done, total))

    def summary(self) -> TaskSummary:
        from lidarfuzz.campaign.results import summarise

        finish_subtasks(self.store, self.task.id)
        summary = summarise(self.store, self.task.id)
        summary.search = SearchSummary(kind=self.config.kind, coverage=self.search.coverage(),
                                       stats=self.search.stats, signatures=self.search.known)
        return summary

    def close(self) -> None:
        self.connection.close()
        self.sut.close()


def finish_subtasks(store: Store, task_id: int) -> None:
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
            rows = list(s.execute(select(FrameResult.frame_id, FrameResult.detections, FrameResult.ground_truth,
                                         FrameResult.failure, FrameResult.relations, FrameResult.seconds,
                                         FrameResult.cached).where(
                FrameResult.subtask_id == sub.id, FrameResult.trial < MINIMISED)))
            figures = evaluate_subtask(rows, calibration, unlabelled=task.options.unlabelled_frames)
            sub.results = figures.model_copy(update={"search": sub.results.search})
            sub.total = sub.done = int(s.scalar(select(func.count()).select_from(FrameResult).where(
                FrameResult.subtask_id == sub.id, FrameResult.trial < MINIMISED)) or 0)
            sub.status = Status.DONE
        row = s.get(Task, task_id)
        assert row is not None
        row.total = row.done = sum(sub.done for sub in row.subtasks)


# -- the kinds' hooks (lidarfuzz.campaign.lifecycle.KindImplementation) ----------------
#: Progress counts the generated tests, not their minimised copies.
counted_below: int | None = MINIMISED


def search_config(spec: CampaignSpec) -> SearchConfig:
    """The search settings of a guided / fuzz campaign: its ``search`` section, its kind, and its
    operators as the pool."""
    values: dict[str, Any] = {**spec.search, "kind": spec.kind}
    if spec.operators:
        values["operators"] = tuple(choice.name for choice in spec.operators)
    return SearchConfig.model_validate(values)


def check_spec(spec: CampaignSpec) -> None:
    search_config(spec)  # fail early on a bad search section


def _check_searchable(model: Model) -> None:
    """A coverage-guided search hooks the SUT's ``torch.nn.Module``: refuse a SUT without one
    now, not when the task runs (the weights are not loaded to find out)."""
    from lidarfuzz.suts.registry import create

    system = create(model.spec, **model.options)
    if not hasattr(type(system), "module") and "module" not in vars(system):
        raise ConflictError(f"a coverage-guided search needs a SUT built on a torch.nn.Module exposed as `.module`; "
                            f"model {model.name!r} ({type(system).__name__}) has none (e.g. --sut pillars)")


def plan(spec: CampaignSpec, model: Model, frame_ids: list[str]) -> KindPlan:
    """One subtask holds every generated test (the budget's worth). Valid tests preserve labels,
    so the relations that apply to invariant operators are checked; "auto" means Zhou & Sun's
    MR1 (an object found before is found after)."""
    from lidarfuzz.operators.base import Relation
    from lidarfuzz.oracles.relations.registry import from_spec as relation

    search = search_config(spec)
    _check_searchable(model)
    choice = spec.relations
    relation_specs = ([relation("preservation").spec()] if choice == "auto"
                      else relations_for_kind(Relation.INVARIANT, choice))
    options = search.model_dump(mode="json")
    return KindPlan([SubtaskPlan(search.kind, {"name": search.kind, "search": options}, search.budget,
                                 relations=relation_specs)], options)


def start(store: Store, task: Task, options: RunOptions) -> _SearchRun:
    return _SearchRun(store, task, options.progress, options.stop)


def describe(task: Task) -> str:
    config = SearchConfig.model_validate(task.options.kind_options)
    return f"{config.kind} search of {config.budget} tests from {len(task.options.frame_ids)} seed frames"


__all__ = ["MINIMISED", "SearchSetupError", "build_criteria", "check_spec", "counted_below", "coverage_profile",
           "describe", "plan", "profile_dirs", "search_config", "start", "torch_module"]
