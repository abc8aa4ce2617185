"""Road users: KITTI-like size distributions and part-based shapes.

Every shape is built in the object's own frame — x forward, y left, z up, origin at
the centre of the box's bottom face — and fits exactly inside its ``length × width ×
height`` box, so the ground-truth box is tight. Shapes are made of parts (a car is
a body, a sloped cabin of glass under a painted roof, four tyres, lights and plates;
a pedestrian has legs that swing with the walking phase, a torso, arms and a head; a
cyclist is a rider on a bicycle with two wheels) so that detectors must learn shape
and point patterns, not boxes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from functools import lru_cache

import numpy as np

from lidarfuzz.sim.meshes import Mesh, box, cylinder, ellipsoid, ring

#: Size statistics per class (mean, standard deviation) of length, width, height in
#: metres, close to those of the KITTI training labels.
SIZE_STATS: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "Car": ((3.88, 0.43), (1.63, 0.10), (1.53, 0.14)),
    "Van": ((5.08, 0.58), (1.90, 0.14), (2.21, 0.32)),
    "Truck": ((10.1, 2.0), (2.59, 0.20), (3.25, 0.45)),
    "Pedestrian": ((0.84, 0.23), (0.66, 0.14), (1.76, 0.11)),
    "Cyclist": ((1.76, 0.18), (0.60, 0.12), (1.74, 0.09)),
}
#: Lower and upper bounds keeping sampled shapes buildable.
SIZE_LIMITS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "Car": ((3.0, 1.4, 1.25), (5.2, 1.95, 1.95)),
    "Van": ((4.2, 1.7, 1.8), (6.5, 2.3, 2.9)),
    "Truck": ((6.5, 2.2, 2.6), (16.5, 2.6, 4.0)),
    "Pedestrian": ((0.45, 0.45, 1.45), (1.2, 0.9, 2.0)),
    "Cyclist": ((1.5, 0.45, 1.55), (2.0, 0.8, 1.95)),
}
ACTOR_CLASSES: tuple[str, ...] = tuple(SIZE_STATS)
VEHICLE_CLASSES = ("Car", "Van", "Truck")


def mean_size(cls: str) -> tuple[float, float, float]:
    (length, _), (w, _), (h, _) = SIZE_STATS[cls]
    return (length, w, h)


def sample_size(rng: np.random.Generator, cls: str) -> tuple[float, float, float]:
    """A size drawn from the class's distribution, clipped to buildable limits."""
    stats = SIZE_STATS[cls]
    lo, hi = SIZE_LIMITS[cls]
    values = [float(np.clip(rng.normal(m, s), a, b)) for (m, s), a, b in zip(stats, lo, hi, strict=True)]
    return (round(values[0], 3), round(values[1], 3), round(values[2], 3))


def _wheels(length: float, w: float, radius: float, axles: list[float]) -> list[Mesh]:
    out = []
    for x in axles:
        for side in (-1.0, 1.0):
            y0 = side * (w / 2 - 0.24)
            y1 = side * (w / 2)
            out.append(cylinder(radius, (x, y0, radius), (x, y1, radius), "tyre", sections=12))
    return out


def car(length: float, w: float, h: float) -> Mesh:
    radius = float(np.clip(0.21 * h, 0.28, 0.36))
    axle = length / 2 - max(radius + 0.25, 0.19 * length)
    body_bottom, body_top = 0.55 * radius, 0.6 * h
    parts = [
        box((length, w, body_top - body_bottom), (0.0, 0.0, (body_bottom + body_top) / 2)),
        # The cabin: glass sides on a painted roof, windscreen sloping back.
        box((0.52 * length, 0.9 * w, h - body_top), (-0.06 * length, 0.0, (body_top + h) / 2), "car-glass",
            top_size=(0.36 * length, 0.82 * w), top_shift=-0.05 * length, top_material=None),
        *_wheels(length, w, radius, [axle, -axle]),
    ]
    parts += _lights_and_plates(length, w, body_bottom, body_top)
    return Mesh.concat(parts)


def _lights_and_plates(length: float, w: float, bottom: float, top: float) -> list[Mesh]:
    z = bottom + 0.7 * (top - bottom)
    out = []
    for x in (length / 2 - 0.01, -length / 2 + 0.01):
        out.append(box((0.02, 0.5, 0.12), (x, 0.0, bottom + 0.35 * (top - bottom)), "plate"))
        for side in (-1.0, 1.0):
            out.append(box((0.02, 0.22, 0.1), (x, side * (w / 2 - 0.18), z), "light"))
    return out


def van(length: float, w: float, h: float) -> Mesh:
    radius = float(np.clip(0.16 * h, 0.3, 0.4))
    bottom = 0.6 * radius
    bonnet = min(0.9, 0.18 * length)
    parts = [
        box((length - bonnet, w, h - bottom), (-bonnet / 2, 0.0, (bottom + h) / 2)),
        box((bonnet, w, 0.45 * h - bottom), (length / 2 - bonnet / 2, 0.0, (bottom + 0.45 * h) / 2)),
        # Windscreen: a glass wedge between the bonnet and the roof.
        box((0.8 * bonnet, 0.92 * w, h * 0.4), (length / 2 - 0.6 * bonnet, 0.0, 0.65 * h), "car-glass",
            top_size=(0.05, 0.9 * w), top_shift=-0.38 * bonnet),
        *_wheels(length, w, radius, [length / 2 - bonnet - 0.1, -length / 2 + 0.9]),
    ]
    parts += _lights_and_plates(length, w, bottom, 0.45 * h)
    return Mesh.concat(parts)


def truck(length: float, w: float, h: float) -> Mesh:
    radius = 0.5
    cab = min(2.4, 0.3 * length)
    gap = 0.3
    parts = [
        box((cab, w, h * 0.85 - 0.5), (length / 2 - cab / 2, 0.0, (0.5 + h * 0.85) / 2)),
        box((cab * 0.1, 0.9 * w, 0.3 * h), (length / 2 - 0.05 * cab, 0.0, 0.62 * h), "car-glass"),
        box((length - cab - gap, w, h - 0.9), (-(cab + gap) / 2, 0.0, (0.9 + h) / 2), "plaster"),  # the cargo box
        box((length, 0.7 * w, 0.35), (0.0, 0.0, 0.75), "metal"),  # chassis
        *_wheels(length, w, radius, [length / 2 - 0.9 * cab / 2, -length / 2 + 1.4, -length / 2 + 2.6]),
    ]
    return Mesh.concat(parts)


def pedestrian(length: float, w: float, h: float, phase: float = 0.0) -> Mesh:
    """A walking person; ``phase`` (radians) sets the stride, 0 = legs together."""
    hip = 0.52 * h
    shoulder = 0.82 * h
    head_r = 0.065 * h
    stride = np.sin(phase) * max(length / 2 - 0.16, 0.02)
    hip_y = 0.09
    parts = []
    for side, sign in ((-1.0, 1.0), (1.0, -1.0)):
        foot = (sign * stride, side * hip_y, 0.05)
        parts.append(cylinder(0.075, (0.0, side * hip_y, hip), foot, None, sections=8))
        parts.append(box((0.22, 0.1, 0.08), (foot[0] + 0.03, foot[1], 0.04), "cloth"))
        hand = (-sign * stride * 0.6, side * (w / 2 - 0.06), hip - 0.02)
        parts.append(cylinder(0.05, (0.0, side * min(0.18, w / 2 - 0.06), shoulder - 0.02), hand, "skin", sections=6))
    parts.append(box((0.24, 0.38, shoulder - hip + 0.05), (0.0, 0.0, (hip + shoulder) / 2)))
    parts.append(cylinder(0.05, (0.0, 0.0, shoulder), (0.0, 0.0, h - 2 * head_r + 0.01), "skin", sections=6))
    parts.append(ellipsoid((head_r * 0.95, head_r * 0.85, head_r), (0.02, 0.0, h - head_r), "skin"))
    return Mesh.concat(parts)


def cyclist(length: float, w: float, h: float) -> Mesh:
    """A rider on a bicycle, the bicycle's wheels touching both ends of the box."""
    radius = 0.34
    rear, front = -length / 2 + radius, length / 2 - radius
    seat = (rear + 0.35 * (front - rear), 0.0, 0.95)
    bar = (front - 0.12, 0.0, 1.05)
    crank = (rear + 0.5 * (front - rear), 0.0, radius)
    parts = [
        ring(radius - 0.02, 0.02, (rear, 0.0, radius), "tyre"),
        ring(radius - 0.02, 0.02, (front, 0.0, radius), "tyre"),
        cylinder(0.02, (rear, 0.0, radius), crank, "bike-frame", sections=6),
        cylinder(0.02, crank, seat, "bike-frame", sections=6),
        cylinder(0.02, seat, (front - 0.1, 0.0, 0.9), "bike-frame", sections=6),
        cylinder(0.02, (front, 0.0, radius), bar, "bike-frame", sections=6),
        cylinder(0.015, (bar[0], -w / 2 + 0.05, bar[2]), (bar[0], w / 2 - 0.05, bar[2]), "metal", sections=6),
    ]
    head_r = 0.065 * h
    shoulder = (seat[0] + 0.3, 0.0, h - 2 * head_r - 0.05)
    for side in (-1.0, 1.0):
        hip, arm, hand = side * min(0.11, w / 2 - 0.08), side * min(0.17, w / 2 - 0.08), side * (w / 2 - 0.06)
        parts.append(cylinder(0.07, (seat[0], hip, seat[2] + 0.05), (crank[0] + 0.1, hip, 0.5), None, sections=8))
        parts.append(cylinder(0.05, (shoulder[0], arm, shoulder[2]), (bar[0], hand, bar[2]), "skin", sections=6))
    parts.append(cylinder(0.15, (seat[0], 0.0, seat[2] + 0.05), shoulder, None, sections=8))
    parts.append(ellipsoid((head_r, head_r * 0.85, head_r), (shoulder[0] + 0.1, 0.0, h - head_r), "skin"))
    return Mesh.concat(parts)


SHAPES: dict[str, Callable[..., Mesh]] = {
    "Car": car, "Van": van, "Truck": truck, "Pedestrian": pedestrian, "Cyclist": cyclist,
}


WALK_POSES = 16  # distinct leg positions per stride: enough for LiDAR, and they can be cached


def actor_mesh(cls: str, size: tuple[float, float, float], phase: float = 0.0) -> Mesh:
    """The shape of a ``cls`` object of ``size`` (length, width, height) in its own frame.

    Each class's shape is built once at the class's mean size (and, for a pedestrian, in
    each of :data:`WALK_POSES` poses of the walking ``phase``) and scaled to ``size``:
    a ±10 % stretch changes nothing a LiDAR can see, and a frame's road users cost a
    multiplication each instead of a rebuild. The shape still fits its box exactly.
    """
    pose = 0
    if cls == "Pedestrian":
        pose = int(np.floor(np.mod(phase, 2 * np.pi) / (2 * np.pi) * WALK_POSES)) % WALK_POSES
    template = _cached_mesh(cls, mean_size(cls), pose)
    scale = np.asarray(size, np.float64) / np.asarray(mean_size(cls))
    return dataclasses.replace(template, vertices=template.vertices * scale)


@lru_cache(maxsize=4096)
def _cached_mesh(cls: str, size: tuple[float, float, float], pose: int) -> Mesh:
    length, w, h = size
    if cls == "Pedestrian":
        return pedestrian(length, w, h, 2 * np.pi * pose / WALK_POSES)
    return SHAPES[cls](length, w, h)
