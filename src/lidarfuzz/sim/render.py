"""Rendering a frame: Embree ray casting of a spinning sensor over a compiled world, then labelling.

Per frame the renderer

1. places the ego vehicle at the firing time of every azimuth column (so a moving ego
   vehicle produces rolling-shutter distortion: each point is expressed in the sensor
   frame of the instant it was measured, as a real driver reports it), and each road
   user at the instant the head sweeps over it;
2. casts all rays with Embree (through embreex) against the static world and the
   road users;
3. turns hits into returns: Gaussian range noise, the receiver's detection threshold
   (dark, far, grazing surfaces are lost), random drop, and intensity in [0, 1] from
   the surface's reflectivity, the incidence angle and the range;
4. computes KITTI labels (see :mod:`lidarfuzz.sim.labels`).

Channels: ``x y z intensity ring time label instance`` — ``label`` is the semantic
class (:data:`~lidarfuzz.sim.materials.SEMANTIC_CLASSES`), ``instance`` the track id of
the road user hit, −1 for the background.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from embreex import rtcore as rtc
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from numpy.typing import NDArray

from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim.labels import LabelConfig, label_actors
from lidarfuzz.sim.meshes import Mesh
from lidarfuzz.sim.world import World, as_multipolygon

CHANNELS = ("x", "y", "z", "intensity", "ring", "time", "label", "instance")
ROI_RADIUS = 150.0  # the drivable area saved with a frame is clipped to this square around the sensor


_DEVICE: rtc.EmbreeDevice | None = None


def _shared_device() -> rtc.EmbreeDevice:
    """One Embree device per process (creating one starts its thread pool)."""
    global _DEVICE
    if _DEVICE is None:
        _DEVICE = rtc.EmbreeDevice()
    return _DEVICE


@dataclass(frozen=True)
class Hits:
    """Raw ray-casting result for all rays of a frame, in firing order."""

    distance: NDArray[np.float32]
    geometry: NDArray[np.int32]  # 0 static, 1 actors, -1 none
    face: NDArray[np.int32]
    normal: NDArray[np.float32]


class Renderer:
    """Renders frames of one compiled world; reuses the Embree device and the static geometry."""

    def __init__(self, world: World, calib: KittiCalibration | None = None, labels: LabelConfig | None = None) -> None:
        self.world = world
        self.sensor = world.sensor
        self.calib = calib or KittiCalibration.default()
        self.labels = labels or LabelConfig()
        self._device = _shared_device()
        self._static_vertices = world.static.vertices.astype(np.float32)
        self._static_faces = world.static.faces
        self._local_directions = self.sensor.local_directions.reshape(-1, 3).astype(np.float32)
        self._direction_components = [np.ascontiguousarray(self._local_directions[:, k]) for k in range(3)]
        self._ring_of_ray = np.tile(np.arange(self.sensor.beams, dtype=np.float32), self.sensor.columns)
        self._time_of_ray = np.repeat(self.sensor.column_times.astype(np.float32), self.sensor.beams)
        self._track_of_index = np.array([a.track_id for a in world.actors] + [-1], np.float32)

    # ------------------------------------------------------------------ geometry
    def ego_pose(self, t: NDArray[np.float64] | float) -> tuple[NDArray[np.float64], ...]:
        """Sensor (x, y, z, yaw) in the world at time(s) ``t``."""
        x, y, yaw = self.world.ego.at(t)
        return x, y, np.full_like(x, self.sensor.mount_height), yaw

    def pose_matrix(self, t: float) -> NDArray[np.float64]:
        """4×4 LiDAR → world transform at time ``t``."""
        x, y, z, yaw = (float(v[0]) for v in self.ego_pose(t))
        c, s = np.cos(yaw), np.sin(yaw)
        pose = np.eye(4)
        pose[:2, :2] = [[c, -s], [s, c]]
        pose[:3, 3] = [x, y, z]
        return pose

    def actor_times(self, t_ref: float) -> NDArray[np.float64]:
        """When the head sweeps over each actor (absolute times), found by two fixed-point steps."""
        times = np.full(len(self.world.actors), t_ref)
        for _ in range(2):
            for i, actor in enumerate(self.world.actors):
                ax, ay, _ = actor.trajectory.at(times[i])
                ex, ey, _, eyaw = self.ego_pose(times[i])
                azimuth = np.arctan2(ay[0] - ey[0], ax[0] - ex[0]) - eyaw[0]
                times[i] = t_ref + float(self.sensor.time_of_azimuth(azimuth))
        return times

    def _actor_meshes(self, times: NDArray[np.float64]) -> tuple[Mesh, NDArray[np.int32], NDArray[np.float64]]:
        meshes, owner, poses = [], [], []
        for actor, t in zip(self.world.actors, times, strict=True):
            mesh, pose = actor.mesh_at(float(t), self.world.ground)
            meshes.append(mesh)
            owner.append(np.full(len(mesh), actor.index, np.int32))
            poses.append(pose)
        if not meshes:
            return Mesh.empty(), np.zeros(0, np.int32), np.zeros((0, 4))
        return Mesh.concat(meshes), np.concatenate(owner), np.asarray(poses)

    def rays(self, t_ref: float) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """World-frame origins and unit directions of every ray, in firing order (column-major)."""
        sensor = self.sensor
        x, y, z, yaw = self.ego_pose(t_ref + sensor.column_times)
        local = self._local_directions.reshape(sensor.columns, sensor.beams, 3)
        c = np.cos(yaw).astype(np.float32)[:, None]
        s = np.sin(yaw).astype(np.float32)[:, None]
        directions = np.empty_like(local)
        directions[..., 0] = c * local[..., 0] - s * local[..., 1]
        directions[..., 1] = s * local[..., 0] + c * local[..., 1]
        directions[..., 2] = local[..., 2]
        origins = np.repeat(np.stack([x, y, z], axis=1).astype(np.float32), sensor.beams, axis=0)
        return origins, directions.reshape(-1, 3)

    def cast(self, origins: NDArray[np.float32], directions: NDArray[np.float32], actors: Mesh) -> Hits:
        scene = rtcore_scene.EmbreeScene(self._device)
        if len(self._static_faces):
            TriangleMesh(scene, self._static_vertices, self._static_faces)
        geometry_of_actors = 1 if len(self._static_faces) else 0
        if len(actors):
            TriangleMesh(scene, actors.vertices.astype(np.float32), actors.faces)
        limit = np.full(len(origins), self.sensor.max_range, np.float32)
        result = scene.run(origins, directions, dists=limit, output=1)
        geometry = result["geomID"].astype(np.int32)
        if geometry_of_actors == 0:
            geometry = np.where(geometry == 0, 1, geometry).astype(np.int32)
        return Hits(result["tfar"], geometry, result["primID"].astype(np.int32), result["Ng"])

    def visible_rays_alone(self, actors: Mesh, owner: NDArray[np.int32], index: int,
                           origins: NDArray[np.float32], directions: NDArray[np.float32],
                           candidates: NDArray[np.intp]) -> int:
        """How many of the ``candidates`` rays would hit actor ``index`` if nothing else were there."""
        faces = actors.faces[owner == index]
        if len(faces) == 0 or len(candidates) == 0:
            return 0
        used = np.unique(faces)
        remap = np.zeros(len(actors.vertices), np.int32)
        remap[used] = np.arange(len(used), dtype=np.int32)
        scene = rtcore_scene.EmbreeScene(self._device)
        TriangleMesh(scene, actors.vertices[used].astype(np.float32), remap[faces])
        limit = np.full(len(candidates), self.sensor.max_range, np.float32)
        result = scene.run(origins[candidates], directions[candidates], dists=limit, output=1)
        hit = (result["geomID"] >= 0) & (result["tfar"] >= self.sensor.min_range)
        return int(hit.sum())

    # ------------------------------------------------------------------ frame
    def render(self, t_ref: float = 0.0, *, frame_id: str = "", frame_seed: int | None = None,
               timestamp: float | None = None) -> Scene:
        """The frame whose forward-facing instant is ``t_ref`` seconds after the scene's start."""
        sensor = self.sensor
        seed = self.world.spec.seed if frame_seed is None else frame_seed
        rng = np.random.default_rng(np.random.SeedSequence([seed, round(t_ref * 1e6) & 0xFFFFFFFF, 0x51D]))
        times = self.actor_times(t_ref)
        actors, owner, actor_poses = self._actor_meshes(times)
        origins, directions = self.rays(t_ref)
        hits = self.cast(origins, directions, actors)

        n = len(origins)
        geometric = (hits.geometry >= 0) & (hits.distance >= sensor.min_range) & (hits.distance <= sensor.max_range)
        reflectivity = np.zeros(n, np.float32)
        semantic = np.zeros(n, np.uint8)
        instance = np.full(n, -1, np.int64)
        static_hit = geometric & (hits.geometry == 0)
        actor_hit = geometric & (hits.geometry == 1)
        faces = hits.face
        reflectivity[static_hit] = self.world.static.reflectivity[faces[static_hit]]
        semantic[static_hit] = self.world.static.semantic[faces[static_hit]]
        if len(actors):
            reflectivity[actor_hit] = actors.reflectivity[faces[actor_hit]]
            semantic[actor_hit] = actors.semantic[faces[actor_hit]]
            instance[actor_hit] = owner[faces[actor_hit]]

        normal = hits.normal
        dot = np.einsum("ij,ij->i", normal, directions)
        norm = np.sqrt(np.einsum("ij,ij->i", normal, normal))
        cos_incidence = np.abs(dot) / np.maximum(norm, np.float32(1e-12))
        distance = hits.distance
        # Draw every random number for every ray, so that a change in the scene does not
        # shift the noise of unrelated rays.
        range_error = rng.standard_normal(n, dtype=np.float32) * np.float32(sensor.range_noise)
        drop_draw = rng.random(n, dtype=np.float32)
        intensity_error = rng.standard_normal(n, dtype=np.float32) * np.float32(sensor.intensity_noise)

        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            signal = reflectivity * np.sqrt(np.maximum(cos_incidence, np.float32(0.05)))
            signal *= (np.float32(100.0) / distance) ** 2
        kept = geometric & (signal >= sensor.detection_threshold) & (drop_draw >= sensor.drop_rate)
        index = np.flatnonzero(kept)
        d = distance[index]
        cos_kept = cos_incidence[index]
        intensity = reflectivity[index] * (np.float32(0.35) + np.float32(0.65) * cos_kept)
        intensity *= np.exp(-d / np.float32(400.0))
        intensity += intensity_error[index]
        np.clip(intensity, 0.0, 1.0, out=intensity)

        measured = d + range_error[index]
        owner_of_point = instance[index]
        columns = np.empty((len(index), len(CHANNELS)), np.float32)
        for axis in range(3):
            columns[:, axis] = self._direction_components[axis][index] * measured
        columns[:, 3] = intensity
        columns[:, 4] = self._ring_of_ray[index]
        columns[:, 5] = self._time_of_ray[index]
        columns[:, 6] = semantic[index]
        columns[:, 7] = self._track_of_index[owner_of_point]  # index −1 picks the trailing −1: background
        points = PointCloud(columns, CHANNELS)

        boxes, info = label_actors(
            self, t_ref=t_ref, times=times, actor_poses=actor_poses, actors=actors, owner=owner,
            origins=origins, directions=directions, geometric_owner=np.where(geometric, instance, -1),
            points_owner=owner_of_point, config=self.labels,
        )
        pose = self.pose_matrix(t_ref)
        world_to_lidar = np.linalg.inv(pose)
        roi = RoiMap(self.world.drivable).transformed(world_to_lidar)
        if not roi.geometry.is_empty:
            clip = shapely.box(-ROI_RADIUS, -ROI_RADIUS, ROI_RADIUS, ROI_RADIUS)
            roi = RoiMap(as_multipolygon(roi.geometry.intersection(clip)))
        metadata = {
            "generator": "lidarfuzz.sim",
            "scene": self.world.spec.name,
            "sensor": sensor.name,
            "seed": seed,
            "scene_time": t_ref,
            **info,
        }
        return Scene(points, boxes, self.calib, frame_id=frame_id, timestamp=timestamp, pose=pose, roi=roi,
                     metadata=metadata)
