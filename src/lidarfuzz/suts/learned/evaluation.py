"""A detector on labelled frames: KITTI AP, and figures that still mean something on a few real frames.

KITTI AP needs dozens of objects per class before it describes a detector (see
:meth:`~lidarfuzz.oracles.kitti_eval.KittiEvalResult.sample_warnings`); a few real frames
have a few cars. So :func:`recall_figures` counts what a user would check by eye: which
labelled cars were found (bird's-eye IoU ≥ 0.5, 3D IoU ≥ 0.5 and ≥ 0.7) and how many boxes
were put where nothing is labelled (no overlap with any labelled object of any class, and
not in a DontCare region of the image).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lidarfuzz.oracles.kitti_eval import KittiFrame, evaluate_kitti
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import iou_3d, iou_bev
from lidarfuzz.scene.scene import Scene

CLASSES = ("Car", "Pedestrian", "Cyclist")


def detections_in_view(scene: Scene, detections: Boxes3D) -> Boxes3D:
    """Detections whose centre the camera sees (KITTI labels, and so scoring, cover only that view)."""
    if len(detections) and scene.calib is not None:
        return detections.select(scene.calib.in_view(detections.centers))
    return detections


def kitti_frame(scene: Scene, detections: Boxes3D) -> KittiFrame:
    """The scene's labels and the detections it sees, for the KITTI evaluator (its default
    calibration when the scene has none)."""
    shown = detections_in_view(scene, detections)
    return KittiFrame(scene.boxes, shown, scene.calib) if scene.calib is not None else KittiFrame(scene.boxes, shown)


def split_ap(sut: Any, scenes: Iterable[Scene], classes: Sequence[str] = CLASSES) -> dict[str, Any]:
    """Moderate KITTI AP|R40 (BEV, 3D) per class of a loaded SUT on labelled scenes, with the evaluator's warnings."""
    frames = [kitti_frame(scene, sut.detect(scene)) for scene in scenes]
    result = evaluate_kitti(frames)
    ap = {c: {m: round(float(result.get(m, c, "moderate", "R40")), 2) for m in ("bev", "3d")} for c in classes}
    return {"ap_r40_moderate": ap, "frames": len(frames), "warnings": result.sample_warnings()}


@dataclass
class RecallFigures:
    """Recall of labelled cars and false boxes over some frames (see :func:`recall_figures`)."""

    frames: int = 0
    cars: int = 0
    cars_in_range: int = 0
    found_bev_05: int = 0
    found_3d_05: int = 0
    found_3d_07: int = 0
    false_boxes: int = 0
    boxes: int = 0
    per_frame: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        def share(k: int) -> float | None:
            return round(k / self.cars_in_range, 3) if self.cars_in_range else None

        return {
            "frames": self.frames, "cars": self.cars, "cars_in_range": self.cars_in_range,
            "recall_bev_0.5": share(self.found_bev_05), "recall_3d_0.5": share(self.found_3d_05),
            "recall_3d_0.7": share(self.found_3d_07),
            "false_boxes_per_frame": round(self.false_boxes / self.frames, 2) if self.frames else None,
            "boxes_per_frame": round(self.boxes / self.frames, 2) if self.frames else None,
            "per_frame": self.per_frame,
        }


def _in_dontcare(scene: Scene, detections: Boxes3D) -> np.ndarray:
    """Detections whose centre projects into a DontCare region's 2D box."""
    dontcare = scene.boxes.labels == "DontCare"
    inside = np.zeros(len(detections), dtype=bool)
    if not dontcare.any() or not len(detections) or scene.calib is None:
        return inside
    uv, depth = scene.calib.lidar_to_image(detections.centers)
    for left, top, right, bottom in scene.boxes.bbox2d[dontcare]:
        inside |= (depth > 0) & (uv[:, 0] >= left) & (uv[:, 0] <= right) & (uv[:, 1] >= top) & (uv[:, 1] <= bottom)
    return inside


def recall_figures(
    detections: Sequence[tuple[Scene, Boxes3D]],
    *,
    min_score: float = 0.3,
    x_range: tuple[float, float] = (0.0, 57.6),
    y_range: tuple[float, float] = (-38.4, 38.4),
) -> RecallFigures:
    """Which labelled cars were found and how many boxes were put where nothing is labelled.

    Args:
        detections: (scene with its labels, the detector's boxes) per frame.
        min_score: Detections scored lower are ignored (the score a user would draw boxes at).
        x_range, y_range: Cars outside this box of the LiDAR frame (the detector's range) count
            in ``cars`` but not in ``cars_in_range``, over which recall is taken.

    A car is found at a threshold when some ``Car`` detection overlaps it by that IoU. A
    false box is a ``Car`` detection in the camera's view that overlaps no labelled object
    of any class (Van, Truck and Misc included: calling a van a car is not a phantom) and
    whose centre is in no DontCare region.
    """
    figures = RecallFigures()
    for scene, boxes in detections:
        boxes = detections_in_view(scene, boxes)
        cars_det = boxes.select((boxes.labels == "Car") & (boxes.scores >= min_score))
        gt = scene.boxes.select(scene.boxes.has_geometry)
        cars = gt.select(gt.labels == "Car")
        reachable = (
            (cars.centers[:, 0] >= x_range[0]) & (cars.centers[:, 0] < x_range[1])
            & (cars.centers[:, 1] >= y_range[0]) & (cars.centers[:, 1] < y_range[1])
        )
        det, truth = cars_det.as_array(), cars.as_array()
        bev = iou_bev(truth, det) if len(det) and len(truth) else np.zeros((len(truth), len(det)))
        full = iou_3d(truth, det) if len(det) and len(truth) else np.zeros((len(truth), len(det)))
        best_bev = bev.max(axis=1) if len(det) else np.zeros(len(truth))
        best_3d = full.max(axis=1) if len(det) else np.zeros(len(truth))
        overlap_any = (iou_bev(det, gt.as_array()).max(axis=1) if len(det) and len(gt) else np.zeros(len(det))) > 0.0
        false = ~overlap_any & ~_in_dontcare(scene, cars_det)
        figures.frames += 1
        figures.cars += len(cars)
        figures.cars_in_range += int(reachable.sum())
        figures.found_bev_05 += int((best_bev[reachable] >= 0.5).sum())
        figures.found_3d_05 += int((best_3d[reachable] >= 0.5).sum())
        figures.found_3d_07 += int((best_3d[reachable] >= 0.7).sum())
        figures.false_boxes += int(false.sum())
        figures.boxes += len(cars_det)
        figures.per_frame.append({
            "frame": scene.frame_id, "cars": len(cars), "cars_in_range": int(reachable.sum()),
            "best_bev_iou": [round(float(v), 2) for v in best_bev],
            "best_3d_iou": [round(float(v), 2) for v in best_3d],
            "car_boxes": len(cars_det), "false_boxes": int(false.sum()),
        })
    return figures


def real_frame_figures(
    sut: Any, scenes: Sequence[Scene], *, min_scores: Sequence[float] = (0.3, 0.5)
) -> dict[str, Any]:
    """Recall and false boxes at each score in ``min_scores``, plus AP with the evaluator's warnings.

    ``sut`` must be loaded (or load itself on first ``detect``). Detections are computed once.
    """
    pairs = [(scene, sut.detect(scene)) for scene in scenes]
    out: dict[str, Any] = {f"score>={s}": recall_figures(pairs, min_score=s).to_json() for s in min_scores}
    result = evaluate_kitti([kitti_frame(s, d) for s, d in pairs])
    out["ap_r40_moderate"] = {c: {m: round(float(result.get(m, c, "moderate", "R40")), 2) for m in ("bev", "3d")}
                              for c in CLASSES}
    out["ap_warnings"] = result.sample_warnings()
    return out


__all__ = ["CLASSES", "RecallFigures", "detections_in_view", "kitti_frame", "real_frame_figures", "recall_figures",
           "split_ap"]
