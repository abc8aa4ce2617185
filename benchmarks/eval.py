"""KITTI evaluation time on a synthetic KITTI-val-sized workload (3,769 frames, 3 classes).

Usage: ``.venv/bin/python benchmarks/eval.py [--frames 3769] [--repeats 3] [--baseline-frames 200]``

The workload is seeded (``numpy.random.default_rng``): per frame 4–8 Car, 0–3 Pedestrian,
0–2 Cyclist, sometimes a Van, 0–3 DontCare regions, placed 4–70 m ahead within the camera's
field of view with projected 2D boxes, truncation from the clipping and occlusion levels
that grow with range. Detections are the ground truth jittered (centre σ 0.04–0.2 m per axis,
growing with range; size σ 2 %; yaw σ 0.03 rad, 3 % reversed), scored lower far away and under
occlusion, about 20 % missed (more at range and under occlusion), plus about 30 % false positives
at random places with lower scores; 2D boxes and alphas by projection. Detections are given
2D boxes and alphas up front so that both sides time the evaluation alone.

Timed: :func:`evaluate_kitti` on every frame, all three classes (median of ``--repeats``).
Baseline, measured in the same run on the first ``--baseline-frames`` frames and scaled per
frame: a straightforward port of the devkit's Python evaluation — per frame, a shapely
polygon intersection per (detection, GT) pair for BEV and 3D IoU, then, for every class,
difficulty, metric and each of the 41 score thresholds, the devkit's matching loop
(:func:`_statistics`) on every frame, without sharing work between thresholds. The script
asserts that the baseline gives the same AP as :func:`evaluate_kitti` on its frames.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray
from shapely.geometry import Polygon

from lidarfuzz.oracles.kitti_eval import (
    DIFFICULTIES,
    GEOMETRIC_METRICS,
    METRICS,
    NUM_SAMPLE_POINTS,
    OFFICIAL_OVERLAPS,
    KittiEvalResult,
    KittiFrame,
    _clean,
    _prepare,
    _statistics,
    ap_r11,
    ap_r40,
    evaluate_kitti,
    get_thresholds,
)
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration

CLASSES = ("Car", "Pedestrian", "Cyclist")
SIZES = {"Car": (3.9, 1.6, 1.5), "Van": (5.0, 1.9, 2.2), "Pedestrian": (0.8, 0.6, 1.75), "Cyclist": (1.8, 0.6, 1.7)}
KITTI_VAL_FRAMES = 3769


# -- the workload --------------------------------------------------------------------------
def _objects(rng: np.random.Generator, labels: NDArray[np.str_]) -> NDArray[np.float64]:
    """N×7 LiDAR boxes of the given classes on the ground, 4–70 m ahead, inside the camera's view."""
    n = len(labels)
    distance = rng.uniform(4.0, 70.0, n)
    azimuth = rng.uniform(-0.65, 0.65, n)
    mean = np.array([SIZES[str(c)] for c in labels]).reshape(n, 3)
    size = mean * rng.normal(1.0, 0.07, (n, 3))
    ground = -1.73 + rng.normal(0.0, 0.1, n)
    return np.column_stack(
        [
            distance * np.cos(azimuth),
            distance * np.sin(azimuth),
            ground + size[:, 2] / 2,
            size,
            rng.uniform(-np.pi, np.pi, n),
        ]
    )


def _labels(
    rng: np.random.Generator, counts: dict[str, NDArray[np.int64]]
) -> tuple[NDArray[np.str_], NDArray[np.int64]]:
    """Labels of every object, frame by frame, and each object's frame."""
    per_frame = np.stack([counts[c] for c in counts], axis=1)
    frame = np.repeat(np.arange(len(per_frame)), per_frame.sum(axis=1))
    names = np.array(list(counts))
    labels = np.concatenate([np.repeat(names, row) for row in per_frame]) if len(per_frame) else names[:0]
    return labels, frame


def make_workload(num_frames: int, seed: int = 0) -> list[KittiFrame]:
    """Synthetic KITTI val: ground truth with DontCare, jittered detections with misses and false positives."""
    rng = np.random.default_rng(seed)
    calib = KittiCalibration.default()
    height, width = calib.image_shape
    counts = {
        "Car": rng.integers(4, 9, num_frames),
        "Van": (rng.random(num_frames) < 0.3).astype(np.int64),
        "Pedestrian": rng.integers(0, 4, num_frames),
        "Cyclist": rng.integers(0, 3, num_frames),
    }
    gt_labels, gt_frame = _labels(rng, counts)
    gt = _objects(rng, gt_labels)
    n = len(gt)
    gt_box2d = calib.boxes_to_image(gt)
    unclipped = calib.boxes_to_image(gt, clip=False)

    def area(b: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.clip(b[:, 2] - b[:, 0], 0, None) * np.clip(b[:, 3] - b[:, 1], 0, None)

    truncation = np.clip(1.0 - area(gt_box2d) / np.maximum(area(unclipped), 1e-9), 0.0, 1.0).round(2)
    distance = np.hypot(gt[:, 0], gt[:, 1])
    occlusion = np.minimum(rng.binomial(2, np.clip(distance / 90.0 + 0.1, 0, 1)), 3).astype(np.int64)
    gt_alpha = calib.alpha(gt)

    # detections: found objects jittered, plus false positives
    miss = rng.random(n) < 0.04 + 0.2 * distance / 70.0 + 0.08 * occlusion
    found = np.flatnonzero(~miss)
    det = gt[found].copy()
    # errors grow with range: σ 0.04 m per axis near, 0.2 m at 70 m (ground-plane error 0.16 m on average)
    sigma = 0.04 + 0.16 * distance[found] / 70.0
    det[:, :2] += rng.normal(0.0, 1.0, (len(found), 2)) * sigma[:, None]
    det[:, 2] += rng.normal(0.0, 0.5, len(found)) * sigma
    det[:, 3:6] *= rng.normal(1.0, 0.02, (len(found), 3))
    det[:, 6] += rng.normal(0.0, 0.03, len(found)) + np.pi * (rng.random(len(found)) < 0.03)
    # confident near, less so far away and under occlusion
    quality = 1.0 - 0.4 * distance[found] / 70.0 - 0.1 * occlusion[found]
    det_scores = np.clip(quality * (0.6 + 0.4 * rng.beta(4.0, 1.5, len(found))), 0.01, 1.0)
    det_labels = gt_labels[found].copy()
    det_labels[det_labels == "Van"] = "Car"  # a detector that knows no vans calls them cars
    det_frame = gt_frame[found]
    num_fp = rng.poisson(0.3 * len(found) / max(num_frames, 1), num_frames)
    fp_labels = rng.choice(np.array(CLASSES), int(num_fp.sum()), p=[0.6, 0.25, 0.15])
    fp = _objects(rng, fp_labels)
    fp_scores = 0.05 + 0.7 * rng.beta(2.0, 5.0, len(fp))
    fp_frame = np.repeat(np.arange(num_frames), num_fp)
    dt = np.concatenate([det, fp])
    dt_labels = np.concatenate([det_labels, fp_labels])
    dt_scores = np.concatenate([det_scores, fp_scores])
    dt_frame = np.concatenate([det_frame, fp_frame])
    dt_box2d = calib.boxes_to_image(dt)
    dt_alpha = calib.alpha(dt)

    # DontCare regions: small far-away image boxes
    dc_count = rng.integers(0, 4, num_frames)
    dc_frame = np.repeat(np.arange(num_frames), dc_count)
    m = len(dc_frame)
    left = rng.uniform(0, width - 90, m)
    top = rng.uniform(height * 0.35, height * 0.6, m)
    dc_box2d = np.column_stack([left, top, left + rng.uniform(15, 80, m), top + rng.uniform(10, 40, m)])

    frames: list[KittiFrame] = []
    g_bounds = np.searchsorted(gt_frame, np.arange(num_frames + 1))
    c_bounds = np.searchsorted(dc_frame, np.arange(num_frames + 1))
    order = np.argsort(dt_frame, kind="stable")
    dt, dt_labels, dt_scores, dt_box2d, dt_alpha = (a[order] for a in (dt, dt_labels, dt_scores, dt_box2d, dt_alpha))
    d_bounds = np.searchsorted(dt_frame[order], np.arange(num_frames + 1))
    for f in range(num_frames):
        g = slice(g_bounds[f], g_bounds[f + 1])
        c = slice(c_bounds[f], c_bounds[f + 1])
        d = slice(d_bounds[f], d_bounds[f + 1])
        k = c.stop - c.start
        nan = np.full((k, 3), np.nan)
        ground_truth = Boxes3D.create(
            np.concatenate([gt[g, :3], nan]),
            np.concatenate([gt[g, 3:6], nan]),
            np.concatenate([gt[g, 6], np.full(k, np.nan)]),
            [*gt_labels[g], *["DontCare"] * k],
            truncation=np.concatenate([truncation[g], np.full(k, np.nan)]),
            occlusion=np.concatenate([occlusion[g], np.full(k, -1)]),
            alpha=np.concatenate([gt_alpha[g], np.full(k, np.nan)]),
            bbox2d=np.concatenate([gt_box2d[g], dc_box2d[c]]),
        )
        detections = Boxes3D.create(
            dt[d, :3],
            dt[d, 3:6],
            dt[d, 6],
            dt_labels[d],
            scores=dt_scores[d],
            alpha=dt_alpha[d],
            bbox2d=dt_box2d[d],
        )
        frames.append(KittiFrame(gt=ground_truth, detections=detections, calib=calib))
    return frames


# -- the baseline: a straightforward port of the devkit's Python evaluation -----------------------
def _camera_footprints(boxes: Boxes3D, calib: KittiCalibration) -> tuple[list[Polygon | None], NDArray[np.float64]]:
    """Per box: the BEV footprint polygon on the camera x–z plane (None without geometry), and
    its vertical extent ``[y_top, y_bottom]`` along camera y, as the devkit builds them."""
    loc, hwl, ry = calib.boxes_to_camera(boxes.as_array())
    polygons: list[Polygon | None] = []
    for i in range(len(boxes)):
        if not np.all(np.isfinite(loc[i])) or not np.all(np.isfinite(hwl[i])):
            polygons.append(None)
            continue
        half_l, half_w = hwl[i, 2] / 2.0, hwl[i, 1] / 2.0
        c, s = np.cos(ry[i]), np.sin(ry[i])
        corners = [
            (loc[i, 0] + c * dx + s * dz, loc[i, 2] - s * dx + c * dz)
            for dx, dz in ((half_l, half_w), (half_l, -half_w), (-half_l, -half_w), (-half_l, half_w))
        ]
        polygons.append(Polygon(corners))
    vertical = np.stack([loc[:, 1] - hwl[:, 0], loc[:, 1]], axis=1)
    return polygons, vertical


def pairwise_iou_loop(frame: KittiFrame) -> dict[str, NDArray[np.float64]]:
    """BEV and 3D IoU (n_dt × n_gt), one shapely intersection per pair."""
    dt_poly, dt_vert = _camera_footprints(frame.detections, frame.calib)
    gt_poly, gt_vert = _camera_footprints(frame.gt, frame.calib)
    dt_arr, gt_arr = frame.detections.as_array(), frame.gt.as_array()
    bev = np.zeros((len(dt_poly), len(gt_poly)))
    iou3d = np.zeros_like(bev)
    for i, a in enumerate(dt_poly):
        for j, b in enumerate(gt_poly):
            if a is None or b is None:
                continue
            inter = a.intersection(b).area
            if inter <= 0:
                continue
            area_a, area_b = dt_arr[i, 3] * dt_arr[i, 4], gt_arr[j, 3] * gt_arr[j, 4]
            bev[i, j] = inter / (area_a + area_b - inter)
            height = min(dt_vert[i, 1], gt_vert[j, 1]) - max(dt_vert[i, 0], gt_vert[j, 0])
            if height > 0:
                inter3 = inter * height
                iou3d[i, j] = inter3 / (area_a * dt_arr[i, 5] + area_b * gt_arr[j, 5] - inter3)
    return {"bev": bev, "3d": iou3d}


def baseline_evaluate(
    frames: Sequence[KittiFrame], classes: Sequence[str] = CLASSES
) -> tuple[dict[str, dict[str, dict[str, dict[str, float]]]], dict[str, float]]:
    """AP as ``evaluate_kitti`` computes it, the devkit's way; also the seconds spent per stage."""
    times: dict[str, float] = {}
    start = time.perf_counter()
    prepared = _prepare(frames)  # labels, 2D boxes, alphas (projected where missing) and 2D IoU
    times["prepare (vectorised)"] = time.perf_counter() - start
    start = time.perf_counter()
    for fr, frame in zip(prepared, frames, strict=True):
        fr.iou.update(pairwise_iou_loop(frame))
    times["IoU, shapely per pair"] = time.perf_counter() - start
    start = time.perf_counter()
    ap: dict[str, dict[str, dict[str, dict[str, float]]]] = {m: {c: {} for c in classes} for m in METRICS}
    for cls in classes:
        for d, difficulty in enumerate(DIFFICULTIES):
            cleans = [_clean(fr, cls, d) for fr in prepared]
            num_valid = sum(c.num_valid_gt for c in cleans)
            for metric in GEOMETRIC_METRICS:
                min_overlap = OFFICIAL_OVERLAPS[metric][cls]
                tp_scores: list[float] = []
                for fr, c in zip(prepared, cleans, strict=True):
                    if c.num_valid_gt:
                        tp_scores += _statistics(fr, c, metric, min_overlap, 0.0, False)[4]
                precision = np.zeros(NUM_SAMPLE_POINTS)
                aos = np.zeros(NUM_SAMPLE_POINTS)
                if tp_scores:
                    thresholds = get_thresholds(np.asarray(tp_scores), num_valid)
                    pr = np.zeros((len(thresholds), 4))
                    for t, thresh in enumerate(thresholds):
                        for fr, c in zip(prepared, cleans, strict=True):
                            tp, fp, fn, similarity, _ = _statistics(fr, c, metric, min_overlap, thresh, True)
                            pr[t] += (tp, fp, fn, similarity if similarity != -1 else 0.0)
                    n = len(thresholds)
                    with np.errstate(invalid="ignore", divide="ignore"):
                        precision[:n] = pr[:, 0] / (pr[:, 0] + pr[:, 1])
                        aos[:n] = pr[:, 3] / (pr[:, 0] + pr[:, 1])
                    precision = np.maximum.accumulate(precision[::-1])[::-1]
                    aos = np.maximum.accumulate(aos[::-1])[::-1]
                ap[metric][cls][difficulty] = {"R11": ap_r11(precision), "R40": ap_r40(precision)}
                if metric == "bbox":
                    ap["aos"][cls][difficulty] = {"R11": ap_r11(aos), "R40": ap_r40(aos)}
    times["matching, per threshold and frame"] = time.perf_counter() - start
    return ap, times


def median_s(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def max_difference(
    a: dict[str, dict[str, dict[str, dict[str, float]]]], b: dict[str, dict[str, dict[str, dict[str, float]]]]
) -> float:
    return max(abs(a[m][c][d][p] - b[m][c][d][p]) for m in a for c in a[m] for d in a[m][c] for p in a[m][c][d])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=KITTI_VAL_FRAMES)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--baseline-frames", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    start = time.perf_counter()
    frames = make_workload(args.frames, args.seed)
    build = time.perf_counter() - start
    gt_objects = sum(int(np.count_nonzero(f.gt.labels != "DontCare")) for f in frames)
    dontcare = sum(int(np.count_nonzero(f.gt.labels == "DontCare")) for f in frames)
    detections = sum(len(f.detections) for f in frames)
    print(
        f"# KITTI evaluation, synthetic KITTI-val workload: {args.frames:,} frames, {gt_objects:,} GT objects "
        f"(+ {dontcare:,} DontCare), {detections:,} detections; classes {', '.join(CLASSES)}; "
        f"built in {build:.1f} s\n"
    )

    subset = frames[: args.baseline_frames]
    reference = evaluate_kitti(subset, classes=CLASSES)  # also warms imports and caches
    baseline_start = time.perf_counter()
    baseline_ap, stages = baseline_evaluate(subset)
    baseline = time.perf_counter() - baseline_start
    diff = max_difference(baseline_ap, reference.ap)
    print(f"baseline vs evaluate_kitti on the first {len(subset)} frames: max |ΔAP| = {diff:.2e} (percentage points)")
    assert diff <= 1e-4, f"the baseline disagrees with evaluate_kitti by {diff}"

    result: list[KittiEvalResult] = []
    elapsed = median_s(lambda: result.append(evaluate_kitti(frames, classes=CLASSES)), args.repeats)
    per_frame = baseline / len(subset)
    projected = per_frame * args.frames
    print(
        f"evaluate_kitti, all frames: Car 3D AP|R40 moderate = {result[-1].get('3d', 'Car', 'moderate'):.2f}, "
        f"mAP 3D R40 moderate = {result[-1].mean_ap('3d', 'moderate'):.2f}\n"
    )
    print("| what | frames | seconds | frames/s | × evaluate_kitti |")
    print("|---|---:|---:|---:|---:|")
    print(
        f"| evaluate_kitti (median of {args.repeats}) | {args.frames:,} | {elapsed:.3f} | "
        f"{args.frames / elapsed:,.0f} | 1.0 |"
    )
    print(f"| baseline, measured (1 run) | {len(subset):,} | {baseline:.3f} | {len(subset) / baseline:,.1f} | |")
    for stage, seconds in stages.items():
        print(f"| — of which {stage} | {len(subset):,} | {seconds:.3f} | | |")
    print(f"| baseline, per 200 frames (scaled) | 200 | {per_frame * 200:.3f} | | |")
    print(
        f"| baseline, projected to all frames | {args.frames:,} | {projected:.1f} | {1 / per_frame:,.1f} | "
        f"{projected / elapsed:.1f} |"
    )
    print(f"\nspeed-up of evaluate_kitti over the devkit-style baseline: {projected / elapsed:.1f}×")


if __name__ == "__main__":
    main()
