"""What ``lidarfuzz info`` reports: counts, channels, value ranges, classes, problems.

Every frame is loaded (or the first ``limit``), so content problems — a bad label
line, a calib file missing a key, NaN coordinates — are found and listed next to
the structural ones, each naming its file. A camera data set (``modality`` camera, or a
source that holds only images) is reported by its images instead: their sizes, the steering
range, how many have a label, depth and a camera matrix.
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
from lidarfuzz.io.open import open_dataset, source_kind, source_modality
from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.scene.image import ImageSample


@dataclass
class ChannelStats:
    minimum: float = float("inf")
    maximum: float = float("-inf")

    def update(self, values: np.ndarray) -> None:
        if values.size:
            self.minimum = min(self.minimum, float(values.min()))
            self.maximum = max(self.maximum, float(values.max()))


@dataclass
class ImageStats:
    """What the images of a camera data set are like (the inspected ones)."""

    sizes: Counter[tuple[int, int]] = field(default_factory=Counter)  # (height, width) → images
    steering: ChannelStats = field(default_factory=ChannelStats)
    labelled: int = 0
    with_depth: int = 0
    with_intrinsics: int = 0

    def add(self, sample: ImageSample) -> None:
        self.sizes[sample.shape] += 1
        if sample.steering is not None:
            self.labelled += 1
            self.steering.update(np.array([sample.steering]))
        self.with_depth += sample.depth is not None
        self.with_intrinsics += sample.intrinsics is not None

    def as_dict(self) -> dict[str, Any]:
        return {
            "sizes": [{"height": h, "width": w, "images": n} for (h, w), n in sorted(self.sizes.items())],
            "steering": {"min": self.steering.minimum, "max": self.steering.maximum} if self.labelled else None,
            "labelled": self.labelled,
            "with_depth": self.with_depth,
            "with_intrinsics": self.with_intrinsics,
        }


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
    modality: str = "lidar"
    images: ImageStats | None = None  # the camera modality's statistics

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
            "modality": self.modality,
            "images": self.images.as_dict() if self.images is not None else None,
        }


def inspect_source(path: str | PathLike[str], *, topic: str | None = None, limit: int | None = None,
                   options: DatasetOptions | None = None, modality: str | None = None,
                   **image_options: Any) -> DatasetReport:
    """Inspect anything :func:`~lidarfuzz.io.open_dataset` opens (with data-set ``options``);
    problems are collected, not raised. Frames without labels in a labelled data set are
    counted (a warning: only AP needs labels); doubts about a layout the user chose are warnings.
    ``modality`` (``lidar`` or ``camera``) says which sensor's frames to inspect; by default
    ``options.modality`` when it is ``camera``, else what the source holds (a source of images
    only, or a log whose topic is an image topic: the camera). ``image_options``: see
    :func:`~lidarfuzz.io.images.open_image_dataset`.

    Raises:
        DataFormatError: Only when the source cannot be opened at all.
    """
    path = Path(path)
    kind = source_kind(path)
    log_info = None
    if kind == "log":
        from lidarfuzz.io.logs import inspect_bag

        log_info = inspect_bag(path)
    options = options or DatasetOptions()
    if modality is None:
        camera = options.modality == "camera" or bool(image_options)
        modality = "camera" if camera else source_modality(path, topic)
    if modality == "camera":
        return _inspect_images(path, kind, log_info, topic=topic, limit=limit, options=options, **image_options)
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
            field = f"field '{exc.field}': " if exc.field else ""  # the header field that lied
            report.problems.append(Problem("error", str(exc.path), field + exc.message + hint, exc.line))
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


def _inspect_images(path: Path, kind: str, log_info: dict[str, Any] | None, *, topic: str | None,
                    limit: int | None, options: DatasetOptions, **image_options: Any) -> DatasetReport:
    """:func:`inspect_source` for the camera modality: each image decoded, its size, label, depth counted."""
    dataset = open_dataset(path, topic=topic, strict=False, options=options, modality="camera", **image_options)
    report = DatasetReport(path=str(path), kind=kind, format=dataset.format, frames=len(dataset),
                           ordered=dataset.ordered, log=log_info, modality="camera", images=ImageStats())
    report.problems.extend(dataset.problems())
    if isinstance(dataset, Log) and len(dataset):
        stamps = dataset.timestamps()
        report.time_span = (float(stamps.min()), float(stamps.max()))
        report.has_poses = dataset.poses() is not None
    stats = report.images
    assert stats is not None
    ids = list(dataset.frame_ids())[:limit] if limit is not None else list(dataset.frame_ids())
    for frame_id in ids:
        try:
            sample = dataset.load(frame_id)
        except DataFormatError as exc:
            hint = f" ({exc.hint})" if exc.hint else ""
            where = f"field '{exc.field}': " if exc.field else ""
            report.problems.append(Problem("error", str(exc.path), where + exc.message + hint, exc.line))
            report.unreadable += 1
            continue
        report.inspected += 1
        stats.add(sample)
        report.calibrated_frames += sample.intrinsics is not None
    if len(stats.sizes) > 1:
        listed = ", ".join(f"{w}×{h} ({n})" for (h, w), n in stats.sizes.most_common())
        report.problems.append(Problem("warning", str(path), f"images of {len(stats.sizes)} sizes: {listed} "
                                       "(allowed: a steering system resizes its input)"))
    if report.inspected and stats.labelled < report.inspected:
        report.problems.append(Problem("warning", str(path), f"{report.inspected - stats.labelled} of "
                                       f"{report.inspected} image(s) have no steering label"))
    return report
