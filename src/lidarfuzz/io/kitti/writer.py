"""Writing scenes into a new KITTI-layout folder: :class:`KittiWriter` (a data set or a log,
frame by frame), :func:`write_kitti_frame` (one frame's files, e.g. from a worker process)
and :func:`write_kitti`. Every file is written atomically.
"""

from __future__ import annotations

import io
import json
from collections.abc import Iterable, Sequence
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import write_bytes, write_text
from lidarfuzz.io.formats import bin as bin_format
from lidarfuzz.io.kitti.labels import exact_number, format_labels
from lidarfuzz.scene.points import STANDARD_CHANNELS
from lidarfuzz.scene.scene import Scene


class KittiWriter:
    """Writes scenes into a new KITTI-layout folder, each file atomically.

    The folder must not exist or be empty (unless ``overwrite``), so an existing data
    set is never modified. Log side files and ImageSets are written by :meth:`close`.

    Example:
        >>> import tempfile, pathlib
        >>> from lidarfuzz.scene.points import PointCloud
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "ds"
        >>> with KittiWriter(out) as writer:
        ...     _ = writer.add(Scene(PointCloud(np.zeros((1, 4))), frame_id="000000"))
        >>> sorted(p.name for p in out.iterdir())
        ['velodyne']
    """

    def __init__(self, root: str | PathLike[str], *, overwrite: bool = False, complete_labels: bool = True,
                 durable: bool = True) -> None:
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise DataFormatError(self.root, "exists and is not a folder")
        if self.root.is_dir() and any(self.root.iterdir()) and not overwrite:
            raise DataFormatError(self.root, "folder exists and is not empty; choose a new folder or pass --overwrite")
        self.overwrite = overwrite
        self.complete_labels = complete_labels
        self.durable = durable
        self._ids: list[str] = []
        self._timestamps: dict[str, float] = {}
        self._poses: dict[str, NDArray[np.float64]] = {}
        self._labelled = False
        self._unlabelled: set[str] = set()  # frames read without labels: they stay without a label file

    def __enter__(self) -> KittiWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.close()

    def add(self, scene: Scene, frame_id: str | None = None) -> str:
        """Write one scene; returns its frame id (``scene.frame_id`` or the next index)."""
        frame_id = frame_id or scene.frame_id or f"{len(self._ids):06d}"
        if frame_id in self._ids:
            raise ValueError(f"duplicate frame id {frame_id!r}")
        labelled = write_kitti_frame(self.root, scene, frame_id, overwrite=self.overwrite,
                                     complete_labels=self.complete_labels, durable=self.durable,
                                     labelled_set=self._labelled)
        self.record(frame_id, scene.timestamp, scene.pose, labelled, unlabelled=scene.metadata.get("labelled") is False)
        return frame_id

    def record(self, frame_id: str, timestamp: float | None, pose: NDArray[np.float64] | None,
               labelled: bool, *, unlabelled: bool = False) -> None:
        """Register a frame whose files were written by :func:`write_kitti_frame` (e.g. in a worker
        process); ``unlabelled``: it was read without labels and keeps no label file."""
        if frame_id in self._ids:
            raise ValueError(f"duplicate frame id {frame_id!r}")
        self._labelled = self._labelled or labelled
        if unlabelled:
            self._unlabelled.add(frame_id)
        if timestamp is not None:
            self._timestamps[frame_id] = timestamp
        if pose is not None:
            self._poses[frame_id] = np.asarray(pose)[:3, :].ravel()
        self._ids.append(frame_id)

    def close(self, image_sets: dict[str, Sequence[str]] | None = None) -> None:
        """Write frames' labels consistently, the log side files and ImageSets lists."""
        self.root.mkdir(parents=True, exist_ok=True)
        ow = self.overwrite
        if self._labelled:
            # A labelled data set has a label file for every frame (possibly empty), but for the
            # frames that were read unlabelled: an empty file would make them frames with no objects.
            for frame_id in self._ids:
                path = self.root / "label_2" / f"{frame_id}.txt"
                if not path.exists() and frame_id not in self._unlabelled:
                    write_text(path, "", overwrite=ow)
        if self._timestamps:
            lines = [f"{f} {exact_number(self._timestamps[f])}" for f in self._ids if f in self._timestamps]
            write_text(self.root / "timestamps.txt", "\n".join(lines) + "\n", overwrite=ow)
        if self._poses:
            lines = [f"{f} " + " ".join(exact_number(v) for v in self._poses[f]) for f in self._ids if f in self._poses]
            write_text(self.root / "poses.txt", "\n".join(lines) + "\n", overwrite=ow)
        for name, ids in (image_sets or {}).items():
            write_text(self.root / "ImageSets" / f"{name}.txt", "".join(f"{i}\n" for i in ids), overwrite=ow)


def compact_channel(values: NDArray[np.floating]) -> NDArray[np.generic]:
    """The channel in the smallest integer type that holds it exactly, or as it is.

    Ring numbers, class ids and instance ids are integers stored as float32 in a
    cloud; on disk they take 1–2 bytes instead of 4, and read back identical.

    A cloud's channel is a strided column: it is copied contiguous once, so that the extremes,
    the cast and the comparison run over packed values (a third of the time on a 120k-point
    frame), and a channel kept as it is is returned as that copy (same values, same bytes
    in a ``.npy``).
    """
    v = np.asarray(values)
    if v.size == 0:
        return v
    v = np.ascontiguousarray(v)
    lo, hi = float(v.min()), float(v.max())  # NaN if any value is: then neither is finite
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return v
    for dtype in (np.uint8, np.int8, np.int16, np.int32):
        info = np.iinfo(dtype)
        if info.min <= lo and hi <= info.max and hi <= 2**24:  # float32 holds integers exactly up to 2**24
            # Within the type's range the cast truncates towards zero and is exact on integers, so
            # it gives back every value exactly when all are integers (what trunc(v) == v tested).
            narrowed = v.astype(dtype)
            return narrowed if np.array_equal(narrowed, v) else v
    return v


def write_kitti_frame(root: str | PathLike[str], scene: Scene, frame_id: str, *, overwrite: bool = False,
                      complete_labels: bool = True, durable: bool = True, labelled_set: bool = False) -> bool:
    """Write one frame's files into a KITTI layout; returns whether a label file was written.

    ``labelled_set`` says the data set has labels, so an empty label file is written for a
    frame without objects — unless the scene was read unlabelled (``metadata["labelled"]``
    False): it keeps no label file. Log side files and ImageSets are written by :class:`KittiWriter`.
    """
    root = Path(root)
    if any(sep in frame_id for sep in "/\\") or frame_id in (".", "..") or not frame_id:
        raise ValueError(f"frame id {frame_id!r} is not a valid file name")
    ow, du = overwrite, durable
    bin_format.write_points(root / "velodyne" / f"{frame_id}.bin", scene.points, overwrite=ow, durable=du)
    extra = [c for c in scene.points.channels if c not in STANDARD_CHANNELS]
    if extra:
        buffer = io.BytesIO()
        np.savez(buffer, **{c: compact_channel(scene.points.channel(c)) for c in extra})  # type: ignore[arg-type]
        write_bytes(root / "velodyne_extra" / f"{frame_id}.npz", buffer.getvalue(), overwrite=ow, durable=du)
    if scene.calib is not None:
        write_text(root / "calib" / f"{frame_id}.txt", scene.calib.to_text(), overwrite=ow, durable=du)
    labelled = (bool(len(scene.boxes)) or labelled_set) and scene.metadata.get("labelled") is not False
    if labelled:
        text = format_labels(scene.boxes, scene.calib, complete=complete_labels)
        write_text(root / "label_2" / f"{frame_id}.txt", text, overwrite=ow, durable=du)
        side: dict[str, object] = {}
        if np.any(scene.boxes.track_ids >= 0):
            side["track_ids"] = scene.boxes.track_ids.tolist()
        objects = scene.metadata.get("objects")
        if isinstance(objects, dict) and objects:
            side["objects"] = objects
        if side:
            write_text(root / "label_2_extra" / f"{frame_id}.json", json.dumps(side), overwrite=ow, durable=du)
    if scene.roi is not None:
        write_text(root / "roi" / f"{frame_id}.json", json.dumps(scene.roi.to_geojson()), overwrite=ow, durable=du)
    return labelled


def write_kitti(
    root: str | PathLike[str],
    scenes: Iterable[Scene],
    *,
    overwrite: bool = False,
    image_sets: dict[str, Sequence[str]] | None = None,
) -> Path:
    """Write scenes as a KITTI-layout data set in a new folder; returns the folder."""
    writer = KittiWriter(root, overwrite=overwrite)
    for scene in scenes:
        writer.add(scene)
    writer.close(image_sets)
    return writer.root
