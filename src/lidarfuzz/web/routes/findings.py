"""``/api/tasks/{id}/findings`` (filtered, sorted, paged, grouped), ``/api/findings/{id}`` (one, with its
replay record) and ``/api/findings/{id}/thumb.png`` (a small picture of it, cached)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException, Query, Response, status
from sqlalchemy import func, select
from starlette.concurrency import run_in_threadpool

from lidarfuzz.campaign.tasks import get_task, subtask_label
from lidarfuzz.store.models import Finding, FrameResult, Subtask
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.security.ids import MAX_COUNT, Offset, QueryId, RowId

router = APIRouter(tags=["findings"])
Web = Annotated[WebContext, Depends(web)]

#: The system under test's failures among the findings' kinds (every other kind is a violated relation;
#: lidarfuzz's own errors are never findings).
SUT_FAILURES = ("crash", "timeout", "invalid_output")
#: What the list sorts by (a leading ``-``: descending). Findings without a magnitude (failures) come
#: last either way; ties keep id order.
SORTS = ("id", "magnitude", "severity", "frame", "operator")
Sort = Literal["id", "-id", "magnitude", "-magnitude", "severity", "-severity", "frame", "-frame", "operator",
               "-operator"]


def _row(finding: Finding, frame_id: str, trial: int, name: str, severity: int, subtask_id: int | None = None
         ) -> dict[str, Any]:
    return {"id": finding.id, "task_id": finding.task_id, "kind": finding.kind, "relation": finding.kind,
            "class": finding.cls, "operator": name, "severity": severity, "label": subtask_label(name, severity),
            "frame_id": frame_id, "trial": trial, "magnitude": finding.magnitude, "message": finding.message,
            "subtask_id": subtask_id, "failure": finding.kind in SUT_FAILURES}


def _base() -> Any:
    return (select(Finding, FrameResult.frame_id, FrameResult.trial, Subtask.name, Subtask.severity)
            .join(FrameResult, Finding.frame_result_id == FrameResult.id)
            .join(Subtask, FrameResult.subtask_id == Subtask.id))


def _order(sort: str) -> list[Any]:
    """The ORDER BY of ``sort`` (see :data:`SORTS`)."""
    key = sort.lstrip("-")
    table: dict[str, list[Any]] = {"id": [], "magnitude": [Finding.magnitude], "severity": [Subtask.severity],
                                   "frame": [FrameResult.frame_id, FrameResult.trial],
                                   "operator": [Subtask.name, Subtask.severity]}
    columns = table[key]
    descending = sort.startswith("-")
    ordered = [c.desc() if descending else c.asc() for c in columns]
    nulls_last = [Finding.magnitude.is_(None)] if key == "magnitude" else []
    return [*nulls_last, *ordered, Finding.id.desc() if descending and key == "id" else Finding.id.asc()]


def object_key(detail: Mapping[str, Any] | None) -> tuple[str, ...]:
    """Which objects of the original frame a finding is about, as the same object is named at every
    severity: its violations' ``gt_index`` (ground-truth boxes of the original), else their
    ``source_index`` (the system's detections on the original); ``()`` for a frame-level finding (a
    failure, a count). A follow-up's own indices (``follow_index``) differ per mutant and are not used.

    Example:
        >>> object_key({"violations": [{"gt_index": 3}, {"gt_index": 1, "source_index": 0}]})
        ('gt1', 'gt3')
    """
    violations = [v for v in (detail or {}).get("violations", []) if isinstance(v, Mapping)]
    for key, prefix in (("gt_index", "gt"), ("source_index", "det")):
        found = sorted({int(v[key]) for v in violations if isinstance(v.get(key), int) and v[key] >= 0})
        if found:
            return tuple(f"{prefix}{i}" for i in found)
    return ()


def group_ids(rows: Sequence[Mapping[str, Any]]) -> list[list[int]]:
    """The ids of ``rows`` (in list order; each with ``id, frame_id, operator, kind, class, objects``)
    in groups, each the same finding at several severities: the same frame, operator, relation or
    failure kind and class, about at least one common object (:func:`object_key`; findings about no
    object: the same frame, operator, kind and class). Groups come in the order of their first
    member, members in list order.

    Example:
        >>> rows = [{"id": i, "frame_id": "f", "operator": "op", "kind": "k", "class": "Car", "objects": o}
        ...         for i, o in ((1, ("det1", "det9")), (2, ("det4",)), (3, ("det9",)))]
        >>> group_ids(rows)
        [[1, 3], [2]]
    """
    parent = list(range(len(rows)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    seen: dict[tuple[Any, ...], int] = {}  # (frame, operator, kind, class, object) -> the first row naming it
    for i, row in enumerate(rows):
        scope = (row["frame_id"], row["operator"], row["kind"], row["class"])
        for obj in row["objects"] or ("",):
            earlier = seen.setdefault((*scope, obj), i)
            parent[root(i)] = root(earlier)
    groups: dict[int, list[int]] = {}
    for i, row in enumerate(rows):  # dicts keep insertion order: groups in the order of their first member
        groups.setdefault(root(i), []).append(int(row["id"]))
    return list(groups.values())


#: The most members a group lists (its size and severities count them all).
MAX_MEMBERS = 50


def _with_group(head: dict[str, Any], members: Sequence[dict[str, Any]], size: int, severities: list[int]
                ) -> dict[str, Any]:
    """A group's first finding (in list order) with ``group``: ``{"size", "severities", "members"}``
    (``members``: by severity, then trial, then id; at most :data:`MAX_MEMBERS`)."""
    out = {k: v for k, v in head.items() if k != "objects"}
    out["group"] = {"size": size, "severities": severities,
                    "members": [{k: r[k] for k in ("id", "severity", "label", "trial", "magnitude", "message")}
                                for r in members]}
    return out


def _member_order(row: Mapping[str, Any]) -> tuple[int, int, int]:
    return int(row["severity"]), int(row["trial"]), int(row["id"])


def group_rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Findings (list items with their ``objects``, in list order) grouped by :func:`group_ids`: each
    group is its first finding with ``group`` (:func:`_with_group`).

    Example:
        >>> rows = [{"id": i, "frame_id": "f", "operator": "op", "kind": "k", "class": "Car", "severity": s,
        ...          "trial": 0, "label": "", "magnitude": 1.0, "message": "", "objects": o}
        ...         for i, s, o in ((1, 3, ("det1", "det9")), (2, 5, ("det1",)), (3, 5, ("det4",)))]
        >>> [(g["id"], g["group"]["severities"]) for g in group_rows(rows)]
        [(1, [3, 5]), (3, [5])]
    """
    by_id = {row["id"]: row for row in rows}
    out = []
    for ids in group_ids(rows):
        members = sorted((by_id[i] for i in ids), key=_member_order)
        out.append(_with_group(by_id[ids[0]], members[:MAX_MEMBERS], len(ids),
                               sorted({r["severity"] for r in members})))
    return out


#: Groupings kept per app (the most recent): a finished task's findings do not change, so paging
#: through them, or coming back, does not read every finding's detail again.
GROUPINGS_KEPT = 16
Grouping = tuple[list[list[int]], dict[int, dict[str, Any]]]


def _grouping(s: Any, where: list[Any], sort: str) -> Grouping:
    """The groups (:func:`group_ids`) of the findings matching ``where`` in ``sort`` order, and what
    each finding's grouping read (its scope, severity and trial). Reads only those columns of every
    matching finding."""
    light = s.execute(select(Finding.id, FrameResult.frame_id, Subtask.name, Finding.kind, Finding.cls,
                             Finding.detail, Subtask.severity, FrameResult.trial)
                      .join(FrameResult, Finding.frame_result_id == FrameResult.id)
                      .join(Subtask, FrameResult.subtask_id == Subtask.id).where(*where).order_by(*_order(sort))).all()
    scopes = {r[0]: {"id": r[0], "frame_id": r[1], "operator": r[2], "kind": r[3], "class": r[4],
                     "objects": object_key(r[5]), "severity": r[6], "trial": r[7]} for r in light}
    return group_ids(list(scopes.values())), scopes


def _kept_grouping(ctx: WebContext, s: Any, key: tuple[Any, ...], where: list[Any], sort: str) -> Grouping:
    """:func:`_grouping`, kept with the app under ``key`` (the filters and sort) while the matching
    findings are the same (their count and largest id: findings are only added, or deleted with
    their task)."""
    from collections import OrderedDict

    count, last = s.execute(select(func.count(), func.max(Finding.id)).select_from(Finding).join(
        FrameResult, Finding.frame_result_id == FrameResult.id).join(
        Subtask, FrameResult.subtask_id == Subtask.id).where(*where)).one()
    kept: OrderedDict[tuple[Any, ...], tuple[Any, Grouping]] = ctx.extras.setdefault("finding-groups", OrderedDict())
    with ctx.lock("finding-groups"):
        hit = kept.get(key)
        if hit is not None and hit[0] == (count, last):
            kept.move_to_end(key)
            return hit[1]
    grouping = _grouping(s, where, sort)
    with ctx.lock("finding-groups"):
        kept[key] = ((count, last), grouping)
        while len(kept) > GROUPINGS_KEPT:
            kept.popitem(last=False)
    return grouping


def _grouped_page(grouping: Grouping, s: Any, limit: int, offset: int) -> tuple[list[dict[str, Any]], int]:
    """One page of groups and how many there are: whole rows only for what the page shows (each
    group's first finding and its listed members)."""
    groups, scopes = grouping
    page = [(ids[0], sorted((scopes[i] for i in ids), key=_member_order)) for ids in groups[offset: offset + limit]]
    wanted = {i for head, members in page for i in (head, *(m["id"] for m in members[:MAX_MEMBERS]))}
    rows = {row[0].id: _row(*row) for row in s.execute(
        _base().add_columns(Subtask.id).where(Finding.id.in_(wanted))).all()} if wanted else {}
    return [_with_group(rows[head], [rows[m["id"]] for m in members[:MAX_MEMBERS]], len(members),
                        sorted({m["severity"] for m in members})) for head, members in page], len(groups)


def _facets(s: Any, task_id: int) -> dict[str, list[Any]]:
    values = s.execute(select(Finding.kind, Subtask.name, Finding.cls, Subtask.severity).join(
        FrameResult, Finding.frame_result_id == FrameResult.id).join(
        Subtask, FrameResult.subtask_id == Subtask.id).where(Finding.task_id == task_id).distinct()).all()
    kinds = {"failure" if v[0] in SUT_FAILURES else "violation" for v in values}
    return {"relation": sorted({v[0] for v in values}), "operator": sorted({v[1] for v in values}),
            "class": sorted({v[2] for v in values}), "severity": sorted({v[3] for v in values}),
            "kind": sorted(kinds)}


def _check_subtask(s: Any, task_id: int, subtask: int) -> None:
    if s.scalar(select(Subtask.task_id).where(Subtask.id == subtask)) != task_id:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"subtask: task {task_id} has no subtask {subtask}")


@router.get("/tasks/{task_id}/findings")
def findings_list(ctx: Web, task_id: RowId, relation: str | None = None, operator: str | None = None,
                  cls: str | None = None, severity: Annotated[int | None, Query(ge=0, le=MAX_COUNT)] = None,
                  kind: Literal["failure", "violation"] | None = None, subtask: QueryId = None,
                  sort: Sort = "id", group: bool = False, limit: Annotated[int, Query(ge=1, le=1000)] = 100,
                  offset: Offset = 0) -> dict[str, Any]:
    """Findings of a task, filtered by relation (or failure kind), operator, severity, class, kind
    (``failure``: the system's crashes, timeouts and invalid outputs; ``violation``: a relation) and
    subtask (its id), sorted by ``sort`` (:data:`SORTS`, ``-`` for descending):
    ``{"items", "total", "total_all", "groups", "limit", "offset", "facets"}`` — ``total`` counts the
    filtered findings, ``total_all`` all of the task's, and the facets list the values each filter can
    take. ``group``: the same finding at several severities is one item (:func:`group_rows`) and
    ``limit``/``offset`` page over the ``groups``."""
    get_task(ctx.store, task_id)
    where = [Finding.task_id == task_id]
    if relation:
        where.append(Finding.kind == relation)
    if operator:
        where.append(Subtask.name == operator)
    if cls is not None and cls != "":
        where.append(Finding.cls == cls)
    if severity is not None:
        where.append(Subtask.severity == severity)
    if kind is not None:
        failed = Finding.kind.in_(SUT_FAILURES)
        where.append(failed if kind == "failure" else ~failed)
    if subtask is not None:
        where.append(Subtask.id == subtask)
    with ctx.store.session() as s:
        if subtask is not None:
            _check_subtask(s, task_id, subtask)
        query = _base().add_columns(Subtask.id).where(*where).order_by(*_order(sort))
        total = s.scalar(select(func.count()).select_from(Finding).join(
            FrameResult, Finding.frame_result_id == FrameResult.id).join(
            Subtask, FrameResult.subtask_id == Subtask.id).where(*where)) or 0
        total_all = s.scalar(select(func.count()).select_from(Finding).where(Finding.task_id == task_id)) or 0
        facets = _facets(s, task_id)
        groups: int | None = None
        if group:
            key = (task_id, relation, operator, cls, severity, kind, subtask, sort, ctx.store.url)
            items, groups = _grouped_page(_kept_grouping(ctx, s, key, where, sort), s, limit, offset)
        else:
            items = [_row(*row) for row in s.execute(query.limit(limit).offset(offset)).all()]
    return {"items": items, "total": int(total), "total_all": int(total_all), "groups": groups, "limit": limit,
            "offset": offset, "sort": sort, "facets": facets}


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
def findings_detail(ctx: Web, finding_id: RowId) -> dict[str, Any]:
    """One finding: what was violated (its detail), its replay record (seed, operator spec and
    params, frame, system and fingerprint; ``lidarfuzz replay ID`` re-runs it), the ids of the task's
    previous and next findings, and where its pictures are: ``frames`` (the LiDAR frames, LFZ1) or,
    for a camera task, ``picture`` (original | transformed, PNG) and ``steering`` (the figures Eq. 2
    and Eq. 3 judged, :func:`steering_figures`)."""
    with ctx.store.session() as s:
        row = s.execute(_base().add_columns(Subtask, FrameResult).where(Finding.id == finding_id)).first()
        if row is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no finding {finding_id}")
        out = _row(row[0], row[1], row[2], row[3], row[4], row[5].id)
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


@router.get("/findings/{finding_id}/thumb.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}, "description": "160 × 120 pixels"}})
async def finding_thumb(ctx: Web, finding_id: RowId) -> Response:
    """A small picture of a finding for the list (160 × 120): a LiDAR finding's mutant from above, cropped
    to the objects it is about (as the report's pictures draw them), a camera finding's transformed
    image. Drawn once, then cached on disk; 422 when its frame cannot be rebuilt any more."""
    from lidarfuzz.errors import LidarfuzzError
    from lidarfuzz.store.models import Task
    from lidarfuzz.web.previews import render_thumbnail, thumb_key, thumbnail_png

    with ctx.store.session() as s:
        finding = s.get(Finding, finding_id)
        if finding is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"no finding {finding_id}")
        created = s.scalar(select(Task.created_at).where(Task.id == finding.task_id))
        modality = task_modality(ctx, finding.task_id)
        key = thumb_key(finding, created, modality)
    datasets: dict[str, Any] = ctx.extras.setdefault(f"thumb-datasets-{modality}", {})

    def draw() -> bytes:
        return render_thumbnail(ctx.store, finding_id, modality, datasets)

    try:
        png = await run_in_threadpool(thumbnail_png, ctx.cache, key, draw, ctx.lock(f"thumb-{finding_id}"))
    except (LidarfuzzError, OSError) as exc:  # the data set moved or changed since the task ran
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"finding {finding_id}: no picture: {str(exc).splitlines()[0]}") from None
    return Response(png, media_type="image/png", headers={"Cache-Control": "private, max-age=86400"})
