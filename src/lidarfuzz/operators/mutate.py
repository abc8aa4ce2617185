"""Applying one operator to a frame file, a data set or a log, writing a new one (the source is never touched).

Every frame's concrete params are recorded, so each mutant can be replayed exactly:
``mutations.jsonl`` in a destination folder (one JSON object per frame: frame id,
operator spec, seed, params), or ``<destination>.mutations.jsonl`` next to a single
file or log.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.io.atomic import atomic_folder, write_text
from lidarfuzz.io.convert import FOLDER_TARGETS, ConvertResult, convert, destination_kind, write_scenes
from lidarfuzz.io.guards import describe
from lidarfuzz.io.open import open_dataset
from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.operators.base import Operator, generator
from lidarfuzz.operators.lidar.log import FrameAverage, interleave
from lidarfuzz.operators.registry import get
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


def build_operator(name: str, severity: int | None = None, params: dict[str, Any] | None = None,
                   ) -> Operator[Any, Any, Any]:
    """An operator by name at a severity, or with config fields (``*_range`` fields accept one number)."""
    cls = get(name)
    if severity is not None and params:
        raise LidarfuzzError("choose --severity or --param, not both")
    if not params:
        return cls.at_severity(3 if severity is None else severity)
    fields = dict(cls.at_severity(3).config.model_dump())
    for key, value in params.items():
        target = key if key in fields else f"{key}_range" if f"{key}_range" in fields else None
        if target is None:
            raise LidarfuzzError(f"{cls.name} has no parameter {key!r}; it has: {', '.join(fields)}")
        if target.endswith("_range") and not isinstance(value, list | tuple):
            value = (value, value)
        fields[target] = value
    try:
        operator = cls(**fields)
    except ValidationError as exc:
        raise LidarfuzzError(f"{cls.name}: {_first_error(exc)}") from None
    # A config can be valid yet draw impossible params (e.g. a deletion ratio of 2): try one draw.
    try:
        operator.sample(np.random.default_rng(0), Scene(PointCloud.empty()))
    except ValidationError as exc:
        raise LidarfuzzError(f"{cls.name}: the parameters you gave draw invalid values: {_first_error(exc)}") from None
    except Exception:
        pass
    return operator


def _first_error(exc: ValidationError) -> str:
    error = exc.errors()[0]
    where = ".".join(str(part) for part in error["loc"])
    return f"{where}: {error['msg']} (got {error.get('input')!r})" if where else str(error["msg"])


def parse_assignments(items: list[str]) -> dict[str, Any]:
    """``k=v`` strings; values are JSON when they parse as JSON, else strings."""
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise LidarfuzzError(f"--param {item!r}: expected key=value, e.g. ratio=0.2 or angle_range=[10,20]")
        key, raw = item.split("=", 1)
        try:
            out[key.strip()] = json.loads(raw)
        except json.JSONDecodeError:
            out[key.strip()] = raw
    return out


@dataclass
class MutationResult:
    conversion: ConvertResult
    record: Path


def mutate(src: str | PathLike[str], dst: str | PathLike[str], operator: Operator[Any, Any, Any], *, seed: int = 0,
           to: str | None = None, overwrite: bool = False,
           on_frame: Callable[[int, int], None] | None = None,
           options: DatasetOptions | None = None) -> MutationResult:
    """Write ``operator`` applied to every frame of ``src`` (read with data-set ``options``) into
    ``dst`` (any format ``convert`` writes).

    A folder destination is written into a temporary folder beside it and renamed at the end, its
    ``mutations.jsonl`` included: a failure (a bad frame half-way, the operator failing on a frame)
    leaves nothing at ``dst``.

    Raises:
        LidarfuzzError: ``dst`` is ``src``, inside it or holds it; a frame cannot be read, or the
            operator fails on one (naming the frame).
    """
    records: list[str] = []
    spec = operator.spec()
    src_path, destination = Path(src), Path(dst)
    _refuse_overlap(src_path, destination)

    def transform(scene: Scene) -> Scene:
        rng = generator(seed, scene.frame_id or len(records), 0, 0)
        with _applying(operator.name, src_path, f"on frame {scene.frame_id or len(records)}"):
            mutant, params = operator(scene, rng)
        records.append(json.dumps({"frame_id": scene.frame_id, "operator": spec, "seed": seed,
                                   "params": params.model_dump(mode="json")}))
        return mutant

    kind = _destination_kind(destination, to)
    if kind in FOLDER_TARGETS:
        with atomic_folder(destination, overwrite=overwrite) as tmp:
            written = convert(src_path, tmp, to=kind, overwrite=True, on_frame=on_frame, transform=transform,
                              options=options)
            write_text(tmp / "mutations.jsonl", "\n".join(records) + "\n", overwrite=True)
        return MutationResult(ConvertResult(destination, written.target, written.frames),
                              destination / "mutations.jsonl")
    result = convert(src_path, destination, to=to, overwrite=overwrite, on_frame=on_frame, transform=transform,
                     options=options)
    record = destination.with_name(destination.name + ".mutations.jsonl")
    write_text(record, "\n".join(records) + "\n", overwrite=True)
    return MutationResult(result, record)


def _destination_kind(dst: Path, to: str | None) -> str:
    try:
        return destination_kind(dst, to)
    except ValueError as exc:  # an unknown --to
        raise LidarfuzzError(str(exc)) from None


def _refuse_overlap(src: Path, dst: Path) -> None:
    """Originals are never modified: refuse a destination that is the source, inside it, or holds it
    (a folder destination replaced at the end would take the source with it)."""
    source, target = src.resolve(), dst.resolve()
    if target == source or source in target.parents or target in source.parents:
        raise LidarfuzzError(f"{dst}: the destination is the source, inside it or holds it; "
                             "originals are never modified (choose a new path)")


@contextlib.contextmanager
def _applying(name: str, src: Path, where: str) -> Iterator[None]:
    """An operator failing on a frame: one line naming the operator, the source and ``where`` (the frame)."""
    try:
        yield
    except LidarfuzzError:
        raise
    except Exception as err:
        raise LidarfuzzError(f"{src}: {name} failed {where}: {describe(err)}") from err


def is_frame_average(name: str) -> bool:
    return name.strip().lower().replace("-", "_") in ("avg", "frame_average")


def mutate_log(src: str | PathLike[str], dst: str | PathLike[str], operator: Operator[Any, Any, Any] | FrameAverage,
               *, seed: int = 0, to: str | None = None, overwrite: bool = False,
               options: DatasetOptions | None = None) -> ConvertResult:
    """A new log from an ordered source (a log, or a data set with timestamps): each mutant right
    after its source frame, or for AVG each averaged frame between its two sources (Neves et al.)."""
    src_path, dst_path = Path(src), Path(dst)
    _refuse_overlap(src_path, dst_path)
    kind = _destination_kind(dst_path, to)
    dataset = open_dataset(src_path, options=options)
    if not dataset.ordered:
        raise LidarfuzzError(f"{src_path}: not a log (no timestamps): --interleave needs ordered frames")
    scenes = _named_failures(interleave(iter(dataset), operator, seed=seed), operator.name, src_path)
    if kind not in FOLDER_TARGETS:
        return write_scenes(scenes, dst_path, kind, overwrite=overwrite)
    with atomic_folder(dst_path, overwrite=overwrite) as tmp:  # a failure mid-log leaves no partial folder
        written = write_scenes(scenes, tmp, kind, overwrite=True)
    return ConvertResult(dst_path, written.target, written.frames)


def _named_failures(scenes: Iterator[Scene], name: str, src: Path) -> Iterator[Scene]:
    """``scenes``, with an operator's failure turned into one line naming the last frame written before it."""
    where = "on the first frame"
    while True:
        with _applying(name, src, where):
            scene = next(scenes, None)
        if scene is None:
            return
        where = f"after frame {scene.frame_id}" if scene.frame_id else "after an unnamed frame"
        yield scene
