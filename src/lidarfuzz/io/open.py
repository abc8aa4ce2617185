"""Open any supported source as a data set, deciding its kind from what is on disk.

Data-set options (:class:`~lidarfuzz.io.options.DatasetOptions`: the point layout, the
intensity scale, a data-set ROI map, the modality) are applied here, so every caller that opens a
data set — the CLI, campaign workers, reports, the web app — reads it the same way.

The ``camera`` modality (``options.modality`` or ``modality=``) opens the images of a source
through :func:`lidarfuzz.io.images.open_image_dataset`: a KITTI folder's ``image_2/`` beside its
scans, a Udacity or CSV image data set, or an image topic of a log. A source that holds only
images (kind ``images``) cannot be read as LiDAR scans and says so.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any, Literal, overload

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFinitePolicy
from lidarfuzz.io.dataset import Dataset
from lidarfuzz.io.frames import FrameFolder, SingleFrame, is_frame_file
from lidarfuzz.io.kitti import find_kitti_root, open_kitti
from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.scene.image import ImageSample
from lidarfuzz.scene.scene import Scene

LOG_SUFFIXES = (".bag", ".mcap", ".db3")
Modality = Literal["lidar", "camera"]


def source_kind(path: str | PathLike[str]) -> str:
    """``log``, ``kitti``, ``folder``, ``frame`` or ``images`` (a folder or CSV of camera images
    only, :func:`lidarfuzz.io.images.is_image_source`) — or a DataFormatError saying why none fits."""
    from lidarfuzz.io.images.open import is_image_source

    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, "no such file or folder")
    if path.is_file():
        if path.suffix.lower() in LOG_SUFFIXES:
            return "log"
        if is_frame_file(path):
            return "frame"
        if path.suffix.lower() == ".csv" and is_image_source(path):
            return "images"
        raise DataFormatError(
            path, f"unsupported file type {path.suffix or '(no suffix)'!r}",
            hint="expected a frame (.bin .pcd .ply .las .laz .npy .npz .feather) or a log (.bag .mcap)",
        )
    if (path / "metadata.yaml").is_file():
        return "log"
    if find_kitti_root(path) is not None:
        return "kitti"
    if is_image_source(path) and not any(is_frame_file(p) for p in path.iterdir() if p.is_file()):
        return "images"
    return "folder"


def source_modality(path: str | PathLike[str], topic: str | None = None) -> Modality:
    """What a source holds when nobody says: ``camera`` for image data sets (kind ``images``) and
    logs whose ``topic`` is an image topic (or, with no topic named, that have image topics but no
    PointCloud2 topic), else ``lidar`` (a KITTI folder with scans)."""
    kind = source_kind(path)
    if kind == "images":
        return "camera"
    if kind == "log":
        from lidarfuzz.io.images.logs import image_topics

        images, clouds = image_topics(path)
        if (topic is not None and topic in images) or (topic is None and images and not clouds):
            return "camera"
    return "lidar"


def _data_folder(path: Path) -> Path:
    """The folder that holds the scans of a data set's root: a nuScenes root's
    ``samples/LIDAR_TOP`` (its keyframes); anything else as it is."""
    if path.is_dir() and (path / "samples" / "LIDAR_TOP").is_dir() and not (path / "velodyne").is_dir():
        return path / "samples" / "LIDAR_TOP"
    if path.is_dir() and (path / "sequences").is_dir() and not (path / "velodyne").is_dir():
        raise DataFormatError(path, "a SemanticKITTI root holds several sequences; open one of them",
                              hint=f"e.g. {path / 'sequences' / '00'}")
    return path


@overload
def open_dataset(path: str | PathLike[str], *, options: DatasetOptions | None = None, topic: str | None = None,
                 strict: bool = True, nonfinite: NonFinitePolicy = "drop", modality: Literal["lidar"],
                 **kitti_options: Any) -> Dataset[Scene]: ...


@overload
def open_dataset(path: str | PathLike[str], *, options: DatasetOptions | None = None, topic: str | None = None,
                 strict: bool = True, nonfinite: NonFinitePolicy = "drop", modality: Literal["camera"],
                 **image_options: Any) -> Dataset[ImageSample]: ...


@overload
def open_dataset(path: str | PathLike[str], *, options: DatasetOptions | None = None, topic: str | None = None,
                 strict: bool = True, nonfinite: NonFinitePolicy = "drop", modality: None = None,
                 **kitti_options: Any) -> Dataset[Any]: ...


def open_dataset(
    path: str | PathLike[str],
    *,
    options: DatasetOptions | None = None,
    topic: str | None = None,
    strict: bool = True,
    nonfinite: NonFinitePolicy = "drop",
    modality: Modality | None = None,
    **kitti_options: Any,
) -> Dataset[Any]:
    """Open a KITTI folder, a folder of frame files, one frame file, a bag or an MCAP file — or,
    for the camera modality, a camera data set (:func:`lidarfuzz.io.images.open_image_dataset`).

    Args:
        path: What to open (a nuScenes root opens its ``samples/LIDAR_TOP`` keyframes).
        options: Data-set options (layout, intensity scale, ROI map, modality); the defaults decide
            the layout from the data's structure.
        topic: For logs, the PointCloud2 (or, for the camera, image) topic (default: the only one there is).
        strict: Raise on structural problems instead of recording them.
        nonfinite: ``drop`` (warn and count) or ``reject`` points with NaN/Inf coordinates.
        modality: ``lidar`` or ``camera``; by default ``options.modality``. The camera modality
            returns a ``Dataset[ImageSample]``.
        **kitti_options: ``split``, ``subset``, ``classes`` for KITTI layouts; for the camera
            ``layout``, ``camera``, ``image_column``, ``steering_column``
            (see :func:`~lidarfuzz.io.images.open_image_dataset`).
    """
    options = options or DatasetOptions()
    if (modality or options.modality) == "camera":
        return _open_images(Path(path), options, topic=topic, strict=strict, **kitti_options)
    layout = options.point_layout()
    path = _data_folder(Path(path))
    kind = source_kind(path)
    dataset: Dataset[Scene]
    if kind == "images":
        raise DataFormatError(path, "holds camera images, not LiDAR scans",
                              hint="open it as the camera modality (modality='camera', --modality camera)")
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


def _open_images(path: Path, options: DatasetOptions, *, topic: str | None, strict: bool,
                 **image_options: Any) -> Dataset[ImageSample]:
    from lidarfuzz.io.images.open import open_image_dataset

    if options.layout is not None:
        raise DataFormatError(path, f"a point layout ({options.layout}) does not apply to camera images",
                              field="layout")
    if options.camera is not None:
        image_options.setdefault("camera", options.camera)
    dataset = open_image_dataset(path, topic=topic, strict=strict, **image_options)
    dataset.configure(options)
    return dataset
