"""Which frames a campaign tests: all, the first N, or N drawn at random with the campaign's seed
(what Zhou & Sun's experiment needs: frames drawn from a data set, not its first ones)."""

from __future__ import annotations

from pathlib import Path

import pytest

from lidarfuzz.campaign.plan import select_frames
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.errors import DataFormatError
from lidarfuzz.store import Store

IDS = [f"{i:06d}" for i in range(100)]


def test_all_or_the_first_n() -> None:
    assert select_frames(IDS, None) == IDS
    assert select_frames(IDS, 3) == ["000000", "000001", "000002"]
    assert select_frames(IDS, 500, "random") == IDS  # more than there are: all of them


def test_a_random_draw_is_seeded_without_repeats_and_in_data_set_order() -> None:
    drawn = select_frames(IDS, 10, "random", seed=7)
    assert len(drawn) == len(set(drawn)) == 10 and set(drawn) <= set(IDS)
    assert drawn == sorted(drawn)  # in the data set's order
    assert drawn == select_frames(IDS, 10, "random", seed=7)  # the same seed, the same frames
    assert drawn != select_frames(IDS, 10, "random", seed=8)
    assert drawn != IDS[:10]  # not the first ten (1 chance in C(100, 10) of being so)
    # every frame can be drawn: over 200 seeds, each of the 100 frames comes up (each draw takes 10 %)
    seen = {f for seed in range(200) for f in select_frames(IDS, 10, "random", seed=seed)}
    assert seen == set(IDS)


def test_an_unknown_order_is_refused() -> None:
    with pytest.raises(ValueError, match="frame order 'middle'"):
        select_frames(IDS, 3, "middle")
    with pytest.raises(DataFormatError, match="frame_order"):
        parse_campaign({"dataset": "d", "sut": "classic", "operators": [{"name": "fog"}], "frame_order": "middle"})


def test_a_task_stores_the_frames_it_drew(world: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    try:
        spec = {"dataset": str(world), "sut": "classic", "operators": [{"name": "fog", "severities": [1]}], "frames": 2,
                "seed": 3}
        def frames_of(campaign: dict[str, object]) -> list[str]:
            return get_task(store, create_task(store, parse_campaign(campaign))).options.frame_ids

        first = frames_of(spec)
        drawn = frames_of({**spec, "frame_order": "random"})
        every = frames_of({k: v for k, v in spec.items() if k != "frames"})
        assert first == every[:2]
        assert drawn == select_frames(every, 2, "random", seed=3) and len(drawn) == 2
    finally:
        store.close()


def test_random_frames_without_a_count_is_refused_naming_the_missing_flag(world: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from lidarfuzz.cli.app import app

    result = CliRunner().invoke(app, ["run", "--dataset", str(world), "--sut", "classic", "--op", "fog@1",
                                      "--random-frames", "--workspace", str(tmp_path / "ws")])
    assert result.exit_code != 0  # lidarfuzz's main() prints it as one "error: ..." line
    assert str(result.exception) == "--random-frames draws --frames N of the data set's frames: give --frames too"
    assert not (tmp_path / "ws").exists()  # refused before anything was created
