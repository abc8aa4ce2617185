"""Object operators and re-labelling on real-like frames: sloped, cambered ground, a scan cropped to
the camera's view, zero-intensity returns, no ring channel, an irregular beam pattern.

The frames are ray-cast here, in the test, from a closed-form ground and boxes, so every expected
value (the ground under a box, the returns a moved car would give) comes from that geometry, not
from the code under test. Their statistics follow the real KITTI frames the project checks by hand
(HDL-64E: 64 beams from −24.8° to +2°, ~0.18° between firings, per-laser azimuth offsets; scans
cropped to the camera as KITTI detectors use them; 8–26 % of returns with intensity 0 — 15 % here).
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators import generator
from lidarfuzz.operators.lidar.common import relabel_in_image
from lidarfuzz.operators.lidar.geometric import RotateZ, RotationParams
from lidarfuzz.operators.lidar.objects import (
    GROUND_BAND,
    ObjectInsertion,
    ObjectLibrary,
    ObjectRotate,
    ObjectRotateParams,
    ObjectScale,
    ObjectScaleParams,
    ObjectTranslate,
    ObjectTranslateParams,
)
from lidarfuzz.oracles.kitti_eval import KittiFrame, evaluate_kitti
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.geometry import points_in_boxes
from lidarfuzz.scene.labels import camera_labels
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

CALIB = KittiCalibration.default()
# Ground: 1.73 m below the sensor (KITTI's mount height) at the origin, rising 3 % ahead and 2 %
# to each side of the road's axis (a camber), so no single plane fits it everywhere.
HEIGHT, SLOPE, CAMBER = -1.73, 0.03, 0.02
CAR = (3.9, 1.6, 1.5)
AZ_STEP = np.deg2rad(0.18)
MAX_RANGE = 80.0


def ground_z(x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
    return HEIGHT + SLOPE * np.asarray(x) + CAMBER * np.abs(np.asarray(y))


def beams(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """64 beam elevations (irregular by ±0.03°, as calibrated lasers are) and per-beam azimuth offsets."""
    rng = np.random.default_rng(seed)
    elevation = np.sort(np.deg2rad(np.linspace(-24.8, 2.0, 64) + rng.normal(0.0, 0.03, 64)))
    return elevation, rng.uniform(0.0, AZ_STEP, 64)


def scan(boxes: np.ndarray, seed: int = 0, walls: np.ndarray | None = None) -> PointCloud:
    """Ray-cast the ground and the boxes (M×7; ``walls`` too, any tall boxes) with the beams of
    :func:`beams`, keep the returns the camera sees, 15 % of them with intensity 0."""
    elevation, offset = beams()
    azimuth = np.arange(np.deg2rad(-50.0), np.deg2rad(50.0), AZ_STEP)
    e = np.repeat(elevation, len(azimuth))
    a = (azimuth[None, :] + offset[:, None]).ravel()
    d = np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    # Ground: t·dz = HEIGHT + t·(SLOPE·dx + CAMBER·|dy|)  →  t = HEIGHT / (dz − SLOPE·dx − CAMBER·|dy|).
    denominator = d[:, 2] - SLOPE * d[:, 0] - CAMBER * np.abs(d[:, 1])
    with np.errstate(divide="ignore"):
        t = np.where(denominator < 0, HEIGHT / denominator, np.inf)
    solids = boxes if walls is None else np.concatenate([boxes.reshape(-1, 7), walls.reshape(-1, 7)])
    for box in solids.reshape(-1, 7):  # slab test per box, all rays at once
        c, s = np.cos(box[6]), np.sin(box[6])
        origin = -np.array([c * box[0] + s * box[1], -s * box[0] + c * box[1], box[2]])
        local = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-box[3:6] / 2 - origin) / local
            t2 = (box[3:6] / 2 - origin) / local
        near = np.nanmax(np.minimum(t1, t2), axis=1)
        far = np.nanmin(np.maximum(t1, t2), axis=1)
        t = np.where((near <= far) & (near > 0) & (near < t), near, t)
    rng = np.random.default_rng(seed + 1)
    hit = t < MAX_RANGE
    xyz = d[hit] * (t[hit] + rng.normal(0.0, 0.01, int(hit.sum())))[:, None]
    xyz = xyz[CALIB.in_view(xyz)]
    intensity = np.where(rng.random(len(xyz)) < 0.15, 0.0, rng.uniform(0.02, 0.6, len(xyz)))
    return PointCloud(np.column_stack([xyz, intensity]).astype(np.float32))


def car_on_ground(x: float, y: float, yaw: float) -> np.ndarray:
    return np.array([x, y, float(ground_z(x, y)) + CAR[2] / 2, *CAR, yaw])


def place_cars(seed: int, count: int, ranges: tuple[float, float] = (8.0, 24.0)) -> np.ndarray:
    """Cars in the camera's view, at least 6 m apart."""
    rng = np.random.default_rng(seed)
    cars: list[np.ndarray] = []
    while len(cars) < count:
        r, az = rng.uniform(*ranges), rng.uniform(np.deg2rad(-32), np.deg2rad(32))
        x, y = r * np.cos(az), r * np.sin(az)
        if all(np.hypot(x - c[0], y - c[1]) > 6.0 for c in cars):
            cars.append(car_on_ground(x, y, rng.uniform(-np.pi, np.pi)))
    return np.array(cars)


def frame(cars: np.ndarray, frame_id: str = "000000", walls: np.ndarray | None = None) -> Scene:
    boxes = Boxes3D.from_array(cars, ["Car"] * len(cars), track_ids=np.arange(len(cars)),
                               occlusion=np.zeros(len(cars), int))
    return Scene(points=scan(cars, walls=walls), boxes=relabel_in_image(boxes, CALIB), calib=CALIB,
                 frame_id=frame_id)


def object_points(cloud: PointCloud, box: np.ndarray) -> int:
    """Returns in the box (grown 5 cm) above the true ground's 15 cm band."""
    inside = points_in_boxes(cloud.xyz, box[None], margin=0.05)[:, 0]
    z = cloud.xyz[inside]
    return int(np.count_nonzero(z[:, 2] > ground_z(z[:, 0], z[:, 1]) + GROUND_BAND))


def rows(cloud: PointCloud) -> set[tuple[float, ...]]:
    return {tuple(r) for r in cloud.data.tolist()}


@pytest.fixture(scope="module")
def scene() -> Scene:
    return frame(place_cars(1, 6))


@pytest.fixture(scope="module")
def library() -> ObjectLibrary:
    """Cars cut out of two other real-like frames."""
    return ObjectLibrary.from_scenes([frame(place_cars(2, 6), "000002"), frame(place_cars(3, 6), "000003")],
                                     min_points=30)


def test_the_frames_look_like_camera_cropped_kitti_scans(scene):
    xyz = scene.points.xyz
    assert CALIB.in_view(xyz).all() and 10_000 < len(xyz) < 40_000
    assert 0.12 < np.mean(scene.points.intensity == 0) < 0.18
    assert not scene.points.has("ring")


# --------------------------------------------------------------------------- insertion
def test_inserted_objects_stand_on_the_local_ground_and_are_seen(scene, library):
    op = ObjectInsertion(objects=library, count_range=(3, 3))
    for trial in range(3):
        mutant, params = op(scene, generator(5, "000000", 0, trial))
        assert len(params.insertions) == 3 and params.reason == ""
        before = rows(scene.points)
        new = PointCloud(np.array([r for r in mutant.points.data.tolist() if tuple(r) not in before],
                                  np.float32).reshape(-1, 4))
        for box, trunc, occ, bbox in zip(mutant.boxes.as_array()[len(scene.boxes):],
                                         mutant.boxes.truncation[len(scene.boxes):],
                                         mutant.boxes.occlusion[len(scene.boxes):],
                                         mutant.boxes.bbox2d[len(scene.boxes):], strict=True):
            # Bottom on the true ground under the footprint's centre, within a few centimetres
            # (the camber bends the ground by 2 cm per metre across the road's axis).
            assert abs((box[2] - box[5] / 2) - ground_z(box[0], box[1])) < 0.05
            assert object_points(new, box) >= op.config.min_points
            assert trunc <= 0.15 and occ in (0, 1, 2) and np.isfinite(bbox).all()


def test_insertion_where_the_sensor_sees_nothing_inserts_nothing_and_says_why(scene, library):
    # Behind the car: a camera-cropped scan has no returns there, so no ground and no points.
    behind = ObjectInsertion(objects=library, azimuth_range=(150.0, 210.0), in_camera_view=False)
    mutant, params = behind(scene, generator(5, "000000", 0, 0))
    assert params.is_identity() and mutant is scene
    assert "inserted 0 of 1" in params.reason and "no ground seen" in params.reason
    # Where labels are the camera's, a range of azimuths it does not see is refused outright.
    aside = ObjectInsertion(objects=library, azimuth_range=(60.0, 120.0))
    _, params = aside(scene, generator(5, "000000", 0, 0))
    assert params.is_identity() and "outside the camera's view" in params.reason
    # A wall 6 m ahead across the whole view: every place beyond it is hidden.
    wall = np.array([6.5, 0.0, 0.0, 1.0, 40.0, 8.0, 0.0])
    walled = frame(place_cars(1, 0), walls=wall)
    far = ObjectInsertion(objects=library, distance_ratio_range=(1.5, 3.0), attempts=20)
    mutant, params = far(walled, generator(5, "000000", 0, 0))
    assert params.is_identity() and mutant.points is walled.points
    assert "fewer than 5 points seen" in params.reason or "no ground seen" in params.reason
    # Nothing to stand on at all.
    empty = walled.replace(points=PointCloud.empty())
    assert far(empty, generator(5, "000000", 0, 0))[1].is_identity()


# --------------------------------------------------------------------------- moves
def test_a_zero_move_keeps_the_frame_exactly(scene):
    for i in range(len(scene.boxes)):
        params = ObjectTranslateParams(object=i, track_id=i, offset=(1e-9, 0.0, 0.0), fill_ground=True, seed=1)
        mutant = ObjectTranslate().apply(scene, params)
        assert rows(mutant.points) == rows(scene.points) and len(mutant.points) == len(scene.points)


@pytest.mark.parametrize("op, make", [
    (ObjectTranslate(), lambda i: ObjectTranslateParams(object=i, track_id=i, offset=(0.01, 0.0, 0.0),
                                                        fill_ground=True, seed=1)),
    (ObjectTranslate(), lambda i: ObjectTranslateParams(object=i, track_id=i, offset=(0.0, 0.01, 0.0),
                                                        fill_ground=True, seed=1)),
    (ObjectRotate(), lambda i: ObjectRotateParams(object=i, track_id=i, angle=0.1, fill_ground=True, seed=1)),
    (ObjectScale(), lambda i: ObjectScaleParams(object=i, track_id=i, factor=1.002, fill_ground=True, seed=1)),
])
def test_a_near_zero_move_keeps_the_objects_points(scene, op, make):
    before = after = 0
    for i in range(len(scene.boxes)):
        mutant = op.apply(scene, make(i))
        before += object_points(scene.points, scene.boxes.as_array()[i])
        after += object_points(mutant.points, mutant.boxes.as_array()[i])
    assert after >= 0.99 * before


def test_a_real_move_keeps_the_returns_the_sensor_would_get():
    # A car alone at 10 m straight ahead, moved 5 m farther: the frame ray-cast with the car there
    # says how many returns the sensor gives it; the mutant must be close (the moved points are
    # the source's, thinned where they crowd into one beam and firing).
    near, far = car_on_ground(10.0, 0.5, 0.4), car_on_ground(15.0, 0.5, 0.4)
    source = frame(near[None])
    offset = tuple(float(v) for v in far[:3] - near[:3])
    mutant = ObjectTranslate().apply(source, ObjectTranslateParams(object=0, track_id=0, offset=offset,
                                                                   fill_ground=True, seed=1))
    expected = object_points(scan(far[None]), far)
    got = object_points(mutant.points, mutant.boxes.as_array()[0])
    assert object_points(source.points, near) > 1.5 * expected  # the move does thin the car
    assert abs(got - expected) <= 0.2 * expected


# --------------------------------------------------------------------------- re-labelling
def share_outside_by_hand(box: np.ndarray, n: int = 24) -> float:
    """The share of a box's volume the default camera does not see, from a dense grid of samples
    projected with the pinhole written out: camera x = −y_lidar, y = −z − 0.08, z = x − 0.27;
    u = fx·(x_c + 0.06)/z_c + cx, v = fy·y_c/z_c + cy (KittiCalibration.default())."""
    fx, cx, cy = 721.5377, 609.5593, 172.854
    g = (np.arange(n) + 0.5) / n - 0.5
    local = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) * box[3:6]
    c, s = np.cos(box[6]), np.sin(box[6])
    x = box[0] + c * local[:, 0] - s * local[:, 1]
    y = box[1] + s * local[:, 0] + c * local[:, 1]
    z = box[2] + local[:, 2]
    xc, yc, zc = -y, -z - 0.08, x - 0.27
    u, v = fx * (xc + 0.06) / zc + cx, fx * yc / zc + cy
    inside = (zc > 0.1) & (u >= 0) & (u < 1242) & (v >= 0) & (v < 375)
    return float(1.0 - inside.mean())


def test_truncation_is_the_share_of_the_box_outside_the_image():
    # The image's left edge (u = 0) through the centre of a car 15 m ahead of the camera:
    # y = cx/fx · 15 + 0.06 = 12.7325 m; a box symmetric about its centre is then half outside.
    half = np.array([15.27, 609.5593 / 721.5377 * 15.0 + 0.06, -0.9, *CAR, 0.3])
    fields = camera_labels(CALIB, half)
    assert share_outside_by_hand(half) == pytest.approx(0.5, abs=0.02)
    assert fields.truncation[0] == pytest.approx(share_outside_by_hand(half), abs=0.03)
    assert fields.bbox2d[0, 0] == 0.0 and fields.bbox2d[0, 2] > 20.0
    # In front of the sensor but wholly beside the image: outside (no zero-width box, truncation 1).
    beside = half.copy()
    beside[1] = 25.0
    assert share_outside_by_hand(beside) == 1.0
    boxes = relabel_in_image(Boxes3D.from_array(np.stack([half, beside]), ["Car", "Car"],
                                                truncation=[0.0, 0.0]), CALIB)
    assert boxes.truncation[1] == 1.0 and np.isnan(boxes.bbox2d[1]).all()
    # The image's size is the calibration's (read from image_2/ when there is one).
    narrow = KittiCalibration.from_mapping({k: getattr(CALIB, k) for k in ("P2", "R0_rect", "Tr_velo_to_cam")},
                                           image_shape=(375, 620))
    assert camera_labels(narrow, half).truncation[0] > 0.45
    right = np.array([15.27, -0.5, -0.9, *CAR, 0.3])  # projects near u = 640: beyond a 620 px image
    assert camera_labels(CALIB, right).truncation[0] == 0.0 and camera_labels(narrow, right).truncation[0] > 0.5


@pytest.fixture(scope="module")
def many() -> list[Scene]:
    """16 frames of 6 cars each in the camera's view (96 cars: AP needs 41 counted to reach 100)."""
    return [frame(place_cars(100 + k, 6), f"{k:06d}") for k in range(16)]


def perfect(scenes: list[Scene]) -> tuple[list[KittiFrame], list[KittiFrame]]:
    """A perfect detector's frames: detections = ground truth, score 1; as KITTI results are (and
    as ``lidarfuzz detect`` and campaigns score them), boxes outside the camera's view left out —
    and, unfiltered, every box."""
    filtered, unfiltered = [], []
    for s in scenes:
        dt = s.boxes.select(np.flatnonzero(s.boxes.has_geometry))
        dt = dt.replace(scores=np.ones(len(dt)))
        filtered.append(KittiFrame(s.boxes, dt.select(CALIB.in_view(dt.centers)), CALIB))
        unfiltered.append(KittiFrame(s.boxes, dt, CALIB))
    return filtered, unfiltered


@pytest.mark.parametrize("angle", [-25.0, -10.0, 4.0, 15.0])
def test_a_perfect_detector_keeps_ap_100_on_rotated_frames(many, angle):
    rotated = [RotateZ().apply(s, RotationParams(angle=angle)) for s in many]
    counted = sum(int(np.count_nonzero(r.boxes.truncation <= 0.3)) for r in rotated)
    assert counted >= 45  # enough for all 41 recall samples
    filtered, unfiltered = perfect(rotated)
    result = evaluate_kitti(filtered, classes=["Car"])
    for metric in ("bbox", "bev", "3d"):
        for difficulty in ("moderate", "hard"):
            assert result.get(metric, "Car", difficulty, "R40") == pytest.approx(100.0)
            assert result.get(metric, "Car", difficulty, "R11") == pytest.approx(100.0)
    everything = evaluate_kitti(unfiltered, classes=["Car"])  # boxes out of view match ignored labels
    assert everything.get("3d", "Car", "moderate", "R40") == pytest.approx(100.0)


@pytest.mark.parametrize("angle", [90.0, 180.0])
def test_a_scene_turned_away_from_the_camera_has_no_box_in_view(many, angle):
    rotated = [RotateZ().apply(s, RotationParams(angle=angle)) for s in many[:4]]
    for r in rotated:
        assert np.all(r.boxes.truncation == 1.0) and np.isnan(r.boxes.bbox2d).all()
    filtered, _ = perfect(rotated)
    assert all(len(f.detections) == 0 for f in filtered)  # nothing scored: no AP, not AP 0
