"""KITTI's camera images beside the LiDAR frames: ``image_2/`` (or ``image_3/``) of a KITTI-layout
folder as a data set of :class:`~lidarfuzz.scene.image.ImageSample`.

Layout (``root`` may also be a folder holding ``training/``)::

    root/image_2/000000.png     the left colour camera (PNG or JPEG); frame ids are the stems,
                                the same as velodyne/000000.bin's
    root/calib/000000.txt       P2 (P3 for image_3): the intrinsics are its left 3×3
    root/depth_2/000000.png     optional: uint16 z-depth, metres × 256, 0 = nothing hit (→ inf)
    root/steering.csv           optional: header ``frame_id,steering,speed``; steering in radians,
                                left positive (the simulator's front-wheel angle), speed m/s
    root/timestamps.txt         optional: ``<frame_id> <seconds>`` — the data set is a log
    root/poses.txt              optional: ``<frame_id> <12 numbers>`` LiDAR → world; with calib the
                                camera → world pose of each image

``lidarfuzz gen --camera`` writes this layout. Frames without a calib file, a depth map or a
steering row (when the data set has them) are read without and listed as warnings; images without
a LiDAR frame (or the reverse) are warnings too.
"""

from __future__ import annotations

import csv
from collections import Counter
from collections.abc import Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.common import Problem
from lidarfuzz.io.dataset import Dataset, Log
from lidarfuzz.io.images.decode import decode_depth, decode_image, image_header
from lidarfuzz.io.images.tabular import number
from lidarfuzz.io.kitti.dataset import _read_keyed_lines
from lidarfuzz.scene.calib import KittiCalibration, invertible
from lidarfuzz.scene.image import ImageSample

#: Camera folder → its projection matrix in calib files.
KITTI_CAMERAS: dict[str, str] = {"image_2": "P2", "image_3": "P3"}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
STEERING_FILE = "steering.csv"


def find_image_root(path: str | PathLike[str], camera: str = "image_2", split: str = "training") -> Path | None:
    """The folder holding ``image_2/`` (``path`` itself or ``path/<split>``), if any."""
    path = Path(path)
    for root in (path, path / split):
        if (root / camera).is_dir():
            return root
    return None


def intrinsics_of(projection: NDArray[np.float64]) -> NDArray[np.float64]:
    """K of a rectified camera: the left 3×3 of its 3×4 projection matrix P = K [I | t]."""
    return np.array(projection[:, :3], dtype=np.float64)


def camera_pose(lidar_pose: NDArray[np.float64], calib: KittiCalibration, projection: NDArray[np.float64]
                ) -> NDArray[np.float64]:
    """Camera → world for a camera with projection P = K [I | t] in the rectified frame: the camera sits at
    -t in rectified coordinates, so camera → rect is a translation by -t, then rect → LiDAR → world."""
    offset = np.linalg.solve(intrinsics_of(projection), projection[:, 3])
    camera_to_rect = np.eye(4)
    camera_to_rect[:3, 3] = -offset
    return np.asarray(lidar_pose @ calib.rect_to_velo @ camera_to_rect, dtype=np.float64)


def read_steering_csv(path: Path) -> tuple[dict[str, tuple[float, float | None, int]], list[DataFormatError]]:
    """``frame_id → (steering, speed or None, line)`` from a ``steering.csv``; bad rows as errors.

    Raises:
        DataFormatError: No header with ``frame_id`` and ``steering`` columns.
    """
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            records = [(i, cells) for i, cells in enumerate(csv.reader(handle), start=1)
                       if any(c.strip() for c in cells)]
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataFormatError(path, f"cannot read: {exc}") from None
    header = [c.strip().lower() for c in records[0][1]] if records else []
    for column in ("frame_id", "steering"):
        if column not in header:
            raise DataFormatError(path, f"no column {column!r}; expected the header frame_id,steering,speed",
                                  line=1, field=column)
    at_id, at_steering = header.index("frame_id"), header.index("steering")
    at_speed = header.index("speed") if "speed" in header else None
    out: dict[str, tuple[float, float | None, int]] = {}
    errors: list[DataFormatError] = []
    for line, cells in records[1:]:
        try:
            if len(cells) < len(header):
                raise DataFormatError(path, f"expected {len(header)} cells, found {len(cells)}", line=line)
            frame_id = cells[at_id].strip()
            if frame_id in out:
                raise DataFormatError(path, f"frame {frame_id!r} twice (first on line {out[frame_id][2]})",
                                      line=line, field="frame_id")
            steering = number(cells[at_steering], path, line, "steering")
            speed = number(cells[at_speed], path, line, "speed") if at_speed is not None else None
            out[frame_id] = (steering, speed, line)
        except DataFormatError as exc:
            errors.append(exc)
    return out, errors


class KittiImages(Dataset[ImageSample]):
    """The camera images of a KITTI-layout folder (see the module docstring).

    Args:
        path: The root (holding ``image_2/``) or a folder with ``training/``.
        camera: ``image_2`` (default, the left colour camera) or ``image_3``.
        split: ``training`` or ``testing`` when ``path`` holds both.
        strict: Raise on errors (a bad ``steering.csv`` row, a malformed side file); when False
            they are listed in :meth:`problems`.
    """

    def __init__(self, path: str | PathLike[str], *, camera: str | None = None, split: str = "training",
                 strict: bool = True) -> None:
        folder = camera or "image_2"
        if folder not in KITTI_CAMERAS:
            raise LidarfuzzError(f"{path}: camera {folder!r} is not one of {', '.join(KITTI_CAMERAS)} "
                                 "for a KITTI layout")
        root = find_image_root(path, folder, split)
        if root is None:
            raise DataFormatError(path, f"not a KITTI camera layout: no {folder}/ folder here or under {split}/")
        super().__init__(root, name=Path(path).resolve().name)
        self.root = root
        self.camera = folder
        self.projection_key = KITTI_CAMERAS[folder]
        self.depth_folder = root / folder.replace("image", "depth")
        self._errors: list[DataFormatError] = []
        self._scan()
        if strict and self._errors:
            first = self._errors[0]
            more = f" (and {len(self._errors) - 1} more problem(s); run 'lidarfuzz info' to list them)" \
                if self._errors[1:] else ""
            raise DataFormatError(first.path, first.message + more, line=first.line, field=first.field)

    def _warn(self, path: Path, message: str) -> None:
        self._problems.append(Problem("warning", str(path), message))

    def _error(self, exc: DataFormatError) -> None:
        self._errors.append(exc)
        text = f"field '{exc.field}': {exc.message}" if exc.field else exc.message
        self._problems.append(Problem("error", str(exc.path), text, exc.line))

    def _scan(self) -> None:
        root, images = self.root, self.root / self.camera
        files = sorted(p for p in images.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
        by_id: dict[str, Path] = {}
        for file in files:
            if file.stem in by_id:
                self._error(DataFormatError(images, f"two images for frame {file.stem!r}: {by_id[file.stem].name} "
                                            f"and {file.name}"))
                continue
            by_id[file.stem] = file
        self._files = by_id
        self._ids = tuple(sorted(by_id))
        others = [p.name for p in images.iterdir() if p.is_file() and p.suffix.lower() not in IMAGE_SUFFIXES]
        if others:
            self._warn(images, f"{len(others)} file(s) that are not PNG or JPEG ignored, e.g. {sorted(others)[0]}")
        velodyne = root / "velodyne"
        if velodyne.is_dir():
            scans = {p.stem for p in velodyne.glob("*.bin")}
            alone = [i for i in self._ids if i not in scans]
            blind = sorted(scans - set(self._ids))
            if alone:
                self._warn(images, f"{len(alone)} image(s) without a LiDAR frame in velodyne/, e.g. {alone[0]}")
            if blind:
                self._warn(velodyne, f"{len(blind)} LiDAR frame(s) without an image in {self.camera}/, e.g. {blind[0]}")
        self._has_calib = (root / "calib").is_dir()
        if self._has_calib:
            missing = [i for i in self._ids if not (root / "calib" / f"{i}.txt").is_file()]
            if missing:
                self._warn(root / "calib", f"{len(missing)} frame(s) without a calib file (no intrinsics), "
                           f"e.g. {missing[0]}")
        if self.depth_folder.is_dir():
            missing = [i for i in self._ids if not (self.depth_folder / f"{i}.png").is_file()]
            if missing:
                self._warn(self.depth_folder, f"{len(missing)} frame(s) without a depth map, e.g. {missing[0]}")
        self._steering: dict[str, tuple[float, float | None, int]] = {}
        steering_file = root / STEERING_FILE
        if steering_file.is_file():
            try:
                self._steering, errors = read_steering_csv(steering_file)
            except DataFormatError as exc:
                errors = [exc]
            for error in errors:
                self._error(error)
            unlabelled = [i for i in self._ids if i not in self._steering]
            if unlabelled and not errors:
                self._warn(steering_file, f"{len(unlabelled)} frame(s) have no steering row (unlabelled), "
                           f"e.g. {unlabelled[0]}")
            strays = sorted(set(self._steering) - set(self._ids))
            if strays:
                self._warn(steering_file, f"{len(strays)} row(s) name no image in {self.camera}/, e.g. {strays[0]}")
        self._timestamps: dict[str, NDArray[np.float64]] | None = None
        self._poses: dict[str, NDArray[np.float64]] | None = None
        for name, width, attr in (("timestamps.txt", 1, "_timestamps"), ("poses.txt", 12, "_poses")):
            side = root / name
            if side.is_file():
                try:
                    setattr(self, attr, _read_keyed_lines(side, width))
                except DataFormatError as exc:
                    self._error(exc)

    @property
    def format(self) -> str:
        return "kitti"

    def frame_ids(self) -> Sequence[str]:
        return self._ids

    def _id_set(self) -> set[str]:
        return set(self._files)

    def image_path(self, frame_id: str) -> Path:
        if frame_id not in self._files:
            raise KeyError(f"{self.root}: no frame with id {frame_id!r}")
        return self._files[frame_id]

    def image_sizes(self) -> Counter[tuple[int, int]]:
        """How many images have each (height, width), from their headers (images may differ in size)."""
        sizes: Counter[tuple[int, int]] = Counter()
        for path in self._files.values():
            _, height, width = image_header(path.read_bytes(), path)
            sizes[height, width] += 1
        return sizes

    def load_calib(self, frame_id: str) -> KittiCalibration | None:
        path = self.root / "calib" / f"{frame_id}.txt"
        return KittiCalibration.from_file(path) if path.is_file() else None

    def _camera_pose(self, frame_id: str, calib: KittiCalibration | None = None) -> NDArray[np.float64] | None:
        """The camera → world pose of a frame: its LiDAR pose (poses.txt) moved to the camera by its calib."""
        if self._poses is None or frame_id not in self._poses:
            return None
        calib = calib or self.load_calib(frame_id)
        if calib is None:
            return None
        lidar_pose = np.eye(4)
        lidar_pose[:3, :] = self._poses[frame_id].reshape(3, 4)
        return camera_pose(lidar_pose, calib, self._projection(frame_id, calib))

    def _projection(self, frame_id: str, calib: KittiCalibration) -> NDArray[np.float64]:
        """The camera's 3×4 projection from the frame's calib: present, with an invertible 3×3 part."""
        matrix = getattr(calib, self.projection_key)
        path = self.root / "calib" / f"{frame_id}.txt"
        if matrix is None:
            raise DataFormatError(path, f"no {self.projection_key}: the {self.camera} camera's projection is needed",
                                  field=self.projection_key)
        projection = np.asarray(matrix, dtype=np.float64)
        if not invertible(projection[:, :3]):
            raise DataFormatError(path, "its 3×3 part is not invertible: not a camera projection",
                                  field=self.projection_key)
        return projection

    def load(self, frame_id: str) -> ImageSample:
        path = self.image_path(frame_id)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise DataFormatError(path, f"cannot read: {exc.strerror or exc}") from None
        image = decode_image(data, path)
        metadata: dict[str, Any] = {"source": str(path), "format": "kitti", "camera": self.camera,
                                    "size": [int(image.shape[0]), int(image.shape[1])]}
        calib = self.load_calib(frame_id)
        intrinsics = None
        if calib is not None:
            intrinsics = intrinsics_of(self._projection(frame_id, calib))
        depth = None
        depth_path = self.depth_folder / f"{frame_id}.png"
        if depth_path.is_file():
            depth = decode_depth(depth_path.read_bytes(), depth_path)
            if depth.shape != image.shape[:2]:
                raise DataFormatError(depth_path, f"the depth map is {depth.shape[1]}×{depth.shape[0]} but the "
                                      f"image is {image.shape[1]}×{image.shape[0]}")
        steering = None
        if frame_id in self._steering:
            steering, speed, line = self._steering[frame_id]
            metadata["steering_row"] = line
            if speed is not None:
                metadata["speed"] = speed
        timestamp = None
        if self._timestamps is not None and frame_id in self._timestamps:
            timestamp = float(self._timestamps[frame_id][0])
        pose = self._camera_pose(frame_id, calib)
        return ImageSample(image, frame_id=frame_id, steering=steering, depth=depth, intrinsics=intrinsics,
                           timestamp=timestamp, pose=pose, metadata=metadata)


class KittiImageLog(KittiImages, Log[ImageSample]):
    """KITTI camera images with ``timestamps.txt``: frames in time order."""

    def __init__(self, path: str | PathLike[str], **kwargs: Any) -> None:
        super().__init__(path, **kwargs)
        stamps = self._timestamps or {}
        missing = [i for i in self._ids if i not in stamps]
        if missing:
            raise DataFormatError(self.root / "timestamps.txt", f"no entry for {len(missing)} frame(s), "
                                  f"e.g. {missing[0]!r}")
        self._ids = tuple(sorted(self._ids, key=lambda i: (float(stamps[i][0]), i)))

    def timestamps(self) -> NDArray[np.float64]:
        stamps = self._timestamps or {}
        return np.array([float(stamps[i][0]) for i in self._ids], dtype=np.float64)

    def poses(self) -> NDArray[np.float64] | None:
        """Camera → world per frame (see :func:`camera_pose`); None unless every frame has a pose and a calib."""
        if self._poses is None:
            return None
        out = np.empty((len(self._ids), 4, 4))
        for index, frame_id in enumerate(self._ids):
            pose = self._camera_pose(frame_id)
            if pose is None:
                return None
            out[index] = pose
        return out


def open_kitti_images(path: str | PathLike[str], **kwargs: Any) -> KittiImages:
    """A :class:`KittiImageLog` when the folder has ``timestamps.txt``, else :class:`KittiImages`."""
    root = find_image_root(path, kwargs.get("camera") or "image_2", kwargs.get("split", "training"))
    if root is not None and (root / "timestamps.txt").is_file():
        return KittiImageLog(path, **kwargs)
    return KittiImages(path, **kwargs)
