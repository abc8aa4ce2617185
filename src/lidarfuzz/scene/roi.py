"""The drivable-area map: region-of-interest polygons in the LiDAR frame.

Apollo's perception keeps only points inside the HD map's road polygons (the "HD-map
ROI"); Zhou & Sun's relation MR1 scatters points *outside* it. A :class:`RoiMap`
holds those polygons for one frame (x, y in metres, LiDAR frame) and answers
"which points are inside" for many points at once.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np
import shapely
import shapely.affinity
from numpy.typing import ArrayLike, NDArray
from shapely.geometry import MultiPolygon, Polygon, mapping, shape


class RoiMap:
    """Drivable-area polygons (holes allowed) in the LiDAR frame's x–y plane.

    Example:
        >>> roi = RoiMap.from_polygons([[(0, -4), (50, -4), (50, 4), (0, 4)]])
        >>> roi.contains_xy([[10, 0], [10, 9]]).tolist()
        [True, False]
    """

    __slots__ = ("_geometry",)

    def __init__(self, geometry: Polygon | MultiPolygon) -> None:
        if isinstance(geometry, Polygon):
            geometry = MultiPolygon([geometry]) if not geometry.is_empty else MultiPolygon()
        if not isinstance(geometry, MultiPolygon):
            raise TypeError(f"ROI must be a Polygon or MultiPolygon, got {geometry.geom_type}")
        shapely.prepare(geometry)
        self._geometry = geometry

    @classmethod
    def from_polygons(
        cls, exteriors: Sequence[ArrayLike], holes: Sequence[Sequence[ArrayLike]] | None = None
    ) -> RoiMap:
        """From exterior rings (each K×2) and, optionally, the holes of each."""
        polys = []
        for i, ring in enumerate(exteriors):
            inner = holes[i] if holes is not None else []
            polys.append(Polygon(np.asarray(ring, dtype=np.float64), [np.asarray(h, float) for h in inner]))
        return cls(MultiPolygon(polys))

    @classmethod
    def from_geojson(cls, data: dict[str, Any] | str) -> RoiMap:
        obj = json.loads(data) if isinstance(data, str) else data
        geometry = shape(obj)
        if not isinstance(geometry, (Polygon, MultiPolygon)):
            raise ValueError(f"ROI GeoJSON must be a Polygon or MultiPolygon, got {geometry.geom_type}")
        return cls(geometry)

    def to_geojson(self) -> dict[str, Any]:
        """A GeoJSON ``MultiPolygon`` mapping (coordinates are LiDAR-frame metres)."""
        return json.loads(json.dumps(mapping(self._geometry)))

    @property
    def geometry(self) -> MultiPolygon:
        return self._geometry

    @property
    def area(self) -> float:
        return float(self._geometry.area)

    def __len__(self) -> int:
        return len(self._geometry.geoms)

    def __repr__(self) -> str:
        return f"RoiMap(polygons={len(self)}, area={self.area:.1f} m²)"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RoiMap):
            return NotImplemented
        return bool(shapely.equals_exact(self._geometry, other._geometry, tolerance=0.0))

    __hash__ = None  # type: ignore[assignment]

    def contains_xy(self, xy: ArrayLike) -> NDArray[np.bool_]:
        """Mask of points (N×2 or N×≥2; only x, y are used) inside the drivable area (boundary included)."""
        p = np.asarray(xy, dtype=np.float64)
        if p.size == 0:
            return np.zeros(0, dtype=bool)
        return np.asarray(shapely.intersects_xy(self._geometry, p[:, 0], p[:, 1]), dtype=bool)

    def transformed(self, matrix: ArrayLike) -> RoiMap:
        """The polygons moved by a 2D affine transform given as a 3×3 (or 4×4, x–y part used) matrix."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape == (4, 4):
            m = m[np.ix_([0, 1, 3], [0, 1, 3])]
        a, b, d, e, xoff, yoff = m[0, 0], m[0, 1], m[1, 0], m[1, 1], m[0, 2], m[1, 2]
        return RoiMap(shapely.affinity.affine_transform(self._geometry, [a, b, d, e, xoff, yoff]))
