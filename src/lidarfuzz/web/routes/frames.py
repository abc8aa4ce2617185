"""Binary frames (``LFZ1``, :mod:`lidarfuzz.web.frames`): a finding's original and mutant, a data set's frames."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Response, status
from starlette.concurrency import run_in_threadpool

from lidarfuzz.store.inventory import get_dataset
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.frames import MEDIA_TYPE, pair_payload, scene_payload
from lidarfuzz.web.security import check_frame_id

router = APIRouter(tags=["frames"])
Web = Annotated[WebContext, Depends(web)]
BINARY: dict[int | str, dict[str, Any]] = {200: {"content": {MEDIA_TYPE: {}}, "description": "an LFZ1 payload"}}


def _binary(blob: bytes) -> Response:
    return Response(blob, media_type=MEDIA_TYPE, headers={"Cache-Control": "private, max-age=60"})


@router.get("/findings/{finding_id}/frames", response_class=Response, responses=BINARY)
async def finding_frames(ctx: Web, finding_id: int) -> Response:
    """Original and mutant of a finding, rebuilt exactly from the stored params, with ground truth,
    detections, the ``change`` channel and the finding's highlights."""
    from lidarfuzz.report.bev import load_pair

    def build() -> bytes:
        return pair_payload(load_pair(ctx.store, finding_id))

    try:
        return _binary(await run_in_threadpool(build))
    except Exception as exc:
        if "no finding" in str(exc):
            raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc)) from None
        raise


@router.get("/datasets/{name}/frames")
def dataset_frames(ctx: Web, name: str, limit: int | None = None, offset: int = 0) -> dict[str, Any]:
    """The frame ids of a data set: ``{"name", "total", "frame_ids"}``."""
    row = get_dataset(ctx.store, name)
    ids = list(ctx.dataset(row.path).frame_ids())
    chosen = ids[offset: None if limit is None else offset + limit]
    return {"name": name, "total": len(ids), "frame_ids": chosen}


@router.get("/datasets/{name}/frames/{frame_id}", response_class=Response, responses=BINARY)
async def dataset_frame(ctx: Web, name: str, frame_id: str) -> Response:
    """One frame of a data set (every channel and its ground truth) as one cloud named ``frame``."""
    check_frame_id(frame_id)
    row = get_dataset(ctx.store, name)

    def build() -> bytes:
        dataset = ctx.dataset(row.path)
        if frame_id not in set(dataset.frame_ids()):
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"data set {name!r} has no frame {frame_id!r}")
        return scene_payload(dataset.load(frame_id), dataset=name)

    return _binary(await run_in_threadpool(build))
