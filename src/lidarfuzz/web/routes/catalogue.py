"""``/api/operators`` (by family, with severity tables and params schemas), operator previews,
``/api/relations``, ``/api/suts`` and ``/api/sequence-systems`` — what ``lidarfuzz operators``,
``relations`` and ``suts`` print."""

from __future__ import annotations

import inspect
from functools import cache
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException, Query, Response, status
from starlette.concurrency import run_in_threadpool

from lidarfuzz.web.context import WebContext, web

router = APIRouter(tags=["catalogue"])
Web = Annotated[WebContext, Depends(web)]


def _doc(obj: Any) -> tuple[str, str]:
    text = inspect.getdoc(obj) or ""
    first = text.split("\n\n", 1)[0].replace("\n", " ").strip()
    return first, text


@cache
def operator_catalogue(modality: str = "lidar") -> list[dict[str, Any]]:
    """The registered operators of one modality (``lidar``, ``camera``; ``all``: every one) grouped by
    family (families and names sorted)."""
    from lidarfuzz.operators import available
    from lidarfuzz.operators.catalogue import severity_rows

    families: dict[str, list[dict[str, Any]]] = {}
    listed = {n: cls for n, cls in available().items() if modality in ("all", cls.modality)}
    for name, cls in sorted(listed.items(), key=lambda kv: (kv[1].family, kv[0])):
        description, doc = _doc(cls)
        severities = sorted(cls.SEVERITIES)
        families.setdefault(cls.family, []).append({
            "name": name, "aliases": list(cls.aliases), "modality": cls.modality, "family": cls.family,
            "relation": cls.relation.value,
            "targets": sorted(t.value for t in cls.targets), "description": description, "doc": doc,
            "severities": severities,
            "severity_configs": {str(s): cls.at_severity(s).config.model_dump(mode="json") for s in severities},
            "severity_table": [{"field": field, "description": text, "values": values}
                               for field, text, values in severity_rows(cls)],
            "params_schema": cls.ConfigModel.model_json_schema(),
            "preview": f"/api/operators/{name}/preview.png"})
    return [{"family": family, "operators": ops} for family, ops in families.items()]


@router.get("/operators")
def operators(ctx: Web, modality: Annotated[Literal["lidar", "camera", "all"], Query()] = "lidar") -> dict[str, Any]:
    """The mutation operators of one modality by family (LiDAR ones unless ``modality`` says
    ``camera`` or ``all``): name, aliases, modality, description, relation, targets, the severity
    table (config per severity 1-5, and a row per field for severities 0-5) and the JSON schema
    of the config a campaign may give instead of severities. The first call starts rendering the
    previews' frame in the background, so the form's first preview is not kept waiting for it."""
    if modality != "camera":
        _prepare_previews(ctx)
    return {"families": operator_catalogue(modality)}


def _prepare_previews(ctx: WebContext) -> None:
    """Render the preview frame (:func:`lidarfuzz.web.previews.preview_frame`) in a thread, once per app."""
    import threading

    from lidarfuzz.web.previews import preview_frame

    with ctx.lock("preview-frame-started"):
        if ctx.extras.get("preview-frame-started"):
            return
        ctx.extras["preview-frame-started"] = True

    def render() -> None:
        try:
            preview_frame(ctx.cache)
        except Exception:  # the preview's own request renders it again and says why
            return

    threading.Thread(target=render, name="preview-frame", daemon=True).start()


@router.get("/operators/{name}/preview.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}, "description": "before | after, from above"}})
async def operator_preview(ctx: Web, name: str, severity: Annotated[int, Query(ge=0, le=5)] = 3,
                           seed: Annotated[int, Query(ge=0, le=2**31)] = 0) -> Response:
    """A bird's-eye picture of a built-in simulator frame before and after the operator at
    ``severity`` (drawn once, then cached)."""
    from lidarfuzz.operators import get
    from lidarfuzz.web.previews import preview_png

    try:
        cls = get(name)
    except KeyError as exc:
        raise HTTPException(status.HTTP_404_NOT_FOUND, str(exc).strip("'\"")) from None
    if cls.modality != "lidar":
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"name: {cls.name} is a {cls.modality} operator; previews are drawn from above, "
                            "for lidar operators")
    if severity and severity not in cls.SEVERITIES:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"severity: {cls.name} has severities {', '.join(map(str, sorted(cls.SEVERITIES)))}")
    png = await run_in_threadpool(preview_png, ctx.cache, cls.name, severity, seed, ctx.lock(f"preview-{cls.name}"))
    return Response(png, media_type="image/png", headers={"Cache-Control": "public, max-age=86400"})


@router.get("/relations")
def relations(ctx: Web) -> dict[str, Any]:
    """The metamorphic relations: name, description, the operator relations (invariant,
    equivariant, degrading) each applies to, and its config's JSON schema."""
    from lidarfuzz.oracles.relations import available

    items = []
    for name, cls in sorted(available().items()):
        items.append({"name": name, "description": cls.description, "doc": _doc(cls)[1],
                      "applies_to": sorted(r.value for r in cls.applies_to),
                      "params_schema": cls.ConfigModel.model_json_schema()})
    return {"items": items}


@router.get("/suts")
def suts(ctx: Web) -> dict[str, Any]:
    """The built-in and plugin systems under test (``lidarfuzz suts``), for the model form: those
    detecting objects in point clouds (``modality`` lidar), then the steering systems (camera)."""
    from lidarfuzz.suts.registry import available, available_camera

    return {"items": [{"name": name, "description": _doc(cls)[0], "version": cls.version, "modality": modality}
                      for modality, group in (("lidar", available()), ("camera", available_camera()))
                      for name, cls in sorted(group.items())],
            "forms": ["NAME", "NAME?key=value", "module:callable (installed plugins)", "onnx file (upload)",
                      "open3d checkpoint (upload)"]}


#: The code a structural task on the built-in controller (or a bug-zoo variant of it) covers unless
#: told otherwise: its methods in the roles of Neves et al.'s cObstacleAvoidance.process() and
#: cVFH.calculate() (docs/structural.md).
CONTROLLER_TARGETS = ("lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process",
                      "lidarfuzz.suts.controller.vfh:VFH.calculate")
HEURISTIC_HELP = {
    "greedy_edges": "greedy set cover on edges",
    "greedy_nodes": "greedy set cover on nodes",
    "budget": "largest new coverage first under a frame budget",
    "decision_change": "the segments where the system's decision changes (no coverage needed)",
    "random": "a baseline: as many segments as another heuristic, drawn with the seed",
}
STRATEGY_HELP = {
    "HGT": "every frame again after itself, every point raised by 10 m (2k frames per segment)",
    "AVG": "the average of each two consecutive frames between them (2k − 1 frames per segment)",
}


def suggested_targets(cls: type[Any]) -> list[str]:
    """The code targets the New task form proposes for a sequence system: the controller's two
    main methods for the controller and its variants, else the system's class."""
    from lidarfuzz.suts.controller import ObstacleAvoidance

    if issubclass(cls, ObstacleAvoidance):
        return list(CONTROLLER_TARGETS)
    return [f"{cls.__module__}:{cls.__qualname__}"]


@router.get("/sequence-systems")
def sequence_systems(ctx: Web) -> dict[str, Any]:
    """The registered systems that consume logs in order (entry-point group
    ``lidarfuzz.sequence_suts``, ``lidarfuzz suts`` lists them as *logs*) with the code targets the
    New task form proposes for each, and what a structural task can choose: its heuristics and
    strategies (the defaults: all of them) and the segment size."""
    from lidarfuzz.campaign.structural import DEFAULT_HEURISTICS, DEFAULT_STRATEGIES
    from lidarfuzz.structural.segments import DEFAULT_SIZE
    from lidarfuzz.suts.registry import available_sequences

    return {"items": [{"name": name, "description": _doc(cls)[0], "version": cls.version,
                       "targets": suggested_targets(cls)} for name, cls in sorted(available_sequences().items())],
            "heuristics": [{"name": name, "description": HEURISTIC_HELP.get(name, "")} for name in DEFAULT_HEURISTICS],
            "strategies": [{"name": name, "description": STRATEGY_HELP.get(name, "")} for name in DEFAULT_STRATEGIES],
            "segments": DEFAULT_SIZE}
