"""The KITTI object layout: ``velodyne/``, ``label_2/``, ``calib/``, ``image_2/``, ``ImageSets/``.

Layout (``root`` may also contain ``training/`` and ``testing/`` with this inside)::

    root/velodyne/000000.bin        N×4 float32 x, y, z, reflectance
    root/label_2/000000.txt         one object per line (camera frame; score optional)
    root/calib/000000.txt           P0–P3, R0_rect, Tr_velo_to_cam, Tr_imu_to_velo
    root/image_2/000000.png         optional; only its size is read
    root/ImageSets/{train,val}.txt  optional frame-id lists

lidarfuzz adds side files that plain KITTI tools ignore:

    root/velodyne_extra/000000.npz  point channels beyond x, y, z, intensity (ring, time, ...)
    root/roi/000000.json            drivable-area polygons (GeoJSON, LiDAR frame)
    root/label_2_extra/000000.json  per-object fields KITTI labels lack ({"track_ids": [...], "objects":
                                    {"num_points": [...], ...}}, one entry per label line)
    root/timestamps.txt             "<frame_id> <seconds>" per line: the data set is a log
    root/poses.txt                  "<frame_id> <12 numbers>" per line: 3×4 LiDAR → world

Label lines are ``type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y [score]``
with ``x y z`` the bottom centre in the rectified camera frame. Unknown values are
written with KITTI's placeholders (truncation -1, occlusion -1, alpha -10, 2D box
-1 -1 -1 -1) and read back as unknown (NaN / -1). Numbers are written in Python's
shortest exact form so files read back bit-for-bit.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable, Sequence
from os import PathLike
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import write_bytes, write_text
from lidarfuzz.io.common import NonFinitePolicy, Problem
from lidarfuzz.io.dataset import Dataset, Log
from lidarfuzz.io.formats import bin as bin_format
from lidarfuzz.io.layouts import LAYOUTS, PointLayout, layout_from_structure, parse_layout
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.geometry import box_corners
from lidarfuzz.scene.points import STANDARD_CHANNELS, PointCloud
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene

KITTI_CLASSES: tuple[str, ...] = (
    "Car", "Van", "Truck", "Pedestrian", "Person_sitting", "Cyclist", "Tram", "Misc", "DontCare",
)
LABEL_FIELDS: tuple[str, ...] = (
    "type", "truncated", "occluded", "alpha", "bbox_left", "bbox_top", "bbox_right", "bbox_bottom",
    "height", "width", "length", "x", "y", "z", "rotation_y", "score",
)


# --------------------------------------------------------------------------- labels
def parse_labels(
    text: str,
    calib: KittiCalibration | None,
    path: str | PathLike[str] = "<labels>",
    *,
    classes: Iterable[str] = KITTI_CLASSES,
) -> Boxes3D:
    """Parse label (or detection) lines into LiDAR-frame boxes.

    Args:
        text: The file's text.
        calib: The frame's calibration (needed to move boxes into the LiDAR frame;
            may be ``None`` only when there are no objects other than DontCare).
        path: Shown in error messages.
        classes: Accepted class names.

    Raises:
        DataFormatError: Wrong field count, non-numbers, unknown class, negative size,
            or objects without a calibration — naming the file, line and field.
    """
    allowed = set(classes)
    rows: list[tuple[str, list[float]]] = []
    line_numbers: list[int] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        tokens = raw.split()
        if not tokens:
            continue
        if len(tokens) not in (15, 16):
            raise DataFormatError(
                path, f"expected 15 fields (16 with a score), found {len(tokens)}", line=lineno,
                hint="format: type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y [score]",
            )
        cls = tokens[0]
        if cls not in allowed:
            raise DataFormatError(
                path, f"unknown class {cls!r}; expected one of {', '.join(sorted(allowed))}",
                line=lineno, field="type",
            )
        values: list[float] = []
        for name, token in zip(LABEL_FIELDS[1:], tokens[1:], strict=False):
            try:
                values.append(float(token))
            except ValueError:
                raise DataFormatError(path, f"{token!r} is not a number", line=lineno, field=name) from None
            if not np.isfinite(values[-1]):
                raise DataFormatError(path, f"{token!r} is not finite", line=lineno, field=name)
        if cls != "DontCare":
            for name, value in zip(("height", "width", "length"), values[7:10], strict=True):
                if value < 0:
                    raise DataFormatError(path, f"negative size {value}", line=lineno, field=name)
            occ = values[1]
            if occ != int(occ) or occ not in (-1, 0, 1, 2, 3):
                raise DataFormatError(path, f"occlusion must be 0, 1, 2, 3 (or -1), got {occ}", line=lineno,
                                      field="occluded")
        rows.append((cls, values))
        line_numbers.append(lineno)

    n = len(rows)
    labels = [r[0] for r in rows]
    v = np.array([r[1][:14] for r in rows], dtype=np.float64).reshape(n, 14)
    has_score = [len(r[1]) == 15 for r in rows]
    if any(has_score) and not all(has_score):
        first = line_numbers[has_score.index(not has_score[0])]
        raise DataFormatError(
            path, "some lines have a score and some do not (this one differs from the first)", line=first,
            field="score",
        )
    scores = np.array([r[1][14] for r in rows]) if n and all(has_score) else None

    dontcare = np.array([c == "DontCare" for c in labels], dtype=bool)
    boxes = np.full((n, 7), np.nan)
    geometric = ~dontcare
    if geometric.any():
        if calib is None:
            raise DataFormatError(path, "labels need the frame's calib file to be placed in the LiDAR frame")
        boxes[geometric] = calib.boxes_from_camera(v[geometric, 10:13], v[geometric, 7:10], v[geometric, 13])
    truncation = np.where(v[:, 0] == -1, np.nan, v[:, 0])
    occlusion = np.where(dontcare, -1, v[:, 1]).astype(np.int64)
    alpha = np.where(v[:, 2] == -10, np.nan, v[:, 2])
    bbox2d = v[:, 3:7].copy()
    bbox2d[np.all(bbox2d == -1, axis=1)] = np.nan
    return Boxes3D.from_array(
        boxes, labels, scores=scores, truncation=truncation, occlusion=occlusion, alpha=alpha, bbox2d=bbox2d
    )


def _num(value: float) -> str:
    return repr(float(value))


def format_labels(boxes: Boxes3D, calib: KittiCalibration | None, *, complete: bool = False) -> str:
    """KITTI label lines for ``boxes`` (a score column when every box has a score).

    Args:
        boxes: LiDAR-frame boxes.
        calib: Needed for boxes with geometry.
        complete: Fill unknown ``alpha`` and 2D boxes by projection through ``calib``
            (as OpenPCDet does for LiDAR-only detections).
    """
    n = len(boxes)
    if n == 0:
        return ""
    geometric = boxes.has_geometry
    if geometric.any() and calib is None:
        raise ValueError("writing labels of 3D boxes needs a calibration")
    arr = boxes.as_array()
    loc = np.full((n, 3), -1000.0)
    hwl = np.full((n, 3), -1.0)
    ry = np.full(n, -10.0)
    alpha = boxes.alpha.copy()
    bbox2d = boxes.bbox2d.copy()
    if geometric.any():
        assert calib is not None
        loc[geometric], hwl[geometric], ry[geometric] = calib.boxes_to_camera(arr[geometric])
        if complete:
            fill_alpha = geometric & np.isnan(alpha)
            alpha[fill_alpha] = calib.alpha(arr[fill_alpha])
            # Only boxes wholly in front of the camera have a projection; others stay unknown (-1).
            fill_box = geometric & np.isnan(bbox2d).any(axis=1)
            if fill_box.any():
                corners = box_corners(arr[fill_box]).reshape(-1, 3)
                _, depth = calib.rect_to_image(calib.lidar_to_rect(corners))
                in_front = np.flatnonzero(fill_box)[np.all(depth.reshape(-1, 8) > 0.1, axis=1)]
                projected = calib.boxes_to_image(arr[in_front])
                # A box in front of the camera but beside the image clips to a zero-width (or
                # zero-height) box: it has no 2D box, as relabel_in_image leaves it, not a sliver
                # at the image's edge that the devkit would count as a visible object.
                has_area = (projected[:, 2] > projected[:, 0]) & (projected[:, 3] > projected[:, 1])
                bbox2d[in_front[has_area]] = projected[has_area]
    alpha = np.where(np.isnan(alpha), -10.0, alpha)
    bbox2d = np.where(np.isnan(bbox2d).any(axis=1, keepdims=True), -1.0, bbox2d)
    truncation = np.where(np.isnan(boxes.truncation), -1.0, boxes.truncation)
    with_score = bool(np.all(np.isfinite(boxes.scores)))
    lines = []
    for i in range(n):
        fields = [
            str(boxes.labels[i]), _num(truncation[i]), str(int(boxes.occlusion[i])), _num(alpha[i]),
            *(_num(x) for x in bbox2d[i]), *(_num(x) for x in hwl[i]), *(_num(x) for x in loc[i]), _num(ry[i]),
        ]
        if with_score:
            fields.append(_num(boxes.scores[i]))
        lines.append(" ".join(fields))
    return "\n".join(lines) + "\n"


def read_label_file(path: str | PathLike[str], calib: KittiCalibration | None, **kwargs: object) -> Boxes3D:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise DataFormatError(path, "not a text file (expected KITTI label lines)") from None
    return parse_labels(text, calib, path, **kwargs)  # type: ignore[arg-type]


# --------------------------------------------------------------------------- small side files
def png_size(path: Path) -> tuple[int, int] | None:
    """(height, width) from a PNG header, without decoding the image; None if not a PNG."""
    with open(path, "rb") as handle:
        head = handle.read(24)
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    return height, width


def _read_keyed_lines(path: Path, width: int) -> dict[str, NDArray[np.float64]]:
    """Lines of ``<frame_id> <width numbers>`` (timestamps.txt, poses.txt)."""
    out: dict[str, NDArray[np.float64]] = {}
    for lineno, raw in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        tokens = raw.split()
        if not tokens:
            continue
        if len(tokens) != width + 1:
            raise DataFormatError(path, f"expected a frame id and {width} number(s), found {len(tokens)} fields",
                                  line=lineno)
        try:
            values = np.array([float(t) for t in tokens[1:]])
        except ValueError:
            raise DataFormatError(path, "not a number", line=lineno) from None
        if tokens[0] in out:
            raise DataFormatError(path, f"duplicate frame id {tokens[0]!r}", line=lineno)
        out[tokens[0]] = values
    return out


# --------------------------------------------------------------------------- data set
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
            for lineno, raw in enumerate(listing.read_text(encoding="utf-8").splitlines(), start=1):
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
        for name, width, attr in (("timestamps.txt", 1, "_timestamps"), ("poses.txt", 12, "_poses")):
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
            try:
                track_ids = json.loads(extra.read_text(encoding="utf-8")).get("track_ids")
                if track_ids is not None:
                    boxes = boxes.replace(track_ids=track_ids)
            except (ValueError, AttributeError) as exc:
                raise DataFormatError(extra, f"expected {{\"track_ids\": [one per label line]}}: {exc}") from None
        return boxes

    def _object_extras(self, frame_id: str) -> dict[str, object] | None:
        extra = self.root / "label_2_extra" / f"{frame_id}.json"
        if not extra.is_file():
            return None
        try:
            objects = json.loads(extra.read_text(encoding="utf-8")).get("objects")
        except (ValueError, AttributeError) as exc:
            raise DataFormatError(extra, f"not a JSON object: {exc}") from None
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
            try:
                roi = RoiMap.from_geojson(roi_path.read_text(encoding="utf-8"))
            except (ValueError, TypeError, KeyError, AttributeError) as exc:
                raise DataFormatError(roi_path, f"not a GeoJSON Polygon/MultiPolygon: {exc}") from None
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
        return self._finish(Scene(scan.cloud, boxes, calib, frame_id=frame_id, timestamp=timestamp, pose=pose,
                                  roi=roi, metadata=meta))


def _attach_extra(cloud: PointCloud, path: Path, dropped: int) -> PointCloud:
    try:
        with np.load(path, allow_pickle=False) as archive:
            columns = {name: archive[name] for name in archive.files}
    except (OSError, ValueError) as exc:
        raise DataFormatError(path, f"cannot read extra channels: {exc}") from None
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
            raise DataFormatError(self.root / "timestamps.txt", "a log needs timestamps.txt")
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


# --------------------------------------------------------------------------- writer
class KittiWriter:
    """Writes scenes into a new KITTI-layout folder, each file atomically.

    The folder must not exist or be empty (unless ``overwrite``), so an existing data
    set is never modified. Log side files and ImageSets are written by :meth:`close`.

    Example:
        >>> import tempfile, pathlib
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "ds"
        >>> with KittiWriter(out) as writer:
        ...     writer.add(Scene(PointCloud(np.zeros((1, 4))), frame_id="000000"))
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
            lines = [f"{f} {_num(self._timestamps[f])}" for f in self._ids if f in self._timestamps]
            write_text(self.root / "timestamps.txt", "\n".join(lines) + "\n", overwrite=ow)
        if self._poses:
            lines = [f"{f} " + " ".join(_num(v) for v in self._poses[f]) for f in self._ids if f in self._poses]
            write_text(self.root / "poses.txt", "\n".join(lines) + "\n", overwrite=ow)
        for name, ids in (image_sets or {}).items():
            write_text(self.root / "ImageSets" / f"{name}.txt", "".join(f"{i}\n" for i in ids), overwrite=ow)


def compact_channel(values: NDArray[np.floating]) -> NDArray[np.generic]:
    """The channel in the smallest integer type that holds it exactly, or as it is.

    Ring numbers, class ids and instance ids are integers stored as float32 in a
    cloud; on disk they take 1–2 bytes instead of 4, and read back identical.
    """
    v = np.asarray(values)
    if v.size == 0 or not np.all(np.isfinite(v)) or not np.array_equal(v, np.round(v)):
        return v
    lo, hi = float(v.min()), float(v.max())
    for dtype in (np.uint8, np.int8, np.int16, np.int32):
        info = np.iinfo(dtype)
        if info.min <= lo and hi <= info.max and hi <= 2**24:  # float32 holds integers exactly up to 2**24
            return v.astype(dtype)
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
        import io

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
