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
  are ignored; unmatched detections overlapping a DontCare 2D box by more than the class
  threshold (intersection over the detection's own area) are not FPs (bbox metric only,
  as in the Python ports);
* matches need overlap strictly ``>`` the threshold; 41 score thresholds sampled from the
  TP scores; precision made monotone; R11 averages samples 0, 4, …, 40, R40 samples 1…40;
  AOS accumulates ``(1 + cos Δα) / 2`` over TPs of the bbox metric.

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
MAX_OCCLUSION = (0, 1, 2)
MAX_TRUNCATION = (0.15, 0.3, 0.5)
NUM_SAMPLE_POINTS = 41
_NO_DETECTION = -10000000.0


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

    def get(self, metric: str, cls: str, difficulty: str, points: str = "R40") -> float:
        return self.ap[metric][cls][difficulty][points]

    def to_dict(self) -> dict[str, Any]:
        return {"ap": self.ap, "overlaps": self.overlaps, "num_frames": self.num_frames}

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


def _fill_projection(boxes: Boxes3D, calib: KittiCalibration) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    bbox = np.array(boxes.bbox2d, dtype=np.float64)
    alpha = np.array(boxes.alpha, dtype=np.float64)
    geo = boxes.has_geometry
    need_box = geo & ~np.all(np.isfinite(bbox), axis=1)
    if need_box.any():
        bbox[need_box] = calib.boxes_to_image(boxes.as_array()[need_box])
    need_alpha = geo & ~np.isfinite(alpha)
    if need_alpha.any():
        alpha[need_alpha] = calib.alpha(boxes.as_array()[need_alpha])
    return bbox, alpha


def _camera(
    boxes: Boxes3D, calib: KittiCalibration
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    if len(boxes) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    return calib.boxes_to_camera(boxes.as_array())


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


def _prepare(frames: Sequence[KittiFrame]) -> list[_Frame]:
    prepared: list[_Frame] = []
    # All dt×gt pairs of all frames go to shapely in one call.
    polys_dt: list[NDArray[np.float64]] = []
    polys_gt: list[NDArray[np.float64]] = []
    pair_frames: list[tuple[int, int, int]] = []
    heights: list[NDArray[np.float64]] = []
    dims: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
    for frame in frames:
        gt, dt, calib = frame.gt, frame.detections, frame.calib
        gt_bbox, gt_alpha = _fill_projection(gt, calib)
        dt_bbox, dt_alpha = _fill_projection(dt, calib)
        g_loc, g_dim, g_ry = _camera(gt, calib)
        d_loc, d_dim, d_ry = _camera(dt, calib)
        g_corn = (
            KittiCalibration.camera_box_corners(g_loc, g_dim, g_ry)[:, :4][..., [0, 2]]
            if len(gt)
            else np.zeros((0, 4, 2))
        )
        d_corn = (
            KittiCalibration.camera_box_corners(d_loc, d_dim, d_ry)[:, :4][..., [0, 2]]
            if len(dt)
            else np.zeros((0, 4, 2))
        )
        n_dt, n_gt = len(dt), len(gt)
        di, gi = np.meshgrid(np.arange(n_dt), np.arange(n_gt), indexing="ij")
        polys_dt.append(d_corn[di.ravel()])
        polys_gt.append(g_corn[gi.ravel()])
        pair_frames.append((len(prepared), n_dt, n_gt))
        # height overlap along camera y (down): a box spans [y - h, y]
        top = np.minimum(d_loc[:, None, 1], g_loc[None, :, 1])
        bottom = np.maximum(d_loc[:, None, 1] - d_dim[:, None, 0], g_loc[None, :, 1] - g_dim[None, :, 0])
        heights.append(top - bottom)
        prepared.append(
            _Frame(
                gt_labels=np.char.lower(gt.labels.astype(str)),
                dt_labels=np.char.lower(dt.labels.astype(str)),
                gt_bbox=gt_bbox,
                dt_bbox=dt_bbox,
                gt_alpha=gt_alpha,
                dt_alpha=dt_alpha,
                gt_trunc=np.asarray(gt.truncation, dtype=np.float64),
                gt_occ=np.asarray(gt.occlusion, dtype=np.int64),
                dt_scores=np.asarray(dt.scores, dtype=np.float64),
                iou={"bbox": image_box_overlap(dt_bbox, gt_bbox)},
            )
        )
        dims.append((d_dim, g_dim))
    all_dt = np.concatenate(polys_dt) if polys_dt else np.zeros((0, 4, 2))
    all_gt = np.concatenate(polys_gt) if polys_gt else np.zeros((0, 4, 2))
    inter_all = np.zeros(all_dt.shape[0])
    finite = np.all(np.isfinite(all_dt), axis=(1, 2)) & np.all(np.isfinite(all_gt), axis=(1, 2))
    if finite.any():
        a = shapely.polygons(all_dt[finite])
        b = shapely.polygons(all_gt[finite])
        inter_all[finite] = shapely.area(shapely.intersection(a, b))
    offset = 0
    for (idx, n_dt, n_gt), dy, (d_dim, g_dim) in zip(pair_frames, heights, dims, strict=True):
        fr = prepared[idx]
        inter = inter_all[offset : offset + n_dt * n_gt].reshape(n_dt, n_gt)
        offset += n_dt * n_gt
        area_d, area_g = d_dim[:, 2] * d_dim[:, 1], g_dim[:, 2] * g_dim[:, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            bev = inter / (area_d[:, None] + area_g[None, :] - inter)
            inter3 = inter * np.clip(dy, 0.0, None)
            vol_d, vol_g = area_d * d_dim[:, 0], area_g * g_dim[:, 0]
            iou3 = inter3 / (vol_d[:, None] + vol_g[None, :] - inter3)
        fr.iou["bev"] = np.nan_to_num(np.where(inter > 0, bev, 0.0), nan=0.0)
        fr.iou["3d"] = np.nan_to_num(np.where(inter3 > 0, iou3, 0.0), nan=0.0)
    return prepared


# -- the devkit's matching ---------------------------------------------------------------
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
    dt_h = fr.dt_bbox[:, 3] - fr.dt_bbox[:, 1]
    ignored_dt = np.where(fr.dt_labels == name, 0, -1).astype(np.int64)
    with np.errstate(invalid="ignore"):
        ignored_dt[dt_h < MIN_HEIGHT[difficulty]] = 1
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
    pr = np.zeros((len(thresholds), 4))
    for fr, c in zip(frames, cleans, strict=True):
        if not np.any(c.ignored_dt != -1):
            # no detection of the class (an ignored one could still absorb a GT): only misses
            pr[:, 2] += c.num_valid_gt
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
        pr += stats[inverse.reshape(-1)]
    n = len(thresholds)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision[:n] = pr[:, 0] / (pr[:, 0] + pr[:, 1])
        aos[:n] = pr[:, 3] / (pr[:, 0] + pr[:, 1])
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    aos = np.maximum.accumulate(aos[::-1])[::-1]
    return precision, aos if with_aos else np.zeros(NUM_SAMPLE_POINTS)


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
    prepared = _prepare(frame_list)
    ap: dict[str, dict[str, dict[str, dict[str, float]]]] = {m: {} for m in METRICS}
    for cls in classes:
        for m in METRICS:
            ap[m][cls] = {}
        for d, difficulty in enumerate(DIFFICULTIES):
            cleans = [_clean(fr, cls, d) for fr in prepared]
            for metric in GEOMETRIC_METRICS:
                prec, aos = _precision_curves(prepared, cleans, metric, table[metric][cls], metric == "bbox")
                ap[metric][cls][difficulty] = {"R11": ap_r11(prec), "R40": ap_r40(prec)}
                if metric == "bbox":
                    ap["aos"][cls][difficulty] = {"R11": ap_r11(aos), "R40": ap_r40(aos)}
    used = {m: {c: float(table[m][c]) for c in classes} for m in GEOMETRIC_METRICS}
    return KittiEvalResult(ap=ap, overlaps=used, num_frames=len(frame_list))


__all__ = [
    "CLASSES",
    "DIFFICULTIES",
    "LOOSE_OVERLAPS",
    "METRICS",
    "OFFICIAL_OVERLAPS",
    "KittiEvalResult",
    "KittiFrame",
    "ap_r11",
    "ap_r40",
    "evaluate_kitti",
    "get_thresholds",
    "image_box_overlap",
]
