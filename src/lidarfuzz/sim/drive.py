"""Drive logs: a generated ego route that stops, turns at a junction and meets road users on its way.

:func:`~lidarfuzz.sim.generate.generate_scene` with ``drive=True`` lays out the usual street with
a junction ahead, and this module plans the drive through it (all from the seed):

* **the route**: straight along the main street to the junction, a left or right turn into the
  crossing street (a rounded corner, :mod:`lidarfuzz.sim.motion`; the speed drops to what the
  corner allows), then along the crossing street for the rest of the log;
* **a stop** before the junction: at the zebra crossing while a pedestrian crosses in front
  (``crossing``), or behind a car that stops there first and then drives straight on
  (``queue``; at an urban junction that car stops for the crossing pedestrian, at a suburban one
  it gives way);
* **an obstacle appearing** after the turn: a pedestrian steps off the kerb ahead and crosses
  the road, clear of the ego vehicle's lane a few seconds before it arrives;
* **no collisions** with the generated traffic: every generated road user whose footprint would
  meet the ego vehicle's (or the queueing car's) on their way is left out (:func:`clear_of`).

The timings come from the motion model itself (:meth:`~lidarfuzz.sim.motion.SpeedProfile.time_at`),
so the pedestrian is on the crossing when the first vehicle brakes for it, and each vehicle
stands until the way ahead is free.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import shapely
from numpy.typing import NDArray
from shapely.geometry import Polygon

from lidarfuzz.sim.actors import sample_size
from lidarfuzz.sim.motion import DECEL
from lidarfuzz.sim.spec import Actor, Ego, Road
from lidarfuzz.sim.world import ProfiledTrajectory, Trajectory, trajectory_of

EGO_SIZE = (4.6, 1.9)  #: length, width of the ego vehicle (a VW Passat estate), for clearances
EGO_FRONT = 2.6  #: metres from the ego's reference point (the sensor, mid-car) to its front bumper
MIN_RIGHT_RADIUS = 4.5  #: metres; a tighter turn than a car's smallest turning circle (about 5 m) allows
SAMPLE_STEP = 0.2  #: seconds between the instants :func:`clear_of` compares footprints at


@dataclass(frozen=True)
class DrivePlan:
    """What the seed chose for a drive: the turn, the stop, where the junction is."""

    turn: Literal["left", "right"]
    stop: Literal["crossing", "queue"]
    junction_x: float
    ego_y: float
    corner_radius: float
    arm: float  # metres of crossing street beyond the junction on the turn's side

    @property
    def side(self) -> float:
        """+1 for a left turn (towards +y), −1 for a right turn."""
        return 1.0 if self.turn == "left" else -1.0


def plan_drive(rng: np.random.Generator, *, speed: float, duration: float, lanes: int, lane_width: float,
               urban: bool) -> DrivePlan:
    """The seeded choices of a drive (``rng`` is the drive's own stream)."""
    turn: Literal["left", "right"] = "left" if rng.random() < 0.5 else "right"
    stop: Literal["crossing", "queue"] = "crossing" if urban and rng.random() < 0.5 else "queue"
    half = lanes * lane_width / 2
    # Right-hand traffic: a left turn from the lane next to the centre line, a right turn from the kerb lane.
    ego_y = -lane_width / 2 if turn == "left" else -half + lane_width / 2
    travel = speed * max(duration, 0.0)
    junction_x = float(np.clip(rng.uniform(0.3, 0.45) * travel, 45.0, 400.0))
    radius = float(rng.uniform(7.0, 10.0) if turn == "left" else rng.uniform(5.0, 8.0))
    arm = max(travel - junction_x + 80.0, 130.0)
    return DrivePlan(turn, stop, junction_x, ego_y, radius, arm)


def _r(value: float) -> float:
    return round(float(value), 2)


def drive_route(plan: DrivePlan, main: Road, cross: Road) -> tuple[list[list[float]], float]:
    """The ego vehicle's waypoints and corner radius: to the junction, into the crossing street's
    right-hand lane, along it. A right turn's radius is kept small enough that the ego's path stays
    1.2 m off the kerb's corner, but not under :data:`MIN_RIGHT_RADIUS`: on narrow streets without
    parking strips the path then passes within a metre of the kerb's (sharp) corner."""
    lane_x = plan.junction_x + plan.side * cross.lane_width / 2
    radius = plan.corner_radius
    if plan.turn == "right":
        # The arc's middle lies (√2 − 1)·R inside the corner, towards the kerb's corner.
        kerb_corner = np.hypot(cross.lane_width / 2, main.half_width + plan.ego_y)
        radius = float(np.clip((kerb_corner - 1.2) / (np.sqrt(2.0) - 1.0), MIN_RIGHT_RADIUS, radius))
    end_y = plan.side * (plan.arm - 10.0)
    route = [[0.0, _r(plan.ego_y)], [_r(lane_x), _r(plan.ego_y)], [_r(lane_x), _r(end_y)]]
    return route, _r(radius)


def _oriented(x: float, y: float, length: float, width: float, yaw: float) -> Polygon:
    c, s = np.cos(yaw), np.sin(yaw)
    corners = np.array([[length, width], [length, -width], [-length, -width], [-length, width]]) / 2
    return Polygon(corners @ np.array([[c, s], [-s, c]]) + [x, y])


def _trajectory(entry: dict[str, Any]) -> Trajectory:
    actor = Actor.model_validate(entry)
    return trajectory_of(actor, 0.0 if actor.parked else actor.speed)


def plan_actors(plan: DrivePlan, ego: dict[str, Any], main: Road, cross: Road, crosswalk_x: float | None,
                rng: np.random.Generator, duration: float) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The ego entry with its stop, and the road users timed against it (the queueing car, the
    crossing pedestrian, the pedestrian stepping out after the turn)."""
    speed = float(ego["speed"])
    actors: list[dict[str, Any]] = []
    # Where the first vehicle in the queue stops: before the zebra crossing, or at the give-way line.
    # (The crossing is 3 m wide: stop 1.5 m short of it; the give-way line is 2 m before the crossing street.)
    line = crosswalk_x - 1.5 - 1.5 if crosswalk_x is not None else plan.junction_x - cross.half_width - 2.0
    lead: dict[str, Any] | None = None
    if plan.stop == "queue":
        length, width, height = sample_size(rng, "Car")
        start = float(rng.uniform(18.0, 30.0))
        lead_stop = line - length / 2
        lead = {"class": "Car", "position": [_r(start), _r(plan.ego_y)], "yaw": 0.0,
                "size": [length, width, height], "speed": _r(speed)}
        ego_stop = lead_stop - length / 2 - 2.0 - EGO_FRONT
    else:
        ego_stop = line - EGO_FRONT
    first_stop_x = lead_stop if lead is not None else ego_stop
    first_start_x = float(lead["position"][0]) if lead is not None else 0.0
    first_entry = lead if lead is not None else ego
    first_entry["stops"] = [{"at": _r(first_stop_x - first_start_x), "duration": 0.0}]  # when: not how long
    first = _profile_of(first_entry, ego=lead is None)
    arrive = first.profile.time_at(first_stop_x - first_start_x)
    brake = arrive - speed / DECEL
    # The pedestrian on the zebra crossing steps out as the first vehicle begins to brake.
    if crosswalk_x is not None:
        walk = float(rng.uniform(1.1, 1.5))
        x = crosswalk_x + float(rng.uniform(-0.8, 0.8))
        reach = main.half_width + 1.2
        wait = max(0.0, brake - float(rng.uniform(0.5, 2.0)))
        pedestrian = {"class": "Pedestrian", "position": [_r(x), _r(-reach)], "yaw": 90.0, "speed": _r(walk),
                      "route": [[_r(x), _r(-reach)], [_r(x), _r(reach)]], "stops": [{"at": 0.0, "duration": _r(wait)}]}
        # The vehicles go once it is 1.5 m past their lane (the ego's and the queueing car's).
        past = plan.ego_y + main.lane_width / 2 + 1.5 + reach
        across = _profile_of(pedestrian, ego=False).profile.time_at(past)
        first_wait = max(3.0, across - arrive)
        actors.append(pedestrian)
    else:
        first_wait = float(rng.uniform(3.0, 6.0))
    first_entry["stops"] = [{"at": _r(first_stop_x - first_start_x), "duration": _r(first_wait)}]
    if lead is not None:
        lead_leaves = arrive + first_wait
        ego["stops"] = [{"at": _r(ego_stop), "duration": 0.0}]
        ego_arrives = _profile_of(ego, ego=True).profile.time_at(ego_stop)
        ego["stops"] = [{"at": _r(ego_stop), "duration": _r(max(2.0, lead_leaves + 1.5 - ego_arrives))}]
        actors.insert(0, lead)
    stepping = _stepping_out(plan, ego, cross, rng, duration)
    if stepping is not None:
        actors.append(stepping)
    return ego, actors


def _profile_of(entry: dict[str, Any], *, ego: bool) -> ProfiledTrajectory:
    model: Ego | Actor = Ego.model_validate(entry) if ego else Actor.model_validate(entry)
    trajectory = trajectory_of(model, model.speed)
    assert isinstance(trajectory, ProfiledTrajectory)
    return trajectory


def _stepping_out(plan: DrivePlan, ego: dict[str, Any], cross: Road, rng: np.random.Generator,
                  duration: float) -> dict[str, Any] | None:
    """A pedestrian who steps off the kerb 35–70 m after the turn and crosses the road, out of the
    ego vehicle's lane 2.5 s before it gets there (None when the log ends before)."""
    trajectory = _profile_of(ego, ego=True)
    path = trajectory.path
    turned = float(path.offsets[-2]) if len(path.offsets) > 2 else 0.0  # where the last straight begins
    at = turned + float(rng.uniform(35.0, 70.0))
    if at > path.length - 10.0:
        return None
    arrive = trajectory.profile.time_at(at)
    x, y, _ = (float(v[0]) for v in path.pose(at))
    kerb_side = plan.side  # the right-hand kerb of a car heading ±y is on the +x side for +y
    start = plan.junction_x + kerb_side * (cross.half_width + cross.sidewalk_width / 2)
    end = plan.junction_x - kerb_side * (cross.half_width + cross.sidewalk_width / 2)
    walk = float(rng.uniform(1.2, 1.6))
    clear = abs(start - (x - kerb_side * (cross.lane_width / 2 + EGO_SIZE[1] / 2 + 0.5)))
    entry = {"class": "Pedestrian", "position": [_r(start), _r(y)], "yaw": _r(180.0 if kerb_side > 0 else 0.0),
             "speed": _r(walk), "route": [[_r(start), _r(y)], [_r(end), _r(y)]],
             "stops": [{"at": 0.0, "duration": 0.0}]}
    clear_time = _profile_of(entry, ego=False).profile.time_at(clear)
    wait = arrive - 2.5 - clear_time
    if wait < 0 or arrive > duration:
        return None
    entry["stops"] = [{"at": 0.0, "duration": _r(wait)}]
    return entry


def clear_of(actors: list[dict[str, Any]], movers: list[dict[str, Any]], ego: dict[str, Any], horizon: float,
             margin: float = 0.5) -> list[dict[str, Any]]:
    """The generated road users whose footprints stay ``margin`` metres clear of the ego vehicle's
    and of each of ``movers``' (the timed road users) at every instant up to ``horizon`` seconds
    (sampled every :data:`SAMPLE_STEP`)."""
    times = np.arange(0.0, max(horizon, 0.0) + SAMPLE_STEP, SAMPLE_STEP)
    ways: list[tuple[NDArray[np.float64], tuple[float, float]]] = []
    ego_way = trajectory_of(Ego.model_validate(ego), float(ego["speed"]))
    ways.append((np.stack(ego_way.at(times), axis=1), EGO_SIZE))
    for mover in movers:
        size = mover.get("size") or sample_size(np.random.default_rng(0), mover["class"])
        ways.append((np.stack(_trajectory(mover).at(times), axis=1), (float(size[0]), float(size[1]))))
    kept = []
    for entry in actors:
        length, width = float(entry["size"][0]), float(entry["size"][1])
        xy_yaw = np.stack(_trajectory(entry).at(times), axis=1)
        if all(_apart(xy_yaw, (length, width), way, size, margin) for way, size in ways):
            kept.append(entry)
    return kept


def _apart(a: NDArray[np.float64], a_size: tuple[float, float], b: NDArray[np.float64], b_size: tuple[float, float],
           margin: float) -> bool:
    reach = np.hypot(*a_size) / 2 + np.hypot(*b_size) / 2 + margin
    near = np.flatnonzero(np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1]) < reach)
    if not len(near):
        return True
    first = [_oriented(a[k, 0], a[k, 1], *a_size, a[k, 2]) for k in near]
    second = [_oriented(b[k, 0], b[k, 1], *b_size, b[k, 2]) for k in near]
    return not bool(np.any(shapely.dwithin(np.asarray(first, dtype=object), np.asarray(second, dtype=object),
                                           margin)))


__all__ = ["DrivePlan", "clear_of", "drive_route", "plan_actors", "plan_drive"]
