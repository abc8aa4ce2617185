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
import uuid
from pathlib import Path
from typing import Annotated, Any

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
                   "notes": {"type": "string"}, "file": {"type": "string", "format": "binary"}}}}}}}


def model_kind(spec: str) -> str:
    scheme, sep, _ = spec.partition(":")
    if sep and scheme in ("subprocess", "worker", "onnx", "open3d"):
        return scheme
    return "plugin" if ":" in spec.partition("?")[0] else "builtin"


def model_row(row: Any) -> dict[str, Any]:
    return {"name": row.name, "spec": row.spec, "kind": model_kind(row.spec), "options": row.options,
            "fingerprint": row.fingerprint, "notes": row.notes,
            "added_at": iso(row.added_at)}


@router.get("/models")
def models_list(ctx: Web) -> dict[str, Any]:
    """Recorded systems under test (also those registered from the CLI, whatever their kind)."""
    return {"items": [model_row(row) for row in list_models(ctx.store)]}


class ModelRequest(BaseModel):
    """A system under test to record: a built-in or plugin spec (``lidarfuzz suts``)."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description="a name for it")
    spec: str = Field(description="classic, pillars?threads=2, an installed plugin's module:callable, ...")
    options: dict[str, Any] = Field(default_factory=dict, description="passed to the system")
    notes: str = ""


@router.post("/models", status_code=status.HTTP_201_CREATED)
async def models_create(ctx: Web, body: ModelRequest) -> dict[str, Any]:
    """Register a system under test by spec (403 for ``subprocess:`` / ``worker:``: CLI only)."""
    check_name(body.name, "name")
    check_model_spec(body.spec, ctx.uploads, body.options.items())
    row = await run_in_threadpool(add_model, ctx.store, body.name, body.spec, body.options, body.notes)
    return model_row(row)


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


def _check_file(kind: str, path: Path, options: dict[str, Any], shown: str) -> None:
    """Open the uploaded model the safe way; a file that is not one is a 422 naming it."""
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
        options = _file_options(kind, str(form.get("options") or ""))
        folder = ctx.uploads / uuid.uuid4().hex
        folder.mkdir(parents=True)
        target = folder / FILE_KINDS[kind][0]
        try:
            with target.open("xb") as out:
                while chunk := await upload.read(1 << 20):
                    out.write(chunk)
            await run_in_threadpool(_check_file, kind, target, options, shown)
            spec = f"{kind}:{target.resolve()}"
            notes = str(form.get("notes") or "") or f"uploaded: {shown}"
            row = await run_in_threadpool(add_model, ctx.store, name, spec, options, notes)
        except BaseException:
            remove_tree(folder, ctx.uploads)
            raise
    finally:
        await form.close()
    return model_row(row)


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
