"""DeepTest's relation in a campaign: MSE_orig over every original before any mutant is judged, the
same value in every verdict and finding (so a replay judges alike), and Table 7 in the summary
agreeing with the findings stored."""

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
from lidarfuzz.oracles.relations import DeepTestTolerance
from lidarfuzz.store import Finding, FrameResult, Store, Subtask

NOT_COUNTED = "not counted as an erroneous behaviour"


@pytest.fixture(scope="module")
def task(tmp_path_factory: pytest.TempPathFactory, world: Path):
    store = Store(tmp_path_factory.mktemp("deeptest"))
    # λ = 1 is on Table 7's grid, so its row can be checked against the findings; ε = 0 drops every
    # transformation whose MSE moved at all, so the findings of dropped ones are there to check
    spec = parse_campaign({"dataset": str(world), "sut": "classic", "trials": 2,
                           "operators": [{"name": "uniform_noise_addition", "severities": [1, 2]}],
                           "relations": [{"name": "deeptest_tolerance", "config": {"lambda": 1, "epsilon": 0.0}}]})
    task_id = create_task(store, spec)
    run_task(store, task_id, executor=InlineExecutor())
    yield store, task_id
    store.close()


def test_mse_orig_is_the_original_data_sets_and_every_verdict_uses_it(task) -> None:
    store, task_id = task
    with store.session() as s:
        rows = s.execute(select(FrameResult.id, Subtask.name, FrameResult.ground_truth, FrameResult.detections,
                                FrameResult.relations).join(Subtask).where(Subtask.task_id == task_id)).all()
    originals = [r for r in rows if r.name == "original"]
    mutants = [r for r in rows if r.name != "original"]
    assert len(originals) == 3 and len(mutants) == 3 * 2 * 2
    assert max(r.id for r in originals) < min(r.id for r in mutants)  # every original ran first
    expected, n = DeepTestTolerance().mse_orig_of((r.ground_truth.boxes(), r.detections.boxes()) for r in originals)
    assert n > 0
    outcomes = [o for r in mutants for o in r.relations if o.relation == "deeptest_tolerance"]
    assert len(outcomes) == len(mutants)
    assert {o.stats["mse_orig_from"] for o in outcomes} == {"data set"}
    assert {o.stats["mse_orig"] for o in outcomes} == {expected}
    with store.session() as s:
        replays = s.scalars(select(Finding.replay).where(Finding.task_id == task_id,
                                                         Finding.kind == "deeptest_tolerance")).all()
    assert replays and all(r.relation is not None and r.relation["config"]["mse_orig"] == expected for r in replays)


def test_a_finding_replays_against_the_same_mse_orig(task) -> None:
    store, task_id = task
    with store.session() as s:
        finding_id = s.scalars(select(Finding.id).where(Finding.task_id == task_id,
                                                        Finding.kind == "deeptest_tolerance")).first()
    assert finding_id is not None
    replay = replay_finding(store, finding_id)
    (outcome,) = [o for o in replay.outcomes_now if o.relation == "deeptest_tolerance"]
    assert outcome.stats["mse_orig_from"] == "data set" and replay.violated_now


def test_table_7_in_the_summary_agrees_with_the_findings(task) -> None:
    store, task_id = task
    table = summarise(store, task_id).deeptest
    assert table is not None
    with store.session() as s:
        messages = s.scalars(select(Finding.message).where(Finding.task_id == task_id,
                                                           Finding.kind == "deeptest_tolerance")).all()
    counted = [m for m in messages if not m.startswith(NOT_COUNTED)]
    assert {t.label for t in table.transformations} == {"uniform_noise_addition@1", "uniform_noise_addition@2"}
    for t in table.transformations:
        assert t.kept == (t.difference == 0.0)  # ε = 0
    # one finding per violating mutant (the relation is frame-level); the findings of a transformation
    # Eq. 3 drops say so, and only the others are counted
    assert len(counted) == sum(t.violated for t in table.transformations if t.kept)
    assert len(messages) - len(counted) == sum(t.violated for t in table.transformations if not t.kept)
    assert len(messages) > len(counted)  # on this world, noise moves the MSE and violates at λ = 1
    # the row of the relation's λ: each ε column sums the violations of the transformations it keeps
    row = table.lambdas.index(1.0)
    for column, epsilon in enumerate(table.epsilons):
        kept = [t for t in table.transformations if abs(t.difference) <= epsilon]
        assert table.counts[row][column] == sum(t.violated for t in kept)
    assert table.unfiltered[row] == len(messages)
