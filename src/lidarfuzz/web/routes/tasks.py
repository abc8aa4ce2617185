"""``/api/tasks``: list, create (a campaign spec), detail, live progress, stop, resume, delete."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, HTTPException, Query, Request, status
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import count_tasks, create_task, delete_task, get_task, list_tasks, subtask_label
from lidarfuzz.store.inventory import list_datasets, list_models
from lidarfuzz.store.models import Status, Task
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.events import iso, progress_events, progress_snapshot
from lidarfuzz.web.security import check_model_spec

router = APIRouter(tags=["tasks"])
Web = Annotated[WebContext, Depends(web)]

CAMPAIGN_EXAMPLE = {"name": "fog-vs-classic", "dataset": "sim", "sut": "classic",
                    "operators": [{"name": "fog", "severities": [1, 3, 5]}], "relations": "auto", "seed": 0,
                    "frames": 10}


def task_row(task: Task) -> dict[str, Any]:
    """A task as the list shows it."""
    options = task.options or {}
    return {"id": task.id, "name": task.name, "status": Status(task.status).value,
            "kind": options.get("kind", "mutation"), "dataset": task.dataset.name, "model": task.model.name,
            "operator_count": len(task.operators or []), "done": task.done, "total": task.total, "seed": task.seed,
            "created_at": iso(task.created_at), "started_at": iso(task.started_at),
            "finished_at": iso(task.finished_at), "error": task.error}


def _moderate(ap: dict[str, Any] | None) -> dict[str, Any] | None:
    """AP|R40 at moderate difficulty per metric: each class and the mAP (the figure 5-14 lines)."""
    if not ap:
        return None
    out: dict[str, Any] = {}
    for metric, classes in ap.get("ap", {}).items():
        row = {cls: table.get("moderate", {}).get("R40") for cls, table in classes.items()}
        row["mAP"] = ap.get("map", {}).get(metric, {}).get("moderate", {}).get("R40")
        out[metric] = row
    return out


@router.get("/tasks")
def tasks_list(ctx: Web, limit: Annotated[int, Query(ge=1, le=500)] = 50, offset: Annotated[int, Query(ge=0)] = 0,
               status_: Annotated[Status | None, Query(alias="status")] = None) -> dict[str, Any]:
    """Tasks, newest first: ``{"items": [...], "total", "limit", "offset"}``."""
    rows = list_tasks(ctx.store, limit, offset=offset, status=status_)
    return {"items": [task_row(t) for t in rows], "total": count_tasks(ctx.store, status_), "limit": limit,
            "offset": offset}


def _check_references(ctx: WebContext, spec: Any) -> None:
    """The API runs campaigns on registered data sets only (no server paths), and on registered
    models or specs the API may register."""
    if spec.dataset not in {d.name for d in list_datasets(ctx.store)}:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"request body: field 'dataset': no data set named {spec.dataset!r} "
                            f"(GET /api/datasets lists them; upload or generate one first)")
    if spec.sut not in {m.name for m in list_models(ctx.store)}:
        check_model_spec(spec.sut, ctx.uploads, field="sut")


@router.post("/tasks", status_code=status.HTTP_201_CREATED)
async def tasks_create(ctx: Web, body: Annotated[dict[str, Any], Body(examples=[CAMPAIGN_EXAMPLE])]) -> dict[str, Any]:
    """Create a task from a campaign spec (the keys of a campaign file: ``lidarfuzz run CAMPAIGN``)
    and queue it for the workers. A bad key is a 422 naming it."""
    spec = parse_campaign(body, "request body")
    _check_references(ctx, spec)
    task_id = await run_in_threadpool(create_task, ctx.store, spec)
    ctx.workers.submit(task_id)
    return {"id": task_id, "status": Status.PENDING.value}


@router.get("/tasks/{task_id}")
def tasks_detail(ctx: Web, task_id: int) -> dict[str, Any]:
    """A task, its subtasks (with AP), the subtask running now, its summary and error."""
    task = get_task(ctx.store, task_id)
    progress = progress_snapshot(ctx.store, task_id) or {}
    subtasks = []
    for sub in task.subtasks:
        results = {k: v for k, v in (sub.results or {}).items() if k != "relation_specs"}
        subtasks.append({"id": sub.id, "name": sub.name, "label": subtask_label(sub.name, sub.severity),
                         "severity": sub.severity, "status": Status(sub.status).value, "done": sub.done,
                         "total": sub.total, "operator": sub.operator,
                         "relations": [r.get("name") for r in (sub.results or {}).get("relation_specs", [])],
                         "ap_moderate": _moderate(results.get("ap")), "ap": results.get("ap"),
                         "violations": results.get("violations_total", []), "failures": results.get("failures"),
                         "frames": results.get("frames")})
    options = task.options or {}
    return {**task_row(task), "dataset_path": task.dataset.path, "model_spec": task.model.spec,
            "fingerprint": task.model.fingerprint, "relations": task.relations, "operators": task.operators,
            "trials": options.get("trials", 1), "frames": len(options.get("frame_ids", [])),
            "search": options.get("search"), "worker": task.worker, "heartbeat_at": iso(task.heartbeat_at),
            "running": progress.get("running"), "subtasks": subtasks, "summary": task.summary or None,
            "queued": ctx.workers.is_active(task_id)}


@router.get("/tasks/{task_id}/events", response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {}},
                             "description": "`progress` events, then one `end` event"}})
async def tasks_events(ctx: Web, task_id: int, request: Request) -> StreamingResponse:
    """Server-sent events: ``progress`` whenever the task's counters or status change, then ``end``."""
    get_task(ctx.store, task_id)  # 404 before the stream starts
    return StreamingResponse(progress_events(ctx.store, task_id, request.is_disconnected),
                             media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


@router.post("/tasks/{task_id}/stop")
def tasks_stop(ctx: Web, task_id: int) -> dict[str, Any]:
    """Cancel cleanly (what ``lidarfuzz cancel`` does): a running task stops within a second."""
    get_task(ctx.store, task_id)
    return {"id": task_id, "status": ctx.workers.stop(task_id).value}


@router.post("/tasks/{task_id}/resume")
def tasks_resume(ctx: Web, task_id: int) -> dict[str, Any]:
    """Queue a cancelled, failed or interrupted task again; only units without a result run."""
    return {"id": task_id, "status": ctx.workers.resume(task_id).value}


@router.delete("/tasks/{task_id}", status_code=status.HTTP_204_NO_CONTENT)
async def tasks_delete(ctx: Web, task_id: int) -> None:
    """Delete a task and its results (stopping it first when this server runs it)."""
    get_task(ctx.store, task_id)
    if ctx.workers.is_active(task_id):
        ctx.workers.stop(task_id)
        await run_in_threadpool(ctx.workers.wait_stopped, task_id)
    await run_in_threadpool(delete_task, ctx.store, task_id)
    from lidarfuzz.web.security import remove_tree

    remove_tree(ctx.reports / f"task-{task_id}", ctx.reports)
