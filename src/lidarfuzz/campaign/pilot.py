"""A pilot before a campaign: trim the operator settings whose false-alarm floor leaves no room.

A harmlessness relation can only show a bug where the correct behaviour rarely violates it. The
pilot measures that floor: a short campaign (``pilot: N`` frames) of every operator of the campaign
at every severity 1–5, run on the reference system when the campaign names one (its floor is the one
a bug must rise above) and on the system under test otherwise. An operator setting has *room* at the
campaign's scale when a system violating a relation on every one of the campaign's frames could be
told from the floor — one-sided Fisher exact test of ``frames/frames`` against the floor's rate at
the same scale, ``p < alpha`` (:func:`~lidarfuzz.oracles.significance.fisher_greater`); a floor of
no violations always has room. A setting without room for some relation it is checked by is lowered
to the highest lower severity that has room for every relation (and is not already in the campaign),
or dropped when there is none. Operators given with an explicit config are left as they are. What
was dropped or lowered, and why, is stored with the task
(:class:`~lidarfuzz.store.contracts.PilotNote`) and printed in its report.
"""

from __future__ import annotations

from collections import defaultdict
from typing import TYPE_CHECKING

from lidarfuzz.oracles.significance import ALPHA, fisher_greater
from lidarfuzz.store.contracts import PilotNote
from lidarfuzz.store.models import FrameResult, Subtask

if TYPE_CHECKING:
    from lidarfuzz.campaign.spec import CampaignSpec
    from lidarfuzz.store.store import Store

#: (operator, severity) -> relation -> (violated, checked)
Floors = dict[tuple[str, int], dict[str, tuple[int, int]]]

SEVERITIES = (1, 2, 3, 4, 5)


def pilot_campaign(spec: CampaignSpec) -> CampaignSpec:
    """The pilot's campaign: ``spec.pilot`` frames, every operator of ``spec`` (those without an
    explicit config) at every severity that configures it differently, on the first reference
    system, or on the system itself."""
    from lidarfuzz.campaign.defaults import distinct_severities

    assert spec.pilot is not None
    names = dict.fromkeys(c.name for c in spec.operators if c.config is None)  # each once, in order
    operators = [{"name": name, "severities": distinct_severities(name, SEVERITIES)} for name in names]
    return spec.model_copy(update={
        "name": f"pilot of {spec.name or 'a campaign'}", "sut": spec.reference[0] if spec.reference else spec.sut,
        "reference": [], "pilot": None, "frames": spec.pilot,
        "operators": type(spec).model_validate({**spec.model_dump(), "operators": operators}).operators,
    })


def floors(store: Store, task_id: int) -> Floors:
    """Violated and checked mutants per operator setting and relation of a finished task."""
    counts: dict[tuple[str, int], dict[str, list[int]]] = defaultdict(lambda: defaultdict(lambda: [0, 0]))
    with store.session() as s:
        rows = s.query(Subtask.name, Subtask.severity, FrameResult.relations).join(
            FrameResult, FrameResult.subtask_id == Subtask.id).filter(Subtask.task_id == task_id).all()
    for name, severity, outcomes in rows:
        for outcome in outcomes or []:
            if outcome.applicable:
                cell = counts[(name, severity)][outcome.relation]
                cell[0] += int(not outcome.holds)
                cell[1] += 1
    return {key: {rel: (k, n) for rel, (k, n) in by.items()} for key, by in counts.items()}


def has_room(violated: int, checked: int, frames: int, alpha: float = ALPHA) -> bool:
    """Could a system violating the relation on all ``frames`` be told from this floor at that scale?

    A floor of no violations never blocks: at a scale too small for any test to reach ``alpha``
    the limit is the campaign's size, not the floor, and trimming would only hide operators.

        >>> has_room(0, 10, 12), has_room(5, 10, 12), has_room(9, 10, 12), has_room(1, 10, 3), has_room(0, 2, 3)
        (True, True, False, False, True)
    """
    if violated == 0 or frames == 0:
        return True
    expected = round(violated / checked * frames)
    return fisher_greater(frames, frames, expected, frames) < alpha


def _blocking(by_relation: dict[str, tuple[int, int]], frames: int) -> list[str]:
    return [f"{rel} {k}/{n}" for rel, (k, n) in sorted(by_relation.items()) if not has_room(k, n, frames)]


def trim(spec: CampaignSpec, found: Floors, frames: int, *, pilot_task: int, system: str) -> tuple[CampaignSpec,
                                                                                                      PilotNote]:
    """``spec`` with the settings that have no room at ``frames`` frames lowered or dropped."""
    kept, dropped, lowered = [], [], []
    for choice in spec.operators:
        if choice.config is not None:
            kept.append(choice)
            continue
        severities: list[int] = []
        for severity in choice.severities:
            blocking = _blocking(found.get((choice.name, severity), {}), frames)
            if not blocking:
                severities.append(severity)
                continue
            lower = [s for s in range(severity - 1, 0, -1) if s not in choice.severities and s not in severities
                     and not _blocking(found.get((choice.name, s), {}), frames)]
            why = ", ".join(blocking)
            if lower:
                severities.append(lower[0])
                lowered.append(f"{choice.name}@{severity} -> @{lower[0]} (floor {why})")
            else:
                dropped.append(f"{choice.name}@{severity} (floor {why})")
        if severities:
            kept.append(choice.model_copy(update={"severities": sorted(set(severities))}))
    note = PilotNote(task_id=pilot_task, system=system, frames=int(spec.pilot or 0), campaign_frames=frames,
                     dropped=dropped, lowered=lowered)
    return spec.model_copy(update={"operators": kept, "pilot": None}), note


__all__ = ["Floors", "floors", "has_room", "pilot_campaign", "trim"]
