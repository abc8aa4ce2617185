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

A search guided by neuron coverage needs a SUT exposing its ``torch.nn.Module``; one guided by
code coverage (``code_nodes``, ``code_edges`` and ``targets``: :mod:`lidarfuzz.search.code`) runs
any system, its coverage recorded around each ``detect`` call in the process running the task.

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
from lidarfuzz.operators.base import Relation
from lidarfuzz.search.algorithms import SearchConfig, TestRecord, make_search
from lidarfuzz.store.boxes import StoredBoxes
from lidarfuzz.store.contracts import SearchProgress, SearchSummary, TaskSummary
from lidarfuzz.store.errors import ConflictError
from lidarfuzz.store.models import Finding, FrameResult, Model, Status, Subtask, Task
from lidarfuzz.store.store import Store

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

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
        relations = [from_spec(spec) for spec in self.sub.plan.relation_specs]
        self.evaluator: SearchEvaluator
        if self.config.code:  # code coverage around each detect call: any Python system
            from lidarfuzz.search.code import CodeSearchEvaluator, make_code_criteria
            from lidarfuzz.structural.python_coverage import RecorderConfig

            self.criteria = list(make_code_criteria(self.config.criteria))
            self.evaluator = CodeSearchEvaluator(open_registered(task.dataset), self.sut, relations,
                                                 RecorderConfig(self.config.targets),
                                                 keep_share=self.config.keep_share)
        else:
            module = torch_module(self.sut)
            self.criteria = build_criteria(self.config.criteria, module, profile_dirs(self.sut))
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
                "relation": relation,
                "operator_relation": e.operator_relation.value if e.valid and e.chain else None}

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
                    done=Subtask.done + n, status=Status.RUNNING,
                    started_at=func.coalesce(Subtask.started_at, now())))  # set once: its first unit
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
        self.watch.close()
        self.sut.close()


class StoredChain:
    """What :func:`~lidarfuzz.campaign.results.evaluate_subtask` reads of an operator, for a
    search's stored tests, each row with its own chain in its params: the map the chain moved the
    scene by (None when it moved nothing, and for a seed frame), so that AP does not score the
    detections of a moved test where the seed frame had no labels.

        >>> from lidarfuzz.search.evaluate import ChainStep, Evaluation
        >>> from lidarfuzz.operators.registry import get
        >>> e = Evaluation("000000", [ChainStep(get("rotate_z").at_severity(4).spec(), {"angle": 90.0})])
        >>> StoredChain().transform({"operator": e.spec, "params": e.params}).round(6)[:2, :2].tolist()
        [[0.0, -1.0], [1.0, 0.0]]
        >>> StoredChain().transform({"role": "seed"}) is None
        True
    """

    relation = Relation.EQUIVARIANT  # evaluate_subtask asks for a row's transform only then

    def parse_params(self, stored: dict[str, Any]) -> dict[str, Any]:
        return stored

    def transform(self, stored: dict[str, Any]) -> NDArray[np.float64] | None:
        from lidarfuzz.operators.registry import from_spec

        if not stored.get("operator") or not stored.get("params"):
            return None
        chain = from_spec(stored["operator"])
        return chain.transform(chain.parse_params(stored["params"]))


def finish_subtasks(store: Store, task_id: int) -> None:
    """Evaluate both subtasks (AP over the generated tests too, each moved test's detections only
    where its seed frame had labels: :class:`StoredChain`) and mark them done."""
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
                                         FrameResult.cached, FrameResult.params).where(
                FrameResult.subtask_id == sub.id, FrameResult.trial < MINIMISED)))
            chains = StoredChain() if sub.name != ORIGINAL else None
            figures = evaluate_subtask(rows, calibration, operator=chains, unlabelled=task.options.unlabelled_frames)
            sub.results = figures.model_copy(update={"search": sub.results.search})
            sub.total = sub.done = int(s.scalar(select(func.count()).select_from(FrameResult).where(
                FrameResult.subtask_id == sub.id, FrameResult.trial < MINIMISED)) or 0)
            if sub.status != Status.DONE or sub.finished_at is None:
                sub.finished_at = now()
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


def moving_operators(config: SearchConfig) -> list[str]:
    """The operators of a search's pool that move the scene (equivariant ones)."""
    from lidarfuzz.operators.registry import get

    return [name for name in config.operators if get(name).relation == Relation.EQUIVARIANT]


def search_relations(config: SearchConfig, choice: Any) -> list[dict[str, Any]]:
    """The relation specs a search checks. Tests whose chain moves nothing preserve the seed's
    labels: the relations for invariant operators ("auto": Zhou & Sun's MR1, ``preservation``).
    When the pool holds a scene-moving operator, its tests carry the labels along: also the
    relations for equivariant operators ("auto": ``equivariance``, default config, as campaigns
    check rotate_z). The evaluator checks each test only against the relations for its kind."""
    from lidarfuzz.oracles.relations.registry import from_spec as relation

    specs = [relation("preservation").spec()] if choice == "auto" else relations_for_kind(Relation.INVARIANT, choice)
    if moving_operators(config):
        moved = ([relation("equivariance").spec()] if choice == "auto"
                 else relations_for_kind(Relation.EQUIVARIANT, choice))
        specs += [spec for spec in moved if spec not in specs]
    return specs


def check_spec(spec: CampaignSpec) -> None:
    """Fail early on a bad search section, and on listed relations none of which could judge the
    tests a scene-moving operator of the pool makes."""
    config = search_config(spec)
    from lidarfuzz.operators.registry import get

    camera = [name for name in config.operators if get(name).modality != "lidar"]
    if camera:
        raise ValueError(f"search.operators: {camera[0]} is a {get(camera[0]).modality} operator; a {spec.kind} "
                         "campaign searches lidar data (lidarfuzz operators --modality lidar)")
    moving = moving_operators(config)
    if moving and spec.relations != "auto" and not relations_for_kind(Relation.EQUIVARIANT, spec.relations):
        raise ValueError(f"relations: operator(s) {moving} move the scene and none of the listed relations judges a "
                         "moved test; add equivariance (or use auto)")


def _check_searchable(model: Model, config: SearchConfig) -> None:
    """A search guided by neuron coverage hooks the SUT's ``torch.nn.Module``: refuse a SUT
    without one now, not when the task runs (the weights are not loaded to find out). A search
    guided by code coverage runs any system: its targets must name code that exists."""
    from lidarfuzz.suts.registry import create

    if config.code:
        from lidarfuzz.structural.targets import resolve

        try:
            resolve(config.targets)
        except LidarfuzzError as exc:
            raise ConflictError(f"targets: {exc}") from None
        return
    system = create(model.spec, **model.options)
    if not hasattr(type(system), "module") and "module" not in vars(system):
        raise ConflictError(f"a coverage-guided search needs a SUT built on a torch.nn.Module exposed as `.module`; "
                            f"model {model.name!r} ({type(system).__name__}) has none (e.g. --sut pillars)")


def plan(spec: CampaignSpec, model: Model, frame_ids: list[str]) -> KindPlan:
    """One subtask holds every generated test (the budget's worth). Valid tests keep the seed's
    labels (moved with the scene by a scene-moving step): :func:`search_relations` says which
    relations are checked."""
    search = search_config(spec)
    _check_searchable(model, search)
    relation_specs = search_relations(search, spec.relations)
    options = search.model_dump(mode="json")
    return KindPlan([SubtaskPlan(search.kind, {"name": search.kind, "search": options}, search.budget,
                                 relations=relation_specs)], options)


def start(store: Store, task: Task, options: RunOptions) -> _SearchRun:
    return _SearchRun(store, task, options.progress, options.stop)


def describe(task: Task) -> str:
    config = SearchConfig.model_validate(task.options.kind_options)
    return f"{config.kind} search of {config.budget} tests from {len(task.options.frame_ids)} seed frames"


__all__ = ["MINIMISED", "SearchSetupError", "StoredChain", "build_criteria", "check_spec", "counted_below",
           "coverage_profile", "describe", "moving_operators", "plan", "profile_dirs", "search_config",
           "search_relations", "start", "torch_module"]
