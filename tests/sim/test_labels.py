"""Labels agree with the points; occlusion, truncation and DontCare behave as in KITTI."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.scene.geometry import points_in_boxes
from lidarfuzz.sim import Renderer, compile_world, generate_scene
from lidarfuzz.sim.materials import SEMANTIC_ID
from lidarfuzz.sim.realism import RealismConfig
from tests.sim.helpers import render

# Seen from the sensor at the origin (azimuths in degrees): wall A covers ±8.5°, car 1 (±2.5°) hides
# behind it; wall B covers −22.8° … −18.8°, half of car 2 (−26° … −18°); car 3 (8.8° … 14°) is in the
# open; car 5 (27° … 46°) crosses the camera's edge (±40.7°); car 4 is behind; the van (24°) is 98 m away.
OPEN_GROUND_ACTORS = {
    "objects": [
        {"kind": "wall", "start": [10, -1.5], "end": [10, 1.5], "height": 3},
        {"kind": "wall", "start": [10, -4.2], "end": [10, -3.4], "height": 3},
    ],
    "actors": [
        {"class": "Car", "position": [20, 0], "id": 1},
        {"class": "Car", "position": [20, -8], "id": 2, "reflectivity": 0.5},
        {"class": "Car", "position": [25, 5], "id": 3, "reflectivity": 0.5},
        {"class": "Car", "position": [-10, 0], "id": 4},
        {"class": "Car", "position": [9, 6.5], "id": 5, "reflectivity": 0.5},
        {"class": "Van", "position": [90, 40], "id": 6, "reflectivity": 0.7},
    ],
}


@pytest.fixture(scope="module")
def staged():
    return render(OPEN_GROUND_ACTORS)


def _box(scene, track_id):
    index = np.flatnonzero(scene.boxes.track_ids == track_id)
    return scene.boxes.select(index) if len(index) else None


def test_object_fully_behind_a_wall_has_no_points_and_no_label(staged):
    assert not np.any(staged.points.channel("instance") == 1)
    assert _box(staged, 1) is None


def test_partly_hidden_object_is_labelled_occluded(staged):
    visible, hidden = _box(staged, 3), _box(staged, 2)
    assert visible.occlusion[0] == 0 and visible.truncation[0] == 0.0
    assert hidden.occlusion[0] in (1, 2)
    objects = staged.metadata["objects"]
    order = list(staged.boxes.track_ids)
    assert objects["visibility"][order.index(2)] < 0.8 <= objects["visibility"][order.index(3)]


def test_objects_outside_the_image_are_not_labelled_and_edge_objects_are_truncated(staged):
    assert np.any(staged.points.channel("instance") == 4)  # the LiDAR sees it ...
    assert _box(staged, 4) is None                         # ... but KITTI labels only the camera's view
    edge = _box(staged, 5)
    assert 0.1 < edge.truncation[0] < 0.9
    x1, _, x2, _ = edge.bbox2d[0]
    assert x1 == 0.0 and x2 > 0  # clipped at the image's left border
    assert _box(staged, 3).truncation[0] == 0.0


def test_far_objects_become_dontcare_regions(staged):
    far = _box(staged, 6)
    assert far.labels[0] == "DontCare" and not far.has_geometry[0]
    assert np.all(np.isfinite(far.bbox2d[0])) and far.bbox2d[0, 2] > far.bbox2d[0, 0]


def test_labels_carry_kitti_geometry(staged):
    labelled = staged.boxes.select(staged.boxes.has_geometry)
    np.testing.assert_allclose(labelled.alpha, staged.calib.alpha(labelled.as_array()))
    np.testing.assert_allclose(labelled.bbox2d, staged.calib.boxes_to_image(labelled.as_array()))
    # Ground-standing boxes: the bottom face is on the ground, 1.73 m below the sensor.
    np.testing.assert_allclose(labelled.centers[:, 2] - labelled.sizes[:, 2] / 2, -1.73, atol=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_labelled_objects_points_lie_in_its_box_even_with_a_moving_ego(seed):
    # Flat ground: a yaw-only box cannot hold a vehicle tilted against the ego vehicle by a
    # grade change (tests/sim/test_realism.py checks boxes on sloping ground).
    scene = Renderer(compile_world(generate_scene(seed, ego_speed=14.0, realism=RealismConfig.off()))).render(0.0)
    instance = scene.points.channel("instance")
    labelled = scene.boxes.select(scene.boxes.has_geometry)
    assert len(labelled) > 0
    counts = scene.metadata["objects"]["num_points"]
    for i in range(len(labelled)):
        own = scene.points.xyz[instance == labelled.track_ids[i]]
        assert len(own) == counts[i] >= 5
        inside = points_in_boxes(own, labelled.as_array()[i:i + 1], margin=0.1)[:, 0]
        assert inside.all(), f"{labelled.labels[i]} {labelled.track_ids[i]}: {np.sum(~inside)} points outside"


def test_points_in_a_box_belong_to_its_object():
    scene = Renderer(compile_world(generate_scene(4, ego_speed=8.0))).render(0.0)
    labelled = scene.boxes.select(scene.boxes.has_geometry)
    inside = points_in_boxes(scene.points.xyz, labelled.as_array(), margin=-0.05)
    label = scene.points.channel("label")
    instance = scene.points.channel("instance")
    for i in range(len(labelled)):
        mine = inside[:, i]
        foreign = mine & (instance != labelled.track_ids[i])
        assert foreign.sum() <= 0.02 * mine.sum() + 2, {int(k) for k in label[foreign]}


@pytest.mark.parametrize("speed", [0.0, 12.0])
def test_the_roi_contains_the_road_surface(speed):
    scene = Renderer(compile_world(generate_scene(5, ego_speed=speed))).render(0.0)
    label = scene.points.channel("label")
    road = scene.points.xyz[(label == SEMANTIC_ID["road"]) | (label == SEMANTIC_ID["lane-marking"])]
    sidewalk = scene.points.xyz[label == SEMANTIC_ID["sidewalk"]]
    assert len(road) > 10_000
    roi = scene.roi
    if speed == 0:  # exact: the map and the points share the frame
        from lidarfuzz.scene.roi import RoiMap

        grown = RoiMap(roi.geometry.buffer(0.05))
        assert grown.contains_xy(road).all()
        shrunk = RoiMap(roi.geometry.buffer(-0.05))
        assert shrunk.contains_xy(sidewalk).mean() < 0.01  # the kerb's face stands on the boundary
    else:  # rolling shutter shifts points fired away from the frame's instant by up to speed × 50 ms
        assert roi.contains_xy(road).mean() > 0.98


@pytest.mark.parametrize("seed", [0, 3])
def test_casting_only_towards_road_users_finds_every_hit(seed):
    # The renderer casts the moving road users' scene only along rays pointed at them; a full
    # cast must find exactly the same hits.
    renderer = Renderer(compile_world(generate_scene(seed, ego_speed=14.0)))
    parts = renderer.moving_parts(0.0, renderer.actor_times(0.0))
    origins, directions = renderer.rays(0.0)
    windowed = renderer.cast(origins, directions, parts)
    renderer._rays_towards_mesh = lambda origins, *args: np.ones(len(origins), bool)  # every ray
    full = renderer.cast(origins, directions, parts)
    for field in ("geometry", "owner", "distance", "reflectivity", "semantic"):
        assert np.array_equal(getattr(windowed, field), getattr(full, field)), field
    assert np.count_nonzero(windowed.owner >= 0) > 1000


def test_tracing_threads_do_not_change_the_frame():
    world = compile_world(generate_scene(6, ego_speed=9.0))
    one = Renderer(world, threads=1).render(0.3)
    three = Renderer(world, threads=3).render(0.3)
    assert one.points == three.points and one.boxes == three.boxes
