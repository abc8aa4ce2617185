"""Issue 19's new operators (terrain, intensity units, object placement) and object rotation's
continuous range. Expected values are worked out by hand in the comments."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from lidarfuzz.operators import available, generator, get
from lidarfuzz.operators.lidar.terrain import Terrain, TerrainParams
from lidarfuzz.operators.lidar.units import IntensityUnits, IntensityUnitsParams
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import points_in_boxes
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


def rng(trial: int = 0) -> np.random.Generator:
    return generator(3, "000000", 0, trial)


def line_scene(count: int) -> Scene:
    xyz = np.column_stack([np.linspace(-0.4, 0.4, count), np.zeros(count), np.zeros(count)])
    return Scene(PointCloud(np.column_stack([xyz, np.full(count, 0.5)]).astype(np.float32)))


# --------------------------------------------------------------------------- terrain
def test_terrain_slope_offset_is_grade_times_distance_along_the_heading():
    cloud = PointCloud(np.array([[10, 0, -1.7, 0.1], [0, 4, -1.7, 0.1], [20, 5, 0.3, 0.2]], np.float32))
    boxes = Boxes3D.from_array(np.array([[20.0, 5.0, -0.9, 4.0, 1.8, 1.6, 0.3]]), ["Car"])
    scene = Scene(cloud, boxes)
    slope = TerrainParams(shape="slope", grade=0.05, heading=0.0, ramp_start=0.0, half_width=0.0)
    out = Terrain().apply(scene, slope)
    # heading 0: along = x; z += 0.05·x → +0.5, +0, +1.0 m; the box at x = 20 rises 1.0 m
    assert np.allclose(out.points.xyz[:, 2], [-1.2, -1.7, 1.3], atol=1e-6)
    assert np.allclose(out.points.xyz[:, :2], cloud.xyz[:, :2])
    assert out.boxes.centers[0, 2] == pytest.approx(0.1)
    assert np.array_equal(out.boxes.sizes, boxes.sizes) and np.array_equal(out.boxes.yaw, boxes.yaw)
    # heading 90°: along = y; the point at (0, 4) rises 0.05·4 = 0.2 m, the one at (10, 0) not at all
    left = Terrain().apply(scene, slope.model_copy(update={"heading": 90.0}))
    assert np.allclose(left.points.xyz[:2, 2], [-1.7, -1.5], atol=1e-6)


def test_terrain_ramp_and_crown_by_hand():
    cloud = PointCloud(np.array([[5, 0, 0, 0], [15, 0, 0, 0], [0, 2, 0, 0], [0, -8, 0, 0]], np.float32))
    scene = Scene(cloud)
    ramp = TerrainParams(shape="ramp", grade=0.1, heading=0.0, ramp_start=10.0, half_width=0.0)
    # flat before x = 10, then 0.1 per metre: x = 5 → 0, x = 15 → 0.5; the y-axis points → 0
    assert np.allclose(Terrain().apply(scene, ramp).points.xyz[:, 2], [0, 0.5, 0, 0], atol=1e-6)
    crown = TerrainParams(shape="crown", grade=0.02, heading=0.0, ramp_start=0.0, half_width=5.0)
    # across = y: falls 0.02 per metre to |y| = 5, flat beyond: y = 2 → -0.04, y = -8 → -0.1
    assert np.allclose(Terrain().apply(scene, crown).points.xyz[:, 2], [0, 0, -0.04, -0.1], atol=1e-6)


def test_terrain_is_declared_degrading_and_harmless_only_at_a_mild_grade():
    assert Terrain.relation == "degrading" and Terrain().transform(Terrain().sample(rng(), line_scene(5))) is None
    assert Terrain.harmless_up_to == 1 and Terrain.at_severity(1).config.grade_range == (0.02, 0.02)


# --------------------------------------------------------------------------- intensity units
def test_units_unit_to_uint8_is_times_255_exactly():
    values = np.array([0.0, 1 / 255, 0.2, 0.5, 1.0], np.float32)
    scene = Scene(PointCloud(np.column_stack([np.zeros((5, 3)), values]).astype(np.float32)),
                  metadata={"intensity_scale": 1.0})
    params = IntensityUnits.at_severity(2).sample(rng(), scene)
    assert params == IntensityUnitsParams(source_scale=1.0, unit="uint8")
    out = IntensityUnits().apply(scene, params)
    # 0·255 = 0, 255/255 = 1, 0.2·255 = 51, 0.5·255 = 127.5 → 128 (integers, half to even), 255
    assert out.points.intensity.tolist() == [0.0, 1.0, 51.0, 128.0, 255.0]
    assert out.metadata["intensity_scale"] == 255.0


def test_units_percent_back_to_unit_and_undeclared():
    scene = Scene(PointCloud(np.array([[0, 0, 0, 51.0], [0, 0, 0, 255.0]], np.float32)),
                  metadata={"intensity_scale": 255})
    # a 0-255 frame asked for 0-255 goes to [0, 1]: 51/255 = 0.2, 255/255 = 1
    params = IntensityUnits.at_severity(2).sample(rng(), scene)
    assert params.unit == "unit"
    assert np.allclose(IntensityUnits().apply(scene, params).points.intensity, [0.2, 1.0])
    # percent: 51/255·100 = 20, 100
    percent = IntensityUnits().apply(scene, IntensityUnitsParams(source_scale=255.0, unit="percent"))
    assert np.allclose(percent.points.intensity, [20.0, 100.0])
    silent = IntensityUnits.at_severity(5)
    out = silent.apply(scene, silent.sample(rng(), scene))
    assert out.metadata["intensity_scale"] == 255  # left as it was: converted silently
    assert np.allclose(out.points.intensity, [13107.0, 65535.0])  # 51·257, 255·257


# --------------------------------------------------------------------------- object placement
def test_placement_puts_the_object_at_the_drawn_range_and_bearing(sample_scenes):
    scene = sample_scenes[0]
    op = get("object_placement")(distance_range=(14.0, 16.0), bearing_range=(-20.0, 20.0))
    params = op.sample(rng(), scene)
    assert len(params.insertions) == 1, params.reason
    x, y, _ = params.insertions[0].center
    assert 14.0 <= np.hypot(x, y) <= 16.0
    assert -20.0 <= np.degrees(np.arctan2(y, x)) <= 20.0
    mutant = op.apply(scene, params)
    assert len(mutant.boxes) == len(scene.boxes) + 1
    assert op.apply(scene, params) == mutant  # from params alone
    # placed as object_insertion places: its points inside its box, at least min_points of them
    inside = points_in_boxes(mutant.points.xyz, mutant.boxes.as_array()[-1:], margin=0.05)[:, 0]
    assert inside.sum() >= 5


def test_placement_behind_the_car_needs_labels_outside_the_camera(sample_scenes):
    scene = sample_scenes[0]  # KITTI-style labels: only the front camera's view is labelled
    behind = {"distance_range": (10.0, 20.0), "bearing_range": (160.0, 200.0)}
    refused = get("object_placement")(**behind).sample(rng(), scene)
    assert refused.is_identity() and "camera" in refused.reason
    params = get("object_placement")(**behind, in_camera_view=False).sample(rng(), scene)
    assert len(params.insertions) == 1, params.reason
    x, y, _ = params.insertions[0].center
    assert x < 0 and abs(np.degrees(np.arctan2(y, -x))) <= 20.0  # within 20 degrees of straight behind


# --------------------------------------------------------------------------- object rotation
def test_object_rotate_draws_continuous_angles(sample_scenes):
    # object_rotate already takes a continuous range: angles uniform in [0, 90], not from a list
    op = get("object_rotate")(angle_range=(0.0, 90.0), both_directions=False)
    angles = [op.sample(rng(t), sample_scenes[0]).angle for t in range(8)]
    turned = [a for a in angles if a != 0.0]  # 0: no object had room to turn (the identity)
    assert len(turned) >= 4 and len(set(turned)) == len(turned)
    assert all(0.0 < a <= 90.0 for a in turned) and any(a % 1.0 for a in turned)


# --------------------------------------------------------------------------- every new operator
@pytest.mark.parametrize("name", ["terrain", "intensity_units", "object_placement"])
def test_new_operators_replay_from_params_and_are_listed(name, sample_scenes):
    scene = sample_scenes[0]
    op = available()[name].at_severity(3)
    mutant, params = op(scene, rng())
    again = op.apply(scene, op.parse_params(json.loads(params.model_dump_json())))
    assert again == mutant and not params.is_identity()
    assert isinstance(available()[name].harmless_because, str) and available()[name].harmless_because
    code = "import sys; from lidarfuzz.cli.app import main; sys.argv = ['lidarfuzz', 'operators', '--plain']; main()"
    listed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120).stdout
    assert any(line.split("\t")[0] == name for line in listed.splitlines())
