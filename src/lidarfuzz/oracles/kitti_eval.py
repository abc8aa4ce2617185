"""KITTI 3D object detection evaluation (bbox, BEV, 3D and AOS; AP|R11 and AP|R40).

A re-implementation of the official devkit's ``evaluate_object_3d_offline`` with the
conventions of its Python ports (OpenPCDet ``kitti_object_eval_python``, mmdetection3d
``kitti_eval``):

* geometry is compared in the rectified camera frame: BEV overlap of the footprints on the
  camera x–z plane, height overlap along camera y, 3D IoU = BEV intersection × height
  overlap / union volume; 2D boxes compared without the ``+1`` pixel convention;
* GT of a neighbour class (Van for Car, Person_sitting for Pedestrian) and GT outside the
  difficulty (occlusion/truncation above the maximum, 2D height ``<=`` the minimum) are
  ignored: they absorb matching detections and never count as FN;
* detections of other classes are dropped; detections whose 2D height is ``<`` the minimum
  are ignored (the devkit's ``|y2 − y1|``, so a box given upside down keeps its height; a
  ground-truth box's height is the signed ``y2 − y1``, so an upside-down one is ignored, as
  there); unmatched detections overlapping a DontCare 2D box by more than the class
  threshold (intersection over the detection's own area) are not FPs (bbox metric only,
  as in the Python ports);
* matches need overlap strictly ``>`` the threshold; 41 score thresholds sampled from the
  TP scores; precision made monotone; R11 averages samples 0, 4, …, 40, R40 samples 1…40;
  AOS accumulates ``(1 + cos Δα) / 2`` over TPs of the bbox metric;
* a detection scored at or below ``-10000000`` (the devkit's ``NO_DETECTION`` marker) never
  matches: the devkit only takes a candidate scoring strictly above the marker when it collects
  the TP scores, so such a detection gives no threshold, and every threshold lies above it;
* the results do not depend on the order of the frames: the frames' orientation
  similarities (the only sum that is not of integers) are added in ascending order.

Detections without a 2D box or alpha get them by projection through the calibration.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import shapely
from numpy.typing import NDArray

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.geometry import polygon_intersection_area

CLASSES: tuple[str, ...] = ("Car", "Pedestrian", "Cyclist")
DIFFICULTIES: tuple[str, ...] = ("easy", "moderate", "hard")
METRICS: tuple[str, ...] = ("bbox", "bev", "3d", "aos")
GEOMETRIC_METRICS: tuple[str, ...] = ("bbox", "bev", "3d")
#: Official overlap thresholds per metric and class.
OFFICIAL_OVERLAPS: dict[str, dict[str, float]] = {
    m: {"Car": 0.7, "Pedestrian": 0.5, "Cyclist": 0.5} for m in GEOMETRIC_METRICS
}
#: The "loose" set of the Python ports: bbox keeps the official values, BEV/3D are relaxed.
LOOSE_OVERLAPS: dict[str, dict[str, float]] = {
    "bbox": {"Car": 0.7, "Pedestrian": 0.5, "Cyclist": 0.5},
    "bev": {"Car": 0.5, "Pedestrian": 0.25, "Cyclist": 0.25},
    "3d": {"Car": 0.5, "Pedestrian": 0.25, "Cyclist": 0.25},
}
#: GT of these classes is ignored (neither TP nor FN) when evaluating the key class.
NEIGHBOUR_CLASSES: dict[str, str] = {"car": "van", "pedestrian": "person_sitting"}
MIN_HEIGHT = (40.0, 25.0, 25.0)
#: The devkit stores a detection's 2D height in an ``int32_t``; a height that does not fit
#: (or NaN) converts to ``INT_MIN`` on x86-64, the ``cvttsd2si`` result, so it counts as low.
_INT32_LIMIT = 2.0**31
MAX_OCCLUSION = (0, 1, 2)
MAX_TRUNCATION = (0.15, 0.3, 0.5)
NUM_SAMPLE_POINTS = 41
_NO_DETECTION = -10000000.0
#: Below this many counted objects of a class and difficulty an AP cannot reach 100 even for a
#: perfect detector: the devkit samples at most one score threshold per true positive, so with n
#: objects only the first n of the 41 precision samples are filled (see :func:`ap_ceiling`).
MIN_RELIABLE_OBJECTS = NUM_SAMPLE_POINTS


@dataclass(frozen=True)
class KittiFrame:
    """One frame to evaluate: ground truth (DontCare included), detections and calibration."""

    gt: Boxes3D
    detections: Boxes3D
    calib: KittiCalibration = field(default_factory=KittiCalibration.default)


@dataclass(frozen=True)
class KittiEvalResult:
    """AP in percent: ``ap[metric][class][difficulty][\"R11\" | \"R40\"]``."""

    ap: dict[str, dict[str, dict[str, dict[str, float]]]]
    overlaps: dict[str, dict[str, float]]
    num_frames: int
    #: Counted (not ignored) ground-truth objects: ``num_objects[class][difficulty]``; empty when
    #: unknown (results stored before it was recorded).
    num_objects: dict[str, dict[str, int]] = field(default_factory=dict)

    def get(self, metric: str, cls: str, difficulty: str, points: str = "R40") -> float:
        return self.ap[metric][cls][difficulty][points]

    def mean_ap(self, metric: str, difficulty: str, points: str = "R40") -> float:
        """mAP: the mean over the evaluated classes."""
        values = [self.ap[metric][cls][difficulty][points] for cls in self.ap[metric]]
        return float(np.mean(values)) if values else float("nan")

    def sample_warnings(self, *, min_objects: int = MIN_RELIABLE_OBJECTS) -> list[str]:
        """Why these figures may not mean what they seem: a single frame, or classes whose AP
        rests on fewer than ``min_objects`` objects (with the highest AP they could reach).

        Example:
            >>> gt = Boxes3D.create([[10, 0, -0.9], [20, 3, -0.9]], [[3.9, 1.6, 1.5]] * 2, [0.0, 0.0],
            ...     ["Car", "Car"], truncation=[0.0, 0.0], occlusion=[0, 0])
            >>> evaluate_kitti([KittiFrame(gt, gt.replace(scores=[0.9, 0.8]))], classes=["Car"]).sample_warnings()[1]
            'Car: too few objects to score (easy 2, moderate 2, hard 2; fewer than 41): a perfect detector \
reaches at most 2.5 AP|R40 and 9.1 AP|R11 (easy, moderate, hard)'
        """
        notes: list[str] = []
        if self.num_frames == 1:
            notes.append("AP from a single frame: it describes that frame, not the detector")
        for cls, per_difficulty in self.num_objects.items():
            few = {d: per_difficulty[d] for d in DIFFICULTIES if per_difficulty.get(d, min_objects) < min_objects}
            if not few:
                continue
            counts = ", ".join(f"{d} {n}" for d, n in few.items())
            if not any(few.values()):
                notes.append(f"{cls}: too few objects to score ({counts}; fewer than {min_objects}); with none the "
                             "AP is 0 whatever the detector does")
                continue
            by_count: dict[int, list[str]] = {}
            for difficulty, n in few.items():
                by_count.setdefault(n, []).append(difficulty)
            ceilings = "; ".join(
                "{:.1f} AP|R40 and {:.1f} AP|R11".format(*ap_ceiling(n)) + f" ({', '.join(ds)})"
                for n, ds in by_count.items())
            notes.append(f"{cls}: too few objects to score ({counts}; fewer than {min_objects}): a perfect "
                         f"detector reaches at most {ceilings}")
        return notes

    def to_dict(self) -> dict[str, Any]:
        mean = {m: {d: {p: self.mean_ap(m, d, p) for p in ("R11", "R40")} for d in DIFFICULTIES} for m in self.ap}
        return {"ap": self.ap, "map": mean, "overlaps": self.overlaps, "num_frames": self.num_frames,
                "num_objects": self.num_objects, "warnings": self.sample_warnings()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> KittiEvalResult:
        """The inverse of :meth:`to_dict` (``num_objects`` may be absent in older records)."""
        return cls(ap=data["ap"], overlaps=data["overlaps"], num_frames=data["num_frames"],
                   num_objects=data.get("num_objects") or {})

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    def format_table(self) -> str:
        """The text the Python ports print, e.g. ``Car AP@0.70, 0.70, 0.70:`` then one line per metric."""
        lines: list[str] = []
        for cls in self.ap["bbox"]:
            thr = ", ".join(f"{self.overlaps[m][cls]:.2f}" for m in GEOMETRIC_METRICS)
            for points, tag in (("R11", "AP"), ("R40", "AP_R40")):
                lines.append(f"{cls} {tag}@{thr}:")
                for metric in METRICS:
                    values = ", ".join(f"{self.ap[metric][cls][d][points]:.4f}" for d in DIFFICULTIES)
                    lines.append(f"{metric:<4} AP:{values}")
        return "\n".join(lines) + "\n"


# -- per-frame preparation ---------------------------------------------------------------
@dataclass
class _Frame:
    gt_labels: NDArray[np.str_]
    dt_labels: NDArray[np.str_]
    gt_bbox: NDArray[np.float64]
    dt_bbox: NDArray[np.float64]
    gt_alpha: NDArray[np.float64]
    dt_alpha: NDArray[np.float64]
    gt_trunc: NDArray[np.float64]
    gt_occ: NDArray[np.int64]
    dt_scores: NDArray[np.float64]
    iou: dict[str, NDArray[np.float64]]  # metric -> (n_dt, n_gt)


def image_box_overlap(a: NDArray[np.float64], b: NDArray[np.float64], criterion: int = -1) -> NDArray[np.float64]:
    """M×K overlap of 2D boxes: IoU (criterion -1) or intersection over the area of ``a`` (0)."""
    iw = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    ih = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    with np.errstate(invalid="ignore"):
        inter = np.where((iw > 0) & (ih > 0), iw * ih, 0.0)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = (
        area_a[:, None] + area_b[None, :] - inter if criterion == -1 else np.broadcast_to(area_a[:, None], inter.shape)
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(inter > 0, inter / union, 0.0)
    return np.nan_to_num(out, nan=0.0)


def detection_too_low(bbox: NDArray[np.float64], min_height: float) -> NDArray[np.bool_]:
    """Whether each detection's 2D box is lower than ``min_height``, as the devkit's ``cleanData`` decides.

    The devkit computes ``int32_t height = fabs(det.box.y1 - det.box.y2)``: the absolute height
    (a box given with ``y1 > y2`` is as tall as the right way up), truncated to an integer,
    then ``height < MIN_HEIGHT``. For a whole ``min_height`` truncation changes nothing
    (``⌊h⌋ < m ⇔ h < m``); a height beyond ``int32`` (or NaN) converts to ``INT_MIN``, low.

    Example:
        >>> detection_too_low(np.array([[0, 100, 50, 60], [0, 60, 50, 100], [0, 0, 9, 39.9]]), 40.0)
        array([False, False,  True])
    """
    height = np.abs(bbox[:, 3] - bbox[:, 1])
    with np.errstate(invalid="ignore"):
        return ~(height < _INT32_LIMIT) | (height < min_height)


# -- all frames at once --------------------------------------------------------------------
@dataclass
class _Batch:
    """Every frame's boxes concatenated (frame order kept) with their camera-frame geometry.

    ``*_frame`` gives each box's frame; ``pair_offset[f]`` is where frame ``f``'s
    ``n_dt × n_gt`` block of pair overlaps starts in ``pair_iou[metric]`` (row-major).
    """

    num_frames: int
    gt_frame: NDArray[np.int64]
    dt_frame: NDArray[np.int64]
    gt_offset: NDArray[np.int64]
    dt_offset: NDArray[np.int64]
    gt_labels: NDArray[np.str_]
    dt_labels: NDArray[np.str_]
    gt_bbox: NDArray[np.float64]
    dt_bbox: NDArray[np.float64]
    gt_alpha: NDArray[np.float64]
    dt_alpha: NDArray[np.float64]
    gt_trunc: NDArray[np.float64]
    gt_occ: NDArray[np.int64]
    dt_scores: NDArray[np.float64]
    pair_offset: NDArray[np.int64]
    pair_iou: dict[str, NDArray[np.float64]]


def _calib_key(calib: KittiCalibration) -> bytes:
    return calib.velo_to_rect.tobytes() + calib.P2.tobytes() + np.asarray(calib.image_shape).tobytes()


def _boxes_arrays(parts: Sequence[Boxes3D]) -> dict[str, NDArray[Any]]:
    if not parts:
        parts = [Boxes3D.empty()]
    return {
        "geometry": np.concatenate([b.as_array() for b in parts]),
        "labels": np.char.lower(np.concatenate([b.labels.astype(str) for b in parts]).astype(str)),
        "bbox": np.concatenate([b.bbox2d for b in parts]).astype(np.float64),
        "alpha": np.concatenate([b.alpha for b in parts]).astype(np.float64),
        "trunc": np.concatenate([b.truncation for b in parts]).astype(np.float64),
        "occ": np.concatenate([b.occlusion for b in parts]).astype(np.int64),
        "scores": np.concatenate([b.scores for b in parts]).astype(np.float64),
    }


def _camera_geometry(
    geometry: NDArray[np.float64],
    bbox: NDArray[np.float64],
    alpha: NDArray[np.float64],
    box_frame: NDArray[np.int64],
    frame_group: NDArray[np.int64],
    calibs: list[KittiCalibration],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Fill missing 2D boxes and alphas by projection (in place) and return the footprint
    corners on the camera x–z plane (M×4×2) and the vertical extent ``[y_top, y_bottom]`` (M×2),
    one calibration group at a time."""
    corners = np.full((len(geometry), 4, 2), np.nan)
    vertical = np.full((len(geometry), 2), np.nan)
    group = frame_group[box_frame]
    has_geo = np.all(np.isfinite(geometry), axis=1)
    for g, calib in enumerate(calibs):
        rows = np.flatnonzero((group == g) & has_geo)
        if rows.size == 0:
            continue
        boxes = geometry[rows]
        need_box = ~np.all(np.isfinite(bbox[rows]), axis=1)
        if need_box.any():
            bbox[rows[need_box]] = calib.boxes_to_image(boxes[need_box])
        need_alpha = ~np.isfinite(alpha[rows])
        if need_alpha.any():
            alpha[rows[need_alpha]] = calib.alpha(boxes[need_alpha])
        loc, dims, ry = calib.boxes_to_camera(boxes)
        corners[rows] = KittiCalibration.camera_box_corners(loc, dims, ry)[:, :4][..., [0, 2]]
        # camera y points down: a box spans [y - h, y]
        vertical[rows] = np.stack([loc[:, 1] - dims[:, 0], loc[:, 1]], axis=1)
    return corners, vertical


def _batch(frames: Sequence[KittiFrame]) -> _Batch:
    n = len(frames)
    groups: dict[bytes, int] = {}
    calibs: list[KittiCalibration] = []
    frame_group = np.zeros(n, dtype=np.int64)
    for f, frame in enumerate(frames):
        key = _calib_key(frame.calib)
        if key not in groups:
            groups[key] = len(calibs)
            calibs.append(frame.calib)
        frame_group[f] = groups[key]
    n_gt = np.array([len(fr.gt) for fr in frames], dtype=np.int64)
    n_dt = np.array([len(fr.detections) for fr in frames], dtype=np.int64)
    gt = _boxes_arrays([fr.gt for fr in frames])
    dt = _boxes_arrays([fr.detections for fr in frames])
    gt_frame = np.repeat(np.arange(n), n_gt)
    dt_frame = np.repeat(np.arange(n), n_dt)
    g_corn, g_vert = _camera_geometry(gt["geometry"], gt["bbox"], gt["alpha"], gt_frame, frame_group, calibs)
    d_corn, d_vert = _camera_geometry(dt["geometry"], dt["bbox"], dt["alpha"], dt_frame, frame_group, calibs)
    gt_offset = np.concatenate([[0], np.cumsum(n_gt)])
    dt_offset = np.concatenate([[0], np.cumsum(n_dt)])
    pairs = n_dt * n_gt
    pair_offset = np.concatenate([[0], np.cumsum(pairs)])
    # flat (dt, gt) index of every pair, frame by frame, row-major within a frame
    pair_frame = np.repeat(np.arange(n), pairs)
    local = np.arange(int(pair_offset[-1])) - pair_offset[pair_frame]
    ngt_p = n_gt[pair_frame]
    di = dt_offset[pair_frame] + local // np.maximum(ngt_p, 1)
    gi = gt_offset[pair_frame] + local % np.maximum(ngt_p, 1)
    iou = {
        "bbox": _paired_image_iou(dt["bbox"][di], gt["bbox"][gi]),
    }
    inter = np.zeros(len(di))
    # only pairs whose footprints' bounding circles meet can overlap
    d_centre, g_centre = d_corn.mean(axis=1), g_corn.mean(axis=1)
    d_radius = np.linalg.norm(d_corn[:, 0] - d_centre, axis=1)
    g_radius = np.linalg.norm(g_corn[:, 0] - g_centre, axis=1)
    with np.errstate(invalid="ignore"):
        near = np.linalg.norm(d_centre[di] - g_centre[gi], axis=1) <= d_radius[di] + g_radius[gi]
    if near.any():
        pairs = np.flatnonzero(near)
        inter[pairs] = polygon_intersection_area(
            shapely.polygons(d_corn[di[pairs]]), shapely.polygons(g_corn[gi[pairs]])
        )
    d_geo, g_geo = dt["geometry"][di], gt["geometry"][gi]
    area_d, area_g = d_geo[:, 3] * d_geo[:, 4], g_geo[:, 3] * g_geo[:, 4]
    height = np.minimum(d_vert[di, 1], g_vert[gi, 1]) - np.maximum(d_vert[di, 0], g_vert[gi, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        bev = inter / (area_d + area_g - inter)
        inter3 = inter * np.clip(height, 0.0, None)
        iou3 = inter3 / (area_d * d_geo[:, 5] + area_g * g_geo[:, 5] - inter3)
    iou["bev"] = np.nan_to_num(np.where(inter > 0, bev, 0.0), nan=0.0)
    iou["3d"] = np.nan_to_num(np.where(inter3 > 0, iou3, 0.0), nan=0.0)
    return _Batch(
        num_frames=n,
        gt_frame=gt_frame,
        dt_frame=dt_frame,
        gt_offset=gt_offset,
        dt_offset=dt_offset,
        gt_labels=gt["labels"],
        dt_labels=dt["labels"],
        gt_bbox=gt["bbox"],
        dt_bbox=dt["bbox"],
        gt_alpha=gt["alpha"],
        dt_alpha=dt["alpha"],
        gt_trunc=gt["trunc"],
        gt_occ=gt["occ"],
        dt_scores=dt["scores"],
        pair_offset=pair_offset,
        pair_iou=iou,
    )


def _paired_image_iou(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Element-wise IoU of two K×4 lists of 2D boxes (no +1 pixel convention)."""
    iw = np.minimum(a[:, 2], b[:, 2]) - np.maximum(a[:, 0], b[:, 0])
    ih = np.minimum(a[:, 3], b[:, 3]) - np.maximum(a[:, 1], b[:, 1])
    with np.errstate(invalid="ignore"):
        inter = np.where((iw > 0) & (ih > 0), iw * ih, 0.0)
    union = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1]) + (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1]) - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(inter > 0, inter / union, 0.0)
    return np.nan_to_num(out, nan=0.0)


def _prepare(frames: Sequence[KittiFrame]) -> list[_Frame]:
    """Per-frame views of :func:`_batch` for the readable reference loop (:func:`_statistics`)."""
    b = _batch(frames)
    out: list[_Frame] = []
    for f in range(b.num_frames):
        g = slice(b.gt_offset[f], b.gt_offset[f + 1])
        d = slice(b.dt_offset[f], b.dt_offset[f + 1])
        shape = (d.stop - d.start, g.stop - g.start)
        p = slice(b.pair_offset[f], b.pair_offset[f + 1])
        out.append(
            _Frame(
                gt_labels=b.gt_labels[g],
                dt_labels=b.dt_labels[d],
                gt_bbox=b.gt_bbox[g],
                dt_bbox=b.dt_bbox[d],
                gt_alpha=b.gt_alpha[g],
                dt_alpha=b.dt_alpha[d],
                gt_trunc=b.gt_trunc[g],
                gt_occ=b.gt_occ[g],
                dt_scores=b.dt_scores[d],
                iou={m: v[p].reshape(shape) for m, v in b.pair_iou.items()},
            )
        )
    return out


# -- the devkit's matching, one frame at a time (the readable reference) -------------------
@dataclass
class _Clean:
    ignored_gt: NDArray[np.int64]
    ignored_dt: NDArray[np.int64]
    dontcare: NDArray[np.float64]
    num_valid_gt: int


def _clean(fr: _Frame, cls: str, difficulty: int) -> _Clean:
    name = cls.lower()
    gt_h = fr.gt_bbox[:, 3] - fr.gt_bbox[:, 1]
    valid = np.where(fr.gt_labels == name, 1, -1)
    neighbour = NEIGHBOUR_CLASSES.get(name)
    if neighbour is not None:
        valid[fr.gt_labels == neighbour] = 0
    # NaN truncation (unknown) and occlusion -1 never exclude a box, as NaN comparisons are False.
    with np.errstate(invalid="ignore"):
        ignore = (
            (fr.gt_occ > MAX_OCCLUSION[difficulty])
            | (fr.gt_trunc > MAX_TRUNCATION[difficulty])
            | (gt_h <= MIN_HEIGHT[difficulty])
        )
    ignored_gt = np.full(len(valid), -1, dtype=np.int64)
    ignored_gt[(valid == 0) | ((valid == 1) & ignore)] = 1
    ignored_gt[(valid == 1) & ~ignore] = 0
    ignored_dt = np.where(fr.dt_labels == name, 0, -1).astype(np.int64)
    ignored_dt[detection_too_low(fr.dt_bbox, MIN_HEIGHT[difficulty])] = 1
    dontcare = fr.gt_bbox[fr.gt_labels == "dontcare"]
    return _Clean(ignored_gt, ignored_dt, dontcare, int(np.count_nonzero(ignored_gt == 0)))


def _statistics(
    fr: _Frame, c: _Clean, metric: str, min_overlap: float, thresh: float, compute_fp: bool
) -> tuple[int, int, int, float, list[float]]:
    """TP, FP, FN, orientation similarity and TP scores of one frame (the devkit's loop)."""
    overlaps = fr.iou[metric]
    scores = fr.dt_scores
    n_dt, n_gt = overlaps.shape
    assigned = np.zeros(n_dt, dtype=bool)
    below = scores < thresh if compute_fp else np.zeros(n_dt, dtype=bool)
    tp = fp = fn = 0
    tp_scores: list[float] = []
    deltas: list[float] = []
    ig_dt = c.ignored_dt
    usable = ((ig_dt != -1) & ~below).tolist()
    for i in range(n_gt):
        if c.ignored_gt[i] == -1:
            continue
        det = -1
        valid = _NO_DETECTION
        max_overlap = 0.0
        assigned_ignored = False
        for j in range(n_dt):
            if not usable[j] or assigned[j]:
                continue
            ov = overlaps[j, i]
            if ov <= min_overlap:
                continue
            if not compute_fp:
                # highest score wins; the first one on ties
                if scores[j] > valid:
                    det, valid = j, scores[j]
            elif (ov > max_overlap or assigned_ignored) and ig_dt[j] == 0:
                # highest overlap among non-ignored detections, replacing an ignored one
                max_overlap, det, valid, assigned_ignored = ov, j, 1.0, False
            elif valid == _NO_DETECTION and ig_dt[j] == 1:
                det, valid, assigned_ignored = j, 1.0, True
        if valid == _NO_DETECTION:
            if c.ignored_gt[i] == 0:
                fn += 1
        elif c.ignored_gt[i] == 1 or ig_dt[det] == 1:
            assigned[det] = True
        else:
            tp += 1
            tp_scores.append(float(scores[det]))
            deltas.append(float(fr.gt_alpha[i] - fr.dt_alpha[det]))
            assigned[det] = True
    similarity = -1.0
    if compute_fp:
        counted = ~(assigned | (ig_dt != 0) | below)
        fp = int(np.count_nonzero(counted))
        if metric == "bbox" and len(c.dontcare) and fp:
            dc = image_box_overlap(fr.dt_bbox, c.dontcare, criterion=0)
            # each DontCare region, in order, absorbs the still-unassigned detections it covers
            for k in range(dc.shape[1]):
                hit = counted & (dc[:, k] > min_overlap)
                fp -= int(np.count_nonzero(hit))
                counted &= ~hit
        if tp > 0 or fp > 0:
            similarity = float(sum((1.0 + np.cos(deltas)) / 2.0)) if deltas else 0.0
    return tp, fp, fn, similarity, tp_scores


def get_thresholds(scores: NDArray[np.float64], num_gt: int, num_sample_pts: int = NUM_SAMPLE_POINTS) -> list[float]:
    """Score thresholds at (about) evenly spaced recall levels, as the devkit picks them."""
    ordered = np.sort(scores)[::-1]
    current = 0.0
    out: list[float] = []
    n = len(ordered)
    for i, score in enumerate(ordered):
        left = (i + 1) / num_gt
        right = (i + 2) / num_gt if i < n - 1 else left
        if (right - current) < (current - left) and i < n - 1:
            continue
        out.append(float(score))
        current += 1.0 / (num_sample_pts - 1.0)
    return out


def _precision_curves(
    frames: list[_Frame], cleans: list[_Clean], metric: str, min_overlap: float, with_aos: bool
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    all_scores: list[float] = []
    for fr, c in zip(frames, cleans, strict=True):
        if c.num_valid_gt:
            all_scores += _statistics(fr, c, metric, min_overlap, 0.0, False)[4]
    num_valid = sum(c.num_valid_gt for c in cleans)
    precision = np.zeros(NUM_SAMPLE_POINTS)
    aos = np.zeros(NUM_SAMPLE_POINTS)
    if not all_scores:
        return precision, aos
    thresholds = np.asarray(get_thresholds(np.asarray(all_scores), num_valid))
    per_frame = np.zeros((len(frames), len(thresholds), 4))
    for f, (fr, c) in enumerate(zip(frames, cleans, strict=True)):
        if not np.any(c.ignored_dt != -1):
            # no detection of the class (an ignored one could still absorb a GT): only misses
            per_frame[f, :, 2] = c.num_valid_gt
            continue
        # the result only depends on how many detections pass the threshold: one evaluation
        # per distinct count, scattered to all thresholds at once
        order = np.sort(fr.dt_scores)
        active = len(order) - np.searchsorted(order, thresholds, side="left")
        keys, inverse = np.unique(active, return_inverse=True)
        stats = np.zeros((len(keys), 4))
        for u, key in enumerate(keys):
            thresh = float(thresholds[int(np.argmax(active == key))])
            tp, fp, fn, sim, _ = _statistics(fr, c, metric, min_overlap, thresh, True)
            stats[u] = (tp, fp, fn, sim if sim != -1 else 0.0)
        per_frame[f] = stats[inverse.reshape(-1)]
    pr = _sum_over_frames(per_frame)
    n = len(thresholds)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision[:n] = pr[:, 0] / (pr[:, 0] + pr[:, 1])
        aos[:n] = pr[:, 3] / (pr[:, 0] + pr[:, 1])
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    aos = np.maximum.accumulate(aos[::-1])[::-1]
    return precision, aos if with_aos else np.zeros(NUM_SAMPLE_POINTS)


# -- the devkit's matching, all frames at once -----------------------------------------------
@dataclass
class _ClassView:
    """One class's boxes padded per frame: ``F × D`` detections (score order kept as given)
    and ``F × G`` ground truth of the class or its neighbour class; padding indexes -1."""

    gt: NDArray[np.int64]  # F × G flat GT index, -1 pad
    dt: NDArray[np.int64]  # F × D flat detection index, -1 pad
    scores: NDArray[np.float64]  # F × D, -inf pad
    overlaps: dict[str, NDArray[np.float64]]  # metric -> F × D × G
    gt_alpha: NDArray[np.float64]
    dt_alpha: NDArray[np.float64]
    dontcare: NDArray[np.float64]  # F × D × C intersection over detection area, -inf pad


def _padded(flat_index: NDArray[np.int64], frame: NDArray[np.int64], num_frames: int) -> NDArray[np.int64]:
    """F × K table of the flat indices of each frame's selected boxes, -1 padded."""
    counts = np.bincount(frame, minlength=num_frames)
    width = int(counts.max()) if counts.size and len(frame) else 0
    table = np.full((num_frames, width), -1, dtype=np.int64)
    if len(frame):
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        rank = np.arange(len(frame)) - starts[frame]
        table[frame, rank] = flat_index
    return table


def _class_view(b: _Batch, cls: str) -> _ClassView:
    name = cls.lower()
    neighbour = NEIGHBOUR_CLASSES.get(name, "\0")
    gsel = np.flatnonzero((b.gt_labels == name) | (b.gt_labels == neighbour))
    # As in the devkit, a detection of any class lower than the difficulty's minimum height is
    # an *ignored* detection (it may absorb a GT); only taller ones of other classes drop out.
    low = detection_too_low(b.dt_bbox, max(MIN_HEIGHT))
    dsel = np.flatnonzero((b.dt_labels == name) | low)
    gt = _padded(gsel, b.gt_frame[gsel], b.num_frames)
    dt = _padded(dsel, b.dt_frame[dsel], b.num_frames)
    gmask, dmask = gt >= 0, dt >= 0
    d_local = np.where(dmask, dt - b.dt_offset[:-1, None], 0)[:, :, None]
    g_local = np.where(gmask, gt - b.gt_offset[:-1, None], 0)[:, None, :]
    n_gt = (b.gt_offset[1:] - b.gt_offset[:-1])[:, None, None]
    pair = b.pair_offset[:-1, None, None] + d_local * n_gt + g_local
    valid = dmask[:, :, None] & gmask[:, None, :]
    pair = np.where(valid, pair, 0)
    overlaps = {}
    for metric, values in b.pair_iou.items():
        taken = values[pair] if values.size else np.zeros(pair.shape)
        overlaps[metric] = np.where(valid, taken, 0.0)
    # DontCare regions of the frame: intersection over the detection's own area
    dc = _padded(*(lambda s: (s, b.gt_frame[s]))(np.flatnonzero(b.gt_labels == "dontcare")), b.num_frames)
    dc_box = (
        np.where((dc >= 0)[..., None], b.gt_bbox[np.maximum(dc, 0)], np.nan)
        if b.gt_bbox.size
        else np.full((*dc.shape, 4), np.nan)
    )
    d_box = (
        np.where(dmask[..., None], b.dt_bbox[np.maximum(dt, 0)], np.nan)
        if b.dt_bbox.size
        else np.full((*dt.shape, 4), np.nan)
    )
    iw = np.minimum(d_box[:, :, None, 2], dc_box[:, None, :, 2]) - np.maximum(
        d_box[:, :, None, 0], dc_box[:, None, :, 0]
    )
    ih = np.minimum(d_box[:, :, None, 3], dc_box[:, None, :, 3]) - np.maximum(
        d_box[:, :, None, 1], dc_box[:, None, :, 1]
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        inter = np.where((iw > 0) & (ih > 0), iw * ih, 0.0)
        area = ((d_box[..., 2] - d_box[..., 0]) * (d_box[..., 3] - d_box[..., 1]))[:, :, None]
        dontcare = np.nan_to_num(np.where(inter > 0, inter / area, 0.0), nan=0.0)
    scores = np.where(dmask, b.dt_scores[np.maximum(dt, 0)] if b.dt_scores.size else 0.0, -np.inf)
    return _ClassView(
        gt=gt,
        dt=dt,
        scores=scores,
        overlaps=overlaps,
        gt_alpha=np.where(gmask, b.gt_alpha[np.maximum(gt, 0)] if b.gt_alpha.size else 0.0, np.nan),
        dt_alpha=np.where(dmask, b.dt_alpha[np.maximum(dt, 0)] if b.dt_alpha.size else 0.0, np.nan),
        dontcare=dontcare,
    )


def _ignored(b: _Batch, view: _ClassView, cls: str, difficulty: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The devkit's ``ignored_gt`` (F × G) and ``ignored_dt`` (F × D): 0 counts, 1 ignored, -1 absent."""
    name = cls.lower()
    # indexing with an empty F × 0 table is fine even when there are no boxes at all
    g = np.maximum(view.gt, 0)
    height = b.gt_bbox[g, 3] - b.gt_bbox[g, 1]
    with np.errstate(invalid="ignore"):
        outside = (
            (b.gt_occ[g] > MAX_OCCLUSION[difficulty])
            | (b.gt_trunc[g] > MAX_TRUNCATION[difficulty])
            | (height <= MIN_HEIGHT[difficulty])
        )
    ignored_gt = np.where((b.gt_labels[g] == name) & ~outside, 0, 1)
    ignored_gt[view.gt < 0] = -1
    d = np.maximum(view.dt, 0)
    low = detection_too_low(b.dt_bbox[d].reshape(-1, 4), MIN_HEIGHT[difficulty]).reshape(d.shape)
    ignored_dt = np.where(low, 1, np.where(b.dt_labels[d] == name, 0, -1))
    ignored_dt[view.dt < 0] = -1
    return ignored_gt.astype(np.int64), ignored_dt.astype(np.int64)


def _match(
    overlaps: NDArray[np.float64],
    ignored_gt: NDArray[np.int64],
    ignored_dt: NDArray[np.int64],
    active: NDArray[np.bool_],
    scores: NDArray[np.float64],
    gt_alpha: NDArray[np.float64],
    dt_alpha: NDArray[np.float64],
    min_overlap: float,
    compute_fp: bool,
) -> tuple[NDArray[np.bool_], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """The devkit's per-frame assignment for N instances at once (N × D detections, N × G GT).

    GT are visited in order. Without ``compute_fp`` the candidate with the highest score wins
    (the first on ties), and only a score above the devkit's ``NO_DETECTION`` (-10⁷) makes a
    candidate (its ``det.thresh > valid_detection``, which starts at the marker); with it, the
    non-ignored candidate of highest overlap (the first on ties), else the first ignored one.
    Returns (assigned N × D, TP N, FN N, similarity N (summed over the TPs in GT order, as the
    devkit sums a frame's), and per GT the index of the detection that made it a true positive,
    -1 for none, N × G).
    """
    n, num_dt = active.shape
    rows = np.arange(n)
    usable = (ignored_dt != -1) & active
    if not compute_fp:
        usable &= scores > _NO_DETECTION
    assigned = np.zeros((n, num_dt), dtype=bool)
    tp = np.zeros(n, dtype=np.int64)
    fn = np.zeros(n, dtype=np.int64)
    similarity = np.zeros(n)
    tp_det = np.full(ignored_gt.shape, -1, dtype=np.int64)
    if num_dt == 0:  # nothing to match anywhere: every counted GT is a miss
        return assigned, tp, np.count_nonzero(ignored_gt == 0, axis=1), similarity, tp_det
    for i in range(ignored_gt.shape[1]):
        g = ignored_gt[:, i]
        cand = usable & ~assigned & (overlaps[:, :, i] > min_overlap)
        if compute_fp:
            counted = cand & (ignored_dt == 0)
            has_counted = counted.any(axis=1)
            best = np.argmax(np.where(counted, overlaps[:, :, i], -1.0), axis=1)
            first_ignored = np.argmax(cand, axis=1)  # only used when no counted candidate: all are ignored
            det = np.where(has_counted, best, first_ignored)
            found = cand.any(axis=1)
        else:
            found = cand.any(axis=1)
            det = np.argmax(np.where(cand, scores, -np.inf), axis=1)
        live = g != -1
        fn += (live & ~found & (g == 0)).astype(np.int64)
        hit = live & found
        assigned[rows[hit], det[hit]] = True
        is_tp = hit & (g == 0) & (ignored_dt[rows, det] == 0)
        tp += is_tp
        tp_det[is_tp, i] = det[is_tp]
        if compute_fp and is_tp.any():
            delta = gt_alpha[is_tp, i] - dt_alpha[rows[is_tp], det[is_tp]]
            similarity[is_tp] += (1.0 + np.cos(delta)) / 2.0
    return assigned, tp, fn, similarity, tp_det


def _sum_over_frames(stats: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per threshold, the frames' TP, FP, FN and similarity (``F × T × 4``) summed over the frames.

    TP, FP and FN are whole numbers, whose float sums are exact in any order; a float sum of
    similarities is not, so they are added in ascending order: a permutation of the frames
    gives the same bits (the devkit adds them in the files' order, a last-digit difference).
    """
    totals = stats.sum(axis=0)
    totals[:, 3] = np.sort(stats[:, :, 3], axis=0).sum(axis=0)
    return totals


def _curves(
    b: _Batch,
    view: _ClassView,
    ignored_gt: NDArray[np.int64],
    ignored_dt: NDArray[np.int64],
    metric: str,
    min_overlap: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Precision and AOS at the 41 sampled recall levels for one class, difficulty and metric."""
    precision = np.zeros(NUM_SAMPLE_POINTS)
    aos = np.zeros(NUM_SAMPLE_POINTS)
    overlaps = view.overlaps[metric]
    num_valid = int(np.count_nonzero(ignored_gt == 0))
    everything = np.ones(view.scores.shape, dtype=bool)
    _, _, _, _, tp_det = _match(
        overlaps, ignored_gt, ignored_dt, everything, view.scores, view.gt_alpha, view.dt_alpha, min_overlap, False
    )
    frame_of, column = np.nonzero(tp_det >= 0)
    tp_scores = view.scores[frame_of, tp_det[frame_of, column]]
    if tp_scores.size == 0:
        return precision, aos
    thresholds = np.asarray(get_thresholds(tp_scores, num_valid))
    # A frame's outcome at a threshold only depends on which detections pass it, i.e. on how
    # many do: one instance per distinct (frame, count), scattered back to every threshold.
    count = np.count_nonzero(view.scores[:, :, None] >= thresholds[None, None, :], axis=1)  # F × T
    num_frames, num_thr = count.shape
    key = np.arange(num_frames)[:, None] * (view.scores.shape[1] + 1) + count
    _, first, inverse = np.unique(key.ravel(), return_index=True, return_inverse=True)
    frame = first // num_thr
    active = view.scores[frame] >= thresholds[first % num_thr][:, None]
    assigned, tp, fn, similarity, _ = _match(
        overlaps[frame],
        ignored_gt[frame],
        ignored_dt[frame],
        active,
        view.scores[frame],
        view.gt_alpha[frame],
        view.dt_alpha[frame],
        min_overlap,
        True,
    )
    counted = active & ~assigned & (ignored_dt[frame] == 0)
    fp = np.count_nonzero(counted, axis=1)
    if metric == "bbox":
        fp -= np.count_nonzero(counted & np.any(view.dontcare[frame] > min_overlap, axis=2), axis=1)
    stats = np.stack([tp, fp, fn, similarity], axis=1)[inverse.reshape(-1)].reshape(num_frames, num_thr, 4)
    pr = _sum_over_frames(stats)
    n = len(thresholds)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision[:n] = pr[:, 0] / (pr[:, 0] + pr[:, 1])
        aos[:n] = pr[:, 3] / (pr[:, 0] + pr[:, 1])
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    aos = np.maximum.accumulate(aos[::-1])[::-1]
    return precision, aos


def ap_ceiling(num_objects: int) -> tuple[float, float]:
    """The highest AP|R40 and AP|R11 (percent) a perfect detector can score on ``num_objects`` objects.

    The devkit picks at most one score threshold per true positive (:func:`get_thresholds`), so
    only the first ``n`` of the 41 precision samples can be non-zero: R40 averages samples 1–40,
    of which ``n − 1`` are filled; R11 averages samples 0, 4, …, 40, of which ``⌊(n − 1)/4⌋ + 1`` are.

    Example:
        >>> ap_ceiling(1), ap_ceiling(2), ap_ceiling(41)
        ((0.0, 9.090909090909092), (2.5, 9.090909090909092), (100.0, 100.0))
    """
    n = min(int(num_objects), NUM_SAMPLE_POINTS)
    if n <= 0:
        return 0.0, 0.0
    return (n - 1) / 40.0 * 100.0, ((n - 1) // 4 + 1) / 11.0 * 100.0


def ap_r11(precision: NDArray[np.float64]) -> float:
    """Mean of the 11 samples 0, 4, …, 40 (recall 0, 0.1, …, 1), in percent."""
    return float(np.sum(precision[0::4]) / 11.0 * 100.0)


def ap_r40(precision: NDArray[np.float64]) -> float:
    """Mean of samples 1…40 (recall 1/40, …, 1; recall 0 excluded), in percent."""
    return float(np.sum(precision[1:]) / 40.0 * 100.0)


def evaluate_kitti(
    frames: Iterable[KittiFrame],
    *,
    classes: Sequence[str] = CLASSES,
    overlaps: Literal["official", "loose"] | dict[str, dict[str, float]] = "official",
) -> KittiEvalResult:
    """Evaluate detections against KITTI ground truth.

    Args:
        frames: ground truth, detections (with scores) and calibration per frame.
        classes: class names to evaluate (thresholds must exist for each).
        overlaps: ``"official"`` (0.7/0.5/0.5), ``"loose"`` (BEV/3D 0.5/0.25/0.25), or a
            mapping ``metric -> class -> threshold`` for ``bbox``, ``bev`` and ``3d``.

    With a single GT only one score threshold exists, so (as in the devkit) only the first
    of the 41 precision samples is filled: a perfect match scores 100/11 on R11 and 0 on R40.

    Example:
        >>> gt = Boxes3D.create([[10, 0, -0.9]], [[3.9, 1.6, 1.5]], [0.0], ["Car"],
        ...     truncation=[0.0], occlusion=[0])
        >>> dt = gt.replace(scores=[0.9])
        >>> r = evaluate_kitti([KittiFrame(gt, dt)])
        >>> round(r.get("3d", "Car", "moderate", "R11"), 4), r.get("3d", "Car", "moderate", "R40")
        (9.0909, 0.0)
    """
    if isinstance(overlaps, str):
        presets = {"official": OFFICIAL_OVERLAPS, "loose": LOOSE_OVERLAPS}
        if overlaps not in presets:
            raise ValueError(f"overlaps must be 'official', 'loose' or a mapping, got {overlaps!r}")
        table = presets[overlaps]
    else:
        table = overlaps
    missing = [(m, c) for m in GEOMETRIC_METRICS for c in classes if c not in table.get(m, {})]
    if missing:
        raise ValueError(f"no overlap threshold for (metric, class) {missing}; add them to `overlaps`")
    frame_list = list(frames)
    for index, frame in enumerate(frame_list):
        if len(frame.detections) and not np.all(np.isfinite(frame.detections.scores)):
            raise ValueError(f"frame {index}: every detection needs a finite score")
    batch = _batch(frame_list)
    ap: dict[str, dict[str, dict[str, dict[str, float]]]] = {m: {} for m in METRICS}
    counted: dict[str, dict[str, int]] = {}
    for cls in classes:
        for m in METRICS:
            ap[m][cls] = {}
        counted[cls] = {}
        view = _class_view(batch, cls)
        for d, difficulty in enumerate(DIFFICULTIES):
            ignored_gt, ignored_dt = _ignored(batch, view, cls, d)
            counted[cls][difficulty] = int(np.count_nonzero(ignored_gt == 0))
            for metric in GEOMETRIC_METRICS:
                prec, aos = _curves(batch, view, ignored_gt, ignored_dt, metric, table[metric][cls])
                ap[metric][cls][difficulty] = {"R11": ap_r11(prec), "R40": ap_r40(prec)}
                if metric == "bbox":
                    ap["aos"][cls][difficulty] = {"R11": ap_r11(aos), "R40": ap_r40(aos)}
    used = {m: {c: float(table[m][c]) for c in classes} for m in GEOMETRIC_METRICS}
    return KittiEvalResult(ap=ap, overlaps=used, num_frames=len(frame_list), num_objects=counted)


__all__ = [
    "CLASSES",
    "DIFFICULTIES",
    "LOOSE_OVERLAPS",
    "METRICS",
    "MIN_RELIABLE_OBJECTS",
    "OFFICIAL_OVERLAPS",
    "KittiEvalResult",
    "KittiFrame",
    "ap_ceiling",
    "ap_r11",
    "ap_r40",
    "detection_too_low",
    "evaluate_kitti",
    "get_thresholds",
    "image_box_overlap",
]
