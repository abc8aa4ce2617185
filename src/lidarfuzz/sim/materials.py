"""Surface materials (near-infrared reflectivity) and the semantic classes of points.

Reflectivities are diffuse reflectances at 905 nm, the wavelength of Velodyne and
Ouster sensors, rounded from published material measurements: asphalt is dark,
vegetation is bright in the near infrared, retro-reflective signs and plates are the
brightest, glass returns little. Each generated point carries its semantic class in
the ``label`` channel (index into :data:`SEMANTIC_CLASSES`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarfuzz.scene.semantics import OBJECT_SEMANTIC, SEMANTIC_CLASSES, SEMANTIC_ID


@dataclass(frozen=True)
class Material:
    """A surface: diffuse reflectance at 905 nm, the semantic class of its points, the
    probability that a beam hitting it returns at all (glass mostly transmits or mirrors the
    beam away: windows show as holes in real scans), and its gloss: the share of the beam a
    glossy surface mirrors away instead of scattering back when hit at a grazing angle (see
    :class:`~lidarfuzz.sim.sensor.Dropouts`), so glossy car bodies and glass lose returns at
    grazing incidence as they do in real scans."""

    name: str
    reflectivity: float
    semantic: str
    returns: float = 1.0
    gloss: float = 0.0


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
    Material("window", 0.04, "building", returns=0.3, gloss=1.0),
    Material("concrete", 0.38, "wall"),
    Material("fence", 0.25, "wall"),
    Material("foliage", 0.55, "vegetation"),
    Material("hedge", 0.45, "vegetation"),
    Material("bark", 0.22, "trunk"),
    Material("metal", 0.40, "pole"),
    Material("sign", 0.90, "traffic-sign"),
    Material("tyre", 0.03, "car"),
    Material("car-glass", 0.03, "car", returns=0.3, gloss=1.0),
    Material("plate", 0.85, "car"),
    Material("light", 0.75, "car"),
    Material("cloth", 0.40, "pedestrian"),
    Material("skin", 0.45, "pedestrian"),
    Material("bike-frame", 0.35, "cyclist"),
)
#: Materials by name; ``paint`` (vehicle body colour) is per object, see :data:`PAINT_REFLECTIVITY`.
MATERIALS: dict[str, Material] = {m.name: m for m in _MATERIALS}
#: Each material's index (a mesh stores it per face, for the camera's visible colours); the
#: object's own paint (:data:`PAINT_MATERIAL`) is the last.
MATERIAL_ID: dict[str, int] = {m.name: i for i, m in enumerate(_MATERIALS)}
PAINT_MATERIAL = len(_MATERIALS)

#: Vehicle paint from black (0.05: carbon-black clear-coated paint reflects 3–8 % diffusely at
#: 905 nm) to white (0.75).
PAINT_REFLECTIVITY = (0.05, 0.75)
#: Paint drawn per vehicle from the colours cars have (global shares, rounded from the paint
#: makers' yearly colour-popularity reports: white ~35 %, black ~20 %, grey ~18 %, silver
#: ~12 %, other colours ~15 %), each a range of reflectivity at 905 nm: (share, low, high).
PAINT_COLOURS: tuple[tuple[float, float, float], ...] = (
    (0.35, 0.50, 0.75),  # white
    (0.20, 0.05, 0.08),  # black
    (0.18, 0.08, 0.20),  # grey
    (0.12, 0.30, 0.50),  # silver
    (0.15, 0.15, 0.50),  # red, blue and the rest
)


def sample_paint(rng: np.random.Generator) -> float:
    """A vehicle's paint reflectivity (:data:`PAINT_COLOURS`); two draws whatever the colour."""
    pick, within = rng.random(2)
    shares = np.cumsum([c[0] for c in PAINT_COLOURS])
    _, low, high = PAINT_COLOURS[min(int(np.searchsorted(shares, pick * shares[-1])), len(PAINT_COLOURS) - 1)]
    return float(low + (high - low) * within)

#: Vehicle paint is clear-coated: half the beam is mirrored at grazing incidence.
PAINT_GLOSS = 0.5

def material(name: str) -> Material:
    try:
        return MATERIALS[name]
    except KeyError:
        raise ValueError(f"unknown material {name!r}; known: {', '.join(MATERIALS)}") from None


__all__ = [
    "MATERIALS", "MATERIAL_ID", "OBJECT_SEMANTIC", "PAINT_COLOURS", "PAINT_GLOSS", "PAINT_MATERIAL",
    "PAINT_REFLECTIVITY", "SEMANTIC_CLASSES", "SEMANTIC_ID", "Material", "material", "sample_paint",
]
