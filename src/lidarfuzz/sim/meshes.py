"""Triangle meshes with a reflectivity and a semantic class per face.

Primitive shapes come from trimesh's generators (cached once as templates and then
scaled and moved with numpy); flat ground pieces and extruded footprints are
triangulated with shapely's constrained Delaunay triangulation.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache

import numpy as np
import shapely
import trimesh
from numpy.typing import ArrayLike, NDArray
from shapely.geometry import MultiPolygon, Polygon

from lidarfuzz.sim.materials import MATERIAL_ID, PAINT_GLOSS, PAINT_MATERIAL, SEMANTIC_ID, material

#: Reflectivity placeholder for "the object's own paint", replaced per instance.
PAINT = -1.0


@dataclass(frozen=True, eq=False)
class Mesh:
    """Triangles (vertices V×3, faces F×3) with per-face reflectivity, semantic class id,
    probability of a return, gloss (see :class:`~lidarfuzz.sim.materials.Material`) and material
    index (:data:`~lidarfuzz.sim.materials.MATERIAL_ID`; the camera's colours)."""

    vertices: NDArray[np.float64]
    faces: NDArray[np.int32]
    reflectivity: NDArray[np.float32]
    semantic: NDArray[np.uint8]
    returns: NDArray[np.float32] = None  # type: ignore[assignment]  # probability of a return; all 1 if None
    gloss: NDArray[np.float32] = None  # type: ignore[assignment]  # all 0 if None
    material: NDArray[np.uint8] = None  # type: ignore[assignment]  # all paint if None

    def __post_init__(self) -> None:
        if self.returns is None:
            object.__setattr__(self, "returns", np.ones(len(self.faces), np.float32))
        if self.gloss is None:
            object.__setattr__(self, "gloss", np.zeros(len(self.faces), np.float32))
        if self.material is None:
            object.__setattr__(self, "material", np.full(len(self.faces), PAINT_MATERIAL, np.uint8))

    @staticmethod
    def empty() -> Mesh:
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int32), np.zeros(0, np.float32), np.zeros(0, np.uint8))

    @staticmethod
    def of(vertices: NDArray[np.float64], faces: NDArray[np.int32], material_name: str | None,
           semantic: str | None = None) -> Mesh:
        """A mesh whose faces all have one material (``None`` = the object's paint)."""
        n = len(faces)
        returns = 1.0
        if material_name is None:
            refl, sem, gloss, index = PAINT, SEMANTIC_ID[semantic or "unlabelled"], PAINT_GLOSS, PAINT_MATERIAL
        else:
            mat = material(material_name)
            refl, sem, returns, gloss = mat.reflectivity, SEMANTIC_ID[semantic or mat.semantic], mat.returns, mat.gloss
            index = MATERIAL_ID[material_name]
        return Mesh(np.asarray(vertices, np.float64), np.asarray(faces, np.int32),
                    np.full(n, refl, np.float32), np.full(n, sem, np.uint8), np.full(n, returns, np.float32),
                    np.full(n, gloss, np.float32), np.full(n, index, np.uint8))

    def __len__(self) -> int:
        return len(self.faces)

    @staticmethod
    def concat(parts: Sequence[Mesh]) -> Mesh:
        parts = [p for p in parts if len(p)]
        if not parts:
            return Mesh.empty()
        # Python-int offsets keep the faces int32 (no int64 detour and cast back).
        offsets = itertools.accumulate((len(p.vertices) for p in parts[:-1]), initial=0)
        return Mesh(
            np.concatenate([p.vertices for p in parts]),
            np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)], dtype=np.int32),
            np.concatenate([p.reflectivity for p in parts]),
            np.concatenate([p.semantic for p in parts]),
            np.concatenate([p.returns for p in parts]),
            np.concatenate([p.gloss for p in parts]),
            np.concatenate([p.material for p in parts]),
        )

    def placed(self, x: float, y: float, yaw: float, z: float = 0.0) -> Mesh:
        """The mesh rotated by ``yaw`` about z and moved to (x, y, z)."""
        c, s = np.cos(yaw), np.sin(yaw)
        v = self.vertices
        out = np.empty_like(v)
        out[:, 0] = c * v[:, 0] - s * v[:, 1] + x
        out[:, 1] = s * v[:, 0] + c * v[:, 1] + y
        out[:, 2] = v[:, 2] + z
        return dataclasses.replace(self, vertices=out)

    def posed(self, rotation: NDArray[np.float64], translation: ArrayLike) -> Mesh:
        """The mesh rotated by the 3×3 ``rotation`` about its origin and moved by ``translation``."""
        return dataclasses.replace(self, vertices=self.vertices @ np.asarray(rotation).T + np.asarray(translation))

    def painted(self, reflectivity: float, semantic: str | None = None, gloss: float | None = None) -> Mesh:
        """Paint placeholders replaced by ``reflectivity`` (and their gloss by ``gloss`` when given:
        clothing is matt); every face relabelled when ``semantic`` is given."""
        paint = self.reflectivity == PAINT
        refl = np.where(paint, np.float32(reflectivity), self.reflectivity).astype(np.float32)
        sem = self.semantic if semantic is None else np.full(len(self.faces), SEMANTIC_ID[semantic], np.uint8)
        shine = self.gloss if gloss is None else np.where(paint, np.float32(gloss), self.gloss).astype(np.float32)
        return dataclasses.replace(self, reflectivity=refl, semantic=sem, gloss=shine)


# --------------------------------------------------------------------------- templates
@cache
def unit_box() -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    """The unit cube's vertices and faces, centred at the origin (shared: never modify them)."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return np.asarray(box.vertices), np.asarray(box.faces, np.int32)


@cache
def unit_cylinder(sections: int) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    """A cylinder of radius 1 and height 1 with ``sections`` sides (shared: never modify it)."""
    cyl = trimesh.creation.cylinder(radius=1.0, height=1.0, sections=sections)
    return np.asarray(cyl.vertices), np.asarray(cyl.faces, np.int32)  # axis z, centred at the origin


@cache
def unit_sphere(subdivisions: int) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    """An icosphere of radius 1 (shared: never modify it)."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return np.asarray(sphere.vertices), np.asarray(sphere.faces, np.int32)


@cache
def _unit_torus(major_sections: int, minor_sections: int,
                ratio: float) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=ratio, major_sections=major_sections,
                                   minor_sections=minor_sections)
    return np.asarray(torus.vertices), np.asarray(torus.faces, np.int32)  # in the xy plane


def box(size: Sequence[float], center: Sequence[float], material_name: str | None = None, *,
        top_size: Sequence[float] | None = None, top_shift: float = 0.0, yaw: float = 0.0,
        top_material: str | bool | None = False) -> Mesh:
    """An axis-aligned box (or a frustum when ``top_size`` is given, its top moved by ``top_shift`` along x).

    ``top_material`` (when not ``False``) gives the upward face its own material, e.g.
    a painted roof over a glass cabin.
    """
    verts, faces = unit_box()
    v = verts * np.asarray(size, np.float64)
    if top_size is not None:
        top = verts[:, 2] > 0
        v[top, 0] = verts[top, 0] * top_size[0] + top_shift
        v[top, 1] = verts[top, 1] * top_size[1]
    mesh = Mesh.of(v, faces, material_name)
    if top_material is not False:
        up = np.all(verts[faces][:, :, 2] > 0, axis=1)
        roof = Mesh.of(v, faces[up], top_material if isinstance(top_material, str) else None)
        sides = Mesh(v, faces[~up], mesh.reflectivity[~up], mesh.semantic[~up], mesh.returns[~up], mesh.gloss[~up],
                     mesh.material[~up])
        mesh = Mesh.concat([sides, roof])
    return mesh.placed(center[0], center[1], yaw, center[2])


def cylinder(radius: float, p0: Sequence[float], p1: Sequence[float], material_name: str | None = None, *,
             sections: int = 10) -> Mesh:
    """A cylinder of ``radius`` from point ``p0`` to point ``p1`` (any direction)."""
    verts, faces = unit_cylinder(sections)
    a, b = np.asarray(p0, np.float64), np.asarray(p1, np.float64)
    axis = b - a
    length = float(np.linalg.norm(axis))
    v = verts * np.array([radius, radius, length])
    rotation = _rotation_from_z(axis / length if length > 0 else np.array([0.0, 0.0, 1.0]))
    v = v @ rotation.T + (a + b) / 2.0
    return Mesh.of(v, faces, material_name)


def ellipsoid(radii: Sequence[float], center: Sequence[float], material_name: str | None = None, *,
              subdivisions: int = 1) -> Mesh:
    verts, faces = unit_sphere(subdivisions)
    return Mesh.of(verts * np.asarray(radii, np.float64) + np.asarray(center, np.float64), faces, material_name)


def ring(radius: float, tube: float, center: Sequence[float], material_name: str | None = None) -> Mesh:
    """A torus standing upright in the xz plane (a bicycle wheel's tyre)."""
    verts, faces = _unit_torus(16, 6, tube / radius)
    v = verts * radius
    v = np.stack([v[:, 0], v[:, 2], v[:, 1]], axis=1) + np.asarray(center, np.float64)
    return Mesh.of(v, faces, material_name)


def _rotation_from_z(direction: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation taking +z to the unit ``direction`` (Rodrigues' formula about z × direction)."""
    dx, dy, dz = (float(d) for d in direction)
    # z × direction and z · direction in scalars, term by term as np.cross and np.dot form them
    # (same products and differences, so the same doubles): a world compiles ~1,000 cylinders,
    # and the numpy calls on 3-vectors cost more than the arithmetic.
    v = (0.0 * dz - 1.0 * dy, 1.0 * dx - 0.0 * dz, 0.0 * dy - 0.0 * dx)
    c = 0.0 * dx + 0.0 * dy + 1.0 * dz
    if math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


# --------------------------------------------------------------------------- polygons
def polygons_of(geometry: object) -> MultiPolygon:
    """The polygonal parts of any shapely geometry (set operations can leave lines and points behind)."""
    return MultiPolygon([g for g in shapely.get_parts(geometry) if isinstance(g, Polygon) and not g.is_empty])


def triangles_of(polygon: Polygon | MultiPolygon | NDArray[np.object_]) -> NDArray[np.float64]:
    """Triangles covering a polygon (with holes), or an array of polygons, shape T×3×2. Each
    part is triangulated on its own, so the edges between parts that touch (a road cut along
    its centreline) stay edges."""
    if isinstance(polygon, np.ndarray):
        parts = np.asarray([g for g in polygon if isinstance(g, Polygon) and not g.is_empty], dtype=object)
    else:
        parts = shapely.get_parts(polygons_of(polygon))
    if len(parts) == 0:
        return np.zeros((0, 3, 2))
    triangles = shapely.constrained_delaunay_triangles(parts)
    parts = shapely.get_parts(triangles)
    if len(parts) == 0:
        return np.zeros((0, 3, 2))
    coords = shapely.get_coordinates(parts)
    return coords.reshape(len(parts), 4, 2)[:, :3, :]


def flat(polygon: Polygon | MultiPolygon, z: float, material_name: str) -> Mesh:
    """A horizontal polygon (road, lawn, marking) at height ``z``."""
    tri = triangles_of(polygon)
    verts = np.concatenate([tri.reshape(-1, 2), np.full((tri.size // 2, 1), z)], axis=1)
    return Mesh.of(verts, np.arange(len(verts), dtype=np.int32).reshape(-1, 3), material_name)


def extruded(polygon: Polygon | MultiPolygon, z0: float, z1: float, material_name: str, *,
             side_material: str | None = None) -> Mesh:
    """A footprint extruded from ``z0`` to ``z1``: its top and its side walls (no bottom)."""
    top = flat(polygon, z1, material_name)
    rings = []
    for poly in polygons_of(polygon).geoms:
        rings.append(np.asarray(poly.exterior.coords))
        rings.extend(np.asarray(hole.coords) for hole in poly.interiors)
    # One quad per ring edge, all rings in one mesh; each ring's faces are its quads' first
    # triangles, then their second ones (the order a mesh per ring, concatenated, had).
    edges = [len(coords) - 1 for coords in rings]
    quad = np.empty((sum(edges), 4, 3))
    faces = []
    start = 0
    for coords, n in zip(rings, edges, strict=True):
        a, b = coords[:-1], coords[1:]
        ring_quads = quad[start:start + n]
        ring_quads[:, 0, :2], ring_quads[:, 1, :2], ring_quads[:, 2, :2], ring_quads[:, 3, :2] = a, b, b, a
        ring_quads[:, :2, 2], ring_quads[:, 2:, 2] = z0, z1
        base = (np.arange(n, dtype=np.int32)[:, None] + start) * 4
        faces += [base + np.array([0, 1, 2], np.int32), base + np.array([0, 2, 3], np.int32)]
        start += n
    walls = Mesh.of(quad.reshape(-1, 3), np.concatenate(faces) if faces else np.zeros((0, 3), np.int32),
                    side_material or material_name)
    return Mesh.concat([top, walls])
