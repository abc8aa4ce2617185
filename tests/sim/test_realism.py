"""Realism of simulated frames: ground that is not flat, KITTI-like intensities, real drop-outs.

Expected values are worked out from the scene descriptions by hand (in the comments), never
from the rendered points they check. Statistics of real scans are KITTI object-benchmark
training frames 000000–000002 (HDL-64E), measured once and written here.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.scene.geometry import points_in_boxes
from lidarfuzz.scene.semantics import SEMANTIC_ID
from lidarfuzz.sim import GenerationConfig, Renderer, compile_world, generate_scene, parse_scene, render_frames
from lidarfuzz.sim.realism import RealismConfig
from lidarfuzz.sim.sensor import SENSOR_PRESETS, Receiver, load_sensor
from tests.sim.helpers import render

# KITTI training 000000–000002: 10.4 %, 8.5 % and 9.1 % of all returns read exactly 0; across
# KITTI the share runs from 8 to 26 %.
REAL_ZERO_SHARE = (0.08, 0.26)

HILL = {"grade": 0.04, "grade_change": 0.03, "camber": 0.025, "sidewalk_slope": 0.02, "undulation": 0.03,
        "undulation_wavelength": 30.0, "undulation_phase": 0.7}


def surface_of_two_lane_road(x: np.ndarray, y: np.ndarray, terrain: dict[str, float], half_width: float = 3.5,
                             kerb: float = 0.15, sidewalk: float = 3.0) -> np.ndarray:
    """The ground of :func:`tests.sim.helpers.street` worked out from the Terrain's definition:
    base = grade·x + ½·(grade_change/100)·x² + undulation·(0.7 sin(kx + φ) + 0.3 sin(1.7ky + 2.3φ));
    road: + camber·(half width − |y|); sidewalk: + kerb + sidewalk_slope·(|y| − half width)."""
    k = 2 * np.pi / terrain.get("undulation_wavelength", 40.0)
    phase = terrain.get("undulation_phase", 0.0)
    base = (terrain.get("grade", 0.0) * x + 0.5 * terrain.get("grade_change", 0.0) / 100 * x * x
            + terrain.get("undulation", 0.0) * (0.7 * np.sin(k * x + phase) + 0.3 * np.sin(1.7 * k * y + 2.3 * phase)))
    on_road = np.abs(y) <= half_width
    road = base + terrain.get("camber", 0.0) * (half_width - np.abs(y))
    walk = base + kerb + terrain.get("sidewalk_slope", 0.0) * (np.abs(y) - half_width)
    return np.where(on_road, road, np.where(np.abs(y) <= half_width + sidewalk, walk, base + 0.8 * kerb))


def hill_street(**extra: object) -> dict[str, object]:
    scene: dict[str, object] = {
        "roads": [{"centerline": [[-150, 0], [150, 0]], "lanes": 2, "lane_width": 3.5}],
        "ego": {"position": [0, -1.75]},
        "terrain": HILL,
    }
    scene.update(extra)
    return scene


def column_of(xyz: np.ndarray, columns: int) -> np.ndarray:
    """The firing column of each point: the head turns clockwise from behind (azimuth π)."""
    return np.round((np.pi - np.arctan2(xyz[:, 1], xyz[:, 0])) / (2 * np.pi) * columns).astype(int) % columns


def to_world(renderer: Renderer, xyz: np.ndarray) -> np.ndarray:
    pose = renderer.pose_matrix(0.0)
    return xyz @ pose[:3, :3].T + pose[:3, 3]


def test_ground_under_every_box_is_where_the_box_says():
    actors = [
        {"class": "Car", "position": [18, -1.75], "parked": True},            # ahead in the ego lane
        {"class": "Car", "position": [35, 1.75], "yaw": 180, "parked": True},  # oncoming lane: the other crown side
        {"class": "Van", "position": [-12, 1.75], "yaw": 180, "parked": True},
        {"class": "Truck", "position": [45, -1.75], "parked": True},
        {"class": "Pedestrian", "position": [22, -5.0], "parked": True},       # on the sidewalk
        {"class": "Car", "position": [60, -1.75], "speed": 6},
    ]
    renderer = Renderer(compile_world(parse_scene(hill_street(actors=actors))))
    scene = renderer.render(0.0)
    boxes = scene.boxes
    labelled = np.flatnonzero(np.isfinite(boxes.centers).all(axis=1))
    assert len(labelled) >= 4
    for i in labelled:
        centre, (length, width, height), yaw = boxes.centers[i], boxes.sizes[i], boxes.as_array()[i, 6]
        c, s = np.cos(yaw), np.sin(yaw)
        corners = np.array([[centre[0] + c * dx - s * dy, centre[1] + s * dx + c * dy, centre[2] - height / 2]
                            for dx in (-length / 2 * 0.8, 0.0, length / 2 * 0.8)
                            for dy in (-width / 2 * 0.85, 0.0, width / 2 * 0.85)])
        world = to_world(renderer, corners)
        ground = surface_of_two_lane_road(world[:, 0], world[:, 1], HILL)
        # The bottom centre lies on the surface (the plane through the wheels: within 1.5 cm of
        # the curved ground); its corners within 6 cm (a yaw-only box on ground whose grade and
        # crown differ from the ego vehicle's by up to ~5 %).
        assert abs(world[4, 2] - ground[4]) < 0.015, (boxes.labels[i], world[4, 2], ground[4])
        assert np.max(np.abs(world[:, 2] - ground)) < 0.06


def test_a_sloped_and_cambered_road_shows_in_the_ground_points():
    scene_description = hill_street(terrain={"grade": 0.05, "camber": 0.025})
    renderer = Renderer(compile_world(parse_scene(scene_description)))
    scene = renderer.render(0.0)
    label = scene.points.channel("label")
    world = to_world(renderer, scene.points.xyz.astype(np.float64))
    road = (label == SEMANTIC_ID["road"]) & (np.abs(world[:, 0]) < 30)

    def plane(mask: np.ndarray) -> np.ndarray:
        a = np.column_stack([world[mask, 0], world[mask, 1], np.ones(mask.sum())])
        return np.linalg.lstsq(a, world[mask, 2], rcond=None)[0]

    # z = 0.05·x + 0.025·(3.5 − |y|): a 5 % grade along x, and the crown falling 2.5 % to each kerb.
    right, left = plane(road & (world[:, 1] < -0.3)), plane(road & (world[:, 1] > 0.3))
    assert right[0] == pytest.approx(0.05, abs=0.003) and left[0] == pytest.approx(0.05, abs=0.003)
    assert right[1] == pytest.approx(0.025, abs=0.003) and left[1] == pytest.approx(-0.025, abs=0.003)
    # In the sensor frame the car pitches with the road (it stands on it), so near the car the
    # road is level ahead; the crown still falls away across it.
    xyz = scene.points.xyz.astype(np.float64)
    near = (label == SEMANTIC_ID["road"]) & (np.abs(xyz[:, 0]) < 20) & (xyz[:, 1] < 1.0)
    local = np.linalg.lstsq(np.column_stack([xyz[near, 0], np.ones(near.sum())]), xyz[near, 2], rcond=None)[0]
    assert abs(local[0]) < 0.005


def test_a_crest_ahead_drops_the_far_road_below_the_plane_under_the_car():
    # Grade falls by 8 % per 100 m: 25 m ahead the road lies ½ · 0.0008 · 25² = 0.25 m below the
    # plane the car stands on (KITTI training 000002 lies on such a crest: 0.3–0.8 m at 50 m).
    renderer = Renderer(compile_world(parse_scene(hill_street(terrain={"grade_change": -0.08}))))
    scene = renderer.render(0.0)
    label, xyz = scene.points.channel("label"), scene.points.xyz.astype(np.float64)
    road = (label == SEMANTIC_ID["road"]) & (np.abs(xyz[:, 1]) < 3)
    ahead = road & (np.abs(xyz[:, 0] - 25) < 1)
    near = road & (np.abs(xyz[:, 0]) < 6)
    assert np.median(xyz[near, 2]) == pytest.approx(-1.73, abs=0.03)
    assert np.median(xyz[ahead, 2]) - np.median(xyz[near, 2]) == pytest.approx(-0.25, abs=0.03)


def test_dropped_kerbs_lower_the_sidewalk_to_a_lip():
    terrain = {"ramps": [{"position": [20, -3.5], "yaw": -90, "width": 3.0, "depth": 1.0}]}
    world = compile_world(parse_scene(hill_street(terrain=terrain)))
    # At the kerb the ramp keeps a 2 cm lip, half-way up its 1 m depth the sidewalk is half-way
    # between lip and kerb (0.02 + 0.13/2), beyond it and beside it the full 15 cm kerb.
    heights = world.ground.height(np.array([20.0, 20.0, 20.0, 25.0]), np.array([-3.51, -4.0, -5.0, -3.51]))
    np.testing.assert_allclose(heights, [0.02, 0.085, 0.15, 0.15], atol=2e-3)


def test_realism_off_is_the_flat_clean_world():
    config = GenerationConfig(frames=1, seed=4, realism=RealismConfig.off())
    spec = generate_scene(4, realism=RealismConfig.off())
    assert spec.terrain.is_flat
    scene = next(render_frames(config))
    road = scene.points.channel("label") == SEMANTIC_ID["road"]
    assert np.median(scene.points.xyz[road, 2]) == pytest.approx(-1.73, abs=0.01)
    assert np.mean(scene.points.channel("intensity") == 0) < 0.01  # the clean receiver: no zero readings


def test_generated_scenes_draw_their_ground_from_the_ranges():
    ranges = RealismConfig()
    terrains = [generate_scene(seed).terrain for seed in range(6)]
    for t in terrains:
        assert ranges.grade_range[0] <= t.grade <= ranges.grade_range[1]
        assert ranges.camber_range[0] <= t.camber <= ranges.camber_range[1]
    assert len({t.grade for t in terrains}) == 6  # drawn per scene
    # The terrain has its own random stream: the layout is the one the seed gives on flat ground.
    assert generate_scene(3).actors == generate_scene(3, realism=RealismConfig.off()).actors


@pytest.mark.slow
def test_zero_share_and_quantisation_match_kitti():
    scenes = list(render_frames(GenerationConfig(frames=3, seed=11)))
    intensity = np.concatenate([s.points.channel("intensity") for s in scenes])
    assert REAL_ZERO_SHARE[0] <= np.mean(intensity == 0) <= REAL_ZERO_SHARE[1]
    # KITTI stores reflectance in steps of 0.01 (97 distinct values in training 000000).
    np.testing.assert_array_equal(intensity, (np.round(intensity.astype(np.float64) * 100) / 100).astype(np.float32))
    # Far returns read 0 far more often than near ones (KITTI: ~5 % within 20 m, ~90 % at 60–80 m).
    distance = np.concatenate([np.linalg.norm(s.points.xyz, axis=1) for s in scenes])
    assert np.mean(intensity[distance < 20] == 0) < 0.2 < 0.6 < np.mean(intensity[distance > 60] == 0)


def test_quantised_readings_are_multiples_of_the_step():
    scene = render(hill_street(sensor="VLP-16"))
    intensity = scene.points.channel("intensity").astype(np.float64)
    np.testing.assert_allclose(intensity * 100, np.round(intensity * 100), atol=1e-4)


def fan_sensor(**receiver: object) -> dict[str, object]:
    """Eight lasers all at −10°: on open flat grass every one meets the ground 9.81 m away
    (1.73 / tan 10°) at the same incidence, so their readings differ only by calibration."""
    return {"name": "fan", "elevations_deg": [-10.0] * 8, "columns": 1800, "max_range": 100.0,
            "receiver": {"falloff_length": None, "step": 0.0, **receiver}}


def test_lasers_are_calibrated_differently():
    sensor = load_sensor(fan_sensor(gain_spread=0.15, offset_spread=0.0))
    scene = render({"sensor": sensor.model_dump(), "extent": 100})
    ring = scene.points.channel("ring").astype(int)
    means = np.array([scene.points.channel("intensity")[ring == k].mean() for k in range(8)])
    gain, _ = sensor.receiver.calibration(8)
    assert means.std() / means.mean() > 0.05
    # The brightest and darkest rings are the ones with the highest and lowest gain.
    assert np.argmax(means) == np.argmax(gain) and np.argmin(means) == np.argmin(gain)
    uniform = render({"sensor": load_sensor(fan_sensor(gain_spread=0.0, offset_spread=0.0)).model_dump(),
                      "extent": 100})
    ring = uniform.points.channel("ring").astype(int)
    flat = np.array([uniform.points.channel("intensity")[ring == k].mean() for k in range(8)])
    assert flat.std() / flat.mean() < 0.01


def test_drop_outs_are_deterministic_per_seed():
    sensor = SENSOR_PRESETS["HDL-64E"].model_dump()
    sensor["dropouts"] = {**sensor["dropouts"], "azimuth_gaps": 3.0}
    renderer = Renderer(compile_world(parse_scene(hill_street(sensor=sensor))))

    def lost_rays(seed: int) -> set[tuple[int, int]]:
        points = renderer.render(0.0, frame_seed=seed).points
        column = column_of(points.xyz, 2083)
        present = set(zip(column.tolist(), points.channel("ring").astype(int).tolist(), strict=True))
        return {(c, r) for c in range(2083) for r in range(4)} - present  # lowest rings (0 = lowest): ground all round

    first, again, other = lost_rays(1), lost_rays(1), lost_rays(2)
    assert first == again
    assert first != other


def test_the_roof_rack_hides_the_ground_from_the_lowest_lasers():
    # KITTI's shadow: nothing within ±24° behind the car below −13.5°.
    scene = render(hill_street())
    points = scene.points
    azimuth = np.rad2deg(np.arctan2(points.xyz[:, 1], points.xyz[:, 0]))
    elevation = np.rad2deg(np.arctan2(points.xyz[:, 2], np.hypot(points.xyz[:, 0], points.xyz[:, 1])))
    behind = np.abs(azimuth) > 157
    assert not np.any(behind & (elevation < -14.0))
    assert np.any(behind & (elevation > -13.0))


def test_azimuth_gaps_remove_every_laser():
    sensor = load_sensor({"preset": "VLP-16", "dropouts": {"azimuth_gaps": 4.0, "gap_columns": [20, 20]}})
    scene = render({"sensor": sensor.model_dump(), "extent": 100, "seed": 5})
    column = column_of(scene.points.xyz, 1800)
    empty = np.setdiff1d(np.arange(1800), column)
    # Open ground: every column has ground returns except in the gaps (Poisson(4) gaps of 20 columns).
    assert len(empty) >= 20 and len(empty) % 20 <= 2 * (len(empty) // 20)


def test_moving_road_users_are_seen_whatever_the_ego_heading():
    counts = []
    for yaw in (0.0, 90.0, 200.0):
        c, s = np.cos(np.deg2rad(yaw)), np.sin(np.deg2rad(yaw))
        scene = render({"ego": {"position": [0, 0], "yaw": yaw},
                        "actors": [{"class": "Car", "position": [15 * c, 15 * s], "yaw": yaw, "speed": 5}]})
        counts.append(int((scene.points.channel("instance") == 0).sum()))
    assert min(counts) > 100 and max(counts) - min(counts) < 0.1 * max(counts)


def test_receiver_clean_is_the_linear_reading():
    clean = Receiver.clean()
    reflectivity = np.array([0.1, 0.5], np.float32)
    cos = np.array([1.0, 0.5], np.float32)
    distance = np.array([10.0, 40.0], np.float32)
    reading = clean.read(reflectivity, cos, distance, np.zeros(2, np.intp), np.zeros(2, np.float32), 1)
    # e = ρ · (0.35 + 0.65 cos θ) · exp(−r / 400): 0.1 · 1 · e^−0.025, 0.5 · 0.675 · e^−0.1
    np.testing.assert_allclose(reading, [0.1 * np.exp(-0.025), 0.5 * 0.675 * np.exp(-0.1)], rtol=1e-5)


def test_per_frame_randomisation_changes_the_sensor_deterministically():
    config = GenerationConfig(frames=2, seed=0, realism=RealismConfig.randomised())
    from lidarfuzz.sim.dataset import _frame_scene

    # each frame's scene (the first of the pair; the second is its lane, the same without a camera)
    a, b, a_again = _frame_scene(config, 0)[0], _frame_scene(config, 1)[0], _frame_scene(config, 0)[0]
    assert a == a_again
    assert a.sensor != b.sensor
    sensor = load_sensor(a.sensor)
    assert 0.06 <= sensor.receiver.gain_spread <= 0.2
    # The default keeps one sensor (KITTI's receiver, one calibration) for every frame; only its
    # pitch and roll against the road vary, within KITTI's 0.17–0.64° of pitch.
    first, second = (load_sensor(_frame_scene(GenerationConfig(frames=2), k)[0].sensor) for k in (0, 1))
    assert first.receiver == second.receiver == SENSOR_PRESETS["HDL-64E"].receiver
    assert first.mount_pitch_deg != second.mount_pitch_deg
    assert 0.15 <= first.mount_pitch_deg <= 0.65


@pytest.mark.parametrize("seed", [0, 1])
def test_labelled_objects_points_lie_in_their_boxes_on_sloping_ground(seed):
    scene = Renderer(compile_world(generate_scene(seed, ego_speed=10.0))).render(0.0)
    instance = scene.points.channel("instance")
    labelled = scene.boxes.select(scene.boxes.has_geometry)
    assert len(labelled) > 0
    for i in range(len(labelled)):
        own = scene.points.xyz[instance == labelled.track_ids[i]]
        # KITTI boxes turn about the vertical only: a vehicle whose ground differs from the ego
        # vehicle's by up to ~5 % (grade change and crown) sticks out at its ends by ≤ 5 % of half its length.
        margin = 0.1 + 0.05 * labelled.sizes[i, 0] / 2
        inside = points_in_boxes(own, labelled.as_array()[i:i + 1], margin=margin)[:, 0]
        assert inside.all(), f"{labelled.labels[i]} {labelled.track_ids[i]}: {np.sum(~inside)} points outside"


@pytest.mark.slow
def test_randomised_realism_gives_the_same_bytes_whatever_the_worker_count(tmp_path):
    import hashlib

    from lidarfuzz.sim import generate_dataset

    def digest(root):
        return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted((root / "velodyne").iterdir())}

    config = GenerationConfig(frames=3, seed=5, sensor="VLP-16", realism=RealismConfig.randomised())
    generate_dataset(tmp_path / "one", config, workers=1)
    generate_dataset(tmp_path / "two", config, workers=2)
    assert digest(tmp_path / "one") == digest(tmp_path / "two")
