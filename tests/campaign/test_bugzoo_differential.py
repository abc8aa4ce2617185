"""The default campaign shows each bug-zoo variant against the correct pipeline, and shows
nothing for the correct pipeline itself (issue 19): a row of the comparison significantly above
the reference (one-sided Fisher exact test, Tarone-corrected, alpha 0.05). Slow: nine campaigns of
the default set on 12 HDL-64E simulator frames (``experiments/bugzoo_differential.py`` prints the
same)."""

from __future__ import annotations

from pathlib import Path

import pytest

from lidarfuzz.campaign.compare import TaskComparison, compare_tasks
from lidarfuzz.campaign.executor import ProcessExecutor
from lidarfuzz.campaign.lifecycle import get_task
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.store import Store
from lidarfuzz.suts.bugzoo import BUGS

pytestmark = pytest.mark.slow

#: Variants the default campaign cannot show on these frames, and why (strict: showing them is news).
NOT_SHOWN = {
    "classic-bug-dense-cell": "switches to a 0.2 m clustering cell above 115,000 points; dual_return crosses it, but "
                              "its second returns double every fragment's points, so far objects still classify "
                              "(objects_lost 3/25 against the reference's 2/25, measured)",
}


@pytest.fixture(scope="module")
def setting(tmp_path_factory: pytest.TempPathFactory) -> tuple[Store, Path]:
    root = tmp_path_factory.mktemp("zoo")
    generate_dataset(root / "world", GenerationConfig(frames=12, seed=0), workers=2, overwrite=True)
    return Store(root / "ws"), root / "world"


def compared(setting: tuple[Store, Path], sut: str) -> TaskComparison:
    store, world = setting
    task_id = create_task(store, parse_campaign({"dataset": str(world), "sut": sut, "operators": "auto",
                                                 "reference": "classic"}))
    reference = get_task(store, task_id).options.references[0]
    for task in (reference, task_id):
        run_task(store, task, executor=ProcessExecutor(2))
    return compare_tasks(store, task_id, reference)


@pytest.mark.parametrize("bug", [pytest.param(b.name, marks=pytest.mark.xfail(strict=True, reason=NOT_SHOWN[b.name]))
                                 if b.name in NOT_SHOWN else b.name for b in BUGS])
def test_the_default_campaign_shows_the_variant(setting: tuple[Store, Path], bug: str) -> None:
    rows = [r for r in compared(setting, bug).significant if r.cls == ""]
    assert rows, f"{bug}: no row significantly above the correct pipeline"
    for row in rows:  # significant only where the variant's rate is above the reference's: >, never >=
        assert row.violated_a / row.checked_a > row.violated_b / row.checked_b and row.p_adjusted < 0.05


def test_the_correct_pipeline_shows_nothing_against_itself(setting: tuple[Store, Path]) -> None:
    result = compared(setting, "classic")
    assert result.significant == [] and result.disagreements_total == 0
