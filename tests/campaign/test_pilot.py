"""The pilot: a campaign's operator settings whose false-alarm floor leaves no room are lowered or dropped."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from lidarfuzz.campaign.pilot import has_room, pilot_campaign, trim
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.cli.app import app
from lidarfuzz.store.store import Store


def test_room_is_whether_a_system_failing_every_frame_could_be_told_from_the_floor() -> None:
    # 12 frames, floor 0/10 -> 0 of 12 expected: 12/12 vs 0/12, p = 1 / C(24, 12) = 3.7e-7 -> room
    assert has_room(0, 10, 12)
    # floor 9/10 -> 11 of 12 expected (10.8 rounded): p = C(12,12) C(12,11) / C(24,23) = 12/24 = 0.5 -> none
    assert not has_room(9, 10, 12)
    # 3 frames, floor 1/10 -> 0 expected: p = 1 / C(6, 3) = 0.05, not below 0.05 -> none
    assert not has_room(1, 10, 3)
    assert has_room(0, 0, 3)  # nothing checked: nothing to trim
    assert has_room(0, 2, 3)  # a zero floor never blocks, though 3/3 vs 0/3 has p = 0.05 too


def test_trim_lowers_to_the_highest_lower_severity_with_room_or_drops() -> None:
    spec = parse_campaign({"dataset": "d", "sut": "classic", "reference": "classic", "pilot": 4, "operators": [
        {"name": "rotate_z", "severities": [1, 3, 5]}, {"name": "fog", "severities": [1, 3]},
        {"name": "rotate_z", "config": {"angle_range": [10, 20]}}]}, "test")
    pilot = pilot_campaign(spec)
    assert pilot.sut == "classic" and pilot.reference == [] and pilot.frames == 4
    every = [1, 2, 3, 4, 5]
    assert [(c.name, c.severities) for c in pilot.operators] == [("rotate_z", every), ("fog", every)]
    full, empty = {"equivariance": (4, 4)}, {"equivariance": (0, 4)}
    found = {("rotate_z", 5): full, ("rotate_z", 4): empty, ("rotate_z", 3): empty, ("rotate_z", 1): empty,
             ("fog", 3): {"preservation": (4, 4)}, ("fog", 2): {"preservation": (3, 4)}, ("fog", 1): {}}
    trimmed, note = trim(spec, found, 12, pilot_task=7, system="classic")
    assert [(c.name, c.severities, c.config) for c in trimmed.operators] == [
        ("rotate_z", [1, 3, 4], None), ("fog", [1], None), ("rotate_z", [1, 3, 5], {"angle_range": [10, 20]})]
    assert note.lowered == ["rotate_z@5 -> @4 (floor equivariance 4/4)"]
    assert note.dropped == ["fog@3 (floor preservation 4/4)"]  # fog@2 has none either (3/4 -> 9 of 12)
    assert (note.task_id, note.frames, note.campaign_frames) == (7, 4, 12) and trimmed.pilot is None


def test_run_with_a_pilot_drops_the_settings_the_system_always_breaks(world: Path, tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    result = CliRunner().invoke(app, [
        "run", "--dataset", str(world), "--sut", "tests.campaign.systems:FixedBox", "--op", "global_flip@1",
        "--op", "intensity_quantisation@1", "--pilot", "2", "--inline", "--workspace", str(ws)],
        env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "pilot: global_flip@1 (floor equivariance 2/2" in result.output
    store = Store(ws)
    from lidarfuzz.campaign.tasks import get_task

    task = get_task(store, 2)  # task 1 is the pilot
    assert [o["name"] for o in task.operators] == ["intensity_quantisation"]
    assert task.options.pilot is not None and task.options.pilot.task_id == 1
    assert task.options.pilot.dropped[0].startswith("global_flip@1")
    report = next((ws / "reports").rglob("*.html")).read_text() if (ws / "reports").exists() else ""
    assert not report or "Dropped global_flip@1" in report
