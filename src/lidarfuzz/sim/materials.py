"""Surface materials (near-infrared reflectivity) and the semantic classes of points.

Reflectivities are diffuse reflectances at 905 nm, the wavelength of Velodyne and
Ouster sensors, rounded from published material measurements: asphalt is dark,
vegetation is bright in the near infrared, retro-reflective signs and plates are the
brightest, glass returns little. Each generated point carries its semantic class in
the ``label`` channel (index into :data:`SEMANTIC_CLASSES`).
"""

from __future__ import annotations

from dataclasses import dataclass

from lidarfuzz.scene.semantics import OBJECT_SEMANTIC, SEMANTIC_CLASSES, SEMANTIC_ID


@dataclass(frozen=True)
class Material:
    """A surface: diffuse reflectance at 905 nm, the semantic class of its points, and the
    probability that a beam hitting it returns at all (glass mostly transmits or mirrors the
    beam away: windows show as holes in real scans)."""

    name: str
    reflectivity: float
    semantic: str
    returns: float = 1.0


_MATERIALS = (
    Material("asphalt", 0.12, "road"),
    Material("road-paint", 0.55, "lane-marking"),
    Material("paving", 0.30, "sidewalk"),
    Material("kerb", 0.35, "sidewalk"),
    Material("grass", 0.42, "terrain"),
    Material("pavement", 0.28, "other-ground"),
    Material("soil", 0.25, "terrain"),
    Material("plaster", 0.50, "building"),
    Material("brick", 0.32, "building"),
    Material("window", 0.06, "building", returns=0.3),
    Material("concrete", 0.38, "wall"),
    Material("fence", 0.25, "wall"),
    Material("foliage", 0.55, "vegetation"),
    Material("hedge", 0.45, "vegetation"),
    Material("bark", 0.22, "trunk"),
    Material("metal", 0.40, "pole"),
    Material("sign", 0.90, "traffic-sign"),
    Material("tyre", 0.04, "car"),
    Material("car-glass", 0.05, "car", returns=0.3),
    Material("plate", 0.85, "car"),
    Material("light", 0.75, "car"),
    Material("cloth", 0.40, "pedestrian"),
    Material("skin", 0.45, "pedestrian"),
    Material("bike-frame", 0.35, "cyclist"),
)
#: Materials by name; ``paint`` (vehicle body colour) is per object, see :data:`PAINT_REFLECTIVITY`.
MATERIALS: dict[str, Material] = {m.name: m for m in _MATERIALS}

#: Vehicle paint from black (0.05) to white (0.75): sampled per vehicle.
PAINT_REFLECTIVITY = (0.05, 0.75)

def material(name: str) -> Material:
    try:
        return MATERIALS[name]
    except KeyError:
        raise ValueError(f"unknown material {name!r}; known: {', '.join(MATERIALS)}") from None


__all__ = [
    "MATERIALS", "OBJECT_SEMANTIC", "PAINT_REFLECTIVITY", "SEMANTIC_CLASSES", "SEMANTIC_ID", "Material", "material",
]
