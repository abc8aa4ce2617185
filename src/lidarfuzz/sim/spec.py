"""The scene description: what a user writes by hand (YAML or JSON) and what the generator samples.

Coordinates are metres in a world frame whose origin is the ego vehicle's start
(x forward, y left, z up, z = 0 on the road surface); angles are degrees,
counter-clockwise from +x. A minimal scene — a pedestrian 30 m ahead, half hidden
behind a parked van::

    roads:
      - centerline: [[-100, 0], [200, 0]]
        lanes: 2
    actors:
      - {class: Van, position: [26, -4.6], parked: true}
      - {class: Pedestrian, position: [30, -5.6], yaw: 90, speed: 1.2}
    ego: {speed: 8}

Roads (their carriageway and parking strips) form the drivable area, which is saved
with every frame as the HD-map ROI. Everything not listed is left empty: a scene with
no roads is open ground.
"""

from __future__ import annotations

import itertools
import json
from collections import deque
from os import PathLike
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    ValidationError,
    field_validator,
    model_serializer,
    model_validator,
)

from lidarfuzz.errors import DataFormatError, validation_error
from lidarfuzz.io.guards import reading
from lidarfuzz.io.textfiles import load_structured
from lidarfuzz.sim.actors import ACTOR_CLASSES
from lidarfuzz.sim.materials import MATERIALS
from lidarfuzz.sim.sensor import DEFAULT_SENSOR, LidarSensor

Point2 = tuple[float, float]


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", populate_by_name=True, allow_inf_nan=False)


def _known_material(value: str | None) -> str | None:
    if value is not None and value not in MATERIALS:
        raise ValueError(f"unknown material {value!r}; known: {', '.join(MATERIALS)}")
    return value


class Road(_Model):
    """A road along a polyline: its carriageway, lane markings, optional parking strips, kerbs and sidewalks."""

    centerline: list[Point2] = Field(min_length=2)
    lanes: int = Field(default=2, ge=1, le=8)
    lane_width: float = Field(default=3.5, gt=1.5, le=6.0)
    parking_width: float = Field(default=0.0, ge=0.0, le=4.0, description="parking strip on each side")
    sidewalk_width: float = Field(default=3.0, ge=0.0, le=15.0)
    kerb_height: float = Field(default=0.15, ge=0.0, le=0.4)
    one_way: bool = False

    @property
    def carriageway_half_width(self) -> float:
        return self.lanes * self.lane_width / 2

    @property
    def half_width(self) -> float:
        """Half the drivable width: lanes plus parking strips."""
        return self.carriageway_half_width + self.parking_width


class Crosswalk(_Model):
    """A zebra crossing centred at ``position`` on a road heading ``yaw``: bars parallel to the
    road, ``width`` long, repeated every metre across it over ``length``."""

    kind: Literal["crosswalk"] = "crosswalk"
    position: Point2
    yaw: float = 0.0
    length: float = Field(default=8.0, gt=0, description="extent across the road")
    width: float = Field(default=4.0, gt=0, description="extent along the road")


class Building(_Model):
    kind: Literal["building"] = "building"
    footprint: list[Point2] = Field(min_length=3, description="corners in order around the building")
    height: float = Field(default=10.0, gt=0, le=300)
    material: str = "plaster"
    windows: bool = True

    _material = field_validator("material")(_known_material)

    @field_validator("footprint")
    @classmethod
    def _simple_polygon(cls, value: list[Point2]) -> list[Point2]:
        """A footprint that crosses itself (corners out of order) has no one inside: repairing it
        keeps part of it (a bow-tie's one lobe) or splits it, and the building would stand where
        the description does not put it. Refused, with where it goes wrong."""
        import shapely
        from shapely.geometry import Polygon

        polygon = Polygon(value)
        if not polygon.is_valid:
            reason = shapely.is_valid_reason(polygon)
            raise ValueError(f"the footprint is not a simple polygon ({reason}): list its corners in order "
                             "around the building, without crossing edges")
        return value


class Wall(_Model):
    """A wall or fence from ``start`` to ``end``."""

    kind: Literal["wall"] = "wall"
    start: Point2
    end: Point2
    height: float = Field(default=2.0, gt=0, le=30)
    thickness: float = Field(default=0.25, gt=0, le=5)
    material: str = "concrete"

    _material = field_validator("material")(_known_material)


class Tree(_Model):
    kind: Literal["tree"] = "tree"
    position: Point2
    height: float = Field(default=7.0, gt=1, le=40)
    canopy_radius: float = Field(default=2.2, gt=0, le=10)
    trunk_radius: float = Field(default=0.18, gt=0, le=2)


class Bush(_Model):
    kind: Literal["bush"] = "bush"
    position: Point2
    radius: float = Field(default=0.8, gt=0, le=5)
    height: float = Field(default=1.2, gt=0, le=5)


class Pole(_Model):
    """A street light (``arm`` > 0 adds a lamp arm pointing along ``yaw``) or a plain post."""

    kind: Literal["pole"] = "pole"
    position: Point2
    height: float = Field(default=7.0, gt=0, le=30)
    radius: float = Field(default=0.1, gt=0, le=1)
    arm: float = Field(default=1.5, ge=0, le=10)
    yaw: float = 0.0


class Sign(_Model):
    """A traffic sign: a post and a retro-reflective plate facing ``yaw``."""

    kind: Literal["sign"] = "sign"
    position: Point2
    yaw: float = 0.0
    height: float = Field(default=2.3, gt=0.5, le=8)
    plate: float = Field(default=0.7, gt=0.1, le=3)


StaticObject = Annotated[Building | Wall | Tree | Bush | Pole | Sign | Crosswalk, Field(discriminator="kind")]


class Stop(_Model):
    """A stop on a road user's way: it brakes to stand at ``at`` metres along its route (or heading
    line), stands ``duration`` seconds, then drives on (a stop at 0 starts from rest)."""

    at: float = Field(ge=0.0, description="metres along the route from its start")
    duration: float = Field(default=0.0, ge=0.0, le=3600.0, description="seconds standing")


#: The motion fields of :class:`Ego` and :class:`Actor` (:mod:`lidarfuzz.sim.motion`). All default
#: to None and are left out of dumps when None, so scenes without them keep their bytes.
MOTION_FIELDS = ("speeds", "stops", "corner_radius", "accel", "decel", "lateral_accel")
LegSpeeds = list[Annotated[float, Field(gt=0.0, le=60.0)]]


def _omit_absent_motion(self: BaseModel, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
    data: dict[str, Any] = handler(self)
    for key in MOTION_FIELDS:
        if key in data and data[key] is None:
            del data[key]
    return data


def _route_length(route: list[Point2] | None) -> float:
    if route is None:
        return 1.0e4  # the heading line a road user without a route follows
    points = [complex(*p) for p in route]
    return sum(abs(b - a) for a, b in itertools.pairwise(points))


def _check_motion(entry: Ego | Actor, moving: bool) -> None:
    """One-line errors naming the motion field that does not fit the rest of the entry."""
    if entry.speeds is not None:
        if entry.route is None:
            raise ValueError("speeds: one speed per leg of the route; give a route")
        if len(entry.speeds) != len(entry.route) - 1:
            raise ValueError(f"speeds: expected one per leg of the route ({len(entry.route) - 1}), "
                             f"got {len(entry.speeds)}")
    if entry.stops and not moving:
        raise ValueError("stops: a road user that does not move cannot stop; give a speed or speeds")
    if not entry.stops:
        return
    length = _route_length(entry.route)  # only stops need it: every generated road user is validated
    for k, stop in enumerate(entry.stops):
        if stop.at > length + 1e-6:
            raise ValueError(f"stops[{k}].at: {stop.at} m is beyond the route's end ({length:.1f} m)")


class Actor(_Model):
    """A road user. Without ``speed`` it stands still; with it, it moves along its heading or its ``route``."""

    cls: Literal["Car", "Van", "Truck", "Pedestrian", "Cyclist"] = Field(alias="class")
    position: Point2
    yaw: float = 0.0
    size: tuple[float, float, float] | None = Field(
        default=None, description="length, width, height in metres; the class's mean size when omitted")
    speed: float = Field(default=0.0, ge=0.0, le=60.0)
    route: list[Point2] | None = Field(default=None, min_length=2,
                                        description="waypoints followed at `speed`; overrides position and yaw")
    parked: bool = False
    reflectivity: float | None = Field(default=None, ge=0.0, le=1.0, description="paint or clothing")
    id: int | None = Field(default=None, ge=0, description="track id; the actor's index when omitted")
    speeds: LegSpeeds | None = Field(default=None, description="m/s on each leg of the route (one per leg)")
    stops: list[Stop] | None = None
    corner_radius: float | None = Field(default=None, gt=0.0, le=1000.0,
                                        description="round the route's corners with arcs of this radius (m)")
    accel: float | None = Field(default=None, gt=0.0, le=10.0, description="m/s²; 2 when omitted")
    decel: float | None = Field(default=None, gt=0.0, le=10.0, description="m/s²; 3 when omitted")
    lateral_accel: float | None = Field(default=None, gt=0.0, le=10.0,
                                        description="m/s² in rounded corners (caps the speed there); 2 when omitted")

    @field_validator("size")
    @classmethod
    def _positive(cls, value: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        if value is not None and min(value) <= 0:
            raise ValueError("length, width and height must be positive")
        return value

    @model_validator(mode="after")
    def _parked_is_still(self) -> Actor:
        if self.parked and self.speed:
            raise ValueError("a parked actor cannot have a speed")
        if self.parked and self.has_motion_profile:
            raise ValueError("a parked actor cannot have motion fields (speeds, stops, corner_radius, …)")
        _check_motion(self, self.speed > 0 or self.speeds is not None)
        return self

    _serialize = model_serializer(mode="wrap")(_omit_absent_motion)

    @property
    def has_motion_profile(self) -> bool:
        """Whether any motion field is given: it then moves as :mod:`lidarfuzz.sim.motion` describes."""
        return any(getattr(self, key) is not None for key in MOTION_FIELDS)

    def acceleration_limits(self) -> dict[str, float]:
        """``accel`` and ``decel`` where given (the rest take :mod:`lidarfuzz.sim.motion`'s defaults)."""
        return {key: value for key in ("accel", "decel") if (value := getattr(self, key)) is not None}


class Ego(_Model):
    """The vehicle carrying the sensor: from ``position``/``yaw`` along its heading, or along ``route``.

    Without motion fields it drives at ``speed`` with sharp corners and stands at the route's
    end; with any of them (``speeds``, ``stops``, ``corner_radius``, ``accel``, ``decel``,
    ``lateral_accel``) it drives as :mod:`lidarfuzz.sim.motion` describes: rounded corners,
    bounded acceleration, stops, and a stop at the route's end.
    """

    position: Point2 = (0.0, 0.0)
    yaw: float = 0.0
    speed: float = Field(default=0.0, ge=0.0, le=60.0)
    route: list[Point2] | None = Field(default=None, min_length=2)
    speeds: LegSpeeds | None = Field(default=None, description="m/s on each leg of the route (one per leg)")
    stops: list[Stop] | None = None
    corner_radius: float | None = Field(default=None, gt=0.0, le=1000.0,
                                        description="round the route's corners with arcs of this radius (m)")
    accel: float | None = Field(default=None, gt=0.0, le=10.0, description="m/s²; 2 when omitted")
    decel: float | None = Field(default=None, gt=0.0, le=10.0, description="m/s²; 3 when omitted")
    lateral_accel: float | None = Field(default=None, gt=0.0, le=10.0,
                                        description="m/s² in rounded corners (caps the speed there); 2 when omitted")

    @model_validator(mode="after")
    def _motion_fits(self) -> Ego:
        _check_motion(self, self.speed > 0 or self.speeds is not None)
        return self

    _serialize = model_serializer(mode="wrap")(_omit_absent_motion)

    @property
    def has_motion_profile(self) -> bool:
        """Whether any motion field is given: it then moves as :mod:`lidarfuzz.sim.motion` describes."""
        return any(getattr(self, key) is not None for key in MOTION_FIELDS)

    def acceleration_limits(self) -> dict[str, float]:
        """``accel`` and ``decel`` where given (the rest take :mod:`lidarfuzz.sim.motion`'s defaults)."""
        return {key: value for key in ("accel", "decel") if (value := getattr(self, key)) is not None}


class Ramp(_Model):
    """A dropped kerb (a driveway or a kerb ramp at a crossing): the sidewalk falls to a 2 cm lip
    over ``width`` metres of kerb, rising back to full height over ``depth`` metres.

    ``position`` is on the carriageway's edge; ``yaw`` points from the road into the sidewalk.
    """

    position: Point2
    yaw: float
    width: float = Field(default=3.0, gt=0, le=20)
    depth: float = Field(default=1.2, gt=0, le=10)


class Terrain(_Model):
    """The shape of the ground (all zero: flat, the default for hand-written scenes).

    Heights are relative to the world origin (the ego vehicle's start); slopes are rise over
    run (0.02 = 2 %). See :mod:`lidarfuzz.sim.terrain` for how they combine and
    :mod:`lidarfuzz.sim.realism` for the ranges real roads have.
    """

    grade: float = Field(default=0.0, ge=-0.15, le=0.15, description="longitudinal slope along +x at x = 0")
    grade_change: float = Field(default=0.0, ge=-0.2, le=0.2,
                                description="change of the grade per 100 m along x (a crest < 0 < a sag)")
    cross_slope: float = Field(default=0.0, ge=-0.1, le=0.1, description="slope of the whole terrain along +y")
    camber: float = Field(default=0.0, ge=0.0, le=0.08,
                          description="crown: cross-fall of each two-way road from its centreline to its edges")
    sidewalk_slope: float = Field(default=0.0, ge=0.0, le=0.08, description="sidewalks' rise away from the road")
    undulation: float = Field(default=0.0, ge=0.0, le=0.5, description="amplitude of gentle waves, metres")
    undulation_wavelength: float = Field(default=40.0, ge=5.0, le=1000.0)
    undulation_phase: float = 0.0
    ramps: list[Ramp] = Field(default_factory=list)

    @property
    def is_flat(self) -> bool:
        return not (self.grade or self.grade_change or self.cross_slope or self.camber or self.sidewalk_slope
                    or self.undulation or self.ramps)


class SceneSpec(_Model):
    """A whole scene: layout, actors, the ego vehicle and its sensor."""

    name: str = "scene"
    seed: int = Field(default=0, ge=0, description="seeds the sensor noise; the layout is fixed by the description")
    ground: Literal["grass", "soil", "paving"] = "grass"
    extent: float = Field(default=140.0, gt=10, le=2000, description="half-size of the ground square around the route")
    terrain: Terrain = Field(default_factory=Terrain)
    roads: list[Road] = Field(default_factory=list)
    objects: list[StaticObject] = Field(default_factory=list)
    actors: list[Actor] = Field(default_factory=list)
    ego: Ego = Field(default_factory=Ego)
    sensor: str | LidarSensor = DEFAULT_SENSOR

    def to_json(self) -> str:
        return self.model_dump_json(by_alias=True, exclude_defaults=False, indent=1)

    def to_yaml(self) -> str:
        return yaml.safe_dump(json.loads(self.model_dump_json(by_alias=True)), sort_keys=False)


#: Largest magnitude of a number in a scene description (metres, seconds, m/s; the seed aside): 10 km
#: is five times the largest ground square (``extent`` ≤ 2,000). A building wall of 10^300 m asked the
#: simulator for more window panes than memory holds.
MAX_SCENE_NUMBER = 10_000.0


def _number_out_of_range(data: Any, where: str = "") -> tuple[str, float] | None:
    """The key path and value of the first number in ``data`` beyond :data:`MAX_SCENE_NUMBER` (seeds aside)."""
    pending: deque[tuple[str, Any]] = deque([(where, data)])
    while pending:
        path, value = pending.popleft()
        if isinstance(value, dict):
            pending += [(f"{path}.{key}" if path else str(key), item) for key, item in value.items()
                        if key != "seed"]
        elif isinstance(value, (list, tuple)):
            pending += [(f"{path}.{index}", item) for index, item in enumerate(value)]
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and abs(value) > MAX_SCENE_NUMBER:
            return path or "<root>", value
    return None


def parse_scene(data: Any, source: str | PathLike[str] = "<scene>") -> SceneSpec:
    """Validate a mapping as a :class:`SceneSpec`; errors name the offending key."""
    if not isinstance(data, dict):
        raise DataFormatError(source, "a scene description must be a mapping with keys such as roads, actors, ego")
    with reading(source, "read the scene description"):  # what pydantic's validators do not turn into errors
        try:
            spec = SceneSpec.model_validate(data)
        except ValidationError as exc:
            raise validation_error(Path(source), exc) from None
    # the numbers as validated: YAML 1.1 reads 1e300 (no dot) as text, which pydantic then makes a float
    beyond = _number_out_of_range(spec.model_dump(by_alias=True))
    if beyond is not None:
        raise DataFormatError(source, f"{beyond[1]:g} is beyond ±{MAX_SCENE_NUMBER:,.0f} (metres, seconds, m/s)",
                              field=beyond[0])
    return spec


def load_scene(path: str | PathLike[str]) -> SceneSpec:
    """Read a scene description from a YAML or JSON file."""
    path = Path(path)
    return parse_scene(load_structured(path, "a scene description"), path)


__all__ = [
    "ACTOR_CLASSES", "MOTION_FIELDS", "Actor", "Building", "Bush", "Crosswalk", "Ego", "Pole", "Ramp", "Road",
    "SceneSpec", "Sign", "StaticObject", "Stop", "Terrain", "Tree", "Wall", "load_scene", "parse_scene",
]
