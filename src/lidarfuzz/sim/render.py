"""Rendering a frame: Embree ray casting of a spinning sensor over a compiled world, then labelling.

Per frame the renderer

1. places the ego vehicle at the firing time of every azimuth column (so a moving ego
   vehicle produces rolling-shutter distortion: each point is expressed in the sensor
   frame of the instant it was measured, as a real driver reports it), resting on the
   ground under its wheels (pitched and rolled with it), and each road user at the
   instant the head sweeps over it;
2. casts all rays with Embree (through embreex) against the static world and the
   road users;
3. turns hits into returns: Gaussian range noise, the receiver's detection threshold
   (dark, far, grazing surfaces are lost), the sensor's other losses (glossy surfaces at
   grazing angles, per-beam random losses, azimuth gaps, the vehicle's own shadow; see
   :class:`~lidarfuzz.sim.sensor.Dropouts`), and the intensity reading from the surface's
   reflectivity, the incidence angle, the range and the laser's calibration
   (:class:`~lidarfuzz.sim.sensor.Receiver`);
4. computes KITTI labels (see :mod:`lidarfuzz.sim.labels`).

Channels: ``x y z intensity ring time label instance`` — ``label`` is the semantic
class (:data:`~lidarfuzz.scene.semantics.SEMANTIC_CLASSES`), ``instance`` the track id of
the road user hit, −1 for the background.
"""

from __future__ import annotations

import itertools
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

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
from lidarfuzz.sim.sensor import LidarSensor
from lidarfuzz.sim.terrain import TRACK, WHEELBASE, frame_from_heading, frame_from_slopes
from lidarfuzz.sim.world import PlacedActor, World, as_multipolygon, poses_on_ground, positions_at

CHANNELS = ("x", "y", "z", "intensity", "ring", "time", "label", "instance")
ROI_RADIUS = 150.0  # the drivable area saved with a frame is clipped to this square around the sensor


_MAX_GAPS = 16  # azimuth gaps per sweep at most (their count is Poisson; see Dropouts.azimuth_gaps)


def _poisson_pmf(mean: float) -> NDArray[np.float64]:
    """P(k) for k = 0 … _MAX_GAPS of a Poisson count with ``mean``."""
    k = np.arange(_MAX_GAPS + 1)
    log_factorial = np.concatenate([[0.0], np.cumsum(np.log(k[1:]))])
    if mean <= 0:
        return (k == 0).astype(np.float64)
    return np.exp(k * np.log(mean) - mean - log_factorial)


def covered_rays(columns: int, beams: int, first_column: NDArray[np.int64], span: NDArray[np.int64],
                 lo_ring: NDArray[np.intp], hi_ring: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Rays (column × beam grid, flattened in firing order) inside any of the rectangles
    ``first_column[i]`` … ``first_column[i] + span[i] − 1`` (wrapping past the last column to the
    first) × rings ``lo_ring[i]`` … ``hi_ring[i] − 1``.

    One slice fill per rectangle (and one for its wrapped remainder): a frame has a few dozen
    road users, and a difference array over the whole grid (~133k cells at HDL-64E
    resolution) with two cumulative sums costs more for the same union.

    Example:
        >>> covered_rays(4, 2, np.array([3]), np.array([2]), np.array([1]), np.array([2])).reshape(4, 2)[:, 1]
        array([ True, False, False,  True])
    """
    covered = np.zeros((columns, beams), np.bool_)
    for start, width, r0, r1 in zip(first_column.tolist(), span.tolist(), lo_ring.tolist(), hi_ring.tolist(),
                                    strict=True):
        stop = start + width
        covered[start:stop, r0:r1] = True  # a slice stops at the last column by itself
        if stop > columns:
            covered[: stop - columns, r0:r1] = True
    return covered.ravel()


def incidence_cosines(normal: NDArray[np.float32], directions: NDArray[np.float32]) -> NDArray[np.float32]:
    """|cos| of the angle between each ray's direction (unit) and the (unnormalised) geometric
    normal of the surface it hit: ``|n · d| / max(|n|, 1e-12)``, in float32.

    The dot products are summed x + y + z over one N×3 product (vectorised twice as fast as
    ``einsum("ij,ij->i")``, which sums the same three float32 products in the same order; the
    two can differ only in the sign of a zero, which the absolute value drops).
    """
    product = normal * directions
    dot = product[:, 0] + product[:, 1]
    dot += product[:, 2]
    np.multiply(normal, normal, out=product)
    norm = product[:, 0] + product[:, 1]
    norm += product[:, 2]
    np.sqrt(norm, out=norm)
    np.abs(dot, out=dot)
    dot /= np.maximum(norm, np.float32(1e-12), out=norm)
    return dot


@dataclass(frozen=True)
class _RayTables:
    """Per-ray tables of a sensor (firing order), read-only: every renderer of that sensor shares them."""

    local_directions: NDArray[np.float32]  # N×3, sensor frame
    direction_components: list[NDArray[np.float32]]  # its x, y and z columns, contiguous
    ring_of_ray: NDArray[np.float32]
    ring_index: NDArray[np.intp]
    drop_rate_of_ray: NDArray[np.float32]
    time_of_ray: NDArray[np.float32]


_RAY_TABLES: dict[tuple[int, int, bytes, bytes, bytes], _RayTables] = {}


def _ray_tables(sensor: LidarSensor) -> _RayTables:
    """The sensor's per-ray tables, built once per process for each distinct beam table.

    A data set's independent frames compile a new world, hence a new renderer, per frame, but
    share the sensor's beam table; rebuilding these ~133k-row tables cost ~1.4 ms a frame at
    HDL-64E resolution. The key holds everything the tables derive from (the directions are
    a function of the ring elevations and the column count).
    """
    key = (sensor.beams, sensor.columns, np.asarray(sensor.ring_elevations, np.float64).tobytes(),
           np.asarray(sensor.beam_drop_rates).tobytes(), np.asarray(sensor.column_times, np.float64).tobytes())
    tables = _RAY_TABLES.get(key)
    if tables is None:
        local = sensor.local_directions.reshape(-1, 3).astype(np.float32)
        tables = _RayTables(
            local_directions=local,
            direction_components=[np.ascontiguousarray(local[:, k]) for k in range(3)],
            ring_of_ray=np.tile(np.arange(sensor.beams, dtype=np.float32), sensor.columns),
            ring_index=np.tile(np.arange(sensor.beams, dtype=np.intp), sensor.columns),
            drop_rate_of_ray=np.tile(sensor.beam_drop_rates, sensor.columns),
            time_of_ray=np.repeat(sensor.column_times.astype(np.float32), sensor.beams),
        )
        shared: list[NDArray[Any]] = [tables.local_directions, *tables.direction_components, tables.ring_of_ray,
                                      tables.ring_index, tables.drop_rate_of_ray, tables.time_of_ray]
        for array in shared:
            array.flags.writeable = False  # shared between renderers
        if len(_RAY_TABLES) >= 8:  # a few sensors per process at most; never grow without bound
            _RAY_TABLES.clear()
        _RAY_TABLES[key] = tables
    return tables


_DRAWS = threading.local()


def _draw_buffers(n: int) -> NDArray[np.float32]:
    """Four float32 rows of ``n`` for a frame's per-ray random draws, reused by every frame this
    thread renders with ``n`` rays.

    A frame's large temporaries are fresh memory each frame (the C allocator hands freed
    heap back to the kernel between frames, and every page is faulted in again: ~5 ms of
    kernel time per HDL-64E frame); the draws are 2 MB of them and never leave
    :meth:`Renderer.render` (only copies, gathered by index, do), so they can be kept. One set
    per thread: renderers may run in several threads at once.
    """
    buffers: NDArray[np.float32] | None = getattr(_DRAWS, "buffers", None)
    if buffers is None or buffers.shape[1] != n:
        buffers = np.empty((4, n), np.float32)
        _DRAWS.buffers = buffers
    return buffers


_DEVICE: rtc.EmbreeDevice | None = None
_POOL: ThreadPoolExecutor | None = None


def _thread_pool(threads: int) -> ThreadPoolExecutor:
    """One tracing thread pool per process, grown on demand."""
    global _POOL
    if _POOL is None or _POOL._max_workers < threads:
        _POOL = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="lidarfuzz-trace")
    return _POOL


def _shared_device() -> rtc.EmbreeDevice:
    """One Embree device per process (creating one starts its thread pool)."""
    global _DEVICE
    if _DEVICE is None:
        _DEVICE = rtc.EmbreeDevice()
    return _DEVICE


def add_triangles(scene: rtcore_scene.EmbreeScene, vertices: NDArray[np.floating[Any]],
                  faces: NDArray[np.integer[Any]]) -> None:
    """Add the triangle mesh (``vertices`` V×3, stored as float32; ``faces`` F×3) to ``scene``.

    embreex (4.4) fills Embree's buffers element by element through Python indexing:
    ``vertices[i, k]`` makes a numpy scalar per coordinate and ``faces[i][k]`` a row view per
    index, ~7 ms for a world's ~18k vertices and ~10k faces (more than its BVH build). Given an
    object array of Python floats and a 1-D object array of index tuples instead, each access
    returns an existing object: the same values reach Embree (float32 coordinates made
    doubles and cast back exactly; the same integers) at a third of the cost, conversions
    included. Should a later embreex type its arguments (it would reject object arrays), the
    plain arrays are passed.
    """
    coordinates = np.asarray(vertices, np.float32)
    index = np.asarray(faces)
    try:
        TriangleMesh(scene, coordinates.astype(object),
                     np.fromiter(zip(*index.T.tolist(), strict=True), dtype=object, count=len(index)))
    except (TypeError, ValueError):  # an embreex that reads typed buffers: already fast with arrays
        TriangleMesh(scene, coordinates, index)


@dataclass(frozen=True)
class Hits:
    """Raw ray-casting result for all rays of a frame, in firing order."""

    distance: NDArray[np.float32]
    geometry: NDArray[np.int32]  # 0 the world, 1 a road user, -1 nothing
    normal: NDArray[np.float32]
    reflectivity: NDArray[np.float32]
    semantic: NDArray[np.uint8]
    owner: NDArray[np.int64]  # index of the road user hit, -1 otherwise
    returns: NDArray[np.float32]  # probability that the surface hit returns the beam
    gloss: NDArray[np.float32]  # share of the beam the surface mirrors away at grazing incidence


@dataclass(frozen=True)
class MovingPart:
    """Moving road users posed for some of the rays: a mesh, each face's owner, where the sensor was
    when it swept over each owner, and the rays (a mask in firing order) that may see this pose."""

    mesh: Mesh
    owner: NDArray[np.int32]
    viewpoints: NDArray[np.float64]  # sensor origins, indexed by actor index
    rays: NDArray[np.bool_]
    orientations: NDArray[np.float64]  # sensor → world rotations, indexed by actor index


class Renderer:
    """Renders frames of one compiled world; reuses the Embree device and the static geometry."""

    def __init__(self, world: World, calib: KittiCalibration | None = None, labels: LabelConfig | None = None,
                 *, threads: int | None = None) -> None:
        """``threads``: how many threads trace a frame's rays (Embree releases the GIL); default:
        the CPU cores, at most 4. Data set workers, one per core already, use 1."""
        self.world = world
        self.threads = max(1, threads if threads is not None else min(4, os.cpu_count() or 1))
        self.sensor = world.sensor
        self.calib = calib or KittiCalibration.default()
        self.labels = labels or LabelConfig()
        self._device = _shared_device()
        self._static_scene: rtcore_scene.EmbreeScene | None = None
        self._still_pose: tuple[NDArray[np.float64], ...] | None = None
        self._tilt_table: tuple[NDArray[np.float64], ...] | None = None
        self._pose_memo: dict[bytes, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
        self._face_table: tuple[tuple[NDArray[Any], ...], NDArray[np.int64]] | None = None
        # The last posed moving road users: a frame poses them at the same instants for its labels
        # (_actor_meshes) and for its rays (moving_parts); posing costs ~0.1 ms per road user.
        self._moving_memo: tuple[bytes, tuple[int, ...], tuple[Mesh, NDArray[np.int32], NDArray[np.float64]]] | None \
            = None
        # Road users that never move are static geometry: built into the static scene once.
        self._still = [a for a in world.actors if a.trajectory.speed == 0]
        self._moving = [a for a in world.actors if a.trajectory.speed != 0]
        still_poses = poses_on_ground(tuple(self._still), positions_at(tuple(self._still), np.zeros(len(self._still))),
                                      world.ground)
        # Their frames in one call (a frame per road user cost ~25 µs), each heading's cosine and
        # sine taken one by one as mesh_at takes them: the same rotations.
        rotations = frame_from_heading(np.array([np.cos(p[3]) for p in still_poses], np.float64),
                                       np.array([np.sin(p[3]) for p in still_poses], np.float64),
                                       still_poses[:, 4], still_poses[:, 5])
        still = [a.mesh_at(0.0, world.ground, pose=tuple(p), rotation=r.copy())
                 for a, p, r in zip(self._still, still_poses, rotations, strict=True)]
        self._still_mesh = Mesh.concat([m for m, _ in still])
        self._still_owner = np.concatenate([np.full(len(m), a.index, np.int32) for (m, _), a in
                                            zip(still, self._still, strict=True)] or [np.zeros(0, np.int32)])
        self._still_poses = {a.index: pose for (_, pose), a in zip(still, self._still, strict=True)}
        tables = _ray_tables(self.sensor)
        self._local_directions = tables.local_directions
        self._direction_components = tables.direction_components
        self._ring_of_ray, self._ring_index = tables.ring_of_ray, tables.ring_index
        self._drop_rate_of_ray, self._time_of_ray = tables.drop_rate_of_ray, tables.time_of_ray
        self._track_of_index = np.array([a.track_id for a in world.actors] + [-1], np.float32)

    # ------------------------------------------------------------------ geometry
    def sensor_pose(self, t: NDArray[np.float64] | float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The sensor's origin (N×3) and rotation (N×3×3, sensor → world) at time(s) ``t``.

        The vehicle rests on the plane through its four wheels (:data:`~lidarfuzz.sim.terrain.WHEELBASE`,
        :data:`~lidarfuzz.sim.terrain.TRACK`), so on a slope or a cambered road it pitches and
        rolls with the ground, as KITTI's car does; the sensor sits ``mount_height`` above that
        plane along its normal, tilted by its mounting angles.
        """
        t = np.atleast_1d(np.asarray(t, np.float64))
        key = t.tobytes()
        if key in self._pose_memo:  # a frame asks for the same instants several times
            return self._pose_memo[key]
        if len(self._pose_memo) > 64:
            self._pose_memo.clear()
        pose = self._sensor_pose(t)
        self._pose_memo[key] = pose
        return pose

    def _sensor_pose(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        x, y, yaw = self.world.ego.at(t)
        ground, sensor = self.world.ground, self.sensor
        tilted = not ground.is_flat or sensor.mount_pitch_deg or sensor.mount_roll_deg
        if not tilted:
            c, s = np.cos(yaw), np.sin(yaw)
            rotation = np.zeros((len(x), 3, 3))
            rotation[:, 0, 0], rotation[:, 0, 1], rotation[:, 1, 0], rotation[:, 1, 1] = c, -s, s, c
            rotation[:, 2, 2] = 1.0
            return np.stack([x, y, np.full_like(x, sensor.mount_height)], axis=1), rotation
        z, forward, left = self._ground_under_ego(t)
        body = frame_from_slopes(yaw, forward, left)
        rotation = body @ sensor.mount_rotation
        origin = np.stack([x, y, z], axis=1) + body[:, :, 2] * sensor.mount_height
        return origin, rotation

    def _ground_under_ego(self, t: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """The height and slopes (forward, left) of the plane under the ego vehicle's wheels at
        times ``t``. The ground under the car changes little within a sweep: it is evaluated at 17
        instants spanning three sweeps around the queried times (the car moves under 0.3 m
        between two at 14 m/s) and interpolated, so a frame's many pose queries cost one lookup."""
        ego = self.world.ego
        if ego.speed == 0:  # one pose for every instant
            if self._still_pose is None:
                x, y, yaw = ego.at(t[:1])
                self._still_pose = self.world.ground.tilt(x, y, yaw, WHEELBASE, TRACK)
            return tuple(np.repeat(v, len(t)) for v in self._still_pose)
        table = self._tilt_table
        if table is None or t.min() < table[0][0] or t.max() > table[0][-1]:
            period = self.sensor.period
            samples = np.linspace(t.min() - 1.5 * period, t.max() + 1.5 * period, 17)
            table = (samples, *self.world.ground.tilt(*ego.at(samples), WHEELBASE, TRACK))
            self._tilt_table = table
        return tuple(np.interp(t, table[0], v) for v in table[1:])

    def ego_pose(self, t: NDArray[np.float64] | float) -> tuple[NDArray[np.float64], ...]:
        """Sensor (x, y, z, yaw) in the world at time(s) ``t`` (its heading; see :meth:`sensor_pose`
        for its full orientation)."""
        origin, rotation = self.sensor_pose(t)
        return origin[:, 0], origin[:, 1], origin[:, 2], np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0])

    def pose_matrix(self, t: float) -> NDArray[np.float64]:
        """4×4 LiDAR → world transform at time ``t``."""
        origin, rotation = self.sensor_pose(np.array([t], np.float64))
        pose = np.eye(4)
        pose[:3, :3] = rotation[0]
        pose[:3, 3] = origin[0]
        return pose

    def actor_times(self, t_ref: float) -> NDArray[np.float64]:
        """When the head sweeps over each actor (absolute times), found by two fixed-point steps
        (one when nothing moves)."""
        actors = self.world.actors
        times = np.full(len(actors), t_ref)
        if not actors:
            return times
        moving = self.world.ego.speed > 0 or any(a.trajectory.speed > 0 for a in actors)
        for _ in range(2 if moving else 1):
            positions = positions_at(actors, times)
            ex, ey, _, eyaw = self.ego_pose(times)
            azimuth = np.arctan2(positions[:, 1] - ey, positions[:, 0] - ex) - eyaw
            times = t_ref + self.sensor.time_of_azimuth(azimuth)
        return times

    def _moving_mesh(self, times: NDArray[np.float64], which: list[PlacedActor] | None = None,
                     ) -> tuple[Mesh, NDArray[np.int32], NDArray[np.float64]]:
        """Moving road users (``which``, default all) posed at ``times`` (indexed by actor index):
        mesh, each face's owner, and every actor's (x, y, z, yaw) (zeros for the others)."""
        actors = self._moving if which is None else which
        key, indices = times.tobytes(), tuple(a.index for a in actors)
        memo = self._moving_memo
        if memo is not None and memo[0] == key and memo[1] == indices:
            mesh, owner, poses = memo[2]
            return mesh, owner, poses.copy()  # callers fill in the still road users' poses
        result = self._pose_moving(times, actors)
        self._moving_memo = (key, indices, result)
        return result[0], result[1], result[2].copy()

    def _pose_moving(self, times: NDArray[np.float64], actors: list[PlacedActor],
                     ) -> tuple[Mesh, NDArray[np.int32], NDArray[np.float64]]:
        own_times = times[[a.index for a in actors]]
        placed = poses_on_ground(tuple(actors), positions_at(tuple(actors), own_times), self.world.ground)
        rotations = frame_from_slopes(placed[:, 3], placed[:, 4], placed[:, 5])
        meshes, owner, poses = [], [], np.zeros((len(self.world.actors), 6))
        for actor, t, pose_on_ground, rotation in zip(actors, own_times, placed, rotations, strict=True):
            mesh, pose = actor.mesh_at(float(t), self.world.ground, pose=tuple(pose_on_ground), rotation=rotation)
            meshes.append(mesh)
            owner.append(np.full(len(mesh), actor.index, np.int32))
            poses[actor.index] = pose
        return Mesh.concat(meshes), np.concatenate(owner or [np.zeros(0, np.int32)]), poses

    def _straddles_seam(self, t_ref: float, times: NDArray[np.float64], actor: PlacedActor) -> bool:
        """Whether the actor, seen from the sensor mid-sweep, spans the azimuth ±π behind the car."""
        if abs(times[actor.index] - t_ref) < self.sensor.period / 4:
            return False  # ahead or beside: the head sweeps over it in one go
        x, y, _ = (float(v[0]) for v in actor.trajectory.at(times[actor.index]))
        ex, ey, _, eyaw = (float(v[0]) for v in self.ego_pose(t_ref))
        length, width, _ = actor.size
        reach = np.hypot(length, width) / 2 + actor.trajectory.speed * self.sensor.period + 1.0
        behind = np.angle(np.exp(1j * (np.arctan2(y - ey, x - ex) - eyaw - np.pi)))  # 0 = straight behind
        distance = max(np.hypot(x - ex, y - ey), 1e-3)
        return bool(abs(behind) < np.arcsin(min(1.0, reach / distance)) + 2 * 2 * np.pi / self.sensor.columns)

    def moving_parts(self, t_ref: float, times: NDArray[np.float64]) -> list[MovingPart]:
        """The moving road users as the rays see them.

        Each is posed when the head sweeps over it. One behind the car can straddle the
        seam where a sweep starts and ends: the head passes its two halves a whole period
        apart, so it is posed twice — at the start of the sweep for the first half of the
        columns and at the end for the second half — as a real spinning sensor sees it.
        """
        if not self._moving:
            return []
        period, columns, beams = self.sensor.period, self.sensor.columns, self.sensor.beams
        seam = [a for a in self._moving if self._straddles_seam(t_ref, times, a)]
        rest = [a for a in self._moving if a not in seam]
        first_half = np.repeat(np.arange(columns) < columns // 2, beams)
        poses: list[tuple[NDArray[np.float64], NDArray[np.bool_], list[PlacedActor]]] = []
        if rest:
            poses.append((times, np.ones(columns * beams, bool), rest))
        if seam:
            early = np.where(times - t_ref > 0, times - period, times)
            late = np.where(times - t_ref < 0, times + period, times)
            poses += [(early, first_half, seam), (late, ~first_half, seam)]
        parts = []
        for pose_times, rays, which in poses:
            mesh, owner, _ = self._moving_mesh(pose_times, which)
            origin, rotation = self.sensor_pose(pose_times)
            parts.append(MovingPart(mesh, owner, origin, rays, rotation))
        return parts

    def _actor_meshes(self, times: NDArray[np.float64]) -> tuple[Mesh, NDArray[np.int32], NDArray[np.float64]]:
        """All road users' mesh (the still ones' faces first), each face's owner, and every
        actor's (x, y, z, yaw) at its time."""
        moving, moving_owner, poses = self._moving_mesh(times)
        for index, pose in self._still_poses.items():
            poses[index] = pose
        return Mesh.concat([self._still_mesh, moving]), np.concatenate([self._still_owner, moving_owner]), poses

    def rays(self, t_ref: float) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """World-frame origins and unit directions of every ray, in firing order (column-major)."""
        sensor = self.sensor
        origin, rotation = self.sensor_pose(t_ref + sensor.column_times)
        local = self._local_directions.reshape(sensor.columns, sensor.beams, 3)
        directions = np.matmul(local, rotation.astype(np.float32).transpose(0, 2, 1))
        origins = np.repeat(origin.astype(np.float32), sensor.beams, axis=0)
        return origins, directions.reshape(-1, 3)

    def _static(self) -> rtcore_scene.EmbreeScene | None:
        """The static world's Embree scene, built once (loading triangles dominates its cost)."""
        static, still = self.world.static, self._still_mesh
        if self._static_scene is None and (len(static) or len(still)):
            scene = rtcore_scene.EmbreeScene(self._device)
            # Geometry ids in the order added: the world (0) then the still road users (1).
            for mesh in (static, still):
                if len(mesh):
                    add_triangles(scene, mesh.vertices, mesh.faces)
                else:  # keep the ids stable with a degenerate placeholder triangle far away
                    TriangleMesh(scene, np.full((3, 3), -1e6, np.float32), np.array([[0, 1, 2]], np.int32))
            self._static_scene = scene
        return self._static_scene

    def cast(self, origins: NDArray[np.float32], directions: NDArray[np.float32],
             moving: list[MovingPart] | None = None) -> Hits:
        """Nearest hit of every ray: the static scene (the world and the road users that never
        move) first, then each pose of the moving road users, only along rays aimed at them
        and only up to the distance found so far."""
        n = len(origins)
        static = self._static()
        if static is not None:
            result = self._trace(static, origins, directions, np.full(n, self.sensor.max_range, np.float32))
            # Embree's fresh output arrays (this call's own: updated in place below).
            distance, normal = result["tfar"], result["Ng"]
            geometry = np.asarray(result["geomID"], np.int32)
            # One gather per property from a table of every static face (the world's faces, then
            # the still road users', then a row for "nothing hit"): a hit on the world is its
            # face's row, a hit on a still road user is moved past the world's faces, and a miss
            # has primID −1 (embreex sets it so, and Embree writes it only on a hit), the last row.
            row = np.asarray(result["primID"], np.int32)
            table, owners = self._static_faces()
            still = np.flatnonzero(geometry == 1)  # a few hundred rays: the rest need no test
            row[still] += len(self.world.static)
            # One 1-D gather per property (np.take on a contiguous column: no N×4 temporary to split).
            reflectivity, semantic, returns, gloss = (np.take(column, row) for column in table)
            owner = np.full(n, -1, np.int64)  # the world's faces and misses have no road user
            owner[still] = np.take(owners, row[still])
        else:
            reflectivity, returns, gloss = np.zeros(n, np.float32), np.ones(n, np.float32), np.zeros(n, np.float32)
            semantic, owner = np.zeros(n, np.uint8), np.full(n, -1, np.int64)
            distance = np.full(n, self.sensor.max_range, np.float32)
            geometry, normal = np.full(n, -1, np.int32), np.zeros((n, 3), np.float32)
        for part in moving or []:
            if not len(part.mesh):
                continue
            rays = np.flatnonzero(part.rays & self._rays_towards_mesh(origins, part.mesh, part.owner,
                                                                      part.viewpoints, part.orientations))
            if not len(rays):
                continue
            scene = rtcore_scene.EmbreeScene(self._device)
            add_triangles(scene, part.mesh.vertices, part.mesh.faces)
            limit = np.nextafter(distance[rays], np.float32(np.inf))
            found = self._trace(scene, origins[rays], directions[rays], limit)
            nearer = found["geomID"] >= 0
            hit, face = rays[nearer], found["primID"][nearer]
            # distance and normal are this call's own arrays (Embree's fresh output, or filled
            # above): updated in place.
            distance[hit] = found["tfar"][nearer]
            normal[hit] = found["Ng"][nearer]
            geometry[hit] = 1
            reflectivity[hit] = part.mesh.reflectivity[face]
            semantic[hit] = part.mesh.semantic[face]
            returns[hit] = part.mesh.returns[face]
            gloss[hit] = part.mesh.gloss[face]
            owner[hit] = part.owner[face]
        return Hits(distance, geometry, normal, reflectivity, semantic, owner, returns, gloss)

    def _static_faces(self) -> tuple[tuple[NDArray[Any], ...], NDArray[np.int64]]:
        """Reflectivity (float32), semantic class (uint8), return probability and gloss (float32)
        of every static face (the world's, then the still road users'), one contiguous column
        each with a last row for rays that hit nothing (0, 0, 1, 0), and each face's road user
        (−1 for the world and that last row)."""
        if self._face_table is None:
            meshes = (self.world.static, self._still_mesh)

            def column(name: str, nothing: float, dtype: type) -> NDArray[Any]:
                return np.concatenate([*(np.asarray(getattr(m, name), dtype) for m in meshes),
                                       np.array([nothing], dtype)])

            columns = (column("reflectivity", 0.0, np.float32), column("semantic", 0, np.uint8),
                       column("returns", 1.0, np.float32), column("gloss", 0.0, np.float32))
            owners = np.concatenate([np.full(len(self.world.static), -1, np.int64), self._still_owner.astype(np.int64),
                                     [-1]])
            self._face_table = (columns, owners)
        return self._face_table

    def _trace(self, scene: rtcore_scene.EmbreeScene, origins: NDArray[np.float32],
               directions: NDArray[np.float32], limit: NDArray[np.float32]) -> dict[str, NDArray[Any]]:
        """``scene.run`` on all rays, split over the renderer's threads when there are many (the
        results do not depend on the split: each ray is traced on its own)."""
        n = len(origins)
        if self.threads == 1 or n < 20_000:
            return scene.run(origins, directions, dists=limit, output=1)  # type: ignore[no-any-return]
        bounds = np.linspace(0, n, self.threads + 1).astype(int)
        chunks = [slice(a, b) for a, b in itertools.pairwise(bounds)]
        results = list(_thread_pool(self.threads).map(
            lambda part: scene.run(origins[part], directions[part], dists=limit[part], output=1), chunks))
        return {key: np.concatenate([r[key] for r in results]) for key in results[0]}

    def _rays_towards_mesh(self, origins: NDArray[np.float32], mesh: Mesh, owner: NDArray[np.int32],
                           viewpoints: NDArray[np.float64], orientations: NDArray[np.float64],
                           ) -> NDArray[np.bool_]:
        """Rays (column × beam grid) fired into the angular extent of each object of ``mesh``
        (faces grouped by ``owner``) seen from ``viewpoints`` with the sensor's ``orientations``
        (the sensor when the head sweeps over each object), measured in the sensor's frame,
        widened by the sensor's travel while sweeping over the object, and two steps."""
        sensor = self.sensor
        groups = owner.astype(np.int64)
        vertex_group = np.zeros(len(mesh.vertices), np.int64)
        vertex_group[mesh.faces.ravel()] = np.repeat(groups, 3)
        sweep_travel = float(np.linalg.norm(origins[-1] - origins[0]))
        # Into each viewpoint's sensor frame: the beam table's azimuths and elevations apply there.
        offset = np.matmul((mesh.vertices - viewpoints[vertex_group])[:, None, :], orientations[vertex_group])[:, 0]
        distance_xy = np.hypot(offset[:, 0], offset[:, 1])
        azimuth = np.arctan2(offset[:, 1], offset[:, 0])
        elevation = np.arctan2(offset[:, 2], distance_xy)
        ids, first = np.unique(vertex_group, return_index=True)
        n = int(ids.max()) + 1
        reference = np.zeros(n)
        reference[ids] = azimuth[first]
        relative = np.angle(np.exp(1j * (azimuth - reference[vertex_group])))  # unwrapped around the object
        lo_az, hi_az = np.full(n, np.inf), np.full(n, -np.inf)
        lo_el, hi_el = np.full(n, np.inf), np.full(n, -np.inf)
        nearest = np.full(n, np.inf)
        np.minimum.at(lo_az, vertex_group, relative)
        np.maximum.at(hi_az, vertex_group, relative)
        np.minimum.at(lo_el, vertex_group, elevation)
        np.maximum.at(hi_el, vertex_group, elevation)
        np.minimum.at(nearest, vertex_group, distance_xy)
        lo_az, hi_az, lo_el, hi_el, nearest, reference = (a[ids] for a in (lo_az, hi_az, lo_el, hi_el, nearest,
                                                                          reference))
        # While the head sweeps over an object the sensor moves by a share of a sweep's travel.
        share = np.minimum((hi_az - lo_az) / (2 * np.pi) + 0.05, 1.0)
        travel = sweep_travel * share + 0.05
        widen = np.minimum(travel / np.maximum(nearest, 1e-3), np.pi) + 2.0 * 2.0 * np.pi / sensor.columns
        close = nearest < travel + 0.3  # the sensor (nearly) inside: every direction
        lo_az, hi_az = np.where(close, -np.pi, lo_az - widen), np.where(close, np.pi, hi_az + widen)
        first_col = np.floor(sensor.column_of_azimuth(reference + hi_az)).astype(np.int64)
        span = np.minimum(np.ceil((hi_az - lo_az) / (2 * np.pi) * sensor.columns).astype(np.int64) + 2,
                          sensor.columns)
        elevations = sensor.ring_elevations
        lo_ring = np.searchsorted(elevations, np.where(close, -np.pi, lo_el - widen))
        hi_ring = np.searchsorted(elevations, np.where(close, np.pi, hi_el + widen))
        return covered_rays(sensor.columns, sensor.beams, first_col % sensor.columns, span, lo_ring, hi_ring)

    def visible_rays_alone(self, actors: Mesh, owner: NDArray[np.int32], index: int,
                           origins: NDArray[np.float32], directions: NDArray[np.float32],
                           candidates: NDArray[np.intp]) -> int:
        """How many of the ``candidates`` rays would hit actor ``index`` if nothing else were there."""
        faces = actors.faces[owner == index]
        if len(faces) == 0 or len(candidates) == 0:
            return 0
        # The span of vertices its faces use (an actor's own block of ``actors``): Embree sees
        # the same triangles in the same order whether or not the span holds vertices no face uses.
        first = int(faces.min())
        scene = rtcore_scene.EmbreeScene(self._device)
        add_triangles(scene, actors.vertices[first:int(faces.max()) + 1], faces - np.int32(first))
        limit = np.full(len(candidates), self.sensor.max_range, np.float32)
        result = scene.run(origins[candidates], directions[candidates], dists=limit, output=1)
        hit = (result["geomID"] >= 0) & (result["tfar"] >= self.sensor.min_range)
        return int(hit.sum())

    # ------------------------------------------------------------------ returns
    def _specular_survival(self, gloss: NDArray[np.float32], cos_incidence: NDArray[np.float32],
                           ) -> NDArray[np.float32]:
        """Probability that a glossy surface hit at ``cos_incidence`` scatters the beam back
        instead of mirroring it away (:class:`~lidarfuzz.sim.sensor.Dropouts`)."""
        edge = np.float32(self.sensor.dropouts.specular_cos)
        if edge <= 0:
            return np.ones_like(gloss)
        grazing = np.clip((edge - cos_incidence) / edge, np.float32(0.0), np.float32(1.0))
        return np.float32(1.0) - gloss * grazing

    def _sensor_losses(self, rng: np.random.Generator) -> NDArray[np.bool_]:
        """Rays that can return at all (firing order): not in the vehicle's shadow, not in a lost
        azimuth sector. A fixed number of draws, whatever the scene, so the other noise stays put."""
        sensor, dropouts = self.sensor, self.sensor.dropouts
        ok = ~sensor.shadowed
        count_draw, start_draw, width_draw = rng.random(), rng.random(_MAX_GAPS), rng.random(_MAX_GAPS)
        gaps = min(int(np.searchsorted(np.cumsum(_poisson_pmf(dropouts.azimuth_gaps)), count_draw)), _MAX_GAPS)
        if gaps:
            ok = ok.copy()
            lo, hi = dropouts.gap_columns
            for start, width in zip(start_draw[:gaps], width_draw[:gaps], strict=True):
                first = int(start * sensor.columns)
                columns = np.arange(first, first + lo + int(width * (hi - lo + 1))) % sensor.columns
                ok[columns] = False
        return ok.ravel()

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
        hits = self.cast(origins, directions, self.moving_parts(t_ref, times))

        n = len(origins)
        geometric = (hits.geometry >= 0) & (hits.distance >= sensor.min_range) & (hits.distance <= sensor.max_range)
        reflectivity, semantic = hits.reflectivity, hits.semantic
        instance = np.where(geometric, hits.owner, -1)

        cos_incidence = incidence_cosines(hits.normal, directions)
        distance = hits.distance
        # Draw every random number for every ray, so that a change in the scene does not
        # shift the noise of unrelated rays.
        range_error, drop_draw, return_draw, intensity_error = _draw_buffers(n)
        rng.standard_normal(dtype=np.float32, out=range_error)
        range_error *= np.float32(sensor.range_noise)
        rng.random(dtype=np.float32, out=drop_draw)
        rng.random(dtype=np.float32, out=return_draw)
        rng.standard_normal(dtype=np.float32, out=intensity_error)
        intensity_error *= np.float32(sensor.intensity_noise)

        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            signal = reflectivity * np.sqrt(np.maximum(cos_incidence, np.float32(0.05)))
            signal *= (np.float32(100.0) / distance) ** 2
        kept = geometric & (signal >= sensor.detection_threshold)
        kept &= drop_draw >= self._drop_rate_of_ray
        kept &= return_draw < hits.returns * self._specular_survival(hits.gloss, cos_incidence)
        kept &= self._sensor_losses(rng)
        index = np.flatnonzero(kept)
        d = distance[index]
        intensity = sensor.receiver.read(reflectivity[index], cos_incidence[index], d, self._ring_index[index],
                                         intensity_error[index], sensor.beams)

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
            origins=origins, directions=directions, geometric_owner=instance,  # −1 where not geometric
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
