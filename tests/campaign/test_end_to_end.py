"""End to end: the same small campaign against the classic pipeline and against a variant with
a seeded bug (whole-cloud intensity normalisation) — the campaign must show the bug.

Scattering points outside the drivable area (``outside_roi_scatter``) is invariant for a correct
ROI-filtering pipeline; the buggy one normalises intensity over the whole cloud, so the scatter
moves its percentile and a dark car inside the ROI vanishes: a violation of Zhou & Sun's MR1
(preservation) that the correct pipeline does not have on the same frame and mutant.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlalchemy import select

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.replay import replay_finding
from lidarfuzz.campaign.results import summarise
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.store import Finding, FrameResult, Store

# MR1 as Zhou & Sun state it: an object found in the source is still found (a loose IoU, so a
# box that merely changes shape under the scatter is not counted as lost).
MR1 = {"name": "preservation", "config": {"min_iou": 0.25}}


@pytest.fixture(scope="module")
def campaigns(tmp_path_factory: pytest.TempPathFactory, world: Path) -> tuple[Store, dict[str, int]]:
    store = Store(tmp_path_factory.mktemp("e2e"))
    ids = {}
    for sut in ("classic", "classic-bug-intensity-norm"):
        spec = parse_campaign({"name": f"scatter vs {sut}", "dataset": str(world), "sut": sut,
                               "operators": [{"name": "outside_roi_scatter", "severities": [5]}],
                               "relations": [MR1]})
        ids[sut] = create_task(store, spec)
        run_task(store, ids[sut], executor=InlineExecutor())
    return store, ids


def vanished(store: Store, task_id: int) -> set[str]:
    """Frames where a source object had no counterpart at all in the follow-up (IoU 0)."""
    with store.session() as s:
        rows = s.execute(select(Finding, FrameResult.frame_id)
                         .join(FrameResult, Finding.frame_result_id == FrameResult.id)
                         .where(Finding.task_id == task_id, Finding.kind == "preservation")).all()
    return {frame for finding, frame in rows
            if any(v["magnitude"] == 0.0 for v in finding.detail["violations"])}


def test_the_campaign_shows_the_seeded_bug(campaigns: tuple[Store, dict[str, int]]) -> None:
    store, ids = campaigns
    buggy, correct = vanished(store, ids["classic-bug-intensity-norm"]), vanished(store, ids["classic"])
    assert buggy and not correct
    summary = {name: summarise(store, task) for name, task in ids.items()}
    rate = {name: s.violations.relation[0] for name, s in summary.items()}
    assert rate["classic-bug-intensity-norm"].relation == "preservation"
    assert rate["classic-bug-intensity-norm"].violated >= 1
    # the same frames and mutants (same seed, same params) were checked for both systems
    assert rate["classic"].checked == rate["classic-bug-intensity-norm"].checked == 3


def test_the_report_shows_the_bug(campaigns: tuple[Store, dict[str, int]], tmp_path: Path) -> None:
    from lidarfuzz.report import parse_gate, write_report

    store, ids = campaigns
    gate = [parse_gate("violations:preservation>0")]
    buggy = write_report(store, ids["classic-bug-intensity-norm"], tmp_path / "bug", gates=gate, images=2)
    html = Path(buggy.html).read_text(encoding="utf-8")
    assert "preservation" in html and "lidarfuzz replay" in html
    assert not buggy.passed  # a CI gate on MR1 fails for the buggy system


def test_the_bug_replays(campaigns: tuple[Store, dict[str, int]]) -> None:
    store, ids = campaigns
    with store.session() as s:
        finding = s.scalar(select(Finding).where(Finding.task_id == ids["classic-bug-intensity-norm"],
                                                 Finding.kind == "preservation").order_by(Finding.magnitude.desc()))
    assert finding is not None
    replay = replay_finding(store, finding.id)
    assert replay.reproduced and replay.same_system
