"""What ``lidarfuzz info`` reports: counts, channels, value ranges, classes, problems.

Every frame is loaded (or the first ``limit``), so content problems — a bad label
line, a calib file missing a key, NaN coordinates — are found and listed next to
the structural ones, each naming its file.
"""

from __future__ import annotations

import warnings
from collections import Counter
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFiniteWarning, Problem
from lidarfuzz.io.dataset import Log
from lidarfuzz.io.open import open_dataset, source_kind
from lidarfuzz.io.options import DatasetOptions


@dataclass
class ChannelStats:
    minimum: float = float("inf")
    maximum: float = float("-inf")

    def update(self, values: np.ndarray) -> None:
        if values.size:
            self.minimum = min(self.minimum, float(values.min()))
            self.maximum = max(self.maximum, float(values.max()))


@dataclass
class DatasetReport:
    """The result of inspecting a frame file, a data set folder or a log."""

    path: str
    kind: str
    format: str
    frames: int
    inspected: int = 0
    unreadable: int = 0
    ordered: bool = False
    time_span: tuple[float, float] | None = None
    has_poses: bool = False
    points_min: int = 0
    points_max: int = 0
    points_total: int = 0
    channels: dict[str, ChannelStats] = field(default_factory=dict)
    classes: Counter[str] = field(default_factory=Counter)
    labelled_frames: int = 0
    unlabelled_frames: int = 0  # no label file in a data set that has labels
    calibrated_frames: int = 0
    roi_frames: int = 0
    dropped_nonfinite: int = 0
    problems: list[Problem] = field(default_factory=list)
    log: dict[str, Any] | None = None

    @property
    def errors(self) -> list[Problem]:
        return [p for p in self.problems if p.severity == "error"]

    def as_dict(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "kind": self.kind,
            "format": self.format,
            "frames": self.frames,
            "inspected": self.inspected,
            "unreadable": self.unreadable,
            "ordered": self.ordered,
            "time_span": list(self.time_span) if self.time_span else None,
            "has_poses": self.has_poses,
            "points": {"min": self.points_min, "max": self.points_max, "total": self.points_total},
            "channels": {k: {"min": v.minimum, "max": v.maximum} for k, v in self.channels.items()},
            "classes": dict(sorted(self.classes.items())),
            "labelled_frames": self.labelled_frames,
            "unlabelled_frames": self.unlabelled_frames,
            "calibrated_frames": self.calibrated_frames,
            "roi_frames": self.roi_frames,
            "dropped_nonfinite": self.dropped_nonfinite,
            "problems": [
                {"severity": p.severity, "path": p.path, "line": p.line, "message": p.message}
                for p in self.problems
            ],
            "log": self.log,
        }


def inspect_source(path: str | PathLike[str], *, topic: str | None = None, limit: int | None = None,
                   options: DatasetOptions | None = None) -> DatasetReport:
    """Inspect anything :func:`~lidarfuzz.io.open_dataset` opens (with data-set ``options``);
    problems are collected, not raised. Frames without labels in a labelled data set are
    counted (a warning: only AP needs labels); doubts about a layout the user chose are warnings.

    Raises:
        DataFormatError: Only when the source cannot be opened at all.
    """
    path = Path(path)
    kind = source_kind(path)
    log_info = None
    if kind == "log":
        from lidarfuzz.io.logs import inspect_bag

        log_info = inspect_bag(path)
    dataset = open_dataset(path, topic=topic, strict=False, options=options)
    report = DatasetReport(
        path=str(path), kind=kind, format=dataset.format, frames=len(dataset), ordered=dataset.ordered, log=log_info
    )
    report.problems.extend(dataset.problems())
    if isinstance(dataset, Log) and len(dataset):
        stamps = dataset.timestamps()
        report.time_span = (float(stamps.min()), float(stamps.max()))  # each Log reports its own order problems
        report.has_poses = dataset.poses() is not None

    points_min: int | None = None
    ids = list(dataset.frame_ids())
    if limit is not None:
        ids = ids[:limit]
    for frame_id in ids:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NonFiniteWarning)
                scene = dataset.load(frame_id)
        except DataFormatError as exc:
            hint = f" ({exc.hint})" if exc.hint else ""  # e.g. the layout that fits a misread scan
            report.problems.append(Problem("error", str(exc.path), exc.message + hint, exc.line))
            report.unreadable += 1
            continue
        report.inspected += 1
        n = len(scene.points)
        points_min = n if points_min is None else min(points_min, n)
        report.points_max = max(report.points_max, n)
        report.points_total += n
        for i, name in enumerate(scene.points.channels):
            report.channels.setdefault(name, ChannelStats()).update(scene.points.data[:, i])
        if len(scene.boxes):
            report.labelled_frames += 1
            report.classes.update(str(c) for c in scene.boxes.labels)
        report.unlabelled_frames += scene.metadata.get("labelled") is False and dataset.has_labels()
        doubts = scene.metadata.get("layout_doubts")
        if doubts:
            report.problems.append(Problem("warning", str(scene.metadata.get("source", path)),
                                           f"read as {scene.metadata.get('layout')} although "
                                           + "; ".join(str(d) for d in doubts)))
        report.calibrated_frames += scene.calib is not None
        report.roi_frames += scene.roi is not None
        dropped = int(scene.metadata.get("dropped_nonfinite", 0))
        if dropped:
            report.dropped_nonfinite += dropped
            report.problems.append(
                Problem("warning", str(scene.metadata.get("source", path)),
                        f"{dropped} point(s) with NaN/Inf coordinates (dropped when read)")
            )
        if n == 0:
            report.problems.append(Problem("warning", str(scene.metadata.get("source", path)), "empty point cloud"))
    report.points_min = points_min or 0
    return report
