"""KITTI label lines ⇄ LiDAR-frame boxes.

Label lines are ``type truncated occluded alpha x1 y1 x2 y2 h w l x y z rotation_y [score]``
with ``x y z`` the bottom centre in the rectified camera frame. Unknown values are
written with KITTI's placeholders (truncation -1, occlusion -1, alpha -10, 2D box
-1 -1 -1 -1) and read back as unknown (NaN / -1). Numbers are written in Python's
shortest exact form (:func:`exact_number`) so files read back bit-for-bit.
"""

from __future__ import annotations

from collections.abc import Iterable
from os import PathLike
from pathlib import Path

import numpy as np

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.textfiles import read_text
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.geometry import box_corners

KITTI_CLASSES: tuple[str, ...] = (
    "Car", "Van", "Truck", "Pedestrian", "Person_sitting", "Cyclist", "Tram", "Misc", "DontCare",
)
LABEL_FIELDS: tuple[str, ...] = (
    "type", "truncated", "occluded", "alpha", "bbox_left", "bbox_top", "bbox_right", "bbox_bottom",
    "height", "width", "length", "x", "y", "z", "rotation_y", "score",
)



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


def exact_number(value: float) -> str:
    """A number in Python's shortest form that reads back as the same float."""
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
            str(boxes.labels[i]), exact_number(truncation[i]), str(int(boxes.occlusion[i])), exact_number(alpha[i]),
            *(exact_number(x) for x in bbox2d[i]), *(exact_number(x) for x in hwl[i]),
            *(exact_number(x) for x in loc[i]), exact_number(ry[i]),
        ]
        if with_score:
            fields.append(exact_number(boxes.scores[i]))
        lines.append(" ".join(fields))
    return "\n".join(lines) + "\n"


def read_label_file(path: str | PathLike[str], calib: KittiCalibration | None, **kwargs: object) -> Boxes3D:
    path = Path(path)
    text = read_text(path, "KITTI label lines")
    return parse_labels(text, calib, path, **kwargs)  # type: ignore[arg-type]
