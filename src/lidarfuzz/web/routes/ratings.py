"""The rating page's API: the thesis's first experiment (Table 6-7), :mod:`lidarfuzz.campaign.ratings`.

* ``GET /api/tasks/{id}/ratings/pairs?rater=&per_operator=&seed=&operators=``: the draw in the
  rater's order, each pair with the rater's verdict so far — blinded: no operator, no severity;
* ``GET /api/tasks/{id}/ratings/pairs/{pair}/picture.png``: original | mutant from above, points only;
* ``GET /api/tasks/{id}/ratings/pairs/{pair}/camera``: the frame's camera image, when the data set has one;
* ``PUT /api/tasks/{id}/ratings/pairs/{pair}``: ``{"rater", "verdict"}`` (same, similar, different);
* ``GET /api/tasks/{id}/ratings/tally``: Table 6-7 (counts, shares and Fleiss' kappa per operator).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query, Response, status
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from lidarfuzz.campaign.ratings import (
    PER_OPERATOR,
    THESIS_EXCLUDED,
    VERDICTS,
    draw_pairs,
    ratings_of,
    record_rating,
    tally,
    tally_dict,
)
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store.errors import StoreError
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.security.ids import RowId, Seed

router = APIRouter(tags=["ratings"])
Web = Annotated[WebContext, Depends(web)]
PROTOCOL = ("Thesis, experiment one (Table 6-7): the same frames, drawn at random, mutated by each operator; raters "
            "told what LiDAR data looks like but not what the operators do judge each mutant against its original: "
            "same (every object as clearly recognisable), similar (every object recognisable, some blurred) or "
            f"different (some object no longer recognisable). {', '.join(THESIS_EXCLUDED)} are left out as in the "
            "thesis (no visual difference) unless named. Pairs are shown in an order of each rater's own; the "
            "pictures show points only, no boxes and no operator.")


class RatingIn(BaseModel):
    """A rater's verdict on one pair."""

    rater: str = Field(description="the rater's name (verdicts are kept per rater)")
    verdict: str = Field(description="same, similar or different")


def _unprocessable(exc: LidarfuzzError) -> HTTPException:
    return HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc).splitlines()[0])


def _operators(text: str | None) -> list[str] | None:
    names = [part.strip() for part in (text or "").split(",") if part.strip()]
    return names or None


@router.get("/tasks/{task_id}/ratings/pairs")
def rating_pairs(ctx: Web, task_id: RowId, rater: Annotated[str, Query(max_length=200)] = "",
                 per_operator: Annotated[int, Query(ge=1, le=10_000)] = PER_OPERATOR, seed: Seed = None,
                 operators: str | None = None) -> dict[str, Any]:
    """The draw (see :func:`lidarfuzz.campaign.ratings.draw_pairs`): ``{"task_id", "seed", "per_operator",
    "frames", "operators" (how many strata), "excluded", "total", "rated", "pairs": [{"id", "index",
    "frame_id", "verdict", "rated_at", "picture", "camera"}], "verdicts", "protocol"}``. With a rater,
    the pairs are in that rater's order with their verdicts; without, in a neutral shuffled order
    (the seed's) and no verdicts. The operators are never named (the raters are blinded)."""
    draw = draw_pairs(ctx.store, task_id, per_operator=per_operator, seed=seed, operators=_operators(operators))
    mine: dict[int, Any] = {}
    if rater.strip():
        ordered = draw.for_rater(rater)
        mine = {v.pair_id: v for v in ratings_of(ctx.store, task_id, rater)}
    else:
        ordered = draw.for_rater("-")
    pairs = []
    for index, pair in enumerate(ordered):
        verdict = mine.get(pair.id)
        base = f"/api/tasks/{task_id}/ratings/pairs/{pair.id}"
        pairs.append({"id": pair.id, "index": index, "frame_id": pair.frame_id,
                      "verdict": verdict.verdict if verdict else None,
                      "rated_at": verdict.rated_at.isoformat() if verdict else None,
                      "picture": f"{base}/picture.png", "camera": f"{base}/camera"})
    return {"task_id": task_id, "seed": draw.seed, "per_operator": draw.per_operator, "frames": len(draw.frames),
            "operators": len(draw.strata), "excluded": list(draw.excluded), "total": len(pairs),
            "rated": sum(1 for p in pairs if p["verdict"]), "pairs": pairs, "verdicts": list(VERDICTS),
            "protocol": PROTOCOL}


@router.get("/tasks/{task_id}/ratings/pairs/{pair_id}/picture.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}, "description": "original | mutant, from above"}})
async def rating_picture(ctx: Web, task_id: RowId, pair_id: RowId) -> Response:
    """The pair as the rater sees it: original (left) and mutant (right) from above, points only."""
    from lidarfuzz.report.ratings import pair_png

    opened: dict[str, Any] = ctx.extras.setdefault("rating-datasets", {})

    def build() -> bytes:
        try:
            return pair_png(ctx.store, task_id, pair_id, datasets=opened)
        except StoreError:  # no such pair: 404 by the app's handler
            raise
        except LidarfuzzError as exc:  # the data set moved or changed since the task ran
            raise _unprocessable(exc) from None

    blob = await run_in_threadpool(build)
    return Response(blob, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})


@router.get("/tasks/{task_id}/ratings/pairs/{pair_id}/camera", response_class=Response,
            responses={200: {"content": {"image/png": {}, "image/jpeg": {}}, "description": "the camera image"},
                       404: {"description": "the data set has no camera image of this frame"}})
async def rating_camera(ctx: Web, task_id: RowId, pair_id: RowId) -> Response:
    """The frame's camera image (KITTI's ``image_2/``), which the thesis's raters had beside the clouds."""
    from lidarfuzz.report.ratings import camera_image

    found = await run_in_threadpool(camera_image, ctx.store, task_id, pair_id)
    if found is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, "this data set has no camera image of the frame")
    blob, media = found
    return Response(blob, media_type=media, headers={"Cache-Control": "private, max-age=3600"})


@router.put("/tasks/{task_id}/ratings/pairs/{pair_id}")
def rate_pair(ctx: Web, task_id: RowId, pair_id: RowId, body: RatingIn) -> dict[str, Any]:
    """Keep the rater's verdict on the pair (again: replaces it, the first time kept):
    ``{"pair_id", "rater", "verdict", "first_rated_at", "rated_at"}``."""
    saved = record_rating(ctx.store, task_id, pair_id, body.rater, body.verdict)
    return {"pair_id": saved.pair_id, "rater": saved.rater, "verdict": saved.verdict,
            "first_rated_at": saved.first_rated_at.isoformat(), "rated_at": saved.rated_at.isoformat()}


@router.get("/tasks/{task_id}/ratings/tally")
def rating_tally(ctx: Web, task_id: RowId) -> dict[str, Any]:
    """Table 6-7: per operator × severity, the verdicts summed over raters, their shares, same + similar
    (the thesis's criterion: above 95%), pairs, raters and Fleiss' kappa; the total row last."""
    return tally_dict(tally(ctx.store, task_id))
