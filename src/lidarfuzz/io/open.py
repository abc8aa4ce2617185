"""Open any supported source as a data set, deciding its kind from what is on disk."""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFinitePolicy
from lidarfuzz.io.dataset import Dataset
from lidarfuzz.io.frames import FrameFolder, SingleFrame, is_frame_file
from lidarfuzz.io.kitti import find_kitti_root, open_kitti
from lidarfuzz.scene.scene import Scene

LOG_SUFFIXES = (".bag", ".mcap", ".db3")


def source_kind(path: str | PathLike[str]) -> str:
    """``log``, ``kitti``, ``folder`` or ``frame`` — or a DataFormatError saying why none fits."""
    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, "no such file or folder")
    if path.is_file():
        if path.suffix.lower() in LOG_SUFFIXES:
            return "log"
        if is_frame_file(path):
            return "frame"
        raise DataFormatError(
            path, f"unsupported file type {path.suffix or '(no suffix)'!r}",
            hint="expected a frame (.bin .pcd .ply .las .laz .npy .npz) or a log (.bag .mcap)",
        )
    if (path / "metadata.yaml").is_file():
        return "log"
    if find_kitti_root(path) is not None:
        return "kitti"
    return "folder"


def open_dataset(
    path: str | PathLike[str],
    *,
    topic: str | None = None,
    strict: bool = True,
    nonfinite: NonFinitePolicy = "drop",
    **kitti_options: Any,
) -> Dataset[Scene]:
    """Open a KITTI folder, a folder of frame files, one frame file, a bag or an MCAP file.

    Args:
        path: What to open.
        topic: For logs, the PointCloud2 topic (default: the only one there is).
        strict: Raise on structural problems instead of recording them.
        nonfinite: ``drop`` (warn and count) or ``reject`` points with NaN/Inf coordinates.
        **kitti_options: ``split``, ``subset``, ``classes`` for KITTI layouts.
    """
    kind = source_kind(path)
    if kind == "log":
        from lidarfuzz.io.logs.bags import BagLog

        return BagLog(path, topic=topic, nonfinite=nonfinite)
    if kind == "kitti":
        return open_kitti(path, strict=strict, nonfinite=nonfinite, **kitti_options)
    if kind == "frame":
        return SingleFrame(path, nonfinite=nonfinite)
    return FrameFolder(path, nonfinite=nonfinite)
