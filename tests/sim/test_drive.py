"""Drive logs (``gen --drive``): a generated route that stops, turns at a junction and drives on,
with road users timed against it; its ego labels written to ego.txt and read into frame metadata."""

from __future__ import annotations

import math

import numpy as np
import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.errors import DataFormatError
from lidarfuzz.io import open_dataset
from lidarfuzz.io.kitti import KittiLog
from lidarfuzz.sim import GenerationConfig, compile_world, generate_dataset, generate_scene, parse_scene
from lidarfuzz.sim.drive import MIN_RIGHT_RADIUS
from lidarfuzz.sim.world import ProfiledTrajectory, ego_labels
from tests.sim.helpers import street

DURATION = 40.0  # s: a 400-frame log at 10 Hz
SEEDS = range(6)


@pytest.fixture(scope="module")
def drives():
    return {seed: generate_scene(seed, drive=True, duration=DURATION, sensor="VLP-16") for seed in SEEDS}


def test_drives_are_deterministic_and_the_seed_picks_left_or_right_and_the_kind_of_stop(drives):
    assert generate_scene(3, drive=True, duration=DURATION, sensor="VLP-16") == drives[3]
    assert drives[3] != drives[4]
    # The last leg's heading: +90° after a left turn, −90° after a right one; both among six seeds.
    turns = {math.copysign(90, s.ego.route[2][1] - s.ego.route[1][1]) for s in drives.values()}
    assert turns == {90, -90}
    queued = [s for s in drives.values() if any(a.stops and a.cls == "Car" for a in s.actors)]
    assert queued and len(queued) < len(drives)  # behind a car at some junctions, first at the others
    assert all(s.name.endswith(f"-drive-{seed}") for seed, s in drives.items())


def test_the_ego_stops_with_bounded_braking_turns_smoothly_and_drives_on_to_the_end_of_the_log(drives):
    for seed, spec in drives.items():
        ego = compile_world(spec).ego
        assert isinstance(ego, ProfiledTrajectory)
        t = np.arange(0.0, DURATION, 0.1)
        speed, yaw_rate, curvature, steering = ego_labels(ego, t).T
        stopped = np.flatnonzero(speed < 1e-9)
        assert len(stopped) >= 19, seed  # stands at least 2 s (behind a car; 3 s at a crossing): 19 samples or more
        assert speed[stopped[-1] + 1:].max() == pytest.approx(spec.ego.speed)  # and gets back to its speed
        assert speed[-1] > 0  # the route outlasts the log
        acceleration = np.diff(speed) / 0.1
        assert acceleration.min() >= -3.0 - 1e-6 and acceleration.max() <= 2.0 + 1e-6, seed
        turning = np.abs(curvature) > 0
        kappa_max = 1 / min(spec.ego.corner_radius, MIN_RIGHT_RADIUS)
        assert turning.any() and np.abs(curvature).max() <= kappa_max + 1e-9
        np.testing.assert_allclose(steering, np.arctan(2.71 * curvature))
        np.testing.assert_allclose(yaw_rate, speed * curvature)
        _, _, heading = ego.at(t)
        # No instant heading change: at most the yaw rate that 2 m/s² of lateral acceleration allows,
        # v·κ = √(2·κ) (0.67 rad/s at R = 4.5 m), per 0.1 s — a sharp corner turns 1.57 rad at once.
        assert np.abs(np.angle(np.exp(1j * np.diff(heading)))).max() <= math.sqrt(2 * kappa_max) * 0.1 + 1e-9
        assert abs(abs(heading[-1]) - math.pi / 2) < 1e-9  # along the crossing street
        assert ego.profile.acceleration(t).min() >= -3.0 - 1e-9


def test_a_pedestrian_is_in_front_while_it_stops_and_no_generated_road_user_meets_the_ego(drives):
    for seed, spec in drives.items():
        world = compile_world(spec)
        t = np.arange(0.0, DURATION, 0.1)
        ex, ey, eyaw = world.ego.at(t)
        speed = ego_labels(world.ego, t)[:, 0]
        stopped = np.flatnonzero(speed < 1e-9)
        k = stopped[len(stopped) // 2]  # halfway through the stop
        ahead = []
        for actor in world.actors:
            ax, ay, _ = actor.trajectory.at(t)
            if actor.trajectory.speed > 0 and not isinstance(actor.trajectory, ProfiledTrajectory):
                assert np.hypot(ax - ex, ay - ey).min() > 1.5, (seed, actor.index)  # never through the ego
            dx, dy, yaw = ax[k] - ex[k], ay[k] - ey[k], eyaw[k]
            forward, left = dx * math.cos(yaw) + dy * math.sin(yaw), -dx * math.sin(yaw) + dy * math.cos(yaw)
            if 2.0 < forward < 15.0 and abs(left) < 5.0:
                ahead.append(actor.cls)
        # At an urban junction a pedestrian crosses in front (or in front of the queueing car); at a
        # suburban one the car it queues behind stands there.
        assert ("Pedestrian" in ahead) or ("Car" in ahead), (seed, ahead)


def test_a_drive_log_writes_ego_labels_that_the_reader_puts_in_frame_metadata(tmp_path):
    config = GenerationConfig(frames=3, seed=2, drive=True, sensor="VLP-16")
    generate_dataset(tmp_path / "drive", config, workers=1)
    log = open_dataset(tmp_path / "drive")
    assert isinstance(log, KittiLog) and len(log) == 3
    lines = (tmp_path / "drive" / "ego.txt").read_text().splitlines()
    assert lines[0].startswith("# frame_id speed yaw_rate curvature steering") and len(lines) == 4
    spec = generate_scene(2, drive=True, duration=0.3, sensor="VLP-16")
    for index, scene in enumerate(log):
        # The log starts at the drive's speed on the straight: no curvature, no steering yet.
        assert scene.metadata["speed"] == pytest.approx(spec.ego.speed, abs=1e-6)
        assert (scene.metadata["yaw_rate"], scene.metadata["curvature"], scene.metadata["steering"]) == (0, 0, 0)
        assert lines[index + 1].split()[0] == scene.frame_id
    assert config.to_json()["drive"] is True and "drive" not in GenerationConfig(frames=3).to_json()


def test_gen_drive_refuses_a_scene_file(tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text("ego: {speed: 8}\n")
    result = CliRunner().invoke(app, ["gen", "--drive", "--scene", str(scene), "--out", str(tmp_path / "x")])
    assert result.exit_code == 2 and "--drive" in result.output
    with pytest.raises(ValueError, match="drive"):
        GenerationConfig(frames=1, drive=True, scene=generate_scene(0))


@pytest.mark.slow
def test_a_300_frame_drive_log_stops_for_a_pedestrian_and_turns(tmp_path):
    generate_dataset(tmp_path / "long", GenerationConfig(frames=300, seed=1, drive=True, sensor="VLP-16"), workers=2)
    log = open_dataset(tmp_path / "long")
    speeds = np.array([s.metadata["speed"] for s in log])
    steering = np.array([s.metadata["steering"] for s in log])
    assert (speeds == 0).sum() >= 20 and (np.abs(steering) > 0.1).sum() >= 10
    stopped = log[int(np.flatnonzero(speeds == 0)[5])]
    ahead = stopped.boxes.centers
    assert any(str(c) == "Pedestrian" and 0 < x < 15 and abs(y) < 6 for c, (x, y, _) in
               zip(stopped.boxes.labels, ahead, strict=True))


def test_a_bad_ego_file_is_one_line_naming_file_and_line(tmp_path):
    root = tmp_path / "log"
    spec = parse_scene(street(ego={"position": [0, -1.75], "speed": 10, "route": [[0, -1.75], [10.5, -1.75]]}))
    generate_dataset(root, GenerationConfig(frames=2, scene=spec, sensor="VLP-16"), workers=1)
    # 10.5 m at 10 m/s: still driving at 0.1 s; a plain route has no curvature.
    assert open_dataset(root)[1].metadata["speed"] == 10.0
    ego = root / "ego.txt"
    lines = ego.read_text().splitlines()
    ego.write_text("\n".join([lines[0], lines[1], "000001 10.0 fast 0 0"]) + "\n")
    with pytest.raises(DataFormatError, match="not a number") as info:
        open_dataset(root)
    assert "ego.txt" in str(info.value) and ":3" in str(info.value) and "\n" not in str(info.value)
