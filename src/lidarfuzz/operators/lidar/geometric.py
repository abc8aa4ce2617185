"""Geometric operators: the whole scene moved, labels moved with it.

Points, boxes (heading included) and the drivable-area map move together; the camera
calibration stays, so each label's alpha and 2D box are recomputed by projection. The
transform T is exposed, so detections on the follow-up can be compared with T applied
to detections on the source (the equivariance relation).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import Config, Operator, Params, Relation, Target, uniform
from lidarfuzz.operators.lidar.common import rigid_transform
from lidarfuzz.scene.scene import Scene

Range = tuple[float, float]
GEOMETRY = frozenset({Target.POINTS, Target.BOXES, Target.MAP})


class RotationConfig(Config):
    angle_range: Range = Field((0.0, 180.0), description="rotation magnitude, degrees")
    both_directions: bool = Field(True, description="draw the sign too (counter-clockwise or clockwise)")


class RotationParams(Params):
    angle: float = Field(description="degrees, counter-clockwise about the sensor's z axis")

    def is_identity(self) -> bool:
        return self.angle == 0


def _rotation(angle_deg: float) -> NDArray[np.float64]:
    a = np.deg2rad(angle_deg)
    m = np.eye(4)
    m[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return m


class RotateZ(Operator[Scene, RotationConfig, RotationParams]):
    """The scene rotated about the sensor's vertical axis (the thesis's RAR, 0–180°): the same
    world seen with the car turned. Points, boxes (headings too) and the ROI rotate; labels
    get new alpha and 2D boxes from the unchanged camera."""

    name = "rotate_z"
    aliases = ("RAR",)
    family = "geometric"
    relation = Relation.EQUIVARIANT
    targets = GEOMETRY
    ConfigModel = RotationConfig
    ParamsModel = RotationParams
    IDENTITY: ClassVar = {"angle_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"angle_range": (a, b)} for s, a, b in
                            [(1, 0.0, 5.0), (2, 5.0, 15.0), (3, 15.0, 45.0), (4, 45.0, 90.0), (5, 90.0, 180.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> RotationParams:
        angle = uniform(rng, self.config.angle_range)
        if self.config.both_directions and rng.random() < 0.5:
            angle = -angle
        return RotationParams(angle=angle)

    def transform(self, params: RotationParams) -> NDArray[np.float64]:
        return _rotation(params.angle)

    def apply(self, sample: Scene, params: RotationParams) -> Scene:
        if params.is_identity():
            return sample
        return rigid_transform(sample, self.transform(params))


class HeightConfig(Config):
    offset_range: Range = Field((-0.3, 0.3), description="z offset, metres")


class HeightParams(Params):
    offset: float

    def is_identity(self) -> bool:
        return self.offset == 0


class HeightShift(Operator[Scene, HeightConfig, HeightParams]):
    """Every point raised by a constant (Neves et al.'s HGT): a sensor mounted higher or lower,
    or a different vehicle. Boxes move with the points; the ROI (2D) is unchanged."""

    name = "height_shift"
    aliases = ("HGT",)
    family = "geometric"
    relation = Relation.EQUIVARIANT
    targets = frozenset({Target.POINTS, Target.BOXES})
    ConfigModel = HeightConfig
    ParamsModel = HeightParams
    IDENTITY: ClassVar = {"offset_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"offset_range": (-d, d)} for s, d in
                            [(1, 0.05), (2, 0.1), (3, 0.2), (4, 0.35), (5, 0.5)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> HeightParams:
        return HeightParams(offset=uniform(rng, self.config.offset_range))

    def transform(self, params: HeightParams) -> NDArray[np.float64]:
        m = np.eye(4)
        m[2, 3] = params.offset
        return m

    def apply(self, sample: Scene, params: HeightParams) -> Scene:
        if params.is_identity():
            return sample
        return rigid_transform(sample, self.transform(params))
