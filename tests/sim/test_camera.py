"""The built-in world's camera: images and depth of the world the LiDAR sees, steering labels, gen --camera."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.sim import Renderer, compile_world, parse_scene
from lidarfuzz.sim.camera import SKY, CameraRenderer, Lighting, camera_calibration
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.sim.generate import generate_scene
from lidarfuzz.sim.materials import MATERIAL_ID, PAINT_MATERIAL
from lidarfuzz.sim.steering import LaneOffset, steering_labels
from lidarfuzz.sim.terrain import WHEELBASE
from tests.sim.helpers import street

SMALL = (160, 120)


def camera_of(scene: dict[str, Any] | None = None, size: tuple[int, int] = SMALL, seed: int = 3,
              **kwargs: Any) -> CameraRenderer:
    spec = parse_scene(scene) if scene is not None else generate_scene(seed)
    calib = camera_calibration(KittiCalibration.default(), size)
    return CameraRenderer(Renderer(compile_world(spec), calib, threads=1), size, **kwargs)


def pixel_of(camera: CameraRenderer, world_xyz: tuple[float, float, float], t_ref: float = 0.0) -> tuple[int, int]:
    """(row, column) of the pixel whose centre a world point projects nearest to."""
    pose = camera.pose(t_ref)
    local = (np.asarray(world_xyz, np.float64) - pose[:3, 3]) @ pose[:3, :3]  # world → camera axes
    u, v, w = camera.intrinsics @ local
    return round(v / w), round(u / w)


# ------------------------------------------------------------------ geometry
def test_the_image_size_keeps_kitti_principal_ray_and_horizontal_view():
    kitti = KittiCalibration.default()
    assert np.array_equal(camera_calibration(kitti, (1242, 375)).P2, kitti.P2)  # KITTI's own size: unchanged
    small = camera_calibration(kitti, (640, 480))
    s = 640 / 1242  # by hand: f = 721.5377 s = 371.807, cx = 609.5593 s = 314.105, cy = 172.854 s + (480 − 375 s)/2
    assert small.P2[0, 0] == pytest.approx(721.5377 * s) and small.P2[1, 1] == pytest.approx(721.5377 * s)
    assert small.P2[0, 2] == pytest.approx(314.105, abs=1e-3) and small.P2[1, 2] == pytest.approx(232.453, abs=1e-3)
    assert small.image_shape == (480, 640)
    # The same horizontal field of view: the image's edge columns see the same directions.
    fov = 2 * np.arctan([kitti.P2[0, 2] / kitti.P2[0, 0], small.P2[0, 2] / small.P2[0, 0]])
    assert fov[0] == pytest.approx(fov[1])


def test_same_seed_same_image_and_another_seed_another():
    one, again = camera_of().render(0.0), camera_of().render(0.0)
    assert np.array_equal(one.image, again.image) and np.array_equal(one.depth, again.depth)
    other = camera_of(seed=4).render(0.0)
    assert not np.array_equal(one.image, other.image)
    assert one.image.shape == (120, 160, 3) and one.image.dtype == np.uint8 and one.depth.dtype == np.float32


def test_bands_on_threads_give_the_same_image_as_one_thread():
    spec = generate_scene(5)
    calib = camera_calibration(KittiCalibration.default(), (320, 240))
    single = CameraRenderer(Renderer(compile_world(spec), calib, threads=1), (320, 240)).render(0.0)
    threaded = CameraRenderer(Renderer(compile_world(spec), calib, threads=3), (320, 240)).render(0.0)
    assert np.array_equal(single.image, threaded.image) and np.array_equal(single.depth, threaded.depth)


def test_the_sky_is_above_the_horizon_blue_and_infinitely_far():
    camera = camera_of(street())  # an open road: nothing above the horizon
    layers = camera.layers(0.0)
    # By hand: the top row looks atan((232.45 − 0) / 371.8) = 32° up (640×480; the same at 160×120).
    top = slice(0, 20)
    assert np.all(layers.material[top] == SKY) and np.all(np.isinf(layers.depth[top]))
    red, blue = layers.image[top, :, 0].astype(int), layers.image[top, :, 2].astype(int)
    assert np.all(blue > red + 20) and np.all(blue > 120)  # blue, not black
    # The ground is below: the bottom row sees the road 1.73 m below the camera (not sky, finite).
    assert np.all(layers.material[-1] != SKY) and np.all(np.isfinite(layers.depth[-1]))
    # The image is upright: the sky on top, and the top is brighter blue than the bottom (asphalt).
    assert layers.image[0].mean() > layers.image[-1].mean()


def test_a_shadow_is_darker_by_the_suns_share():
    # Sun from +y (the left), 45° high; a 5 m wall along the road at y = 6 shades the ground
    # between y = 1 and y = 6 (by hand: shadow length 5 m / tan 45°).
    sun = (0.0, float(np.cos(np.pi / 4)), float(np.sin(np.pi / 4)))
    light = Lighting(sun=sun, sun_irradiance=(2.0, 2.0, 2.0), sky_irradiance=(0.5, 0.5, 0.5), haze_distance=1e9)
    scene = street(objects=[{"kind": "wall", "start": [-60, 6.0], "end": [80, 6.0], "height": 5.0}])
    camera = camera_of(scene, (320, 240), lighting=light)
    layers = camera.layers(0.0)
    albedo = camera_of(scene, (320, 240), lighting=Lighting(sun=sun, sun_irradiance=(0, 0, 0),
                                                             sky_irradiance=(1, 1, 1), haze_distance=1e9)).layers(0.0)
    lit_pixel, shaded_pixel = pixel_of(camera, (20.0, -2.0, 0.0)), pixel_of(camera, (20.0, 2.0, 0.0))
    for pixel in (lit_pixel, shaded_pixel):
        assert layers.material[pixel] == MATERIAL_ID["asphalt"]
    assert layers.sunlit[lit_pixel] == pytest.approx(np.sin(np.pi / 4), abs=1e-3) and layers.sunlit[shaded_pixel] == 0
    # Radiance = albedo × (sunlit × 2 + 0.5) on flat ground (the second render gives albedo × 1):
    # lit / shaded = (0.7071 × 2 + 0.5) / 0.5 = 3.828 for the same albedo.
    lit = layers.radiance[lit_pixel] / albedo.radiance[lit_pixel]
    shaded = layers.radiance[shaded_pixel] / albedo.radiance[shaded_pixel]
    assert lit / shaded == pytest.approx(np.full(3, 3.828), rel=1e-3)
    assert layers.image[lit_pixel].mean() > 1.5 * layers.image[shaded_pixel].mean()


def test_markings_are_brighter_than_the_asphalt_beside_them():
    camera = camera_of(street(), (320, 240))
    layers = camera.layers(0.0)
    # The two-way road's solid centre line is 0.15 m wide at y = 0; its right edge line at y = −3.3.
    for paint, asphalt in (((12.0, 0.0, 0.006), (12.0, 0.6, 0.0)), ((10.0, -3.3, 0.006), (10.0, -2.6, 0.0))):
        marking, beside = pixel_of(camera, paint), pixel_of(camera, asphalt)
        assert layers.material[marking] == MATERIAL_ID["road-paint"]
        assert layers.material[beside] == MATERIAL_ID["asphalt"]
        # Albedo 0.72 against 0.085 (8.5 times) under the same light; in 8-bit sRGB about twice as bright.
        assert layers.radiance[marking].mean() > 5 * layers.radiance[beside].mean()
        assert layers.image[marking].mean() > 1.8 * layers.image[beside].mean() and layers.image[marking].max() < 255


@pytest.mark.parametrize("moving", [False, True])
def test_lidar_points_project_onto_the_pixels_that_show_them(moving):
    """P2 of the calibration describes the image: an actor's LiDAR points land on pixels of that
    actor, whose depth is the point's camera z (LiDAR range noise is 2 cm)."""
    size = (640, 480)
    if moving:  # a generated street: the ego and road users move (the LiDAR's rolling shutter)
        spec = generate_scene(8)
    else:
        spec = parse_scene(street(actors=[{"class": "Car", "position": [14, -1.75], "parked": True},
                                          {"class": "Pedestrian", "position": [9, 2.5], "parked": True}]))
    calib = camera_calibration(KittiCalibration.default(), size)
    renderer = Renderer(compile_world(spec), calib, threads=1)
    frame = renderer.render(0.0)
    layers = CameraRenderer(renderer, size).layers(0.0)
    points = frame.points
    actor = points.channel("instance") >= 0
    xyz = np.asarray(points.xyz)[actor]
    uv, z = frame.calib.lidar_to_image(xyz)
    column, row = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    inside = (z > 1.0) & (column >= 0) & (column < size[0]) & (row >= 0) & (row < size[1])
    assert inside.sum() >= 50
    depth = layers.depth[row[inside], column[inside]]
    error = np.abs(depth - (z[inside] + calib.P2[2, 3]))
    assert np.isfinite(depth).all() and np.all(layers.material[row[inside], column[inside]] != SKY)
    # Points on an object's outline may round onto the pixel beside it: most, not all, agree.
    assert np.median(error) < 0.05 and np.mean(error < 0.2) > (0.85 if moving else 0.92)
    assert np.mean(layers.owner[row[inside], column[inside]] >= 0) > (0.85 if moving else 0.92)


def test_vehicle_paint_follows_the_paint_draw():
    camera = camera_of(seed=3)
    colours = {tuple(camera._actor_colour[a.index]) for a in camera.renderer.world.actors if a.cls == "Car"}
    assert len(colours) > 1  # not one colour for all
    layers = camera.layers(0.0)
    painted = layers.material == PAINT_MATERIAL
    assert painted.any() and np.all(layers.owner[painted] >= 0)


def test_wheels_are_solid_not_speckled_with_paint():
    """A tyre's outer face lies in the plane of the car's side (Embree returns either): the
    pixels around a wheel's centre show tyre throughout."""
    from lidarfuzz.sim.camera import _wheel_discs

    size = (3.9, 1.63, 1.53)
    # Parked in the oncoming lane ahead: its right side (y = 1.75 − |y| of the wheel faces) faces the camera.
    scene = street(actors=[{"class": "Car", "position": [9.0, 1.75], "size": list(size), "parked": True}])
    camera = camera_of(scene, (640, 480))
    layers = camera.layers(0.0)
    wheels = [w for w in _wheel_discs("Car", size) if w[2] > 0]
    assert len(wheels) == 4
    for x, z, _radius, side in wheels:
        row, column = pixel_of(camera, (9.0 + x, 1.75 - side, z))
        patch = layers.material[row - 3:row + 4, column - 1:column + 2]  # seen obliquely: a narrow ellipse
        assert np.all(patch == MATERIAL_ID["tyre"]), patch


# ------------------------------------------------------------------ steering labels
def test_a_route_bending_left_steers_left_and_right_steers_right():
    for side, sign in ((1.0, 1.0), (-1.0, -1.0)):
        scene = street(ego={"position": [0, -1.75], "speed": 5.0, "corner_radius": 8.0,
                            "route": [[0, -1.75], [40, -1.75], [40, -1.75 + side * 40]]})
        spec = parse_scene(scene)
        steering, speed = steering_labels(spec, np.arange(0.0, 16.0, 0.05))
        # By hand: where both the car and the point 8 m ahead lie on the 8 m arc, pure pursuit
        # holds the arc's curvature exactly: atan(2.71 / 8) = 0.3264 rad.
        assert (sign * steering).max() == pytest.approx(np.arctan(WHEELBASE / 8.0), abs=2e-3)
        assert np.all(sign * steering >= -1e-9)  # never the wrong way
        assert abs(steering[0]) < 1e-9  # the bend is 40 m ahead at the start: straight on
        assert speed.max() > 0


def test_an_ego_right_of_its_lane_centre_steers_back_left():
    lane = parse_scene(street(ego={"position": [0, -1.75], "speed": 8.0}))
    right = LaneOffset(lateral=-0.5, heading_deg=0.0).applied(lane)
    assert right.ego.position == (0.0, -2.25)
    steering, _ = steering_labels(right, np.array([0.0]), lane=lane)
    # By hand: the lane point 8 m ahead is 0.5 m to the left: κ = 2·0.5 / (8² + 0.5²) = 0.015564,
    # δ = atan(2.71 × 0.015564) = 0.042154 rad (left positive).
    assert steering[0] == pytest.approx(0.042154, abs=1e-5)
    left = LaneOffset(lateral=0.5, heading_deg=0.0).applied(lane)
    assert steering_labels(left, np.array([0.0]), lane=lane)[0][0] == pytest.approx(-0.042154, abs=1e-5)
    # Turned 5° left on the lane's centre: the point 8 m ahead lies to the right: steer right.
    turned = LaneOffset(lateral=0.0, heading_deg=5.0).applied(lane)
    assert steering_labels(turned, np.array([0.0]), lane=lane)[0][0] < -0.02
    assert steering_labels(lane, np.array([0.0]), lane=lane)[0][0] == pytest.approx(0.0, abs=1e-12)


def test_lane_offsets_are_drawn_per_seed_within_their_ranges():
    offsets = [LaneOffset.draw(seed) for seed in range(200)]
    lateral = np.array([o.lateral for o in offsets])
    heading = np.array([o.heading_deg for o in offsets])
    assert lateral.min() >= -0.8 and lateral.max() <= 0.8 and heading.min() >= -5 and heading.max() <= 5
    assert lateral.std() > 0.3 and heading.std() > 2.0 and LaneOffset.draw(7) == LaneOffset.draw(7)


# ------------------------------------------------------------------ gen --camera
def digest(root: Path, sub: str) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted((root / sub).iterdir())}


@pytest.fixture(scope="module")
def camera_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("gen") / "camera"
    result = CliRunner().invoke(app, ["gen", "--frames", "2", "--seed", "4", "--out", str(out), "--sensor", "VLP-16",
                                      "--workers", "1", "--camera", "--image-size", "160x120"])
    assert result.exit_code == 0, result.output
    return out


def test_gen_camera_writes_images_depth_and_steering(camera_set):
    out = camera_set
    for frame_id in ("000000", "000001"):
        image = cv2.imread(str(out / "image_2" / f"{frame_id}.png"), cv2.IMREAD_UNCHANGED)
        depth = cv2.imread(str(out / "depth_2" / f"{frame_id}.png"), cv2.IMREAD_UNCHANGED)
        assert image.shape == (120, 160, 3) and image.dtype == np.uint8
        assert depth.shape == (120, 160) and depth.dtype == np.uint16
        assert (depth[0] == 0).all() or (depth == 0).any()  # sky (or beyond 255 m) is 0
        assert depth[-1].min() > 0 and depth[-1].max() < 20 * 256  # the road just ahead: under 20 m
        calib = KittiCalibration.from_file(out / "calib" / f"{frame_id}.txt")
        assert np.allclose(calib.P2, camera_calibration(KittiCalibration.default(), (160, 120)).P2, atol=1e-6)
    lines = (out / "steering.csv").read_text().splitlines()
    assert lines[0] == "frame_id,steering,speed" and len(lines) == 3
    rows = [line.split(",") for line in lines[1:]]
    assert [r[0] for r in rows] == ["000000", "000001"]
    assert all(abs(float(r[1])) < 0.3 and float(r[2]) > 0 for r in rows)
    summary = json.loads((out / "lidarfuzz_sim.json").read_text())
    assert summary["complete"] and summary["camera"]["images"] == 2 and summary["camera"]["size"] == [160, 120]
    assert summary["config"]["camera"] == {"width": 160, "height": 120}
    # The label is the one the frame's saved scene and its lane give.
    scene = parse_scene(json.loads((out / "scenes" / "000000.json").read_text()))
    assert scene.ego.position[1] != -1.75 or scene.ego.yaw != 0.0  # moved off its lane


def test_frames_in_memory_are_the_frames_on_disk(camera_set):
    from lidarfuzz.sim.dataset import render_camera_frames

    config = GenerationConfig(frames=2, seed=4, sensor="VLP-16", camera=(160, 120))
    rows = {r.split(",")[0]: r.split(",") for r in (camera_set / "steering.csv").read_text().splitlines()[1:]}
    for scene, sample in render_camera_frames(config):
        on_disk = cv2.imread(str(camera_set / "image_2" / f"{sample.frame_id}.png"), cv2.IMREAD_COLOR)[:, :, ::-1]
        assert np.array_equal(sample.image, on_disk) and scene.frame_id == sample.frame_id
        assert sample.steering == pytest.approx(float(rows[sample.frame_id][1]), abs=1e-6)
        assert sample.metadata["speed"] == pytest.approx(float(rows[sample.frame_id][2]), abs=1e-4)
        depth = cv2.imread(str(camera_set / "depth_2" / f"{sample.frame_id}.png"), cv2.IMREAD_UNCHANGED)
        near = np.isfinite(sample.depth) & (sample.depth < 255)
        assert np.allclose(depth[near] / 256.0, sample.depth[near], atol=1 / 512 + 1e-6)
        assert np.all(depth[~near] == 0)


def test_gen_camera_resumes_missing_images(camera_set, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(camera_set, copy)
    (copy / "image_2" / "000001.png").unlink()
    summary = json.loads((copy / "lidarfuzz_sim.json").read_text())
    summary["complete"] = False
    (copy / "lidarfuzz_sim.json").write_text(json.dumps(summary))
    config = GenerationConfig(frames=2, seed=4, sensor="VLP-16", camera=(160, 120))
    result = generate_dataset(copy, config, workers=1, resume=True)
    assert result.resumed == 1 and result.generated == 1 and result.images == 2
    assert digest(copy, "image_2") == digest(camera_set, "image_2")
    assert (copy / "steering.csv").read_text() == (camera_set / "steering.csv").read_text()


def test_a_camera_does_not_change_a_sequences_lidar(tmp_path):
    plain = GenerationConfig(frames=2, seed=1, sensor="VLP-16", sequence=True)
    with_camera = GenerationConfig(frames=2, seed=1, sensor="VLP-16", sequence=True, camera=(64, 48))
    assert "camera" not in plain.to_json()  # the configuration (and resume) of LiDAR-only sets as before
    generate_dataset(tmp_path / "a", plain, workers=1)
    generate_dataset(tmp_path / "b", with_camera, workers=1)
    assert digest(tmp_path / "a", "velodyne") == digest(tmp_path / "b", "velodyne")
    assert not (tmp_path / "a" / "image_2").exists() and not (tmp_path / "a" / "steering.csv").exists()
    assert len(list((tmp_path / "b" / "image_2").iterdir())) == 2


def test_a_drive_log_has_steering_from_its_turn(tmp_path):
    from lidarfuzz.sim.dataset import sequence_scene

    config = GenerationConfig(frames=300, seed=0, sensor="VLP-16", drive=True, camera=(64, 48))
    spec = sequence_scene(config)
    times = np.arange(300) * 0.1
    steering, _ = steering_labels(spec, times)
    turn = spec.ego.route[2][1] - spec.ego.route[1][1]  # + for a left turn
    assert np.sign(steering[np.argmax(np.abs(steering))]) == np.sign(turn)
    assert np.abs(steering).max() > 0.15 and abs(steering[0]) < 1e-6


def test_a_bad_image_size_is_one_line(tmp_path):
    for args in (["--camera", "--image-size", "640by480"], ["--camera", "--image-size", "4x4"],
                 ["--image-size", "640x480"]):
        result = subprocess.run([sys.executable, "-c", "from lidarfuzz.cli.app import main; main()", "gen",
                                 "--frames", "1", "--out", str(tmp_path / "x"), *args],
                                capture_output=True, text=True, timeout=60)
        assert result.returncode == 2 and result.stderr.count("\n") == 1 and "--image-size" in result.stderr
    assert not (tmp_path / "x").exists()
