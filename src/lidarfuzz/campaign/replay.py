"""Replaying a finding: the same frame, the same operator with the same concrete params, the
same system, run again — and what differs from what the campaign recorded.

A replay draws no random numbers: the mutant is rebuilt from the stored params. The system is
rebuilt from its spec and options, and its fingerprint compared with the recorded one (a
changed system is reported, not hidden). The finding reproduces when the relation is
violated again (or, for a failure, the system fails the same way).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import select

from lidarfuzz.campaign.plan import ORIGINAL
from lidarfuzz.campaign.work import UnitResult, WorkContext, Worker, WorkUnit
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.store.contracts import FailureRecord, OutcomeRecord
from lidarfuzz.store.errors import NotFoundError
from lidarfuzz.store.models import Finding, FrameResult, Subtask, Task
from lidarfuzz.store.store import Store


@dataclass
class Replay:
    finding: dict[str, Any]
    fingerprint_recorded: str
    fingerprint_now: str
    source_recorded: Boxes3D
    follow_recorded: Boxes3D
    source_now: Boxes3D | None
    follow_now: Boxes3D | None
    failure_now: FailureRecord | None
    outcomes_now: list[OutcomeRecord]
    reproduced: bool

    @property
    def same_system(self) -> bool:
        return self.fingerprint_recorded == self.fingerprint_now


def _same(a: Boxes3D | None, b: Boxes3D) -> bool:
    return a is not None and len(a) == len(b) and (len(a) == 0 or a.allclose(b, atol=1e-3))


def replay_finding(store: Store, finding_id: int) -> Replay:
    """Re-run finding ``finding_id`` in this process and compare."""
    with store.session() as s:
        finding = s.get(Finding, finding_id)
        if finding is None:
            raise NotFoundError(f"no finding {finding_id} (lidarfuzz report TASK lists them)")
        row = s.get(FrameResult, finding.frame_result_id)
        assert row is not None
        original = s.scalar(select(FrameResult).join(Subtask).where(
            Subtask.task_id == finding.task_id, Subtask.name == ORIGINAL, FrameResult.frame_id == row.frame_id))
        sub = s.get(Subtask, row.subtask_id)
        assert sub is not None
        info = {"id": finding.id, "task_id": finding.task_id, "kind": finding.kind, "class": finding.cls,
                "message": finding.message, "frame_id": row.frame_id, "trial": row.trial, "subtask": sub.name,
                "severity": sub.severity, "detail": finding.detail}
        replay = finding.replay
        task = s.get(Task, finding.task_id)
        dataset_options = dict(task.dataset.options or {}) if task is not None else {}
        follow_recorded = row.detections.boxes()
        source_recorded = original.detections.boxes() if original is not None else Boxes3D.empty()
    context = WorkContext(replay.dataset, replay.sut, dict(replay.options), replay.fingerprint,
                          dataset_options=dataset_options)
    worker = Worker(context)
    try:
        fingerprint_now = worker.sut.fingerprint()
        source: UnitResult = worker.run(WorkUnit(0, replay.frame_id, replay.trial))
        source_now = source.detections.boxes() if source.detections is not None and source.failure is None else None
        relations = (replay.relation,) if replay.relation else ()
        follow_now: Boxes3D | None = None
        failure_now = None
        outcomes: list[OutcomeRecord] = []
        if replay.operator is None:  # a failure on an original
            failure_now = source.failure
        else:
            follow = worker.run(WorkUnit(0, replay.frame_id, replay.trial, replay.operator,
                                         replay.op_index, replay.seed, sub.name, relations,
                                         source.detections, source.failure is not None,
                                         params=replay.params, operator_relation=replay.operator_relation))
            failure_now = follow.failure
            follow_now = follow.detections.boxes() if follow.detections is not None and follow.failure is None else None
            outcomes = follow.relations
    finally:
        worker.close()
    if replay.relation:
        reproduced = any(not o.holds and any(v.cls == info["class"] for v in o.violations) for o in outcomes)
    else:
        reproduced = failure_now is not None and failure_now.kind == info["kind"]
    return Replay(info, replay.fingerprint, fingerprint_now, source_recorded, follow_recorded, source_now,
                  follow_now, failure_now, outcomes, reproduced)


__all__ = ["Replay", "replay_finding"]
