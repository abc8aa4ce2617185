"""Which image layout a path holds (:func:`detect_layout`) and :func:`open_image_dataset`, which opens it.

Detection, in this order:

1. a ``.bag``/``.mcap``/``.db3`` file, or a folder with ``metadata.yaml``: ``log``;
2. a folder with ``image_2/`` (itself or under ``training/``): ``kitti``;
3. a folder with ``interpolated.csv``: ``udacity``; with ``driving_log.csv``: ``driving_log``;
4. a folder with exactly one ``.csv``, or a ``.csv`` file: the layout its name or first row says
   (:func:`~lidarfuzz.io.images.tabular.sniff_layout`).
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Literal, get_args

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.dataset import Dataset
from lidarfuzz.io.images.kitti import find_image_root, open_kitti_images
from lidarfuzz.io.images.logs import ImageLog
from lidarfuzz.io.images.tabular import DRIVING_LOG_FILE, UDACITY_FILE, open_table, sniff_layout
from lidarfuzz.scene.image import ImageSample

ImageLayout = Literal["udacity", "driving_log", "csv", "kitti", "log"]
IMAGE_LAYOUTS: tuple[str, ...] = get_args(ImageLayout)
LOG_SUFFIXES = (".bag", ".mcap", ".db3")


def _table(path: Path) -> Path | None:
    """The CSV that describes a folder of images, or None; several candidates are an error."""
    for name in (UDACITY_FILE, DRIVING_LOG_FILE):
        if (path / name).is_file():
            return path / name
    tables = sorted(p for p in path.glob("*.csv") if p.is_file())
    if len(tables) > 1:
        raise DataFormatError(path, f"{len(tables)} CSV files ({', '.join(p.name for p in tables)}): which one "
                              "lists the images?", hint="open the CSV file itself")
    return tables[0] if tables else None


def detect_layout(path: str | PathLike[str]) -> tuple[ImageLayout, Path]:
    """The image layout of ``path`` and the path to open it from (a folder's CSV).

    Raises:
        DataFormatError: Nothing here is an image data set (naming what was looked for).
    """
    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, "no such file or folder")
    if path.is_file():
        if path.suffix.lower() in LOG_SUFFIXES or path.name == "metadata.yaml":
            return "log", path
        if path.suffix.lower() == ".csv":
            return sniff_layout(path), path
        raise DataFormatError(path, f"unsupported file type {path.suffix or '(no suffix)'!r} for images",
                              hint="expected a folder of images with a CSV, a KITTI folder with image_2/, a CSV, "
                                   "a .bag, an .mcap or a ROS 2 bag folder")
    if (path / "metadata.yaml").is_file():
        return "log", path
    if find_image_root(path) is not None:
        return "kitti", path
    table = _table(path)
    if table is not None:
        return sniff_layout(table), table
    raise DataFormatError(path, "not an image data set: no image_2/ folder, interpolated.csv, driving_log.csv or "
                          "other CSV listing images", hint="see 'lidarfuzz info --help' for the camera layouts")


def is_image_source(path: str | PathLike[str]) -> bool:
    """Whether a folder or CSV holds images only (a CSV-described layout, or ``image_2/`` without
    ``velodyne/``) — what LiDAR readers cannot open. Logs and KITTI folders with scans are not."""
    path = Path(path)
    try:
        layout, _ = detect_layout(path)
    except DataFormatError:
        # several CSVs beside the images: the camera reader's error says which to open
        return path.is_dir() and len(list(path.glob("*.csv"))) > 1
    if layout == "log":
        return False
    if layout == "kitti":
        root = find_image_root(path)
        return root is not None and not (root / "velodyne").is_dir()
    return True


def open_image_dataset(
    path: str | PathLike[str],
    *,
    layout: str | None = None,
    camera: str | None = None,
    topic: str | None = None,
    image_column: str | None = None,
    steering_column: str | None = None,
    steering_topic: str | None = None,
    steering_field: str | None = None,
    strict: bool = True,
) -> Dataset[ImageSample]:
    """Open a camera data set: Udacity, a driving log, a CSV of images, KITTI ``image_2/`` or an image topic.

    Args:
        path: A folder, a CSV file or a log (see :func:`detect_layout`).
        layout: ``udacity``, ``driving_log``, ``csv``, ``kitti`` or ``log``; by default detected.
        camera: ``center`` (default), ``left`` or ``right`` for the Udacity layouts; ``image_2``
            (default) or ``image_3`` for KITTI.
        topic: The image topic of a log (default: the only one).
        image_column, steering_column: The columns of a plain CSV (default: found by name).
        steering_topic, steering_field: A log's steering topic and the field holding the angle
            (:class:`~lidarfuzz.io.images.logs.ImageLog`).
        strict: Raise on bad rows and files; when False they are listed in ``problems()``.

    Raises:
        DataFormatError: The data is not what the layout needs (one line naming file, line, field).
        LidarfuzzError: An option that does not apply to the layout.
    """
    if layout is not None and layout not in IMAGE_LAYOUTS:
        raise LidarfuzzError(f"image layout {layout!r} is not one of {', '.join(IMAGE_LAYOUTS)}")
    found, source = detect_layout(path)
    chosen = layout or found
    if chosen in ("udacity", "driving_log", "csv") and Path(path).is_dir() and source == Path(path):
        raise DataFormatError(path, f"the {chosen} layout needs a CSV; none found here")
    for option, value in (("topic", topic), ("steering_topic", steering_topic), ("steering_field", steering_field)):
        if value is not None and chosen != "log":
            raise LidarfuzzError(f"{path}: {option}={value!r} applies to logs, not the {chosen} layout")
    if chosen == "log":
        if camera is not None:
            raise LidarfuzzError(f"{path}: camera={camera!r} does not apply to a log; choose the image topic "
                                 "with topic=...")
        return ImageLog(path, topic, steering_topic=steering_topic, steering_field=steering_field)
    if chosen == "kitti":
        return open_kitti_images(path, camera=camera, strict=strict)
    return open_table(source, layout=chosen, camera=camera, image_column=image_column,
                      steering_column=steering_column, strict=strict)
