"""Matching boxes: optimal vs greedy, classes, thresholds, per-range counts."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.oracles.matching import detection_counts, match_boxes, range_bin_labels
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import transform_boxes


def cars(
    xs: list[float], scores: list[float] | None = None, labels: list[str] | None = None, y: float = 0.0
) -> Boxes3D:
    """2 m × 1 m boxes along x: two of them offset by d overlap with BEV IoU (2 − d) / (2 + d)."""
    n = len(xs)
    return Boxes3D.create(
        [[x, y, 0.0] for x in xs], [[2.0, 1.0, 1.5]] * n, [0.0] * n, labels or ["Car"] * n, scores=scores
    )


def test_hungarian_finds_the_assignment_greedy_misses() -> None:
    # IoU(a0, b0) = 1.5/2.5 = 0.6, IoU(a0, b1) = 1.1/2.9 ≈ 0.379, IoU(a1, b0) = 0.6, IoU(a1, b1) ≈ 0.026
    a = cars([0.5, -0.5], scores=[0.9, 0.8])
    b = cars([0.0, 1.4])
    greedy = match_boxes(a, b, min_iou=0.3, method="greedy")
    assert greedy.pairs.tolist() == [[0, 0]]
    assert greedy.unmatched_a.tolist() == [1] and greedy.unmatched_b.tolist() == [1]
    optimal = match_boxes(a, b, min_iou=0.3, method="hungarian")
    assert optimal.pairs.tolist() == [[0, 1], [1, 0]]
    np.testing.assert_allclose(optimal.iou, [1.1 / 2.9, 0.6])
    assert optimal.partner_of_a(2).tolist() == [1, 0]
    assert optimal.partner_of_b(2).tolist() == [1, 0]


def test_threshold_is_inclusive_and_per_class() -> None:
    a = cars([0.5])  # IoU 0.6 with b
    b = cars([0.0])
    assert len(match_boxes(a, b, min_iou=0.6).pairs) == 1
    assert len(match_boxes(a, b, min_iou=0.61).pairs) == 0
    assert len(match_boxes(a, b, min_iou={"car": 0.7, "*": 0.1}).pairs) == 0
    assert len(match_boxes(a, b, min_iou={"Pedestrian": 0.7, "*": 0.5}).pairs) == 1


def test_classes_must_agree_unless_told_otherwise_and_dontcare_never_matches() -> None:
    a = cars([0.0], labels=["Car"])
    b = cars([0.0], labels=["Pedestrian"])
    assert len(match_boxes(a, b).pairs) == 0
    assert len(match_boxes(a, b, class_aware=False).pairs) == 1
    assert len(match_boxes(a, cars([0.0], labels=["car"])).pairs) == 1  # case-insensitive
    dontcare = cars([0.0], labels=["DontCare"])
    assert len(match_boxes(dontcare, dontcare, class_aware=False).pairs) == 0


def test_empty_sets() -> None:
    m = match_boxes(Boxes3D.empty(), cars([1.0]))
    assert m.pairs.shape == (0, 2) and m.unmatched_b.tolist() == [0]
    m = match_boxes(cars([1.0], scores=[0.5]), Boxes3D.empty(), method="greedy")
    assert m.unmatched_a.tolist() == [0]


def test_detection_counts_per_class_and_range() -> None:
    gt = Boxes3D.concat([cars([10.0, 30.0, 50.0]), cars([12.0], labels=["Pedestrian"], y=5.0)])
    # finds the 10 m and 50 m cars, misses the 30 m car and the pedestrian, invents a car at 25 m
    dets = cars([10.1, 50.0, 25.0], scores=[0.9, 0.8, 0.7], y=0.0)
    rows = detection_counts(dets, gt, range_bins=(0, 20, 40, np.inf))
    table = {(r.cls, r.range_bin): (r.tp, r.fp, r.fn) for r in rows}
    assert table == {
        ("Car", "0-20"): (1, 0, 0),
        ("Car", "20-40"): (0, 1, 1),
        ("Car", "40+"): (1, 0, 0),
        ("Pedestrian", "0-20"): (0, 0, 1),
    }
    assert rows[1].precision == 0.0 and rows[0].recall == 1.0
    assert np.isnan(rows[-1].precision)
    assert range_bin_labels((0, 10, np.inf)) == ["0-10", "10+"]
    # low scores are left out entirely
    low = detection_counts(dets.replace(scores=[0.9, 0.8, 0.1]), gt, min_score=0.5)
    assert sum(r.fp for r in low) == 0


@pytest.mark.parametrize("angle", [0.3, -2.0, 3.0])
def test_transform_boxes_rotation_translation_mirror_scale(angle: float) -> None:
    box = np.array([[5.0, 2.0, -0.5, 4.0, 2.0, 1.5, 0.4]])
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0, 1.0], [s, c, 0, -2.0], [0, 0, 1, 0.3], [0, 0, 0, 1]])
    out = transform_boxes(box, rot)[0]
    np.testing.assert_allclose(out[:2], [c * 5 - s * 2 + 1, s * 5 + c * 2 - 2])
    np.testing.assert_allclose(out[2:6], [-0.2, 4.0, 2.0, 1.5])
    assert np.isclose(np.cos(out[6] - 0.4 - angle), 1.0)
    mirrored = transform_boxes(box, np.diag([1.0, -1.0, 1.0, 1.0]))[0]
    np.testing.assert_allclose(mirrored, [5.0, -2.0, -0.5, 4.0, 2.0, 1.5, -0.4])
    scaled = transform_boxes(box, np.diag([1.1, 1.1, 1.1, 1.0]))[0]
    np.testing.assert_allclose(scaled, [5.5, 2.2, -0.55, 4.4, 2.2, 1.65, 0.4])
