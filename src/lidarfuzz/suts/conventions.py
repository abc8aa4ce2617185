"""Box conventions of the field's tools, converted at the edge to lidarfuzz's.

lidarfuzz: LiDAR frame (x forward, y left, z up), **centre** origin,
``[x, y, z, l, w, h, yaw]`` with ``yaw`` counter-clockwise from +x.

* ``openpcdet`` — OpenPCDet's ``boxes_lidar``: ``[x, y, z, dx, dy, dz, heading]``, centre
  origin, same axes and heading: identical to lidarfuzz's.
* ``mmdet3d`` — mmdetection3d ≥ 1.0 ``LiDARInstance3DBoxes``: ``[x, y, z, x_size, y_size,
  z_size, yaw]`` with the **bottom** centre as origin (relative origin (0.5, 0.5, 0)),
  yaw counter-clockwise from +x.
* ``mmdet3d-legacy`` — mmdetection3d before the 1.0 coordinate refactor: bottom centre,
  ``x_size``/``y_size`` hold width and length, and ``yaw_old = -yaw - π/2``.
* ``kitti`` — KITTI camera labels: ``location`` (bottom centre, rectified camera frame),
  ``dimensions`` (h, w, l) and ``rotation_y``; needs the frame's calibration.

Labels may be names or integer class ids (1-based for OpenPCDet, 0-based for mmdet3d),
given with the list of class names.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.calib import KittiCalibration

Convention = Literal["lidarfuzz", "openpcdet", "mmdet3d", "mmdet3d-legacy"]
CONVENTIONS: tuple[str, ...] = ("lidarfuzz", "openpcdet", "mmdet3d", "mmdet3d-legacy")


def _array(boxes: ArrayLike) -> NDArray[np.float64]:
    b = np.asarray(boxes, dtype=np.float64)
    if b.size == 0:
        return b.reshape(0, 7)
    if b.ndim != 2 or b.shape[1] < 7:
        raise ValueError(f"boxes must be M×7 (or wider), got shape {b.shape}")
    return b[:, :7].copy()


def to_lidarfuzz(boxes: ArrayLike, convention: Convention) -> NDArray[np.float64]:
    """M×7 boxes of ``convention`` → lidarfuzz's centre-origin LiDAR boxes."""
    b = _array(boxes)
    if convention in ("lidarfuzz", "openpcdet"):
        return b
    if convention == "mmdet3d":
        b[:, 2] += b[:, 5] / 2.0
        return b
    if convention == "mmdet3d-legacy":
        b[:, 2] += b[:, 5] / 2.0
        b[:, [3, 4]] = b[:, [4, 3]]
        b[:, 6] = wrap_angle(-b[:, 6] - np.pi / 2.0)
        return b
    raise ValueError(f"unknown box convention {convention!r}; choose one of {', '.join(CONVENTIONS)}")


def from_lidarfuzz(boxes: ArrayLike, convention: Convention) -> NDArray[np.float64]:
    """lidarfuzz boxes → M×7 boxes of ``convention`` (the inverse of :func:`to_lidarfuzz`)."""
    b = _array(boxes)
    if convention in ("lidarfuzz", "openpcdet"):
        return b
    if convention == "mmdet3d":
        b[:, 2] -= b[:, 5] / 2.0
        return b
    if convention == "mmdet3d-legacy":
        b[:, 2] -= b[:, 5] / 2.0
        b[:, [3, 4]] = b[:, [4, 3]]
        b[:, 6] = wrap_angle(-b[:, 6] - np.pi / 2.0)
        return b
    raise ValueError(f"unknown box convention {convention!r}; choose one of {', '.join(CONVENTIONS)}")


def labels_from_ids(ids: ArrayLike, class_names: Sequence[str], *, one_based: bool) -> list[str]:
    """Class ids → names (OpenPCDet's ``pred_labels`` are 1-based, mmdet3d's ``labels_3d`` 0-based)."""
    index = np.asarray(ids, dtype=np.int64) - (1 if one_based else 0)
    bad = (index < 0) | (index >= len(class_names))
    if bad.any():
        raise ValueError(f"class id {int(np.asarray(ids)[bad][0])} outside the {len(class_names)} class names")
    return [class_names[i] for i in index.tolist()]


def detections(
    boxes: ArrayLike,
    labels: Sequence[str] | ArrayLike,
    scores: ArrayLike,
    convention: Convention = "lidarfuzz",
    class_names: Sequence[str] | None = None,
) -> Boxes3D:
    """A detector's raw arrays as lidarfuzz detections.

    Args:
        boxes: M×7 (or wider: extra columns such as velocities are dropped).
        labels: Names, or integer ids when ``class_names`` is given.
        scores: M confidences.
        convention: The detector's box convention.
        class_names: Names of the ids (OpenPCDet ids are 1-based, mmdet3d ids 0-based).

    Example:
        >>> d = detections([[10, 0, -1.5, 4, 2, 1.5, 0]], [0], [0.9], "mmdet3d", ["Car"])
        >>> d.centers.tolist(), d.labels.tolist()
        ([[10.0, 0.0, -0.75]], ['Car'])
    """
    array = to_lidarfuzz(boxes, convention)
    label_array = np.asarray(labels)
    if class_names is not None and label_array.size and np.issubdtype(label_array.dtype, np.integer):
        names = labels_from_ids(label_array, class_names, one_based=convention == "openpcdet")
    else:
        names = [str(v) for v in label_array.tolist()]
    return Boxes3D.from_array(array, names, scores=np.asarray(scores, dtype=np.float64).reshape(-1))


def from_kitti_camera(
    location: ArrayLike,
    dims_hwl: ArrayLike,
    rotation_y: ArrayLike,
    labels: Sequence[str],
    scores: ArrayLike,
    calib: KittiCalibration,
) -> Boxes3D:
    """KITTI camera-frame boxes (as in label files) → lidarfuzz detections."""
    return Boxes3D.from_array(
        calib.boxes_from_camera(location, dims_hwl, rotation_y),
        list(labels),
        scores=np.asarray(scores, dtype=np.float64).reshape(-1),
    )


def to_kitti_camera(
    boxes: Boxes3D, calib: KittiCalibration
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """lidarfuzz boxes → KITTI ``location``, ``dimensions`` (h, w, l), ``rotation_y``."""
    return calib.boxes_to_camera(boxes.as_array())
