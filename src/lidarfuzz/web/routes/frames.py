"""Binary frames (``LFZ1``, :mod:`lidarfuzz.web.frames`): a finding's original and mutant, a data set's frames;
for camera data (images), PNG pictures instead: a finding's original | transformed image and a data set's
images, with the steering arrows the report draws (:mod:`lidarfuzz.report.camera`)."""

from __future__ import annotations

import threading
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query, Response, status
from sqlalchemy import select
from starlette.concurrency import run_in_threadpool

from lidarfuzz.store.inventory import get_dataset
from lidarfuzz.store.models import Finding
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.frames import MEDIA_TYPE, pair_payload, scene_payload
from lidarfuzz.web.security import check_frame_id
from lidarfuzz.web.security.ids import MAX_COUNT, Offset, RowId

router = APIRouter(tags=["frames"])
Web = Annotated[WebContext, Depends(web)]
BINARY: dict[int | str, dict[str, Any]] = {200: {"content": {MEDIA_TYPE: {}}, "description": "an LFZ1 payload"}}
PNG: dict[int | str, dict[str, Any]] = {200: {"content": {"image/png": {}}, "description": "a PNG picture"}}


def _binary(blob: bytes) -> Response:
    return Response(blob, media_type=MEDIA_TYPE, headers={"Cache-Control": "private, max-age=60"})


def _png(blob: bytes) -> Response:
    return Response(blob, media_type="image/png", headers={"Cache-Control": "private, max-age=60"})


def _unprocessable(detail: str) -> HTTPException:
    return HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, detail)


@router.get("/findings/{finding_id}/frames", response_class=Response, responses=BINARY)
async def finding_frames(ctx: Web, finding_id: RowId) -> Response:
    """Original and mutant of a finding, rebuilt exactly from the stored params, with ground truth,
    detections, the ``change`` channel and the finding's highlights."""
    from lidarfuzz.report.bev import load_pair
    from lidarfuzz.web.routes.findings import task_modality

    with ctx.store.session() as s:
        task_id = s.scalar(select(Finding.task_id).where(Finding.id == finding_id))
    if task_id is not None and task_modality(ctx, task_id) == "camera":
        raise _unprocessable(f"finding {finding_id} is from a camera task: it has images, not point clouds; its "
                             f"picture is /api/findings/{finding_id}/pair.png")

    def build() -> bytes:
        return pair_payload(load_pair(ctx.store, finding_id))

    try:
        return _binary(await run_in_threadpool(build))
    except Exception as exc:
        if "no finding" in str(exc):
            raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc)) from None
        raise


def _replay_order(dataset: Any) -> tuple[list[str], list[float] | None, str | None]:
    """A data set's frame ids in replay order, their timestamps (None: no clock) and what the order
    comes from (:mod:`lidarfuzz.structural.logs`); its listing order and ``None`` when it has none."""
    from lidarfuzz.structural.logs import NotALogError, order_of

    try:
        log = order_of(dataset)
    except NotALogError:
        return list(dataset.frame_ids()), None, None
    stamps = None if log.timestamps is None else [round(float(t), 6) for t in log.timestamps]
    return list(log.frame_ids), stamps, log.order


@router.get("/datasets/{name}/frames")
def dataset_frames(ctx: Web, name: str, limit: Annotated[int | None, Query(ge=0, le=MAX_COUNT)] = None,
                   offset: Offset = 0) -> dict[str, Any]:
    """The frame ids of a data set: ``{"name", "modality", "total", "frame_ids", "order", "timestamps"}``
    (``modality`` ``camera``: its frames are images, ``/api/datasets/{name}/images`` lists them with their
    labels). A log (frames with an order: timestamps, a bag's order or poses) lists its frames in replay
    order, ``order`` saying where it comes from and ``timestamps`` the frames' seconds (null without a
    clock); for any other data set both are null (the viewer's playback is for logs)."""
    from lidarfuzz.store.inventory import dataset_options

    row = get_dataset(ctx.store, name)
    options = dataset_options(row)
    if options.modality == "camera":
        ids, stamps, order = list(ctx.dataset(row.path).frame_ids()), None, None
    else:
        ids, stamps, order = _replay_order(ctx.dataset(row.path))
    window = slice(offset, None if limit is None else offset + limit)
    return {"name": name, "modality": options.modality, "total": len(ids), "frame_ids": ids[window],
            "order": order, "timestamps": None if stamps is None else stamps[window]}


@router.get("/datasets/{name}/frames/{frame_id}", response_class=Response, responses=BINARY)
async def dataset_frame(ctx: Web, name: str, frame_id: str) -> Response:
    """One frame of a data set (every channel and its ground truth) as one cloud named ``frame``."""
    from lidarfuzz.store.inventory import dataset_options

    check_frame_id(frame_id)
    row = get_dataset(ctx.store, name)
    if dataset_options(row).modality == "camera":
        raise _unprocessable(f"data set {name!r} holds camera images, not point clouds; its pictures are "
                             f"/api/datasets/{name}/frames/{{frame_id}}/image.png")

    def build() -> bytes:
        dataset = ctx.dataset(row.path)
        if frame_id not in set(dataset.frame_ids()):
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"data set {name!r} has no frame {frame_id!r}")
        return scene_payload(dataset.load(frame_id), dataset=name)

    return _binary(await run_in_threadpool(build))


# -- camera data: pictures -------------------------------------------------------------------
@router.get("/findings/{finding_id}/pair.png", response_class=Response, responses=PNG)
async def finding_pair_png(ctx: Web, finding_id: RowId) -> Response:
    """A camera task's finding as the report draws it: the original and the transformed image (rebuilt
    from the stored operator and params) side by side, with the label (green) and the predictions on
    the original (blue) and on the transformed image (red) as arrows. 422 for a LiDAR task's finding
    (its frames: ``/api/findings/{id}/frames``) or a data set that cannot be read any more."""
    from lidarfuzz.errors import LidarfuzzError
    from lidarfuzz.report.camera import finding_png
    from lidarfuzz.web.routes.findings import task_modality

    with ctx.store.session() as s:
        task_id = s.scalar(select(Finding.task_id).where(Finding.id == finding_id))
    if task_id is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no finding {finding_id}")
    modality = task_modality(ctx, task_id)
    if modality != "camera":
        raise _unprocessable(f"finding {finding_id} is from a {modality} task: it has no images; its frames are "
                             f"/api/findings/{finding_id}/frames")
    opened: dict[str, Any] = ctx.extras.setdefault("camera-datasets", {})

    def build() -> bytes:
        try:
            return finding_png(ctx.store, finding_id, opened)
        except (LidarfuzzError, OSError) as exc:  # the data set moved or changed since the task ran
            raise _unprocessable(f"finding {finding_id}: no picture: {str(exc).splitlines()[0]}") from None

    return _png(await run_in_threadpool(build))


def _camera_dataset(ctx: WebContext, name: str) -> Any:
    """A registered camera data set, opened (422 for a LiDAR one: its frames are point clouds)."""
    from lidarfuzz.store.inventory import dataset_options

    row = get_dataset(ctx.store, name)
    if dataset_options(row).modality != "camera":
        raise _unprocessable(f"data set {name!r} holds lidar frames (point clouds), not images; its frames are "
                             f"/api/datasets/{name}/frames/{{frame_id}}")
    return ctx.dataset(row.path)


_facts_lock = threading.Lock()


def image_facts(ctx: WebContext, name: str, dataset: Any, frame_id: str) -> dict[str, Any]:
    """An image's steering label and size, read once per data set and frame (the image is decoded
    the first time, then the facts are kept with the app)."""
    facts: dict[tuple[str, str], dict[str, Any]] = ctx.extras.setdefault("image-facts", {})
    key = (str(dataset.path), frame_id)
    with _facts_lock:
        known = facts.get(key)
    if known is None:
        sample = dataset.load(frame_id)
        steering = sample.steering
        known = {"frame_id": frame_id, "steering": None if steering is None else float(steering),
                 "width": int(sample.image.shape[1]), "height": int(sample.image.shape[0])}
        with _facts_lock:
            facts[key] = known
    return {**known, "image": f"/api/datasets/{name}/frames/{frame_id}/image.png"}


@router.get("/datasets/{name}/images")
async def dataset_images(ctx: Web, name: str, limit: Annotated[int, Query(ge=1, le=500)] = 60,
                         offset: Offset = 0) -> dict[str, Any]:
    """A camera data set's images, a page at a time: ``{"name", "total", "limit", "offset", "items":
    [{"frame_id", "steering", "width", "height", "image"}]}`` (``steering``: the label in the data set's
    units, None for an unlabelled image; ``image``: its picture's URL)."""

    def build() -> dict[str, Any]:
        dataset = _camera_dataset(ctx, name)
        ids = list(dataset.frame_ids())
        items = [image_facts(ctx, name, dataset, f) for f in ids[offset: offset + limit]]
        return {"name": name, "total": len(ids), "limit": limit, "offset": offset, "items": items}

    return await run_in_threadpool(build)


@router.get("/datasets/{name}/frames/{frame_id}/image.png", response_class=Response, responses=PNG)
async def dataset_image(ctx: Web, name: str, frame_id: str,
                        width: Annotated[int | None, Query(ge=32, le=4096)] = None) -> Response:
    """One image of a camera data set with its label's steering arrow (green; straight up for 0,
    turned left for a positive angle) and value; ``width``: resized to that many pixels (thumbnails)."""
    from lidarfuzz.report.camera import frame_picture, png_bytes

    check_frame_id(frame_id)

    def build() -> bytes:
        dataset = _camera_dataset(ctx, name)
        if frame_id not in set(dataset.frame_ids()):
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"data set {name!r} has no frame {frame_id!r}")
        sample = dataset.load(frame_id)
        return png_bytes(frame_picture(sample.image, label=sample.steering, width=width, caption=frame_id))

    return _png(await run_in_threadpool(build))
