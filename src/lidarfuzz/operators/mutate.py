"""Applying one operator to a frame file, a data set or a log, writing a new one (the source is never touched).

Every frame's concrete params are recorded, so each mutant can be replayed exactly:
``mutations.jsonl`` in a destination folder (one JSON object per frame: frame id,
operator spec, seed, params), or ``<destination>.mutations.jsonl`` next to a single
file or log.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.io.atomic import atomic_folder, write_text
from lidarfuzz.io.convert import FOLDER_TARGETS, ConvertResult, convert, destination_kind, write_scenes
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
    ``dst`` (any format ``convert`` writes)."""
    records: list[str] = []
    spec = operator.spec()

    def transform(scene: Scene) -> Scene:
        rng = generator(seed, scene.frame_id or len(records), 0, 0)
        mutant, params = operator(scene, rng)
        records.append(json.dumps({"frame_id": scene.frame_id, "operator": spec, "seed": seed,
                                   "params": params.model_dump(mode="json")}))
        return mutant

    result = convert(src, dst, to=to, overwrite=overwrite, on_frame=on_frame, transform=transform, options=options)
    destination = Path(dst)
    record = destination / "mutations.jsonl" if destination.is_dir() else destination.with_name(
        destination.name + ".mutations.jsonl")
    write_text(record, "\n".join(records) + "\n", overwrite=True)
    return MutationResult(result, record)


def is_frame_average(name: str) -> bool:
    return name.strip().lower().replace("-", "_") in ("avg", "frame_average")


def mutate_log(src: str | PathLike[str], dst: str | PathLike[str], operator: Operator[Any, Any, Any] | FrameAverage,
               *, seed: int = 0, to: str | None = None, overwrite: bool = False,
               options: DatasetOptions | None = None) -> ConvertResult:
    """A new log from an ordered source (a log, or a data set with timestamps): each mutant right
    after its source frame, or for AVG each averaged frame between its two sources (Neves et al.)."""
    src_path, dst_path = Path(src), Path(dst)
    if dst_path.resolve() == src_path.resolve() or src_path.resolve() in dst_path.resolve().parents:
        raise LidarfuzzError(f"{dst_path}: the destination is the source or inside it; originals are never modified")
    dataset = open_dataset(src_path, options=options)
    if not dataset.ordered:
        raise LidarfuzzError(f"{src_path}: not a log (no timestamps): --interleave needs ordered frames")
    kind = destination_kind(dst_path, to)
    if kind not in FOLDER_TARGETS:
        return write_scenes(interleave(iter(dataset), operator, seed=seed), dst_path, kind, overwrite=overwrite)
    with atomic_folder(dst_path, overwrite=overwrite) as tmp:  # a failure mid-log leaves no partial folder
        written = write_scenes(interleave(iter(dataset), operator, seed=seed), tmp, kind, overwrite=True)
    return ConvertResult(dst_path, written.target, written.frames)
