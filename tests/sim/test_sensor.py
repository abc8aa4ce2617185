"""Sensor presets: beam tables, sweep timing and ranges, checked on rendered frames."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.sim import SENSOR_PRESETS, load_sensor
from tests.sim.helpers import render


def test_hdl64e_is_the_kitti_sensor():
    sensor = SENSOR_PRESETS["HDL-64E"]
    assert sensor.beams == 64
    assert max(sensor.elevations_deg) == pytest.approx(2.0) and min(sensor.elevations_deg) == pytest.approx(-24.8)
    assert 360 / sensor.columns == pytest.approx(0.17, abs=0.01)
    assert 125_000 < sensor.rays < 140_000
    assert sensor.max_range == 120.0 and sensor.mount_height == 1.73
    # The upper block of lasers is denser than the lower one, as on the real head.
    steps = -np.diff(np.sort(sensor.elevations_deg)[::-1])
    assert steps[:31].mean() < steps[33:].mean()


@pytest.mark.parametrize("name", list(SENSOR_PRESETS))
def test_rendered_beams_have_the_preset_elevations_and_timing(name):
    sensor = SENSOR_PRESETS[name]
    scene = render({"sensor": name, "extent": 300})  # open flat ground: every downward beam returns
    points = scene.points
    ring = points.channel("ring").astype(int)
    xyz = points.xyz.astype(np.float64)
    elevation = np.rad2deg(np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1])))
    expected = np.sort(sensor.elevations_deg)[ring]  # ring 0 is the lowest beam
    np.testing.assert_allclose(elevation, expected, atol=1e-3)
    # Every beam whose hit on the grass (reflectivity 0.42) is clearly above the detection
    # threshold returns (signal = 0.42 · √cos(incidence) · (100 m / range)², cos = sin(−elevation));
    # beams at or above the horizon do not.
    elevations = np.deg2rad(np.sort(sensor.elevations_deg))
    ground_range = np.where(elevations < 0, sensor.mount_height / np.sin(-np.minimum(elevations, -1e-9)), np.inf)
    signal = 0.42 * np.sqrt(np.sin(np.maximum(-elevations, 1e-9))) * (100.0 / ground_range) ** 2
    strong = set(np.flatnonzero((signal >= 1.2 * sensor.detection_threshold) & (ground_range < sensor.max_range)))
    assert strong <= set(np.unique(ring)) <= set(np.flatnonzero(elevations < 0))
    assert len(strong) >= sensor.beams // 3
    # Flat ground at z = 0: z is minus the mount height, up to the range noise.
    assert np.median(xyz[:, 2]) == pytest.approx(-sensor.mount_height, abs=0.01)
    distance = np.linalg.norm(xyz, axis=1)
    assert distance.max() <= sensor.max_range + 5 * sensor.range_noise
    assert distance.min() >= sensor.min_range - 5 * sensor.range_noise
    time = points.channel("time")
    assert time.min() >= -sensor.period / 2 and time.max() < sensor.period / 2
    assert len(np.unique(time)) == pytest.approx(sensor.columns, rel=0.02)


def test_head_spins_clockwise_from_behind():
    scene = render({"sensor": "VLP-16", "extent": 300})
    xyz, time = scene.points.xyz, scene.points.channel("time")
    azimuth = np.arctan2(xyz[:, 1], xyz[:, 0])
    ahead = np.abs(azimuth) < 0.05
    assert np.all(np.abs(time[ahead]) < 0.002)  # facing forward at the frame's timestamp
    left = np.abs(azimuth - np.pi / 2) < 0.05
    right = np.abs(azimuth + np.pi / 2) < 0.05
    assert time[left].mean() == pytest.approx(-0.025, abs=0.002)  # left before right: clockwise
    assert time[right].mean() == pytest.approx(0.025, abs=0.002)


def test_range_noise_has_the_preset_spread():
    scene = render({"sensor": "HDL-64E", "extent": 300})
    xyz = scene.points.xyz.astype(np.float64)
    ring = scene.points.channel("ring").astype(int)
    low = ring == 0  # ground at a steep angle: range error shows directly in z
    direction_z = np.sin(np.deg2rad(min(SENSOR_PRESETS["HDL-64E"].elevations_deg)))
    measured = xyz[low, 2] / direction_z  # the range along the beam
    true = 1.73 / -direction_z
    assert np.std(np.abs(measured) - true) == pytest.approx(0.02, rel=0.15)


def test_user_defined_beam_table(tmp_path):
    path = tmp_path / "sensor.yaml"
    # The highest beam (−3°) meets the grass 38 m away, within the detection threshold's reach.
    path.write_text("preset: VLP-16\nname: my-4-beam\nelevations_deg: [-3, -5, -10, -15]\nmount_height: 2.0\n")
    sensor = load_sensor(path)
    assert sensor.beams == 4 and sensor.columns == 1800 and sensor.mount_height == 2.0
    scene = render({"sensor": sensor.model_dump(), "extent": 300})
    assert set(np.unique(scene.points.channel("ring"))) == {0, 1, 2, 3}
    assert np.median(scene.points.xyz[:, 2]) == pytest.approx(-2.0, abs=0.01)


@pytest.mark.parametrize(("text", "field"), [
    ("preset: VLP-16\ncolumns: -4\n", "columns"),
    ("elevations_deg: [95]\ncolumns: 10\nmax_range: 10\n", "elevations_deg"),
    ("preset: VLP-16\nbeams_per_second: 3\n", "beams_per_second"),
])
def test_bad_sensor_file_names_the_field(tmp_path, text, field):
    path = tmp_path / "sensor.yaml"
    path.write_text(text)
    with pytest.raises(DataFormatError) as info:
        load_sensor(path)
    assert str(path) in str(info.value) and field in str(info.value)


def test_unknown_sensor_name():
    with pytest.raises(DataFormatError, match="neither a sensor preset"):
        load_sensor("HDL-128")
