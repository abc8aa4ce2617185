"""A small analytic sample world: flat ground and parked cars seen by an HDL-64E-like sensor.

This is the stand-in default data until the ray-cast simulator lands (issue 3): it
produces real, labelled, calibrated frames with the KITTI sensor geometry so that
``lidarfuzz demo`` and the I/O benchmarks have data without any download. Rays are
intersected analytically with the ground plane and with the cars' oriented boxes
(nearest hit wins, so cars cast shadows on the ground); cars are boxes, not shaped
meshes, and there are no buildings — the simulator issue replaces all of that.

Everything is deterministic for a seed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene

#: HDL-64E as mounted on KITTI's car: 64 beams from +2° to -24.8°, 0.17° steps, 1.73 m high.
ELEVATIONS_DEG = np.linspace(2.0, -24.8, 64)
AZIMUTH_STEP_DEG = 0.17
MAX_RANGE = 120.0
MOUNT_HEIGHT = 1.73
SWEEP_SECONDS = 0.1
ROAD_HALF_WIDTH = 7.0


def _rays() -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    azimuth = np.deg2rad(np.arange(0.0, 360.0, AZIMUTH_STEP_DEG))
    elev = np.deg2rad(ELEVATIONS_DEG)
    az, el = np.meshgrid(azimuth, elev)  # 64 × A, ring-major
    dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)
    ring = np.repeat(np.arange(len(elev)), len(azimuth)).astype(np.float64)
    time = np.tile(azimuth / (2 * np.pi) * SWEEP_SECONDS, len(elev))
    return dirs, ring, time


def _hit_boxes(dirs: NDArray[np.float64], boxes: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Distance along each ray (from the origin) to the nearest box, and which box (-1: none)."""
    best = np.full(dirs.shape[0], np.inf)
    which = np.full(dirs.shape[0], -1, dtype=np.int64)
    for j, (x, y, z, length, width, height, yaw) in enumerate(boxes):
        c, s = np.cos(yaw), np.sin(yaw)
        origin = np.array([-x * c - y * s, x * s - y * c, -z])  # sensor origin in the box frame
        d = np.stack([dirs[:, 0] * c + dirs[:, 1] * s, -dirs[:, 0] * s + dirs[:, 1] * c, dirs[:, 2]], axis=1)
        half = np.array([length, width, height]) / 2.0
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - origin) / d
            t2 = (half - origin) / d
        t_near = np.nanmax(np.minimum(t1, t2), axis=1)
        t_far = np.nanmin(np.maximum(t1, t2), axis=1)
        hit = (t_far >= t_near) & (t_near > 0) & (t_near < best)
        best[hit] = t_near[hit]
        which[hit] = j
    return best, which


def sample_scene(seed: int, frame_index: int = 0, n_cars: int = 6, ego_speed: float = 10.0) -> Scene:
    """One frame of the sample world; frames of the same seed form a log (ego driving along +x).

    Example:
        >>> scene = sample_scene(seed=0)
        >>> len(scene.points) > 50_000, set(scene.boxes.labels) == {"Car"}
        (True, True)
    """
    world = np.random.default_rng(np.random.SeedSequence([seed, 0]))
    # Parked cars along both kerbs of a straight road, in world coordinates.
    xs = np.sort(world.uniform(4.0, 70.0, n_cars))
    side = world.choice([-1.0, 1.0], n_cars)
    cars = np.column_stack([
        xs,
        side * world.uniform(3.0, 5.5, n_cars),
        np.zeros(n_cars),
        world.normal(3.9, 0.2, n_cars),
        world.normal(1.6, 0.08, n_cars),
        world.normal(1.5, 0.06, n_cars),
        world.normal(0.0, 0.08, n_cars) + (side < 0) * np.pi,
    ])
    cars[:, 2] = cars[:, 5] / 2.0 - MOUNT_HEIGHT  # resting on the ground

    ego_x = frame_index * ego_speed * SWEEP_SECONDS
    local = cars.copy()
    local[:, 0] -= ego_x

    dirs, ring, time = _rays()
    t_box, which = _hit_boxes(dirs, local)
    with np.errstate(divide="ignore"):
        t_ground = np.where(dirs[:, 2] < 0, -MOUNT_HEIGHT / dirs[:, 2], np.inf)
    t = np.minimum(t_box, t_ground)
    keep = t <= MAX_RANGE
    noise_rng = np.random.default_rng(np.random.SeedSequence([seed, 1, frame_index]))
    ground = keep & (t_ground <= t_box)
    t = t + np.where(ground, noise_rng.normal(0.0, 0.02, t.shape), 0.0)
    xyz = dirs * np.where(keep, t, 0.0)[:, None]
    intensity = np.where(ground, 0.12, 0.45) + noise_rng.uniform(-0.05, 0.05, t.shape)
    intensity *= np.clip(1.0 - t / 200.0, 0.2, 1.0)
    instance = np.where(ground, 0, which + 1)
    label = np.where(ground, 1, 10)  # 1 road, 10 car
    drop = noise_rng.random(t.shape) < 0.05
    keep &= ~drop
    cloud = PointCloud.from_channels({
        "x": xyz[keep, 0], "y": xyz[keep, 1], "z": xyz[keep, 2],
        "intensity": np.clip(intensity[keep], 0.0, 1.0),
        "ring": ring[keep], "time": time[keep], "label": label[keep], "instance": instance[keep],
    })

    calib = KittiCalibration.default()
    visible = np.bincount(which[keep & ~ground], minlength=n_cars)
    in_front = local[:, 0] > 1.0
    labelled = in_front & (visible >= 5) & (local[:, 0] < 80.0)
    arr = local[labelled].copy()
    arr[:, 3:6] += 0.04  # annotated boxes enclose the surface returns with a small margin
    boxes = Boxes3D.from_array(
        arr, ["Car"] * len(arr), truncation=np.zeros(len(arr)), occlusion=np.zeros(len(arr), dtype=np.int64),
        alpha=calib.alpha(arr), bbox2d=calib.boxes_to_image(arr), track_ids=np.nonzero(labelled)[0],
    )
    road = RoiMap.from_polygons([[(-200.0, -ROAD_HALF_WIDTH), (400.0, -ROAD_HALF_WIDTH),
                                  (400.0, ROAD_HALF_WIDTH), (-200.0, ROAD_HALF_WIDTH)]])
    pose = np.eye(4)
    pose[0, 3] = ego_x
    pose[2, 3] = MOUNT_HEIGHT
    return Scene(
        cloud, boxes, calib, frame_id=f"{frame_index:06d}", timestamp=round(frame_index * SWEEP_SECONDS, 9), pose=pose,
        roi=road.transformed(np.linalg.inv(pose)),
        metadata={"generator": "lidarfuzz.sim.sample", "seed": seed, "points_per_object": visible[labelled].tolist()},
    )
