"""Differential testing: two finished tasks on the same frames and mutants, side by side.

``lidarfuzz compare A B``, a campaign with a ``reference:`` system and ``lidarfuzz report A
--baseline B`` all read :func:`compare_tasks`, which returns one typed
:class:`TaskComparison`:

* **violation rates** per operator × severity × relation (and class, where the violations carry
  one; ``cls == ""`` is the frame-level row): violating / checked frames of each, the difference,
  the p-value of "A's rate is above B's" (:mod:`lidarfuzz.oracles.significance`: one-sided Fisher
  exact test, corrected by Tarone's Bonferroni over the rows that could be significant, α = 0.05)
  and whether it is significant;
* **objects lost** per operator × severity (relation ``objects_lost``): the labelled objects each
  system found on the original and lost on the mutant, counted per object and tested the same
  way. It assumes nothing harmless, so a degrading operator at any severity is compared too;
* **disagreements**: each (mutant, relation) checked on both where one violates and the other
  does not, with the finding that replays it;
* **breakdowns** of recall and AP by range band, class, object size and occlusion, for the
  originals and per operator, so a bug that is the same on original and mutant (a box height
  wrong everywhere, points beyond a range dropped, a size gate) shows where it lives.

Two tasks are comparable when they ran the same data set, frames, seed, trials and operator
configurations — then their mutants are identical, since a mutant's seed stream depends on the
seed, frame, operator and trial, not on the system — and every mutant's params agree (checked:
tasks created by versions with different seed streams are refused).

The breakdown rule (:data:`BREAKDOWN_RULE`): for a group (say the 20–40 m band) the ground truth
outside it becomes don't-care — ignored at every KITTI difficulty, so a detection matching such
an object is neither a true nor a false positive — and detections are kept where their own box
falls in the group (range band by centre distance, size by footprint); for occlusion, an
attribute of the ground truth alone, every detection is kept (a false positive with no object
counts against every occlusion level). AP is the exact KITTI evaluation
(:func:`lidarfuzz.oracles.kitti_eval.evaluate_kitti`) at the hard difficulty (the one that
counts occlusion levels 0–2), AP|R40, BEV and 3D, the mean over the classes with objects in the
group; recall is the share of the group's objects (Car, Pedestrian, Cyclist) in the camera's view
that a detection of their class overlaps with BEV IoU at least 0.5 (Car) or 0.25 (Pedestrian,
Cyclist). A group whose AP is undefined (no object counted at hard: KITTI ignores objects under
25 px in the image, so a 1.5 m car beyond about 43 m) has AP NaN, not 0; its recall still counts.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field
from sqlalchemy import select

from lidarfuzz.campaign.lifecycle import get_task
from lidarfuzz.campaign.plan import ORIGINAL, subtask_label
from lidarfuzz.oracles.kitti_eval import CLASSES, LOOSE_OVERLAPS, KittiEvalResult, KittiFrame, evaluate_kitti
from lidarfuzz.oracles.matching import RANGE_BINS, ground_range, match_boxes, range_bin_labels
from lidarfuzz.oracles.robustness import RelationRecord, violation_rates
from lidarfuzz.oracles.significance import ALPHA, CORRECTION_NAME, TEST_NAME, compare_many
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.store.contracts import Contract, Number, OutcomeRecord
from lidarfuzz.store.errors import ConflictError
from lidarfuzz.store.models import Finding, FrameResult, Status, Subtask, Task
from lidarfuzz.store.store import Store

#: Footprint (length × width, m²) bounds of the size groups: pedestrians and cyclists are small,
#: most cars medium, large cars and vans large.
SIZE_BOUNDS: tuple[tuple[str, float, float], ...] = (("small", 0.0, 2.0), ("medium", 2.0, 8.0),
                                                     ("large", 8.0, math.inf))
#: KITTI's ``occluded`` field: 0 fully visible, 1 partly, 2 largely; 3 (and -1) unknown.
OCCLUSION_GROUPS: tuple[tuple[str, tuple[int, ...]], ...] = (("0 visible", (0,)), ("1 partly", (1,)),
                                                             ("2 largely", (2,)), ("unknown", (3, -1)))
#: Difficulty and interpolation of the breakdowns' AP.
BREAKDOWN_DIFFICULTY = "hard"
BREAKDOWN_POINTS = "R40"
#: BEV IoU a detection needs to recall an object, per class.
RECALL_IOU: dict[str, float] = dict(LOOSE_OVERLAPS["bev"])
BREAKDOWN_RULE = (
    "ground truth outside a group is don't-care (ignored at every difficulty: a detection matching it is neither "
    "true nor false positive); detections are kept where their own box is in the group (range band: centre "
    "distance in the ground plane; size: footprint l x w, small < 2 m², medium 2-8 m², large >= 8 m²) and, for "
    "occlusion (a ground-truth attribute), everywhere; AP: exact KITTI evaluation, hard, AP|R40, mean over the "
    "classes with objects in the group; recall: objects in the camera's view overlapped by a detection of their "
    "class with BEV IoU >= 0.5 (Car) / 0.25 (Pedestrian, Cyclist)")
#: How many disagreeing units a comparison lists (all are counted).
MAX_DISAGREEMENTS = 500

Dimension = Literal["range", "class", "size", "occlusion"]


# -- the typed result -------------------------------------------------------------------------
class ComparisonRow(Contract):
    """A's and B's violation rates of one operator × severity × relation (× class) and the test.

    ``cls`` is ``""`` for the frame-level row (any violation on the frame); rates, p-values and
    the difference are NaN (``null`` in JSON) where a side checked nothing.
    """

    label: str
    operator: str
    severity: int
    relation: str
    cls: str = ""
    violated_a: int
    checked_a: int
    violated_b: int
    checked_b: int
    rate_a: Number = math.nan
    rate_b: Number = math.nan
    difference: Number = math.nan
    p_value: Number = math.nan
    p_adjusted: Number = math.nan
    significant: bool = False


class Disagreement(Contract):
    """A mutant (or original) and relation checked on both where exactly one violated it."""

    label: str
    operator: str
    severity: int
    relation: str
    frame_id: str
    trial: int = 0
    violated_by: Literal["A", "B"]
    classes: list[str] = Field(default_factory=list)
    finding: int | None = None
    replay: str = ""


class BreakdownRow(Contract):
    """Recall and AP of A and B on one group of objects (a range band, class, size or occlusion level)
    for the originals (``scope == "original"``) or one operator's mutants (all its severities)."""

    scope: str
    dimension: Dimension
    group: str
    objects: int
    recalled_a: int
    recalled_b: int
    recall_a: Number = math.nan
    recall_b: Number = math.nan
    ap_bev_a: Number = math.nan
    ap_bev_b: Number = math.nan
    ap_3d_a: Number = math.nan
    ap_3d_b: Number = math.nan


class SystemRef(Contract):
    task: int
    name: str
    model: str
    fingerprint: str


class TaskComparison(Contract):
    """Everything ``lidarfuzz compare`` and the reports show about A against B."""

    a: SystemRef
    b: SystemRef
    dataset: str
    frames: int
    trials: int
    seed: int
    test: str = TEST_NAME
    correction: str = CORRECTION_NAME
    alpha: float = ALPHA
    rows: list[ComparisonRow] = Field(default_factory=list)
    disagreements: list[Disagreement] = Field(default_factory=list)
    disagreements_total: int = 0
    disagreements_by_side: dict[str, int] = Field(default_factory=dict)
    breakdown: list[BreakdownRow] = Field(default_factory=list)
    breakdown_rule: str = BREAKDOWN_RULE
    breakdown_ap: str = f"{BREAKDOWN_DIFFICULTY}, AP|{BREAKDOWN_POINTS}"

    @property
    def significant(self) -> list[ComparisonRow]:
        return [r for r in self.rows if r.significant]


# -- comparability ----------------------------------------------------------------------------
def _few(items: Iterable[str], limit: int = 5) -> str:
    listed = sorted(items)
    return ", ".join(listed[:limit]) + (f" and {len(listed) - limit} more" if len(listed) > limit else "")


def _subtask_keys(task: Task) -> dict[tuple[str, int], Subtask]:
    return {(sub.operator_key, sub.severity): sub for sub in task.subtasks}


def check_comparable(a: Task, b: Task) -> None:
    """Raise :class:`ConflictError` (one line, saying what differs) unless A and B ran the same
    data, frames, seed, trials and operator configurations and both are done."""
    for task in (a, b):
        if task.status != Status.DONE:
            raise ConflictError(f"task {task.id} is {task.status.value} ({task.done}/{task.total} units); "
                                f"compare finished tasks", cli=f"lidarfuzz resume {task.id}")
    if a.id == b.id:
        raise ConflictError(f"task {a.id} compared with itself: name two tasks")
    if a.dataset.path != b.dataset.path:
        raise ConflictError(f"not comparable: task {a.id} ran data set {a.dataset.name} ({a.dataset.path}), "
                            f"task {b.id} {b.dataset.name} ({b.dataset.path})")
    frames_a, frames_b = set(a.options.frame_ids), set(b.options.frame_ids)
    if frames_a != frames_b:
        parts = []
        if frames_a - frames_b:
            parts.append(f"only task {a.id} has frames {_few(frames_a - frames_b)}")
        if frames_b - frames_a:
            parts.append(f"only task {b.id} has frames {_few(frames_b - frames_a)}")
        raise ConflictError(f"not comparable: different frames: {'; '.join(parts)}")
    for name, va, vb in (("seed", a.seed, b.seed), ("trials", a.options.trials, b.options.trials),
                         ("kind", a.options.kind, b.options.kind)):
        if va != vb:
            raise ConflictError(f"not comparable: {name} {va} (task {a.id}) against {vb} (task {b.id}); "
                                "the mutants differ")
    subs_a, subs_b = _subtask_keys(a), _subtask_keys(b)
    if set(subs_a) != set(subs_b):
        parts = []
        for task, mine, other in ((a, subs_a, subs_b), (b, subs_b, subs_a)):
            extra = [subtask_label(mine[k].name, mine[k].severity) for k in mine if k not in other]
            if extra:
                parts.append(f"only task {task.id} has {_few(extra)}")
        raise ConflictError(f"not comparable: different operators: {'; '.join(parts)}")


# -- reading the stored units -----------------------------------------------------------------
@dataclass
class _Unit:
    id: int
    frame_id: str
    trial: int
    params: dict[str, Any]
    detections: Boxes3D
    ground_truth: Boxes3D
    failure: Any
    relations: list[OutcomeRecord]


@dataclass
class _Side:
    task: Task
    units: dict[tuple[str, int], dict[tuple[str, int], _Unit]] = field(default_factory=dict)


def _load(store: Store, task: Task) -> _Side:
    side = _Side(task)
    keys = {sub.id: (sub.operator_key, sub.severity) for sub in task.subtasks}
    with store.session() as s:
        rows = s.execute(select(FrameResult.id, FrameResult.subtask_id, FrameResult.frame_id, FrameResult.trial,
                                FrameResult.params, FrameResult.detections, FrameResult.ground_truth,
                                FrameResult.failure, FrameResult.relations).where(
            FrameResult.subtask_id.in_(list(keys))))
        for uid, sid, frame_id, trial, params, detected, truth, failure, relations in rows:
            side.units.setdefault(keys[sid], {})[(frame_id, trial)] = _Unit(
                uid, frame_id, trial, dict(params or {}), detected.boxes(), truth.boxes(), failure,
                list(relations or []))
    return side


def _check_mutants(a: _Side, b: _Side) -> None:
    """The same unit must have had the same mutant on both sides (its params agree)."""
    subs = _subtask_keys(a.task)
    for key, units in a.units.items():
        others = b.units.get(key, {})
        for unit_key, unit in units.items():
            other = others.get(unit_key)
            if other is not None and unit.params and other.params and unit.params != other.params:
                sub = subs[key]
                raise ConflictError(
                    f"not comparable: the mutants differ ({subtask_label(sub.name, sub.severity)}, frame "
                    f"{unit_key[0]}, trial {unit_key[1]}: other params); the tasks were made by lidarfuzz versions "
                    "with different seed streams, run the campaign again")


# -- violation rates and their test ------------------------------------------------------------
def _labels(task: Task) -> dict[tuple[str, int], tuple[str, str, int]]:
    """(operator key, severity) → (label, operator, severity), labels made unique."""
    out: dict[tuple[str, int], tuple[str, str, int]] = {}
    seen: defaultdict[str, int] = defaultdict(int)
    for sub in task.subtasks:
        label = subtask_label(sub.name, sub.severity)
        seen[label] += 1
        if seen[label] > 1:
            label = f"{label} #{sub.operator_key[:6]}"
        out[(sub.operator_key, sub.severity)] = (label, sub.name, sub.severity)
    return out


def _records(side: _Side, labels: dict[tuple[str, int], tuple[str, str, int]]) -> list[RelationRecord]:
    from lidarfuzz.campaign.results import outcome_from_record

    out = []
    for key, units in side.units.items():
        label = labels[key][0]
        for unit in units.values():
            for item in unit.relations:
                # the label stands in for the operator: it tells two configs of one operator apart
                out.append(RelationRecord(item.relation, label, 0, unit.frame_id, outcome_from_record(item)))
    return out


def _rate_table(records: Sequence[RelationRecord]) -> dict[tuple[str, str, str], tuple[int, int]]:
    """(label, relation, class) → (violated, checked); class "" for the frame level."""
    table: dict[tuple[str, str, str], tuple[int, int]] = {}
    for rate in violation_rates(records, by=("operator", "relation")):
        table[(rate.get("operator"), rate.get("relation"), "")] = (rate.violated, rate.checked)
    for rate in violation_rates(records, by=("operator", "relation", "class")):
        table[(rate.get("operator"), rate.get("relation"), str(rate.get("class") or ""))] = (
            rate.violated, rate.checked)
    return table


#: The differential row of every mutant subtask (see :func:`_lost_table`).
OBJECTS_LOST = "objects_lost"


def _lost_table(side: _Side, labels: dict[tuple[str, int], tuple[str, str, int]]) -> dict[tuple[str, str, str],
                                                                                       tuple[int, int]]:
    """(label, ``objects_lost``, "") → (objects lost, objects found): labelled objects each side found
    on the original frame and lost on its mutant (:func:`~lidarfuzz.oracles.relations.detection.objects_lost`).
    No harmlessness is assumed, so this row exists at every severity: a degrading mutation costs both
    systems objects, and the test asks whether it costs A significantly more than B. Counted per
    object, not per frame. Units where either run failed are left out (failures are findings of
    their own)."""
    from lidarfuzz.oracles.relations.detection import objects_lost

    originals = side.units.get((ORIGINAL, 0), {})
    table: dict[tuple[str, str, str], tuple[int, int]] = {}
    for key, units in side.units.items():
        if key[0] == ORIGINAL:
            continue
        lost = found = 0
        for (frame_id, _trial), unit in units.items():
            source = originals.get((frame_id, 0))
            if source is None or source.failure is not None or unit.failure is not None:
                continue
            counts = objects_lost(source.ground_truth, source.detections, unit.ground_truth, unit.detections)
            if counts is not None:
                lost, found = lost + counts[0], found + counts[1]
        if found:
            table[(labels[key][0], OBJECTS_LOST, "")] = (lost, found)
    return table


def comparison_rows(a: _Side, b: _Side, labels: dict[tuple[str, int], tuple[str, str, int]], *,
                    alpha: float = ALPHA) -> list[ComparisonRow]:
    """Every (label, relation, class) either side checked, and every mutant subtask's objects lost
    (:func:`_lost_table`), with the corrected test."""
    table_a = _rate_table(_records(a, labels)) | _lost_table(a, labels)
    table_b = _rate_table(_records(b, labels)) | _lost_table(b, labels)
    by_label = {label: (name, severity) for label, name, severity in labels.values()}
    order = {label: i for i, (label, _, _) in enumerate(labels.values())}
    keys = sorted(set(table_a) | set(table_b), key=lambda k: (order.get(k[0], len(order)), k[1], k[2]))
    counts = [(*table_a.get(k, (0, 0)), *table_b.get(k, (0, 0))) for k in keys]
    tests = compare_many(counts, alpha=alpha)
    rows = []
    for (label, relation, cls), test in zip(keys, tests, strict=True):
        name, severity = by_label.get(label, (label, 0))
        rows.append(ComparisonRow(label=label, operator=name, severity=severity, relation=relation, cls=cls,
                                  violated_a=test.violated_a, checked_a=test.checked_a, violated_b=test.violated_b,
                                  checked_b=test.checked_b, rate_a=test.rate_a, rate_b=test.rate_b,
                                  difference=test.difference, p_value=test.p_value, p_adjusted=test.p_adjusted,
                                  significant=test.significant))
    return rows


def disagreements(store: Store, a: _Side, b: _Side,
                  labels: dict[tuple[str, int], tuple[str, str, int]]) -> tuple[list[Disagreement], dict[str, int]]:
    """Units and relations checked on both where exactly one side violated (the first
    :data:`MAX_DISAGREEMENTS`), and how many there are per side."""
    found: list[tuple[Disagreement, int]] = []
    by_side = {"A": 0, "B": 0}
    for key, units in a.units.items():
        label, name, severity = labels[key]
        others = b.units.get(key, {})
        for unit_key in sorted(units):
            unit, other = units[unit_key], others.get(unit_key)
            if other is None:
                continue
            theirs = {r.relation: r for r in other.relations if r.applicable}
            for mine in unit.relations:
                partner = theirs.get(mine.relation)
                if not mine.applicable or partner is None or mine.holds == partner.holds:
                    continue
                side: Literal["A", "B"] = "B" if mine.holds else "A"
                violating, record = (unit, mine) if side == "A" else (other, partner)
                by_side[side] += 1
                if len(found) < MAX_DISAGREEMENTS:
                    classes = sorted({v.cls for v in record.violations if v.cls})
                    found.append((Disagreement(label=label, operator=name, severity=severity,
                                               relation=mine.relation, frame_id=unit.frame_id, trial=unit.trial,
                                               violated_by=side, classes=classes), violating.id))
    if found:
        with store.session() as s:
            ids = dict(((fr, kind), fid) for fid, fr, kind in s.execute(
                select(Finding.id, Finding.frame_result_id, Finding.kind).where(
                    Finding.frame_result_id.in_([unit_id for _, unit_id in found])).order_by(Finding.id.desc())))
        for row, unit_id in found:
            finding = ids.get((unit_id, row.relation))
            if finding is not None:
                row.finding, row.replay = finding, f"lidarfuzz replay {finding}"
    return [row for row, _ in found], by_side


# -- breakdowns of recall and AP -----------------------------------------------------------------
def _in_view(boxes: Boxes3D, calib: Any) -> Boxes3D:
    from lidarfuzz.campaign.results import in_view

    return in_view(boxes, calib)


def scored_frames(units: Iterable[_Unit], calibration: Callable[[str], Any], operator: Any,
                  unlabelled: Iterable[str]) -> list[KittiFrame]:
    """The frames a subtask's AP is computed on, as :func:`lidarfuzz.campaign.results.evaluate_subtask`
    builds them: detections in the camera's view (and, for a moved scene, where the source had labels);
    no frame for an operator error or an unlabelled frame; a SUT failure counts as no detections."""
    from lidarfuzz.campaign.results import labelled_region
    from lidarfuzz.operators.base import Relation

    skipped = set(unlabelled)
    frames = []
    for unit in units:
        if unit.failure is not None and unit.failure.kind == "operator_error":
            continue  # no mutant
        if unit.frame_id in skipped:
            continue
        calib = calibration(unit.frame_id)
        transform = None
        if operator is not None and operator.relation == Relation.EQUIVARIANT and unit.params:
            transform = operator.transform(operator.parse_params(unit.params))
        if calib is None:
            frames.append(KittiFrame(unit.ground_truth, unit.detections))
        else:
            frames.append(KittiFrame(unit.ground_truth,
                                     labelled_region(_in_view(unit.detections, calib), calib, transform), calib))
    return frames


def _footprint(boxes: Boxes3D) -> NDArray[np.float64]:
    return np.asarray(boxes.sizes[:, 0] * boxes.sizes[:, 1], dtype=np.float64)


Member = Callable[[Boxes3D], NDArray[np.bool_]]


def _in_range(lo: float, hi: float) -> Member:
    return lambda boxes: (ground_range(boxes) >= lo) & (ground_range(boxes) < hi)


def _of_class(cls: str) -> Member:
    return lambda boxes: np.char.lower(boxes.labels.astype(str)) == cls.lower()


def _of_footprint(lo: float, hi: float) -> Member:
    return lambda boxes: (_footprint(boxes) >= lo) & (_footprint(boxes) < hi)


def _occluded(values: tuple[int, ...]) -> Member:
    return lambda boxes: np.isin(boxes.occlusion, values)


def _groups() -> list[tuple[Dimension, str, Member, bool]]:
    """(dimension, group, membership of boxes, whether detections are grouped by it too)."""
    out: list[tuple[Dimension, str, Member, bool]] = []
    for name, (lo, hi) in zip(range_bin_labels(), pairwise(RANGE_BINS), strict=True):
        out.append(("range", f"{name} m", _in_range(lo, hi), True))
    out += [("class", cls, _of_class(cls), False) for cls in CLASSES]
    out += [("size", name, _of_footprint(lo, hi), True) for name, lo, hi in SIZE_BOUNDS]
    out += [("occlusion", name, _occluded(values), False) for name, values in OCCLUSION_GROUPS]
    return out


def _restrict(frame: KittiFrame, member: Member, detections_too: bool) -> KittiFrame:
    """The frame seen through one group: other ground truth ignored at every difficulty (occlusion
    3, above every difficulty's maximum), detections outside the group dropped when ``detections_too``."""
    gt = frame.gt
    inside = member(gt) | ~gt.has_geometry  # DontCare regions stay as they are
    occlusion = np.where(inside, gt.occlusion, 3)
    gt = gt.replace(occlusion=occlusion)
    detections = frame.detections
    if detections_too and len(detections):
        detections = detections.select(member(detections))
    return KittiFrame(gt, detections, frame.calib)


def _recall(frames: Sequence[KittiFrame], member: Member) -> tuple[int, int]:
    """(objects, recalled) of the group: Car, Pedestrian and Cyclist ground truth in it."""
    objects = recalled = 0
    wanted = [c.lower() for c in CLASSES]
    for frame in frames:
        gt = frame.gt
        if len(gt) == 0:
            continue
        mask = member(gt) & gt.has_geometry & np.isin(np.char.lower(gt.labels.astype(str)), wanted)
        # only objects in the camera's view: detections are scored there (a moved scene's others cannot be)
        mask &= np.asarray(frame.calib.in_view(np.nan_to_num(gt.centers)), dtype=bool)
        if not mask.any():
            continue
        chosen = gt.select(mask)
        objects += len(chosen)
        if len(frame.detections):
            matching = match_boxes(chosen, frame.detections, metric="bev", min_iou=RECALL_IOU)
            recalled += len(matching.pairs)
    return objects, recalled


def _mean_ap(result: KittiEvalResult, metric: str, classes: Sequence[str]) -> float:
    counted = [c for c in classes if result.num_objects.get(c, {}).get(BREAKDOWN_DIFFICULTY, 0) > 0]
    if not counted:
        return math.nan
    return float(np.mean([result.get(metric, c, BREAKDOWN_DIFFICULTY, BREAKDOWN_POINTS) for c in counted]))


@dataclass(frozen=True)
class _GroupFigures:
    objects: int
    recalled: int
    ap_bev: float
    ap_3d: float


def group_figures(frames: Sequence[KittiFrame]) -> dict[tuple[Dimension, str], _GroupFigures]:
    """Recall and AP per group of :func:`_groups` on ``frames``."""
    out: dict[tuple[Dimension, str], _GroupFigures] = {}
    if not frames:
        return out
    whole: KittiEvalResult | None = None  # the unrestricted evaluation, for the class groups
    for dimension, group, member, detections_too in _groups():
        objects, recalled = _recall(frames, member)
        if dimension == "class":
            whole = whole or evaluate_kitti(frames)
            result, classes = whole, [group]
        else:
            result, classes = evaluate_kitti([_restrict(f, member, detections_too) for f in frames]), list(CLASSES)
        out[(dimension, group)] = _GroupFigures(objects, recalled, _mean_ap(result, "bev", classes),
                                                _mean_ap(result, "3d", classes))
    return out


def breakdown_rows(store: Store, a: _Side, b: _Side) -> list[BreakdownRow]:
    """Recall and AP per group for the originals and each operator, A beside B."""
    from lidarfuzz.operators.registry import from_spec
    from lidarfuzz.store.inventory import open_registered

    dataset = open_registered(a.task.dataset)
    load_calib = getattr(dataset, "load_calib", None)
    calibs: dict[str, Any] = {}

    def calibration(frame_id: str) -> Any:
        if frame_id not in calibs:
            calibs[frame_id] = load_calib(frame_id) if load_calib else dataset.load(frame_id).calib
        return calibs[frame_id]

    scopes: dict[str, list[tuple[str, int]]] = {}
    for sub in a.task.subtasks:
        scopes.setdefault(sub.name, []).append((sub.operator_key, sub.severity))
    subs = _subtask_keys(a.task)
    figures: list[dict[str, dict[tuple[Dimension, str], _GroupFigures]]] = [{}, {}]
    for index, side in enumerate((a, b)):
        for scope, keys in scopes.items():
            frames: list[KittiFrame] = []
            for key in keys:
                spec = subs[key].operator
                operator = from_spec(spec) if spec else None
                frames += scored_frames(side.units.get(key, {}).values(), calibration, operator,
                                        side.task.options.unlabelled_frames)
            figures[index][scope] = group_figures(frames)
    rows = []
    for scope in scopes:
        fa, fb = figures[0][scope], figures[1][scope]
        for group_key in fa:
            ga, gb = fa[group_key], fb.get(group_key)
            if ga.objects == 0 and (gb is None or gb.objects == 0):
                continue
            rows.append(BreakdownRow(
                scope=scope, dimension=group_key[0], group=group_key[1], objects=ga.objects,
                recalled_a=ga.recalled, recalled_b=gb.recalled if gb else 0,
                recall_a=ga.recalled / ga.objects if ga.objects else math.nan,
                recall_b=gb.recalled / gb.objects if gb and gb.objects else math.nan,
                ap_bev_a=ga.ap_bev, ap_bev_b=gb.ap_bev if gb else math.nan,
                ap_3d_a=ga.ap_3d, ap_3d_b=gb.ap_3d if gb else math.nan))
    return rows


# -- the whole comparison ---------------------------------------------------------------------------
def _system(task: Task) -> SystemRef:
    return SystemRef(task=task.id, name=task.name, model=task.model.name, fingerprint=task.model.fingerprint)


def compare_tasks(store: Store, task_a: int, task_b: int, *, alpha: float = ALPHA,
                  breakdown: bool = True) -> TaskComparison:
    """Compare task A (the system under test) with task B (the reference or baseline).

    Raises:
        NotFoundError: When a task does not exist.
        ConflictError: When the tasks are not finished or not comparable (the message says what differs).
    """
    a, b = get_task(store, task_a), get_task(store, task_b)
    check_comparable(a, b)
    side_a, side_b = _load(store, a), _load(store, b)
    _check_mutants(side_a, side_b)
    labels = _labels(a)
    found, by_side = disagreements(store, side_a, side_b, labels)
    return TaskComparison(
        a=_system(a), b=_system(b), dataset=a.dataset.name, frames=len(a.options.frame_ids),
        trials=a.options.trials, seed=a.seed, alpha=alpha,
        rows=comparison_rows(side_a, side_b, labels, alpha=alpha), disagreements=found,
        disagreements_total=sum(by_side.values()), disagreements_by_side=by_side,
        breakdown=breakdown_rows(store, side_a, side_b) if breakdown else [])


def references_of(store: Store, task_id: int) -> list[int]:
    """The reference tasks a campaign created beside task ``task_id`` (none for most tasks)."""
    return list(get_task(store, task_id).options.references)


__all__ = ["BREAKDOWN_RULE", "BreakdownRow", "ComparisonRow", "Disagreement", "SystemRef", "TaskComparison",
           "breakdown_rows", "check_comparable", "compare_tasks", "comparison_rows", "disagreements",
           "group_figures", "references_of", "scored_frames"]
