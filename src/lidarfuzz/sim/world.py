"""A scene description compiled into geometry and motion: the static mesh, the drivable area, trajectories.

The static world (ground, roads with markings, kerbs and sidewalks, buildings with
windows, walls, vegetation, poles, signs) is built once per scene, draped over the
scene's terrain (:mod:`lidarfuzz.sim.terrain`); road users are placed per frame from
their trajectories, standing on the ground beneath them (vehicles tilted with it).
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache, cached_property
from typing import Any

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import LineString, MultiPolygon, Point, Polygon, box
from shapely.ops import unary_union

from lidarfuzz.sim.actors import actor_mesh, mean_size
from lidarfuzz.sim.materials import MATERIAL_ID, OBJECT_SEMANTIC, PAINT_GLOSS, SEMANTIC_ID, material, sample_paint
from lidarfuzz.sim.meshes import Mesh, cylinder, ellipsoid, extruded, polygons_of, unit_box, unit_cylinder, unit_sphere
from lidarfuzz.sim.meshes import box as box_mesh
from lidarfuzz.sim.motion import LATERAL_ACCEL, RoundedPath, SpeedProfile, steering_angle
from lidarfuzz.sim.sensor import LidarSensor, load_sensor
from lidarfuzz.sim.spec import Actor, Building, Bush, Crosswalk, Ego, Pole, Road, SceneSpec, Sign, Tree, Wall
from lidarfuzz.sim.terrain import VERGE_CELLS, Ground, frame_from_slopes, ramp_edges

#: Road users that rest on four wheels tilt with the ground; people and riders stay upright.
TILTING_CLASSES = frozenset({"Car", "Van", "Truck"})
#: Static objects are sunk this far into sloping ground, so none floats above its lowest corner.
SINK = 0.05

MARKING_Z = 0.006  # paint sits just above the asphalt so rays hit it first
STRIDE = 1.5  # metres per walking cycle
GROUND_MATERIALS = {"grass": "grass", "soil": "soil", "paving": "pavement"}  # open ground beside the roads


# --------------------------------------------------------------------------- motion
@dataclass(frozen=True)
class Trajectory:
    """Constant-speed motion along a polyline; before the start it extrapolates the first segment backwards."""

    waypoints: NDArray[np.float64]  # K×2
    speed: float

    @staticmethod
    def of(position: tuple[float, float], yaw_deg: float, speed: float,
           route: list[tuple[float, float]] | None) -> Trajectory:
        if route is not None:
            return Trajectory(np.asarray(route, dtype=np.float64), speed)
        heading = np.deg2rad(yaw_deg)
        start = np.asarray(position, dtype=np.float64)
        end = start + 1.0e4 * np.array([np.cos(heading), np.sin(heading)])
        return Trajectory(np.stack([start, end]), speed)

    @cached_property
    def _arc(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        seg = np.diff(self.waypoints, axis=0)
        length = np.linalg.norm(seg, axis=1)
        keep = length > 1e-9
        seg, length = seg[keep], length[keep]
        if len(seg) == 0:
            return np.zeros(1), np.zeros((1, 2)), np.zeros(1)
        cum = np.concatenate([[0.0], np.cumsum(length)])
        heading = np.arctan2(seg[:, 1], seg[:, 0])
        return cum, seg / length[:, None], heading

    def distance(self, t: NDArray[np.float64] | float) -> NDArray[np.float64]:
        return np.asarray(t, dtype=np.float64) * self.speed

    def at(self, t: NDArray[np.float64] | float
           ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(x, y, yaw) at time(s) ``t`` (seconds from the scene's start)."""
        s = np.atleast_1d(self.distance(t))
        cum, unit, heading = self._arc
        if len(cum) == 1:
            n = len(s)
            return np.full(n, self.waypoints[0, 0]), np.full(n, self.waypoints[0, 1]), np.zeros(n)
        s = np.minimum(s, cum[-1])
        seg = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(unit) - 1)
        xy = _segment_starts(self.waypoints)[seg] + (s - cum[seg])[:, None] * unit[seg]
        return xy[:, 0], xy[:, 1], heading[seg]

    def kinematics(self, t: NDArray[np.float64] | float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(speed in m/s, curvature in 1/m) at time(s) ``t``: the constant speed until the route's end,
        then 0; a polyline's curvature is 0 (its corners turn in an instant)."""
        s = np.atleast_1d(self.distance(t))
        end = self._arc[0][-1]
        moving = (s < end) if len(self._arc[0]) > 1 else np.zeros(len(s), bool)
        return np.where(moving, self.speed, 0.0), np.zeros(len(s))


@dataclass(frozen=True)
class ProfiledTrajectory(Trajectory):
    """Motion along a :class:`~lidarfuzz.sim.motion.RoundedPath` with a
    :class:`~lidarfuzz.sim.motion.SpeedProfile` (:mod:`lidarfuzz.sim.motion`); ``speed`` is its top speed."""

    path: RoundedPath
    profile: SpeedProfile

    @staticmethod
    def of_entry(entry: Ego | Actor, speed: float) -> ProfiledTrajectory:
        """The motion of a scene entry that has motion fields (``speed`` 0 for a parked actor)."""
        if entry.route is not None:
            waypoints = np.asarray(entry.route, np.float64)
        else:
            heading = np.deg2rad(entry.yaw)
            start = np.asarray(entry.position, np.float64)
            waypoints = np.stack([start, start + 1.0e4 * np.array([np.cos(heading), np.sin(heading)])])
        path = RoundedPath.of(waypoints, entry.corner_radius)
        marks = path.waypoint_offsets
        leg_speeds = entry.speeds if entry.speeds is not None else [speed] * (len(waypoints) - 1)
        limits = [(float(marks[k]), float(marks[k + 1]), float(v)) for k, v in enumerate(leg_speeds)]
        lateral = entry.lateral_accel if entry.lateral_accel is not None else LATERAL_ACCEL
        for k, kappa in enumerate(path.curvatures):
            if kappa:  # the corner's speed: lateral acceleration v²·|κ| at most `lateral`
                limits.append((float(path.offsets[k]), float(path.offsets[k + 1]),
                               float(np.sqrt(lateral / abs(kappa)))))
        stops = [(stop.at, stop.duration) for stop in entry.stops or []]
        profile = SpeedProfile.plan(path.length, limits, stops=stops, **entry.acceleration_limits())
        return ProfiledTrajectory(waypoints, profile.top_speed, path, profile)

    def distance(self, t: NDArray[np.float64] | float) -> NDArray[np.float64]:
        return self.profile.distance(t).reshape(np.shape(t))  # a scalar time gives a 0-d array, as the base's

    def at(self, t: NDArray[np.float64] | float
           ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        return self.path.pose(self.profile.distance(t))

    def kinematics(self, t: NDArray[np.float64] | float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return self.profile.speed(t), self.path.curvature(self.profile.distance(t))


def trajectory_of(entry: Ego | Actor, speed: float) -> Trajectory:
    """An entry's motion: a :class:`ProfiledTrajectory` when it has motion fields, else the plain
    constant-speed :class:`Trajectory` (unchanged, so scenes without those fields render as before)."""
    if entry.has_motion_profile and (speed > 0 or entry.speeds is not None):
        return ProfiledTrajectory.of_entry(entry, speed)
    return Trajectory.of(entry.position, entry.yaw, speed, entry.route)


def ego_labels(trajectory: Trajectory, times: NDArray[np.float64]) -> NDArray[np.float64]:
    """N×4 rows of the ego vehicle's speed (m/s), yaw rate (rad/s, left positive), curvature (1/m)
    and steering angle (rad, bicycle model with :data:`~lidarfuzz.sim.terrain.WHEELBASE`) at ``times``."""
    speed, curvature = trajectory.kinematics(np.asarray(times, np.float64))
    return np.stack([speed, speed * curvature, curvature, steering_angle(curvature)], axis=1)


def _segment_starts(waypoints: NDArray[np.float64]) -> NDArray[np.float64]:
    seg = np.diff(waypoints, axis=0)
    keep = np.linalg.norm(seg, axis=1) > 1e-9
    return waypoints[:-1][keep] if keep.any() else waypoints[:1]


@dataclass(frozen=True)
class PlacedActor:
    """A road user of a compiled world."""

    index: int
    track_id: int
    cls: str
    size: tuple[float, float, float]
    reflectivity: float
    trajectory: Trajectory
    phase: float  # walking phase offset (radians)

    def pose_at(self, ground: Ground, x: float, y: float, yaw: float) -> tuple[float, ...]:
        """(x, y, z, yaw, rise forward, rise left): standing at (x, y) on the ``ground``
        (see :func:`poses_on_ground`)."""
        return tuple(float(v) for v in poses_on_ground((self,), np.array([[x, y, yaw]]), ground)[0])

    def mesh_at(self, t: float, ground: Ground, xy_yaw: tuple[float, float, float] | None = None,
                pose: tuple[float, ...] | None = None, rotation: NDArray[np.float64] | None = None,
                ) -> tuple[Mesh, tuple[float, ...]]:
        """World-frame mesh and pose (:func:`poses_on_ground`) at time ``t``, standing on the
        ``ground`` (``xy_yaw`` or ``pose``, and the pose's ``rotation``: where it is at ``t`` when
        the caller has it already)."""
        if pose is None:
            x, y, yaw = xy_yaw if xy_yaw is not None else (float(v[0]) for v in self.trajectory.at(t))
            pose = self.pose_at(ground, float(x), float(y), float(yaw))
        phase = self.phase + 2 * np.pi * float(self.trajectory.distance(t)) / STRIDE
        gloss = PAINT_GLOSS if self.cls in TILTING_CLASSES else 0.0  # clear-coated paint, matt clothes
        local = actor_mesh(self.cls, self.size, phase).painted(self.reflectivity, OBJECT_SEMANTIC[self.cls], gloss)
        if pose[4] or pose[5]:
            rotation = frame_from_slopes(pose[3], pose[4], pose[5]) if rotation is None else rotation
            return local.posed(rotation, pose[:3]), pose
        return local.placed(pose[0], pose[1], pose[3], pose[2]), pose


def poses_on_ground(actors: tuple[PlacedActor, ...], xy_yaw: NDArray[np.float64], ground: Ground,
                    ) -> NDArray[np.float64]:
    """Where road users at ``xy_yaw`` (N×3) stand: N×6 (x, y, z, yaw, rise forward, rise left).

    A vehicle rests on the plane through its wheels (80 % of its length and 85 % of its width
    apart), tilted with it; a person stands upright on the surface under its centre.
    """
    out = np.zeros((len(actors), 6))
    if not len(actors):
        return out
    out[:, [0, 1, 3]] = xy_yaw
    tilting = np.array([a.cls in TILTING_CLASSES for a in actors]) & (not ground.is_flat)
    if tilting.any():
        sizes = np.array([a.size for a in actors])[tilting]
        z, forward, left = ground.tilt(xy_yaw[tilting, 0], xy_yaw[tilting, 1], xy_yaw[tilting, 2],
                                       0.8 * sizes[:, 0], 0.85 * sizes[:, 1])
        out[tilting, 2], out[tilting, 4], out[tilting, 5] = z, forward, left
    if (~tilting).any():
        out[~tilting, 2] = ground.height(xy_yaw[~tilting, 0], xy_yaw[~tilting, 1])
    return out


def positions_at(actors: tuple[PlacedActor, ...], times: NDArray[np.float64]) -> NDArray[np.float64]:
    """(x, y, yaw) of every actor at its own time, N×3; straight-line motion is vectorised."""
    out = np.empty((len(actors), 3))
    straight = [i for i, a in enumerate(actors)
                if len(a.trajectory.waypoints) == 2 and type(a.trajectory) is Trajectory]
    if straight:
        index = np.asarray(straight)
        start = np.array([actors[i].trajectory.waypoints[0] for i in straight])
        end = np.array([actors[i].trajectory.waypoints[1] for i in straight])
        speed = np.array([actors[i].trajectory.speed for i in straight])
        seg = end - start
        length = np.linalg.norm(seg, axis=1)
        unit = seg / np.maximum(length, 1e-12)[:, None]
        s = np.minimum(times[index] * speed, length)
        out[index, :2] = start + s[:, None] * unit
        out[index, 2] = np.where(length > 1e-9, np.arctan2(seg[:, 1], seg[:, 0]), 0.0)
    for i, actor in enumerate(actors):
        if len(actor.trajectory.waypoints) != 2 or type(actor.trajectory) is not Trajectory:
            out[i] = [float(v[0]) for v in actor.trajectory.at(times[i])]
    return out


@dataclass(frozen=True, eq=False)
class World:
    """A compiled scene: static geometry, drivable area, actors, ego trajectory and sensor."""

    spec: SceneSpec
    sensor: LidarSensor
    static: Mesh
    drivable: MultiPolygon
    actors: tuple[PlacedActor, ...]
    ego: Trajectory
    ground: Ground


def compile_world(spec: SceneSpec) -> World:
    """Build the geometry of ``spec``."""
    sensor = load_sensor(spec.sensor)
    ego = trajectory_of(spec.ego, spec.ego.speed)
    parts, ground = _ground_and_roads(spec, ego)
    parts.append(_on_ground(_static_objects(list(spec.objects)), list(spec.objects), ground))
    actors = []
    for index, actor in enumerate(spec.actors):
        actors.append(_place_actor(index, actor, spec.seed))
    return World(spec, sensor, Mesh.concat(parts), ground.drivable, tuple(actors), ego, ground)


def _place_actor(index: int, actor: Actor, seed: int) -> PlacedActor:
    rng = np.random.default_rng([seed, index, 0xAC7])
    size = actor.size or mean_size(actor.cls)
    if actor.reflectivity is not None:
        refl = actor.reflectivity
    elif actor.cls in ("Pedestrian", "Cyclist"):
        refl = float(rng.uniform(0.1, 0.6))
    else:
        refl = sample_paint(rng)
    speed = 0.0 if actor.parked else actor.speed
    trajectory = trajectory_of(actor, speed)
    track_id = actor.id if actor.id is not None else index
    return PlacedActor(index, track_id, actor.cls, tuple(size), refl, trajectory,  # type: ignore[arg-type]
                       float(rng.uniform(0, 2 * np.pi)))


# --------------------------------------------------------------------------- ground and roads
def _ground_and_roads(spec: SceneSpec, ego: Trajectory) -> tuple[list[Mesh], Ground]:
    route_extent = ego.waypoints
    if spec.ego.route is None and spec.ego.speed == 0:
        route_extent = ego.waypoints[:1]  # a standing ego vehicle: not its 10 km heading line
    elif spec.ego.route is None:
        x, y, _ = ego.at(np.array([0.0, 60.0]))  # a minute of driving is more than any generated log
        route_extent = np.stack([x, y], axis=1)
    lo = route_extent.min(axis=0) - spec.extent
    hi = route_extent.max(axis=0) + spec.extent
    if not spec.terrain.is_flat:  # on the open ground's grid: its edge cells are whole
        grid = max(VERGE_CELLS)
        lo, hi = np.floor(lo / grid) * grid, np.ceil(hi / grid) * grid
    square = box(lo[0], lo[1], hi[0], hi[1])

    carriageways = [LineString(r.centerline).buffer(r.half_width, cap_style="flat", join_style="mitre")
                    for r in spec.roads]
    drivable = unary_union(carriageways).intersection(square) if carriageways else Polygon()
    sidewalk_areas = [LineString(r.centerline).buffer(r.half_width + r.sidewalk_width, cap_style="flat",
                                                      join_style="mitre") for r in spec.roads if r.sidewalk_width > 0]
    sidewalks = unary_union(sidewalk_areas).difference(drivable).intersection(square) if sidewalk_areas else Polygon()
    kerb = max((r.kerb_height for r in spec.roads), default=0.0)
    terrain = square.difference(drivable).difference(sidewalks)
    terrain_height = kerb * 0.8 if spec.roads else 0.0
    ground = Ground(spec.terrain, tuple(spec.roads), as_multipolygon(drivable), as_multipolygon(sidewalks), kerb,
                    terrain_height)
    parts: list[Mesh] = []
    if not drivable.is_empty:
        # Cut along the centrelines so the crown's ridge is an edge of the mesh.
        ridges = unary_union([LineString(r.centerline) for r in spec.roads if not r.one_way])
        parts.append(ground.drape(drivable, "road", "asphalt", cut=ridges))
        parts.append(_markings(spec, drivable, ground))
    if not sidewalks.is_empty:
        parts.append(ground.drape(sidewalks, "sidewalk", "paving", cut=ramp_edges(ground)))
        parts.append(ground.walls(sidewalks, "sidewalk", "kerb"))
    ground_material = GROUND_MATERIALS[spec.ground]
    parts.append(ground.drape(terrain, "verge", ground_material, cell=ground.verge_cell))
    if spec.roads:
        parts.append(ground.walls(terrain, "verge", ground_material))
    return parts, ground


def as_multipolygon(geometry: object) -> MultiPolygon:
    return polygons_of(geometry)


def _markings(spec: SceneSpec, drivable: Polygon | MultiPolygon, ground: Ground) -> Mesh:
    """Edge lines, centre lines, dashed lane dividers (kept out of junctions) and crosswalks."""
    lines = []
    junctions = _junctions(spec.roads)
    for road in spec.roads:
        centre = LineString(road.centerline)
        half = road.carriageway_half_width
        for side in (-1.0, 1.0):
            lines.append(centre.offset_curve(side * (half - 0.2)).buffer(0.075, cap_style="flat"))
        for lane in range(1, road.lanes):
            offset = -half + lane * road.lane_width
            line = centre.offset_curve(offset) if abs(offset) > 1e-6 else centre
            solid = abs(offset) < 1e-6 and not road.one_way
            lines.append(line.buffer(0.075, cap_style="flat") if solid else _dashes(line, 3.0, 6.0, 0.075))
    paint = unary_union(lines).difference(junctions) if lines else Polygon()
    stripes = [_crosswalk(c) for c in spec.objects if isinstance(c, Crosswalk)]
    if stripes:
        paint = unary_union([paint, *stripes])
    paint = paint.intersection(drivable)
    return ground.drape(paint, "road", "road-paint", lift=MARKING_Z) if not paint.is_empty else Mesh.empty()


def _junctions(roads: list[Road]) -> Polygon | MultiPolygon:
    areas = [LineString(r.centerline).buffer(r.half_width + 1.0, cap_style="flat") for r in roads]
    overlaps = [a.intersection(b) for i, a in enumerate(areas) for b in areas[i + 1:]]
    return unary_union(overlaps) if overlaps else Polygon()


def _dashes(line: LineString, on: float, off: float, half_width: float) -> Polygon | MultiPolygon:
    """Dashes ``on`` metres long every ``on + off`` metres along ``line``, ``2 half_width`` wide.

    The dashes are buffered in one vectorised call (a road has dozens; the geometry method per
    dash cost ~10 µs of Python each): the same GEOS buffer with the method's parameters
    (``quad_segs=16``, where ``shapely.buffer``'s default is 8)."""
    starts = np.arange(0.0, line.length, on + off)
    pieces = np.empty(len(starts), dtype=object)
    pieces[:] = [shapely.ops.substring(line, s, min(s + on, line.length)) for s in starts]
    pieces = pieces[shapely.length(pieces) > 0] if len(pieces) else pieces
    return unary_union(shapely.buffer(pieces, half_width, quad_segs=16, cap_style="flat"))


def _crosswalk(c: Crosswalk) -> Polygon | MultiPolygon:
    yaw = np.deg2rad(c.yaw)
    along = np.array([np.cos(yaw), np.sin(yaw)])  # stripes run along yaw, repeat across
    across = np.array([-along[1], along[0]])
    stripes = []
    for offset in np.arange(-c.length / 2 + 0.25, c.length / 2, 1.0):
        centre = np.asarray(c.position) + offset * across
        a = centre - along * c.width / 2
        b = centre + along * c.width / 2
        stripes.append(LineString([a, b]).buffer(0.25, cap_style="flat"))
    return unary_union(stripes)


# --------------------------------------------------------------------------- static objects
def _on_ground(meshes: list[Mesh], objects: list[object], ground: Ground) -> Mesh:
    """Static objects built on z = 0 moved onto the ground, merged into one mesh: each to its
    footprint's lowest point (a building's or wall's corners, another object's centre), sunk by
    :data:`SINK` on sloping ground so that no corner floats.

    The objects are merged first and moved with one addition over the merged vertices (each
    vertex gets its own object's shift, x and y + 0, exactly as a mesh-by-mesh addition).
    """
    merged = Mesh.concat(meshes)
    if ground.is_flat:
        return merged
    xy, index = footprint_points(objects)
    if not len(xy):
        return merged
    lowest = np.full(len(objects), np.inf)
    np.minimum.at(lowest, index, ground.height(xy[:, 0], xy[:, 1]))
    kept = [k for k, m in enumerate(meshes) if len(m)]  # Mesh.concat leaves out meshes without faces
    counts = [len(meshes[k].vertices) for k in kept]
    moved = np.repeat(np.isfinite(lowest[kept]), counts)
    shift = np.zeros((int(moved.sum()), 3))
    shift[:, 2] = np.repeat(lowest[kept] - SINK, counts)[moved]
    merged.vertices[moved] += shift  # merged's own fresh array
    return merged


def footprint_points(objects: list[object]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The points a static object stands on, in object order, and each point's object index: a
    building's or wall's footprint corners (its closed exterior ring), another object's
    footprint centre; none for a crosswalk (painted, not standing).

    The same points as the exterior ring or centroid of :func:`footprint_of`, computed with
    shapely's vectorised functions: a world has ~70 objects and a shapely call per object cost
    ~1.4 ms a world.
    """
    chunks: list[NDArray[np.float64]] = []
    owners: list[NDArray[np.int64]] = []
    buildings = [(k, obj) for k, obj in enumerate(objects) if isinstance(obj, Building)]
    walls = [(k, obj) for k, obj in enumerate(objects) if isinstance(obj, Wall)]
    centred = [(k, disc) for k, obj in enumerate(objects) if (disc := _footprint_disc(obj)) is not None]
    for k, building in buildings:
        ring = np.asarray(building.footprint, np.float64)
        if not np.array_equal(ring[0], ring[-1]):  # shapely closes the ring
            ring = np.concatenate([ring, ring[:1]])
        chunks.append(ring)
        owners.append(np.full(len(ring), k, np.int64))
    if walls:
        lines = shapely.linestrings(np.array([[w.start, w.end] for _, w in walls], np.float64))
        # quad_segs=16: the default of the geometry method footprint_of calls (shapely.buffer's is 8)
        outlines = shapely.buffer(lines, np.array([w.thickness / 2 for _, w in walls]), quad_segs=16,
                                  cap_style="flat")
        coords, which = shapely.get_coordinates(shapely.get_exterior_ring(outlines), return_index=True)
        chunks.append(coords)
        owners.append(np.array([k for k, _ in walls], np.int64)[which])
    if centred:
        discs = shapely.buffer(shapely.points(np.array([centre for _, (centre, _) in centred], np.float64)),
                               np.array([radius for _, (_, radius) in centred]), quad_segs=16)
        chunks.append(shapely.get_coordinates(shapely.centroid(discs)))
        owners.append(np.array([k for k, _ in centred], np.int64))
    if not chunks:
        return np.zeros((0, 2)), np.zeros(0, np.int64)
    owner = np.concatenate(owners)
    order = np.argsort(owner, kind="stable")  # object order, each object's points in ring order
    return np.concatenate(chunks)[order], owner[order]


def _footprint_disc(obj: object) -> tuple[tuple[float, float], float] | None:
    """Centre and radius of the disc :func:`footprint_of` gives a tree, bush, pole or sign; None for others."""
    if isinstance(obj, Tree):
        return obj.position, obj.canopy_radius * 0.6
    if isinstance(obj, Bush):
        return obj.position, obj.radius
    if isinstance(obj, Pole | Sign):
        return obj.position, 0.3
    return None


def _static_object(obj: object) -> Mesh:
    if isinstance(obj, Building):
        return _building(obj)
    if isinstance(obj, Wall):
        a, b = np.asarray(obj.start), np.asarray(obj.end)
        length = float(np.linalg.norm(b - a))
        yaw = float(np.arctan2(*(b - a)[::-1]))
        mid = (a + b) / 2
        return box_mesh((length, obj.thickness, obj.height), (mid[0], mid[1], obj.height / 2), obj.material, yaw=yaw)
    if isinstance(obj, Tree):
        return _tree(obj)
    if isinstance(obj, Bush):
        x, y = obj.position
        return ellipsoid((obj.radius, obj.radius, obj.height / 2), (x, y, obj.height / 2), "hedge")
    if isinstance(obj, Pole):
        x, y = obj.position
        parts = [cylinder(obj.radius, (x, y, 0.0), (x, y, obj.height), "metal", sections=8)]
        if obj.arm > 0:
            yaw = np.deg2rad(obj.yaw)
            tip = (x + obj.arm * np.cos(yaw), y + obj.arm * np.sin(yaw), obj.height)
            parts.append(cylinder(0.05, (x, y, obj.height - 0.1), tip, "metal", sections=6))
            parts.append(box_mesh((0.6, 0.3, 0.15), (tip[0], tip[1], obj.height - 0.1), "metal", yaw=float(yaw)))
        return Mesh.concat(parts)
    if isinstance(obj, Sign):
        x, y = obj.position
        yaw = float(np.deg2rad(obj.yaw))
        return Mesh.concat([
            cylinder(0.04, (x, y, 0.0), (x, y, obj.height - obj.plate / 2), "metal", sections=6),
            box_mesh((0.03, obj.plate, obj.plate), (x, y, obj.height), "sign", yaw=yaw),
        ])
    if isinstance(obj, Crosswalk):
        return Mesh.empty()  # painted with the road markings
    raise TypeError(f"unknown scene object {obj!r}")


def _tree(tree: Tree) -> Mesh:
    x, y = tree.position
    canopy_bottom = max(tree.height - 2.2 * tree.canopy_radius, 1.5)
    trunk = cylinder(tree.trunk_radius, (x, y, 0.0), (x, y, canopy_bottom + 0.5), "bark", sections=8)
    crown = ellipsoid((tree.canopy_radius, tree.canopy_radius, (tree.height - canopy_bottom) / 2),
                      (x, y, (tree.height + canopy_bottom) / 2), "foliage", subdivisions=1)
    # An irregular crown: vertices pushed in and out, seeded by the position (deterministic).
    rng = np.random.default_rng(zlib.crc32(np.asarray(tree.position, np.float64).tobytes()))
    centre = np.array([x, y, (tree.height + canopy_bottom) / 2])
    scale = rng.uniform(0.8, 1.12, size=(len(crown.vertices), 1))
    crown = dataclasses.replace(crown, vertices=centre + (crown.vertices - centre) * scale)
    return Mesh.concat([trunk, crown])


def _static_objects(objects: list[object]) -> list[Mesh]:
    """Each static object's mesh, in order: the buildings built together (:func:`_buildings`),
    trees, poles and signs built together (:func:`_street_furniture`), the others one by one."""
    meshes: list[Mesh | None] = [None] * len(objects)
    buildings = [k for k, obj in enumerate(objects) if isinstance(obj, Building)]
    for k, mesh in zip(buildings, _buildings([objects[k] for k in buildings]), strict=True):  # type: ignore[misc]
        meshes[k] = mesh
    for k, mesh in _street_furniture(objects).items():
        meshes[k] = mesh
    return [mesh if mesh is not None else _static_object(obj) for mesh, obj in zip(meshes, objects, strict=True)]


def _street_furniture(objects: list[object]) -> dict[int, Mesh]:
    """The meshes :func:`_static_object` makes for the trees, poles and signs among ``objects``,
    by object index, built together.

    A world has ~20 trees, ~12 poles and ~4 signs, and building them one by one cost ~50 µs
    each (~2 ms a world), mostly numpy calls on a few dozen vertices. Their upright cylinders
    (trunks, posts), crowns and boxes (lamp heads, plates) are computed here for all of them at
    once with the same arithmetic element by element; each object's mesh is a view of the
    batch, laid out as :meth:`Mesh.concat` lays out its parts. A pole's slanted arm keeps
    :func:`~lidarfuzz.sim.meshes.cylinder` (its rotation is a matrix product per pole). An
    object whose numbers are not finite, or whose post would not rise above the ground, takes
    the one-by-one path.
    """
    out: dict[int, Mesh] = {}
    trees = [(k, obj) for k, obj in enumerate(objects) if isinstance(obj, Tree)]
    poles = [(k, obj) for k, obj in enumerate(objects) if isinstance(obj, Pole)]
    signs = [(k, obj) for k, obj in enumerate(objects) if isinstance(obj, Sign)]
    if trees:
        out.update(zip([k for k, _ in trees], _trees([t for _, t in trees]), strict=True))
    if poles:
        out.update(zip([k for k, _ in poles], _poles([p for _, p in poles]), strict=True))
    if signs:
        out.update(zip([k for k, _ in signs], _signs([s for _, s in signs]), strict=True))
    return out


def _upright_cylinders(radius: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64],
                       top: NDArray[np.float64], sections: int) -> NDArray[np.float64]:
    """The vertices of ``cylinder(radius, (x, y, 0), (x, y, top), sections=sections)`` for each
    row (top > 0), n×V×3: its axis is (0, 0, top), so its length is ``sqrt(top * top)`` (the
    norm's only non-zero term) and its rotation the identity, applied with the same product."""
    verts, _ = unit_cylinder(sections)
    length = np.sqrt(top * top)
    scale = np.stack([radius, radius, length], axis=1)
    v = (verts[None] * scale[:, None, :]).reshape(-1, 3) @ np.eye(3).T
    centre = np.stack([(x + x) / 2.0, (y + y) / 2.0, (0.0 + top) / 2.0], axis=1)
    return v.reshape(len(top), len(verts), 3) + centre[:, None, :]


def _yawed_boxes(size: NDArray[np.float64], centre: NDArray[np.float64], yaw: list[float]) -> NDArray[np.float64]:
    """The vertices of ``box(size, centre, yaw=yaw)`` for each row, n×8×3 (:meth:`Mesh.placed`'s
    arithmetic, with each box's own cosine and sine computed as it computes them)."""
    verts, _ = unit_box()
    v = verts[None] * size[:, None, :]
    c = np.array([np.cos(a) for a in yaw], np.float64)[:, None]
    s = np.array([np.sin(a) for a in yaw], np.float64)[:, None]
    out = np.empty_like(v)
    out[:, :, 0] = c * v[:, :, 0] - s * v[:, :, 1] + centre[:, 0:1]
    out[:, :, 1] = s * v[:, :, 0] + c * v[:, :, 1] + centre[:, 1:2]
    out[:, :, 2] = v[:, :, 2] + centre[:, 2:3]
    return out


def _laid_out(vertices: NDArray[np.float64], template: Mesh) -> list[Mesh]:
    """One mesh per row of ``vertices`` (n×V×3), each with ``template``'s faces and materials."""
    return [Mesh(v, template.faces, template.reflectivity, template.semantic, template.returns, template.gloss,
                 template.material) for v in vertices]


@cache
def _template(parts: tuple[tuple[int, str], ...]) -> Mesh:
    """The faces and materials of a mesh concatenated from unit primitives, given as
    (cylinder sections, 0 for a box or -1 for a once-subdivided sphere; material), as
    :meth:`Mesh.concat` of :meth:`Mesh.of` each gives them."""
    meshes = []
    for sections, material_name in parts:
        verts, faces = (unit_cylinder(sections) if sections > 0 else unit_box() if sections == 0
                        else unit_sphere(1))
        meshes.append(Mesh.of(verts, faces, material_name))
    return Mesh.concat(meshes)


def _in_batch(items: list[Any], batchable: NDArray[np.bool_], batch: Callable[[list[Any]], list[Mesh]],
              one: Callable[[Any], Mesh]) -> list[Mesh]:
    """``batch`` of the batchable items and ``one`` of each other item, in the items' order."""
    if batchable.all():
        return batch(items)
    built = iter(batch([item for item, ok in zip(items, batchable, strict=True) if ok]) if batchable.any() else [])
    return [next(built) if ok else one(item) for item, ok in zip(items, batchable, strict=True)]


def _all_finite(*columns: NDArray[np.float64]) -> NDArray[np.bool_]:
    return np.asarray(np.isfinite(np.stack(columns)).all(axis=0), bool)


def _trees(trees: list[Tree]) -> list[Mesh]:
    """:func:`_tree` for every tree (see :func:`_street_furniture`)."""
    numbers = np.array([(*t.position, t.height, t.canopy_radius, t.trunk_radius) for t in trees], np.float64)
    return _in_batch(trees, _all_finite(*numbers.T), _tree_batch, _tree)


def _tree_batch(trees: list[Tree]) -> list[Mesh]:
    x = np.array([t.position[0] for t in trees], np.float64)
    y = np.array([t.position[1] for t in trees], np.float64)
    height = np.array([t.height for t in trees], np.float64)
    canopy = np.array([t.canopy_radius for t in trees], np.float64)
    bottom = np.array([max(t.height - 2.2 * t.canopy_radius, 1.5) for t in trees], np.float64)
    trunk = _upright_cylinders(np.array([t.trunk_radius for t in trees], np.float64), x, y, bottom + 0.5, 8)
    sphere, _ = unit_sphere(1)
    centre = np.stack([x, y, (height + bottom) / 2], axis=1)[:, None, :]
    radii = np.stack([canopy, canopy, (height - bottom) / 2], axis=1)[:, None, :]
    crown = sphere[None] * radii + centre
    # An irregular crown: vertices pushed in and out, seeded by the position (deterministic).
    scale = np.stack([np.random.default_rng(zlib.crc32(np.asarray(t.position, np.float64).tobytes()))
                      .uniform(0.8, 1.12, size=(len(sphere), 1)) for t in trees])
    crown = centre + (crown - centre) * scale
    return _laid_out(np.concatenate([trunk, crown], axis=1), _template(((8, "bark"), (-1, "foliage"))))


def _poles(poles: list[Pole]) -> list[Mesh]:
    """:func:`_static_object` for every pole (see :func:`_street_furniture`)."""
    numbers = np.array([(*p.position, p.height, p.radius, p.arm, p.yaw) for p in poles], np.float64)
    return _in_batch(poles, _all_finite(*numbers.T) & (numbers[:, 2] > 0), _pole_batch, _static_object)


def _pole_batch(poles: list[Pole]) -> list[Mesh]:
    x = np.array([p.position[0] for p in poles], np.float64)
    y = np.array([p.position[1] for p in poles], np.float64)
    height = np.array([p.height for p in poles], np.float64)
    post = _upright_cylinders(np.array([p.radius for p in poles], np.float64), x, y, height, 8)
    bare = _template(((8, "metal"),))
    armed = [k for k, p in enumerate(poles) if p.arm > 0]
    meshes = _laid_out(post, bare)
    if not armed:
        return meshes
    arms, head_centre, head_yaw = [], [], []
    for k in armed:
        pole = poles[k]
        px, py = pole.position
        yaw = np.deg2rad(pole.yaw)
        tip = (px + pole.arm * np.cos(yaw), py + pole.arm * np.sin(yaw), pole.height)
        arms.append(cylinder(0.05, (px, py, pole.height - 0.1), tip, "metal", sections=6).vertices)
        head_centre.append((tip[0], tip[1], pole.height - 0.1))
        head_yaw.append(float(yaw))
    heads = _yawed_boxes(np.tile(np.array([0.6, 0.3, 0.15]), (len(armed), 1)), np.array(head_centre, np.float64),
                         head_yaw)
    lamps = _laid_out(np.concatenate([post[armed], np.stack(arms), heads], axis=1),
                      _template(((8, "metal"), (6, "metal"), (0, "metal"))))
    for k, mesh in zip(armed, lamps, strict=True):
        meshes[k] = mesh
    return meshes


def _signs(signs: list[Sign]) -> list[Mesh]:
    """:func:`_static_object` for every sign (see :func:`_street_furniture`)."""
    numbers = np.array([(*s.position, s.height, s.plate, s.yaw) for s in signs], np.float64)
    post_top = numbers[:, 2] - numbers[:, 3] / 2
    return _in_batch(signs, _all_finite(*numbers.T) & (post_top > 0), _sign_batch, _static_object)


def _sign_batch(signs: list[Sign]) -> list[Mesh]:
    x = np.array([s.position[0] for s in signs], np.float64)
    y = np.array([s.position[1] for s in signs], np.float64)
    height = np.array([s.height for s in signs], np.float64)
    plate = np.array([s.plate for s in signs], np.float64)
    post = _upright_cylinders(np.full(len(signs), 0.04), x, y, height - plate / 2, 6)
    plates = _yawed_boxes(np.stack([np.full(len(signs), 0.03), plate, plate], axis=1),
                          np.stack([x, y, height], axis=1), [float(np.deg2rad(s.yaw)) for s in signs])
    return _laid_out(np.concatenate([post, plates], axis=1), _template(((6, "metal"), (0, "sign"))))


def _buildings(buildings: list[Building]) -> list[Mesh]:
    """The meshes :func:`_building` makes, built for all the buildings at once.

    A world has ~20 buildings, and building them one by one cost ~0.4 ms each, most of it
    numpy and shapely calls on a few dozen coordinates. Here every step runs once over all
    of them: shapely triangulates each footprint (the same GEOS call per polygon), the walls'
    quads and the windows' panes are computed with the same arithmetic element by element,
    and each building's mesh is a slice of the merged arrays, laid out as :func:`_building`
    lays it out (roof triangles, wall quads, window panes; the same faces in the same order).
    Footprints that are not valid polygons (repaired by ``buffer(0)``) take the one-by-one
    path.
    """
    if not buildings:
        return []
    sizes = np.array([len(b.footprint) for b in buildings])
    try:
        shells = shapely.linearrings(np.array([p for b in buildings for p in b.footprint], np.float64),
                                     indices=np.repeat(np.arange(len(buildings)), sizes))
    except (ValueError, shapely.errors.GEOSException):  # a degenerate footprint: let Polygon() report it
        return [_building(b) for b in buildings]
    footprints = shapely.polygons(shells)
    valid = shapely.is_valid(footprints)
    chosen = np.flatnonzero(valid)
    meshes: list[Mesh | None] = [None if ok else _building(b) for b, ok in zip(buildings, valid, strict=True)]
    if not len(chosen):
        return meshes  # type: ignore[return-value]
    polygons = footprints[chosen]
    heights = np.array([buildings[k].height for k in chosen], np.float64)
    count = len(chosen)

    # Roofs: each footprint's constrained Delaunay triangles (flat() at the building's height).
    roof_parts, roof_of = shapely.get_parts(shapely.constrained_delaunay_triangles(polygons), return_index=True)
    roof_xy = shapely.get_coordinates(roof_parts).reshape(len(roof_parts), 4, 2)[:, :3, :].reshape(-1, 2)
    roof_vertices = np.concatenate([roof_xy, np.repeat(heights[roof_of], 3)[:, None]], axis=1)
    roof_count = np.bincount(roof_of, minlength=count)  # triangles per building

    # Walls: one quad per edge of the exterior ring, from 0 up to the height (extruded()).
    ring_xy, ring_of = shapely.get_coordinates(shapely.get_exterior_ring(polygons), return_index=True)
    same_ring = ring_of[:-1] == ring_of[1:]
    a, b = ring_xy[:-1][same_ring], ring_xy[1:][same_ring]
    wall_of = ring_of[:-1][same_ring]
    quad = np.empty((len(a), 4, 3))
    quad[:, 0, :2], quad[:, 1, :2], quad[:, 2, :2], quad[:, 3, :2] = a, b, b, a
    quad[:, :2, 2], quad[:, 2:, 2] = 0.0, heights[wall_of][:, None]
    wall_count = np.bincount(wall_of, minlength=count)

    window_vertices, window_of = _window_panes(polygons, heights,
                                               np.array([buildings[k].windows for k in chosen], bool))
    window_count = np.bincount(window_of, minlength=count)

    # Each building's vertices: roof (3 per triangle), walls (4 per quad), windows (4 per pane);
    # its faces: roof triangles, then each quad's first triangle and each quad's second one,
    # then the same for the panes; indices local to the building.
    roof_start, wall_start, window_start = (np.cumsum(c) - c for c in (roof_count, wall_count, window_count))
    wall_base = 3 * roof_count
    window_base = wall_base + 4 * wall_count
    vertex_count = window_base + 4 * window_count
    roof_faces = (np.arange(len(roof_of), dtype=np.int64) - roof_start[roof_of])[:, None] * 3 + np.arange(3)
    wall_rank = np.arange(len(wall_of)) - wall_start[wall_of]
    wall_first = wall_base[wall_of] + 4 * wall_rank
    window_rank = np.arange(len(window_of)) - window_start[window_of]
    window_first = window_base[window_of] + 4 * window_rank
    first, second = np.array([0, 1, 2]), np.array([0, 2, 3])
    # Sort keys: building, then part (roof 0, walls' first triangles 1, second 2, windows' 3 and 4).
    face_owner = np.concatenate([roof_of, wall_of, wall_of, window_of, window_of])
    face_part = np.repeat(np.arange(5), [len(roof_of), len(wall_of), len(wall_of), len(window_of), len(window_of)])
    faces = np.concatenate([roof_faces, wall_first[:, None] + first, wall_first[:, None] + second,
                            window_first[:, None] + first, window_first[:, None] + second]).astype(np.int32)
    face_order = np.lexsort((face_part, face_owner))  # stable within a part: the original order
    vertices = np.concatenate([roof_vertices, quad.reshape(-1, 3), window_vertices])
    vertex_owner = np.concatenate([np.repeat(roof_of, 3), np.repeat(wall_of, 4), np.repeat(window_of, 4)])
    vertices = vertices[np.argsort(vertex_owner, kind="stable")]
    faces, face_part = faces[face_order], face_part[face_order]
    is_window = face_part >= 3
    face_count = roof_count + 2 * wall_count + 2 * window_count
    vertex_stop, face_stop = np.cumsum(vertex_count), np.cumsum(face_count)
    for j, k in enumerate(chosen.tolist()):
        v0, f0 = int(vertex_stop[j] - vertex_count[j]), int(face_stop[j] - face_count[j])
        v1, f1 = int(vertex_stop[j]), int(face_stop[j])
        meshes[k] = _with_materials(vertices[v0:v1], faces[f0:f1], is_window[f0:f1], buildings[k].material)
    return meshes  # type: ignore[return-value]


def _with_materials(vertices: NDArray[np.float64], faces: NDArray[np.int32], is_window: NDArray[np.bool_],
                    body: str) -> Mesh:
    """A building's mesh: faces of ``body``'s material, and of ``window`` where ``is_window``
    (what :meth:`Mesh.of` gives each part)."""
    parts = [material(body), material("window")]
    pick = is_window.astype(np.intp)

    def column(values: list[float | int], dtype: type) -> NDArray[Any]:
        return np.array(values, dtype)[pick]

    return Mesh(vertices, faces, column([m.reflectivity for m in parts], np.float32),
                column([SEMANTIC_ID[m.semantic] for m in parts], np.uint8),
                column([m.returns for m in parts], np.float32), column([m.gloss for m in parts], np.float32),
                column([MATERIAL_ID[body], MATERIAL_ID["window"]], np.uint8))


def _window_panes(footprints: NDArray[np.object_], heights: NDArray[np.float64], windows: NDArray[np.bool_],
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The panes :func:`_windows` puts on each footprint with ``windows`` (4 vertices each, in
    its order: facade edges, then slots along an edge, then floors), and each pane's footprint."""
    exteriors = shapely.get_exterior_ring(footprints)
    ring_xy, ring_of = shapely.get_coordinates(exteriors, return_index=True)
    # Counter-clockwise rings: reverse each clockwise one in place (its rows, back to front).
    clockwise = ~shapely.is_ccw(exteriors)
    sizes = np.bincount(ring_of, minlength=len(footprints))
    start = np.cumsum(sizes) - sizes
    rank = np.arange(len(ring_of)) - start[ring_of]
    flip = clockwise[ring_of]
    ring_xy = ring_xy[np.where(flip, start[ring_of] + sizes[ring_of] - 1 - rank, np.arange(len(ring_of)))]
    same_ring = ring_of[:-1] == ring_of[1:]
    a, edge_of = ring_xy[:-1][same_ring], ring_of[:-1][same_ring]
    edge = ring_xy[1:][same_ring] - a
    length = np.linalg.norm(edge, axis=1)
    floor_count = np.array([len(np.arange(1.0, h - 1.6, 3.0)) for h in heights.tolist()], np.int64)
    long_enough = (length >= 3.0) & windows[edge_of] & (floor_count[edge_of] > 0)
    a, edge, length, edge_of = a[long_enough], edge[long_enough], length[long_enough], edge_of[long_enough]
    if not len(a):
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    unit = edge / length[:, None]
    outward = np.stack([unit[:, 1], -unit[:, 0]], axis=1)  # right of a counter-clockwise ring
    # Slots 1.5, 4.5, … (exact: 1.5 + 3 i) short of each edge's end by a metre; floors 1, 4, …
    slots = np.arange(1.5, float(length.max()) - 1.0, 3.0)
    slot_count = np.searchsorted(slots, length - 1.0, side="left")  # slots < length − 1
    per_edge = slot_count * floor_count[edge_of]
    edge_index = np.repeat(np.arange(len(a)), per_edge)
    rank = np.arange(len(edge_index)) - np.repeat(np.cumsum(per_edge) - per_edge, per_edge)
    floors_here = floor_count[edge_of][edge_index]
    slot_index, floor_index = rank // floors_here, rank % floors_here
    u = slots[slot_index]
    z = 1.0 + 3.0 * floor_index  # np.arange(1.0, …, 3.0)'s values, exactly
    return _pane_quads(a, unit, outward, edge_index, u, z).reshape(-1, 3), edge_of[edge_index]


def _pane_quads(a: NDArray[np.float64], unit: NDArray[np.float64], outward: NDArray[np.float64],
                edge_index: NDArray[np.intp], u: NDArray[np.float64], z: NDArray[np.float64]) -> NDArray[np.float64]:
    """Window panes 1.4 m wide and 1.5 m tall, 3 cm proud of facade edges starting at ``a`` (along
    ``unit``, facing ``outward``): one per (edge, slot centre ``u`` along it, sill height ``z``),
    corners counter-clockwise seen from outside, (panes, 4, 3)."""
    base = a[edge_index] + outward[edge_index] * 0.03
    left = base + (u - 0.7)[:, None] * unit[edge_index]
    right = base + (u + 0.7)[:, None] * unit[edge_index]
    quad = np.empty((len(u), 4, 3))
    quad[:, 0, :2], quad[:, 1, :2], quad[:, 2, :2], quad[:, 3, :2] = left, right, right, left
    quad[:, 0, 2] = quad[:, 1, 2] = z
    quad[:, 2, 2] = quad[:, 3, 2] = z + 1.5
    return quad


def _building(b: Building) -> Mesh:
    footprint = Polygon(b.footprint)
    if not footprint.is_valid:
        footprint = footprint.buffer(0)
    body = extruded(footprint, 0.0, b.height, b.material)
    if not b.windows:
        return body
    return Mesh.concat([body, _windows(footprint, b.height)])


def _windows(footprint: Polygon, height: float) -> Mesh:
    """Glass panes 3 cm proud of every facade: one per 3 m of wall per 3 m storey, above the ground floor sill."""
    ring = np.asarray(footprint.exterior.coords)
    if not footprint.exterior.is_ccw:
        ring = ring[::-1]
    floors = np.arange(1.0, height - 1.6, 3.0)
    a, b = ring[:-1], ring[1:]
    edge = b - a
    length = np.linalg.norm(edge, axis=1)
    long_enough = length >= 3.0
    if len(floors) == 0 or not long_enough.any():
        return Mesh.empty()
    a, edge, length = a[long_enough], edge[long_enough], length[long_enough]
    unit = edge / length[:, None]
    outward = np.stack([unit[:, 1], -unit[:, 0]], axis=1)  # right of a counter-clockwise ring
    slots = np.arange(1.5, float(length.max()) - 1.0, 3.0)
    edge_index, slot_index, floor_index = np.nonzero(
        (slots[None, :] < (length[:, None] - 1.0))[:, :, None] & np.ones(len(floors), bool)[None, None, :])
    u = slots[slot_index]
    z = floors[floor_index]
    quad = _pane_quads(a, unit, outward, edge_index, u, z)
    base_index = np.arange(len(u), dtype=np.int32)[:, None] * 4
    faces = np.concatenate([base_index + np.array([0, 1, 2]), base_index + np.array([0, 2, 3])]).astype(np.int32)
    return Mesh.of(quad.reshape(-1, 3), faces, "window")


def footprint_of(obj: object) -> Polygon:
    """The ground footprint of a static object or actor spec (used for placement and the docs' layout plot)."""
    if isinstance(obj, Building):
        return Polygon(obj.footprint)
    if isinstance(obj, Wall):
        return LineString([obj.start, obj.end]).buffer(obj.thickness / 2, cap_style="flat")
    if (disc := _footprint_disc(obj)) is not None:  # trees, bushes, poles and signs
        return Point(disc[0]).buffer(disc[1])
    if isinstance(obj, Crosswalk):
        return _crosswalk(obj).envelope
    if isinstance(obj, Actor):
        length, w, _ = obj.size or mean_size(obj.cls)
        yaw = np.deg2rad(obj.yaw)
        c, s = np.cos(yaw), np.sin(yaw)
        corners = np.array([[length, w], [length, -w], [-length, -w], [-length, w]]) / 2
        return Polygon(corners @ np.array([[c, s], [-s, c]]) + np.asarray(obj.position))
    raise TypeError(f"unknown scene object {obj!r}")


__all__ = ["PlacedActor", "ProfiledTrajectory", "Trajectory", "World", "compile_world", "ego_labels", "footprint_of",
           "material", "trajectory_of"]
