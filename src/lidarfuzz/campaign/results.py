"""A task's numbers: per-subtask KITTI AP and relation figures, and the task's summary.

:func:`evaluate_subtask` runs when a subtask completes (its AP against the mutants' own ground
truth — boxes move with their objects — and its violation counts); :func:`summarise` runs when
the task completes and builds the one JSON-able structure every report reads: the thesis's AP
table, ΔAP per operator × severity, Robo3D's RR (and CE against a baseline task), violation
rates per relation, operator, severity and class, the count form of MR1, DeepTest's Table 7
(erroneous mutants per λ and ε, :func:`deeptest_table`), and the findings.

Detections are evaluated as KITTI results are: boxes outside the camera's view are left out,
since labels exist only there. A frame where the system failed counts as one with no
detections (every object missed); a frame with a data fault (it could not be read) is left out
and counted apart (``tool_errors["data_error"]``), as lidarfuzz's own errors are. Frames are
evaluated in (frame, trial) order, whatever order their results were stored in, so sums over them
(AOS, DeepTest's MSE) come out to the same last digit on every run.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import func, select

from lidarfuzz.campaign.lifecycle import get_task
from lidarfuzz.campaign.plan import ORIGINAL, subtask_label
from lidarfuzz.campaign.work import DATA_FAULT, NOT_THE_SYSTEM
from lidarfuzz.operators.base import Relation
from lidarfuzz.oracles.kitti_eval import CLASSES, DIFFICULTIES, KittiEvalResult, KittiFrame, evaluate_kitti
from lidarfuzz.oracles.relations.base import RelationOutcome, Violation
from lidarfuzz.oracles.robustness import RelationRecord, count_form_rates, robustness_summary, violation_rates
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.store.contracts import (
    APExcluded,
    APRecord,
    DatasetRef,
    DeepTestErrors,
    DeepTestRow,
    DeepTestTable,
    DeltaRow,
    FindingsSummary,
    ModelRef,
    OutcomeRecord,
    RateRow,
    RobustnessRecord,
    SubtaskResults,
    SubtaskSummary,
    TaskInfo,
    TaskSummary,
    TopFinding,
    ViolationTables,
)
from lidarfuzz.store.models import Finding, FrameResult, Subtask
from lidarfuzz.store.store import Store

AP_METRICS: tuple[str, ...] = ("bbox", "bev", "3d")
TOP_FINDINGS = 24


def outcome_from_record(record: OutcomeRecord) -> RelationOutcome:
    """A stored relation outcome as the oracles' :class:`RelationOutcome`."""
    violations = tuple(Violation(**v.model_dump()) for v in record.violations)
    return RelationOutcome(record.relation, record.holds, violations, dict(record.checked), dict(record.stats),
                           record.applicable)


def in_view(detections: Boxes3D, calib: Any) -> Boxes3D:
    if len(detections) == 0 or calib is None:
        return detections
    return detections.select(calib.in_view(detections.centers))


def labelled_region(detections: Boxes3D, calib: Any, transform: NDArray[np.float64] | None) -> Boxes3D:
    """The detections of a moved scene that lie where the source frame had labels.

    Labels cover only the camera's view (KITTI's convention). When an equivariant operator moves
    the scene (``transform``: source → mutant), part of the view shows what was unlabelled in
    the source (behind or beside the car); a detection there has nothing to be matched against and
    would count as a false positive, so it is left out — as KITTI leaves out DontCare regions.
    """
    if transform is None or calib is None or len(detections) == 0:
        return detections
    centres = np.c_[detections.centers, np.ones(len(detections))] @ np.linalg.inv(transform).T
    return detections.select(calib.in_view(centres[:, :3]))


def evaluate_subtask(rows: Sequence[Any], calibration: Callable[[str], Any], *,
                     operator: Any = None, unlabelled: Iterable[str] = ()) -> SubtaskResults:
    """Figures of one complete subtask from its frame results (rows of frame id, detections and
    ground truth (:class:`~lidarfuzz.store.boxes.StoredBoxes`), failure, relations, seconds, cached
    and, when ``operator`` is given, the params of its mutant).

    With an operator that moves the scene (an equivariant one with a transform), detections in the
    part of the view the source had no labels for are not scored (:func:`labelled_region`), and
    when no labelled object is left in view at all the subtask has no AP (``None``: not 0).

    Rows are taken in frame order (stably: pass them ordered by frame and trial, as the store's
    query does), so the figures do not depend on the order results were stored in. A frame with a
    data fault is counted in ``tool_errors`` and left out of everything else.

    Frames in ``unlabelled`` (no label file in a labelled data set, run with ``--allow-unlabelled``)
    are left out of AP — with no ground truth every detection there would count as a false
    positive — and counted in ``ap_excluded``; their relations and failures still count.

    When the mutants' params name a region (``outside_roi_scatter``: the frame's map, a data-set
    map, the estimated drivable area or the boxes), ``regions`` says on how many frames each was used.
    """
    skipped = set(unlabelled)
    excluded: list[str] = []
    frames, records = [], []
    labelled = moved = False
    failures = cached = 0
    tool_errors: dict[str, int] = defaultdict(int)
    seconds = 0.0
    regions: dict[str, set[str]] = defaultdict(set)
    for frame_id, detected, truth, failure, relations, secs, was_cached, *more in sorted(rows, key=lambda r: r[0]):
        if failure is not None and failure.kind in NOT_THE_SYSTEM:
            tool_errors[failure.kind] += 1
        else:
            failures += int(failure is not None)
        if failure is not None and failure.kind == DATA_FAULT:
            continue  # nothing was read: no output, no ground truth
        if more and isinstance(more[0], Mapping) and more[0].get("region"):
            regions[str(more[0]["region"])].add(frame_id)
        cached += int(bool(was_cached))
        seconds += float(secs or 0.0)
        for item in relations or []:
            records.append(RelationRecord(item.relation, "", 0, frame_id, outcome_from_record(item)))
        if failure is not None and failure.kind == "operator_error":
            continue  # no mutant: nothing to evaluate
        if frame_id in skipped:
            excluded.append(frame_id)
            continue
        gt = truth.boxes()
        calib = calibration(frame_id)
        transform = None
        # only equivariant operators move the scene; a frame the SUT crashed on may have no params
        if operator is not None and operator.relation == Relation.EQUIVARIANT and more and more[0]:
            transform = operator.transform(operator.parse_params(more[0]))
        if transform is not None and calib is not None:
            moved = True
            real = gt.centers[np.isfinite(gt.centers[:, 0])]  # DontCare regions have no geometry
            labelled = labelled or (len(real) > 0 and bool(calib.in_view(real).any()))
        else:
            labelled = labelled or len(gt) > 0
        detections = detected.boxes()  # none when the SUT failed
        frame = KittiFrame(gt, labelled_region(in_view(detections, calib), calib, transform), calib) \
            if calib is not None else KittiFrame(gt, detections)
        frames.append(frame)
    def rates(rows: Iterable[Any]) -> list[RateRow]:
        return [RateRow.model_validate(r.to_dict()) for r in rows]

    out = SubtaskResults(frames=len(rows), failures=failures, tool_errors=dict(tool_errors), cached=cached,
                         sut_seconds=seconds)
    out.ap = APRecord.of(evaluate_kitti(frames)) if labelled and frames else None
    if out.ap is None and moved and frames:
        out.ap_note = "no AP: the operator moved every labelled object out of the camera's view"
    if excluded:
        unique = sorted(set(excluded))
        out.ap_excluded = APExcluded(frames=len(unique), examples=unique[:5],
                                     reason="no label file (unlabelled; run with --allow-unlabelled)")
    out.violations = rates(violation_rates(records, by=("relation", "class")))
    out.violations_per_object = rates(violation_rates(records, by=("relation", "class"), per="object"))
    out.violations_total = rates(violation_rates(records, by=("relation",)))
    out.count_form = rates(count_form_rates(records, by=("severity",)))
    if regions:
        out.regions = {name: len(ids) for name, ids in sorted(regions.items())}
    out.deeptest = deeptest_errors(records)
    return out


#: The relations whose outcomes carry DeepTest's per-mutant errors: on detections' centres and on steering.
DEEPTEST_RELATIONS = ("deeptest_tolerance", "deeptest_steering")


def deeptest_errors(records: Iterable[RelationRecord]) -> DeepTestErrors | None:
    """DeepTest's figures of one subtask (its MSE, Eq. 3 at the relation's ε, erroneous mutants per
    λ of :data:`~lidarfuzz.oracles.deeptest.LAMBDAS`); None when it has no ``deeptest_tolerance``
    outcome with per-object errors (nor, for a steering system, ``deeptest_steering``)."""
    from lidarfuzz.oracles.deeptest import transformation_errors

    found = transformation_errors((r.outcome.stats, r.outcome.holds) for r in records
                                  if r.relation in DEEPTEST_RELATIONS and r.outcome.applicable)
    return None if found is None else DeepTestErrors.model_validate(found.to_dict())


def deeptest_table(subtasks: Sequence[SubtaskSummary]) -> DeepTestTable | None:
    """DeepTest's Table 7 over a task's subtasks (each one transformation); None without any."""
    from lidarfuzz.oracles.deeptest import TransformationErrors, erroneous_table

    entries = [e for e in subtasks if e.deeptest is not None]
    if not entries:
        return None
    errors = []
    for entry in entries:
        d = entry.deeptest
        assert d is not None
        errors.append(TransformationErrors(d.mse_orig, d.mse_orig_from, d.mse, d.objects, d.mutants, d.violated,
                                           tuple(d.lambdas), tuple(d.erroneous), d.configured_lambda,
                                           d.configured_epsilon, filtered=d.filtered))
    table = erroneous_table(errors)
    rows = []
    for entry, e in zip(entries, errors, strict=True):
        rows.append(DeepTestRow(label=entry.label, operator=entry.operator, severity=entry.severity, mse=e.mse,
                                difference=e.mse - e.mse_orig, objects=e.objects, mutants=e.mutants,
                                violated=e.violated, kept=e.kept, filtered=e.filtered))
    first = errors[0]
    return DeepTestTable.model_validate({**table.to_dict(), "configured_lambda": first.configured_lambda,
                                         "configured_epsilon": first.configured_epsilon,
                                         "transformations": [r.dump() for r in rows]})


def ap_result(record: APRecord | None) -> KittiEvalResult | None:
    """A stored AP record as a :class:`KittiEvalResult` (None: no AP)."""
    if record is None:
        return None
    return KittiEvalResult.from_dict(record.model_dump())


def ap_warnings(subtasks: Sequence[SubtaskSummary]) -> list[str]:
    """Why a task's AP may not mean what it seems (single frame, few objects): the original's
    warnings, then those a mutant adds for a class the original had enough of (an operator that
    removes objects or moves them out of view), prefixed by its label."""
    notes: list[str] = []
    warned: set[str] = set()  # the original's classes (and "AP from a single frame")
    for index, entry in enumerate(subtasks):
        result = ap_result(entry.ap)
        if result is None:
            continue
        for note in result.sample_warnings():
            subject = note.split(":", 1)[0]
            if index == 0:
                warned.add(subject)
                notes.append(note)
            elif subject not in warned:
                notes.append(f"{entry.label}: {note}")
    return notes


def _sum_rates(rows: Iterable[tuple[dict[str, Any], RateRow]], keys: Sequence[str]) -> list[RateRow]:
    """Rates summed over the groups ``keys`` (fields of the rows, or of their context)."""
    checked: dict[tuple[Any, ...], int] = defaultdict(int)
    violated: dict[tuple[Any, ...], int] = defaultdict(int)
    for context, rate in rows:
        merged = {**rate.model_dump(by_alias=True), **context}
        key = tuple(merged.get(k) for k in keys)
        checked[key] += rate.checked
        violated[key] += rate.violated
    out = []
    for key in sorted(checked, key=lambda k: tuple(str(v) for v in k)):
        n = checked[key]
        out.append(RateRow.model_validate({**dict(zip(keys, key, strict=True)), "checked": n,
                                           "violated": violated[key], "rate": violated[key] / n if n else None}))
    return out


def summarise(store: Store, task_id: int, *, baseline: int | None = None) -> TaskSummary:
    """The task's report data; ``baseline``: a task of another system on the same campaign, for
    Robo3D's corruption error."""
    from lidarfuzz.operators.registry import get as get_operator

    task = get_task(store, task_id)
    subtasks: list[SubtaskSummary] = []
    clean: KittiEvalResult | None = None
    corrupted: dict[tuple[str, int], KittiEvalResult] = {}
    for sub in task.subtasks:
        family = relation_kind = ""
        if sub.name != ORIGINAL:
            try:
                cls = get_operator(sub.name)
                family, relation_kind = cls.family, cls.relation.value
            except Exception:  # an operator plugin no longer installed: the stored figures still stand
                pass
        entry = SubtaskSummary(id=sub.id, label=subtask_label(sub.name, sub.severity), operator=sub.name,
                               family=family, relation_kind=relation_kind, severity=sub.severity,
                               config=sub.operator.get("config", {}), status=sub.status.value, done=sub.done,
                               total=sub.total, relations=sub.plan.relation_names, **dict(sub.results))
        subtasks.append(entry)
        result = ap_result(entry.ap)
        if sub.name == ORIGINAL:
            clean = result
        elif result is not None and sub.severity > 0:
            corrupted[(sub.name, sub.severity)] = result

    delta_rows = []
    if clean is not None:
        for entry in subtasks[1:]:
            result = ap_result(entry.ap)
            if result is None:
                continue
            for metric in AP_METRICS:
                for class_name in [*result.ap[metric], "mAP"]:
                    for difficulty in DIFFICULTIES:
                        if class_name == "mAP":
                            c, m = clean.mean_ap(metric, difficulty), result.mean_ap(metric, difficulty)
                        else:
                            c, m = clean.get(metric, class_name, difficulty), result.get(metric, class_name, difficulty)
                        delta_rows.append(DeltaRow(label=entry.label, operator=entry.operator,
                                                   severity=entry.severity, metric=metric, cls=class_name,
                                                   difficulty=difficulty, clean=c, corrupted=m, delta=m - c))

    robustness: dict[str, RobustnessRecord] = {}
    if clean is not None and corrupted:
        base_clean: KittiEvalResult | None = None
        base_corrupted: dict[tuple[str, int], KittiEvalResult] | None = None
        if baseline is not None:
            other = summarise(store, baseline)
            base_clean = ap_result(other.subtasks[0].ap)
            base_corrupted = {}
            for e in other.subtasks[1:]:
                found = ap_result(e.ap) if e.severity > 0 else None
                if found is not None:
                    base_corrupted[(e.operator, e.severity)] = found
        for metric in AP_METRICS:
            try:
                summary = robustness_summary(clean, corrupted, baseline_clean=base_clean,
                                             baseline_corrupted=base_corrupted, metric=metric)
            except ValueError as exc:
                robustness[metric] = RobustnessRecord(error=str(exc))
                continue
            robustness[metric] = RobustnessRecord.model_validate(summary.to_dict())

    def rate_rows(field: str) -> Iterable[tuple[dict[str, Any], RateRow]]:
        for entry in subtasks[1:]:
            for rate in getattr(entry, field):
                yield {"operator": entry.operator, "severity": entry.severity, "label": entry.label}, rate

    violation = ViolationTables(
        relation=_sum_rates(rate_rows("violations_total"), ("relation",)),
        relation_operator=_sum_rates(rate_rows("violations_total"), ("relation", "operator")),
        relation_label=_sum_rates(rate_rows("violations_total"), ("relation", "label")),
        relation_class=_sum_rates(rate_rows("violations"), ("relation", "class")),
        relation_operator_class=_sum_rates(rate_rows("violations"), ("relation", "operator", "class")),
        relation_class_objects=_sum_rates(rate_rows("violations_per_object"), ("relation", "class")),
        count_form=_sum_rates(rate_rows("count_form"), ("label",)),
    )

    with store.session() as s:
        kinds = dict(s.execute(select(Finding.kind, func.count()).where(Finding.task_id == task_id).group_by(
            Finding.kind)).all())
        top = top_findings(s, task_id)
    options = task.options
    info = TaskInfo(id=task.id, name=task.name, status=task.status.value,
                    dataset=DatasetRef(name=task.dataset.name, path=task.dataset.path, format=task.dataset.format),
                    model=ModelRef(name=task.model.name, spec=task.model.spec, options=task.model.options,
                                   fingerprint=task.model.fingerprint),
                    seed=task.seed, trials=options.trials, frames=len(options.frame_ids), relations=task.relations,
                    unlabelled_frames=len(options.unlabelled_frames),
                    created_at=task.created_at.isoformat() if task.created_at else None,
                    started_at=task.started_at.isoformat() if task.started_at else None,
                    finished_at=task.finished_at.isoformat() if task.finished_at else None,
                    done=task.done, total=task.total, baseline=baseline, pilot=options.pilot)
    return TaskSummary(task=info, classes=list(CLASSES), subtasks=subtasks, delta_ap=delta_rows,
                       ap_warnings=ap_warnings(subtasks), robustness=robustness, violations=violation,
                       deeptest=deeptest_table(subtasks[1:]),
                       findings=FindingsSummary(total=sum(kinds.values()), by_kind=kinds, top=top),
                       run=task.summary.run if task.summary else None, kind_summary=_kind_summary(store, task))


def _kind_summary(store: Store, task: Any) -> dict[str, Any]:
    """What the task's kind reports beyond the shared tables: its module's ``kind_summary(store,
    task)`` when it has one (a structural task's coverage tables), else nothing."""
    from lidarfuzz.campaign.kinds import kind_of

    hook = getattr(kind_of(task).implementation(), "kind_summary", None)
    return dict(hook(store, task)) if callable(hook) else {}


def top_findings(session: Any, task_id: int, limit: int = TOP_FINDINGS) -> list[TopFinding]:
    """The most telling findings: failures first, then violations with the most objects,
    at most three per (kind, operator) so one noisy operator does not fill the list."""
    rows = session.execute(
        select(Finding, FrameResult.frame_id, FrameResult.trial, Subtask.name, Subtask.severity).join(
            FrameResult, Finding.frame_result_id == FrameResult.id).join(
            Subtask, FrameResult.subtask_id == Subtask.id).where(Finding.task_id == task_id).order_by(
            # ties by unit, not id: the same choice however the store numbered them
            Finding.magnitude.desc().nulls_first(), Subtask.id, FrameResult.frame_id, FrameResult.trial,
            Finding.id).limit(2000)).all()
    chosen: list[TopFinding] = []
    per_group: Counter[tuple[str, str]] = Counter()
    for finding, frame_id, trial, name, severity in rows:
        group = (finding.kind, name)
        if per_group[group] >= 3:
            continue
        per_group[group] += 1
        chosen.append(TopFinding(id=finding.id, kind=finding.kind, cls=finding.cls, magnitude=finding.magnitude,
                                 message=finding.message, operator=name, severity=severity,
                                 label=subtask_label(name, severity), frame_id=frame_id, trial=trial,
                                 replay=f"lidarfuzz replay {finding.id}"))
        if len(chosen) >= limit:
            break
    return chosen


__all__ = ["ap_result", "ap_warnings", "deeptest_errors", "deeptest_table", "evaluate_subtask", "outcome_from_record",
           "summarise", "top_findings"]
