"""``/api/datasets``: list, upload (validated by ``inspect_source``), generate with the simulator, one
data set's detail (its labels counted, the tasks using it), its notes changed (``PATCH``), forget.

Uploads are stored under ``<workspace>/uploads/<generated id>/`` and never executed:

* one ``.zip`` — a KITTI layout (or a folder of frames, or a ROS2 bag folder), extracted after
  every member is checked (:func:`lidarfuzz.web.security.extract_zip`);
* point-cloud files, with KITTI label and calibration files for ``.bin`` frames (sorted into
  ``velodyne/``, ``label_2/`` and ``calib/`` by content) — or frames of any format alone;
* one ROS1 bag or MCAP file;
* camera images (``.png``, ``.jpg``) with one CSV of steering angles (an image column and a
  steering column), kept side by side.

``modality`` says which sensor's frames a data set is read as: ``lidar`` (point clouds), ``camera``
(images: a KITTI folder's ``image_2/``, Udacity, images + CSV, the image topic of a bag), or by
default what the data holds (images only: the camera; anything with point clouds: LiDAR).

Before it is recorded the data is inspected as ``lidarfuzz info`` does, in a worker process
(:mod:`lidarfuzz.web.inspection`: a reader that aborts cannot take the server down); any error
makes the upload a 422 that lists every problem with its file (relative to the upload) and line.
"""

from __future__ import annotations

import json
import shutil
import threading
import uuid
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException, Request, status
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import UploadFile

from lidarfuzz.errors import DataFormatError
from lidarfuzz.store.errors import NotFoundError
from lidarfuzz.store.inventory import (
    add_dataset,
    dataset_options,
    get_dataset,
    list_datasets,
    open_registered,
    printable,
    remove_dataset,
    set_dataset_notes,
    tasks_using,
)
from lidarfuzz.store.models import Dataset
from lidarfuzz.web.context import WebContext, web
from lidarfuzz.web.events import iso
from lidarfuzz.web.inspection import inspector, relative
from lidarfuzz.web.jobs import jobs_of
from lidarfuzz.web.security import check_name, extract_zip, remove_tree, safe_component, within

router = APIRouter(tags=["datasets"])
Web = Annotated[WebContext, Depends(web)]

FRAME_SUFFIXES = (".bin", ".pcd", ".ply", ".las", ".laz", ".npy", ".npz")
LOG_SUFFIXES = (".bag", ".mcap")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
#: KITTI's camera folders: a zip holding one alone is that layout (images need no calib/), not a
#: folder's zip (a zip of velodyne/ alone is still read as the folder of frames it holds)
KITTI_FOLDERS = ("image_2", "image_3")
UPLOAD_FORM = {"requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
    "type": "object", "required": ["name", "files"],
    "properties": {"name": {"type": "string", "description": "a name for the data set"},
                   "notes": {"type": "string"},
                   "layout": {"type": "string", "description": "point layout of .bin scans: kitti, nuscenes, "
                                                               "… or columns such as x,y,z,intensity,ring:f4"},
                   "allow_unlabelled": {"type": "boolean", "description": "campaigns may run frames without "
                                                                          "labels (AP from the labelled ones)"},
                   "modality": {"type": "string", "enum": ["", "lidar", "camera"],
                                "description": "read the data as point clouds (lidar) or images (camera); "
                                               "default: what it holds"},
                   "files": {"type": "array", "items": {"type": "string", "format": "binary"},
                             "description": "one .zip; or frames (+ KITTI label and calib files); or one "
                                            ".bag / .mcap; or images + one CSV of steering angles"}}}}}}}


#: The longest notes a data set or model keeps (characters)
NOTES_LIMIT = 10_000


class NotesUpdate(BaseModel):
    """A change to a data set's or model's notes (``PATCH``)."""

    model_config = ConfigDict(extra="forbid")

    notes: str = Field(max_length=NOTES_LIMIT, description="free text: where it came from, what it is for, ...")


def dataset_row(row: Any, uploads: Path) -> dict[str, Any]:
    options = dict(row.options or {})
    return {"name": row.name, "status": "ready", "format": row.format, "frame_count": row.frame_count,
            "path": row.path, "notes": row.notes, "added_at": iso(row.added_at),
            "uploaded": within(Path(row.path), uploads), "options": options,
            "modality": options.get("modality", "lidar")}


@router.get("/datasets")
def datasets_list(ctx: Web) -> dict[str, Any]:
    """Recorded data sets, and those the simulator is rendering (``status`` generating / failed)."""
    rows = [dataset_row(row, ctx.uploads) for row in list_datasets(ctx.store)]
    names = {r["name"] for r in rows}
    rows += [job.as_dict() for job in jobs_of(ctx).jobs() if job.name not in names]
    return {"items": sorted(rows, key=lambda r: r["name"])}


def _log_rows(ctx: WebContext) -> dict[str, Any]:
    from lidarfuzz.structural.logs import open_log

    logs, refused = [], []
    for row in list_datasets(ctx.store):
        try:
            log = open_log(row.path, options=dataset_options(row))
        except DataFormatError as exc:  # no order (NotALogError), or not readable any more
            refused.append({"name": row.name, "reason": exc.message + (f" ({exc.hint})" if exc.hint else "")})
            continue
        logs.append({"name": row.name, "frame_count": len(log), "order": log.order, "format": log.format})
    return {"items": logs, "refused": refused}


@router.get("/datasets/logs")
async def datasets_logs(ctx: Web) -> dict[str, Any]:
    """The recorded data sets that are logs (they have an order: ``lidarfuzz.structural.logs.open_log``
    opens them), for a structural task: ``{"items": [{name, frame_count, order, format}],
    "refused": [{name, reason}]}`` (``reason``: why a data set has no order)."""
    return await run_in_threadpool(_log_rows, ctx)


def _name_free(ctx: WebContext, name: str) -> None:
    check_name(name, "name")
    job = jobs_of(ctx).get(name)
    if job is not None or name in {d.name for d in list_datasets(ctx.store)}:
        raise HTTPException(status.HTTP_409_CONFLICT, f"name: a data set called {name!r} exists already")


# -- labels ----------------------------------------------------------------------------------
#: Frames loaded to count labels when the data set does not say which frames have them (a KITTI
#: ``label_2/`` does; point-cloud files, ``.npz`` scenes and images are read one by one)
LABEL_SCAN = 500
_labels: dict[tuple[str, str, int], dict[str, Any]] = {}
_labels_lock = threading.Lock()


def _label_warning(facts: dict[str, Any], allow_unlabelled: bool) -> str | None:
    """One line for a data set some or all of whose frames have no labels, saying what that
    costs (AP, or a camera data set's MSE and DeepTest relation) and what still runs."""
    labelled, checked, frames = facts["labelled"], facts["checked"], facts["frames"]
    if labelled >= checked:
        return None
    scope = f"{labelled} of {checked} {facts['unit']}" + (f" (the first {checked} of {frames} checked)"
                                                          if checked < frames else "")
    if facts["unit"] == "images":
        if not labelled:
            return (f"No image has a steering label ({scope}): MSE and DeepTest's relation compare outputs with "
                    "the labels, so they have nothing to score")
        return f"Only {scope} have a steering label: MSE and DeepTest's relation are computed on the labelled ones"
    if not labelled:
        return (f"No frame has labels ({scope}): AP needs labels and will be shown as — (no labels); the "
                "metamorphic relations still run")
    if facts["label_files"] and not allow_unlabelled:
        return (f"Only {scope} have a label file: AP needs labels, and tasks on this data set are refused "
                "because it does not allow unlabelled frames (upload it again with 'Frames without labels' "
                "ticked to score AP on the labelled ones); the relations still run")
    return f"Only {scope} have labels: AP is scored on the labelled frames; the relations run on all"


def label_facts(row: Dataset, report: Any = None) -> dict[str, Any]:
    """How many of a data set's frames have labels: ``{"frames", "checked", "labelled", "unit",
    "label_files", "warning"}`` (``checked``: frames looked at — all of a KITTI folder, whose
    ``label_2/`` says which frames have a label file, else up to :data:`LABEL_SCAN` loaded;
    ``warning``: None when all checked have labels). ``report``: the upload's inspection of every
    frame, when there is one. Kept per path, options and frame count."""
    from lidarfuzz.io.inspect import inspect_source

    key = (row.path, json.dumps(row.options or {}, sort_keys=True, default=str), row.frame_count)
    with _labels_lock:
        known = _labels.get(key)
    if known is not None:
        return known
    options = dataset_options(row)
    facts: dict[str, Any] | None = None
    if options.modality != "camera":
        dataset = open_registered(row)
        if dataset.has_labels():
            frames = len(dataset.frame_ids())
            facts = {"frames": frames, "checked": frames, "labelled": frames - len(dataset.unlabelled_ids()),
                     "unit": "frames", "label_files": True}
    if facts is None:
        if report is None:
            report = inspect_source(row.path, options=options, limit=LABEL_SCAN)
        camera = report.images is not None
        facts = {"frames": row.frame_count, "checked": report.inspected, "unit": "images" if camera else "frames",
                 "labelled": report.images.labelled if camera else report.labelled_frames, "label_files": False}
    facts["warning"] = _label_warning(facts, options.allow_unlabelled)
    with _labels_lock:
        _labels[key] = facts
    return facts


# -- upload ----------------------------------------------------------------------------------
async def _save(upload: UploadFile, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with target.open("xb") as out:
        while chunk := await upload.read(1 << 20):
            out.write(chunk)


async def _store_images(files: list[UploadFile], names: list[str], suffixes: list[str], folder: Path) -> Path:
    """Camera images and their CSV of steering angles, side by side in one folder (the CSV names
    the images relative to itself)."""
    other = [n for n, s in zip(names, suffixes, strict=True) if s not in (*IMAGE_SUFFIXES, ".csv")]
    if other:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{other[0]}: images go with one CSV of steering angles, nothing else; upload other "
                            "layouts as one .zip")
    tables = [n for n, s in zip(names, suffixes, strict=True) if s == ".csv"]
    if len(tables) != 1:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"files: images need exactly one CSV of steering angles beside them, got {len(tables)}"
                            + (f" ({', '.join(tables)})" if tables else ""))
    root = folder / "data"
    root.mkdir()
    seen: set[str] = set()
    for upload, name in zip(files, names, strict=True):
        target = safe_component(name)
        if target in seen:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"{name}: uploaded twice")
        seen.add(target)
        await _save(upload, root / target)
    return root


def _is_calib(path: Path) -> bool:
    head = path.read_bytes()[:4096].decode("utf-8", "replace")
    return "Tr_velo_to_cam" in head or head.lstrip().startswith(("P0:", "P2:", "R0_rect:"))


async def _store_files(ctx: WebContext, files: list[UploadFile], folder: Path) -> tuple[Path, list[str]]:
    """Write the uploaded files into ``folder`` in a layout lidarfuzz opens; returns its root and
    the original file names."""
    names = [Path(f.filename or "file").name for f in files]
    suffixes = [Path(n).suffix.lower() for n in names]
    if len(files) == 1 and suffixes[0] == ".zip":
        archive = folder / "upload.zip"
        await _save(files[0], archive)
        root = folder / "data"
        root.mkdir()
        await run_in_threadpool(extract_zip, archive, root, ctx.limits)
        archive.unlink()
        entries = [p for p in root.iterdir()]
        if len(entries) == 1 and entries[0].is_dir() and entries[0].name not in KITTI_FOLDERS:
            root = entries[0]  # the zip of a folder (not of KITTI's image_2/ alone)
        return root, names
    if len(files) == 1 and suffixes[0] in LOG_SUFFIXES:
        target = folder / f"log{suffixes[0]}"
        await _save(files[0], target)
        return target, names
    if any(s in IMAGE_SUFFIXES or s == ".csv" for s in suffixes):
        return await _store_images(files, names, suffixes, folder), names
    unknown = [n for n, s in zip(names, suffixes, strict=True) if s not in (*FRAME_SUFFIXES, ".txt")]
    if unknown:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"{unknown[0]}: unsupported file type; upload one .zip (KITTI layout), point-cloud files "
                            f"({', '.join(FRAME_SUFFIXES)}) with KITTI label/calib .txt files, or one .bag / .mcap")
    frames = [s for s in suffixes if s in FRAME_SUFFIXES]
    if not frames:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "files: no point-cloud file among them")
    kitti = all(s == ".bin" for s in frames)
    if not kitti and ".txt" in suffixes:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            "files: label files go with .bin frames (KITTI layout); for other formats upload the "
                            "frames alone, .npz scenes (they hold their boxes), or a zip in KITTI layout")
    root = folder / "data"
    seen: set[Path] = set()
    for upload, name, suffix in zip(files, names, suffixes, strict=True):
        stem = safe_component(Path(name).stem)
        staged = folder / "staging" / uuid.uuid4().hex
        await _save(upload, staged)
        if not kitti:
            target = root / f"{stem}{suffix}"
        elif suffix == ".bin":
            target = root / "velodyne" / f"{stem}.bin"
        else:
            target = root / ("calib" if _is_calib(staged) else "label_2") / f"{stem}.txt"
        if target in seen:
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"{name}: a second file for {target.relative_to(root)}")
        seen.add(target)
        target.parent.mkdir(parents=True, exist_ok=True)
        staged.rename(target)
    shutil.rmtree(folder / "staging", ignore_errors=True)
    return root, names


def _inspect(ctx: WebContext, root: Path, base: Path, options: Any = None) -> tuple[list[dict[str, Any]], Any]:
    """The upload's problems and report, from the inspecting worker process (a reader that
    crashes, hangs or exhausts memory there is a problem of the upload, not the server's end)."""
    return inspector(ctx.limits.inspect_memory, ctx.limits.inspect_seconds).inspect(root, base, options)


def _options(form: Any) -> Any:
    """Data-set options from the upload form's ``layout`` and ``allow_unlabelled`` fields."""
    from lidarfuzz.errors import LidarfuzzError
    from lidarfuzz.io.options import options_from_flags

    allow = str(form.get("allow_unlabelled") or "").strip().lower() in ("1", "true", "yes", "on")
    try:
        return options_from_flags(str(form.get("layout") or "") or None, allow)
    except LidarfuzzError as exc:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc).replace("--layout", "layout", 1)) from None


def _notes(form: Any) -> str:
    """The upload form's ``notes`` (at most :data:`NOTES_LIMIT` characters)."""
    notes = str(form.get("notes") or "").replace("\r\n", "\n").strip()  # a form sends a textarea's lines as CRLF
    if len(notes) > NOTES_LIMIT:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"notes: {len(notes)} characters; at most {NOTES_LIMIT}")
    return notes


def _modality(form: Any) -> str | None:
    """The upload form's ``modality``: ``lidar``, ``camera`` or None (what the data holds)."""
    value = str(form.get("modality") or "").strip().lower()
    if value not in ("", "lidar", "camera"):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"modality: expected lidar or camera (or nothing: what the data holds), got {value!r}")
    return value or None


def _with_modality(options: Any, root: Path, modality: str | None) -> Any:
    """``options`` reading ``root`` as ``modality``'s data (by default what it holds)."""
    from lidarfuzz.io.open import source_modality

    if modality is None:
        try:
            modality = source_modality(root)
        except DataFormatError:
            modality = "lidar"  # inspecting it says what is wrong
    if modality == "camera" and options.layout is not None:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            "layout: a point layout is for LiDAR scans; camera images have none")
    return options.model_copy(update={"modality": modality})


def _problem_line(problem: dict[str, Any]) -> str:
    where = problem["file"] + (f":{problem['line']}" if problem["line"] is not None else "")
    return f"{where}: {problem['message']}"


def _record(ctx: WebContext, name: str, root: Path, notes: str, options: Any, base: Path) -> Dataset:
    """:func:`add_dataset`, its errors naming the upload's files (never the server's folder)."""
    from lidarfuzz.errors import LidarfuzzError

    try:
        return add_dataset(ctx.store, name, root, notes, options)
    except DataFormatError as exc:
        where = relative(str(exc.path), base) + (f":{exc.line}" if exc.line is not None else "")
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, f"{where}: {relative(exc.message, base)}") from None
    except LidarfuzzError as exc:
        if "exists already" in str(exc):  # another upload took the name meanwhile
            raise HTTPException(status.HTTP_409_CONFLICT, f"name: a data set called {name!r} exists already") from None
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, relative(str(exc), base)) from None


@router.post("/datasets/upload", status_code=status.HTTP_201_CREATED, openapi_extra=UPLOAD_FORM,
             responses={422: {"description": "every problem found, each naming its file and line"}})
async def datasets_upload(ctx: Web, request: Request) -> Any:
    """Upload a data set (multipart: ``name``, ``files``); validated, then recorded. A 422 has
    ``detail`` (one ``file:line: message`` per line) and ``problems`` (the same as objects)."""
    form = await request.form(max_files=100_000, max_fields=20)
    name = str(form.get("name") or "")
    _name_free(ctx, name)
    given_notes = _notes(form)
    options = _options(form)
    modality = _modality(form)
    files = [f for f in form.getlist("files") + form.getlist("file") if isinstance(f, UploadFile)]
    if not files:
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, "files: no file uploaded")
    folder = ctx.uploads / uuid.uuid4().hex
    folder.mkdir(parents=True)
    try:
        root, names = await _store_files(ctx, files, folder)
        base = root if root.is_dir() else root.parent
        options = _with_modality(options, root, modality)
        problems, report = await run_in_threadpool(_inspect, ctx, root, base, options)
        errors = [p for p in problems if p["severity"] == "error"]
        if errors:
            remove_tree(folder, ctx.uploads)
            return JSONResponse({"detail": "\n".join(_problem_line(p) for p in errors), "problems": errors},
                                status_code=422)
        shown = [printable(n) for n in names[:5]]  # a file's name may hold control characters
        notes = given_notes or f"uploaded: {', '.join(shown)}" + (
            f" and {len(names) - 5} more" if len(names) > 5 else "")
        row = await run_in_threadpool(_record, ctx, name, root, notes, options, base)
    except BaseException:
        remove_tree(folder, ctx.uploads)
        raise
    finally:
        await form.close()
    out = dataset_row(row, ctx.uploads)
    out["warnings"] = [_problem_line(p) for p in problems if p["severity"] != "error"]
    out["frames_inspected"] = report.inspected if report is not None else 0
    out["labels"] = await run_in_threadpool(label_facts, row, report)
    return out


# -- generate --------------------------------------------------------------------------------
class GenerateRequest(BaseModel):
    """What ``lidarfuzz gen`` renders: independent procedural scenes, or one scene driven through as a
    log (``--sequence``), or a drive log with a stop and a turn (``--drive``)."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description="a name for the data set")
    frames: int = Field(default=10, ge=1, le=10_000, description="number of frames")
    seed: int = Field(default=0, ge=0, description="the same seed gives the same bytes")
    kind: Literal["urban", "suburban"] | None = Field(default=None, description="scene kind (default: a mix)")
    sensor: str | None = Field(default=None, description="a sensor preset (default HDL-64E)")
    scenes: Literal["independent", "sequence", "drive"] = Field(
        default="independent", description="independent scenes; one scene driven through at 10 Hz (a log with "
                                           "timestamps and poses); or a drive log: a stop, a turn, pedestrians")
    camera: Literal["640x480", "1242x375"] | None = Field(
        default=None, description="also render camera 2's images at this size (image_2/, depth_2/, steering.csv: "
                                  "lidarfuzz gen --camera) and record the data set as a camera one")


@router.post("/datasets/generate", status_code=status.HTTP_202_ACCEPTED)
def datasets_generate(ctx: Web, body: GenerateRequest) -> dict[str, Any]:
    """Render a labelled data set with the simulator in the background; it is listed as
    ``generating`` (done/total frames) until it is recorded (with ``camera``: as a camera data set of
    the rendered images and their steering labels)."""
    from lidarfuzz.sim.sensor import preset_names

    _name_free(ctx, body.name)
    if body.sensor is not None and body.sensor not in preset_names():
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"sensor: {body.sensor!r} is not a preset ({', '.join(preset_names())})")
    camera = None if body.camera is None else (int(body.camera.split("x")[0]), int(body.camera.split("x")[1]))
    job = jobs_of(ctx).start(body.name, body.frames, body.seed, body.kind, body.sensor, body.scenes, camera)
    return job.as_dict()


def _dataset(ctx: WebContext, name: str) -> Dataset:
    """The data set ``name``, or a 404 that says so (without the CLI's advice)."""
    try:
        return get_dataset(ctx.store, name)
    except NotFoundError:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"name: no data set called {name!r} (deleted?)") from None


def _detail(ctx: WebContext, name: str) -> dict[str, Any]:
    job = jobs_of(ctx).get(name)
    if job is not None and name not in {d.name for d in list_datasets(ctx.store)}:
        return {**job.as_dict(), "used_by": [], "labels": None}
    row = _dataset(ctx, name)
    out = dataset_row(row, ctx.uploads)
    tasks = tasks_using(ctx.store, Dataset, name)
    out["used_by"] = [{"id": task_id, "name": task_name} for task_id, task_name in tasks]
    try:
        out["labels"] = label_facts(row)
    except DataFormatError as exc:  # its files changed since it was recorded
        out["labels"] = None
        out["labels_error"] = exc.message
    return out


@router.get("/datasets/{name}")
async def datasets_get(ctx: Web, name: str) -> dict[str, Any]:
    """One data set with its facts (as in the list), ``labels`` (how many frames have labels, and a
    ``warning`` when not all do: :func:`label_facts`) and ``used_by``: the tasks that run on it
    (``[{id, name}]``, oldest first; while there are any it cannot be forgotten)."""
    return await run_in_threadpool(_detail, ctx, name)


@router.patch("/datasets/{name}")
def datasets_patch(ctx: Web, name: str, body: NotesUpdate) -> dict[str, Any]:
    """Change a data set's notes (its frames, path and options stay as they were recorded)."""
    _dataset(ctx, name)
    return dataset_row(set_dataset_notes(ctx.store, name, body.notes), ctx.uploads)


@router.delete("/datasets/{name}", status_code=status.HTTP_204_NO_CONTENT)
def datasets_delete(ctx: Web, name: str) -> None:
    """Forget a data set; files the app stored (under ``uploads/``) are removed, others stay."""
    jobs = jobs_of(ctx)
    job = jobs.get(name)
    if job is not None:
        if job.status == "generating":
            raise HTTPException(status.HTTP_409_CONFLICT, f"data set {name!r} is being generated; wait for it")
        jobs.dismiss(name)
        remove_tree(job.path, ctx.uploads)
        return
    row = get_dataset(ctx.store, name)
    remove_dataset(ctx.store, name)
    ctx.forget_dataset(row.path)
    path = Path(row.path)
    if within(path, ctx.uploads):
        top = ctx.uploads.resolve() / path.resolve().relative_to(ctx.uploads.resolve()).parts[0]
        remove_tree(top, ctx.uploads)
