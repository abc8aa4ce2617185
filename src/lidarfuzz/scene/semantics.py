"""Point-level semantic classes: the values of a cloud's ``label`` channel.

The list follows SemanticKITTI's spirit (road, sidewalk, building, vegetation, vehicles,
people) at the granularity the simulator produces; the value is the index in
:data:`SEMANTIC_CLASSES`. Operators use it to tell ground from objects and to label the
points they add; data from other sources may map their own ids onto it.
"""

from __future__ import annotations

#: Point-level classes written to the ``label`` channel (the index is the value).
SEMANTIC_CLASSES: tuple[str, ...] = (
    "unlabelled", "road", "lane-marking", "sidewalk", "terrain", "building", "wall", "vegetation",
    "trunk", "pole", "traffic-sign", "car", "van", "truck", "pedestrian", "cyclist", "other-ground",
)
SEMANTIC_ID: dict[str, int] = {name: i for i, name in enumerate(SEMANTIC_CLASSES)}

#: Classes whose points are the ground surface.
GROUND_CLASSES: tuple[str, ...] = ("road", "lane-marking", "sidewalk", "terrain", "other-ground")

#: KITTI object class → semantic class of its points.
OBJECT_SEMANTIC: dict[str, str] = {
    "Car": "car", "Van": "van", "Truck": "truck", "Pedestrian": "pedestrian", "Cyclist": "cyclist",
}
