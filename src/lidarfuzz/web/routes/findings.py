"""``/api/tasks/{id}/findings`` (filtered, paged) and ``/api/findings/{id}`` (one, with its replay record)."""

from __future__ import annotations

import math
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


def task_modality(ctx: WebContext, task_id: int) -> str:
    """``lidar`` or ``camera``: what the data of a task's kind holds."""
    from lidarfuzz.campaign.kinds import find_kind

    kind = find_kind(get_task(ctx.store, task_id).options.kind)
    return kind.modality if kind is not None else "lidar"


def _neighbours(s: Any, finding: Finding) -> tuple[int | None, int | None]:
    """The ids of the task's findings just before and after this one (id order, as the list)."""
    before = s.scalar(select(func.max(Finding.id)).where(Finding.task_id == finding.task_id, Finding.id < finding.id))
    after = s.scalar(select(func.min(Finding.id)).where(Finding.task_id == finding.task_id, Finding.id > finding.id))
    return before, after


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else None


def steering_figures(finding: Finding, subtask: Subtask, result: FrameResult) -> dict[str, Any]:
    """What a camera finding's page shows: the label and both predictions, the squared error against
    λ·MSE_orig (Eq. 2) and the transformation's MSE_t against MSE_orig at ε (Eq. 3's verdict:
    ``kept``, ``filtered_out`` or ``not_filtered`` for a composite transformation or a search's chain).
    The figures are the violated relation's outcome on the image, as stored with its result (a
    transformation's finding also copies them into its detail; a search's does not)."""
    outcome = next((o for o in result.relations or [] if o.relation == finding.kind), None)
    stats = dict((finding.detail or {}).get("stats") or (outcome.stats if outcome is not None else {}) or {})
    errors = [e for e in stats.get("squared_errors") or [] if isinstance(e, int | float)]
    lam, mse_orig = _number(stats.get("lambda")), _number(stats.get("mse_orig"))
    out: dict[str, Any] = {
        "label": _number(stats.get("label")), "prediction": _number(stats.get("prediction")),
        "original_prediction": _number(stats.get("original_prediction")),
        "squared_error": _number(errors[0]) if errors else None, "lambda": lam, "mse_orig": mse_orig,
        "threshold": lam * mse_orig if lam is not None and mse_orig is not None else None,
        "epsilon": _number(stats.get("epsilon")), "mse_t": None, "difference": None, "eq3": None}
    deeptest = subtask.results.deeptest
    if deeptest is not None:
        mse = _number(deeptest.mse)
        out["mse_t"] = mse
        out["difference"] = mse - mse_orig if mse is not None and mse_orig is not None else None
        out["eq3"] = ("not_filtered" if not deeptest.filtered else "kept" if deeptest.kept else "filtered_out")
    elif "filtered" in stats:
        out["eq3"] = None if stats["filtered"] else "not_filtered"
    return out


@router.get("/findings/{finding_id}")
def findings_detail(ctx: Web, finding_id: int) -> dict[str, Any]:
    """One finding: what was violated (its detail), its replay record (seed, operator spec and
    params, frame, system and fingerprint; ``lidarfuzz replay ID`` re-runs it), the ids of the task's
    previous and next findings, and where its pictures are: ``frames`` (the LiDAR frames, LFZ1) or,
    for a camera task, ``picture`` (original | transformed, PNG) and ``steering`` (the figures Eq. 2
    and Eq. 3 judged, :func:`steering_figures`)."""
    with ctx.store.session() as s:
        row = s.execute(_base().add_columns(Subtask, FrameResult).where(Finding.id == finding_id)).first()
        if row is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no finding {finding_id}")
        out = _row(*row[:5])
        finding, subtask, result = row[0], row[5], row[6]
        previous, following = _neighbours(s, finding)
        modality = task_modality(ctx, finding.task_id)
        out.update(detail=finding.detail, replay=finding.replay.dump(), replay_command=f"lidarfuzz replay {finding.id}",
                   modality=modality, previous=previous, next=following,
                   frames=f"/api/findings/{finding.id}/frames" if modality == "lidar" else None)
        if modality == "camera":
            out.update(picture=f"/api/findings/{finding.id}/pair.png",
                       steering=steering_figures(finding, subtask, result),
                       operator_params=finding.replay.params, chain=subtask.name == "guided")
    return out
