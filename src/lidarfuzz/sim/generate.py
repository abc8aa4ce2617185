"""Procedural scenes: urban streets and suburban roads sampled from a seed.

The ego vehicle starts at the origin in the rightmost lane of a main road along +x
(right-hand traffic, as in KITTI's Karlsruhe). Around it the generator lays out

* **urban**: a two- or four-lane street, often with parking strips, sidewalks and a
  junction with a crossing street and zebra crossings; continuous rows of buildings
  with windows; street trees, lamp posts and signs; parked and moving cars, vans and
  trucks, pedestrians on sidewalks and crossings, cyclists at the kerb;
* **suburban**: a two-lane road with verges, detached houses set back behind fences
  and hedges, more trees, fewer road users, sometimes a T junction.

Vehicles in one lane move at that lane's speed (the ego lane's speed is the ego's),
so a sequence does not drive cars through each other. Every object is placed on a
free footprint; sizes follow :data:`~lidarfuzz.sim.actors.SIZE_STATS`. The ground is
not flat: its grade, vertical curve, camber, cross-fall and undulation are drawn from
the ranges of a :class:`~lidarfuzz.sim.realism.RealismConfig`, with dropped kerbs at
zebra crossings and driveways. The result is a :class:`~lidarfuzz.sim.spec.SceneSpec`,
so a generated scene can be saved, edited and rendered again. Deterministic per seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry import box as shapely_box

from lidarfuzz.sim.actors import sample_size
from lidarfuzz.sim.drive import DrivePlan, clear_of, drive_route, plan_actors, plan_drive
from lidarfuzz.sim.realism import RealismConfig
from lidarfuzz.sim.sensor import DEFAULT_SENSOR, LidarSensor
from lidarfuzz.sim.spec import Actor, Crosswalk, Road, SceneSpec
from lidarfuzz.sim.world import footprint_of

SceneKind = Literal["urban", "suburban"]
SCENE_KINDS: tuple[str, ...] = ("urban", "suburban")
HALF_SPAN = 90.0  # objects are placed within this distance of the route (±x) and of the road (±y)


@dataclass
class _Layout:
    rng: np.random.Generator
    occupied: list[Polygon] = field(default_factory=list)
    drivable: Polygon | None = None  # static objects keep off the carriageway
    objects: list[dict[str, Any]] = field(default_factory=list)
    actors: list[dict[str, Any]] = field(default_factory=list)
    ramps: list[dict[str, Any]] = field(default_factory=list)  # dropped kerbs
    sidewalk_width: float = 0.0

    def free(self, footprint: Polygon, margin: float = 0.3) -> bool:
        if not self.occupied:
            return True
        return not bool(np.any(shapely.dwithin(np.asarray(self.occupied, dtype=object), footprint, margin)))

    def take(self, footprint: Polygon) -> None:
        self.occupied.append(footprint)

    def add_object(self, obj: dict[str, Any], footprint: Polygon, margin: float = 0.3) -> bool:
        if self.drivable is not None and footprint.intersects(self.drivable):
            return False
        if not self.free(footprint, margin):
            return False
        self.take(footprint)
        self.objects.append(obj)
        return True

    def add_actor(self, cls: str, x: float, y: float, yaw: float, *, speed: float = 0.0,
                  parked: bool = False, margin: float = 0.4, off_road: bool = False, gap: float = 0.0) -> bool:
        """Place a road user if its footprint is free by ``margin`` all round and by ``gap`` more
        ahead and behind (the headway between vehicles in a lane)."""
        size = sample_size(self.rng, cls)
        footprint = _oriented(x, y, size[0], size[1], yaw)
        if off_road and self.drivable is not None and footprint.intersects(self.drivable):
            return False
        clearance = _oriented(x, y, size[0] + 2 * gap, size[1], yaw) if gap else footprint
        if not self.free(clearance, margin):
            return False
        self.take(footprint)
        actor: dict[str, Any] = {"class": cls, "position": [_r(x), _r(y)], "yaw": _r(np.rad2deg(yaw)),
                                 "size": list(size)}
        if speed > 0:
            actor["speed"] = _r(speed)
        if parked:
            actor["parked"] = True
        self.actors.append(actor)
        return True


def parse_object(obj: dict[str, Any]) -> Crosswalk:
    return Crosswalk.model_validate(obj)


def _r(value: float) -> float:
    return round(float(value), 2)


def _oriented(x: float, y: float, length: float, width: float, yaw: float) -> Polygon:
    c, s = np.cos(yaw), np.sin(yaw)
    corners = np.array([[length, width], [length, -width], [-length, -width], [-length, width]]) / 2
    return Polygon(corners @ np.array([[c, s], [-s, c]]) + [x, y])


def generate_scene(
    seed: int,
    *,
    kind: SceneKind | None = None,
    sensor: str | LidarSensor = DEFAULT_SENSOR,
    ego_speed: float | None = None,
    duration: float = 0.0,
    name: str | None = None,
    realism: RealismConfig | None = None,
    drive: bool = False,
) -> SceneSpec:
    """Sample a scene.

    Args:
        seed: Fixes everything (layout, actors, sensor noise).
        kind: ``"urban"`` or ``"suburban"``; drawn from the seed (70 % urban) when ``None``.
        sensor: Preset name or sensor model.
        ego_speed: Metres per second; drawn from the seed when ``None``.
        duration: Seconds the scene must cover (a sequence's length): the world is
            extended along the route so the ego never drives off it.
        name: Scene name (default ``"<kind>-<seed>"``).
        realism: The ranges the terrain is drawn from (default :class:`RealismConfig`'s);
            ``RealismConfig.off()`` gives flat ground.
        drive: A drive log's scene (:mod:`lidarfuzz.sim.drive`): a crossroads ahead, the ego
            vehicle stopping before it, turning left or right and driving on along the
            crossing street for ``duration`` seconds, with road users timed against it. Its
            speed (when not given) is drawn from 7–12 m/s; the name is ``"<kind>-drive-<seed>"``.

    Example:
        >>> spec = generate_scene(3)
        >>> spec == generate_scene(3)
        True
    """
    # Separate streams: fixing the kind or the ego's speed leaves the rest of the scene as the seed made it.
    kind_rng, speed_rng, rng, terrain_rng = (np.random.default_rng(np.random.SeedSequence([seed, 0x5CE7E, stream]))
                                             for stream in range(4))
    realism = realism if realism is not None else RealismConfig()
    drawn_kind: SceneKind = "urban" if kind_rng.random() < 0.7 else "suburban"
    drawn_speed = 0.0 if speed_rng.random() < 0.15 else float(speed_rng.uniform(4.0, 14.0))
    kind = kind or drawn_kind
    if kind not in SCENE_KINDS:
        raise ValueError(f"unknown scene kind {kind!r}; choose one of {', '.join(SCENE_KINDS)}")
    urban = kind == "urban"
    layout = _Layout(rng)

    lanes = int(rng.choice([2, 4], p=[0.55, 0.45])) if urban else 2
    lane_width = _r(rng.uniform(3.1, 3.6))
    parking = _r(2.2) if urban and rng.random() < 0.6 else 0.0
    sidewalk = _r(rng.uniform(2.5, 4.5) if urban else rng.uniform(1.5, 2.5))
    half = lanes * lane_width / 2
    ego_y = -half + lane_width / 2
    plan: DrivePlan | None = None
    drive_rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5CE7E, 4]))  # drives only
    if drive:
        if ego_speed is None:
            ego_speed = float(drive_rng.uniform(7.0, 12.0))
        if ego_speed <= 0:
            raise ValueError("ego_speed: a drive needs a speed above 0")
        plan = plan_drive(drive_rng, speed=ego_speed, duration=duration, lanes=lanes, lane_width=lane_width,
                          urban=urban)
        ego_y = plan.ego_y
    if ego_speed is None:
        ego_speed = drawn_speed
    travel = ego_speed * max(duration, 0.0) if plan is None else plan.junction_x
    x_lo, x_hi = -HALF_SPAN, HALF_SPAN + travel
    main = Road(centerline=[(x_lo - 40, 0.0), (x_hi + 40, 0.0)], lanes=lanes, lane_width=lane_width,
                parking_width=parking, sidewalk_width=sidewalk)
    roads = [main]

    # The ego vehicle's own footprint and a little space ahead stay clear.
    layout.take(shapely_box(-4.0, ego_y - 1.5, 8.0, ego_y + 1.5))

    junction_x: float | None = None
    if plan is not None:  # a crossroads, the crossing street long enough on the side it turns to
        junction_x = plan.junction_x
        arms = {plan.side: plan.arm, -plan.side: HALF_SPAN + 40}
        roads.append(Road(centerline=[(junction_x, -arms[-1.0]), (junction_x, arms[1.0])], lanes=2,
                          lane_width=lane_width, sidewalk_width=sidewalk))
        if urban:
            offset = roads[1].half_width + sidewalk + 1.5
            _crosswalk(layout, main, junction_x - offset)  # the one it stops at
            if rng.random() < 0.7:
                _crosswalk(layout, main, junction_x + offset)
    elif rng.random() < (0.65 if urban else 0.4):
        junction_x = float(rng.uniform(18.0, 70.0) if rng.random() < 0.75 else rng.uniform(-60.0, -20.0))
        cross_lanes = 2
        cross = Road(centerline=[(junction_x, -HALF_SPAN - 40), (junction_x, HALF_SPAN + 40)] if urban or
                     rng.random() < 0.5 else [(junction_x, 0.0), (junction_x, HALF_SPAN + 40)],
                     lanes=cross_lanes, lane_width=lane_width, sidewalk_width=sidewalk)
        roads.append(cross)
        if urban:
            offset = cross.half_width + sidewalk + 1.5
            for x in (junction_x - offset, junction_x + offset):
                if rng.random() < 0.7:
                    _crosswalk(layout, main, x)
    layout.drivable = shapely.union_all([LineString(r.centerline).buffer(r.half_width, cap_style="flat")
                                         for r in roads])

    kerb_line = main.half_width + sidewalk
    layout.sidewalk_width = sidewalk
    ego: dict[str, Any] = {"position": [0.0, _r(ego_y)], "yaw": 0.0, "speed": _r(ego_speed)}
    timed: list[dict[str, Any]] = []
    reach: dict[float, float] | None = None
    if plan is not None:
        route, radius = drive_route(plan, main, roads[1])
        ego.update(route=route, corner_radius=radius)
        near = junction_x - (roads[1].half_width + sidewalk + 1.5) if urban and junction_x is not None else None
        ego, timed = plan_actors(plan, ego, main, roads[1], near, drive_rng, duration)
        for entry in timed:
            layout.take(footprint_of(Actor.model_validate(entry)))
        reach = {plan.side: plan.arm - 10.0, -plan.side: HALF_SPAN}
    _buildings(layout, kerb_line, x_lo, x_hi, urban, junction_x, roads, reach)
    _street_furniture(layout, main, x_lo, x_hi, urban, junction_x)
    _road_users(layout, main, roads, ego_y, ego_speed, x_lo, x_hi, urban, junction_x,
                skip_lane=ego_y if plan is not None else None)
    if plan is not None:  # no generated road user meets the ego vehicle or the timed ones on their way
        layout.actors = timed + clear_of(layout.actors, [a for a in timed if a["class"] != "Pedestrian"], ego,
                                         duration + 2.0)
    terrain = realism.sample_terrain(terrain_rng)
    if terrain and realism.ramps:
        terrain["ramps"] = layout.ramps

    return SceneSpec.model_validate({
        "name": name or (f"{kind}-drive-{seed}" if drive else f"{kind}-{seed}"),
        "seed": seed,
        "ground": "paving" if urban and rng.random() < 0.3 else "grass",
        "extent": 125.0,
        "terrain": terrain,
        "roads": [r.model_dump() for r in roads],
        "objects": layout.objects,
        "actors": layout.actors,
        "ego": ego,
        "sensor": sensor if isinstance(sensor, str) else sensor.model_dump(),
    })


def _crosswalk(layout: _Layout, main: Road, x: float) -> None:
    """A zebra crossing over the main road at ``x``, with kerb ramps at both ends."""
    layout.objects.append({"kind": "crosswalk", "position": [_r(x), 0.0], "yaw": 0.0,
                           "length": _r(2 * main.half_width), "width": 3.0})
    for side in (-1.0, 1.0):
        layout.ramps.append({"position": [_r(x), _r(side * main.half_width)],
                             "yaw": 90.0 * side, "width": 3.0, "depth": 1.0})


def _buildings(layout: _Layout, kerb: float, x_lo: float, x_hi: float, urban: bool, junction_x: float | None,
               roads: list[Road], cross_reach: dict[float, float] | None = None) -> None:
    """Rows of buildings along the main road, and along the crossing street out to ``cross_reach``
    metres on each side (``HALF_SPAN`` by default)."""
    rng = layout.rng
    for side in (-1.0, 1.0):
        x = x_lo + rng.uniform(0, 10)
        while x < x_hi:
            frontage = rng.uniform(10, 32) if urban else rng.uniform(9, 15)
            gap = rng.uniform(0, 4) if urban else rng.uniform(6, 16)
            setback = rng.uniform(0.0, 2.5) if urban else rng.uniform(6, 14)
            depth = rng.uniform(10, 20) if urban else rng.uniform(8, 12)
            height = rng.uniform(7, 24) if urban else rng.uniform(5, 9)
            near = kerb + setback
            y0, y1 = sorted((side * near, side * (near + depth)))
            footprint = shapely_box(x, y0, x + frontage, y1)
            material = str(rng.choice(["plaster", "brick", "plaster", "concrete"] if urban else ["plaster", "brick"]))
            layout.add_object({"kind": "building", "footprint": [[_r(a), _r(b)] for a, b in
                                                                 list(footprint.exterior.coords)[:-1]],
                               "height": _r(height), "material": material}, footprint, margin=0.5)
            if not urban:
                _front_garden(layout, x, frontage, side, kerb, near)
            x += frontage + gap
        if junction_x is not None and urban:
            # Buildings along the crossing street, both sides of it.
            cross = roads[1]
            ckerb = cross.half_width + cross.sidewalk_width
            reach = HALF_SPAN if cross_reach is None else cross_reach[side]
            for cside in (-1.0, 1.0):
                y = side * (kerb + 2.0)
                while abs(y) < reach:
                    frontage = rng.uniform(10, 25)
                    depth = rng.uniform(10, 18)
                    xa = junction_x + cside * (ckerb + rng.uniform(0, 2))
                    xb = xa + cside * depth
                    ya, yb = sorted((y, y + side * frontage))
                    footprint = shapely_box(min(xa, xb), ya, max(xa, xb), yb)
                    layout.add_object({"kind": "building", "footprint": [[_r(a), _r(b)] for a, b in
                                                                         list(footprint.exterior.coords)[:-1]],
                                       "height": _r(rng.uniform(7, 22)), "material": "plaster"}, footprint, 0.5)
                    y += side * (frontage + rng.uniform(0, 4))


def _front_garden(layout: _Layout, x: float, frontage: float, side: float, kerb: float, near: float) -> None:
    rng = layout.rng
    fence_y = side * (kerb + 0.8)
    if rng.random() < 0.6:
        kind = "fence" if rng.random() < 0.5 else "hedge"
        if kind == "fence":
            layout.add_object({"kind": "wall", "start": [_r(x + 0.5), _r(fence_y)], "end": [_r(x + frontage - 3.5),
                               _r(fence_y)], "height": _r(rng.uniform(0.9, 1.6)), "thickness": 0.08,
                               "material": "fence"},
                              LineString([(x + 0.5, fence_y), (x + frontage - 3.5, fence_y)]).buffer(0.1), 0.1)
        else:
            for hx in np.arange(x + 1.0, x + frontage - 4.0, 1.4):
                layout.add_object({"kind": "bush", "position": [_r(hx), _r(fence_y)], "radius": 0.8,
                                   "height": _r(rng.uniform(1.0, 1.8))}, Point(hx, fence_y).buffer(0.6), 0.0)
    if rng.random() < 0.5:
        tx, ty = x + rng.uniform(2, frontage - 2), side * (kerb + rng.uniform(2.5, max(near - 1.5, 3.0)))
        layout.add_object({"kind": "tree", "position": [_r(tx), _r(ty)], "height": _r(rng.uniform(5, 11)),
                           "canopy_radius": _r(rng.uniform(1.5, 3.0))}, Point(tx, ty).buffer(0.5))
    if rng.random() < 0.45:  # a car in the driveway
        dx = x + frontage - 2.0
        dy = side * (kerb + rng.uniform(3.0, max(near - 2.5, 3.5)))
        cls = "Car" if rng.random() < 0.8 else "Van"
        layout.add_actor(cls, dx, dy, np.pi / 2 * side + (np.pi if rng.random() < 0.5 else 0.0), parked=True)
        edge = kerb - layout.sidewalk_width  # the driveway crosses the sidewalk: a dropped kerb
        layout.ramps.append({"position": [_r(dx), _r(side * edge)], "yaw": 90.0 * side, "width": 3.0,
                             "depth": 1.0})


def _street_furniture(layout: _Layout, main: Road, x_lo: float, x_hi: float, urban: bool,
                      junction_x: float | None) -> None:
    rng = layout.rng
    for side in (-1.0, 1.0):
        y_kerb = side * (main.half_width + 0.6)
        tree_gap = rng.uniform(7, 14) if urban else rng.uniform(10, 25)
        if rng.random() < (0.7 if urban else 0.5):
            for x in np.arange(x_lo + rng.uniform(0, tree_gap), x_hi, tree_gap):
                tx = x + rng.uniform(-1, 1)
                layout.add_object({"kind": "tree", "position": [_r(tx), _r(y_kerb + side * 0.4)],
                                   "height": _r(rng.uniform(5, 10)), "canopy_radius": _r(rng.uniform(1.5, 2.8)),
                                   "trunk_radius": _r(rng.uniform(0.12, 0.25))}, Point(tx, y_kerb).buffer(0.4))
        for x in np.arange(x_lo + rng.uniform(0, 25), x_hi, rng.uniform(22, 35)):
            yaw = -90.0 * side
            layout.add_object({"kind": "pole", "position": [_r(x), _r(y_kerb)], "height": _r(rng.uniform(6, 9)),
                               "yaw": yaw, "arm": _r(rng.uniform(0.8, 2.0))}, Point(x, y_kerb).buffer(0.3), 0.1)
        for _ in range(int(rng.integers(1, 4))):
            x = rng.uniform(x_lo, x_hi)
            layout.add_object({"kind": "sign", "position": [_r(x), _r(y_kerb)], "yaw": 180.0 if side < 0 else 0.0,
                               "height": _r(rng.uniform(2.0, 2.8)), "plate": _r(rng.uniform(0.5, 0.9))},
                              Point(x, y_kerb).buffer(0.3), 0.1)
    if junction_x is not None:
        for sx, sy in ((-1.0, -1.0), (1.0, 1.0)):
            x = junction_x + sx * (main.half_width + 1.0)
            y = sy * (main.half_width + 0.6)
            layout.add_object({"kind": "sign", "position": [_r(x), _r(y)], "yaw": 180.0 if sx < 0 else 0.0},
                              Point(x, y).buffer(0.3), 0.1)


def _road_users(layout: _Layout, main: Road, roads: list[Road], ego_y: float, ego_speed: float, x_lo: float,
                x_hi: float, urban: bool, junction_x: float | None, skip_lane: float | None = None) -> None:
    """Traffic, parked vehicles, pedestrians and cyclists; no moving traffic in the lane at
    ``skip_lane`` (a drive's: its own stops and turn would meet it)."""
    rng = layout.rng
    half = main.carriageway_half_width
    lane_centres = [-half + (k + 0.5) * main.lane_width for k in range(main.lanes)]
    span_lo, span_hi = -45.0, x_hi - 15.0  # mostly ahead, where the camera looks
    # Moving traffic: vehicles in one lane share the lane's speed.
    for y in lane_centres:
        if skip_lane is not None and abs(y - skip_lane) < 1e-6:
            continue
        forward = y < 0
        speed = ego_speed if abs(y - ego_y) < 1e-6 else float(rng.uniform(5.0, 14.0))
        count = int(rng.poisson(3.0 if urban else 1.5))
        for _ in range(count):
            cls = str(rng.choice(["Car", "Car", "Car", "Car", "Van", "Truck"]))
            x = rng.uniform(span_lo, span_hi)
            layout.add_actor(cls, x, y + rng.normal(0, 0.15), 0.0 if forward else np.pi, speed=speed, margin=0.3,
                             gap=2.0)
    # Parked vehicles in the parking strips (a road without strips has none: they would stand in
    # the outer lane), never in a junction's mouth or on a zebra crossing.
    if main.parking_width:
        no_parking = [footprint_of(parse_object(o)).buffer(1.0) for o in layout.objects if o["kind"] == "crosswalk"]
        if junction_x is not None and len(roads) > 1:
            mouth = roads[1].half_width + roads[1].sidewalk_width + 4.0
            no_parking.append(shapely_box(junction_x - mouth, -HALF_SPAN, junction_x + mouth, HALF_SPAN))
        y_strip = half + main.parking_width / 2
        for side in (-1.0, 1.0):
            x = span_lo + rng.uniform(0, 6)
            while x < span_hi:
                if rng.random() < (0.65 if urban else 0.3):
                    cls = str(rng.choice(["Car", "Car", "Car", "Van"]))
                    y = side * y_strip + rng.normal(0, 0.1)
                    if not any(zone.contains(Point(x, y)) or zone.distance(Point(x, y)) < 2.5 for zone in no_parking):
                        layout.add_actor(cls, x, y, (0.0 if side < 0 else np.pi) + rng.normal(0, 0.03),
                                         parked=True, margin=0.3)
                x += rng.uniform(5.0, 8.0)
    # Traffic on the crossing street: queueing at the junction (the main road has green), or
    # driving away from it on the far side — nobody crosses the main road's traffic.
    if junction_x is not None and len(roads) > 1:
        half_lane = roads[1].lane_width / 2
        reach = HALF_SPAN if len(roads[1].centerline) and roads[1].centerline[0][1] < 0 else 0.0
        for y_dir, lane_x in ((1.0, junction_x + half_lane), (-1.0, junction_x - half_lane)):
            for _ in range(int(rng.poisson(1.2))):
                y = y_dir * -rng.uniform(main.half_width + 4, 50)
                if y < -reach:
                    continue  # a T junction has no southern arm
                layout.add_actor(str(rng.choice(["Car", "Car", "Van"])), lane_x, y, y_dir * np.pi / 2, margin=0.3,
                                 gap=1.5)
            lane_speed = float(rng.uniform(4, 10))  # one speed per lane: nobody catches up
            for _ in range(int(rng.poisson(0.6))):
                y = y_dir * rng.uniform(main.half_width + 6, 50)
                if y < -reach:
                    continue
                layout.add_actor(str(rng.choice(["Car", "Car", "Van"])), lane_x, y, y_dir * np.pi / 2,
                                 speed=lane_speed, margin=0.3, gap=1.5)
    # Pedestrians: on sidewalks (walking along or standing), and on the crossings.
    walk_y = main.half_width + main.sidewalk_width / 2
    for _ in range(int(rng.poisson(6.0 if urban else 2.0))):
        side = rng.choice([-1.0, 1.0])
        x = rng.uniform(span_lo, span_hi)
        y = side * (walk_y + rng.uniform(-0.4, 0.4) * main.sidewalk_width)
        if rng.random() < 0.3:
            layout.add_actor("Pedestrian", x, y, rng.uniform(-np.pi, np.pi), off_road=True)
        else:
            heading = 0.0 if rng.random() < 0.5 else np.pi
            layout.add_actor("Pedestrian", x, y, heading, speed=float(rng.uniform(0.8, 1.7)), off_road=True)
    for obj in [o for o in layout.objects if o["kind"] == "crosswalk"]:
        for _ in range(int(rng.poisson(1.5))):
            x = obj["position"][0] + rng.uniform(-1.2, 1.2)
            y = rng.uniform(-main.half_width, main.half_width)
            layout.add_actor("Pedestrian", x, y, np.pi / 2 if rng.random() < 0.5 else -np.pi / 2,
                             speed=float(rng.uniform(0.9, 1.5)))
    # Cyclists: at the right edge of the outer lanes (one speed per direction: nobody catches up),
    # or standing at the kerb.
    cycling_speed = {True: float(rng.uniform(3.0, 7.0)), False: float(rng.uniform(3.0, 7.0))}
    for _ in range(int(rng.poisson(1.5 if urban else 0.8))):
        forward = bool(rng.random() < 0.6)
        y = -(half - 0.35) if forward else half - 0.35
        x = rng.uniform(span_lo, span_hi)
        speed = 0.0 if rng.random() < 0.2 else cycling_speed[forward]
        layout.add_actor("Cyclist", x, y, 0.0 if forward else np.pi, speed=speed, margin=0.6)
