"""Tasks in the store: creating one from a campaign, listing, finding, cancelling, deleting.

A task is planned entirely when it is created: its frames (ids fixed then, so a resume tests
the same frames), one subtask for the originals, and the subtasks its kind plans (one per
operator × severity for a detection campaign, one holding every test of a search; see
:mod:`lidarfuzz.campaign.kinds`), each with the relations that apply to it.

Finding a task, its liveness and cancelling it are the shared lifecycle's
(:mod:`lidarfuzz.campaign.lifecycle`), and the names of subtasks :mod:`lidarfuzz.campaign.plan`'s;
they are importable from here too.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from sqlalchemy import Float, String, Text, cast, func, or_, select
from sqlalchemy.orm import contains_eager, defer

from lidarfuzz.campaign.kinds import task_kind
from lidarfuzz.campaign.lifecycle import (
    STALE_AFTER,
    cancel_task,
    get_task,
    heartbeat_age,
    looks_alive,
    task_row,
)
from lidarfuzz.campaign.plan import ORIGINAL, SubtaskPlan, operator_key, relations_for, select_frames, subtask_label
from lidarfuzz.campaign.spec import CampaignSpec
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.store.contracts import PilotNote, SubtaskInputs, TaskOptions
from lidarfuzz.store.errors import ConflictError, StoreError
from lidarfuzz.store.models import Dataset, Model, Status, Subtask, Task
from lidarfuzz.store.store import Store


def _dataset_row(s: Any, ref: str, options: DatasetOptions | None = None, *, modality: str = "lidar") -> Dataset:
    """The data set a campaign names: a registered one, or a path (registered now, with
    ``options``, read as ``modality``'s data). Options that change how a registered data set is
    read are refused: register it again under another name (lidarfuzz datasets add)."""
    from lidarfuzz.io.open import open_dataset
    from lidarfuzz.store.inventory import dataset_options

    given = (options or DatasetOptions()).resolved()
    if given.modality != modality:
        given = given.model_copy(update={"modality": modality})
    row = s.scalar(select(Dataset).where(Dataset.name == ref))
    if row is None:
        path = Path(ref).expanduser()
        if not path.exists():
            raise StoreError(f"{ref}: neither a registered data set nor a path", cli="lidarfuzz datasets list")
        resolved = path.resolve()
        rows = s.scalars(select(Dataset).where(Dataset.path == str(resolved)).order_by(Dataset.id))
        row = next((r for r in rows if dataset_options(r).modality == modality), None)
        if row is None:
            dataset = open_dataset(resolved, options=given)
            frames = len(dataset.frame_ids())
            if frames == 0:
                raise StoreError(f"{resolved}: no frames to test")
            name = resolved.name
            while s.scalar(select(Dataset).where(Dataset.name == name)) is not None:
                name = f"{resolved.name}-{hashlib.sha256(str(resolved).encode()).hexdigest()[:6]}"
            row = Dataset(name=name, path=str(resolved), format=dataset.format, frame_count=frames,
                          notes="registered by a campaign", options=given.stored())
            s.add(row)
            s.flush()
            return row
    stored = dataset_options(row)
    if stored.modality != modality:
        raise ConflictError(f"data set {row.name!r} holds {stored.modality} frames; a {modality} campaign needs "
                            f"{modality} data; register it as {modality} data",
                            cli=f"lidarfuzz datasets add --modality {modality}")
    for field in ("layout", "intensity_scale", "roi_map"):
        value = getattr(given, field)
        if value is not None and value != getattr(stored, field):
            raise ConflictError(f"data set {row.name!r} is registered with {field} {getattr(stored, field)!r}, not "
                               f"{value!r}; register it again under another name", cli="lidarfuzz datasets add")
    return row


def unlabelled_frames(dataset: Any, frame_ids: list[str], allow: bool, path: str) -> list[str]:
    """The campaign's frames that have no labels in a labelled data set: refused (one line naming
    them and ``--allow-unlabelled``) unless ``allow``; AP is then scored without them."""
    from lidarfuzz.io.kitti import unlabelled_note

    chosen = set(frame_ids)
    missing = [f for f in dataset.unlabelled_ids() if f in chosen]
    if missing and not allow:
        raise StoreError(f"{path}: {unlabelled_note(missing, len(frame_ids))}; AP needs labels: pass "
                         f"--allow-unlabelled to run every frame and score AP on the "
                         f"{len(frame_ids) - len(missing)} labelled one(s)")
    return missing


def _model_row(s: Any, ref: str, options: dict[str, Any], *, sequence: bool = False, modality: str = "lidar") -> Model:
    """The model a campaign runs: a registered one by name, else one registered for ``ref`` and
    ``options`` now. Either way the system is built and fingerprinted: when its code (or weights)
    changed since it was registered, another row holds the new fingerprint, so the old rows'
    fingerprint, and with it the old code's cached outputs, is never reused. ``sequence``: the
    system consumes logs in order (:func:`~lidarfuzz.suts.registry.create_sequence` builds it);
    ``modality`` ``camera``: a steering system (:func:`~lidarfuzz.suts.registry.create_camera`)."""
    from lidarfuzz.suts.registry import create, create_camera, create_sequence
    from lidarfuzz.suts.specs import SutSpecError

    def build(spec: str, **given: Any) -> Any:
        if modality == "camera":
            try:
                return create_camera(spec, **given)
            except LidarfuzzError as exc:  # the user's choice: a bad input
                raise SutSpecError(f"sut: {exc}") from None  # the message names the steering systems
        if not sequence:
            return create(spec, **given)
        try:
            return create_sequence(spec, **given)
        except LidarfuzzError as exc:  # the user's choice, not a state of the store: a bad input
            raise SutSpecError(f"sut: {exc} (a log campaign needs a system that consumes logs in order, e.g. "
                               "controller)") from None

    row = s.scalar(select(Model).where(Model.name == ref))
    if row is not None:
        if options:
            raise ConflictError(f"model {ref!r} is registered with its options; register another to change them")
        fingerprint = build(row.spec, **dict(row.options or {})).fingerprint()
        if fingerprint == row.fingerprint:
            return row
        ref, options, note = row.spec, dict(row.options or {}), f"{row.name} with changed code or weights"
    else:
        fingerprint = build(ref, **options).fingerprint()
        note = "registered by a campaign"
    for candidate in s.scalars(select(Model).where(Model.spec == ref)):
        if candidate.fingerprint == fingerprint and candidate.options == options:
            return candidate
    name = ref if not options else f"{ref}#{fingerprint[:8]}"
    while s.scalar(select(Model).where(Model.name == name)) is not None:
        name = f"{ref}#{fingerprint[:8]}"
        if s.scalar(select(Model).where(Model.name == name)) is not None:
            name = f"{ref}#{fingerprint[:16]}"
            break
    row = Model(name=name, spec=ref, options=options, fingerprint=fingerprint, notes=note)
    s.add(row)
    s.flush()
    return row


def create_task(store: Store, spec: CampaignSpec, *, sut_options: dict[str, Any] | None = None,
                isolate: bool = False, timeout: float = 60.0, save_mutants: str | None = None,
                dataset_options: DatasetOptions | None = None, pilot: PilotNote | None = None) -> int:
    """Plan ``spec`` as a new pending task; returns its id. A campaign naming ``reference``
    systems also gets one pending task per reference (listed in the task's
    ``options.references``; run them too, then the task's report compares).

    ``dataset_options`` (the CLI's ``--layout``, ``--allow-unlabelled``) register a data set given
    by path; ``allow_unlabelled`` also lets a registered one run with frames that have no labels.
    ``pilot``: what a pilot changed in ``spec`` (:mod:`lidarfuzz.campaign.pilot`), kept with the task.

    Two processes creating campaigns on one data set or model at once both register it: the
    one that loses (a name taken meanwhile, or SQLite's stale snapshot) plans again and finds it.
    """
    from sqlalchemy.exc import IntegrityError, OperationalError

    for attempt in range(3):
        try:
            return _create_task(store, spec, sut_options=sut_options, isolate=isolate, timeout=timeout,
                                save_mutants=save_mutants, dataset_options=dataset_options, pilot=pilot)
        except (IntegrityError, OperationalError) as exc:
            if attempt == 2 or (isinstance(exc, OperationalError) and "locked" not in str(exc)):
                raise
    raise AssertionError("unreachable")


def _create_task(store: Store, spec: CampaignSpec, *, sut_options: dict[str, Any] | None,
                 isolate: bool, timeout: float, save_mutants: str | None,
                 dataset_options: DatasetOptions | None, pilot: PilotNote | None) -> int:
    from lidarfuzz.store.inventory import dataset_options as stored_options
    from lidarfuzz.store.inventory import open_registered

    row = task_kind(spec.kind)
    logs = row.consumes_logs
    with store.session() as s:
        dataset = _dataset_row(s, spec.dataset, dataset_options, modality=row.modality)
        model = _model_row(s, spec.sut, dict(sut_options or {}), sequence=logs, modality=row.modality)
        opened = open_registered(dataset)
        frame_ids = select_frames(opened.frame_ids(), spec.frames, spec.frame_order, spec.seed)
        allow = stored_options(dataset).allow_unlabelled or bool(dataset_options and dataset_options.allow_unlabelled)
        # a log is replayed whole and judged by decisions, not AP, and an image's label is a steering
        # angle (an unlabelled image is left out of Eq. 2, see lidarfuzz.campaign.camera): no 3D labels needed
        unlabelled = [] if logs or row.modality == "camera" else unlabelled_frames(opened, frame_ids, allow,
                                                                                    dataset.path)
        options = TaskOptions(kind=spec.kind, frame_ids=frame_ids, trials=spec.trials, isolate=isolate,
                              timeout=timeout, save_mutants=save_mutants, unlabelled_frames=unlabelled,
                              pilot=pilot)
        planned = spec
        if logs:  # every field-test log by its path: registered names (the web API's way) or paths
            others = [_dataset_row(s, ref).path for ref in spec.logs]
            planned = spec.model_copy(update={"dataset": dataset.path, "logs": others})
        task = _add_task(s, planned, spec.name, dataset, model, options)
        as_reference = options.model_copy(update={"reference_of": task.id, "pilot": None})
        references = [_add_task(s, spec, f"{spec.name or 'campaign'}: reference {ref}", dataset,
                                _model_row(s, ref, {}, sequence=logs, modality=row.modality), as_reference)
                      for ref in spec.reference]
        if references:
            task.options = task.options.model_copy(update={"references": [r.id for r in references]})
        s.flush()
        return task.id


def campaign_frames(store: Store, spec: CampaignSpec, dataset_options: DatasetOptions | None = None) -> int:
    """How many frames ``spec`` would test (registers its data set when given by path)."""
    from lidarfuzz.store.inventory import open_registered

    with store.session() as s:
        opened = open_registered(_dataset_row(s, spec.dataset, dataset_options))
        return len(select_frames(opened.frame_ids(), spec.frames, spec.frame_order, spec.seed))


def _add_task(s: Any, spec: CampaignSpec, name: str, dataset: Dataset, model: Model, options: TaskOptions) -> Task:
    """One task of ``spec`` on ``model`` with its subtasks planned (a campaign with references adds
    one per reference system: the same frames, operators and seed, so the same mutants)."""
    kind = task_kind(spec.kind).implementation().plan(spec, model, options.frame_ids)
    originals = len(options.frame_ids) if kind.original_units is None else kind.original_units
    plans = [SubtaskPlan(ORIGINAL, None, originals, 0, -1), *kind.subtasks]
    keys = [operator_key(p.operator) for p in plans]
    if len(set(keys)) != len(keys):
        raise ConflictError("the campaign lists the same operator configuration twice")
    relations = ["auto"] if spec.relations == "auto" else [
        r if isinstance(r, str) else r.model_dump() for r in spec.relations]
    # unlabelled frames: run through the SUT, left out of AP
    task = Task(name=name, dataset_id=dataset.id, model_id=model.id, seed=spec.seed,
                options=options.model_copy(update={"kind_options": kind.options}),
                operators=[c.model_dump(mode="json") for c in spec.operators], relations=relations)
    s.add(task)
    for plan, key in zip(plans, keys, strict=True):
        task.subtasks.append(Subtask(operator_key=key, operator=plan.operator or {}, name=plan.name,
                                     op_index=plan.op_index, severity=plan.severity, total=plan.units,
                                     plan=SubtaskInputs(relation_specs=plan.relations, unchecked=plan.unchecked)))
    task.total = sum(plan.units for plan in plans)
    s.flush()
    return task


#: What the task list sorts by: a key of :func:`list_tasks`'s ``sort`` → the column (``dataset`` and
#: ``model``: the names; the headline figures: :mod:`lidarfuzz.campaign.headline`'s, read from the JSON).
SORT_KEYS: tuple[str, ...] = ("id", "name", "status", "dataset", "model", "created", "started", "finished",
                              "progress", "map", "delta_map", "violations", "violation_rate", "failures")
#: Headline figures sortable in SQL: JSON_EXTRACT on SQLite, ``->>`` on PostgreSQL (SQLAlchemy's JSON index).
HEADLINE_SORTS: tuple[str, ...] = ("map", "delta_map", "violations", "violation_rate", "failures")


@dataclass(frozen=True)
class TaskQuery:
    """Which tasks a list shows and in what order.

    Attributes:
        status: Only tasks in this state.
        text: Only tasks whose name, data set, model, status, tags or notes contain it (any case).
        tags: Only tasks carrying every one of these tags.
        sort: A key of :data:`SORT_KEYS`, ``-`` first for descending; ties go newest first. A task
            without the figure (not done, or no AP) comes last either way.
    """

    status: Status | str | None = None
    text: str = ""
    tags: tuple[str, ...] = ()
    sort: str = "-id"


def _sort_column(key: str) -> Any:
    if key in HEADLINE_SORTS:
        return Task.headline[key].as_float()
    columns = {"id": Task.id, "name": func.lower(Task.name), "status": Task.status, "dataset": func.lower(Dataset.name),
               "model": func.lower(Model.name), "created": Task.created_at, "started": Task.started_at,
               "finished": Task.finished_at, "progress": cast(Task.done, Float) / func.nullif(Task.total, 0)}
    return columns[key]


def _filtered(query: Any, spec: TaskQuery) -> Any:
    """``query`` (joined with the data set and model) restricted to what ``spec`` asks for."""
    if spec.status:
        query = query.where(Task.status == Status(spec.status))
    text = spec.text.strip()
    if text:
        fields = [Task.name, Dataset.name, Model.name, cast(Task.status, String), cast(Task.tags, Text), Task.notes]
        query = query.where(or_(*(func.lower(f).contains(text.lower(), autoescape=True) for f in fields)))
    for tag in spec.tags:  # a JSON list of strings: the tag in quotes matches it whole
        query = query.where(cast(Task.tags, Text).contains(json.dumps(tag), autoescape=True))
    return query


def _ordered(query: Any, sort: str) -> Any:
    descending = sort.startswith("-")
    key = sort.lstrip("-+")
    if key not in SORT_KEYS:
        raise ValueError(f"sort: {sort!r} is not one of {', '.join(SORT_KEYS)} (- first for descending)")
    column = _sort_column(key)
    if key == "id":
        return query.order_by(Task.id.desc() if descending else Task.id.asc())
    # a task without the figure last either way: NULLS LAST is spelt the same on SQLite and PostgreSQL
    ordered = column.desc().nulls_last() if descending else column.asc().nulls_last()
    return query.order_by(ordered, Task.id.desc())


def list_tasks(store: Store, limit: int | None = None, *, offset: int = 0,
               status: Status | str | None = None, query: TaskQuery | None = None) -> list[Task]:
    """Tasks, newest first (or as ``query`` sorts), with their data set and model loaded (the
    summary is not: it can be large, and a listing does not show it). Finished tasks without
    headline figures get them first (:func:`lidarfuzz.campaign.headline.fill_headlines`).

    Args:
        store: The campaign store.
        limit: At most this many (all when None or 0).
        offset: Skip the first ``offset`` (pages).
        status: Only tasks in this state (``query.status`` too).
        query: Filters and order, done in SQL (:class:`TaskQuery`).

    Raises:
        ValueError: An unknown sort key (the message names ``sort`` and the keys).
    """
    from lidarfuzz.campaign.headline import fill_headlines

    spec = query or TaskQuery()
    if status is not None:
        spec = replace(spec, status=status)
    fill_headlines(store)
    with store.session() as s:
        select_ = (select(Task).join(Task.dataset).join(Task.model)
                   .options(defer(Task.summary), contains_eager(Task.dataset), contains_eager(Task.model)))
        select_ = _ordered(_filtered(select_, spec), spec.sort).offset(offset or None)
        if limit:
            select_ = select_.limit(limit)
        return list(s.scalars(select_))


def count_tasks(store: Store, status: Status | str | None = None, *, query: TaskQuery | None = None) -> int:
    """How many tasks there are (matching ``query``, in ``status``, when given)."""
    spec = query or TaskQuery()
    if status is not None:
        spec = replace(spec, status=status)
    with store.session() as s:
        select_ = select(func.count(Task.id)).select_from(Task).join(Task.dataset).join(Task.model)
        return int(s.scalar(_filtered(select_, spec)) or 0)


def delete_task(store: Store, task_id: int) -> None:
    with store.session() as s:
        task = task_row(s, task_id)
        if task.status == Status.RUNNING:
            raise ConflictError(f"task {task_id} is running; stop it first", cli=f"lidarfuzz cancel {task_id}")
        s.delete(task)


__all__ = ["ORIGINAL", "SORT_KEYS", "STALE_AFTER", "TaskQuery", "campaign_frames", "cancel_task", "count_tasks",
           "create_task", "delete_task", "get_task", "heartbeat_age", "list_tasks", "looks_alive", "operator_key",
           "relations_for", "subtask_label", "unlabelled_frames"]
