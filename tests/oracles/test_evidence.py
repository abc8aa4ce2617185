"""The evidence rule: an object is checked only where the mutant still shows it (hand-built clouds)."""

from __future__ import annotations

import numpy as np

from lidarfuzz.campaign.plan import relations_for, unchecked_relations
from lidarfuzz.operators.base import Relation
from lidarfuzz.operators.registry import get
from lidarfuzz.oracles.relations import Equivariance, Pair, Preservation
from lidarfuzz.oracles.relations.evidence import CROWDED, LOST, EvidenceConfig, object_evidence
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

BOX = np.array([[10.0, 0.0, 0.0, 4.0, 2.0, 2.0, 0.0]])  # a 4 x 2 x 2 m box centred 10 m ahead


def car_points() -> np.ndarray:
    """100 points on a 10 x 10 grid of the box's near face and top, inside the box, 0.3 m apart."""
    u, v = np.meshgrid(np.linspace(-1.5, 1.5, 10), np.linspace(-0.9, 0.9, 10))
    return np.column_stack([10.0 + u.ravel(), v.ravel(), np.linspace(-0.8, 0.8, 100), np.zeros(100)])


def scene(points: np.ndarray) -> Scene:
    return Scene(PointCloud(points.astype(np.float32)))


def car(scores: float = 0.9) -> Boxes3D:
    return Boxes3D.from_array(BOX, ["Car"], scores=[scores])


def evidence(follow: np.ndarray, **cfg: float) -> tuple[int, int, int]:
    e = object_evidence(scene(car_points()), BOX, scene(follow), BOX, EvidenceConfig(**cfg))[0]
    return e.before, e.kept, e.added


def test_points_kept_deleted_and_added_are_counted() -> None:
    pts = car_points()
    assert evidence(pts) == (100, 100, 0)
    assert evidence(pts[:40]) == (100, 40, 0)  # 60 deleted
    # 7 points 0.3 m beyond the box's far side (x = 12.3): inside the 0.5 m neighbourhood, so added
    extra = np.column_stack([np.full(7, 12.3), np.linspace(-0.5, 0.5, 7), np.zeros(7), np.zeros(7)])
    assert evidence(np.vstack([pts, extra])) == (100, 100, 7)
    # the same 7 points 0.8 m beyond it are outside the neighbourhood
    extra[:, 0] = 12.8
    assert evidence(np.vstack([pts, extra])) == (100, 100, 0)
    # jitter below same_point_m (0.1 m) keeps a point the same point
    assert evidence(pts + np.array([0.05, 0.0, 0.0, 0.0])) == (100, 100, 0)


def test_a_detection_whose_points_the_mutant_deleted_is_not_a_violation() -> None:
    src, lost = scene(car_points()), scene(car_points()[:40])
    out = Preservation()(Pair(src, lost, car(), Boxes3D.empty(), Relation.INVARIANT, basis="fog is harmless"))
    assert out.holds and not out.violations
    assert dict(out.skipped) == {LOST: 1}
    assert out.basis.startswith("fog is harmless; objects checked where the mutant keeps at least 50%")


def test_a_crowded_detection_is_not_checked_but_a_whole_one_is() -> None:
    pts = car_points()
    extra = np.column_stack([np.full(11, 12.3), np.linspace(-0.5, 0.5, 11), np.zeros(11), np.zeros(11)])
    out = Preservation()(Pair(scene(pts), scene(np.vstack([pts, extra])), car(), Boxes3D.empty(), Relation.INVARIANT))
    assert out.holds and dict(out.skipped) == {CROWDED: 1}  # 11 added > 10 % of 100
    out = Preservation()(Pair(scene(pts), scene(pts), car(), Boxes3D.empty(), Relation.INVARIANT))
    assert not out.holds and not out.skipped
    (violation,) = out.violations
    assert dict(violation.evidence) == {"points_before": 100, "points_kept": 100, "points_added": 0, "best_iou": 0.0}
    assert "it kept 100 of 100 points, 0 added around it" in violation.message


def test_evidence_follows_a_mirroring_transform() -> None:
    """global_flip mirrors y: the mirrored car keeps all its points when compared through T."""
    flip = np.diag([1.0, -1.0, 1.0, 1.0])
    pts = car_points()
    pts[:, 1] += 0.05  # an asymmetric cloud, so that a mirror is not the identity in the box's frame
    mirrored = pts * np.array([1.0, -1.0, 1.0, 1.0])
    box_mirrored = BOX * np.array([1.0, -1.0, 1.0, 1.0, 1.0, 1.0, -1.0])
    out = Equivariance()(Pair(scene(pts), scene(mirrored), car(), Boxes3D.empty(), Relation.EQUIVARIANT,
                              transform=flip))
    assert not out.skipped and len(out.violations) == 1  # checked: the mirrored car kept its evidence
    (e,) = object_evidence(scene(pts), BOX, scene(mirrored), box_mirrored, EvidenceConfig(), flip)
    assert (e.before, e.kept, e.added) == (100, 100, 0)


def test_harmlessness_is_read_from_the_severity_table() -> None:
    fog = get("fog")
    assert fog.harmless_up_to == 1
    assert [fog.at_severity(s).harmless() for s in range(1, 6)] == [True, False, False, False, False]
    # visibility 600-900 m is harmless: 700-800 m lies inside it, 100-800 m reaches below 600 m
    assert fog(mor_range=(700.0, 800.0)).harmless() and not fog(mor_range=(100.0, 800.0)).harmless()
    # a height offset of (-0.5, 0.5) m is harmless: anything between, nothing beyond
    shift = get("height_shift")
    assert shift(offset_range=(-0.1, 0.3)).harmless() and not shift(offset_range=(-0.1, 0.6)).harmless()
    assert not get("motion_distortion").at_severity(1).harmless()  # never harmless


def test_a_campaign_checks_harmlessness_relations_only_where_the_operator_is_harmless() -> None:
    fog = get("fog")
    assert [r["name"] for r in relations_for(fog.at_severity(1), "auto")] == ["gt_recall"]
    assert relations_for(fog.at_severity(3), "auto") == []
    (why,) = unchecked_relations(fog.at_severity(3), "auto").values()
    assert why.startswith("fog is meant to be harmless only up to severity 1")
