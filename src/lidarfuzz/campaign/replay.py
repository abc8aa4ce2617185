"""Replaying a finding: the same frame, the same operator with the same concrete params, the
same system, run again — and what differs from what the campaign recorded.

A replay draws no random numbers: the mutant is rebuilt from the stored params. The system is
rebuilt from its spec and options, and a replay reports three things apart:

* **the system**: its fingerprint now against the recorded one (code, weights, configuration);
* **the outputs**: the source's and the follow-up's now against the recorded ones, box by box
  within :data:`TOLERANCE` (counts per class and the largest centre shift when they differ);
* **the verdict**: whether the relation is violated again for the finding's class (or, for a
  failure, the system fails the same way).

The finding *reproduces* only when the outputs match the record and the verdict is the same.
Each frame is then run a second time: a system that answers differently to the same input is
non-deterministic (or stateful), the usual reason a finding does not reproduce.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import select

from lidarfuzz.campaign.kinds import kind_of
from lidarfuzz.campaign.plan import ORIGINAL
from lidarfuzz.campaign.work import UnitResult, WorkContext, Worker, WorkUnit
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.store.contracts import FailureRecord, OutcomeRecord
from lidarfuzz.store.errors import NotFoundError
from lidarfuzz.store.models import Finding, FrameResult, Subtask, Task
from lidarfuzz.store.store import Store

#: Largest difference of any box value (metres, radians, score) for two outputs to be the same.
TOLERANCE = 1e-3


@dataclass(frozen=True)
class OutputComparison:
    """One output against another (the record, or the system's first answer to the same input).

    Attributes:
        before: The earlier output; None when the system produced none (it failed).
        after: The later one; None likewise.
    """

    before: Boxes3D | None
    after: Boxes3D | None

    @property
    def same(self) -> bool:
        """Both failed, or both have the same boxes within :data:`TOLERANCE`."""
        if self.before is None or self.after is None:
            return self.before is None and self.after is None
        return len(self.before) == len(self.after) and (
            len(self.before) == 0 or self.after.allclose(self.before, atol=TOLERANCE))

    @property
    def centre_shift(self) -> float | None:
        """The largest distance (m) from a box centre on either side to the nearest centre on
        the other (None when a side has no boxes or no output)."""
        if self.before is None or self.after is None or len(self.before) == 0 or len(self.after) == 0:
            return None
        gaps = np.linalg.norm(self.before.centers[:, None, :] - self.after.centers[None, :, :], axis=2)
        return float(max(gaps.min(axis=1).max(), gaps.min(axis=0).max()))

    def describe(self, before: str = "recorded", after: str = "now") -> str:
        """``same``, or how they differ: ``3 Car now, 4 Car recorded; centres moved up to 0.52 m``."""
        if self.same:
            return "same"
        if self.before is None or self.after is None:
            return f"{_count(self.after)} {after}, {_count(self.before)} {before}"
        parts = []
        if _classes(self.before) != _classes(self.after):
            parts.append(f"{_count(self.after)} {after}, {_count(self.before)} {before}")
        shift = self.centre_shift
        if shift is not None:
            parts.append(f"centres moved up to {shift:.3g} m")
        return "; ".join(parts) or f"scores, sizes or headings differ by more than {TOLERANCE:g}"


def _classes(boxes: Boxes3D) -> dict[str, int]:
    labels, counts = np.unique(boxes.labels.astype(str), return_counts=True)
    return {str(label): int(n) for label, n in zip(labels, counts, strict=True)}


def _count(boxes: Boxes3D | None) -> str:
    if boxes is None:
        return "no output (failed)"
    if len(boxes) == 0:
        return "no boxes"
    return ", ".join(f"{n} {label}" for label, n in _classes(boxes).items())


@dataclass
class Replay:
    """What a replay found (see the module docstring).

    Attributes:
        finding: The finding as recorded (id, task, kind, class, message, frame, subtask, ...).
        source_recorded, follow_recorded: The recorded outputs (None: the system failed; the
            follow-up of a finding on an original is the original's).
        source_now, follow_now: The outputs now (None: failed, or no follow-up for an original).
        source_again, follow_again: The second answer to the same frames.
        violated_now: The verdict now: the relation violated again for the finding's class, or
            the system failing the same way.
    """

    finding: dict[str, Any]
    fingerprint_recorded: str
    fingerprint_now: str
    source_recorded: Boxes3D | None
    follow_recorded: Boxes3D | None
    source_now: Boxes3D | None
    follow_now: Boxes3D | None
    source_again: Boxes3D | None
    follow_again: Boxes3D | None
    failure_now: FailureRecord | None
    outcomes_now: list[OutcomeRecord]
    violated_now: bool
    has_follow: bool = True

    @property
    def same_system(self) -> bool:
        return self.fingerprint_recorded == self.fingerprint_now

    def against_record(self) -> dict[str, OutputComparison]:
        """The outputs now against the record: ``source`` and (for a mutant) ``follow-up``."""
        out = {"source": OutputComparison(self.source_recorded, self.source_now)}
        if self.has_follow:
            out["follow-up"] = OutputComparison(self.follow_recorded, self.follow_now)
        return out

    def repeated(self) -> dict[str, OutputComparison]:
        """The second answer to each frame against the first."""
        out = {"source": OutputComparison(self.source_now, self.source_again)}
        if self.has_follow:
            out["follow-up"] = OutputComparison(self.follow_now, self.follow_again)
        return out

    @property
    def outputs_match(self) -> bool:
        return all(c.same for c in self.against_record().values())

    @property
    def deterministic(self) -> bool:
        """The system gave the same output both times it saw each frame."""
        return all(c.same for c in self.repeated().values())

    @property
    def reproduced(self) -> bool:
        """The outputs match the record and the verdict is the same."""
        return self.outputs_match and self.violated_now

    @property
    def verdict(self) -> str:
        """One line: ``reproduced``, or ``not reproduced: ...`` with the reasons."""
        if self.reproduced:
            return "reproduced"
        reasons = []
        if not self.outputs_match:
            differ = [f"{what} ({c.describe()})" for what, c in self.against_record().items() if not c.same]
            reasons.append("outputs differ from the record: " + ", ".join(differ))
        if not self.violated_now:
            reasons.append("the system does not fail the same way now" if not self.finding.get("relation")
                           else "the relation is not violated for this class now")
        if not self.deterministic:
            reasons.append("the system answers differently to the same frame (non-deterministic or stateful)")
        if not self.same_system:
            reasons.append("the system changed since (another fingerprint)")
        return "not reproduced: " + "; ".join(reasons)


def _boxes(result: UnitResult) -> Boxes3D | None:
    return result.detections.boxes() if result.detections is not None and result.failure is None else None


class ReplayError(LidarfuzzError):
    """A finding that cannot be replayed on its own (one step of a log)."""


def replay_finding(store: Store, finding_id: int) -> Replay:
    """Re-run finding ``finding_id`` in this process, twice, and compare (see the module docstring)."""
    with store.session() as s:
        finding = s.get(Finding, finding_id)
        if finding is None:
            raise NotFoundError(f"no finding {finding_id}", cli="lidarfuzz report TASK lists them")
        row = s.get(FrameResult, finding.frame_result_id)
        assert row is not None
        original = s.scalar(select(FrameResult).join(Subtask).where(
            Subtask.task_id == finding.task_id, Subtask.name == ORIGINAL, FrameResult.frame_id == row.frame_id))
        sub = s.get(Subtask, row.subtask_id)
        assert sub is not None
        replay = finding.replay
        info = {"id": finding.id, "task_id": finding.task_id, "kind": finding.kind, "class": finding.cls,
                "message": finding.message, "frame_id": row.frame_id, "trial": row.trial, "subtask": sub.name,
                "severity": sub.severity, "detail": finding.detail, "relation": replay.relation}
        task = s.get(Task, finding.task_id)
        if task is not None and kind_of(task).consumes_logs:  # a decision of a stateful system on a whole log
            raise ReplayError(f"finding {finding_id} is a step of a log (task {task.id}, {task.options.kind}): step "
                              f"{finding.detail.get('step')} of {replay.dataset}; its decisions depend on every step "
                              f"before it, so replay the log in order: lidarfuzz logs select {replay.dataset} --sut "
                              f"{replay.sut} --target CODE")
        dataset_options = dict(task.dataset.options or {}) if task is not None else {}
        follow_recorded = None if row.detections.missing else row.detections.boxes()
        source_recorded = None if original is None or original.detections.missing else original.detections.boxes()
    context = WorkContext(replay.dataset, replay.sut, dict(replay.options), replay.fingerprint,
                          dataset_options=dataset_options)
    worker = Worker(context)
    relations = (replay.relation,) if replay.relation else ()

    def follow_unit(source: UnitResult) -> WorkUnit:
        assert replay.operator is not None
        return WorkUnit(0, replay.frame_id, replay.trial, replay.operator, replay.op_index, replay.seed, sub.name,
                        relations, source.detections, source.failure is not None, params=replay.params,
                        operator_relation=replay.operator_relation)

    try:
        fingerprint_now = worker.sut.fingerprint()
        source = worker.run(WorkUnit(0, replay.frame_id, replay.trial))
        follow = worker.run(follow_unit(source)) if replay.operator is not None else None
        # the same frames again, in the same order: a system must answer the same input the same way
        source_again = worker.run(WorkUnit(0, replay.frame_id, replay.trial))
        follow_again = worker.run(follow_unit(source)) if replay.operator is not None else None
    finally:
        worker.close()
    outcomes = follow.relations if follow is not None else []
    failure_now = follow.failure if follow is not None else source.failure
    if replay.relation:
        violated = any(not o.holds and any(v.cls == info["class"] for v in o.violations) for o in outcomes)
    else:
        violated = failure_now is not None and failure_now.kind == info["kind"]
    return Replay(info, replay.fingerprint, fingerprint_now, source_recorded,
                  follow_recorded if follow is not None else None, _boxes(source),
                  _boxes(follow) if follow is not None else None, _boxes(source_again),
                  _boxes(follow_again) if follow_again is not None else None, failure_now, outcomes, violated,
                  has_follow=follow is not None)


__all__ = ["TOLERANCE", "OutputComparison", "Replay", "ReplayError", "replay_finding"]
