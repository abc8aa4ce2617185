"""Opening a KITTI-layout folder: :class:`KittiDataset` (frames by id), :class:`KittiLog` (a
folder with ``timestamps.txt``: frames in time order, with poses) and :func:`open_kitti`,
which picks one. Structural problems are checked on opening (see :class:`KittiDataset`).
"""

from __future__ import annotations

import dataclasses
import json
import zipfile
from collections.abc import Iterable, Sequence
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFinitePolicy, Problem
from lidarfuzz.io.dataset import Dataset, Log
from lidarfuzz.io.formats import bin as bin_format
from lidarfuzz.io.guards import reading
from lidarfuzz.io.kitti.labels import KITTI_CLASSES, read_label_file
from lidarfuzz.io.layouts import LAYOUTS, PointLayout, layout_from_structure, parse_layout
from lidarfuzz.io.textfiles import check_json_depth, read_text
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration, invertible
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene


def png_size(path: Path) -> tuple[int, int] | None:
    """(height, width) from a PNG header, without decoding the image; None if not a PNG."""
    with open(path, "rb") as handle:
        head = handle.read(24)
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    return height, width


#: ``ego.txt`` (a simulator log's ego-vehicle labels): ``<frame_id>`` then these columns, each
#: attached to the frame's metadata under its name — speed (m/s), yaw rate (rad/s, left positive),
#: path curvature (1/m, left positive), steering angle (rad, left positive; bicycle model).
EGO_FILE = "ego.txt"
EGO_COLUMNS: tuple[str, ...] = ("speed", "yaw_rate", "curvature", "steering")


def _read_keyed_lines(path: Path, width: int) -> dict[str, NDArray[np.float64]]:
    """Lines of ``<frame_id> <width numbers>`` (timestamps.txt, poses.txt, ego.txt); ``#`` starts a comment line.

    Twelve numbers are a pose (3×4, row-major): its rotation must be invertible (maps given in the
    world frame are moved into the frame by the pose's inverse)."""
    out: dict[str, NDArray[np.float64]] = {}
    text = read_text(path, f"lines of a frame id and {width} number(s)")
    for lineno, raw in enumerate(text.splitlines(), start=1):
        tokens = raw.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if len(tokens) != width + 1:
            raise DataFormatError(path, f"expected a frame id and {width} number(s), found {len(tokens)} fields",
                                  line=lineno)
        try:
            values = np.array([float(t) for t in tokens[1:]])
        except ValueError:
            raise DataFormatError(path, "not a number", line=lineno) from None
        if not np.all(np.isfinite(values)):
            raise DataFormatError(path, "not a finite number", line=lineno)
        if width == 12 and not invertible(values.reshape(3, 4)[:, :3]):
            raise DataFormatError(path, f"the pose of frame {tokens[0]!r} has no inverse (its 3×3 rotation is "
                                  "singular)", line=lineno)
        if tokens[0] in out:
            raise DataFormatError(path, f"duplicate frame id {tokens[0]!r}", line=lineno)
        out[tokens[0]] = values
    return out



def unlabelled_note(ids: Sequence[str], total: int, shown: int = 5) -> str:
    """``2 of 5 frame(s) have no label file in label_2/ (000003, 000004)``: counted and named."""
    names = ", ".join(ids[:shown]) + (f", … ({len(ids) - shown} more)" if len(ids) > shown else "")
    return f"{len(ids)} of {total} frame(s) have no label file in label_2/ ({names}): unlabelled"


def find_kitti_root(path: str | PathLike[str], split: str = "training") -> Path | None:
    """The folder holding ``velodyne/`` (``path`` itself or ``path/<split>``), if any."""
    path = Path(path)
    if (path / "velodyne").is_dir():
        return path
    if (path / split / "velodyne").is_dir():
        return path / split
    return None


class KittiDataset(Dataset[Scene]):
    """A KITTI object data set (or a lidarfuzz data set in KITTI layout).

    Args:
        path: The root (holding ``velodyne/``) or a folder with ``training/``.
        split: ``training`` or ``testing`` when ``path`` holds both.
        subset: Name of an ``ImageSets/<subset>.txt`` list restricting the frames.
        strict: Raise on structural problems (labels without frames, frames without
            labels, duplicate ids, ...); when False they are only recorded in
            :meth:`problems` (this is what ``lidarfuzz info`` does).
        nonfinite: Policy for NaN/Inf coordinates (see :mod:`lidarfuzz.io.common`).
        classes: Class names accepted in label files.
        layout: The scans' point layout (a name or column spec, :mod:`lidarfuzz.io.layouts`);
            by default the folder's structure says (a SemanticKITTI sequence), else KITTI's.

    A data set with ``label_2/`` may have frames without a label file: they are *unlabelled*
    (``scene.metadata["labelled"]`` False, no boxes — unlike a labelled frame with no objects),
    listed by :meth:`unlabelled_ids` and reported as a warning; commands that need labels
    (AP) refuse them unless told to leave them out.
    """

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        split: str = "training",
        subset: str | None = None,
        strict: bool = True,
        nonfinite: NonFinitePolicy = "drop",
        classes: Iterable[str] = KITTI_CLASSES,
        layout: PointLayout | str | None = None,
    ) -> None:
        root = find_kitti_root(path, split)
        if root is None:
            raise DataFormatError(path, "not a KITTI layout: no velodyne/ folder here or under training/")
        super().__init__(root, name=Path(path).resolve().name)
        self.root = root
        self.nonfinite: NonFinitePolicy = nonfinite
        # a chosen layout is passed to every read (the user's word); else each scan's path decides
        self._layout_option: PointLayout | None = parse_layout(layout) if isinstance(layout, str) else layout
        self.layout = self._layout_option or layout_from_structure(root / "velodyne") or LAYOUTS["kitti"]
        self.classes = tuple(classes)
        self.subset = subset
        self._scan(Path(path), subset)
        errors = [p for p in self._problems if p.severity == "error"]
        if strict and errors:
            more = ""
            if len(errors) > 1:
                more = f" (and {len(errors) - 1} more problem(s); run 'lidarfuzz info' to list them)"
            first = errors[0]
            raise DataFormatError(first.path, first.message + more, line=first.line)

    @property
    def format(self) -> str:
        return "kitti"

    def _problem(self, severity: str, path: Path | str, message: str, line: int | None = None) -> None:
        self._problems.append(Problem(severity, str(path), message, line))  # type: ignore[arg-type]

    def _scan(self, given: Path, subset: str | None) -> None:
        root = self.root
        velodyne = root / "velodyne"
        frames = sorted(p.stem for p in velodyne.glob("*.bin"))
        others = sorted(p.name for p in velodyne.iterdir() if p.is_file() and p.suffix != ".bin")
        if others:
            self._problem("warning", velodyne, f"{len(others)} file(s) that are not .bin ignored, e.g. {others[0]}")
        labels: set[str] = set()
        if (root / "label_2").is_dir():
            labels = {p.stem for p in (root / "label_2").glob("*.txt")}
            if not labels:
                self._problem("warning", root / "label_2", "empty: the data set has no labels")
        self._label_ids = labels
        self._has_labels = bool(labels)
        self._has_calib = (root / "calib").is_dir()
        frame_set = set(frames)
        if self._has_labels:
            for stem in sorted(labels - frame_set):
                self._problem("error", root / "label_2" / f"{stem}.txt", "label file without a point-cloud frame")
            if not self._has_calib:
                self._problem("error", root, "label_2/ present but no calib/ folder: labels cannot be placed")
        if self._has_calib:
            calibs = {p.stem for p in (root / "calib").glob("*.txt")}
            for stem in sorted(frame_set - calibs):
                self._problem("error" if stem in labels else "warning",
                              velodyne / f"{stem}.bin", "frame without a calib file in calib/")

        if subset is not None:
            candidates = [root / "ImageSets" / f"{subset}.txt", given / "ImageSets" / f"{subset}.txt"]
            listing = next((c for c in candidates if c.is_file()), None)
            if listing is None:
                raise DataFormatError(candidates[0], f"no ImageSets list named {subset!r}")
            chosen: list[str] = []
            seen: dict[str, int] = {}
            for lineno, raw in enumerate(read_text(listing, "a list of frame ids").splitlines(), start=1):
                frame_id = raw.strip()
                if not frame_id:
                    continue
                if frame_id in seen:
                    self._problem("error", listing, f"duplicate frame id {frame_id!r} (first on line {seen[frame_id]})",
                                  lineno)
                    continue
                seen[frame_id] = lineno
                if frame_id not in frame_set:
                    self._problem("error", listing, f"frame id {frame_id!r} has no velodyne/{frame_id}.bin", lineno)
                    continue
                chosen.append(frame_id)
            frames = chosen
        self._frames = frames
        self._frame_set = set(frames)
        self._unlabelled = [f for f in frames if f not in labels] if self._has_labels else []
        if self._unlabelled:
            self._problem("warning", root / "label_2", unlabelled_note(self._unlabelled, len(frames)))

        self._timestamps: dict[str, NDArray[np.float64]] | None = None
        self._poses: dict[str, NDArray[np.float64]] | None = None
        self._ego: dict[str, NDArray[np.float64]] | None = None
        for name, width, attr in (("timestamps.txt", 1, "_timestamps"), ("poses.txt", 12, "_poses"),
                                  (EGO_FILE, len(EGO_COLUMNS), "_ego")):
            side = root / name
            if side.is_file() and self.layout.point_labels:
                # SemanticKITTI's poses.txt: one camera-frame pose per line, no frame ids
                self._problem("warning", side, "SemanticKITTI's camera-frame poses are not read")
            elif side.is_file():
                try:
                    values = _read_keyed_lines(side, width)
                except DataFormatError as exc:
                    self._problem("error", exc.path, exc.message, exc.line)
                    continue
                missing = [f for f in frames if f not in values]
                if missing:
                    self._problem("error", side, f"no entry for {len(missing)} frame(s), e.g. {missing[0]!r}")
                setattr(self, attr, values)

    # -- Dataset API ------------------------------------------------------------------
    def frame_ids(self) -> Sequence[str]:
        return self._frames

    def _id_set(self) -> set[str]:
        return self._frame_set

    def has_labels(self) -> bool:
        return self._has_labels

    def unlabelled_ids(self) -> list[str]:
        return list(self._unlabelled)

    def points_path(self, frame_id: str) -> Path:
        return self.root / "velodyne" / f"{frame_id}.bin"

    def label_path(self, frame_id: str) -> Path:
        return self.root / "label_2" / f"{frame_id}.txt"

    def calib_path(self, frame_id: str) -> Path:
        return self.root / "calib" / f"{frame_id}.txt"

    def load_calib(self, frame_id: str) -> KittiCalibration | None:
        path = self.calib_path(frame_id)
        if not path.is_file():
            return None
        calib = KittiCalibration.from_file(path)
        image = self.root / "image_2" / f"{frame_id}.png"
        if image.is_file():
            shape = png_size(image)
            if shape is not None:
                calib = KittiCalibration.from_mapping(
                    {k: getattr(calib, k) for k in ("P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam",
                                                     "Tr_imu_to_velo")},
                    image_shape=shape,
                )
        return calib

    def load_labels(self, frame_id: str, calib: KittiCalibration | None = None) -> Boxes3D:
        path = self.label_path(frame_id)
        if not path.is_file():
            return Boxes3D.empty()
        if calib is None:
            calib = self.load_calib(frame_id)
        boxes = read_label_file(path, calib, classes=self.classes)
        extra = self.root / "label_2_extra" / f"{frame_id}.json"
        if extra.is_file():
            track_ids = _label_extras(extra).get("track_ids")
            if track_ids is not None:
                boxes = boxes.replace(track_ids=_track_ids(extra, track_ids, len(boxes)))
        return boxes

    def _object_extras(self, frame_id: str) -> dict[str, object] | None:
        extra = self.root / "label_2_extra" / f"{frame_id}.json"
        if not extra.is_file():
            return None
        objects = _label_extras(extra).get("objects")
        return objects if isinstance(objects, dict) else None

    def load_points(self, frame_id: str) -> tuple[PointCloud, int]:
        scan = self.load_scan(frame_id)
        return scan.cloud, scan.dropped

    def load_scan(self, frame_id: str) -> bin_format.ScanRead:
        """The frame's scan (with its ``velodyne_extra/`` channels) and what reading it learnt."""
        scan = bin_format.read_scan(self.points_path(frame_id), layout=self.layout, nonfinite=self.nonfinite,
                                    user_chosen=self._layout_option is not None)
        extra = self.root / "velodyne_extra" / f"{frame_id}.npz"
        if extra.is_file():
            scan = dataclasses.replace(scan, cloud=_attach_extra(scan.cloud, extra, scan.dropped))
        return scan

    def load(self, frame_id: str) -> Scene:
        if frame_id not in self._frame_set:
            raise KeyError(f"{self.root}: no frame with id {frame_id!r}")
        scan = self.load_scan(frame_id)
        calib = self.load_calib(frame_id)
        labelled = frame_id in self._label_ids
        boxes = self.load_labels(frame_id, calib) if labelled else Boxes3D.empty()
        objects = self._object_extras(frame_id) if labelled else None
        roi_path = self.root / "roi" / f"{frame_id}.json"
        roi = None
        if roi_path.is_file():
            roi = _frame_map(roi_path)
        timestamp = float(self._timestamps[frame_id][0]) if self._timestamps and frame_id in self._timestamps else None
        pose = None
        if self._poses and frame_id in self._poses:
            pose = np.eye(4)
            pose[:3, :] = self._poses[frame_id].reshape(3, 4)
        meta: dict[str, object] = {"source": str(self.points_path(frame_id)), "format": "kitti",
                                   "labelled": labelled, **scan.metadata()}
        if roi is not None:
            meta["roi_source"] = "frame_map"
        if objects:
            meta["objects"] = objects
        if self._ego and frame_id in self._ego:
            meta.update(zip(EGO_COLUMNS, (float(v) for v in self._ego[frame_id]), strict=True))
        return self._finish(Scene(scan.cloud, boxes, calib, frame_id=frame_id, timestamp=timestamp, pose=pose,
                                  roi=roi, metadata=meta))


def _label_extras(path: Path) -> dict[str, Any]:
    """A ``label_2_extra/`` file: a JSON object (checked for depth before parsing)."""
    text = read_text(path, "a JSON object of per-object fields")
    check_json_depth(text, path)
    with reading(path, "read the per-object fields"):
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataFormatError(path, f"not valid JSON: {exc.msg}", line=exc.lineno) from None
    if not isinstance(data, dict):
        raise DataFormatError(path, f"expected a JSON object, found {type(data).__name__}", field="<root>",
                              hint='{"track_ids": [one per label line], "objects": {...}}')
    return data


def _track_ids(path: Path, values: object, boxes: int) -> NDArray[np.int64]:
    """``track_ids``: one integer per label line."""
    if not isinstance(values, list) or len(values) != boxes:
        found = f"{len(values)} value(s)" if isinstance(values, list) else f"a {type(values).__name__}"
        raise DataFormatError(path, f"expected a list of {boxes} integer(s), one per label line; found {found}",
                              field="track_ids")
    for index, value in enumerate(values):
        if isinstance(value, bool) or not isinstance(value, int) or not -(2**63) <= value < 2**63:
            raise DataFormatError(path, f"{value!r} is not a 64-bit integer", field=f"track_ids.{index}")
    return np.array(values, dtype=np.int64).reshape(boxes)


def _frame_map(path: Path) -> RoiMap:
    """A ``roi/`` file: a GeoJSON Polygon or MultiPolygon of finite coordinates."""
    text = read_text(path, "a GeoJSON Polygon/MultiPolygon")
    check_json_depth(text, path)
    with reading(path, "read the drivable-area map", hint="expected a GeoJSON Polygon or MultiPolygon"):
        roi = RoiMap.from_geojson(text)
    if not np.all(np.isfinite(np.asarray(shapely.get_coordinates(roi.geometry)))):
        raise DataFormatError(path, "coordinates must be finite numbers", field="coordinates")
    return roi


def _attach_extra(cloud: PointCloud, path: Path, dropped: int) -> PointCloud:
    # each member's .npy header is checked against the scan before numpy allocates what it claims
    with reading(path, "read extra channels"), zipfile.ZipFile(path) as archive:
        for member in archive.infolist():
            with archive.open(member) as handle:
                version = np.lib.format.read_magic(handle)
                read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                               else np.lib.format.read_array_header_2_0)
                shape, _, dtype = read_header(handle)
            name = member.filename.removesuffix(".npy")
            if tuple(shape) != (len(cloud),) or dtype.kind not in "biuf":
                raise DataFormatError(path, f"holds values of shape {tuple(shape)} ({dtype}) but the scan has "
                                      f"{len(cloud)} points", field=name)
    with reading(path, "read extra channels"), np.load(path, allow_pickle=False) as npz:
        columns = {name: npz[name] for name in npz.files}
    if dropped:
        raise DataFormatError(path, "extra channels cannot be matched to a scan whose NaN points were dropped",
                              hint="read with nonfinite='reject' to find the bad points")
    for name, values in columns.items():
        if values.shape != (len(cloud),):
            raise DataFormatError(path, f"has {values.shape[0] if values.ndim else 0} values but the scan has "
                                  f"{len(cloud)} points", field=name)
        cloud = cloud.with_channel(name, values)
    return cloud


class KittiLog(KittiDataset, Log[Scene]):
    """A KITTI-layout data set with ``timestamps.txt``: frames ordered by time, with poses if present."""

    def __init__(self, path: str | PathLike[str], **kwargs: object) -> None:
        super().__init__(path, **kwargs)  # type: ignore[arg-type]
        if self._timestamps is None:
            stamps = self.root / "timestamps.txt"
            # unreadable (recorded as a problem when not strict): that problem is why there is no log
            why = next((p for p in self._problems if p.severity == "error" and Path(p.path) == stamps), None)
            if why is not None:
                raise DataFormatError(stamps, why.message, line=why.line)
            raise DataFormatError(stamps, "a log needs timestamps.txt")
        self._frames = sorted(self._frames, key=lambda f: (self._stamp(f), f))

    def _stamp(self, frame_id: str) -> float:
        assert self._timestamps is not None
        return float(self._timestamps[frame_id][0]) if frame_id in self._timestamps else float("inf")

    def timestamps(self) -> NDArray[np.float64]:
        return np.array([self._stamp(f) for f in self._frames])

    def poses(self) -> NDArray[np.float64] | None:
        if self._poses is None:
            return None
        out = np.tile(np.eye(4), (len(self._frames), 1, 1))
        for i, frame_id in enumerate(self._frames):
            if frame_id in self._poses:
                out[i, :3, :] = self._poses[frame_id].reshape(3, 4)
        return out


def open_kitti(path: str | PathLike[str], **kwargs: object) -> KittiDataset:
    """A :class:`KittiLog` when the layout has ``timestamps.txt``, else a :class:`KittiDataset`."""
    root = find_kitti_root(path, str(kwargs.get("split", "training")))
    if root is not None and (root / "timestamps.txt").is_file():
        return KittiLog(path, **kwargs)
    return KittiDataset(path, **kwargs)  # type: ignore[arg-type]
