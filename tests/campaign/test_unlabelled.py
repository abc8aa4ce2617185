"""``lidarfuzz run`` on a labelled data set with a frame that has no label file: refused without
``--allow-unlabelled`` (naming the frame and the flag); with it every frame goes through the
system and the relations, and AP is scored on the labelled frames only — exactly the AP of the
same campaign on a data set that holds only those frames."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store.contracts import TaskSummary

runner = CliRunner()
# an invariant operator (uniform noise), so both relations apply: preservation needs no labels,
# gt_recall does
CAMPAIGN = ["--sut", "classic", "--op", "UNA@1", "--inline", "--relations", "preservation,gt_recall"]


def _copy_without(world: Path, target: Path, stem: str, *, everything: bool) -> Path:
    """A copy of ``world`` without frame ``stem``'s label (or, ``everything``, without the frame)."""
    shutil.copytree(world, target)
    for path in target.rglob(f"{stem}.*"):
        if everything or path.parent.name in ("label_2", "label_2_extra"):
            path.unlink()
    return target


@pytest.fixture(scope="module")
def mixed(world: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _copy_without(world, tmp_path_factory.mktemp("mixed") / "sim", "000001", everything=False)


def _summary(workspace: Path, task: int = 1) -> TaskSummary:
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.store import Store

    return summarise(Store(str(workspace)), task)


def test_run_refuses_unlabelled_frames_without_the_flag(mixed: Path, tmp_path: Path) -> None:
    result = runner.invoke(app, ["run", "--dataset", str(mixed), *CAMPAIGN, "--workspace", str(tmp_path / "ws")])
    assert isinstance(result.exception, LidarfuzzError), result.output
    message = str(result.exception)
    assert "1 of 3 frame(s) have no label file in label_2/ (000001)" in message
    assert "--allow-unlabelled" in message and "\n" not in message


def test_run_with_the_flag_scores_ap_on_the_labelled_frames_only(mixed: Path, world: Path, tmp_path: Path) -> None:
    workspace = tmp_path / "ws"
    result = runner.invoke(app, ["run", "--dataset", str(mixed), *CAMPAIGN, "--allow-unlabelled",
                                 "--workspace", str(workspace)], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "AP from the labelled frames only: 1 frame(s) without a label file left out (000001)" in result.output
    summary = _summary(workspace)
    assert summary.task.unlabelled_frames == 1
    original, noise = summary.subtasks
    assert original.frames == noise.frames == 3  # the unlabelled frame ran through the system too
    assert original.ap_excluded is not None and original.ap is not None
    assert original.ap_excluded.frames == 1 and original.ap_excluded.examples == ["000001"]
    assert original.ap.num_frames == 2

    # the reference: the same campaign on a data set holding only the two labelled frames
    labelled_only = _copy_without(world, tmp_path / "labelled" / "sim", "000001", everything=True)
    reference_ws = tmp_path / "reference"
    result = runner.invoke(app, ["run", "--dataset", str(labelled_only), *CAMPAIGN, "--workspace", str(reference_ws)])
    assert result.exit_code == 0, result.output
    reference = _summary(reference_ws)
    for got, expected in zip(summary.subtasks, reference.subtasks, strict=True):
        assert got.ap is not None and expected.ap is not None and got.ap.ap == expected.ap.ap

    # relations: preservation needs no labels and was checked on all 3 frames; gt_recall only where
    # the source has ground truth
    from sqlalchemy import select

    from lidarfuzz.store import FrameResult, Store
    from lidarfuzz.store.models import Subtask

    with Store(str(workspace)).session() as s:
        rows = s.execute(select(FrameResult.frame_id, FrameResult.relations).join(Subtask).where(
            Subtask.name != "original")).all()
    outcomes = {(frame, item.relation): item.applicable for frame, relations in rows for item in relations}
    assert outcomes[("000001", "preservation")] is True
    assert outcomes[("000001", "gt_recall")] is False and outcomes[("000000", "gt_recall")] is True


def test_a_registered_data_set_keeps_the_flag(mixed: Path, tmp_path: Path) -> None:
    workspace = str(tmp_path / "ws")
    added = runner.invoke(app, ["datasets", "add", "mixed", str(mixed), "--allow-unlabelled", "--workspace", workspace])
    assert added.exit_code == 0, added.output and "allow_unlabelled True" in added.output
    result = runner.invoke(app, ["run", "--dataset", "mixed", *CAMPAIGN, "--detach", "--workspace", workspace])
    assert result.exit_code == 0, result.output  # planned: the stored option lets the frame through
    other = runner.invoke(app, ["run", "--dataset", "mixed", *CAMPAIGN, "--layout", "nuscenes", "--detach",
                                "--workspace", workspace])
    assert isinstance(other.exception, LidarfuzzError) and "registered with layout None" in str(other.exception)
