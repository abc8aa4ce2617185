"""A task's report and its exports, written by :mod:`lidarfuzz.report` and cached per task.

The files go to ``<workspace>/reports/task-N/`` (where ``lidarfuzz report`` puts them) and are
written again when the task changed since (its status, units done or finish time). The HTML
report (with its bird's-eye pictures: seconds) is written only when asked for; the exports
(JSON, CSV, JUnit XML) are cheap and written on their own.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, status
from fastapi.responses import FileResponse, HTMLResponse
from starlette.concurrency import run_in_threadpool

from lidarfuzz.campaign.tasks import get_task
from lidarfuzz.io.atomic import write_text
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.security.ids import RowId

router = APIRouter(tags=["reports"])
Web = Annotated[WebContext, Depends(web)]
STATE = ".web-report.json"
REPORT_POLICY = "sandbox allow-scripts allow-popups allow-popups-to-escape-sandbox allow-downloads"
EXPORTS = {"report.json": "application/json", "ap.csv": "text/csv", "delta_ap.csv": "text/csv",
           "violations.csv": "text/csv", "findings.csv": "text/csv", "ratings.csv": "text/csv",
           "junit.xml": "application/xml"}


def _key(ctx: WebContext, task_id: int) -> str:
    """What the report depends on: the task's state and its raters' verdicts (count, latest time)."""
    from sqlalchemy import func, select

    from lidarfuzz.store.models import Rating

    task = get_task(ctx.store, task_id)
    with ctx.store.session() as s:
        verdicts = s.execute(select(func.count(Rating.id), func.max(Rating.rated_at)).where(
            Rating.task_id == task_id)).one()
    return "|".join(str(v) for v in (task.created_at, task.status, task.done, task.finished_at, *verdicts))


def _fresh(folder: Path, part: str, key: str) -> bool:
    try:
        state = json.loads((folder / STATE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return bool(state.get(part) == key)


def _remember(folder: Path, part: str, key: str) -> None:
    path = folder / STATE
    try:
        state = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        state = {}
    state[part] = key
    if part == "html":
        state["exports"] = key  # write_report writes the exports too
    write_text(path, json.dumps(state), overwrite=True)


def ensure(ctx: WebContext, task_id: int, part: str) -> Path:
    """The task's report folder with ``part`` (``html`` or ``exports``) up to date."""
    folder = ctx.reports / f"task-{task_id}"
    with ctx.lock(f"report-{task_id}"):
        key = _key(ctx, task_id)
        if _fresh(folder, part, key):
            return folder
        folder.mkdir(parents=True, exist_ok=True)
        if part == "html":
            from lidarfuzz.report import write_report

            write_report(ctx.store, task_id, folder)
        else:
            _write_exports(ctx, task_id, folder)
        _remember(folder, part, key)
    return folder


def _write_exports(ctx: WebContext, task_id: int, folder: Path) -> None:
    """``report.json``, the CSV files and ``junit.xml`` — :func:`lidarfuzz.report.write_report`
    without the HTML page and its pictures."""
    from lidarfuzz.campaign.ratings import tally
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.report.exports import finding_rows, junit_from_results, write_csvs, write_json
    from lidarfuzz.report.gates import evaluate
    from lidarfuzz.report.ratings import write_ratings_csv

    summary = summarise(ctx.store, task_id)
    write_json(summary, folder / "report.json")
    write_csvs(summary, folder, finding_rows(ctx.store, task_id))
    write_ratings_csv(tally(ctx.store, task_id), folder / "ratings.csv")
    write_text(folder / "junit.xml", junit_from_results(summary, evaluate(summary, [])), overwrite=True)


@router.get("/tasks/{task_id}/report", response_class=FileResponse,
            responses={200: {"content": {"text/html": {}}, "description": "the self-contained HTML report"}})
async def report_html(ctx: Web, task_id: RowId) -> FileResponse:
    """The HTML report (``lidarfuzz report``), written on demand and cached until the task changes."""
    folder = await run_in_threadpool(ensure, ctx, task_id, "html")
    # opened in its own tab it runs in an opaque origin: its scripts never see the app's token
    return FileResponse(folder / "report.html", media_type="text/html",
                        headers={"Cache-Control": "no-cache", "Content-Security-Policy": REPORT_POLICY})


def _structural_page(ctx: WebContext, task_id: int) -> str:
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.report.structural import section_html

    page = section_html(summarise(ctx.store, task_id))
    if page is None:
        raise HTTPException(status.HTTP_409_CONFLICT, f"task {task_id} is not a structural task")
    return page


@router.get("/tasks/{task_id}/structural", response_class=HTMLResponse,
            responses={200: {"content": {"text/html": {}}, "description": "a structural task's tables and views"},
                       409: {"description": "not a structural task"}})
async def structural_html(ctx: Web, task_id: RowId) -> HTMLResponse:
    """A structural task's coverage tables (Neves et al.'s form), coverage per module/class/function,
    annotated source, control-flow graphs and logs side by side: the report's section as a page
    (what the task page embeds), from what is stored now."""
    page = await run_in_threadpool(_structural_page, ctx, task_id)
    return HTMLResponse(page, headers={"Cache-Control": "no-cache", "Content-Security-Policy": REPORT_POLICY})


def _export_route(name: str, media_type: str) -> None:
    async def export(ctx: Web, task_id: RowId) -> FileResponse:
        folder = await run_in_threadpool(ensure, ctx, task_id, "exports")
        return FileResponse(folder / name, media_type=media_type, filename=f"task-{task_id}-{name}",
                            headers={"Cache-Control": "no-cache"})

    export.__name__ = f"export_{name.replace('.', '_')}"
    export.__doc__ = f"The task's ``{name}`` (see lidarfuzz.report.exports)."
    router.add_api_route(f"/tasks/{{task_id}}/{name}", export, methods=["GET"], response_class=FileResponse,
                         responses={200: {"content": {media_type: {}}}})


for _name, _type in EXPORTS.items():
    _export_route(_name, _type)


