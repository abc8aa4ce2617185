"""``/api/tasks``: list, create (a campaign spec), detail, live progress, stop, resume, delete."""

from __future__ import annotations

import math
import re
from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, HTTPException, Query, Request, status
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool

from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import (
    SORT_KEYS,
    TaskQuery,
    count_tasks,
    create_task,
    delete_task,
    get_task,
    list_tasks,
    subtask_label,
)
from lidarfuzz.store.contracts import APRecord, DeepTestErrors, RateRow, SearchProgress, TaskSummary, summary_schema
from lidarfuzz.store.inventory import list_datasets, list_models
from lidarfuzz.store.models import Status, Subtask, Task
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.events import FINAL, iso, progress_events, progress_snapshot
from lidarfuzz.web.security import check_model_spec
from lidarfuzz.web.security.ids import Offset, RowId

router = APIRouter(tags=["tasks"])
Web = Annotated[WebContext, Depends(web)]

CAMPAIGN_EXAMPLE = {"name": "fog-vs-classic", "dataset": "sim", "sut": "classic",
                    "operators": [{"name": "fog", "severities": [1, 3, 5]}], "relations": "auto", "seed": 0,
                    "frames": 10}


# -- what the API sends: the front end reads these models' JSON Schema (GET /api/schemas/task) ------
class Reply(BaseModel):
    model_config = ConfigDict(extra="forbid")


class TaskRow(Reply):
    """A task as the list shows it."""

    id: int
    name: str
    status: Status
    kind: str
    dataset: str
    model: str
    operator_count: int
    done: int
    total: int
    seed: int
    created_at: str | None
    started_at: str | None
    finished_at: str | None
    error: str
    tags: list[str] = Field(default_factory=list, description="the user's labels (PATCH /api/tasks/{id})")
    notes: str = Field(default="", description="the user's notes (PATCH /api/tasks/{id})")
    headline: dict[str, float | int | None] | None = Field(
        default=None, description="a finished task's figures the list sorts by (lidarfuzz.campaign.headline): map "
                                  "(originals, 3D moderate AP|R40), delta_map (the worst over the mutants), "
                                  "violations, checked, violation_rate, failures (the system's), ap_warnings "
                                  "(how many small-sample warnings its AP carries)")


#: A tag: letters, digits and . _ : + - (no spaces: the list filters by whole tags), 1 to 32 characters.
TAG_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._:+-]{0,31}")
MAX_TAGS = 20
MAX_NOTES = 10_000


class TaskEdit(BaseModel):
    """What ``PATCH /api/tasks/{id}`` changes: the user's tags and notes (either or both)."""

    model_config = ConfigDict(extra="forbid")

    tags: list[str] | None = Field(default=None, max_length=MAX_TAGS,
                                   description=f"at most {MAX_TAGS}, each {TAG_PATTERN.pattern}")
    notes: str | None = Field(default=None, max_length=MAX_NOTES)


class SubtaskRow(Reply):
    """A subtask in the task's detail: its progress and, once complete, its figures."""

    id: int
    name: str
    label: str
    severity: int
    status: Status
    done: int
    total: int
    operator: dict[str, Any]
    relations: list[str]
    ap_moderate: dict[str, dict[str, float | None]] | None = Field(
        description="AP|R40 at moderate difficulty: metric → class (and mAP) → AP in percent")
    ap: APRecord | None
    ap_note: str | None = Field(default=None, description="why the subtask has no AP (None: it has one, or is "
                                                          "not complete)")
    sample_warnings: list[str] = Field(
        default_factory=list, description="why its AP may not mean what it seems: one frame, or a class with fewer "
                                          "objects than KITTI's figures need (oracles.kitti_eval.MIN_RELIABLE_OBJECTS)")
    violations: list[RateRow]
    failures: int = Field(description="the system under test's failures: crashes, timeouts, invalid outputs")
    tool_errors: dict[str, int] = Field(
        default_factory=dict, description="lidarfuzz's own errors, never blamed on the system: operator_error (the "
                                          "operator raised on a frame), oracle_error (a relation raised)")
    frames: int
    started_at: str | None = None
    finished_at: str | None = None
    deeptest: DeepTestErrors | None = Field(
        default=None, description="a camera task's transformation: its MSE_t, Eq. 2 violations and Eq. 3's verdict")
    search: SearchProgress | None = Field(default=None, description="a search's coverage and counters so far")


class RunningSubtask(Reply):
    """The subtask running now (:func:`lidarfuzz.web.events.progress_snapshot`)."""

    id: int
    label: str
    done: int
    total: int


class TaskDetail(TaskRow):
    """A task, its subtasks, the subtask running now and, once it is done, its summary."""

    model_config = ConfigDict(json_schema_extra={"x-final-statuses": [s.value for s in FINAL]})

    dataset_path: str
    model_spec: str
    fingerprint: str
    relations: list[Any]
    operators: list[Any]
    trials: int
    frames: int
    search: dict[str, Any] | None = Field(description="a search task's configuration (None: not a search)")
    worker: str
    heartbeat_at: str | None
    running: RunningSubtask | None
    subtasks: list[SubtaskRow]
    summary: TaskSummary | None
    queued: bool
    resumable: bool = Field(default=False, description="Resume would queue it: cancelled, failed, or interrupted "
                                                       "(its process gone), and not queued or run now")
    loading: bool = Field(default=False, description="running, and the system under test is still loading (this "
                                                     "server's run has finished no unit yet)")
    modality: str = Field(description="what its data holds: lidar (point clouds) or camera (images)")
    camera: dict[str, Any] | None = Field(
        default=None, description="a camera task's MSE_orig, labelled and tested images and the seed images' "
                                  "coverage (lidarfuzz.campaign.camera.kind_summary), as soon as the originals ran")


def task_schema() -> dict[str, Any]:
    """The JSON Schema of the task-detail reply (its ``summary``: :func:`summary_schema`);
    ``x-final-statuses`` lists the statuses a task ends in."""
    return TaskDetail.model_json_schema(mode="serialization", by_alias=True)


def _row_fields(task: Task) -> dict[str, Any]:
    return {"id": task.id, "name": task.name, "status": task.status, "kind": task.options.kind,
            "dataset": task.dataset.name, "model": task.model.name, "operator_count": len(task.operators or []),
            "done": task.done, "total": task.total, "seed": task.seed, "created_at": iso(task.created_at),
            "started_at": iso(task.started_at), "finished_at": iso(task.finished_at), "error": task.error,
            "tags": list(task.tags or []), "notes": task.notes or "", "headline": task.headline}


def task_row(task: Task) -> dict[str, Any]:
    """A task as the list shows it."""
    return TaskRow.model_validate(_row_fields(task)).model_dump(mode="json")


def _finite(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else value


def _moderate(ap: APRecord | None) -> dict[str, dict[str, float | None]] | None:
    """AP|R40 at moderate difficulty per metric: each class and the mAP (the figure 5-14 lines)."""
    if ap is None:
        return None
    out: dict[str, dict[str, float | None]] = {}
    for metric, classes in ap.ap.items():
        row = {cls: _finite(table.get("moderate", {}).get("R40")) for cls, table in classes.items()}
        row["mAP"] = _finite(ap.map.get(metric, {}).get("moderate", {}).get("R40"))
        out[metric] = row
    return out


def _sample_warnings(ap: APRecord | None) -> list[str]:
    from lidarfuzz.campaign.results import ap_result

    result = ap_result(ap)
    return result.sample_warnings() if result is not None else []


def _subtask_row(sub: Subtask) -> SubtaskRow:
    results = sub.results
    return SubtaskRow(id=sub.id, name=sub.name, label=subtask_label(sub.name, sub.severity), severity=sub.severity,
                      status=sub.status, done=sub.done, total=sub.total, operator=sub.operator,
                      relations=sub.plan.relation_names, ap_moderate=_moderate(results.ap), ap=results.ap,
                      ap_note=results.ap_note, sample_warnings=_sample_warnings(results.ap),
                      violations=results.violations_total, failures=results.failures,
                      tool_errors=results.tool_errors, frames=results.frames, started_at=iso(sub.started_at),
                      finished_at=iso(sub.finished_at), deeptest=results.deeptest, search=results.search)


def _camera_figures(ctx: WebContext, task: Task) -> dict[str, Any] | None:
    from lidarfuzz.campaign.camera import kind_summary

    if not any(sub.name == "original" for sub in task.subtasks):
        return None
    return kind_summary(ctx.store, task)


@router.get("/tasks")
def tasks_list(ctx: Web, limit: Annotated[int, Query(ge=1, le=500)] = 50, offset: Offset = 0,
               status_: Annotated[Status | None, Query(alias="status")] = None,
               q: Annotated[str, Query(max_length=200, description="in the name, data set, model, status, tags or "
                                                                   "notes (any case)")] = "",
               tag: Annotated[list[str], Query(description="only tasks with every one of these tags")] = [],  # noqa: B006
               sort: Annotated[str, Query(description=f"one of {', '.join(SORT_KEYS)}; - first for descending")]
               = "-id") -> dict[str, Any]:
    """Tasks, newest first or as ``sort`` says (a task without the figure last), filtered by status,
    text and tags, all in SQL: ``{"items": [...], "total", "limit", "offset"}``."""
    if sort.lstrip("-+") not in SORT_KEYS:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"query: field 'sort': {sort!r} is not one of {', '.join(SORT_KEYS)} (- first: descending)")
    spec = TaskQuery(status=status_, text=q, tags=tuple(tag), sort=sort)
    rows = list_tasks(ctx.store, limit, offset=offset, query=spec)
    return {"items": [task_row(t) for t in rows], "total": count_tasks(ctx.store, query=spec), "limit": limit,
            "offset": offset}


def _check_tags(tags: list[str]) -> list[str]:
    """The tags, each checked (a 422 naming ``tags.N``), duplicates dropped, order kept."""
    for index, tag in enumerate(tags):
        if not TAG_PATTERN.fullmatch(tag):
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"request body: field 'tags.{index}': {tag[:40]!r} is not a tag: 1 to 32 letters, "
                                "digits or . _ : + - (starting with a letter or digit)")
    return list(dict.fromkeys(tags))


@router.patch("/tasks/{task_id}", responses={200: {"model": TaskRow}})
def tasks_edit(ctx: Web, task_id: RowId, body: TaskEdit) -> dict[str, Any]:
    """Change a task's tags or notes (the user's, whatever its state); returns its row."""
    tags = _check_tags(body.tags) if body.tags is not None else None
    with ctx.store.session() as s:
        row = s.get(Task, task_id)
        if row is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no task {task_id}")
        if tags is not None:
            row.tags = tags
        if body.notes is not None:
            row.notes = body.notes
    return task_row(get_task(ctx.store, task_id))


def _check_order(field: str, row: Any) -> None:
    """A structural campaign's field-test log must have an order (a 422 naming the field, not the
    server path the engine would name)."""
    from lidarfuzz.errors import DataFormatError
    from lidarfuzz.store.inventory import dataset_options
    from lidarfuzz.structural.logs import open_log

    try:
        open_log(row.path, options=dataset_options(row))
    except DataFormatError as exc:
        hint = f" ({exc.hint})" if exc.hint else ""
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"request body: field '{field}': data set {row.name!r}: {exc.message}{hint}; "
                            f"GET /api/datasets/logs lists the logs") from None


def _check_references(ctx: WebContext, spec: Any) -> None:
    """The API runs campaigns on registered data sets only (no server paths), and on registered
    models or specs the API may register."""
    rows = {d.name: d for d in list_datasets(ctx.store)}
    for field, name in [("dataset", spec.dataset), *((f"logs.{i}", log) for i, log in enumerate(spec.logs))]:
        if name not in rows:  # a structural campaign's further field-test logs pass the same check
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"request body: field '{field}': no data set named {name!r} "
                                f"(GET /api/datasets lists them; upload or generate one first)")
        if spec.kind == "structural":
            _check_order(field, rows[name])
    models = {m.name for m in list_models(ctx.store)}
    if spec.sut not in models:
        check_model_spec(spec.sut, ctx.uploads, field="sut")
    for index, reference in enumerate(spec.reference):  # reference systems pass the same check
        if reference not in models:
            check_model_spec(reference, ctx.uploads, field=f"reference.{index}")


@router.post("/tasks", status_code=status.HTTP_201_CREATED)
async def tasks_create(ctx: Web, body: Annotated[dict[str, Any], Body(examples=[CAMPAIGN_EXAMPLE])]) -> dict[str, Any]:
    """Create a task from a campaign spec (the keys of a campaign file: ``lidarfuzz run CAMPAIGN``)
    and queue it for the workers. A bad key is a 422 naming it."""
    spec = parse_campaign(body, "request body")
    _check_references(ctx, spec)
    task_id = await run_in_threadpool(create_task, ctx.store, spec)
    for reference in get_task(ctx.store, task_id).options.references:  # a campaign's reference systems
        ctx.workers.submit(reference)
    ctx.workers.submit(task_id)
    return {"id": task_id, "status": Status.PENDING.value}


@router.get("/tasks/{task_id}", responses={200: {"model": TaskDetail}})
def tasks_detail(ctx: Web, task_id: RowId) -> dict[str, Any]:
    """A task, its subtasks (with AP; a camera task's: MSE_t and Eq. 3, and the search's coverage), the
    subtask running now, its summary and error, what its data holds (``modality``) and a camera task's
    MSE_orig (the reply's JSON Schema: ``GET /api/schemas/task``)."""
    from lidarfuzz.campaign.kinds import find_kind

    task = get_task(ctx.store, task_id)
    progress = progress_snapshot(ctx.store, task_id, ctx.workers.loading) or {}
    options = task.options
    kind = find_kind(options.kind)
    modality = kind.modality if kind is not None else "lidar"
    detail = TaskDetail.model_validate({
        **_row_fields(task), "dataset_path": task.dataset.path, "model_spec": task.model.spec,
        "fingerprint": task.model.fingerprint, "relations": task.relations, "operators": task.operators,
        "trials": options.trials, "frames": len(options.frame_ids), "search": options.kind_options or None,
        "worker": task.worker, "heartbeat_at": iso(task.heartbeat_at), "running": progress.get("running"),
        "subtasks": [_subtask_row(sub) for sub in task.subtasks], "summary": task.summary,
        "queued": ctx.workers.is_active(task_id), "loading": bool(progress.get("loading")),
        "resumable": ctx.workers.resumable(task), "modality": modality,
        "camera": _camera_figures(ctx, task) if modality == "camera" else None})
    return detail.model_dump(mode="json", by_alias=True)


@router.get("/schemas/summary", tags=["schemas"])
def schemas_summary() -> dict[str, Any]:
    """The JSON Schema of a task's summary (:class:`lidarfuzz.store.contracts.TaskSummary`): what
    ``summary`` in ``GET /api/tasks/{id}`` and ``report.json`` hold."""
    return summary_schema()


@router.get("/schemas/task", tags=["schemas"])
def schemas_task() -> dict[str, Any]:
    """The JSON Schema of ``GET /api/tasks/{id}`` (its ``summary``: ``GET /api/schemas/summary``);
    ``x-final-statuses`` lists the statuses a task ends in. The front end reads it."""
    return task_schema()


@router.get("/tasks/{task_id}/events", response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {}},
                             "description": "`progress` events, then one `end` event"}})
async def tasks_events(ctx: Web, task_id: RowId, request: Request) -> StreamingResponse:
    """Server-sent events: ``progress`` whenever the task's counters or status change, then ``end``."""
    get_task(ctx.store, task_id)  # 404 before the stream starts
    return StreamingResponse(progress_events(ctx.store, task_id, request.is_disconnected,
                                             loading=ctx.workers.loading),
                             media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


class ActionReply(Reply):
    """What a stop or resume did: the task's status now, whether the action was refused, and a
    sentence saying what happened (or why not) that a page shows as it is."""

    id: int
    status: Status
    refused: bool
    message: str


@router.post("/tasks/{task_id}/stop", response_model=ActionReply)
def tasks_stop(ctx: Web, task_id: RowId) -> ActionReply:
    """Cancel cleanly (what ``lidarfuzz cancel`` does): a running task stops within a second."""
    get_task(ctx.store, task_id)
    now = ctx.workers.stop(task_id)
    if now != Status.CANCELLED:
        return ActionReply(id=task_id, status=now, refused=True,
                           message=f"Task #{task_id} is {now.value}: there is nothing to stop.")
    return ActionReply(id=task_id, status=now, refused=False,
                       message=f"Task #{task_id} stopped: what is done is kept; Resume goes on from there.")


@router.post("/tasks/{task_id}/resume", response_model=ActionReply)
def tasks_resume(ctx: Web, task_id: RowId) -> ActionReply:
    """Queue a cancelled, failed or interrupted task again; only units without a result run."""
    now = ctx.workers.resume(task_id)
    if now == Status.PENDING and ctx.workers.is_active(task_id):
        return ActionReply(id=task_id, status=now, refused=False,
                           message=f"Task #{task_id} is queued again: only the units without a result run.")
    why = {Status.DONE: "it is done, nothing is left to run",
           Status.RUNNING: "it runs already"}.get(now, "it is queued already")
    return ActionReply(id=task_id, status=now, refused=True, message=f"Resume refused: task #{task_id} {why}.")


@router.delete("/tasks/{task_id}", status_code=status.HTTP_204_NO_CONTENT)
async def tasks_delete(ctx: Web, task_id: RowId) -> None:
    """Delete a task and its results (stopping it first when this server runs it)."""
    get_task(ctx.store, task_id)
    if ctx.workers.is_active(task_id):
        ctx.workers.stop(task_id)
        await run_in_threadpool(ctx.workers.wait_stopped, task_id)
    await run_in_threadpool(delete_task, ctx.store, task_id)
    from lidarfuzz.web.security import remove_tree

    remove_tree(ctx.reports / f"task-{task_id}", ctx.reports)
