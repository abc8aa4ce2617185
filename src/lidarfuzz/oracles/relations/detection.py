"""Metamorphic relations for 3D object detection (outputs are :class:`~lidarfuzz.scene.boxes.Boxes3D`).

* ``preservation`` — Zhou & Sun's MR1, strict form: every object detected in the source
  (inside the drivable-area ROI when the frame has one) is detected in the follow-up,
  same class, IoU at least ``min_iou``. The paper's weaker count form ``|O| <= |O'|`` is
  reported in ``stats`` so results compare with its table.
* ``equivariance`` — detections of ``T(x)`` match ``T`` applied to the detections of ``x``,
  both ways (nothing lost, nothing invented), for operators exposing ``T``.
* ``invariance`` — each source detection is found again with its score dropping by at most
  ``max_score_drop``, its centre moving at most ``max_drift_m`` and its heading turning at
  most ``max_heading_change`` radians.
* ``deeptest_tolerance`` — DeepTest's relaxed relation for regression outputs:
  ``(ŷ_t − y)^2 <= λ · MSE_orig`` with ``MSE_orig`` over the original data set; for boxes the
  regressed value is each ground-truth object's centre, for scalar outputs (e.g. a steering
  angle) the sample's label. Its ε filter and Table 7 are :mod:`lidarfuzz.oracles.deeptest`.
* ``gt_recall`` — objects of the ground truth that the source detections found and the
  follow-up detections lost.

"Detected" means a score of at least ``min_score``; the follow-up side of ``invariance``
accepts any score, so that a drop is measured instead of declared a loss.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from typing import Any, ClassVar, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import ConfigDict, Field

from lidarfuzz.operators.base import Relation as OperatorRelation
from lidarfuzz.oracles.matching import IGNORED_LABELS, Matching, ground_range, match_boxes, overlap_matrix
from lidarfuzz.oracles.relations.base import MetamorphicRelation, Pair, RelationOutcome, Violation
from lidarfuzz.oracles.relations.evidence import Evidence, EvidenceConfig, with_evidence
from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.geometry import box_corners, transform_boxes

DetectionPair = Pair[Any, Boxes3D]


class MatchConfig(EvidenceConfig):
    """How boxes are matched, what counts as detected, and when an object still carries the
    evidence it was found by (:class:`~lidarfuzz.oracles.relations.evidence.EvidenceConfig`)."""

    metric: Literal["bev", "3d"] = Field(default="bev", description="IoU used to match boxes")
    min_iou: float | dict[str, float] = Field(
        default=0.5, description="smallest IoU of a match; a number or {class: IoU, '*': rest}"
    )
    method: Literal["hungarian", "greedy"] = Field(default="hungarian", description="optimal or greedy by score")
    min_score: float = Field(default=0.5, ge=0.0, description="a detection counts as detected from this score")
    score_margin: float = Field(
        default=0.1, ge=0.0,
        description="hysteresis about min_score: only clear detections (score >= min_score + margin) are checked, "
                    "and a follow-up detection scoring down to min_score - margin still counts as found, so a score "
                    "wobbling across the threshold is not a lost or a new object",
    )
    iou_margin: float = Field(
        default=0.05, ge=0.0,
        description="hysteresis about min_iou: a follow-up box still matches its object from min_iou - margin, so "
                    "an overlap wobbling across the threshold (0.50 before, 0.49 after a harmless move) is not a "
                    "lost object; the source side (a detection matched to ground truth) needs min_iou itself",
    )
    roi_only: bool = Field(default=True, description="check only objects inside the frame's drivable-area ROI")
    max_truncation: float | None = Field(
        default=None, ge=0.0, le=1.0,
        description="check only objects the camera's view cuts by at most this share (ground truth: its KITTI "
                    "truncation; a detection: the share of its box corners outside the view); none: all objects",
    )


def _view_share_outside(sample: Any, boxes: Boxes3D) -> NDArray[np.float64]:
    """Share of each box's 8 corners outside the camera's view (0 when the frame has no camera)."""
    calib = getattr(sample, "calib", None)
    if calib is None or len(boxes) == 0:
        return np.zeros(len(boxes))
    corners = box_corners(boxes.as_array()).reshape(-1, 3)
    return 1.0 - calib.in_view(corners).reshape(len(boxes), 8).mean(axis=1)


def _not_truncated(sample: Any, boxes: Boxes3D, index: NDArray[np.int64], limit: float | None,
                   *, labelled: bool = False) -> NDArray[np.int64]:
    """``index`` without the boxes the camera's view cuts by more than ``limit``: ground truth by
    its truncation (when known), detections by their corners."""
    if limit is None or index.size == 0:
        return index
    if labelled and np.isfinite(boxes.truncation[index]).all():
        share = boxes.truncation[index]
    else:
        share = _view_share_outside(sample, boxes.select(index))
    return index[share <= limit]


def _detected(boxes: Boxes3D, min_score: float) -> NDArray[np.int64]:
    keep = ~(boxes.scores < min_score) & ~np.isin(np.char.lower(boxes.labels.astype(str)), list(IGNORED_LABELS))
    return np.flatnonzero(keep)


def _clear(boxes: Boxes3D, cfg: MatchConfig) -> NDArray[np.int64]:
    """Detections clearly above the threshold: the ones a relation holds the follow-up to."""
    return _detected(boxes, cfg.min_score + cfg.score_margin)


def _found(boxes: Boxes3D, cfg: MatchConfig) -> NDArray[np.int64]:
    """Detections that count as finding an object again (the threshold less the margin)."""
    return _detected(boxes, max(cfg.min_score - cfg.score_margin, 0.0))


def _in_roi(sample: Any, boxes: Boxes3D, index: NDArray[np.int64], roi_only: bool) -> NDArray[np.int64]:
    roi = getattr(sample, "roi", None)
    if not roi_only or roi is None or index.size == 0:
        return index
    return index[roi.contains_xy(boxes.centers[index, :2])]


def _lenient(min_iou: float | dict[str, float], margin: float) -> float | dict[str, float]:
    """``min_iou`` lowered by the hysteresis margin (never below zero)."""
    if isinstance(min_iou, dict):
        return {cls: max(float(v) - margin, 0.0) for cls, v in min_iou.items()}
    return max(float(min_iou) - margin, 0.0)


def _match(a: Boxes3D, b: Boxes3D, cfg: MatchConfig, *, lenient: bool = True) -> Matching:
    """Match ``a`` to ``b``: a follow-up side matches from ``min_iou - iou_margin`` (``lenient``),
    a detection to the ground truth it is credited with from ``min_iou``."""
    min_iou = _lenient(cfg.min_iou, cfg.iou_margin) if lenient else cfg.min_iou
    return match_boxes(a, b, metric=cfg.metric, min_iou=min_iou, method=cfg.method)


def _best_iou(a: Boxes3D, b: Boxes3D, metric: str) -> NDArray[np.float64]:
    """For each box of ``a``, its best IoU with a same-class box of ``b`` (0 when none)."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros(len(a))
    overlap = overlap_matrix(a, b, metric)  # type: ignore[arg-type]
    same = np.char.lower(a.labels.astype(str))[:, None] == np.char.lower(b.labels.astype(str))[None, :]
    return np.where(same, overlap, 0.0).max(axis=1)


def _ranges(boxes: Boxes3D) -> NDArray[np.float64]:
    return ground_range(boxes) if len(boxes) else np.zeros(0)


def _checked(boxes: Boxes3D) -> dict[str, int]:
    return dict(Counter(boxes.labels.astype(str).tolist()))


def _points_note(evidence: Evidence | None) -> str:
    if evidence is None:
        return ""
    return f"; it kept {evidence.kept} of {evidence.before} points, {evidence.added} added around it"


def _evidence_of(evidence: list[Evidence], local: int, **more: float) -> dict[str, float]:
    out: dict[str, float] = dict(evidence[local].as_dict()) if evidence else {}
    out.update(more)
    return out


def _missing(
    relation: str,
    src: Boxes3D,
    src_index: NDArray[np.int64],
    follow: Boxes3D,
    unmatched: NDArray[np.int64],
    metric: str,
    kind: str = "missing",
    what: str = "no match in the follow-up",
    evidence: list[Evidence] | None = None,
) -> list[Violation]:
    best = _best_iou(src.select(unmatched), follow, metric)
    ranges = _ranges(src)
    evidence = evidence or []
    out = []
    for k, local in enumerate(unmatched.tolist()):
        i = int(src_index[local])
        cls = str(src.labels[local])
        out.append(
            Violation(
                relation=relation,
                kind=kind,
                cls=cls,
                source_index=i,
                magnitude=float(best[k]),
                measure="iou",
                range_m=float(ranges[local]),
                message=f"{cls} #{i} at {ranges[local]:.1f} m: {what} (best IoU {best[k]:.2f})"
                f"{_points_note(evidence[local] if evidence else None)}",
                evidence=_evidence_of(evidence, local, best_iou=float(best[k])),
            )
        )
    return out


def basis(pair: Pair[Any, Any], cfg: MatchConfig) -> str:
    """The outcome's "checked because …": the operator's harmlessness and the evidence rule."""
    parts = [pair.basis] if pair.basis else []
    if cfg.evidence:
        parts.append(f"objects checked where the mutant keeps at least {cfg.min_kept_share:.0%} of their points "
                     f"and adds at most {cfg.max_added_share:.0%} within {cfg.neighbourhood_m:g} m")
    return "; ".join(parts)


def _keep_evidence(pair: Pair[Any, Any], boxes: Boxes3D, follow_boxes: Boxes3D, index: NDArray[np.int64],
                   cfg: MatchConfig) -> tuple[NDArray[np.int64], Boxes3D, list[Evidence], dict[str, int]]:
    """``index`` (and ``boxes``, its rows) without the objects whose evidence the mutation destroyed,
    the evidence of those kept, and the count left out by reason."""
    keep, evidence, skipped = with_evidence(pair.source, boxes.as_array(), pair.follow, follow_boxes.as_array(), cfg)
    kept_evidence = [e for e, k in zip(evidence, keep.tolist(), strict=True) if k] if evidence else []
    return index[keep], boxes.select(keep), kept_evidence, skipped


class Preservation(MetamorphicRelation[Any, Boxes3D, MatchConfig]):
    """Zhou & Sun MR1: no object detected in the source disappears in the follow-up."""

    name: ClassVar[str] = "preservation"
    assumes_harmless: ClassVar[bool] = True
    assumption: ClassVar[str] = ("the operator is harmless at this setting, and each object keeps its evidence "
                                 "(most of its points, few added around it)")
    description: ClassVar[str] = "every source detection (in the ROI) has a same-class match in the follow-up"
    ConfigModel = MatchConfig
    applies_to: ClassVar[frozenset[OperatorRelation]] = frozenset({OperatorRelation.INVARIANT})

    def check(self, pair: DetectionPair) -> RelationOutcome:
        cfg = self.config
        # the count form counts every source object at the threshold, as the paper does
        n_source = len(_not_truncated(pair.source, pair.source_output, _in_roi(
            pair.source, pair.source_output, _detected(pair.source_output, cfg.min_score), cfg.roi_only),
            cfg.max_truncation))
        fol_roi = _in_roi(pair.follow, pair.follow_output, _detected(pair.follow_output, cfg.min_score), cfg.roi_only)
        src_idx = _in_roi(pair.source, pair.source_output, _clear(pair.source_output, cfg), cfg.roi_only)
        src_idx = _not_truncated(pair.source, pair.source_output, src_idx, cfg.max_truncation)
        fol_idx = _found(pair.follow_output, cfg)
        src = pair.source_output.select(src_idx)
        src_idx, src, evidence, skipped = _keep_evidence(pair, src, src, src_idx, cfg)
        follow = pair.follow_output.select(fol_idx)
        m = _match(src, follow, cfg)
        violations = _missing(self.name, src, src_idx, follow, m.unmatched_a, cfg.metric, evidence=evidence)
        count_holds = n_source <= len(fol_roi)
        return RelationOutcome(
            self.name,
            holds=not violations,
            violations=tuple(violations),
            checked=_checked(src),
            stats={"n_source": n_source, "n_follow": len(fol_roi), "count_holds": float(count_holds)},
            basis=basis(pair, cfg),
            skipped=skipped,
        )


def _moved(boxes: Boxes3D, transform: NDArray[np.float64]) -> Boxes3D:
    """``boxes`` carried by the operator's transform."""
    return Boxes3D.from_array(transform_boxes(boxes.as_array(), transform), boxes.labels, scores=boxes.scores)


class EquivarianceConfig(MatchConfig):
    check_spurious: bool = Field(default=True, description="also report follow-up detections nothing maps to")


class Equivariance(MetamorphicRelation[Any, Boxes3D, EquivarianceConfig]):
    """Detections follow the operator's transform: det(T(x)) = T(det(x)), both ways."""

    name: ClassVar[str] = "equivariance"
    assumes_harmless: ClassVar[bool] = True
    assumption: ClassVar[str] = ("the operator moves the whole scene by T and is harmless at this setting, and "
                                 "each object keeps its evidence in T's frame")
    description: ClassVar[str] = "follow-up detections equal the source detections moved by the operator's transform"
    ConfigModel = EquivarianceConfig
    applies_to: ClassVar[frozenset[OperatorRelation]] = frozenset({OperatorRelation.EQUIVARIANT})

    def applicable(self, pair: DetectionPair) -> bool:
        return super().applicable(pair) and pair.transform is not None

    def check(self, pair: DetectionPair) -> RelationOutcome:
        cfg = self.config
        assert pair.transform is not None
        src_idx = _in_roi(pair.source, pair.source_output, _clear(pair.source_output, cfg), cfg.roi_only)
        src_idx = _not_truncated(pair.source, pair.source_output, src_idx, cfg.max_truncation)
        fol_idx = _found(pair.follow_output, cfg)
        src = pair.source_output.select(src_idx)
        moved = _moved(src, pair.transform)
        if cfg.max_truncation is not None:  # nor objects the move carries to the edge of the view
            keep = _view_share_outside(pair.follow, moved) <= cfg.max_truncation
            src_idx, src, moved = src_idx[keep], src.select(keep), moved.select(keep)
        keep, evidence, skipped = with_evidence(pair.source, src.as_array(), pair.follow, moved.as_array(), cfg,
                                                pair.transform)
        evidence = [e for e, k in zip(evidence, keep.tolist(), strict=True) if k] if evidence else []
        follow = pair.follow_output.select(fol_idx)
        src_idx, src, moved = src_idx[keep], src.select(keep), moved.select(keep)
        m = _match(moved, follow, cfg)
        violations = _missing(
            self.name,
            moved,
            src_idx,
            follow,
            m.unmatched_a,
            cfg.metric,
            what="its transformed box has no match in the follow-up",
            evidence=evidence,
        )
        checked = Counter(_checked(src))
        if cfg.check_spurious:
            # a clear follow-up detection in the ROI that no source detection (any that counts as
            # found, checked or not) accounts for
            fol_idx = _in_roi(pair.follow, pair.follow_output, _clear(pair.follow_output, cfg), cfg.roi_only)
            follow = pair.follow_output.select(fol_idx)
            m = _match(_moved(pair.source_output.select(_found(pair.source_output, cfg)), pair.transform), follow, cfg)
            if cfg.max_truncation is not None:
                outside = _view_share_outside(pair.follow, follow.select(m.unmatched_b))
                m = Matching(m.pairs, m.iou, m.unmatched_a, m.unmatched_b[outside <= cfg.max_truncation])
            best = _best_iou(follow.select(m.unmatched_b), moved, cfg.metric)
            ranges = _ranges(follow)
            for k, local in enumerate(m.unmatched_b.tolist()):
                j = int(fol_idx[local])
                cls = str(follow.labels[local])
                violations.append(
                    Violation(
                        relation=self.name,
                        kind="spurious",
                        cls=cls,
                        follow_index=j,
                        magnitude=float(best[k]),
                        measure="iou",
                        range_m=float(ranges[local]),
                        message=f"{cls} #{j} of the follow-up at {ranges[local]:.1f} m matches no transformed "
                        f"source detection (best IoU {best[k]:.2f})",
                        evidence={"best_iou": float(best[k])},
                    )
                )
            checked.update(_checked(follow.select(m.unmatched_b)))
        return RelationOutcome(
            self.name,
            holds=not violations,
            violations=tuple(violations),
            checked=dict(checked),
            stats={"n_source": len(src_idx), "n_follow": len(fol_idx)},
            basis=basis(pair, cfg),
            skipped=skipped,
        )


class InvarianceConfig(MatchConfig):
    min_iou: float | dict[str, float] = Field(default=0.3, description="smallest IoU to count as the same object")
    max_score_drop: float = Field(default=0.2, ge=0.0, description="largest allowed fall of the score")
    max_drift_m: float = Field(default=0.3, ge=0.0, description="largest allowed move of the centre (metres)")
    max_heading_change: float = Field(default=0.35, ge=0.0, description="largest allowed turn (radians)")


class Invariance(MetamorphicRelation[Any, Boxes3D, InvarianceConfig]):
    """The same objects, within tolerances on score, centre and heading."""

    name: ClassVar[str] = "invariance"
    assumes_harmless: ClassVar[bool] = True
    assumption: ClassVar[str] = ("the operator is harmless at this setting, and each object keeps its "
                                 "evidence")
    description: ClassVar[str] = "source detections found again with bounded score drop, centre drift and turn"
    ConfigModel = InvarianceConfig
    applies_to: ClassVar[frozenset[OperatorRelation]] = frozenset({OperatorRelation.INVARIANT})

    def check(self, pair: DetectionPair) -> RelationOutcome:
        cfg = self.config
        src_idx = _in_roi(pair.source, pair.source_output, _clear(pair.source_output, cfg), cfg.roi_only)
        src_idx = _not_truncated(pair.source, pair.source_output, src_idx, cfg.max_truncation)
        fol_idx = _detected(pair.follow_output, 0.0)
        src = pair.source_output.select(src_idx)
        src_idx, src, evidence, skipped = _keep_evidence(pair, src, src, src_idx, cfg)
        follow = pair.follow_output.select(fol_idx)
        m = _match(src, follow, cfg)
        violations = _missing(self.name, src, src_idx, follow, m.unmatched_a, cfg.metric, evidence=evidence)
        ranges = _ranges(src)
        drift = (
            np.hypot(*(follow.centers[m.pairs[:, 1], :2] - src.centers[m.pairs[:, 0], :2]).T) if len(m.pairs) else []
        )
        for k, (a, b) in enumerate(m.pairs.tolist()):
            i, j, cls, rng = int(src_idx[a]), int(fol_idx[b]), str(src.labels[a]), float(ranges[a])
            drop = float(src.scores[a] - follow.scores[b])
            turn = float(abs(wrap_angle(follow.yaw[b] - src.yaw[a])))
            for kind, value, limit, measure, text in (
                ("score_drop", drop, cfg.max_score_drop, "score", f"score fell by {drop:.2f}"),
                ("drift", float(drift[k]), cfg.max_drift_m, "metres", f"centre moved {drift[k]:.2f} m"),
                ("heading", turn, cfg.max_heading_change, "radians", f"heading turned {turn:.2f} rad"),
            ):
                if value > limit:
                    violations.append(
                        Violation(
                            relation=self.name,
                            kind=kind,
                            cls=cls,
                            source_index=i,
                            follow_index=j,
                            magnitude=value,
                            measure=measure,
                            range_m=rng,
                            message=f"{cls} #{i} at {rng:.1f} m: {text} (limit {limit:g})"
                            f"{_points_note(evidence[a] if evidence else None)}",
                            evidence=_evidence_of(evidence, a, partner_iou=float(m.iou[k]) if len(m.iou) else 0.0),
                        )
                    )
        return RelationOutcome(
            self.name,
            holds=not violations,
            violations=tuple(violations),
            checked=_checked(src),
            stats={"n_source": len(src_idx), "n_matched": len(m.pairs)},
            basis=basis(pair, cfg),
            skipped=skipped,
        )


def gt_correspondence(source_gt: Boxes3D, follow_gt: Boxes3D) -> NDArray[np.int64] | None:
    """For each source ground-truth box, the index of the same object in the follow-up (-1 if it is gone).

    Objects are identified by track id when every box has a distinct one, otherwise by
    position in the list when both lists have the same labels; None when neither works.
    """
    s_ids, f_ids = source_gt.track_ids, follow_gt.track_ids
    if (
        len(s_ids)
        and np.all(s_ids >= 0)
        and len(np.unique(s_ids)) == len(s_ids)
        and len(np.unique(f_ids)) == len(f_ids)
    ):
        lookup = {int(t): k for k, t in enumerate(f_ids.tolist())}
        return np.array([lookup.get(int(t), -1) for t in s_ids.tolist()], dtype=np.int64)
    if len(source_gt) == len(follow_gt) and np.array_equal(source_gt.labels, follow_gt.labels):
        return np.arange(len(source_gt), dtype=np.int64)
    return None


def _gt_matches(dets: Boxes3D, gt: Boxes3D, cfg: MatchConfig, min_score: float | None = None, *,
                lenient: bool = False) -> NDArray[np.int64]:
    """For each ground-truth box, the detection (score >= ``min_score``, the config's by default)
    matched to it, or -1; ``lenient``: from ``min_iou - iou_margin`` (a follow-up finding an
    object again)."""
    idx = _detected(dets, cfg.min_score if min_score is None else min_score)
    if len(idx) == 0:  # nothing detected: every object unmatched
        return np.full(len(gt), -1, dtype=np.int64)
    m = _match(dets.select(idx), gt, cfg, lenient=lenient)
    partner = m.partner_of_b(len(gt))
    return np.where(partner >= 0, idx[np.maximum(partner, 0)], -1)


def objects_lost(source_gt: Boxes3D, source_output: Boxes3D, follow_gt: Boxes3D, follow_output: Boxes3D,
                 cfg: MatchConfig | None = None) -> tuple[int, int] | None:
    """(lost, found): labelled objects the source output found (score >= ``min_score``) and how
    many of them the follow-up output lost, objects followed by track id. No harmlessness is
    assumed: a differential comparison reads it on any mutant, beside a reference system's count
    on the same mutant. None when the two ground truths cannot be paired up.

        >>> gt = Boxes3D.create([[10, 0, -1], [20, 0, -1]], [[4, 2, 1.5]] * 2, [0, 0], ["Car"] * 2,
        ...                     track_ids=[1, 2])
        >>> objects_lost(gt, gt, gt, gt.select([0]))
        (1, 2)
    """
    cfg = cfg or MatchConfig()
    source_gt = source_gt.select(source_gt.has_geometry)
    follow_gt = follow_gt.select(follow_gt.has_geometry)
    corr = gt_correspondence(source_gt, follow_gt)
    if corr is None:
        return None
    found = (_gt_matches(source_output, source_gt, cfg) >= 0) & (corr >= 0)
    again = _gt_matches(follow_output, follow_gt, cfg, lenient=True)
    lost = found & (again[np.maximum(corr, 0)] < 0) if len(follow_gt) else found
    return int(np.count_nonzero(lost)), int(np.count_nonzero(found))


class GroundTruthRecall(MetamorphicRelation[Any, Boxes3D, MatchConfig]):
    """Ground-truth objects the source detections found and the follow-up detections lost."""

    name: ClassVar[str] = "gt_recall"
    assumes_harmless: ClassVar[bool] = True
    assumption: ClassVar[str] = ("the operator is harmless at this setting, and each labelled object keeps its "
                                 "evidence (followed through moves by its track)")
    description: ClassVar[str] = "objects found in the source (matched to ground truth) are still found"
    ConfigModel = MatchConfig

    def applicable(self, pair: DetectionPair) -> bool:
        return (
            super().applicable(pair)
            and len(getattr(pair.source, "boxes", ())) > 0
            and gt_correspondence(pair.source.boxes, pair.follow.boxes) is not None
        )

    def check(self, pair: DetectionPair) -> RelationOutcome:
        cfg = self.config
        src_gt, fol_gt = pair.source.boxes, pair.follow.boxes
        corr = gt_correspondence(src_gt, fol_gt)
        assert corr is not None
        found_src = _gt_matches(pair.source_output, src_gt, cfg, cfg.min_score + cfg.score_margin)
        found_fol = _gt_matches(pair.follow_output, fol_gt, cfg, max(cfg.min_score - cfg.score_margin, 0.0),
                                lenient=True)
        in_roi = _in_roi(pair.source, src_gt, np.arange(len(src_gt)), cfg.roi_only)
        in_roi = _not_truncated(pair.source, src_gt, in_roi, cfg.max_truncation, labelled=True)
        considered = np.zeros(len(src_gt), dtype=bool)
        considered[in_roi] = True
        considered &= (found_src >= 0) & (corr >= 0)
        evidence_of: dict[int, Evidence] = {}
        skipped: dict[str, int] = {}
        candidates = np.flatnonzero(considered)
        if cfg.evidence and candidates.size:
            keep, evidence, skipped = with_evidence(pair.source, src_gt.select(candidates).as_array(), pair.follow,
                                                    fol_gt.select(corr[candidates]).as_array(), cfg)
            considered[candidates[~keep]] = False
            evidence_of = dict(zip(candidates.tolist(), evidence, strict=False))  # none when not judged
        ranges = _ranges(src_gt)
        violations = []
        # a mutant with no labelled object left has nothing to index: its objects are gone from the ground
        # truth (corr < 0), so none was considered, none is expected
        lost = considered & ((found_fol[np.maximum(corr, 0)] < 0) if len(fol_gt) else False)
        best = _best_iou(
            fol_gt.select(corr[lost]),
            pair.follow_output.select(_found(pair.follow_output, cfg)),
            cfg.metric,
        )
        for k, g in enumerate(np.flatnonzero(lost).tolist()):
            cls = str(src_gt.labels[g])
            violations.append(
                Violation(
                    relation=self.name,
                    kind="lost_gt",
                    cls=cls,
                    source_index=int(found_src[g]),
                    gt_index=g,
                    magnitude=float(best[k]),
                    measure="iou",
                    range_m=float(ranges[g]),
                    message=f"ground-truth {cls} #{g} at {ranges[g]:.1f} m was detected in the source, "
                    f"not in the follow-up (best IoU {best[k]:.2f}){_points_note(evidence_of.get(g))}",
                    evidence={**(evidence_of[g].as_dict() if g in evidence_of else {}), "best_iou": float(best[k])},
                )
            )
        n_gt = int(np.count_nonzero(corr >= 0))
        return RelationOutcome(
            self.name,
            holds=not violations,
            violations=tuple(violations),
            checked=_checked(src_gt.select(considered)),
            stats={
                "n_gt": n_gt,
                "n_found_source": int(np.count_nonzero(considered)),
                "n_lost": int(np.count_nonzero(lost)),
            },
            basis=basis(pair, cfg),
            skipped=skipped,
        )


class DeepTestConfig(MatchConfig):
    lambda_: float = Field(default=5.0, gt=0.0, alias="lambda", description="λ: allowed multiple of MSE_orig")
    epsilon: float = Field(default=0.03, ge=0.0, description="ε: keep transformations with |MSE_t − MSE_orig| ≤ ε")
    mse_orig: float | None = Field(
        default=None, ge=0.0, description="MSE_orig of the original data set (a campaign sets it from its originals)"
    )
    new_only: bool = Field(
        default=False,
        description="flag only errors the transformation brought: objects whose error on the original was within "
                    "λ·MSE_orig (DeepTest flags every object over the limit, also those already over it on the "
                    "original, which then count against every transformation)",
    )

    model_config = ConfigDict(frozen=True, extra="forbid", populate_by_name=True)


def centre_squared_errors(truth: Boxes3D, output: Boxes3D, cfg: MatchConfig) -> NDArray[np.float64]:
    """Squared centre error (m²) of each ground-truth object ``output`` found (matched as
    :func:`deeptest_tolerance <DeepTestTolerance>` matches them); objects not found are left out."""
    errors = _object_errors(truth.select(truth.has_geometry), output, cfg)
    return errors[np.isfinite(errors)]


def _object_errors(gt: Boxes3D, output: Boxes3D, cfg: MatchConfig) -> NDArray[np.float64]:
    """Squared centre error of each object of ``gt`` against its matched detection; NaN when not found."""
    found = _gt_matches(output, gt, cfg)
    errors = np.full(len(gt), np.nan)
    ok = found >= 0
    errors[ok] = np.sum((output.centers[found[ok]] - gt.centers[ok]) ** 2, axis=1)
    return errors


def _squared_errors(sample: Any, output: Any, cfg: MatchConfig) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Squared error of each label of one sample and the label's index: for boxes each
    ground-truth object's centre against its matched detection's (NaN for an object not found:
    losing it is ``gt_recall``'s business), for scalar outputs the sample's ``label``."""
    if isinstance(output, Boxes3D):
        index = np.flatnonzero(sample.boxes.has_geometry)
        return _object_errors(sample.boxes.select(index), output, cfg), index
    label = getattr(sample, "label", None)
    if label is None:
        label = getattr(sample, "metadata", {}).get("label")
    if label is None:
        raise ValueError(
            "deeptest_tolerance on scalar outputs needs the sample's label (sample.label or metadata['label'])"
        )
    y = np.atleast_2d(np.asarray(label, dtype=np.float64))
    return np.sum((np.atleast_2d(np.asarray(output, dtype=np.float64)) - y) ** 2, axis=1), np.arange(len(y))


def _source_errors(pair: Pair[Any, Any], src_err: NDArray[np.float64], fol_index: NDArray[np.int64],
                   cfg: MatchConfig) -> NDArray[np.float64] | None:
    """The source's error of each follow-up label (NaN where the source did not find it); None
    when the two samples' labels cannot be paired up."""
    if not isinstance(pair.follow_output, Boxes3D):
        return src_err if len(src_err) == len(fol_index) else None
    corr = gt_correspondence(pair.follow.boxes, pair.source.boxes)  # follow label -> source label
    if corr is None:
        return None
    by_label = np.full(len(pair.source.boxes), np.nan)
    by_label[np.flatnonzero(pair.source.boxes.has_geometry)] = src_err
    mapped = corr[fol_index]
    return np.where(mapped >= 0, by_label[np.maximum(mapped, 0)], np.nan)


class DeepTestTolerance(MetamorphicRelation[Any, Any, DeepTestConfig]):
    """DeepTest's relaxed relation (Eq. 2): the follow-up's squared error is within λ times MSE_orig.

    ``MSE_orig`` is the mean squared error of the system on the original data set (for boxes:
    over every ground-truth object the originals' detections matched, :meth:`mse_orig_of`). A
    campaign computes it from its originals before any mutant is checked and passes it as the
    config's ``mse_orig`` (so a finding replays with the same limit); ``pair.reference["mse_orig"]``
    overrides it. Without either, the source sample's own error stands in, and the outcome says so
    (``stats["mse_orig_from"] == "frame"``). DeepTest's ε filter (Eq. 3) — count violations only
    for transformations whose MSE stays within ε of ``MSE_orig`` — judges a whole transformation,
    so it is applied when a subtask is summarised (:meth:`keeps_transformation`,
    :mod:`lidarfuzz.oracles.deeptest`); ``stats`` keep each object's squared error for it.
    """

    name: ClassVar[str] = "deeptest_tolerance"
    assumes_harmless: ClassVar[bool] = True
    assumption: ClassVar[str] = ("the transformation is harmless at this setting, so the error may grow at most λ "
                                 "times the data set's")
    description: ClassVar[str] = "(y_follow - y)^2 <= lambda * MSE_orig, DeepTest's relaxed relation"
    ConfigModel = DeepTestConfig
    applies_to: ClassVar[frozenset[OperatorRelation]] = frozenset({OperatorRelation.INVARIANT})

    def check(self, pair: Pair[Any, Any]) -> RelationOutcome:
        cfg = self.config
        src_err, _ = _squared_errors(pair.source, pair.source_output, cfg)
        fol_err, fol_index = _squared_errors(pair.follow, pair.follow_output, cfg)
        src_sq, fol_found = src_err[np.isfinite(src_err)], np.isfinite(fol_err)
        fol_sq = fol_err[fol_found]
        if "mse_orig" in pair.reference:
            mse_orig, origin = float(pair.reference["mse_orig"]), "data set"
        elif cfg.mse_orig is not None:
            mse_orig, origin = float(cfg.mse_orig), "data set"
        else:
            mse_orig, origin = (float(src_sq.mean()) if src_sq.size else float("nan")), "frame"
        limit = cfg.lambda_ * mse_orig
        over = fol_found & (np.nan_to_num(fol_err) > limit) if np.isfinite(limit) else np.zeros(len(fol_err), bool)
        stats: dict[str, Any] = {}
        if over.any():  # how many were over the limit (or not found) on the original already
            before = _source_errors(pair, src_err, fol_index, cfg)
            if before is None:
                stats["already_over_on_source"] = None  # the labels could not be paired: not known
            else:
                already = over & ~(before <= limit)
                stats["already_over_on_source"] = int(np.count_nonzero(already))
                if cfg.new_only:
                    over &= ~already
        violations = []
        for k in np.flatnonzero(over).tolist():
            violations.append(
                Violation(
                    relation=self.name,
                    kind="regression",
                    magnitude=float(fol_err[k]),
                    measure="squared error",
                    gt_index=int(fol_index[k]),
                    message=f"squared error {fol_err[k]:.3g} exceeds λ·MSE_orig = {cfg.lambda_:g} × "
                    f"{mse_orig:.3g} = {limit:.3g}" + (" (MSE_orig of this frame alone)" if origin == "frame"
                                                       else ""),
                )
            )
        return RelationOutcome(
            self.name,
            holds=not violations,
            violations=tuple(violations),
            checked={"": int(fol_sq.size)},
            stats={
                "mse_orig": mse_orig,
                "mse_orig_from": origin,
                "lambda": cfg.lambda_,
                "epsilon": cfg.epsilon,
                "sum_squared_error": float(fol_sq.sum()),
                "n": int(fol_sq.size),
                "squared_errors": [float(e) for e in fol_sq],
                "source_squared_errors": [float(e) for e in src_sq],
                **stats,
            },
        )

    def mse_orig_of(self, frames: Iterable[tuple[Boxes3D, Boxes3D]]) -> tuple[float, int]:
        """MSE_orig over a data set's originals, given as (ground truth, the system's output) per
        frame: the mean squared centre error over every object found, and how many there were
        (NaN, 0 when none was found).

        Example:
            >>> gt = Boxes3D.create([[10.0, 0, 0], [20.0, 0, 0]], [[4, 2, 1.5]] * 2, [0.0, 0.0], ["Car"] * 2)
            >>> out = Boxes3D.create([[10.1, 0, 0], [20.3, 0, 0]], [[4, 2, 1.5]] * 2, [0.0, 0.0], ["Car"] * 2,
            ...                      scores=[0.9, 0.9])
            >>> mse, n = DeepTestTolerance().mse_orig_of([(gt, out)])
            >>> round(mse, 3), n  # (0.01 + 0.09) / 2
            (0.05, 2)
        """
        errors = [centre_squared_errors(truth, output, self.config) for truth, output in frames]
        every = np.concatenate(errors) if errors else np.zeros(0)
        return (float(every.mean()), int(every.size)) if every.size else (float("nan"), 0)

    def keeps_transformation(self, mse_transformation: float, mse_orig: float) -> bool:
        """DeepTest's Equation 3: ``|MSE_(trans, param) − MSE_orig| <= ε``."""
        return abs(mse_transformation - mse_orig) <= self.config.epsilon
