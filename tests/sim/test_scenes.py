"""Scene descriptions, procedural layouts and road-user shapes."""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from shapely.geometry import LineString, Point

from lidarfuzz.errors import DataFormatError
from lidarfuzz.sim import generate_scene, load_scene, parse_scene
from lidarfuzz.sim.actors import ACTOR_CLASSES, SIZE_LIMITS, SIZE_STATS, actor_mesh, sample_size
from lidarfuzz.sim.world import compile_world, footprint_of
from tests.sim.helpers import render, street


# ---------------------------------------------------------------- shapes
@pytest.mark.parametrize("cls", ACTOR_CLASSES)
def test_shapes_fit_their_boxes_exactly(cls):
    rng = np.random.default_rng(0)
    for size in [SIZE_LIMITS[cls][0], SIZE_LIMITS[cls][1], *(sample_size(rng, cls) for _ in range(20))]:
        for phase in np.linspace(0, 2 * np.pi, 9):
            vertices = actor_mesh(cls, size, phase).vertices
            length, width, height = size
            lo, hi = vertices.min(axis=0), vertices.max(axis=0)
            assert lo[0] >= -length / 2 - 1e-9 and hi[0] <= length / 2 + 1e-9
            assert lo[1] >= -width / 2 - 1e-9 and hi[1] <= width / 2 + 1e-9
            assert lo[2] >= -1e-9 and hi[2] == pytest.approx(height)  # the top of the box is touched


def test_sizes_follow_kitti_statistics():
    rng = np.random.default_rng(1)
    for cls, stats in SIZE_STATS.items():
        sizes = np.array([sample_size(rng, cls) for _ in range(400)])
        means = np.array([m for m, _ in stats])
        np.testing.assert_allclose(sizes.mean(axis=0), means, rtol=0.06)


def test_a_pedestrian_walks():
    still = actor_mesh("Pedestrian", (0.8, 0.6, 1.75), 0.0).vertices
    stride = actor_mesh("Pedestrian", (0.8, 0.6, 1.75), np.pi / 2).vertices
    low = still[:, 2] < 0.1
    assert np.ptp(stride[stride[:, 2] < 0.1, 0]) > np.ptp(still[low, 0]) + 0.3  # feet apart mid-stride


def test_shapes_are_more_than_boxes():
    # A car's points show a cabin narrower and shorter than the body, and wheels: not a box.
    scene = render({"actors": [{"class": "Car", "position": [8, 0], "yaw": 90, "id": 1, "reflectivity": 0.5}]})
    car = scene.points.xyz[scene.points.channel("instance") == 1]
    height = car[:, 2] + 1.73
    upper, lower = car[height > 1.2], car[(height > 0.4) & (height < 0.8)]
    assert np.ptp(upper[:, 1]) < np.ptp(lower[:, 1]) - 0.5  # the cabin is shorter than the body (yaw 90: along y)


# ---------------------------------------------------------------- descriptions
def test_hand_written_yaml_scene(tmp_path):
    path = tmp_path / "scene.yaml"
    path.write_text("""
roads:
  - centerline: [[-100, 0], [200, 0]]
    lanes: 2
actors:
  - {class: Van, position: [26, -4.6], parked: true}
  - {class: Pedestrian, position: [30, -5.6], yaw: 90, speed: 1.2}
ego: {speed: 8}
""")
    spec = load_scene(path)
    assert [a.cls for a in spec.actors] == ["Van", "Pedestrian"] and spec.actors[0].parked
    assert spec.sensor == "HDL-64E" and spec.ego.speed == 8
    round_trip = parse_scene(__import__("yaml").safe_load(spec.to_yaml()))
    assert round_trip == spec


@pytest.mark.parametrize(("text", "where", "line"), [
    ("actors:\n  - {class: Tractor, position: [1, 2]}\n", "actors.0", None),
    ("actors:\n  - {class: Car}\n", "actors.0.position", None),
    ("roads:\n  - centerline: [[0, 0]]\n", "roads.0.centerline", None),
    ("objects:\n  - {kind: castle, position: [1, 2]}\n", "objects.0", None),
    ("actors:\n  - {class: Car, position: [1, 2], parked: true, speed: 3}\n", "actors.0", None),
    ("ego: {speed: 8\nactors: []\n", None, 2),
    # corners out of order: a bow-tie (repairing it would keep one lobe) and a split footprint
    ("objects:\n  - {kind: building, footprint: [[10, 10], [20, 20], [20, 10], [10, 20]]}\n",
     "objects.0.building.footprint", None),
    ("objects:\n  - {kind: tree, position: [0, 0]}\n  - {kind: building, "
     "footprint: [[10, 0], [20, 0], [20, 10], [15, -5], [10, 10]]}\n", "objects.1.building.footprint", None),
    ("- just\n- a list\n", None, None),
])
def test_bad_scene_files_name_the_key_or_line(tmp_path, text, where, line):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(DataFormatError) as info:
        load_scene(path)
    message = str(info.value)
    assert message.startswith(str(path))
    if where is not None:
        assert f"field '{where}" in message
    if line is not None:
        assert f":{line}:" in message


# ---------------------------------------------------------------- procedural layouts
@pytest.mark.parametrize("seed", range(6))
def test_generated_layouts_are_plausible(seed):
    spec = generate_scene(seed)
    assert spec == generate_scene(seed)  # deterministic
    world = compile_world(spec)
    drivable = world.drivable
    footprints = [footprint_of(a) for a in spec.actors]
    # Road users do not overlap each other at the start.
    for i, a in enumerate(footprints):
        for b in footprints[i + 1:]:
            assert a.intersection(b).area < 1e-6
    for actor in spec.actors:
        centre = Point(actor.position)
        if actor.cls in ("Car", "Van", "Truck") and not actor.parked:
            assert drivable.contains(centre)  # moving vehicles drive on the road
        if actor.cls == "Pedestrian" and drivable.contains(centre):
            crossings = [o for o in spec.objects if o.kind == "crosswalk"]
            assert any(footprint_of(c).distance(centre) < 1.0 for c in crossings)  # on a crossing
    buildings = [footprint_of(o) for o in spec.objects if o.kind == "building"]
    assert buildings and not any(b.intersects(drivable) for b in buildings)
    assert len(spec.actors) >= 3


def test_generator_kinds_differ():
    urban = generate_scene(11, kind="urban")
    suburban = generate_scene(11, kind="suburban")
    assert urban.name.startswith("urban") and suburban.name.startswith("suburban")
    urban_heights = [o.height for o in urban.objects if o.kind == "building"]
    suburban_heights = [o.height for o in suburban.objects if o.kind == "building"]
    assert max(suburban_heights) < 10 < max(urban_heights)
    with pytest.raises(ValueError, match="unknown scene kind"):
        generate_scene(1, kind="rural")  # type: ignore[arg-type]


def test_a_sequence_world_covers_the_whole_drive():
    spec = generate_scene(2, ego_speed=12.0, duration=20.0)
    road = LineString(spec.roads[0].centerline)
    assert road.bounds[2] > 12.0 * 20.0 + 100  # the road runs past the end of the drive
    assert shapely.box(-50, -5, 300, 5).within(compile_world(spec).drivable.buffer(1.0))


# ---------------------------------------------------------------- motion
def test_rolling_shutter_shears_static_objects_behind_a_moving_ego():
    pole = {"kind": "pole", "position": [-15, -6], "arm": 0, "height": 4, "radius": 0.15}
    scene = {"objects": [pole], "sensor": "HDL-64E"}
    still = render({**scene, "ego": {"speed": 0}})
    moving = render({**scene, "ego": {"speed": 20}})

    def pole_points(frame):
        label = frame.points.channel("label")
        return frame.points.xyz[label == 9], frame.points.channel("time")[label == 9]

    (p0, _), (p1, t1) = pole_points(still), pole_points(moving)
    # Behind on the right, the head fires ~44 ms after the frame's instant, when the ego is ~0.9 m
    # further on: in the sensor frame of that instant (raw points) the pole is ~0.9 m further back.
    assert abs(t1.mean()) > 0.03
    shift = p1[:, 0].mean() - p0[:, 0].mean()
    assert shift == pytest.approx(-20 * t1.mean(), abs=0.1)


def test_actors_move_between_frames():
    description = street(actors=[{"class": "Cyclist", "position": [15, -3], "speed": 5, "id": 3}])
    world = compile_world(parse_scene(description))
    from lidarfuzz.sim import Renderer

    renderer = Renderer(world)
    first, later = renderer.render(0.0), renderer.render(1.0)
    a = first.boxes.select(first.boxes.track_ids == 3).centers[0]
    b = later.boxes.select(later.boxes.track_ids == 3).centers[0]
    assert b[0] - a[0] == pytest.approx(5.0, abs=0.05)


def test_a_car_following_across_the_sweep_seam_stays_in_one_piece():
    # Straight behind, the head passes the car's two halves a whole sweep apart; a car that
    # keeps its distance must still come out in one piece, not split by the ego's travel.
    follow = {"ego": {"speed": 15},
              "actors": [{"class": "Car", "position": [-12, 0], "speed": 15, "id": 1, "reflectivity": 0.5}]}

    def split(description):
        scene = render(description)
        car = scene.points.xyz[scene.points.channel("instance") == 1]
        front = car[car[:, 0] > -11.0]  # the face towards the sensor (and the bonnet above it)
        left, right = front[front[:, 1] > 0.1], front[front[:, 1] < -0.1]
        assert len(left) > 20 and len(right) > 20
        return abs(float(np.max(left[:, 0]) - np.max(right[:, 0])))

    assert split(follow) < 0.1
    # A parked car at the seam IS split by the ego's travel during the sweep: 15 m/s × 0.1 s.
    parked = {**follow, "actors": [{**follow["actors"][0], "speed": 0}]}
    assert split(parked) == pytest.approx(1.5, abs=0.15)
