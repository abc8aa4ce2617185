"""Tasks in the store: creating one from a campaign, listing, finding, cancelling, deleting.

A task is planned entirely when it is created: its frames (ids fixed then, so a resume tests
the same frames), one subtask for the originals and one per operator × severity (or per
operator with an explicit config), each with the relations that apply to it.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import defer, joinedload

from lidarfuzz.campaign.spec import CampaignSpec
from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.store.models import Dataset, Model, Status, Subtask, Task
from lidarfuzz.store.store import Store, StoreError

ORIGINAL = "original"
STALE_AFTER = 30.0  # seconds without a heartbeat before a "running" task is taken as dead


def operator_key(spec: dict[str, Any] | None) -> str:
    """A stable key of an operator spec ("original" for none)."""
    if spec is None:
        return ORIGINAL
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:32]


def subtask_label(name: str, severity: int) -> str:
    """How reports name a subtask: ``fog@3``, ``fog (config)`` or ``original``."""
    if name == ORIGINAL:
        return ORIGINAL
    return f"{name}@{severity}" if severity else f"{name} (config)"


def relations_for(operator: Any, choice: Any) -> list[dict[str, Any]]:
    """Relation specs to check for ``operator``: every applicable one for ``auto``, else the
    chosen ones (names or ``{name, config}``) that apply to the operator's relation kind."""
    from lidarfuzz.oracles.relations.registry import for_operator, from_spec

    if choice == "auto":
        return [r.spec() for r in for_operator(operator.relation)]
    chosen = [from_spec(item if isinstance(item, str) else item.model_dump()) for item in choice]
    return [r.spec() for r in chosen if operator.relation in r.applies_to]


def _dataset_row(s: Any, ref: str, options: DatasetOptions | None = None) -> Dataset:
    """The data set a campaign names: a registered one, or a path (registered now, with
    ``options``). Options that change how a registered data set is read are refused: register
    it again under another name (lidarfuzz datasets add)."""
    from lidarfuzz.io.open import open_dataset
    from lidarfuzz.store.inventory import dataset_options

    given = (options or DatasetOptions()).resolved()
    row = s.scalar(select(Dataset).where(Dataset.name == ref))
    if row is None:
        path = Path(ref).expanduser()
        if not path.exists():
            raise StoreError(f"{ref}: neither a registered data set (lidarfuzz datasets list) nor a path")
        resolved = path.resolve()
        row = s.scalar(select(Dataset).where(Dataset.path == str(resolved)).order_by(Dataset.id))
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
    for field in ("layout", "intensity_scale", "roi_map"):
        value = getattr(given, field)
        if value is not None and value != getattr(stored, field):
            raise StoreError(f"data set {row.name!r} is registered with {field} {getattr(stored, field)!r}, not "
                             f"{value!r}; register it again under another name (lidarfuzz datasets add)")
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


def _model_row(s: Any, ref: str, options: dict[str, Any]) -> Model:
    row = s.scalar(select(Model).where(Model.name == ref))
    if row is not None:
        if options:
            raise StoreError(f"model {ref!r} is registered with its options; register another to change them")
        return row
    from lidarfuzz.suts.registry import create

    system = create(ref, **options)
    fingerprint = system.fingerprint()
    for candidate in s.scalars(select(Model).where(Model.spec == ref)):
        if candidate.fingerprint == fingerprint and candidate.options == options:
            return candidate
    name = ref if not options else f"{ref}#{fingerprint[:8]}"
    while s.scalar(select(Model).where(Model.name == name)) is not None:
        name = f"{ref}#{fingerprint[:8]}"
        if s.scalar(select(Model).where(Model.name == name)) is not None:
            name = f"{ref}#{fingerprint[:16]}"
            break
    row = Model(name=name, spec=ref, options=options, fingerprint=fingerprint, notes="registered by a campaign")
    s.add(row)
    s.flush()
    return row


def _check_searchable(model: Model) -> None:
    """A coverage-guided search hooks the SUT's ``torch.nn.Module``: refuse a SUT without one
    now, not when the task runs (the weights are not loaded to find out)."""
    from lidarfuzz.suts.registry import create

    system = create(model.spec, **model.options)
    if not hasattr(type(system), "module") and "module" not in vars(system):
        raise StoreError(f"a coverage-guided search needs a SUT built on a torch.nn.Module exposed as `.module`; "
                         f"model {model.name!r} ({type(system).__name__}) has none (e.g. --sut pillars)")


def create_task(store: Store, spec: CampaignSpec, *, sut_options: dict[str, Any] | None = None,
                isolate: bool = False, timeout: float = 60.0, save_mutants: str | None = None,
                dataset_options: DatasetOptions | None = None) -> int:
    """Plan ``spec`` as a new pending task; returns its id.

    ``dataset_options`` (the CLI's ``--layout``, ``--allow-unlabelled``) register a data set given
    by path; ``allow_unlabelled`` also lets a registered one run with frames that have no labels.
    """
    from lidarfuzz.operators.registry import get
    from lidarfuzz.store.inventory import dataset_options as stored_options
    from lidarfuzz.store.inventory import open_registered

    with store.session() as s:
        dataset = _dataset_row(s, spec.dataset, dataset_options)
        model = _model_row(s, spec.sut, dict(sut_options or {}))
        opened = open_registered(dataset)
        frame_ids = list(opened.frame_ids())
        if spec.frames is not None:
            frame_ids = frame_ids[: spec.frames]
        allow = stored_options(dataset).allow_unlabelled or bool(dataset_options and dataset_options.allow_unlabelled)
        unlabelled = unlabelled_frames(opened, frame_ids, allow, dataset.path)
        plans: list[tuple[dict[str, Any] | None, str, int, int, list[dict[str, Any]]]] = [
            (None, ORIGINAL, 0, -1, [])]
        search = spec.search_config() if spec.kind != "mutation" else None
        if search is not None:
            _check_searchable(model)
            # one subtask holds every generated test. Valid tests preserve labels, so the invariant
            # relations apply; "auto" means Zhou & Sun's MR1 (an object found before is found after)
            from lidarfuzz.oracles.relations.registry import from_spec as relation

            choice = spec.relations
            relation_specs = [relation("preservation").spec()] if choice == "auto" else relations_for(
                get("gaussian_noise_addition")(), choice)
            plans.append(({"name": search.kind, "search": search.model_dump(mode="json")}, search.kind, 0, 0,
                          relation_specs))
        for index, choice in enumerate([] if search is not None else spec.operators):
            cls = get(choice.name)
            if choice.config is not None:
                op = cls(**choice.config)
                plans.append((op.spec(), cls.name, 0, index, relations_for(op, spec.relations)))
                continue
            for severity in choice.severities:
                op = cls.at_severity(severity)
                plans.append((op.spec(), cls.name, severity, index, relations_for(op, spec.relations)))
        keys = [operator_key(p[0]) for p in plans]
        if len(set(keys)) != len(keys):
            raise StoreError("the campaign lists the same operator configuration twice")
        relations_json = spec.relations if spec.relations == "auto" else [
            r if isinstance(r, str) else r.model_dump() for r in spec.relations]
        options = {"frame_ids": frame_ids, "trials": spec.trials, "isolate": isolate, "timeout": timeout,
                   "save_mutants": save_mutants, "relations": relations_json, "kind": spec.kind}
        if unlabelled:
            options["unlabelled_frames"] = unlabelled  # run through the SUT, left out of AP
        if search is not None:
            options["search"] = search.model_dump(mode="json")
        task = Task(name=spec.name, dataset_id=dataset.id, model_id=model.id, seed=spec.seed, options=options,
                    operators=[c.model_dump(mode="json") for c in spec.operators],
                    relations=relations_json if isinstance(relations_json, list) else ["auto"])
        s.add(task)
        total = 0
        for (op_spec, name, severity, index, relations), key in zip(plans, keys, strict=True):
            units = len(frame_ids) * (1 if op_spec is None else spec.trials)
            if search is not None and op_spec is not None:
                units = search.budget
            total += units
            task.subtasks.append(Subtask(operator_key=key, operator=op_spec or {}, name=name, op_index=index,
                                         severity=severity, total=units,
                                         results={"relation_specs": relations}))
        task.total = total
        s.flush()
        return task.id


def _task(session: Any, task_id: int) -> Task:
    task = session.get(Task, task_id)
    if task is None:
        raise StoreError(f"no task {task_id} (lidarfuzz list)")
    return task


def get_task(store: Store, task_id: int) -> Task:
    """A task with its data set, model and subtasks loaded."""
    with store.session() as s:
        task = _task(s, task_id)
        task.dataset, task.model, list(task.subtasks)  # loaded before the session closes
        return task


def list_tasks(store: Store, limit: int | None = None, *, offset: int = 0,
               status: Status | str | None = None) -> list[Task]:
    """Tasks, newest first, with their data set and model loaded (the summary is not: it can be
    large, and a listing does not show it).

    Args:
        store: The campaign store.
        limit: At most this many (all when None or 0).
        offset: Skip the newest ``offset`` first (pages).
        status: Only tasks in this state.
    """
    with store.session() as s:
        query = select(Task).options(defer(Task.summary), joinedload(Task.dataset), joinedload(Task.model))
        if status is not None:
            query = query.where(Task.status == Status(status))
        query = query.order_by(Task.id.desc()).offset(offset or None)
        if limit:
            query = query.limit(limit)
        return list(s.scalars(query))


def count_tasks(store: Store, status: Status | str | None = None) -> int:
    """How many tasks there are (in ``status``, when given)."""
    with store.session() as s:
        query = select(func.count()).select_from(Task)
        if status is not None:
            query = query.where(Task.status == Status(status))
        return int(s.scalar(query) or 0)


def heartbeat_age(task: Task) -> float | None:
    """Seconds since the process running ``task`` last reported (None: it never did)."""
    moment = task.heartbeat_at
    if moment is None:
        return None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return (datetime.now(UTC) - moment).total_seconds()


def _process_gone(worker: str) -> bool:
    """True when ``worker`` (``host:pid``) names a process of this host that no longer exists."""
    host, _, pid = worker.rpartition(":")
    if host != socket.gethostname() or not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except OSError:  # exists, owned by someone else
        return False
    return False


def looks_alive(task: Task, stale_after: float = STALE_AFTER) -> bool:
    """Whether a process seems to be running ``task`` now: it is marked running, its worker
    reported within ``stale_after`` seconds, and (on this host) that process still exists.
    ``lidarfuzz resume`` and the web app's workers resume only tasks that do not look alive."""
    if task.status != Status.RUNNING:
        return False
    age = heartbeat_age(task)
    if age is None or age >= stale_after:
        return False
    return not _process_gone(task.worker)


def cancel_task(store: Store, task_id: int) -> Status:
    """Ask a task to stop: a running one stops at its next unit (what is done stays done)."""
    with store.session() as s:
        task = _task(s, task_id)
        if task.status in (Status.DONE, Status.FAILED, Status.CANCELLED):
            return task.status
        task.status = Status.CANCELLED
        return task.status


def delete_task(store: Store, task_id: int) -> None:
    with store.session() as s:
        task = _task(s, task_id)
        if task.status == Status.RUNNING:
            raise StoreError(f"task {task_id} is running; cancel it first (lidarfuzz cancel {task_id})")
        s.delete(task)
