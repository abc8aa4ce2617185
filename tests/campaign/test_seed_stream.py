"""A mutant's randomness is keyed by its operator, not by the operator's place in the campaign:
adding an operator before another leaves the other's mutants as they were, so two tasks' mutants
can be compared frame by frame."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sqlalchemy import select

from lidarfuzz.campaign.plan import operator_stream
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.store import FrameResult, Store, Subtask

ROTATE = {"name": "rotate_z", "severities": [3]}
NOISE = {"name": "uniform_noise_addition", "severities": [2]}


def params_of(store: Store, task_id: int, name: str) -> dict[tuple[str, int], dict[str, Any]]:
    with store.session() as s:
        rows = s.execute(select(FrameResult.frame_id, FrameResult.trial, FrameResult.params).join(Subtask)
                         .where(Subtask.task_id == task_id, Subtask.name == name))
        return {(frame, trial): params for frame, trial, params in rows}


def test_the_stream_is_the_operator_and_its_explicit_config() -> None:
    assert operator_stream("rotate_z") == operator_stream("rotate_z")
    assert operator_stream("rotate_z") != operator_stream("fog")
    assert operator_stream("rotate_z", {"angle_range": [10, 20]}) != operator_stream("rotate_z")
    # the config's key order is not part of the key
    assert operator_stream("fog", {"a": 1, "b": 2}) == operator_stream("fog", {"b": 2, "a": 1})
    assert 0 <= operator_stream("rotate_z") < 2**31  # fits PostgreSQL's integer column


def test_adding_an_operator_before_another_leaves_its_mutants_unchanged(world: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    try:
        def run(operators: list[dict[str, Any]]) -> int:
            campaign = {"dataset": str(world), "sut": "classic", "operators": operators, "frames": 2, "trials": 2,
                        "seed": 5}
            task_id = create_task(store, parse_campaign(campaign))
            run_task(store, task_id)
            return task_id

        alone, after = run([ROTATE]), run([NOISE, ROTATE])
        turned = params_of(store, alone, "rotate_z")
        assert len(turned) == 4  # 2 frames x 2 trials, each drawn its own angle
        assert len({p["angle"] for p in turned.values()}) == 4
        assert params_of(store, after, "rotate_z") == turned  # the same angles, frame by frame
    finally:
        store.close()
