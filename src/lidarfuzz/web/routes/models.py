"""``/api/models``: systems under test — list (each with its type and modality), register by spec,
upload a model file, one model's detail (with the tasks using it), its notes changed (``PATCH``), remove.

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
from typing import Annotated, Any, Literal, NamedTuple

from fastapi import APIRouter, Depends, HTTPException, Request, status
from pydantic import BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from lidarfuzz.store.errors import NotFoundError
from lidarfuzz.store.inventory import (
    add_model,
    get_model,
    list_models,
    printable,
    remove_model,
    set_model_notes,
    tasks_using,
)
from lidarfuzz.store.models import Model
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.events import iso
from lidarfuzz.web.routes.datasets import NOTES_LIMIT, NotesUpdate
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


class SystemFacts(NamedTuple):
    """What a registered spec builds: its ``modality`` (``lidar`` or ``camera``) and its type
    (:func:`~lidarfuzz.suts.registry.system_type`; ``unavailable`` when it cannot be built here)."""

    modality: str
    type: str
    type_label: str


_facts: dict[tuple[str, str, str], SystemFacts] = {}
_facts_lock = threading.Lock()


def _builds(factory: Any, spec: str, options: dict[str, Any]) -> tuple[Any, str | None]:
    """The system ``factory`` builds from the spec, or None and why not."""
    try:
        return factory(spec, **options), None
    except Exception as exc:  # not this modality's system (or not buildable here at all)
        return None, str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def system_facts(row: Any, modality: str | None = None) -> SystemFacts:
    """A registered model's modality and type. The store keeps no modality with a model: it is
    ``camera`` when the spec builds as a steering system (:func:`~lidarfuzz.suts.registry.create_camera`)
    whose fingerprint is the one recorded, or when only that builds; else ``lidar`` (the detectors of
    :func:`~lidarfuzz.suts.registry.create`, and the systems consuming logs of
    :func:`~lidarfuzz.suts.registry.create_sequence`). ``modality``: known already (just registered).
    Kept per spec, options and fingerprint."""
    from lidarfuzz.suts.registry import create, create_camera, create_sequence, system_type

    options = dict(row.options or {})
    key = (row.spec, json.dumps(options, sort_keys=True, default=str), row.fingerprint)
    with _facts_lock:
        known = _facts.get(key)
    if known is not None:
        return known
    steering, _ = (None, None) if modality == "lidar" else _builds(create_camera, row.spec, options)
    detector, why = (None, None) if modality == "camera" else _builds(create, row.spec, options)
    if steering is not None and (detector is None or _fingerprint(steering) == row.fingerprint):
        system: Any = steering
    else:
        system = detector if detector is not None else _builds(create_sequence, row.spec, options)[0]
    if system is None:
        facts = SystemFacts(modality or "lidar", "unavailable", f"cannot be built here: {why}")
    else:
        code, label = system_type(system)
        facts = SystemFacts("camera" if system is steering else "lidar", code, label)
    with _facts_lock:
        _facts[key] = facts
    return facts


def _fingerprint(system: Any) -> str | None:
    try:
        return str(system.fingerprint())
    except Exception:  # weights missing: cannot say from the fingerprint
        return None


def model_row(row: Any, modality: str | None = None) -> dict[str, Any]:
    """A model as the API shows it: ``kind`` (how it was registered: builtin, plugin, onnx, open3d,
    ...), ``type`` and ``type_label`` (what kind of system it is) and ``modality``."""
    facts = system_facts(row, modality)
    return {"name": row.name, "spec": row.spec, "kind": model_kind(row.spec), "options": row.options,
            "fingerprint": row.fingerprint, "notes": row.notes, "added_at": iso(row.added_at),
            "modality": facts.modality, "type": facts.type, "type_label": facts.type_label}


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
    notes: str = Field(default="", max_length=NOTES_LIMIT, description="what it is: version, training, ...")
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


def _checked_as_uploaded(kind: str, path: Path, options: dict[str, Any], shown: str, modality: str) -> None:
    """:func:`_check_file`, its errors naming the user's file (``shown``), never where the server keeps it."""
    from lidarfuzz.errors import LidarfuzzError

    try:
        _check_file(kind, path, options, shown, modality)
    except LidarfuzzError as exc:
        text = str(exc)
        for where in (str(path.resolve()), str(path), str(path.parent.resolve()), str(path.parent)):
            text = text.replace(where, shown)
        text = text if text.startswith(shown) else f"{shown}: {text}"
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, text) from None


@router.post("/models/upload", status_code=status.HTTP_201_CREATED, openapi_extra=UPLOAD_FORM)
async def models_upload(ctx: Web, request: Request) -> dict[str, Any]:
    """Upload an ONNX model or an Open3D-ML checkpoint (multipart: ``name``, ``file``, optional
    ``kind``, ``options`` as JSON, ``notes``) and register it."""
    form = await request.form(max_files=1, max_fields=10)
    try:
        name = check_name(str(form.get("name") or ""), "name")
        given_notes = str(form.get("notes") or "").replace("\r\n", "\n").strip()  # a form's lines come as CRLF
        if len(given_notes) > NOTES_LIMIT:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"notes: {len(given_notes)} characters; at most {NOTES_LIMIT}")
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
            await run_in_threadpool(_checked_as_uploaded, kind, target, options, shown, modality)
            spec = f"{kind}:{target.resolve()}"
            notes = given_notes or f"uploaded: {printable(shown)}"  # a file's name may hold control characters
            row = await run_in_threadpool(lambda: add_model(ctx.store, name, spec, options, notes, modality=modality))
        except BaseException:
            remove_tree(folder, ctx.uploads)
            raise
    finally:
        await form.close()
    return model_row(row, modality)


def _model(ctx: WebContext, name: str) -> Any:
    """The model ``name``, or a 404 that says so (without the CLI's advice)."""
    try:
        return get_model(ctx.store, name)
    except NotFoundError:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"name: no model called {name!r} (deleted?)") from None


@router.get("/models/{name}")
async def models_get(ctx: Web, name: str) -> dict[str, Any]:
    """One model with its facts (as in the list) and ``used_by``: the tasks that run against it
    (``[{id, name}]``, oldest first; while there are any it cannot be removed)."""
    row = _model(ctx, name)
    out = await run_in_threadpool(model_row, row)
    out["used_by"] = [{"id": task_id, "name": task_name} for task_id, task_name in tasks_using(ctx.store, Model, name)]
    return out


@router.patch("/models/{name}")
async def models_patch(ctx: Web, name: str, body: NotesUpdate) -> dict[str, Any]:
    """Change a model's notes (the only thing that can change: its spec and options made its
    fingerprint; register another model for another configuration)."""
    _model(ctx, name)
    row = set_model_notes(ctx.store, name, body.notes)
    return await run_in_threadpool(model_row, row)


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
