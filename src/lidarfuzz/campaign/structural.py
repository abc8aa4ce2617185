"""Structural campaigns: Neves et al.'s environment as the ``structural`` task kind.

A structural task replays field-test logs in order through a sequence system (a controller,
:mod:`lidarfuzz.suts.sequence`) under the coverage recorder, cuts each log into segments,
selects discriminatory segments with each heuristic into a base log L′, generates a new log
L″ from those segments with each strategy (HGT, AVG, any operator) and replays those too.

**Units.** One unit is one log replayed from a reset — the system's state makes the log the
unit. For each field-test log, in order: the log itself (subtask ``original``), then for each
heuristic its base log (subtask ``base:<heuristic>``), then for each strategy the log generated
from the base's segments (subtask ``<heuristic>+<strategy>``). A unit commits in one
transaction: its frame result (``trial`` = the field-test log's number; ``output`` holds the
decisions per step, the covered requirements, failures and relation counts), the store's
meta-model rows (:class:`~lidarfuzz.store.models.Log` field_test or generated with parent,
heuristic and strategy; the field-test log's segments; a
:class:`~lidarfuzz.store.models.CoverageRecord` per log, criterion and — for field-test logs —
segment, with the system's fingerprint) and its findings. A resumed task skips every unit that
has its frame result, so nothing is redone or recorded twice; a heuristic re-reads the segment
coverage the store holds. Generated folders are written beside the store
(``<workspace>/logs/task-<id>/``) and replaced whole when a unit is redone.

**Findings.** A step's failure (crash, timeout, invalid output, as
:func:`lidarfuzz.suts.sequence.replay` makes them) and every violated decision relation: ``safety``
on consecutive steps of every log; ``steering_tolerance`` / ``speed_tolerance`` on a generated
frame made by an operator from one source frame, against the field-test log's decision on that
source (checked only where the operator is meant to be harmless at its setting, as detection
campaigns do). Evidence: the log, the step, the frame, the decisions before and after, the params.

**Determinism.** Generation and the random heuristic draw from the task's seed; coverage is
measured in this process (the executor is not used), so the same seed gives the same records.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict, Field, field_validator
from sqlalchemy import func, insert, select, update

from lidarfuzz.campaign.lifecycle import ProgressEvent, RunOptions, RunStats, Watch, now
from lidarfuzz.campaign.plan import ORIGINAL, KindPlan, SubtaskPlan
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store.contracts import FailureRecord, FindingReplay, SubtaskResults, TaskSummary
from lidarfuzz.store.models import CoverageRecord, Finding, FrameResult, Log, Status, Subtask, Task
from lidarfuzz.store.models import Segment as SegmentRow
from lidarfuzz.store.store import Store

if TYPE_CHECKING:
    from lidarfuzz.campaign.spec import CampaignSpec
    from lidarfuzz.campaign.structural_summary import StructuralSummary
    from lidarfuzz.store.models import Model
    from lidarfuzz.structural.logs import OrderedLog
    from lidarfuzz.structural.requirements import Covered
    from lidarfuzz.suts.sequence import SequenceSystem, StepResult

#: The heuristics a campaign runs unless it lists its own (:mod:`lidarfuzz.structural.heuristics`).
DEFAULT_HEURISTICS = ("greedy_edges", "greedy_nodes", "budget", "decision_change", "random")
#: The strategies unless listed: the paper's two.
DEFAULT_STRATEGIES = ("HGT", "AVG")
BASE = "base"


class StructuralSetupError(LidarfuzzError, ValueError):
    """A structural campaign that cannot run (named field, one line)."""


class StructuralConfig(BaseModel):
    """A structural task's settings (``TaskOptions.kind_options``).

    Attributes:
        logs: The field-test logs (resolved paths), replayed in this order.
        targets: The code to cover (``pkg.module``, ``pkg.module:Class``, ``pkg.module:Class.method``).
        segment_size: Frames per segment.
        heuristics: Heuristics selecting each base log.
        strategies: Strategies generating a log from each base's segments.
        budget_frames: The ``budget`` heuristic's frame budget (None: as many frames as greedy_edges chose).
        height: HGT's constant c (m).
        severity: The severity of an operator strategy.
        radius: AVG without rings: the farthest apart two points may be to pair (m).
        timeout: Seconds a step may take (None: no limit).
        gcov: A compiled ``worker:`` program's build folder: its coverage is read from gcov data per
            step (:class:`~lidarfuzz.structural.gcov.GcovRecorder`; targets are source files or
            ``file:function``), not measured by coverage.py.
        source_root: With ``gcov``: the sources' root (default: the build folder).
        total: Every requirement of the targets when the task was planned, as stored labels.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    logs: tuple[str, ...] = Field(min_length=1)
    targets: tuple[str, ...] = Field(min_length=1)
    segment_size: int = Field(default=5, ge=1)
    heuristics: tuple[str, ...] = DEFAULT_HEURISTICS
    strategies: tuple[str, ...] = DEFAULT_STRATEGIES
    budget_frames: int | None = Field(default=None, ge=1)
    height: float = 10.0
    severity: int = Field(default=3, ge=1, le=5)
    radius: float = Field(default=0.5, gt=0.0)
    timeout: float | None = Field(default=None, gt=0.0)
    gcov: str | None = None
    source_root: str | None = None
    total: dict[str, list[str]] = Field(default_factory=dict)

    @field_validator("heuristics")
    @classmethod
    def _heuristics(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        from lidarfuzz.structural.heuristics import HEURISTICS

        known = (*HEURISTICS, "decision_change")
        bad = [h for h in value if h not in known]
        if bad:
            raise ValueError(f"unknown heuristic {bad[0]!r}; choose among {', '.join(dict.fromkeys(known))}")
        if not value:
            raise ValueError("give at least one heuristic")
        return tuple(dict.fromkeys(value))

    @field_validator("strategies")
    @classmethod
    def _strategies(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        from lidarfuzz.structural.generate import strategy

        names = []
        for name in value:
            try:
                names.append(strategy(name).name)
            except LidarfuzzError as exc:
                raise ValueError(str(exc).replace("--strategy ", "")) from None
        return tuple(dict.fromkeys(names))


# -- planning ---------------------------------------------------------------------------
def config_of(spec: CampaignSpec) -> StructuralConfig:
    """The settings of a structural campaign: its field-test logs (``dataset`` then ``logs``), its
    ``coverage.targets``, ``segments``, ``heuristics``, ``strategies`` and ``coverage``'s other keys
    (budget_frames, height, severity, radius, timeout, gcov, source_root)."""
    coverage = dict(spec.coverage)
    targets = coverage.pop("targets", None)
    if isinstance(targets, str):
        targets = [targets]
    values: dict[str, Any] = {"logs": [spec.dataset, *spec.logs], "targets": targets or [], **coverage}
    if spec.segments is not None:
        values["segment_size"] = spec.segments
    if spec.heuristics:
        values["heuristics"] = spec.heuristics
    if spec.strategies:
        values["strategies"] = spec.strategies
    return StructuralConfig.model_validate(values)


def decision_relations(choice: Any) -> list[dict[str, Any]]:
    """The decision relations a campaign checks: every one for ``auto``, else those listed
    (a relation that reads detections is refused, naming it)."""
    from lidarfuzz.oracles.relations.registry import available, from_spec

    if choice == "auto":
        return [cls().spec() for cls in available().values() if cls.output == "decisions"]
    chosen = [from_spec(item if isinstance(item, str) else item.model_dump()) for item in choice]
    wrong = [r.name for r in chosen if type(r).output != "decisions"]
    if wrong:
        raise ValueError(f"relations: {wrong[0]!r} judges detections, not a sequence system's decisions "
                         "(steering_tolerance, speed_tolerance, safety)")
    return [r.spec() for r in chosen]


def check_spec(spec: CampaignSpec) -> None:
    """Refuse what a structural campaign cannot run: no targets, an unknown heuristic or strategy,
    relations that read detections, operators or references (raised as ValueError: pydantic names
    the campaign)."""
    if not spec.coverage.get("targets"):
        raise ValueError("coverage.targets: name the code to cover, e.g. "
                         "lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process")
    if spec.operators:
        raise ValueError("operators: a structural campaign generates logs with strategies, not operators")
    if spec.reference:
        raise ValueError("reference: a structural campaign compares logs, not reference systems")
    try:
        config_of(spec)
    except Exception as exc:  # pydantic's error, in one line naming the field
        from pydantic import ValidationError

        if isinstance(exc, ValidationError):
            first = exc.errors()[0]
            where = ".".join(str(p) for p in first["loc"])
            raise ValueError(f"{where}: {first['msg'].removeprefix('Value error, ')}") from None
        raise
    decision_relations(spec.relations)


def open_logs(paths: Sequence[str]) -> list[OrderedLog]:
    """The field-test logs, each with its order (a source without order is refused, named)."""
    from lidarfuzz.structural.logs import open_log

    out = []
    for path in paths:
        if not Path(path).exists():
            raise StructuralSetupError(f"dataset: log {path!r} does not exist")
        out.append(open_log(path))
    return out


def _resolve_logs(spec: CampaignSpec, first: str) -> list[str]:
    rest = [str(Path(p).expanduser().resolve()) for p in spec.logs]
    return [first, *rest]


def plan(spec: CampaignSpec, model: Model, frame_ids: list[str]) -> KindPlan:
    """One unit per log: the field-test logs (the originals' subtask), one base log per heuristic
    and one generated log per heuristic × strategy for each of them. The targets are resolved now
    (a module or function that does not exist is refused here, named) and every log's order
    checked."""
    from lidarfuzz.structural.python_coverage import requirements_of
    from lidarfuzz.structural.stored import to_labels
    from lidarfuzz.suts.registry import create_sequence

    config = config_of(spec)
    first = model_dataset_path(spec)
    logs = _resolve_logs(spec, first)
    open_logs(logs)
    try:
        if config.gcov is not None:
            from lidarfuzz.structural.gcov import requirements, selected

            build = Path(config.gcov).expanduser().resolve()
            root = Path(config.source_root).expanduser().resolve() if config.source_root else build
            config = config.model_copy(update={"gcov": str(build), "source_root": str(root)})
            total = selected(requirements(build, root), config.targets)
            if not total:
                raise LidarfuzzError(f"no function of {', '.join(config.targets)} in the gcov notes of {build} "
                                     f"(source files or file:function, relative to {root})")
        else:
            total = requirements_of(config.targets)
    except LidarfuzzError as exc:
        raise StructuralSetupError(f"coverage.targets: {exc}") from None
    try:
        create_sequence(model.spec, **dict(model.options or {}))
    except LidarfuzzError as exc:
        raise StructuralSetupError(f"sut: {exc}") from None
    config = config.model_copy(update={"logs": tuple(logs), "total": to_labels(total)})
    units = len(logs)
    subtasks = []
    for heuristic in config.heuristics:
        subtasks.append(SubtaskPlan(f"{BASE}:{heuristic}", {"name": "structural", "heuristic": heuristic}, units))
        for name in config.strategies:
            subtasks.append(SubtaskPlan(f"{heuristic}+{name}", {"name": "structural", "heuristic": heuristic,
                                                                 "strategy": name}, units))
    relations = decision_relations(spec.relations)
    subtasks = [SubtaskPlan(p.name, p.operator, p.units, relations=relations) for p in subtasks]
    options = config.model_dump(mode="json")
    options["relations"] = relations
    return KindPlan(subtasks, options, original_units=units)


def model_dataset_path(spec: CampaignSpec) -> str:
    """The first field-test log's path (``dataset``; a registered data set's name stays as given)."""
    path = Path(spec.dataset).expanduser()
    return str(path.resolve()) if path.exists() else spec.dataset


# -- replay under coverage --------------------------------------------------------------
class _Measured:
    """A sequence system whose every step runs under a coverage recorder (what each step covered,
    in :attr:`covered`; a step that raises keeps what it covered before raising)."""

    def __init__(self, system: SequenceSystem, recorder: Any) -> None:
        self.system, self.recorder = system, recorder
        self.covered: list[Covered] = []

    @property
    def alive(self) -> bool:
        return self.system.alive

    def set_timeout(self, seconds: float) -> None:
        self.system.set_timeout(seconds)

    def reset(self) -> None:
        self.system.reset()

    def validate(self, decision: Any) -> str | None:
        return self.system.validate(decision)

    def step(self, frame: Any) -> Any:
        try:
            decision, covered = self.recorder.record(self.system.step, frame)
        except BaseException:
            self.covered.append(self.recorder.last)
            raise
        self.covered.append(covered)
        return decision


def measured_replay(system: SequenceSystem, recorder: Any, frames: Iterable[Any], *,
                    timeout: float | None = None) -> tuple[list[StepResult], list[Covered]]:
    """:func:`~lidarfuzz.suts.sequence.replay` with every step measured: its results and, per frame,
    what the step covered (nothing for a frame that was never stepped)."""
    from lidarfuzz.suts.sequence import replay

    measured = _Measured(system, recorder)
    results = replay(measured, frames, timeout=timeout)  # type: ignore[arg-type]
    taken = iter(measured.covered)
    per_frame: list[Covered] = [next(taken) if r.stepped else frozenset() for r in results]
    return results, per_frame


def decision_record(decision: Any) -> dict[str, Any] | None:
    """What a step's decision is stored as (obstacles counted, not kept)."""
    if decision is None:
        return None
    obstacles = getattr(decision, "obstacles", None)
    return {"steering": float(decision.steering), "speed": float(decision.speed),
            "emergency_stop": bool(decision.emergency_stop),
            "obstacles": None if obstacles is None else len(obstacles)}


def _as_decision(record: dict[str, Any] | None) -> Any:
    from lidarfuzz.suts.sequence import Decision

    if record is None:
        return None
    return Decision(record["steering"], record["speed"], record["emergency_stop"])


# -- one run ----------------------------------------------------------------------------
class _Unit:
    """One log to replay: which field-test log, and (after the originals) which heuristic and strategy."""

    def __init__(self, sub: Subtask, ft: int, heuristic: str = "", strategy: str = "") -> None:
        self.sub, self.ft, self.heuristic, self.strategy = sub, ft, heuristic, strategy

    @property
    def role(self) -> str:
        return "field_test" if not self.heuristic else ("base" if not self.strategy else "generated")


def logs_folder(store: Store, task_id: int) -> Path:
    """Where a task's generated logs go: beside a workspace's SQLite store, else in the cache."""
    url = store.url
    if url.startswith("sqlite:///") and not url.endswith(":memory:"):
        root = Path(url[len("sqlite:///"):]).parent
    else:
        from lidarfuzz.settings import settings

        root = settings().cache
    return root / "logs" / f"task-{task_id}"


class _StructuralRun:
    def __init__(self, store: Store, task: Task, progress: Callable[[ProgressEvent], None] | None,
                 stop: Any) -> None:
        from lidarfuzz.oracles.relations.registry import from_spec
        from lidarfuzz.structural.stored import from_labels

        self.store, self.task, self.progress = store, task, progress
        self.watch = Watch(store, task.id, stop)
        self.config = task_config(task)
        self.relations = [from_spec(spec) for spec in task.options.kind_options.get("relations", [])]
        self.logs = open_logs(self.config.logs)
        self.total = from_labels(self.config.total)
        from lidarfuzz.structural.log_coverage import measured_system

        self.system, self.recorder, fingerprint = measured_system(task.model.spec, self.config.targets,
                                                                  options=dict(task.model.options or {}),
                                                                  gcov=self.config.gcov,
                                                                  source_root=self.config.source_root)
        self.system.load()
        if fingerprint != task.model.fingerprint:
            self.system.close()
            raise StructuralSetupError(
                f"sut: the system's code changed since task {task.id} was planned (fingerprint "
                f"{task.model.fingerprint} → {fingerprint}); coverage of two versions does not add up: run a new task")
        self.fingerprint = fingerprint
        self.target = ",".join(self.config.targets)
        self.folder = logs_folder(store, task.id)
        self.stats = RunStats()
        self.subs = {sub.name: sub for sub in task.subtasks}

    # -- the units, in dependency order ------------------------------------------------
    def units(self) -> list[_Unit]:
        out = []
        for ft in range(len(self.logs)):
            out.append(_Unit(self.subs[ORIGINAL], ft))
            for heuristic in self.config.heuristics:
                out.append(_Unit(self.subs[f"{BASE}:{heuristic}"], ft, heuristic))
                for name in self.config.strategies:
                    out.append(_Unit(self.subs[f"{heuristic}+{name}"], ft, heuristic, name))
        return out

    def _done(self) -> set[tuple[int, int]]:
        with self.store.session() as s:
            ids = [sub.id for sub in self.subs.values()]
            return {(int(a), int(b)) for a, b in s.execute(
                select(FrameResult.subtask_id, FrameResult.trial).where(FrameResult.subtask_id.in_(ids)))}

    def execute(self) -> None:
        done = self._done()
        for unit in self.units():
            if (unit.sub.id, unit.ft) in done:
                continue
            self.watch.check()
            self.run_unit(unit)
            if self.progress is not None:
                with self.store.session() as s:
                    task_done = s.scalar(select(Task.done).where(Task.id == self.task.id)) or 0
                    sub_done = s.scalar(select(Subtask.done).where(Subtask.id == unit.sub.id)) or 0
                self.progress(ProgressEvent(task_done, self.task.total, unit.sub.id, unit.sub.name, sub_done,
                                            unit.sub.total))

    # -- names -------------------------------------------------------------------------
    def log_name(self, unit: _Unit) -> str:
        label = Path(self.config.logs[unit.ft]).name
        name = f"task-{self.task.id}/{unit.ft}:{label}"
        if unit.heuristic:
            name += f"/{unit.heuristic}"
        if unit.strategy:
            name += f"+{unit.strategy}"
        return name[:200]

    # -- selection from the stored segment coverage --------------------------------------
    def selection(self, session: Any, unit: _Unit) -> tuple[Any, list[Any], Log]:
        """The heuristic's choice on the field-test log's segments (their coverage as stored)."""
        from lidarfuzz.structural.heuristics import select as run_heuristic
        from lidarfuzz.structural.log_coverage import decision_signature
        from lidarfuzz.structural.requirements import union
        from lidarfuzz.structural.segments import partition
        from lidarfuzz.structural.stored import from_labels, get_log

        log = self.logs[unit.ft]
        ft_row = get_log(session, self.log_name(_Unit(unit.sub, unit.ft)))
        segments = partition(log.frame_ids, self.config.segment_size)
        rows = list(session.scalars(select(SegmentRow).where(SegmentRow.log_id == ft_row.id, SegmentRow.size == max(
            len(s) for s in segments)).order_by(SegmentRow.index)))
        records = session.execute(select(CoverageRecord.segment_id, CoverageRecord.covered).where(
            CoverageRecord.segment_id.in_([r.id for r in rows]), CoverageRecord.fingerprint == self.fingerprint,
            CoverageRecord.target == self.target)).all()
        by_segment: dict[int, list[Any]] = {}
        for segment_id, covered in records:
            by_segment.setdefault(segment_id, []).append(from_labels(covered))
        coverage = [union(*by_segment.get(r.id, [])) for r in rows]
        original = session.scalar(select(FrameResult.output).where(
            FrameResult.subtask_id == self.subs[ORIGINAL].id, FrameResult.trial == unit.ft))
        signatures = [decision_signature(_as_decision(d)) for d in (original or {}).get("decisions", [])]
        frames = self.config.budget_frames
        if unit.heuristic == "budget" and frames is None:
            frames = run_heuristic("greedy_edges", segments, coverage).frames
        chosen = run_heuristic(unit.heuristic, segments, coverage, frames=frames, signatures=signatures,
                               seed=self.task.seed)
        return chosen, segments, ft_row

    # -- one unit ----------------------------------------------------------------------
    def run_unit(self, unit: _Unit) -> None:
        from lidarfuzz.store.log_contracts import Criterion
        from lidarfuzz.structural.generate import strategy, write_generated_log
        from lidarfuzz.structural.logs import open_log
        from lidarfuzz.structural.requirements import union
        from lidarfuzz.structural.segments import partition, segment_coverage
        from lidarfuzz.structural.stored import (
            record_coverage,
            record_generated,
            record_log,
            record_segments,
            to_labels,
        )

        name = self.log_name(unit)
        criteria: tuple[Criterion, ...] = ("node", "edge")
        with self.store.session() as session:
            made = None
            selection: dict[str, Any] = {}
            if unit.role == "field_test":
                log = self.logs[unit.ft]
            else:
                chosen, segments, ft_row = self.selection(session, unit)
                picked = [segments[i] for i in chosen.segments]
                selection = {"segments": list(chosen.segments), "frames": chosen.frames,
                             "log_segments": len(segments), "log_frames": len(self.logs[unit.ft])}
                if not picked:  # the field-test log covered nothing of the targets: an empty log covers nothing
                    empty: dict[str, Any] = {
                        "role": unit.role, "log": name, "log_id": None, "path": "", "ft": unit.ft,
                        "heuristic": unit.heuristic, "strategy": unit.strategy, "frames": 0, "frame_ids": [],
                        "decisions": [], "failures": {}, "covered": {}, "selection": selection,
                        "relations": {r.name: {"checked": 0, "violated": 0} for r in self.relations},
                        "note": "the heuristic chose no segment: the field-test log covered none of the targets"}
                    self._commit(session, unit, name, selection, empty, None, 0.0)
                    self.stats.units += 1
                    return
                chosen_strategy = strategy(unit.strategy or "none", height=self.config.height,
                                           severity=self.config.severity, radius=self.config.radius)
                made = write_generated_log(self.logs[unit.ft], picked, chosen_strategy,
                                           self.folder / name.split("/", 1)[1].replace(":", "_"),
                                           seed=self.task.seed, heuristic=unit.heuristic,
                                           segment_size=self.config.segment_size, overwrite=True)
                log = open_log(made.path)
            results, per_frame = measured_replay(self.system, self.recorder, log.frames(),
                                                 timeout=self.config.timeout)
            covered = union(*per_frame)
            if unit.role == "field_test":
                row = record_log(session, log, name, dataset_id=self.task.dataset_id if unit.ft == 0 else None)
                segments = partition(log.frame_ids, self.config.segment_size)
                segment_rows = record_segments(session, row, segments)
                for criterion in criteria:
                    for segment_row, mine in zip(segment_rows, segment_coverage(segments, per_frame), strict=True):
                        record_coverage(session, segment=segment_row, fingerprint=self.fingerprint,
                                        criterion=criterion, target=self.target, covered=mine, total=self.total)
            else:
                assert made is not None
                row = record_generated(session, made, name, ft_row)
            for criterion in criteria:
                record_coverage(session, log=row, fingerprint=self.fingerprint, criterion=criterion,
                                target=self.target, covered=covered, total=self.total)
            outcomes, findings = self.check_relations(unit, log, results, made)
            failed = [r for r in results if r.failure is not None]
            output = {"role": unit.role, "log": name, "log_id": row.id, "path": str(log.path), "ft": unit.ft,
                      "heuristic": unit.heuristic, "strategy": unit.strategy, "frames": len(log),
                      "frame_ids": list(log.frame_ids), "decisions": [decision_record(r.decision) for r in results],
                      "failures": {str(r.index): f"{r.failure.kind.value}: {r.failure.message}"
                                   for r in failed if r.failure is not None},
                      "covered": to_labels(covered), "relations": outcomes, "selection": selection}
            first = failed[0].failure if failed else None
            seconds = sum(r.seconds for r in results)
            for failure in failed:
                assert failure.failure is not None
                findings.insert(0, self._finding(unit, log, made, failure.index, failure.failure.kind.value, None,
                                                 failure.failure.message, results, None))
            self._commit(session, unit, name, selection, output, None if first is None else FailureRecord(
                kind=first.kind.value, message=f"step {failed[0].index}: {first.message}"), seconds, findings)
        self.stats.units += 1
        self.stats.sut += seconds
        self.stats.failures += len(failed)

    def _commit(self, session: Any, unit: _Unit, name: str, selection: dict[str, Any], output: dict[str, Any],
                failure: FailureRecord | None, seconds: float, findings: Sequence[dict[str, Any]] = ()) -> None:
        """The unit's frame result, its findings and the counters (in the unit's transaction)."""
        result_id = session.execute(insert(FrameResult).returning(FrameResult.id), {
            "subtask_id": unit.sub.id, "frame_id": Path(self.config.logs[unit.ft]).name[:200], "trial": unit.ft,
            "params": {"log": name, "heuristic": unit.heuristic, "strategy": unit.strategy, **selection},
            "output": output, "failure": failure, "relations": [], "seconds": seconds, "cached": False,
            "created_at": now()}).scalar_one()
        for finding in findings:
            session.execute(insert(Finding), {**finding, "task_id": self.task.id, "frame_result_id": result_id})
        session.execute(update(Subtask).where(Subtask.id == unit.sub.id).values(
            done=Subtask.done + 1, status=Status.RUNNING,
            started_at=func.coalesce(Subtask.started_at, now())))  # set once: its first unit
        session.execute(update(Task).where(Task.id == self.task.id).values(done=Task.done + 1, heartbeat_at=now()))

    # -- relations ---------------------------------------------------------------------
    def _finding(self, unit: _Unit, log: OrderedLog, made: Any, step: int, kind: str, magnitude: float | None,
                 message: str, results: Sequence[StepResult], relation: dict[str, Any] | None,
                 extra: dict[str, Any] | None = None) -> dict[str, Any]:
        provenance = made.frames[step] if made is not None and step < len(made.frames) else None
        detail = {"log": self.log_name(unit), "role": unit.role, "step": step, "frame_id": log.frame_ids[step],
                  "decision_before": decision_record(results[step - 1].decision) if step > 0 else None,
                  "decision_after": decision_record(results[step].decision),
                  "sources": list(provenance.sources) if provenance is not None else [log.frame_ids[step]],
                  "params": provenance.params if provenance is not None else {}, **(extra or {})}
        replay = FindingReplay(dataset=str(log.path), frame_id=log.frame_ids[step], trial=step, seed=self.task.seed,
                               operator=provenance.operator if provenance is not None else None,
                               params=provenance.params if provenance is not None else {},
                               sut=self.task.model.spec, options=dict(self.task.model.options or {}),
                               fingerprint=self.fingerprint, relation=relation)
        safe = magnitude if magnitude is None or math.isfinite(magnitude) else None
        return {"kind": kind, "cls": "", "magnitude": safe, "message": message, "detail": detail, "replay": replay}

    def check_relations(self, unit: _Unit, log: OrderedLog, results: Sequence[StepResult],
                        made: Any) -> tuple[dict[str, dict[str, int]], list[dict[str, Any]]]:
        """Every relation on this log: counts per relation (checked, violated) and the findings."""
        from lidarfuzz.oracles.relations.base import Pair

        counts: dict[str, dict[str, int]] = {r.name: {"checked": 0, "violated": 0} for r in self.relations}
        findings: list[dict[str, Any]] = []
        if not self.relations:
            return counts, findings
        pairwise = [r for r in self.relations if r.name == "safety"]
        tolerant = [r for r in self.relations if r.name != "safety"]
        previous = None
        for step, frame in enumerate(log.frames()):
            decision = results[step].decision
            if previous is not None and decision is not None and results[step - 1].decision is not None:
                pair = Pair(previous, frame, results[step - 1].decision, decision)
                for relation in pairwise:
                    self._judge(relation, pair, unit, log, made, step, results, counts, findings)
            previous = frame
            if made is not None and tolerant and decision is not None:
                judged = self._source_pair(unit, made, step, frame, decision)
                if judged is not None:
                    for relation in tolerant:
                        if relation.assumes_harmless and not judged[1]:
                            continue  # as campaigns do: only where the operator is meant to be harmless
                        self._judge(relation, judged[0], unit, log, made, step, results, counts, findings)
        return counts, findings

    def _judge(self, relation: Any, pair: Any, unit: _Unit, log: OrderedLog, made: Any, step: int,
               results: Sequence[StepResult], counts: dict[str, dict[str, int]],
               findings: list[dict[str, Any]]) -> None:
        outcome = relation(pair)
        if not outcome.applicable:
            return
        counts[relation.name]["checked"] += 1
        if outcome.holds:
            return
        counts[relation.name]["violated"] += 1
        for violation in outcome.violations:
            stats = {k: v for k, v in outcome.stats.items() if isinstance(v, int | float | str)}
            findings.append(self._finding(unit, log, made, step, relation.name, float(violation.magnitude),
                                          violation.message, results, relation.spec(), {"stats": stats}))

    def _source_pair(self, unit: _Unit, made: Any, step: int, frame: Any, decision: Any) -> tuple[Any, bool] | None:
        """The (field-test frame, its decision there; generated frame, its decision) pair of a frame an
        operator made from one source, and whether the operator is meant to be harmless there."""
        from lidarfuzz.operators.registry import from_spec
        from lidarfuzz.oracles.relations.base import Pair

        provenance = made.frames[step]
        if provenance.operator is None or len(provenance.sources) != 1:
            return None
        source_id = provenance.sources[0]
        decisions = self._ft_decisions(unit.ft)
        before = decisions.get(source_id)
        if before is None:
            return None
        operator = from_spec(provenance.operator)
        params = operator.parse_params(provenance.params)
        source = self.logs[unit.ft].dataset.load(source_id)
        pair = Pair(source, frame, before, decision, operator_relation=operator.relation,
                    transform=operator.transform(params))
        return pair, bool(operator.harmless())

    def _ft_decisions(self, ft: int) -> dict[str, Any]:
        cache: dict[int, dict[str, Any]] = self.__dict__.setdefault("_ft_cache", {})
        if ft not in cache:
            with self.store.session() as s:
                output = s.scalar(select(FrameResult.output).where(
                    FrameResult.subtask_id == self.subs[ORIGINAL].id, FrameResult.trial == ft)) or {}
            cache[ft] = {fid: _as_decision(d) for fid, d in zip(output.get("frame_ids", []),
                                                                 output.get("decisions", []), strict=False)}
        return cache[ft]

    # -- the end -----------------------------------------------------------------------
    def summary(self) -> TaskSummary:
        from lidarfuzz.campaign.results import summarise

        finish_subtasks(self.store, self.task.id)
        return summarise(self.store, self.task.id)

    def close(self) -> None:
        self.watch.close()
        self.system.close()


def finish_subtasks(store: Store, task_id: int) -> None:
    """Every subtask done, with its count of replayed logs, failed steps and the system's time."""
    with store.session() as s:
        for sub in s.scalars(select(Subtask).where(Subtask.task_id == task_id)):
            rows = s.execute(select(FrameResult.output, FrameResult.seconds).where(
                FrameResult.subtask_id == sub.id)).all()
            failures = sum(len((output or {}).get("failures", {})) for output, _ in rows)
            sub.results = SubtaskResults(frames=len(rows), failures=failures,
                                         sut_seconds=float(sum(seconds or 0.0 for _, seconds in rows)))
            if sub.status != Status.DONE or sub.finished_at is None:
                sub.finished_at = now()
            sub.status = Status.DONE


# -- the kind's hooks (lidarfuzz.campaign.lifecycle.KindImplementation) ----------------
counted_below: int | None = None


def start(store: Store, task: Task, options: RunOptions) -> _StructuralRun:
    return _StructuralRun(store, task, options.progress, options.stop)


def describe(task: Task) -> str:
    config = task_config(task)
    return (f"structural: {len(config.logs)} field-test log(s) × ({len(config.heuristics)} heuristic(s) × "
            f"(1 base + {len(config.strategies)} strategy log(s)) + 1), segments of {config.segment_size}")


def task_config(task: Task) -> StructuralConfig:
    """A structural task's settings as planned."""
    return StructuralConfig.model_validate({k: v for k, v in task.options.kind_options.items() if k != "relations"})


def summary_of(store: Store, task: Task) -> StructuralSummary:
    """The task's structural figures (:func:`lidarfuzz.campaign.structural_summary.build`)."""
    from lidarfuzz.campaign.structural_summary import build

    return build(store, task, task_config(task))


def kind_summary(store: Store, task: Task) -> dict[str, Any]:
    """The figures as the task summary's ``kind_summary`` holds them."""
    return summary_of(store, task).model_dump(mode="json")


__all__ = ["BASE", "DEFAULT_HEURISTICS", "DEFAULT_STRATEGIES", "StructuralConfig", "StructuralSetupError",
           "check_spec", "config_of", "counted_below", "decision_relations", "describe", "finish_subtasks",
           "kind_summary", "logs_folder", "measured_replay", "open_logs", "plan", "start",
           "summary_of", "task_config"]
