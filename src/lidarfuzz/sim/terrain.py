"""Ground that is not flat: the height of every surface of a scene, and meshes draped over it.

Real roads are not the plane ``z = −1.73 m`` a flat simulator gives a detector. In
KITTI's scans (HDL-64E, 1.73 m above the road) the ground seen from the sensor tilts
by about 1 % near the car, rises or falls by 0.3–0.8 m at 50 m where the grade
changes (crests and sags), falls off towards the kerbs by the road's crown, and steps
up onto sidewalks, verges and driveways. A detector trained on flat ground puts car
boxes at the flat ground's height and covers a real road with them.

A :class:`~lidarfuzz.sim.spec.Terrain` (part of the scene description) sets the
shape; :class:`Ground` evaluates it (vectorised) for the whole scene:

* **base**: ``grade·x + ½·grade_change·x² + cross_slope·y`` plus a gentle
  undulation (two sine waves, along and across the road) — the terrain everything
  stands on;
* **road**: base plus the crown, ``camber × (half width − distance to the
  centreline)`` for the nearest road (highest along the centreline, the carriageway's
  edge at base height; at a junction the higher of the two roads' crowns);
* **sidewalk**: base plus the kerb height plus ``sidewalk_slope ×`` the distance from
  the carriageway (sidewalks fall towards the road), lowered to a 2 cm lip at a
  dropped kerb (:attr:`Terrain.ramps`, at zebra crossings and driveways), rising to
  full height over the ramp's depth;
* **terrain** beside the roads: base plus 0.8 × the kerb height (as before).

Meshes are built flat and their vertices lifted to the surface. Roads and sidewalks are
strips whose surface is linear across them: they are cut along the crown's ridges (the
centrelines) and the ramps' edges, and get vertices along their edges close enough that
the mesh departs from the surface by under :data:`TOLERANCE` (:attr:`Ground.spacing`), so
the crown and the ramps are exact. Open ground is cut along a square grid
(:func:`grid_triangles`); neighbouring cells share their vertices, so the mesh stays
watertight (no cracks a ray could slip through).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
from numpy.typing import ArrayLike, NDArray
from shapely.geometry import MultiPolygon, Polygon
from shapely.ops import split

from lidarfuzz.sim.meshes import Mesh, polygons_of, triangles_of
from lidarfuzz.sim.spec import Road, Terrain

#: How far a draped mesh may depart from the analytic surface between its vertices, metres.
TOLERANCE = 0.01
#: Bounds of the vertex spacing along roads and sidewalks, metres (:attr:`Ground.spacing`).
MIN_EDGE, MAX_EDGE = 2.0, 16.0
#: Open ground beside the roads (most of the area, mostly far away, where only parked cars in
#: driveways, trees and buildings stand) may depart from the surface by this much, metres.
VERGE_TOLERANCE = 0.04
#: Its grid cell is one of these (each divides the next, so a world's edges are on every grid).
VERGE_CELLS = (8.0, 16.0, 32.0)
#: A dropped kerb keeps a lip of this height above the road (wheelchair and driveway ramps).
RAMP_LIP = 0.02
#: Where the wheels of the ego vehicle touch the ground, relative to the point under the
#: sensor: KITTI's VW Passat B6 has a 2.71 m wheelbase and a 1.55 m track.
WHEELBASE = 2.71
TRACK = 1.55


@dataclass(frozen=True, eq=False)
class Ground:
    """The heights of a scene's surfaces: vectorised over points, used to drape the meshes,
    stand road users and static objects on the ground and seat the ego vehicle.

    Attributes:
        terrain: The shape (slopes, camber, undulation, ramps); flat when all zero.
        roads: The scene's roads (centrelines and widths give the crown).
        drivable: Carriageways and parking strips.
        sidewalks: Sidewalks (raised by the kerb).
        sidewalk_height: Kerb height.
        terrain_height: Height of open ground beside roads above the base.
    """

    terrain: Terrain
    roads: tuple[Road, ...]
    drivable: MultiPolygon
    sidewalks: MultiPolygon
    sidewalk_height: float
    terrain_height: float
    _ramps: MultiPolygon = field(init=False, repr=False)
    _ramp_polygons: tuple[tuple[Polygon, NDArray[np.float64], NDArray[np.float64]], ...] = field(
        init=False, repr=False)

    def __post_init__(self) -> None:
        shapely.prepare(self.sidewalks)
        shapely.prepare(self.drivable)
        ramps = []
        for ramp in self.terrain.ramps:
            yaw = np.deg2rad(ramp.yaw)
            into = np.array([np.cos(yaw), np.sin(yaw)])  # from the road into the sidewalk
            along = np.array([-into[1], into[0]])
            start = np.asarray(ramp.position, np.float64)
            corners = [start + along * ramp.width / 2, start + along * ramp.width / 2 + into * ramp.depth,
                       start - along * ramp.width / 2 + into * ramp.depth, start - along * ramp.width / 2]
            ramps.append((Polygon(corners), start, into * 1.0 / ramp.depth))
        object.__setattr__(self, "_ramp_polygons", tuple(ramps))
        object.__setattr__(self, "_ramps", MultiPolygon([r[0] for r in ramps]) if ramps else MultiPolygon())
        shapely.prepare(self._ramps)

    @property
    def is_flat(self) -> bool:
        return self.terrain.is_flat

    @property
    def spacing(self) -> float:
        """Vertex spacing along roads and sidewalks: a chord of length L departs from a curve of
        curvature κ by κ·L²/8, so L = √(8 · :data:`TOLERANCE` / κ), κ the base's sharpest
        curvature (:func:`curvature`), within [:data:`MIN_EDGE`, :data:`MAX_EDGE`]."""
        bend = curvature(self.terrain)
        return MAX_EDGE if bend <= 0 else float(np.clip(np.sqrt(8 * TOLERANCE / bend), MIN_EDGE, MAX_EDGE))

    @property
    def verge_cell(self) -> float:
        """Grid cell of open ground: the largest of :data:`VERGE_CELLS` within :data:`VERGE_TOLERANCE`."""
        return verge_cell(self.terrain)

    # ------------------------------------------------------------------ surfaces
    def base(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """The terrain under everything (no crown, kerb or verge)."""
        t = self.terrain
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        z = t.grade * x + 0.5 * t.grade_change / 100.0 * x * x + t.cross_slope * y
        if t.undulation:
            k = 2 * np.pi / t.undulation_wavelength
            z = z + t.undulation * (0.7 * np.sin(k * x + t.undulation_phase)
                                    + 0.3 * np.sin(1.7 * k * y + 2.3 * t.undulation_phase))
        return z

    def crown(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """The road's crown above the base: ``camber × (half width − distance to the centreline)``,
        the highest over the roads, never below 0."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        out = np.zeros(np.broadcast(x, y).shape)
        if not self.terrain.camber:
            return out
        for road in self.roads:
            if road.one_way:  # a one-way road falls to one side: its cross slope is the terrain's
                continue
            margin = road.half_width - _distance_to_polyline(np.asarray(road.centerline, np.float64), x, y)
            np.maximum(out, margin, out=out)
        return self.terrain.camber * out

    def road(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """The carriageway's surface."""
        return self.base(x, y) + self.crown(x, y)

    def sidewalk(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """The sidewalk's surface: the kerb's height, rising away from the road by the sidewalk's
        cross-fall; at a dropped kerb lowered to a lip and ramped back up."""
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        z = self.base(x, y)
        rise = np.full(np.broadcast(x, y).shape, self.sidewalk_height)
        if self.terrain.sidewalk_slope and self.roads:
            away = np.full(rise.shape, np.inf)
            for road in self.roads:
                d = _distance_to_polyline(np.asarray(road.centerline, np.float64), x, y) - road.half_width
                np.minimum(away, d, out=away)
            rise = rise + self.terrain.sidewalk_slope * np.clip(away, 0.0, None)
        if not self._ramp_polygons or not np.any(shapely.contains_xy(self._ramps, x, y)):
            return z + rise
        for polygon, start, gradient in self._ramp_polygons:
            inside = shapely.contains_xy(polygon, x, y)
            if np.any(inside):
                share = np.clip((x - start[0]) * gradient[0] + (y - start[1]) * gradient[1], 0.0, 1.0)
                lowered = RAMP_LIP + (rise - RAMP_LIP) * share
                rise = np.where(inside, np.minimum(rise, lowered), rise)
        return z + rise

    def verge(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """Open ground (grass, soil, paving) beside the roads."""
        return self.base(x, y) + self.terrain_height

    def height(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """The top surface at (x, y): road, sidewalk or verge, whichever lies there."""
        x, y = np.broadcast_arrays(np.asarray(x, np.float64), np.asarray(y, np.float64))
        on_road = shapely.contains_xy(self.drivable, x, y)
        on_sidewalk = ~on_road & shapely.contains_xy(self.sidewalks, x, y)
        z = np.array(self.verge(x, y), np.float64)
        if np.any(on_road):  # each surface evaluated only where it lies
            z[on_road] = self.road(x[on_road], y[on_road])
        if np.any(on_sidewalk):
            z[on_sidewalk] = self.sidewalk(x[on_sidewalk], y[on_sidewalk])
        return z

    def tilt(self, x: ArrayLike, y: ArrayLike, yaw: ArrayLike, length: ArrayLike,
             width: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Where a vehicle standing at (x, y) heading ``yaw`` rests: the height of the plane
        through its four wheels under (x, y), and the rise per metre forward and to the left
        (wheels at ±``length``/2 and ±``width``/2)."""
        x, y, yaw, length, width = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in
                                                         (x, y, yaw, length, width)))
        c, s = np.cos(yaw), np.sin(yaw)
        fx, fy = c * length / 2, s * length / 2
        lx, ly = -s * width / 2, c * width / 2
        heights = self.height(np.stack([x + fx + lx, x + fx - lx, x - fx + lx, x - fx - lx]),
                              np.stack([y + fy + ly, y + fy - ly, y - fy + ly, y - fy - ly]))
        front_left, front_right, rear_left, rear_right = heights
        centre = heights.mean(axis=0)
        forward = (front_left + front_right - rear_left - rear_right) / (2 * length)
        left = (front_left + rear_left - front_right - rear_right) / (2 * width)
        return centre, forward, left

    # ------------------------------------------------------------------ meshes
    def drape(self, polygon: Polygon | MultiPolygon, surface: str, material_name: str, *,
              lift: float = 0.0, cut: object | None = None, cell: float | None = None) -> Mesh:
        """A ground polygon as a mesh lying on ``surface`` (``road``, ``sidewalk``, ``verge`` or
        ``base``), ``lift`` above it. ``cut`` (lines) become mesh edges (the crown's ridge, the
        edges of ramps). Strips (roads, sidewalks, paint; ``cell`` None) get vertices every
        :attr:`spacing` along their edges, across which their surface is linear; wide areas
        are cut along a grid of ``cell`` metres."""
        polygon = polygons_of(polygon)
        if polygon.is_empty:
            return Mesh.empty()
        if self.is_flat:
            triangles = triangles_of(polygon)
        else:
            pieces = polygon
            if cut is not None and not shapely.is_empty(cut):
                pieces = polygons_of(split(polygon, cut))
            if cell is None:  # strips: vertices along their edges suffice
                # Part by part: segmentizing a multipolygon merges parts that touch (the ridge).
                triangles = triangles_of(shapely.segmentize(shapely.get_parts(pieces), self.spacing))
            else:
                triangles = grid_triangles(pieces, cell)
        xy = triangles.reshape(-1, 2)
        z = getattr(self, surface)(xy[:, 0], xy[:, 1]) + lift
        vertices = np.column_stack([xy, z])
        return Mesh.of(vertices, np.arange(len(vertices), dtype=np.int32).reshape(-1, 3), material_name)

    def walls(self, polygon: Polygon | MultiPolygon, surface: str, material_name: str) -> Mesh:
        """Vertical walls along a polygon's boundary from the base up to its ``surface`` (kerb
        faces, the edges of raised verges), so no ray passes between two surfaces of different heights."""
        rings = []
        polygon = polygons_of(polygon)
        if polygon.is_empty:
            return Mesh.empty()
        if not self.is_flat:
            polygon = polygons_of(shapely.segmentize(polygon, self.spacing))
        for poly in polygon.geoms:
            rings.append(np.asarray(poly.exterior.coords))
            rings.extend(np.asarray(hole.coords) for hole in poly.interiors)
        coords = np.concatenate(rings)
        starts = np.concatenate([np.arange(len(r) - 1) + offset for r, offset in
                                 zip(rings, np.cumsum([0] + [len(r) for r in rings[:-1]]), strict=True)])
        bottom = self.base(coords[:, 0], coords[:, 1])
        top = getattr(self, surface)(coords[:, 0], coords[:, 1])
        a, b = starts, starts + 1
        quad = np.stack([
            np.column_stack([coords[a], bottom[a]]), np.column_stack([coords[b], bottom[b]]),
            np.column_stack([coords[b], top[b]]), np.column_stack([coords[a], top[a]]),
        ], axis=1).reshape(-1, 3)
        base = np.arange(len(a), dtype=np.int32)[:, None] * 4
        faces = np.concatenate([base + np.array([0, 1, 2]), base + np.array([0, 2, 3])]).astype(np.int32)
        return Mesh.of(quad, faces, material_name)


def curvature(terrain: Terrain) -> float:
    """The sharpest curvature of the base (1/m): the vertical curve's plus the undulation's
    (its two waves' amplitudes times their wavenumbers squared)."""
    k = 2 * np.pi / terrain.undulation_wavelength
    return abs(terrain.grade_change) / 100.0 + terrain.undulation * k * k * (0.7 + 0.3 * 1.7 ** 2)


def verge_cell(terrain: Terrain) -> float:
    """The largest of :data:`VERGE_CELLS` whose chords depart from the base by under
    :data:`VERGE_TOLERANCE` (κ·L²/8)."""
    bend = curvature(terrain)
    fits = [c for c in VERGE_CELLS if bend * c * c / 8 <= VERGE_TOLERANCE]
    return max(fits) if fits else VERGE_CELLS[0]


def ramp_edges(ground: Ground) -> object:
    """The outlines of the dropped kerbs (edges of the sidewalk's mesh), or None."""
    if not ground.terrain.ramps:
        return None
    return shapely.union_all([polygon.exterior for polygon, _, _ in ground._ramp_polygons])


def _distance_to_polyline(line: NDArray[np.float64], x: NDArray[np.float64],
                          y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance from each (x, y) to a polyline (K×2), vectorised over the points and segments."""
    a, b = line[:-1], line[1:]
    seg = b - a
    length2 = np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-18)
    px = np.asarray(x, np.float64)[..., None] - a[:, 0]
    py = np.asarray(y, np.float64)[..., None] - a[:, 1]
    t = np.clip((px * seg[:, 0] + py * seg[:, 1]) / length2, 0.0, 1.0)
    dx, dy = px - t * seg[:, 0], py - t * seg[:, 1]
    return np.sqrt(np.min(dx * dx + dy * dy, axis=-1))


def grid_triangles(polygon: Polygon | MultiPolygon, cell: float) -> NDArray[np.float64]:
    """Triangles (T×3×2) covering ``polygon``, cut along a square grid of ``cell`` metres aligned
    with the origin: two per cell inside it, a constrained Delaunay triangulation of the piece in
    each cell its boundary crosses. Neighbouring cells (and neighbouring polygons cut by the same
    grid) share their vertices on the grid lines, so a lifted mesh has no cracks.

    Example:
        >>> from shapely.geometry import box
        >>> len(grid_triangles(box(0, 0, 8, 4), 4.0))
        4
    """
    polygon = polygons_of(polygon)
    if polygon.is_empty:
        return np.zeros((0, 3, 2))
    minx, miny, maxx, maxy = polygon.bounds
    i0, j0 = int(np.floor(minx / cell)), int(np.floor(miny / cell))
    columns, rows = int(np.ceil(maxx / cell)) - i0, int(np.ceil(maxy / cell)) - j0
    # Cells the boundary crosses: every cell a boundary segment's bounding box touches (segments
    # no longer than half a cell, so that box spans at most 2 × 2 cells; a superset is harmless).
    crossing = np.zeros((columns, rows), bool)
    for rings in shapely.get_parts(shapely.segmentize(polygon.boundary, cell / 2)):
        xy = shapely.get_coordinates(rings)
        ci = np.clip(np.floor(xy[:, 0] / cell).astype(np.int64) - i0, 0, columns - 1)
        cj = np.clip(np.floor(xy[:, 1] / cell).astype(np.int64) - j0, 0, rows - 1)
        for a, b in ((ci[:-1], cj[:-1]), (ci[1:], cj[1:]), (ci[:-1], cj[1:]), (ci[1:], cj[:-1])):
            crossing[a, b] = True
    i, j = np.meshgrid(np.arange(columns), np.arange(rows), indexing="ij")
    x0, y0 = (i + i0) * cell, (j + j0) * cell
    inside = ~crossing & shapely.contains_xy(polygon, x0 + cell / 2, y0 + cell / 2)
    a = np.stack([x0[inside], y0[inside]], axis=1).astype(np.float64)
    b, c, d = (a + np.array(corner) for corner in ((cell, 0.0), (cell, cell), (0.0, cell)))
    triangles = [np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)]
    pieces = []
    for row in np.flatnonzero(crossing.any(axis=0)):  # clip to the row first: each cell's clip then is small
        y = (row + j0) * cell
        strip = shapely.clip_by_rect(polygon, i0 * cell, y, (i0 + columns) * cell, y + cell)
        pieces += [shapely.clip_by_rect(strip, x, y, x + cell, y + cell)
                   for x in (np.flatnonzero(crossing[:, row]) + i0) * cell]
    if pieces:
        triangles.append(triangles_of(shapely.get_parts(np.asarray(pieces, dtype=object))))
    return np.concatenate(triangles)


def frame_from_slopes(yaw: ArrayLike, rise_forward: ArrayLike, rise_left: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices (…×3×3, columns: forward, left, up in the world) of a body heading
    ``yaw`` on ground that rises by ``rise_forward`` per metre ahead and ``rise_left`` per metre
    to its left.

    Example:
        >>> (frame_from_slopes(0.0, 0.0, 0.0).round(6) + 0.0).tolist()
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    yaw, rise_forward, rise_left = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in
                                                         (yaw, rise_forward, rise_left)))
    return frame_from_heading(np.cos(yaw), np.sin(yaw), rise_forward, rise_left)


def frame_from_heading(c: NDArray[np.float64], s: NDArray[np.float64], rise_forward: NDArray[np.float64],
                       rise_left: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`frame_from_slopes` given the heading's cosine ``c`` and sine ``s`` (arrays of one
    shape): for a caller that must take them one by one, as a single body's frame takes them."""
    # forward = (c, s, rf)/|·|; up = forward × (−s, c, rl), normalised; left = up × forward.
    norm = np.sqrt(1.0 + rise_forward * rise_forward)
    fx, fy, fz = c / norm, s / norm, rise_forward / norm
    ux, uy, uz = fy * rise_left - fz * c, fz * -s - fx * rise_left, fx * c + fy * s
    length = np.sqrt(ux * ux + uy * uy + uz * uz)
    ux, uy, uz = ux / length, uy / length, uz / length
    lx, ly, lz = uy * fz - uz * fy, uz * fx - ux * fz, ux * fy - uy * fx
    return np.stack([np.stack([fx, lx, ux], -1), np.stack([fy, ly, uy], -1), np.stack([fz, lz, uz], -1)], -2)

__all__ = ["MAX_EDGE", "MIN_EDGE", "RAMP_LIP", "TOLERANCE", "TRACK", "VERGE_CELLS", "VERGE_TOLERANCE", "WHEELBASE",
           "Ground", "curvature", "frame_from_heading", "frame_from_slopes", "grid_triangles", "verge_cell"]
