"""``/api/models``: systems under test — list, register by spec, upload a model file, remove.

Registration is :func:`lidarfuzz.store.inventory.add_model`, as ``lidarfuzz models add`` does: the
spec is built once (a bad one fails now) and recorded with its fingerprint. What the API
accepts is narrower than the CLI (:func:`lidarfuzz.web.security.check_model_spec`): no
``subprocess:`` / ``worker:`` commands, no imports outside installed plugins, no server files.
Uploaded ONNX models are opened by ONNX Runtime and Open3D-ML checkpoints are read with
``torch.load(weights_only=True)`` before they are recorded — plain tensors only, nothing runs.
"""

from __future__ import annotations

import json
import re
import threading
import uuid
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException, Request, status
from pydantic import BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from lidarfuzz.store.inventory import add_model, get_model, list_models, remove_model
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.events import iso
from lidarfuzz.web.security import check_model_spec, check_name, remove_tree, within

router = APIRouter(tags=["models"])
Web = Annotated[WebContext, Depends(web)]

FILE_KINDS = {"onnx": ("model.onnx", {".onnx"}), "open3d": ("checkpoint.pth", {".pth", ".pt", ".ckpt"})}
FILE_OPTIONS: dict[str, dict[str, type | tuple[type, ...]]] = {
    "onnx": {"class_names": list, "convention": str, "threads": int, "name": str, "version": str},
    "open3d": {"config": str, "threads": int},
}
UPLOAD_FORM = {"requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
    "type": "object", "required": ["name", "file"],
    "properties": {"name": {"type": "string"}, "kind": {"type": "string", "enum": ["onnx", "open3d"]},
                   "options": {"type": "string", "description": "JSON object, e.g. {\"class_names\": [\"Car\"]}"},
                   "modality": {"type": "string", "enum": ["lidar", "camera"],
                                "description": "camera: an ONNX steering network (images in, an angle out)"},
                   "notes": {"type": "string"}, "file": {"type": "string", "format": "binary"}}}}}}}


def model_kind(spec: str) -> str:
    scheme, sep, _ = spec.partition(":")
    if sep and scheme in ("subprocess", "worker", "onnx", "open3d"):
        return scheme
    return "plugin" if ":" in spec.partition("?")[0] else "builtin"


_modalities: dict[tuple[str, str, str], str] = {}
_modalities_lock = threading.Lock()


def _builds(factory: Any, spec: str, options: dict[str, Any]) -> Any:
    try:
        return factory(spec, **options)
    except Exception:  # not this modality's system (or not buildable here at all)
        return None


def model_modality(row: Any) -> str:
    """``camera`` for a registered steering system, else ``lidar``: the system the spec builds as a
    steering system (:func:`~lidarfuzz.suts.registry.create_camera`) when its fingerprint is the one
    recorded, or when only that builds (the store keeps no modality with a model). Kept per spec,
    options and fingerprint."""
    from lidarfuzz.suts.registry import create, create_camera

    options = dict(row.options or {})
    key = (row.spec, json.dumps(options, sort_keys=True, default=str), row.fingerprint)
    with _modalities_lock:
        known = _modalities.get(key)
    if known is not None:
        return known
    steering = _builds(create_camera, row.spec, options)
    if steering is None:
        modality = "lidar"
    elif _fingerprint(steering) == row.fingerprint:
        modality = "camera"
    else:
        modality = "lidar" if _builds(create, row.spec, options) is not None else "camera"
    with _modalities_lock:
        _modalities[key] = modality
    return modality


def _fingerprint(system: Any) -> str | None:
    try:
        return str(system.fingerprint())
    except Exception:  # weights missing: cannot say from the fingerprint
        return None


def model_row(row: Any, modality: str | None = None) -> dict[str, Any]:
    return {"name": row.name, "spec": row.spec, "kind": model_kind(row.spec), "options": row.options,
            "fingerprint": row.fingerprint, "notes": row.notes,
            "added_at": iso(row.added_at), "modality": modality or model_modality(row)}


@router.get("/models")
async def models_list(ctx: Web) -> dict[str, Any]:
    """Recorded systems under test (also those registered from the CLI, whatever their kind), each
    with its ``modality``: ``camera`` for a steering system, else ``lidar``."""
    rows = list_models(ctx.store)
    return {"items": await run_in_threadpool(lambda: [model_row(row) for row in rows])}


class ModelRequest(BaseModel):
    """A system under test to record: a built-in or plugin spec (``lidarfuzz suts``)."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description="a name for it")
    spec: str = Field(description="classic, pillars?threads=2, an installed plugin's module:callable, ...; "
                                  "a steering system: dave2, epoch, chauffeur, ...")
    options: dict[str, Any] = Field(default_factory=dict, description="passed to the system")
    notes: str = ""
    modality: Literal["lidar", "camera"] = Field(
        default="lidar", description="lidar: a system detecting objects in point clouds; camera: a steering "
                                     "system on images (camera tasks)")


@router.post("/models", status_code=status.HTTP_201_CREATED)
async def models_create(ctx: Web, body: ModelRequest) -> dict[str, Any]:
    """Register a system under test by spec (403 for ``subprocess:`` / ``worker:``: CLI only)."""
    check_name(body.name, "name")
    check_model_spec(body.spec, ctx.uploads, body.options.items())
    row = await run_in_threadpool(lambda: add_model(ctx.store, body.name, body.spec, body.options, body.notes,
                                                    modality=body.modality))
    return model_row(row, body.modality)


def _file_options(kind: str, text: str) -> dict[str, Any]:
    try:
        options = json.loads(text) if text.strip() else {}
    except json.JSONDecodeError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"options: not JSON ({exc})") from None
    if not isinstance(options, dict):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "options: expected a JSON object")
    allowed = FILE_OPTIONS[kind]
    for key, value in options.items():
        if key not in allowed:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"options.{key}: not an option of an uploaded {kind} model "
                                f"(allowed: {', '.join(allowed)}; others only from the CLI)")
        if not isinstance(value, allowed[key]) or isinstance(value, bool):
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"options.{key}: wrong type")
    if kind == "open3d" and not re.match(r"^[A-Za-z0-9_]+$", str(options.get("config", "pointpillars_kitti"))):
        raise HTTPException(status.HTTP_403_FORBIDDEN, "options.config: only a bundled Open3D-ML configuration "
                                                       "name (e.g. pointpillars_kitti); files only from the CLI")
    return options


def _steering_options(text: str) -> dict[str, Any]:
    """An uploaded ONNX steering network's options: its input (``height``, ``width``, ``crop_top``,
    ``crop_bottom``, ``color``, ``scale``, ``offset``: lidarfuzz.suts.steering.preprocess), ``threads``."""
    from lidarfuzz.suts.steering.preprocess import Preprocess

    try:
        options = json.loads(text) if text.strip() else {}
    except json.JSONDecodeError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"options: not JSON ({exc})") from None
    if not isinstance(options, dict):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "options: expected a JSON object")
    allowed = {*Preprocess.model_fields, "threads"}
    for key, value in options.items():
        if key not in allowed:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"options.{key}: not an option of an uploaded steering network (allowed: "
                                f"{', '.join(sorted(allowed))})")
        if not isinstance(value, str | int | float) or isinstance(value, bool):
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"options.{key}: wrong type")
    return options


def _check_file(kind: str, path: Path, options: dict[str, Any], shown: str, modality: str = "lidar") -> None:
    """Open the uploaded model the safe way; a file that is not one is a 422 naming it."""
    if kind == "onnx" and modality == "camera":
        from lidarfuzz.suts.registry import create_camera

        steering = create_camera(f"onnx:{path}", **options)
        try:
            steering.load()  # ONNX Runtime parses the graph; nothing in an ONNX file runs Python
        finally:
            steering.close()
        return
    if kind == "onnx":
        from lidarfuzz.suts.onnx import OnnxSut

        sut = OnnxSut(str(path), **options)
        try:
            sut.load()  # ONNX Runtime parses the graph; nothing in an ONNX file runs Python
        finally:
            sut.close()
        return
    try:
        import torch
    except ImportError:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{shown}: checking an Open3D-ML checkpoint needs torch "
                            "(pip install 'lidarfuzz[open3d]')") from None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{shown}: not a checkpoint of plain tensors (torch.load(weights_only=True) refused it: "
                            f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from None
    if not isinstance(state, dict):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{shown}: expected a state_dict (or a dict with model_state_dict), got "
                            f"{type(state).__name__}")


@router.post("/models/upload", status_code=status.HTTP_201_CREATED, openapi_extra=UPLOAD_FORM)
async def models_upload(ctx: Web, request: Request) -> dict[str, Any]:
    """Upload an ONNX model or an Open3D-ML checkpoint (multipart: ``name``, ``file``, optional
    ``kind``, ``options`` as JSON, ``notes``) and register it."""
    form = await request.form(max_files=1, max_fields=10)
    try:
        name = check_name(str(form.get("name") or ""), "name")
        upload = form.get("file")
        if not isinstance(upload, UploadFile):
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "file: no model file uploaded")
        shown = Path(upload.filename or "model").name
        suffix = Path(shown).suffix.lower()
        kind = str(form.get("kind") or next((k for k, (_, s) in FILE_KINDS.items() if suffix in s), ""))
        if kind not in FILE_KINDS:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"kind: {kind or shown!r} — upload an ONNX model (.onnx) or an Open3D-ML checkpoint "
                                "(.pth); other systems are registered by spec")
        if name in {m.name for m in list_models(ctx.store)}:
            raise HTTPException(status.HTTP_409_CONFLICT, f"name: a model called {name!r} exists already")
        modality = str(form.get("modality") or "lidar")
        if modality not in ("lidar", "camera") or (modality == "camera" and kind != "onnx"):
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"modality: {modality!r} — lidar, or camera for an ONNX steering network")
        options = _file_options(kind, str(form.get("options") or "")) if modality == "lidar" else \
            _steering_options(str(form.get("options") or ""))
        folder = ctx.uploads / uuid.uuid4().hex
        folder.mkdir(parents=True)
        target = folder / FILE_KINDS[kind][0]
        try:
            with target.open("xb") as out:
                while chunk := await upload.read(1 << 20):
                    out.write(chunk)
            await run_in_threadpool(_check_file, kind, target, options, shown, modality)
            spec = f"{kind}:{target.resolve()}"
            notes = str(form.get("notes") or "") or f"uploaded: {shown}"
            row = await run_in_threadpool(lambda: add_model(ctx.store, name, spec, options, notes, modality=modality))
        except BaseException:
            remove_tree(folder, ctx.uploads)
            raise
    finally:
        await form.close()
    return model_row(row, modality)


@router.delete("/models/{name}", status_code=status.HTTP_204_NO_CONTENT)
def models_delete(ctx: Web, name: str) -> None:
    """Forget a system under test (409 while tasks use it); an uploaded model file is removed."""
    row = get_model(ctx.store, name)
    remove_model(ctx.store, name)
    scheme, sep, rest = row.spec.partition(":")
    if sep and scheme in FILE_KINDS:
        path = Path(rest.partition("?")[0])
        still_used = any(m.spec.partition("?")[0] == row.spec.partition("?")[0] for m in list_models(ctx.store))
        if within(path, ctx.uploads) and not still_used:
            remove_tree(path.parent, ctx.uploads)
