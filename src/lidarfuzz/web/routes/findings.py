"""``/api/tasks/{id}/findings`` (filtered, paged) and ``/api/findings/{id}`` (one, with its replay record)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query, status
from sqlalchemy import func, select

from lidarfuzz.campaign.tasks import get_task, subtask_label
from lidarfuzz.store.models import Finding, FrameResult, Subtask
from lidarfuzz.web.context import WebContext, web

router = APIRouter(tags=["findings"])
Web = Annotated[WebContext, Depends(web)]


def _row(finding: Finding, frame_id: str, trial: int, name: str, severity: int) -> dict[str, Any]:
    return {"id": finding.id, "task_id": finding.task_id, "kind": finding.kind, "relation": finding.kind,
            "class": finding.cls, "operator": name, "severity": severity, "label": subtask_label(name, severity),
            "frame_id": frame_id, "trial": trial, "magnitude": finding.magnitude, "message": finding.message}


def _base() -> Any:
    return (select(Finding, FrameResult.frame_id, FrameResult.trial, Subtask.name, Subtask.severity)
            .join(FrameResult, Finding.frame_result_id == FrameResult.id)
            .join(Subtask, FrameResult.subtask_id == Subtask.id))


@router.get("/tasks/{task_id}/findings")
def findings_list(ctx: Web, task_id: int, relation: str | None = None, operator: str | None = None,
                  cls: str | None = None, limit: Annotated[int, Query(ge=1, le=1000)] = 100,
                  offset: Annotated[int, Query(ge=0)] = 0) -> dict[str, Any]:
    """Findings of a task, in id order, filtered by relation (or failure kind), operator and class:
    ``{"items", "total", "limit", "offset", "facets": {"relation", "operator", "class"}}`` — the facets
    list the values each filter can take."""
    get_task(ctx.store, task_id)
    where = [Finding.task_id == task_id]
    if relation:
        where.append(Finding.kind == relation)
    if operator:
        where.append(Subtask.name == operator)
    if cls is not None and cls != "":
        where.append(Finding.cls == cls)
    with ctx.store.session() as s:
        rows = s.execute(_base().where(*where).order_by(Finding.id).limit(limit).offset(offset)).all()
        total = s.scalar(select(func.count()).select_from(Finding).join(
            FrameResult, Finding.frame_result_id == FrameResult.id).join(
            Subtask, FrameResult.subtask_id == Subtask.id).where(*where)) or 0
        facets = s.execute(select(Finding.kind, Subtask.name, Finding.cls).join(
            FrameResult, Finding.frame_result_id == FrameResult.id).join(
            Subtask, FrameResult.subtask_id == Subtask.id).where(Finding.task_id == task_id).distinct()).all()
        items = [_row(*row) for row in rows]
    return {"items": items, "total": int(total), "limit": limit, "offset": offset,
            "facets": {"relation": sorted({f[0] for f in facets}), "operator": sorted({f[1] for f in facets}),
                       "class": sorted({f[2] for f in facets})}}


@router.get("/findings/{finding_id}")
def findings_detail(ctx: Web, finding_id: int) -> dict[str, Any]:
    """One finding: what was violated (its detail), and its replay record (seed, operator spec and
    params, frame, system and fingerprint); ``lidarfuzz replay ID`` re-runs it."""
    with ctx.store.session() as s:
        row = s.execute(_base().where(Finding.id == finding_id)).first()
        if row is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no finding {finding_id}")
        out = _row(*row)
        finding = row[0]
        out.update(detail=finding.detail, replay=finding.replay.dump(), replay_command=f"lidarfuzz replay {finding.id}",
                   frames=f"/api/findings/{finding.id}/frames")
    return out
