"""Metamorphic relations on hand-built (source, follow-up) pairs."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators.base import Relation
from lidarfuzz.oracles.relations import (
    DeepTestTolerance,
    Equivariance,
    GroundTruthRecall,
    Invariance,
    Pair,
    Preservation,
    available,
    for_operator,
    from_spec,
    get,
)
from lidarfuzz.plugins import UnknownPluginError
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import transform_boxes
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene


def boxes(
    xy: list[tuple[float, float]],
    scores: list[float] | None = None,
    labels: list[str] | None = None,
    yaw: list[float] | None = None,
    track_ids: list[int] | None = None,
) -> Boxes3D:
    n = len(xy)
    return Boxes3D.create(
        [[x, y, -0.8] for x, y in xy],
        [[4.0, 1.8, 1.5]] * n,
        yaw or [0.0] * n,
        labels or ["Car"] * n,
        scores=scores,
        track_ids=track_ids,
    )


def scene(gt: Boxes3D | None = None, roi: RoiMap | None = None) -> Scene:
    return Scene(PointCloud(np.zeros((0, 4))), boxes=gt if gt is not None else Boxes3D.empty(), roi=roi)


def pair(src: Boxes3D, fol: Boxes3D, kind: Relation | None = Relation.INVARIANT, **kw: object) -> Pair:
    return Pair(kw.pop("source", scene()), kw.pop("follow", scene()), src, fol, kind, **kw)  # type: ignore[arg-type]


# -- preservation (Zhou & Sun MR1) ----------------------------------------------------------
def test_preservation_names_the_lost_object_and_gives_the_count_form() -> None:
    src = boxes([(10, 0), (30, 4)], scores=[0.9, 0.8])
    out = Preservation()(pair(src, boxes([(10.1, 0)], scores=[0.9])))
    assert not out.holds and out.applicable
    (v,) = out.violations
    assert (v.kind, v.cls, v.source_index, v.magnitude) == ("missing", "Car", 1, 0.0)
    assert v.range_m == pytest.approx(np.hypot(30, 4))
    assert "30.3 m" in v.message
    assert out.checked == {"Car": 2}
    assert out.stats == {"n_source": 2, "n_follow": 1, "count_holds": 0.0}


def test_preservation_holds_with_extra_follow_up_detections_and_ignores_low_scores() -> None:
    src = boxes([(10, 0), (30, 4)], scores=[0.9, 0.2])  # the second is not "detected"
    fol = boxes([(10, 0), (50, 0)], scores=[0.7, 0.6])
    out = Preservation()(pair(src, fol))
    assert out.holds and out.stats["count_holds"] == 1.0 and out.checked == {"Car": 1}
    # the strict form can fail while the count form holds: same number, different objects
    out = Preservation()(pair(boxes([(10, 0)], [0.9]), boxes([(40, 0)], [0.9])))
    assert not out.holds and out.stats["count_holds"] == 1.0


def test_preservation_checks_only_objects_inside_the_roi() -> None:
    roi = RoiMap.from_polygons([[(0, -5), (20, -5), (20, 5), (0, 5)]])
    src = boxes([(10, 0), (30, 0)], scores=[0.9, 0.9])
    out = Preservation()(pair(src, Boxes3D.empty(), source=scene(roi=roi), follow=scene(roi=roi)))
    assert [v.source_index for v in out.violations] == [0]
    assert len(Preservation(roi_only=False)(pair(src, Boxes3D.empty(), source=scene(roi=roi))).violations) == 2


def test_class_must_be_kept() -> None:
    out = Preservation()(pair(boxes([(10, 0)], [0.9]), boxes([(10, 0)], [0.9], labels=["Cyclist"])))
    assert not out.holds and out.violations[0].magnitude == 0.0


def test_relations_do_not_apply_to_other_operator_kinds() -> None:
    out = Preservation()(pair(boxes([(10, 0)], [0.9]), Boxes3D.empty(), Relation.DEGRADING))
    assert not out.applicable and out.holds and not out.violations
    assert Preservation()(pair(boxes([(10, 0)], [0.9]), Boxes3D.empty(), None)).applicable


# -- hysteresis about the score threshold ----------------------------------------------------
def test_a_score_wobbling_across_the_threshold_is_not_a_lost_or_a_new_object() -> None:
    # min_score 0.5, score_margin 0.1: a source detection is checked from 0.6; a follow-up
    # detection counts as found from 0.4; a new one counts as spurious from 0.6
    src = boxes([(10, 0), (30, 4)], scores=[0.9, 0.55])  # the second is not clear: not checked
    out = Preservation()(pair(src, boxes([(10, 0)], scores=[0.45])))  # 0.9 -> 0.45: found again
    assert out.holds and out.checked == {"Car": 1}
    assert out.stats["n_source"] == 2  # the count form still counts at the threshold itself
    lost = Preservation()(pair(src, boxes([(10, 0)], scores=[0.35])))  # below 0.4: lost
    assert [v.source_index for v in lost.violations] == [0]
    assert not Preservation(score_margin=0.0)(pair(src, boxes([(10, 0)], scores=[0.9]))).holds  # 0.55 now checked
    t = rotation(0.3)
    follow = Boxes3D.concat([moved(src, t).select([0]), boxes([(5, 5), (-8, 3)], scores=[0.55, 0.65])])
    out = Equivariance()(pair(src, follow, Relation.EQUIVARIANT, transform=t))
    # (5, 5) at 0.55 is not clear: not spurious; (-8, 3) at 0.65 is; the source's 0.55 at (30, 4)
    # moved and lost is not checked
    assert [(v.kind, v.follow_index) for v in out.violations] == [("spurious", 2)]
    # a follow-up detection that a source detection below the clear line accounts for is not new
    follow = Boxes3D.concat([moved(src, t)])  # both moved, the second still at 0.55
    assert Equivariance()(pair(src, Boxes3D.from_array(follow.as_array(), follow.labels, scores=[0.9, 0.65]),
                                Relation.EQUIVARIANT, transform=t)).holds


def test_an_overlap_wobbling_across_min_iou_is_not_a_lost_object() -> None:
    # two 4 x 1.8 m cars offset along x by d overlap (4 - d) * 1.8 of 2 * 7.2 - (4 - d) * 1.8, so
    # BEV IoU = (4 - d) / (4 + d): d = 1.36 gives 2.64 / 5.36 = 0.4925 (under min_iou 0.5, above
    # 0.45 = min_iou - iou_margin); d = 1.6 gives 2.4 / 5.6 = 0.4286 (under both)
    src = boxes([(10, 0)], scores=[0.9])
    assert Preservation()(pair(src, boxes([(11.36, 0)], scores=[0.9]))).holds
    assert not Preservation(iou_margin=0.0)(pair(src, boxes([(11.36, 0)], scores=[0.9]))).holds
    assert not Preservation()(pair(src, boxes([(11.6, 0)], scores=[0.9]))).holds
    # ground-truth recall: the source must match its object at 0.5 itself, the follow-up from 0.45
    gt = boxes([(10, 0)], track_ids=[1])
    judged = dict(source=scene(gt), follow=scene(gt))
    assert GroundTruthRecall(evidence=False)(pair(src, boxes([(11.36, 0)], scores=[0.9]), **judged)).holds
    out = GroundTruthRecall(evidence=False, iou_margin=0.0)(pair(src, boxes([(11.36, 0)], scores=[0.9]), **judged))
    assert not out.holds
    # a source detection credited at IoU 0.4925 only is not counted as found, so nothing is checked
    out = GroundTruthRecall(evidence=False)(pair(boxes([(11.36, 0)], scores=[0.9]), Boxes3D.empty(), **judged))
    assert out.holds


# -- equivariance -----------------------------------------------------------------------------
def rotation(angle: float, shift: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0, shift[0]], [s, c, 0, shift[1]], [0, 0, 1, 0], [0, 0, 0, 1]])


def moved(b: Boxes3D, t: np.ndarray) -> Boxes3D:
    return Boxes3D.from_array(transform_boxes(b.as_array(), t), b.labels, scores=b.scores)


@pytest.mark.parametrize("t", [rotation(0.5), rotation(-1.0, (2, 1)), np.diag([1.0, -1.0, 1.0, 1.0])])
def test_equivariance_holds_when_detections_follow_the_transform(t: np.ndarray) -> None:
    src = boxes([(10, 2), (25, -6)], scores=[0.9, 0.8], yaw=[0.3, 1.2])
    out = Equivariance()(pair(src, moved(src, t), Relation.EQUIVARIANT, transform=t))
    assert out.holds, out.violations


def test_equivariance_reports_lost_and_invented_objects() -> None:
    t = rotation(0.5)
    src = boxes([(10, 2), (25, -6)], scores=[0.9, 0.8])
    follow = Boxes3D.concat([moved(src, t).select([0]), boxes([(5, 5)], scores=[0.9])])
    out = Equivariance()(pair(src, follow, Relation.EQUIVARIANT, transform=t))
    kinds = sorted((v.kind, v.source_index, v.follow_index) for v in out.violations)
    assert kinds == [("missing", 1, -1), ("spurious", -1, 1)]
    assert out.checked == {"Car": 3}
    # untransformed follow-up boxes do not match a rotated frame
    assert not Equivariance()(pair(src, src, Relation.EQUIVARIANT, transform=t)).holds
    assert len(Equivariance(check_spurious=False)(pair(src, follow, Relation.EQUIVARIANT, transform=t)).violations) == 1


def test_equivariance_needs_a_transform() -> None:
    src = boxes([(10, 2)], scores=[0.9])
    assert not Equivariance()(pair(src, src, Relation.EQUIVARIANT)).applicable


# -- invariance with tolerance ------------------------------------------------------------
def test_invariance_bounds_score_drop_drift_and_turn() -> None:
    src = boxes([(10, 0), (20, 0), (30, 0), (40, 0)], scores=[0.9, 0.9, 0.9, 0.9])
    fol = boxes([(10, 0), (20.5, 0), (30, 0), (40.1, 0)], scores=[0.6, 0.85, 0.9, 0.8], yaw=[0, 0, np.pi, 0.1])
    out = Invariance()(pair(src, fol))
    found = sorted((v.kind, v.source_index, round(v.magnitude, 3)) for v in out.violations)
    assert found == [("drift", 1, 0.5), ("heading", 2, round(np.pi, 3)), ("score_drop", 0, 0.3)]
    loose = Invariance(max_score_drop=0.5, max_drift_m=1.0, max_heading_change=4.0)(pair(src, fol))
    assert loose.holds


# -- ground-truth recall --------------------------------------------------------------------
def test_gt_recall_reports_objects_found_then_lost_by_track_id() -> None:
    gt = boxes([(10, 0), (20, 5), (35, -3)], track_ids=[7, 8, 9])
    follow_gt = gt.select([2, 0])  # object 8 removed by the operator; order changed
    src_dets = boxes([(10, 0), (20, 5)], scores=[0.9, 0.9])  # 9 never found in the source
    fol_dets = boxes([(35, -3)], scores=[0.9])  # finds 9, loses 7
    p = pair(src_dets, fol_dets, Relation.DEGRADING, source=scene(gt), follow=scene(follow_gt))
    out = GroundTruthRecall()(p)
    (v,) = out.violations
    assert (v.kind, v.gt_index, v.source_index, v.range_m) == ("lost_gt", 0, 0, 10.0)
    assert out.stats == {"n_gt": 2, "n_found_source": 1, "n_lost": 1}


def test_gt_recall_on_a_mutant_with_no_labelled_object_left_holds() -> None:
    """Every labelled object removed by the operator (track ids 7 and 8 gone): none is expected on
    the mutant, so nothing is lost (before: an IndexError indexing the mutant's empty matches)."""
    gt = boxes([(10, 0), (20, 5)], track_ids=[7, 8])
    src_dets = boxes([(10, 0), (20, 5)], scores=[0.9, 0.9])
    gone = gt.select(np.zeros(0, dtype=int))
    p = pair(src_dets, Boxes3D.empty(), Relation.DEGRADING, source=scene(gt), follow=scene(gone))
    out = GroundTruthRecall()(p)
    assert out.holds and not out.violations
    assert out.stats["n_lost"] == 0


def test_max_truncation_skips_objects_the_camera_view_cuts() -> None:
    """An object beside the car (half outside the camera's view) is not checked with
    max_truncation; one well inside the view still is."""
    from lidarfuzz.scene.calib import KittiCalibration

    def framed(gt: Boxes3D | None = None) -> Scene:
        return Scene(PointCloud(np.zeros((0, 4))), boxes=gt if gt is not None else Boxes3D.empty(),
                     calib=KittiCalibration.default())

    src = boxes([(0.5, -3.0), (20, 0)], scores=[0.9, 0.9])  # beside the car: x = -1.5 .. 2.5
    lost_both = pair(src, Boxes3D.empty(), source=framed(), follow=framed())
    assert len(Preservation()(lost_both).violations) == 2
    out = Preservation(max_truncation=0.3)(lost_both)
    assert [v.source_index for v in out.violations] == [1] and out.checked == {"Car": 1}
    # ground truth by its KITTI truncation
    gt = Boxes3D.create([[0.5, -3.0, -0.8], [20, 0, -0.8]], [[4.0, 1.8, 1.5]] * 2, [0.0, 0.0], ["Car"] * 2,
                        track_ids=[1, 2], truncation=[0.6, 0.0])
    p = pair(src, Boxes3D.empty(), Relation.DEGRADING, source=framed(gt), follow=framed(gt))
    assert [v.gt_index for v in GroundTruthRecall()(p).violations] == [0, 1]
    assert [v.gt_index for v in GroundTruthRecall(max_truncation=0.5)(p).violations] == [1]
    # equivariance: neither a source object cut by the view nor a follow-up one counts
    shift = np.eye(4)
    out = Equivariance(max_truncation=0.3)(pair(src, boxes([(20, 0), (1.0, 3.0)], scores=[0.9, 0.9]),
                                              Relation.EQUIVARIANT, source=framed(), follow=framed(),
                                              transform=shift))
    assert out.holds, out.violations
    assert not Equivariance()(pair(src, boxes([(20, 0), (1.0, 3.0)], scores=[0.9, 0.9]), Relation.EQUIVARIANT,
                                   source=framed(), follow=framed(), transform=shift)).holds
    with pytest.raises(ValueError):
        Preservation(max_truncation=1.5)


def test_gt_recall_needs_ground_truth_it_can_pair_up() -> None:
    d = boxes([(10, 0)], scores=[0.9])
    assert not GroundTruthRecall()(pair(d, d)).applicable
    gt = boxes([(10, 0), (20, 0)])
    different = pair(d, d, source=scene(gt), follow=scene(gt.select([0])))
    assert not GroundTruthRecall()(different).applicable
    assert GroundTruthRecall()(pair(d, d, source=scene(gt), follow=scene(gt))).holds


# -- DeepTest tolerance -------------------------------------------------------------------------
def test_deeptest_tolerance_on_box_centres() -> None:
    gt = boxes([(10, 0), (20, 0)])
    src = boxes([(10.1, 0), (20.1, 0)], scores=[0.9, 0.9])  # squared errors 0.01, MSE_orig 0.01
    relation = DeepTestTolerance()  # λ = 5: limit 0.05
    ok = relation(pair(src, boxes([(10.2, 0), (20.1, 0)], scores=[0.9, 0.9]), source=scene(gt), follow=scene(gt)))
    assert ok.holds and ok.stats["mse_orig"] == pytest.approx(0.01)
    assert ok.stats["sum_squared_error"] == pytest.approx(0.05)
    bad = relation(pair(src, boxes([(10.3, 0), (20.1, 0)], scores=[0.9, 0.9]), source=scene(gt), follow=scene(gt)))
    (v,) = bad.violations
    assert v.kind == "regression" and v.magnitude == pytest.approx(0.09) and v.gt_index == 0
    # a data-set MSE from the campaign overrides the per-frame fallback
    strict = relation(
        pair(
            src,
            boxes([(10.2, 0), (20.1, 0)], scores=[0.9, 0.9]),
            source=scene(gt),
            follow=scene(gt),
            reference={"mse_orig": 0.001},
        )
    )
    assert len(strict.violations) == 2
    assert DeepTestTolerance(**{"lambda": 10}).config.lambda_ == 10


def test_deeptest_new_only_leaves_out_errors_already_there_on_the_original() -> None:
    # MSE_orig 0.02, λ 5: limit 0.1. The first object is 0.4 m off on the original too (0.16 > 0.1):
    # DeepTest flags it on every mutant; new_only does not. The second goes 0.1 -> 0.4 m (0.01 -> 0.16):
    # the transformation's doing, flagged by both. Track ids pair the labels; the third object
    # (x = 40) is not found on the original, so its follow-up error (0.25) is not known to be new.
    gt = boxes([(10, 0), (20, 0), (40, 0)], track_ids=[1, 2, 3])
    src = boxes([(10.4, 0), (20.1, 0)], scores=[0.9, 0.9])
    fol = boxes([(10.4, 0), (20.4, 0), (40.5, 0)], scores=[0.9, 0.9, 0.9])
    judged = dict(source=scene(gt), follow=scene(gt), reference={"mse_orig": 0.02})
    paper = DeepTestTolerance()(pair(src, fol, **judged))
    assert sorted(v.gt_index for v in paper.violations) == [0, 1, 2]
    new = DeepTestTolerance(new_only=True)(pair(src, fol, **judged))
    assert [v.gt_index for v in new.violations] == [1]
    assert new.violations[0].magnitude == pytest.approx(0.16)
    assert new.stats["already_over_on_source"] == 2


def test_deeptest_tolerance_when_the_follow_up_finds_nothing() -> None:
    gt = boxes([(10, 0), (20, 0)])
    src = boxes([(10.1, 0), (20.1, 0)], scores=[0.9, 0.9])
    outcome = DeepTestTolerance()(pair(src, boxes([]), source=scene(gt), follow=scene(gt)))
    assert outcome.applicable  # found a crash in a campaign: an empty follow-up output


def test_deeptest_tolerance_on_scalar_outputs_and_the_epsilon_filter() -> None:
    src = scene().replace(metadata={"label": 0.1})
    out = DeepTestTolerance()(Pair(src, src, 0.12, 0.5, Relation.INVARIANT, reference={"mse_orig": 0.01}))
    assert not out.holds and out.violations[0].magnitude == pytest.approx(0.16)
    relation = DeepTestTolerance(epsilon=0.03)
    assert relation.keeps_transformation(0.04, 0.02) and not relation.keeps_transformation(0.06, 0.02)
    with pytest.raises(ValueError, match="label"):
        DeepTestTolerance()(Pair(scene(), scene(), 0.1, 0.2, Relation.INVARIANT))


# -- registry ------------------------------------------------------------------------------
def test_registry_lists_builtins_and_round_trips_specs() -> None:
    assert {"preservation", "equivariance", "invariance", "deeptest_tolerance", "gt_recall"} <= set(available())
    assert get("GT-Recall") is GroundTruthRecall
    relation = from_spec({"name": "invariance", "config": {"max_drift_m": 0.5}})
    assert relation.config.max_drift_m == 0.5
    assert from_spec(relation.spec()).spec() == relation.spec()
    assert from_spec(DeepTestTolerance(**{"lambda": 3}).spec()).config.lambda_ == 3
    with pytest.raises(UnknownPluginError, match=r"known: .*preservation"):
        get("nope")
    with pytest.raises(ValueError):
        Invariance(max_drift_m=-1)
    names = {r.name for r in for_operator(Relation.EQUIVARIANT)}
    assert names == {"equivariance", "gt_recall"}
