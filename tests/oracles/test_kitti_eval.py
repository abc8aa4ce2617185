"""KITTI evaluation: hand-worked cases of the devkit's rules.

Reminder of the devkit's sampling used in the expected values below: the TP scores give
the score thresholds (``get_thresholds``); sample ``i`` of the 41-point precision curve is
the precision at the ``i``-th threshold (0 past the last one), made monotone from the right.
R11 = sum of samples 0, 4, …, 40 / 11 × 100; R40 = sum of samples 1…40 / 40 × 100.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarfuzz.oracles.kitti_eval import (
    KittiFrame,
    evaluate_kitti,
    get_thresholds,
)
from lidarfuzz.scene.boxes import Boxes3D

CAR = (3.9, 1.6, 1.5)
PED = (0.8, 0.6, 1.75)
CYC = (1.8, 0.6, 1.7)


def boxes(
    rows: list[tuple[str, tuple[float, float, float], tuple[float, float, float], float]],
    scores: list[float] | None = None,
    occlusion: list[int] | None = None,
    truncation: list[float] | None = None,
) -> Boxes3D:
    """rows: (label, LiDAR centre, (l, w, h), yaw)."""
    if not rows:
        return Boxes3D.empty()
    n = len(rows)
    return Boxes3D.create(
        [r[1] for r in rows],
        [r[2] for r in rows],
        [r[3] for r in rows],
        [r[0] for r in rows],
        scores=scores,
        occlusion=occlusion if occlusion is not None else [0] * n,
        truncation=truncation if truncation is not None else [0.0] * n,
    )


def car(
    x: float, y: float = 0.0, yaw: float = 0.0
) -> tuple[str, tuple[float, float, float], tuple[float, float, float], float]:
    return ("Car", (x, y, -0.9), CAR, yaw)


def frame(gt: Boxes3D, dt: Boxes3D) -> KittiFrame:
    return KittiFrame(gt=gt, detections=dt)


def ap(frames: list[KittiFrame], metric: str = "3d", difficulty: str = "moderate", points: str = "R40") -> float:
    return evaluate_kitti(frames, classes=("Car",)).get(metric, "Car", difficulty, points)


def perfect_frames(n: int = 45, yaw_offset: float = 0.0, square: bool = False) -> list[KittiFrame]:
    out = []
    for k in range(n):
        size = (1.6, 1.6, 1.5) if square else CAR
        rows = [
            ("Car", (12.0, -4.0, -0.9), size, 0.3),
            ("Pedestrian", (14.0, 0.0, -0.85), PED, 1.0),
            ("Cyclist", (16.0, 4.0, -0.85), CYC, -0.5),
        ]
        gt = boxes(rows)
        det_rows = [(r[0], r[1], r[2], r[3] + yaw_offset) for r in rows]
        dt = boxes(det_rows, scores=[0.5 + k / 100, 0.51 + k / 100, 0.52 + k / 100])
        out.append(frame(gt, dt))
    return out


def test_perfect_detector_scores_100_everywhere() -> None:
    # 45 GT per class → 41 distinct thresholds, precision 1 at each: every sample is 1.
    result = evaluate_kitti(perfect_frames())
    for metric in ("bbox", "bev", "3d", "aos"):
        for cls in ("Car", "Pedestrian", "Cyclist"):
            for d in ("easy", "moderate", "hard"):
                for pts in ("R11", "R40"):
                    assert result.get(metric, cls, d, pts) == pytest.approx(100.0), (metric, cls, d, pts)
    assert json.loads(result.to_json())["map"]["3d"]["moderate"]["R40"] == pytest.approx(100.0)
    assert "Car AP_R40@0.70, 0.70, 0.70:" in result.format_table()


def test_map_is_the_mean_over_classes() -> None:
    # Car perfect (100), Pedestrian and Cyclist without any detection (0): mAP = 100 / 3
    frames = [KittiFrame(f.gt, f.detections.select(f.detections.labels == "Car")) for f in perfect_frames()]
    result = evaluate_kitti(frames)
    assert result.get("bev", "Pedestrian", "easy") == 0.0
    assert result.mean_ap("bev", "easy") == pytest.approx(100.0 / 3)
    assert evaluate_kitti(frames, classes=("Car",)).mean_ap("bev", "easy") == pytest.approx(100.0)


def test_single_match_fills_only_first_sample() -> None:
    # one GT, one TP → thresholds [0.9]; samples [1, 0, …]: R11 = 100/11, R40 = 0.
    f = frame(boxes([car(15)]), boxes([car(15)], scores=[0.9]))
    assert ap([f], points="R11") == pytest.approx(100 / 11)
    assert ap([f], points="R40") == 0.0


@pytest.mark.parametrize(("shift", "matched"), [(0.70, True), (0.71, False)])
def test_overlap_threshold_is_strict(shift: float, matched: bool) -> None:
    # Shifting a box of length 4 by d along its length: 3D IoU = (4 - d) / (4 + d);
    # d = 0.70 → 0.7021 > 0.7 (TP), d = 0.71 → 0.6985 (not a TP; 0 AP).
    size = (4.0, 1.6, 1.5)
    gt = boxes([("Car", (15.0, 0.0, -0.9), size, 0.0)])
    dt = boxes([("Car", (15.0 + shift, 0.0, -0.9), size, 0.0)], scores=[0.9])
    expected = 100 / 11 if matched else 0.0
    assert ap([frame(gt, dt)], "3d", points="R11") == pytest.approx(expected)
    assert ap([frame(gt, dt)], "bev", points="R11") == pytest.approx(expected)


def two_frames_base() -> list[KittiFrame]:
    # Two Car GT, TPs with scores 0.9 and 0.5 → thresholds [0.9, 0.5]; with no FP the
    # samples are [1, 1, 0, …] → R40 = 1/40 × 100 = 2.5
    # (sample 0 is not part of R40).
    return [
        frame(boxes([car(15)]), boxes([car(15)], scores=[0.9])),
        frame(boxes([car(20)]), boxes([car(20)], scores=[0.5])),
    ]


def test_two_detections_on_one_gt_give_one_tp_one_fp() -> None:
    # Frame 1: GT with detections 0.9 and 0.8 (duplicate); frame 2: GT with detection 0.7.
    # TP scores 0.9, 0.7 → thresholds [0.9, 0.7]. At 0.9: 1 TP, 0 FP → 1.
    # At 0.7: 2 TP, 1 FP (the duplicate) → 2/3. R40 = 2/3 / 40 × 100 = 1.6667.
    frames = [
        frame(boxes([car(15)]), boxes([car(15), car(15)], scores=[0.9, 0.8])),
        frame(boxes([car(20)]), boxes([car(20)], scores=[0.7])),
    ]
    assert ap(frames) == pytest.approx(100 * (2 / 3) / 40)


def test_van_is_neither_fp_nor_fn_for_car() -> None:
    frames = two_frames_base()
    assert ap(frames) == pytest.approx(2.5)
    # a Car detection on a Van GT is assigned to the ignored GT (not FP), and a Van
    # detection on a Car GT is not a Car detection at all: still 2.5.
    van_gt = boxes([("Van", (25.0, 0.0, -0.9), CAR, 0.0)])
    frames.append(frame(van_gt, boxes([car(25)], scores=[0.8])))
    frames[0] = frame(frames[0].gt, boxes([car(15), ("Van", (15.0, 0.0, -0.9), CAR, 0.0)], scores=[0.9, 0.95]))
    assert ap(frames) == pytest.approx(2.5)
    # the same Car detection with no GT at all is an FP at threshold 0.5: samples [1, 2/3].
    frames[-1] = frame(Boxes3D.empty(), boxes([car(25)], scores=[0.8]))
    assert ap(frames) == pytest.approx(100 * (2 / 3) / 40)


def test_detection_in_dontcare_region_is_ignored_for_bbox() -> None:
    frames = two_frames_base()
    dontcare = Boxes3D.create(
        np.full((1, 3), np.nan), np.full((1, 3), np.nan), [np.nan], ["DontCare"], bbox2d=[[0.0, 0.0, 1241.0, 374.0]]
    )
    frames.append(frame(dontcare, boxes([car(25)], scores=[0.8])))
    # bbox: the unmatched detection lies inside the DontCare box (intersection / its own
    # area = 1 > 0.7) → not an FP: samples [1, 1] → 2.5.
    assert ap(frames, "bbox") == pytest.approx(2.5)
    # The Python ports apply DontCare to the bbox metric only: in 3D it is an FP at
    # threshold 0.5, samples [1, 2/3] → R40 = 2/3/40 × 100.
    assert ap(frames, "3d") == pytest.approx(100 * (2 / 3) / 40)


@pytest.mark.parametrize(
    ("occlusion", "truncation", "x"),
    [(1, 0.0, 20.0), (0, 0.2, 20.0), (0, 0.0, 35.0)],  # occluded / truncated / 2D height ≈ 31 px
)
def test_gt_outside_easy_is_ignored_there_but_counts_for_hard(occlusion: int, truncation: float, x: float) -> None:
    # Frame 1 is an easy TP (0.9); frame 2's GT fails 'easy' on one criterion.
    # easy: 1 valid GT, the 0.5 detection is absorbed by the ignored GT → thresholds [0.9]
    #       → R40 = 0 (only sample 0), R11 = 100/11.
    # moderate/hard: 2 valid GT, thresholds [0.9, 0.5], samples [1, 1] → R40 = 2.5.
    frames = [
        frame(boxes([car(15)]), boxes([car(15)], scores=[0.9])),
        frame(boxes([car(x)], occlusion=[occlusion], truncation=[truncation]), boxes([car(x)], scores=[0.5])),
    ]
    assert ap(frames, difficulty="easy") == 0.0
    assert ap(frames, difficulty="easy", points="R11") == pytest.approx(100 / 11)
    assert ap(frames, difficulty="hard") == pytest.approx(2.5)


def test_tied_scores_both_pass_their_threshold() -> None:
    # Two GT, two exact detections with the same score 0.8 → thresholds [0.8, 0.8];
    # dets with score == threshold are kept → samples [1, 1] → R40 = 2.5.
    f = frame(boxes([car(15, -3), car(20, 3)]), boxes([car(15, -3), car(20, 3)], scores=[0.8, 0.8]))
    assert ap([f]) == pytest.approx(2.5)
    assert get_thresholds(np.array([0.8, 0.8]), 2) == [0.8, 0.8]


def test_empty_frames() -> None:
    empty = frame(Boxes3D.empty(), Boxes3D.empty())
    assert evaluate_kitti([]).get("3d", "Car", "easy", "R40") == 0.0
    assert evaluate_kitti([empty, empty]).get("bbox", "Pedestrian", "hard", "R11") == 0.0
    base = two_frames_base()
    assert ap([empty, *base, empty]) == pytest.approx(ap(base))


def test_hand_worked_precision_recall_curve() -> None:
    # GT A, B, C. Detections: d1 0.9 on A, d2 0.8 nowhere, d3 0.7 on B, d4 0.6 on C.
    # TP scores [0.9, 0.7, 0.6], num_gt 3 → get_thresholds keeps all three:
    #   i=0: l=1/3, r=2/3, cur=0 → keep; i=1: r - cur = 0.975 ≥ cur - l < 0 → keep; i=2 last → keep.
    # precision: at 0.9 → 1/1, at 0.7 → 2/3 (d2 FP), at 0.6 → 3/4; recall 1/3, 2/3, 1.
    # monotone from the right: [1, 3/4, 3/4, 0, …].
    # R11 = (1 + 0 × 10)/11 × 100 = 9.0909; R40 = (3/4 + 3/4)/40 × 100 = 3.75.
    gt = boxes([car(15, -3), car(20, 0), car(25, 3)])
    dt = boxes([car(15, -3), car(30, -8), car(20, 0), car(25, 3)], scores=[0.9, 0.8, 0.7, 0.6])
    assert get_thresholds(np.array([0.9, 0.7, 0.6]), 3) == [0.9, 0.7, 0.6]
    assert ap([frame(gt, dt)], points="R11") == pytest.approx(100 / 11)
    assert ap([frame(gt, dt)], points="R40") == pytest.approx(3.75)


def test_aos_follows_orientation() -> None:
    # square footprints so that turning the detections keeps IoU 1 and AP 100:
    # Δα = π → (1 + cos π)/2 = 0 → AOS 0; Δα = π/2 → 1/2 → AOS 50.
    right = evaluate_kitti(perfect_frames(square=True), classes=("Car",))
    flipped = evaluate_kitti(perfect_frames(yaw_offset=np.pi, square=True), classes=("Car",))
    quarter = evaluate_kitti(perfect_frames(yaw_offset=np.pi / 2, square=True), classes=("Car",))
    assert right.get("aos", "Car", "moderate") == pytest.approx(100.0)
    assert flipped.get("3d", "Car", "moderate") == pytest.approx(100.0)
    assert flipped.get("aos", "Car", "moderate") == pytest.approx(0.0, abs=1e-9)
    assert quarter.get("aos", "Car", "moderate") == pytest.approx(50.0)


def random_frames(seed: int, n: int = 12) -> list[KittiFrame]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        k = int(rng.integers(0, 6))
        labels = rng.choice(["Car", "Pedestrian", "Cyclist", "Van"], size=k)
        centers = np.stack([rng.uniform(8, 40, k), rng.uniform(-8, 8, k), np.full(k, -0.9)], axis=1)
        sizes = np.array(
            [CAR if lab in ("Car", "Van") else PED if lab == "Pedestrian" else CYC for lab in labels]
        ).reshape(k, 3)
        yaw = rng.uniform(-np.pi, np.pi, k)
        gt = Boxes3D.create(
            centers, sizes, yaw, labels, occlusion=rng.integers(0, 3, k), truncation=rng.uniform(0, 0.4, k)
        )
        keep = rng.random(k) < 0.8
        dc = centers[keep] + rng.normal(0, 0.3, (int(keep.sum()), 3))
        m = int(keep.sum())
        dt = Boxes3D.create(
            dc,
            sizes[keep] * rng.uniform(0.9, 1.1, (m, 3)),
            yaw[keep] + rng.normal(0, 0.2, m),
            labels[keep],
            scores=rng.random(m),
        )
        out.append(frame(gt, dt))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_invariant_to_order_of_frames_and_boxes(seed: int) -> None:
    frames = random_frames(seed)
    rng = np.random.default_rng(100 + seed)
    shuffled = []
    for i in rng.permutation(len(frames)):
        f = frames[i]
        shuffled.append(
            frame(f.gt.select(rng.permutation(len(f.gt))), f.detections.select(rng.permutation(len(f.detections))))
        )
    a, b = evaluate_kitti(frames), evaluate_kitti(shuffled)
    for metric in a.ap:
        for cls in a.ap[metric]:
            for d in a.ap[metric][cls]:
                for pts in ("R11", "R40"):
                    assert a.get(metric, cls, d, pts) == pytest.approx(b.get(metric, cls, d, pts))


def test_loose_thresholds_accept_a_half_overlap() -> None:
    # 3D IoU (4 - d)/(4 + d) with d = 1.0 → 3/5 = 0.6: official Car (0.7) rejects it (AP 0),
    # loose Car (0.5) accepts it (one TP → R11 = 100/11).
    size = (4.0, 1.6, 1.5)
    gt = boxes([("Car", (15.0, 0.0, -0.9), size, 0.0)])
    dt = boxes([("Car", (16.0, 0.0, -0.9), size, 0.0)], scores=[0.9])
    official = evaluate_kitti([frame(gt, dt)], classes=("Car",))
    loose = evaluate_kitti([frame(gt, dt)], classes=("Car",), overlaps="loose")
    assert official.get("3d", "Car", "moderate", "R11") == 0.0
    assert loose.get("3d", "Car", "moderate", "R11") == pytest.approx(100 / 11)
    assert loose.overlaps["3d"]["Car"] == 0.5 and loose.overlaps["bbox"]["Car"] == 0.7
    with pytest.raises(ValueError, match="overlaps"):
        evaluate_kitti([], overlaps="strict")  # type: ignore[arg-type]


# -- the batched evaluation against the readable per-frame loop ---------------------------
def _random_frames(seed: int) -> list[KittiFrame]:
    """Frames that exercise every rule: neighbour classes, DontCare, far (low) boxes of any
    class, occlusion/truncation beyond each difficulty, tied scores, empty frames."""
    rng = np.random.default_rng(seed)
    sizes = {"Car": CAR, "Van": (4.8, 1.9, 2.1), "Pedestrian": PED, "Person_sitting": (0.9, 0.6, 1.2), "Cyclist": CYC}
    names = list(sizes)
    frames = []
    for _ in range(int(rng.integers(1, 12))):
        m = int(rng.integers(0, 7))
        labels = list(rng.choice(names, m))
        centres = np.c_[rng.uniform(4, 70, m), rng.uniform(-12, 12, m), np.full(m, -0.9)]
        dims = np.array([sizes[label] for label in labels]).reshape(-1, 3)
        yaw = rng.uniform(-np.pi, np.pi, m)
        gt = Boxes3D.create(
            centres, dims, yaw, labels, occlusion=rng.integers(0, 4, m), truncation=rng.uniform(0, 0.6, m)
        )
        if rng.random() < 0.5:
            x1, y1 = rng.uniform(0, 1000), rng.uniform(100, 300)
            gt = Boxes3D.concat(
                [
                    gt,
                    Boxes3D.create(
                        [[np.nan] * 3], [[np.nan] * 3], [np.nan], ["DontCare"], bbox2d=[[x1, y1, x1 + 200, y1 + 60]]
                    ),
                ]
            )
        keep = rng.random(m) < 0.8
        k = int(keep.sum())
        extra = int(rng.integers(0, 4))
        dt_labels = [label for label, kept in zip(labels, keep, strict=True) if kept] + list(rng.choice(names, extra))
        dt = Boxes3D.create(
            np.r_[
                centres[keep] + rng.normal(0, 0.25, (k, 3)),
                np.c_[rng.uniform(4, 70, extra), rng.uniform(-12, 12, extra), np.full(extra, -0.9)],
            ],
            np.r_[
                dims[keep] * rng.uniform(0.9, 1.1, (k, 3)), np.array([sizes[n] for n in dt_labels[k:]]).reshape(-1, 3)
            ],
            np.r_[yaw[keep] + rng.normal(0, 0.2, k), rng.uniform(-np.pi, np.pi, extra)],
            dt_labels,
            scores=rng.choice([0.2, 0.5, 0.5, 0.7, 0.9], k + extra),  # ties on purpose
        )
        frames.append(KittiFrame(gt, dt))
    frames.append(KittiFrame(Boxes3D.empty(), Boxes3D.empty()))
    return frames


@pytest.mark.parametrize("seed", range(40))
def test_batched_evaluation_equals_the_per_frame_loop(seed: int) -> None:
    from lidarfuzz.oracles import kitti_eval as k

    frames = _random_frames(seed)
    batch = k._batch(frames)
    prepared = k._prepare(frames)
    for cls in k.CLASSES:
        view = k._class_view(batch, cls)
        for difficulty in range(3):
            ignored_gt, ignored_dt = k._ignored(batch, view, cls, difficulty)
            cleans = [k._clean(fr, cls, difficulty) for fr in prepared]
            for metric in k.GEOMETRIC_METRICS:
                overlap = k.OFFICIAL_OVERLAPS[metric][cls]
                ref_prec, ref_aos = k._precision_curves(prepared, cleans, metric, overlap, metric == "bbox")
                prec, aos = k._curves(batch, view, ignored_gt, ignored_dt, metric, overlap)
                np.testing.assert_allclose(prec, ref_prec, atol=1e-12, err_msg=f"{cls} {difficulty} {metric}")
                if metric == "bbox":
                    np.testing.assert_allclose(aos, ref_aos, atol=1e-12, err_msg=f"{cls} {difficulty} aos")


def test_a_detection_with_reversed_heading_still_overlaps_fully() -> None:
    # plain GEOS overlay loses this intersection (coincident edges); BEV/3D must match like bbox does
    gt_box = [28.472630568828517, 3.7997185326700578, -1.2500509599108747, 8.673443842941696, 4.065235603340231,
              2.4105425628344315, -1.3080781776389534]
    gt = Boxes3D.from_array([gt_box], ["Car"], truncation=[0.0], occlusion=[0])
    flipped = list(gt_box)
    flipped[6] += np.pi
    dt = Boxes3D.from_array([flipped], ["Car"], scores=[0.9])
    result = evaluate_kitti([KittiFrame(gt, dt)], classes=("Car",))
    for metric in ("bbox", "bev", "3d"):
        assert result.get(metric, "Car", "easy", "R11") == pytest.approx(100 / 11), metric
