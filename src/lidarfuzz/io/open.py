"""Open any supported source as a data set, deciding its kind from what is on disk.

Data-set options (:class:`~lidarfuzz.io.options.DatasetOptions`: the point layout, the
intensity scale, a data-set ROI map) are applied here, so every caller that opens a data set —
the CLI, campaign workers, reports, the web app — reads it the same way.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFinitePolicy
from lidarfuzz.io.dataset import Dataset
from lidarfuzz.io.frames import FrameFolder, SingleFrame, is_frame_file
from lidarfuzz.io.kitti import find_kitti_root, open_kitti
from lidarfuzz.io.options import DatasetOptions
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
            hint="expected a frame (.bin .pcd .ply .las .laz .npy .npz .feather) or a log (.bag .mcap)",
        )
    if (path / "metadata.yaml").is_file():
        return "log"
    if find_kitti_root(path) is not None:
        return "kitti"
    return "folder"


def _data_folder(path: Path) -> Path:
    """The folder that holds the scans of a data set's root: a nuScenes root's
    ``samples/LIDAR_TOP`` (its keyframes); anything else as it is."""
    if path.is_dir() and (path / "samples" / "LIDAR_TOP").is_dir() and not (path / "velodyne").is_dir():
        return path / "samples" / "LIDAR_TOP"
    if path.is_dir() and (path / "sequences").is_dir() and not (path / "velodyne").is_dir():
        raise DataFormatError(path, "a SemanticKITTI root holds several sequences; open one of them",
                              hint=f"e.g. {path / 'sequences' / '00'}")
    return path


def open_dataset(
    path: str | PathLike[str],
    *,
    options: DatasetOptions | None = None,
    topic: str | None = None,
    strict: bool = True,
    nonfinite: NonFinitePolicy = "drop",
    **kitti_options: Any,
) -> Dataset[Scene]:
    """Open a KITTI folder, a folder of frame files, one frame file, a bag or an MCAP file.

    Args:
        path: What to open (a nuScenes root opens its ``samples/LIDAR_TOP`` keyframes).
        options: Data-set options (layout, intensity scale, ROI map); the defaults decide the
            layout from the data's structure.
        topic: For logs, the PointCloud2 topic (default: the only one there is).
        strict: Raise on structural problems instead of recording them.
        nonfinite: ``drop`` (warn and count) or ``reject`` points with NaN/Inf coordinates.
        **kitti_options: ``split``, ``subset``, ``classes`` for KITTI layouts.
    """
    options = options or DatasetOptions()
    layout = options.point_layout()
    path = _data_folder(Path(path))
    kind = source_kind(path)
    dataset: Dataset[Scene]
    if kind == "log":
        from lidarfuzz.io.logs import BagLog

        dataset = BagLog(path, topic=topic, nonfinite=nonfinite)
    elif kind == "kitti":
        dataset = open_kitti(path, strict=strict, nonfinite=nonfinite, layout=layout, **kitti_options)
    elif kind == "frame":
        dataset = SingleFrame(path, nonfinite=nonfinite, layout=layout)
    else:
        dataset = FrameFolder(path, nonfinite=nonfinite, layout=layout)
    dataset.configure(options)
    return dataset
