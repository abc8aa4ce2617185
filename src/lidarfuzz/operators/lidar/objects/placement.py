"""An object inserted at a chosen range and bearing from the sensor."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import Config, NonNegativeRange
from lidarfuzz.operators.base import uniform as draw_uniform
from lidarfuzz.operators.lidar.objects.insertion import ObjectInsertion, ObjectInsertionParams, _pick
from lidarfuzz.operators.lidar.objects.support import Range

#: An entry is placed no nearer than its source range over this: farther, the z-buffer thins it to
#: the frame's beams as a real scan would; much nearer, it would be sparser than a real object.
NEAREST_RATIO = 1.25


class ObjectPlacementConfig(Config):
    library: str | None = Field(None, description="path of an ObjectLibrary .npz; None: the cached simulator one")
    count_range: NonNegativeRange = Field((1, 1), description="objects placed")
    classes: tuple[str, ...] | None = Field(None, description="only library entries of these classes")
    distance_range: NonNegativeRange = Field(
        (10.0, 30.0), description="range of the object's centre from the sensor, metres")
    bearing_range: Range = Field((-30.0, 30.0), description="bearing of the object's centre, degrees counter-"
                                                            "clockwise from straight ahead (+x; 90 is left)")
    attempts: int = Field(40, ge=1, description="places tried per object before giving up")
    min_points: int = Field(5, ge=1, description="returns the sensor must get from a placed object, or the place "
                                                 "is refused")
    in_camera_view: bool | None = Field(None, description="only places the camera sees (at most 15 % cut off by "
                                                          "the image); None: when the frame has a calibration")


class ObjectPlacement(ObjectInsertion):
    """An object that was not there, placed at a chosen range and bearing from the sensor (a car
    parked 8 m ahead, a pedestrian 30 m off to the left): :class:`ObjectInsertion` with the place
    drawn from ``distance_range`` (metres) and ``bearing_range`` (degrees, 0 straight ahead,
    positive to the left) instead of near the library entry's source range.

    Everything else is the insertion's (see ``object_insertion``): the entry's heading shows the
    sensor the same side as in its source, its box stands on the local ground, the place must be on
    the drivable area when the frame has an ROI map, clear of other boxes and of anything standing
    there, in the camera's view when labels are the camera's, and seen by at least ``min_points``
    returns; occlusion both ways with the range-image z-buffer (background behind the object
    removed, the object's points behind nearer returns removed, thinned to the frame's beams).
    A place that fails is redrawn up to ``attempts`` times; ``reason`` in the params says why
    fewer objects were placed than drawn.

    Point density: the entry is drawn among those captured no farther than 1.25 times the wanted
    range (the insertion's own tolerance): placed farther than its source, the z-buffer thins it to
    the frame's beams as a real scan would; placed much nearer, it would be sparser than a real
    object there. When no entry of the wanted classes was captured near enough, any entry is used
    (then sparser than a real object).

    Relation: degrading, as for insertion (a new object may hide others); a correct detector
    should find the placed object where it has the points a real one would."""

    name = "object_placement"
    aliases = ("OBJ_PLACE",)
    family = "object"
    relation = ObjectInsertion.relation
    targets = ObjectInsertion.targets
    harmless_up_to: ClassVar[int] = 5
    harmless_because: ClassVar[str] = ("a placed object takes no point from the others; an object it hides or "
                                       "crowds loses its evidence and is not checked")
    ConfigModel = ObjectPlacementConfig  # type: ignore[assignment]  # its own fields, read through hooks
    ParamsModel = ObjectInsertionParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    # One object, nearer with severity: a near object hides more of the scene behind it.
    SEVERITIES: ClassVar = {s: {"distance_range": (lo, hi)} for s, lo, hi in
                            [(1, 30.0, 40.0), (2, 20.0, 30.0), (3, 12.0, 20.0), (4, 8.0, 12.0), (5, 5.0, 8.0)]}

    def _azimuths_deg(self) -> tuple[float, float]:
        return self.config.bearing_range  # type: ignore[attr-defined, no-any-return]

    def _draw_place(self, rng: np.random.Generator, entries: NDArray[np.intp], lo: float,
                    hi: float) -> tuple[int, float, float]:
        distance = draw_uniform(rng, self.config.distance_range)  # type: ignore[attr-defined]
        dense_enough = entries[self.library.ranges[entries] <= NEAREST_RATIO * distance]
        entry = int(_pick(rng, dense_enough if len(dense_enough) else entries))
        return entry, distance, draw_uniform(rng, (lo, hi))
