"""``evaluate_kitti`` on abnormal inputs, against the official devkit's rules (issue 23).

The devkit's code these cases rest on (``cpp/evaluate_object.cpp``; ``evaluate_object_3d_offline.cpp``
is the same here), as read for this test:

* ``cleanData``, ground truth: ``double height = gt.box.y2 - gt.box.y1`` (signed) and the box is
  ignored when ``height <= MIN_HEIGHT[difficulty]`` (40, 25, 25 px): a ground-truth box given upside
  down (y1 > y2) has a negative height and is always ignored (it absorbs a match, never a FN).
* ``cleanData``, detections: ``int32_t height = fabs(det.box.y1 - det.box.y2)`` and the detection is
  ignored when ``height < MIN_HEIGHT``: an upside-down detection is as tall as the right way up.
* ``imageBoxOverlap``: ``w = min(x2) - max(x1)``, ``h = min(y2) - max(y1)``, 0 when ``w <= 0 || h <= 0``:
  an upside-down box (y1 > y2) has ``h <= y2 - y1 < 0`` with anything, so it overlaps nothing in 2D.
* ``computeStatistics``: ``valid_detection`` starts at ``NO_DETECTION = -10000000`` and, when the TP
  scores are collected (``compute_fp`` false), a candidate must have ``det.thresh > valid_detection``:
  a detection scored ``<= -1e7`` is never taken, gives no threshold, and every threshold (a TP score)
  is above it, so ``det.thresh < thresh`` drops it from the precision counts as well.
* Class names are compared with ``strcasecmp`` everywhere (``car`` is a Car, ``dontcare`` DontCare).

Sampling used for the expected numbers (``getThresholds``, ``eval_class``): the thresholds are the TP
scores picked for evenly spaced recall; sample ``i`` of the 41-point curve is the precision at the
``i``-th threshold (0 past the last); R11 = (samples 0, 4, …, 40) / 11 × 100; R40 = (samples 1…40) / 40
× 100. So one threshold at precision p gives R11 = 100 p / 11 and R40 = 0; two thresholds at precision
1 give R11 = 100 / 11 = 9.0909… and R40 = 100 / 40 = 2.5.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.oracles import kitti_eval as k
from lidarfuzz.oracles.kitti_eval import KittiFrame, detection_too_low, evaluate_kitti, image_box_overlap
from lidarfuzz.oracles.kitti_files import canonical_class_names, load_kitti_eval_frames
from lidarfuzz.scene.boxes import Boxes3D
from tests.oracles.test_kitti_files import car_line

CAR = (3.9, 1.6, 1.5)
UPRIGHT = (100.0, 100.0, 200.0, 160.0)  # 60 px tall
UPSIDE_DOWN = (100.0, 160.0, 200.0, 100.0)  # the same box with y1 > y2
ONE_THRESHOLD = 100 / 11  # one threshold at precision 1: R11 only
HALF_ONE_THRESHOLD = 50 / 11  # one threshold at precision 0.5


def cars(xs: list[float], bbox: list[tuple[float, float, float, float]], scores: list[float] | None = None,
         labels: list[str] | None = None) -> Boxes3D:
    """Fully visible cars at LiDAR (x, 0, -0.9), heading 0, alpha 0, with the given 2D boxes."""
    n = len(xs)
    return Boxes3D.create([[x, 0.0, -0.9] for x in xs], [CAR] * n, [0.0] * n, labels or ["Car"] * n,
                          scores=scores, occlusion=[0] * n, truncation=[0.0] * n, alpha=[0.0] * n, bbox2d=bbox)


def car_ap(frames: list[KittiFrame]) -> dict[str, dict[str, dict[str, float]]]:
    """AP per metric and difficulty for the Car class."""
    result = evaluate_kitti(frames, classes=("Car",))
    return {m: {d: result.ap[m]["Car"][d] for d in k.DIFFICULTIES} for m in k.METRICS}


def expect(ap: dict[str, dict[str, float]], metric: str, difficulties: tuple[str, ...], r11: float, r40: float) -> None:
    for difficulty in difficulties:
        got = ap[metric][difficulty]
        assert got["R11"] == pytest.approx(r11, abs=1e-9), (metric, difficulty)
        assert got["R40"] == pytest.approx(r40, abs=1e-9), (metric, difficulty)


ALL = ("easy", "moderate", "hard")


# -- 2D boxes given upside down -------------------------------------------------------------------
def test_inverted_boxes_overlap_nothing_in_2d() -> None:
    # min(y2) - max(y1) = min(100, 160) - max(160, 100) = -60 <= 0: overlap 0, whatever the other box
    a = np.array([UPSIDE_DOWN])
    b = np.array([UPRIGHT, UPSIDE_DOWN, (0.0, 0.0, 1000.0, 1000.0)])
    assert image_box_overlap(a, b).tolist() == [[0.0, 0.0, 0.0]]
    assert image_box_overlap(a, b, criterion=0).tolist() == [[0.0, 0.0, 0.0]]
    assert image_box_overlap(b[:1], b[:1]).tolist() == [[1.0]]


def test_a_detection_height_is_absolute_and_truncated_like_an_int32() -> None:
    boxes = np.array([UPRIGHT, UPSIDE_DOWN, (0, 130, 10, 100), (0, 0, 10, 39.99), (0, 0, 10, 3e9)])
    # heights 60, |-60|, |-30|, 39.99 (int 39), 3e9 (beyond int32: INT_MIN on x86-64)
    assert detection_too_low(boxes, 40.0).tolist() == [False, False, True, True, True]
    assert detection_too_low(boxes, 25.0).tolist() == [False, False, False, False, True]


def test_an_upside_down_detection_counts_in_bev_and_3d_not_in_2d() -> None:
    # Two frames, one car each, found by a detection with the same 3D box (BEV and 3D overlap 1) but its
    # 2D box upside down. Its height |100 - 160| = 60 >= 40: a counted detection at every difficulty.
    # bbox: overlap 0 -> no TP anywhere -> no threshold -> AP 0 (and AOS 0).
    # BEV/3D: TP scores 0.9, 0.8 for 2 GT -> thresholds 0.9, 0.8 (getThresholds keeps both: at i = 0
    # r_recall - 0 = 1 is not < 0 - l_recall = -0.5); precision 1 at each -> R11 9.0909, R40 2.5.
    frames = [KittiFrame(cars([10.0], [UPRIGHT]), cars([10.0], [UPSIDE_DOWN], scores=[0.9])),
              KittiFrame(cars([20.0], [UPRIGHT]), cars([20.0], [UPSIDE_DOWN], scores=[0.8]))]
    ap = car_ap(frames)
    expect(ap, "bbox", ALL, 0.0, 0.0)
    expect(ap, "aos", ALL, 0.0, 0.0)
    for metric in ("bev", "3d"):
        expect(ap, metric, ALL, 100 / 11, 2.5)


def test_an_upside_down_detection_is_low_by_its_absolute_height() -> None:
    # The same with a 2D box 30 px tall upside down (y1 130, y2 100): |h| = 30 < 40 -> ignored for easy
    # (it absorbs the GT in the first pass, so no TP score and AP 0); 30 >= 25 -> counted for moderate
    # and hard, where BEV/3D score as above.
    low = (100.0, 130.0, 200.0, 100.0)
    frames = [KittiFrame(cars([10.0], [UPRIGHT]), cars([10.0], [low], scores=[0.9])),
              KittiFrame(cars([20.0], [UPRIGHT]), cars([20.0], [low], scores=[0.8]))]
    ap = car_ap(frames)
    for metric in ("bev", "3d"):
        expect(ap, metric, ("easy",), 0.0, 0.0)
        expect(ap, metric, ("moderate", "hard"), 100 / 11, 2.5)


def test_an_upside_down_ground_truth_box_is_ignored() -> None:
    # Frame 0: a car found exactly (score 0.9). Frame 1: a car whose GT 2D box is upside down (signed
    # height 100 - 160 = -60 <= 40: ignored at every difficulty), detected with the right 2D box at 0.95.
    # n_gt = 1, TP scores [0.9] -> one threshold, 0.9.
    # BEV/3D: frame 1's detection matches the ignored GT (overlap 1): assigned, neither TP nor FP ->
    #   precision 1 -> R11 9.0909, R40 0.
    # bbox: it overlaps the upside-down GT box by 0 -> a FP at 0.9 -> precision 1 / 2 -> R11 4.5454;
    #   AOS: similarity 1 (frame 0's TP, alpha equal) / (TP 1 + FP 1) = 0.5 -> R11 4.5454.
    frames = [KittiFrame(cars([10.0], [UPRIGHT]), cars([10.0], [UPRIGHT], scores=[0.9])),
              KittiFrame(cars([20.0], [UPSIDE_DOWN]), cars([20.0], [UPRIGHT], scores=[0.95]))]
    ap = car_ap(frames)
    expect(ap, "bbox", ALL, HALF_ONE_THRESHOLD, 0.0)
    expect(ap, "aos", ALL, HALF_ONE_THRESHOLD, 0.0)
    for metric in ("bev", "3d"):
        expect(ap, metric, ALL, ONE_THRESHOLD, 0.0)


# -- scores at the devkit's no-detection marker ------------------------------------------------------
@pytest.mark.parametrize("marker_score", [-1e7, -2e7, -1e300])
def test_a_detection_at_or_below_the_no_detection_marker_is_never_taken(marker_score: float) -> None:
    # Frame 0: a car detected exactly but scored at/below NO_DETECTION; frame 1: one detected at 0.5.
    # First pass: frame 0's detection is no candidate (score > -1e7 fails) -> TP scores [0.5], n_gt 2 ->
    # one threshold, 0.5. At 0.5 frame 0's detection is below the threshold: TP 1, FP 0 (FN 1) ->
    # precision 1 on every metric -> R11 9.0909, R40 0; AOS the same (alpha equal: similarity 1).
    frames = [KittiFrame(cars([10.0], [UPRIGHT]), cars([10.0], [UPRIGHT], scores=[marker_score])),
              KittiFrame(cars([20.0], [UPRIGHT]), cars([20.0], [UPRIGHT], scores=[0.5]))]
    ap = car_ap(frames)
    for metric in k.METRICS:
        expect(ap, metric, ALL, ONE_THRESHOLD, 0.0)


def test_a_detection_just_above_the_marker_is_an_ordinary_detection() -> None:
    # Score -9999999 > -1e7: a TP in the first pass -> TP scores [0.5, -9999999], n_gt 2 -> thresholds
    # 0.5 and -9999999 (as in the first test above); precision 1 at both -> R11 9.0909, R40 2.5.
    frames = [KittiFrame(cars([10.0], [UPRIGHT]), cars([10.0], [UPRIGHT], scores=[-9999999.0])),
              KittiFrame(cars([20.0], [UPRIGHT]), cars([20.0], [UPRIGHT], scores=[0.5]))]
    ap = car_ap(frames)
    for metric in k.METRICS:
        expect(ap, metric, ALL, 100 / 11, 2.5)


# -- class names in any case ----------------------------------------------------------------------------
def test_class_names_are_matched_in_any_case_in_the_files(tmp_path: Path) -> None:
    # GT: a car at camera (0, 10) (projected 2D box, ~110 px tall) and a DontCare region at x 1000-1200,
    # y 150-250. Detections: the car exactly at 0.9, and a false car at 0.95 far away in 3D whose 2D box
    # (1010-1190, 160-240, 80 px tall) lies inside the region. n_gt 1 -> one threshold, 0.9.
    # bbox: the false car is inside the region (intersection / its own area = 1 > 0.7): not a FP ->
    #   precision 1 -> R11 9.0909; AOS 9.0909 (alpha equal).
    # BEV/3D: DontCare does not apply -> FP -> precision 0.5 -> R11 4.5454.
    # Written in lower/upper case, it must read the same as in KITTI's spelling.
    gt_lines = [car_line(0.0, 10.0), "DontCare -1 -1 -10 1000.00 150.00 1200.00 250.00 -1 -1 -1 -1000 -1000 -1000 -10"]
    dt_lines = [car_line(0.0, 10.0, score=0.9),
                "Car 0.00 0 0.0 1010.00 160.00 1190.00 240.00 1.5 1.6 3.9 8.0 1.65 40.0 0.0 0.95"]
    results = []
    for name, change in (("canonical", str), ("lower", str.lower), ("upper", str.upper)):
        labels, dets = tmp_path / name / "label_2", tmp_path / name / "dets"
        labels.mkdir(parents=True)
        dets.mkdir()
        (labels / "000000.txt").write_text("\n".join(_recase(line, change) for line in gt_lines) + "\n")
        (dets / "000000.txt").write_text("\n".join(_recase(line, change) for line in dt_lines) + "\n")
        loaded = load_kitti_eval_frames(labels, dets)
        assert loaded.frames[0].gt.labels.tolist() == ["Car", "DontCare"]
        results.append(evaluate_kitti(loaded.frames, classes=("Car",)))
    ap = {m: {d: results[0].ap[m]["Car"][d] for d in ALL} for m in k.METRICS}
    expect(ap, "bbox", ALL, ONE_THRESHOLD, 0.0)
    expect(ap, "aos", ALL, ONE_THRESHOLD, 0.0)
    expect(ap, "bev", ALL, HALF_ONE_THRESHOLD, 0.0)
    assert results[1].to_json() == results[0].to_json() == results[2].to_json()


def _recase(line: str, change: Callable[[str], str]) -> str:
    name, rest = line.split(" ", 1)
    return f"{change(name)} {rest}"


def test_canonical_names_keep_lines_and_leave_unknown_names_alone() -> None:
    text = "car 0 0\n\n  PERSON_SITTING 1\r\nbus 2\nDontCare x"
    assert canonical_class_names(text) == "Car 0 0\n\n  Person_sitting 1\nbus 2\nDontCare x"


# -- order independence ------------------------------------------------------------------------------------
def abnormal_frames(seed: int, num_frames: int = 60) -> list[KittiFrame]:
    """Cars, pedestrians and vans with a share of upside-down 2D boxes, marker scores and
    lower-case names; distinct scores so that no tie makes the detection order matter."""
    rng = np.random.default_rng(seed)
    sizes = {"Car": CAR, "car": CAR, "Van": (4.8, 1.9, 2.1), "Pedestrian": (0.8, 0.6, 1.75)}
    names = list(sizes)
    scores = iter(rng.permutation(np.linspace(0.01, 0.99, 4000)))
    frames = []
    for _ in range(num_frames):
        m = int(rng.integers(1, 8))
        labels = list(rng.choice(names, m))
        centres = np.c_[rng.uniform(4, 60, m), rng.uniform(-10, 10, m), np.full(m, -0.9)]
        dims = np.array([sizes[n] for n in labels])
        yaw = rng.uniform(-np.pi, np.pi, m)
        top = rng.uniform(100, 250, m)
        left = rng.uniform(0, 1000, m)
        bbox = np.c_[left, top, left + rng.uniform(20, 200, m), top + rng.uniform(10, 120, m)]
        gt = Boxes3D.create(centres, dims, yaw, labels, occlusion=rng.integers(0, 3, m),
                            truncation=rng.uniform(0, 0.4, m), alpha=rng.uniform(-np.pi, np.pi, m), bbox2d=bbox)
        jitter = np.c_[rng.normal(0, 0.3, (m, 2)), np.zeros(m)]
        dt_bbox = bbox + rng.normal(0, 4, (m, 4))
        flip = rng.random(m) < 0.25
        dt_bbox[flip] = dt_bbox[flip][:, [0, 3, 2, 1]]  # upside down
        dt_scores = np.array([next(scores) for _ in range(m)])
        dt_scores[rng.random(m) < 0.1] = -1e7 - rng.uniform(0, 1e7)
        dt = Boxes3D.create(centres + jitter, dims, yaw + rng.normal(0, 0.2, m), labels, scores=dt_scores,
                            alpha=rng.uniform(-np.pi, np.pi, m), bbox2d=dt_bbox)
        frames.append(KittiFrame(gt, dt))
    return frames


@pytest.mark.parametrize("seed", range(3))
def test_permuting_frames_and_detections_gives_the_same_bits(seed: int) -> None:
    # Frames are independent in the devkit and, with distinct scores, a frame's detections are only
    # compared by score and overlap, so any order of either must give the very same AP and AOS floats.
    frames = abnormal_frames(seed)
    rng = np.random.default_rng(100 + seed)
    shuffled = [KittiFrame(f.gt, f.detections.select(rng.permutation(len(f.detections))), f.calib)
                for f in (frames[i] for i in rng.permutation(len(frames)))]
    first, second = evaluate_kitti(frames), evaluate_kitti(shuffled)
    assert json.loads(first.to_json())["ap"] == json.loads(second.to_json())["ap"]
    assert first.to_json() == second.to_json()
    assert 0 < first.get("aos", "Car", "moderate", "R11") < 100  # the AOS sums are exercised


def test_the_batched_evaluation_equals_the_per_frame_devkit_loop_on_abnormal_frames() -> None:
    # The per-frame loop (_statistics) is a line-by-line port of computeStatistics; both must agree
    # on upside-down boxes and marker scores too.
    frames = abnormal_frames(7, num_frames=25)
    batch, prepared = k._batch(frames), k._prepare(frames)
    for cls in ("Car", "Pedestrian"):
        view = k._class_view(batch, cls)
        for difficulty in range(3):
            ignored_gt, ignored_dt = k._ignored(batch, view, cls, difficulty)
            cleans = [k._clean(fr, cls, difficulty) for fr in prepared]
            for metric in k.GEOMETRIC_METRICS:
                overlap = k.OFFICIAL_OVERLAPS[metric][cls]
                ref_prec, ref_aos = k._precision_curves(prepared, cleans, metric, overlap, metric == "bbox")
                prec, aos = k._curves(batch, view, ignored_gt, ignored_dt, metric, overlap)
                np.testing.assert_allclose(prec, ref_prec, rtol=0, atol=1e-12)
                if metric == "bbox":
                    np.testing.assert_allclose(aos, ref_aos, rtol=0, atol=1e-12)


def test_the_reliability_harness_at_ci_size() -> None:
    # benchmarks/eval_abnormal.py, one 3-frame case per kind of abnormality: every AP value equals its
    # transcription of the devkit (to 1e-9 points) and shuffling frames and detections changes no bit.
    from benchmarks.eval_abnormal import KINDS, run_cases

    results = run_cases(1, 3, seed=1)
    assert set(results) == set(KINDS)
    for kind, result in results.items():
        assert result.cases == 1 and result.values == 72, kind
        assert result.agreeing_cases == 1 and result.permuted_identical == 1, (kind, result.max_difference)
