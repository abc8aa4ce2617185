"""Convert any supported source to any supported destination.

* frame file → frame file (the destination suffix picks the format);
* anything → folder in KITTI layout (the default for a destination without a suffix);
* anything → folder of frame files (``to="pcd"``, ``"ply"``, ...);
* anything → log (``.bag`` for ROS1, ``.mcap``, or ``to="ros2"`` for a ROS2 bag folder).

The source is only read; the destination must be new (or ``overwrite`` given) and may
not be the source or lie inside it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFinitePolicy
from lidarfuzz.io.frames import FRAME_FORMATS, write_frame
from lidarfuzz.io.kitti import KittiWriter
from lidarfuzz.io.open import open_dataset
from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.scene.scene import Scene

LOG_TARGETS = ("ros1", "ros2", "mcap")
FOLDER_TARGETS = ("kitti", *(suffix[1:] for suffix in FRAME_FORMATS))


@dataclass
class ConvertResult:
    destination: Path
    target: str
    frames: int


def destination_kind(dst: Path, to: str | None) -> str:
    """What to write: ``kitti``, a frame format name, ``frame:<fmt>``, or a log kind."""
    if to is not None:
        to = to.lower()
        if to not in (*LOG_TARGETS, *FOLDER_TARGETS):
            raise ValueError(f"unknown target format {to!r}; choose from {', '.join((*FOLDER_TARGETS, *LOG_TARGETS))}")
        return to
    suffix = dst.suffix.lower()
    if suffix == ".bag":
        return "ros1"
    if suffix == ".mcap":
        return "mcap"
    if suffix in FRAME_FORMATS:
        return f"frame:{suffix[1:]}"
    return "kitti"


def convert(
    src: str | PathLike[str],
    dst: str | PathLike[str],
    *,
    to: str | None = None,
    topic: str | None = None,
    overwrite: bool = False,
    nonfinite: NonFinitePolicy = "drop",
    on_frame: Callable[[int, int], None] | None = None,
    transform: Callable[[Scene], Scene] | None = None,
    options: DatasetOptions | None = None,
) -> ConvertResult:
    """Convert ``src`` (read with data-set ``options``: layout, …) into ``dst``;
    ``on_frame(done, total)`` reports progress; ``transform`` (e.g. a mutation operator) maps
    each scene on the way."""
    src_path, dst_path = Path(src), Path(dst)
    src_abs, dst_abs = src_path.resolve(), dst_path.resolve()
    if dst_abs == src_abs or src_abs in dst_abs.parents:
        raise DataFormatError(dst_path, "the destination is the source or inside it; originals are never modified")
    target = destination_kind(dst_path, to)
    dataset = open_dataset(src_path, topic=topic, nonfinite=nonfinite, options=options)
    total = len(dataset)

    def scenes() -> Iterator[Scene]:
        for i, scene in enumerate(dataset, start=1):
            yield transform(scene) if transform is not None else scene
            if on_frame:
                on_frame(i, total)

    return write_scenes(scenes(), dst_path, target, total=total, overwrite=overwrite)


def write_scenes(scenes: Iterator[Scene], dst: str | PathLike[str], target: str, *, total: int | None = None,
                 overwrite: bool = False) -> ConvertResult:
    """Write ``scenes`` to ``dst`` as ``target`` (see :func:`destination_kind`)."""
    dst_path = Path(dst)
    if target.startswith("frame:"):
        first = next(scenes, None)
        if first is None or next(scenes, None) is not None or (total is not None and total != 1):
            raise DataFormatError(
                dst_path, f"the source has {total if total is not None else 'several'} frames but the destination "
                "is a single file", hint="give a folder as destination (KITTI layout by default, or --to pcd/ply/...)",
            )
        write_frame(dst_path, first, overwrite=overwrite)
        return ConvertResult(dst_path, target.split(":", 1)[1], 1)
    if target in LOG_TARGETS:
        from lidarfuzz.io.logs import write_log

        counted = _Counted(scenes)
        write_log(dst_path, counted, kind=target, overwrite=overwrite)  # type: ignore[arg-type]
        return ConvertResult(dst_path, target, counted.count)
    if target == "kitti":
        writer = KittiWriter(dst_path, overwrite=overwrite)
        count = 0
        for scene in scenes:
            writer.add(scene)
            count += 1
        writer.close()
        return ConvertResult(dst_path, "kitti", count)
    # A folder of frame files in one format.
    if dst_path.exists() and any(dst_path.iterdir()) and not overwrite:
        raise DataFormatError(dst_path, "folder exists and is not empty; choose a new folder or pass --overwrite")
    suffix = f".{target}"
    count = 0
    for scene in scenes:
        write_frame(dst_path / f"{scene.frame_id or f'{count:06d}'}{suffix}", scene, overwrite=overwrite)
        count += 1
    return ConvertResult(dst_path, target, count)


class _Counted:
    def __init__(self, scenes: Iterator[Scene]) -> None:
        self._scenes, self.count = scenes, 0

    def __iter__(self) -> Iterator[Scene]:
        for scene in self._scenes:
            self.count += 1
            yield scene
