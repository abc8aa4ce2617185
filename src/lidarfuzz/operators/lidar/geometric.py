"""Geometric operators: the whole scene moved, labels moved with it.

Points, boxes (heading included) and the drivable-area map move together; the camera
calibration stays, so each label is re-derived from it as the simulator labels a box
(``relabel_in_image``): alpha, the 2D box clipped to the image and the truncation (the share
of the box outside the image). KITTI labels exist only in the camera's view, so a box moved
out of the image gets truncation 1 and no 2D box, and the devkit ignores it rather than
counting an object no label could have (a perfect detector keeps AP 100 at any rotation).
The transform T is exposed, so detections on the follow-up can be compared with T applied
to detections on the source (the equivariance relation).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import (
    Config,
    NonNegativeRange,
    Operator,
    Params,
    PositiveRange,
    Relation,
    Target,
    uniform,
)
from lidarfuzz.operators.lidar.common import relabel_in_image, rigid_transform
from lidarfuzz.scene.scene import Scene

Range = tuple[float, float]
GEOMETRY = frozenset({Target.POINTS, Target.BOXES, Target.MAP})


class RotationConfig(Config):
    angle_range: NonNegativeRange = Field((0.0, 180.0), description="rotation magnitude, degrees")
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
    get new alpha, 2D boxes and truncation from the unchanged camera (truncation 1 and no 2D
    box for a box turned out of the image).

    Thesis, section 3.2.3 (1): RAR rotates the cloud about the z axis by a random angle "in the
    range 0 to 180 degrees" and modifies the labels to match. The default config is that range
    (with either sign, ``both_directions``); the severity table splits it into bands."""

    name = "rotate_z"
    aliases = ("RAR",)
    family = "geometric"
    relation = Relation.EQUIVARIANT
    harmless_up_to = 5
    harmless_because = ("a spinning LiDAR sees the same street turned: the ROI turns with it and every object "
                        "keeps its points")
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
    harmless_up_to = 5
    harmless_because = ("mounts differ by up to half a metre between a car and a van, and a system that finds its "
                        "ground should not care; no object changes shape")
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


class TranslationConfig(Config):
    x_range: Range = Field((-1.0, 1.0), description="metres")
    y_range: Range = Field((-1.0, 1.0), description="metres")
    z_range: Range = Field((0.0, 0.0), description="metres")


class TranslationParams(Params):
    offset: tuple[float, float, float]

    def is_identity(self) -> bool:
        return not any(self.offset)


class GlobalTranslate(Operator[Scene, TranslationConfig, TranslationParams]):
    """The whole scene shifted (a sensor mounted elsewhere on the car): points, boxes and the ROI
    move by one offset; labels get new alpha, 2D boxes and truncation from the unchanged camera."""

    name = "global_translate"
    family = "geometric"
    relation = Relation.EQUIVARIANT
    harmless_up_to = 2
    harmless_because = "the sensor moved by up to 0.5 m sees the objects from almost the same place"
    targets = GEOMETRY
    ConfigModel = TranslationConfig
    ParamsModel = TranslationParams
    IDENTITY: ClassVar = {"x_range": (0.0, 0.0), "y_range": (0.0, 0.0), "z_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"x_range": (-d, d), "y_range": (-d, d), "z_range": (-d / 5, d / 5)} for s, d in
                            [(1, 0.2), (2, 0.5), (3, 1.0), (4, 2.0), (5, 4.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> TranslationParams:
        c = self.config
        return TranslationParams(offset=(uniform(rng, c.x_range), uniform(rng, c.y_range), uniform(rng, c.z_range)))

    def transform(self, params: TranslationParams) -> NDArray[np.float64]:
        m = np.eye(4)
        m[:3, 3] = params.offset
        return m

    def apply(self, sample: Scene, params: TranslationParams) -> Scene:
        if params.is_identity():
            return sample
        return rigid_transform(sample, self.transform(params))


class ScaleConfig(Config):
    factor_range: PositiveRange = Field((0.95, 1.05), description="uniform scale about the sensor")


class ScaleParams(Params):
    factor: float = Field(gt=0)

    def is_identity(self) -> bool:
        return self.factor == 1.0


class GlobalScale(Operator[Scene, ScaleConfig, ScaleParams]):
    """The whole scene scaled about the sensor (the standard augmentation; objects change size,
    so it tests scale robustness rather than a physical effect): points, box centres and sizes,
    and the ROI scale together."""

    name = "global_scale"
    family = "geometric"
    relation = Relation.EQUIVARIANT
    harmless_up_to = 1
    harmless_because = "a world up to 2 % larger or smaller keeps every object inside its class's sizes"
    targets = GEOMETRY
    ConfigModel = ScaleConfig
    ParamsModel = ScaleParams
    IDENTITY: ClassVar = {"factor_range": (1.0, 1.0)}
    SEVERITIES: ClassVar = {s: {"factor_range": (1 - d, 1 + d)} for s, d in
                            [(1, 0.02), (2, 0.05), (3, 0.1), (4, 0.15), (5, 0.25)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ScaleParams:
        return ScaleParams(factor=uniform(rng, self.config.factor_range))

    def transform(self, params: ScaleParams) -> NDArray[np.float64]:
        m = np.eye(4)
        m[:3, :3] *= params.factor
        return m

    def apply(self, sample: Scene, params: ScaleParams) -> Scene:
        if params.is_identity():
            return sample
        f = params.factor
        points = sample.points.with_xyz((sample.points.xyz.astype(np.float64) * f).astype(np.float32))
        boxes = sample.boxes
        if len(boxes):
            boxes = relabel_in_image(boxes.with_geometry(centers=boxes.centers * f, sizes=boxes.sizes * f),
                                     sample.calib)
        roi = sample.roi.transformed(self.transform(params)) if sample.roi is not None else None
        return sample.replace(points=points, boxes=boxes, roi=roi)


class FlipConfig(Config):
    probability: float = Field(1.0, ge=0, le=1, description="chance that the mirror is applied")


class FlipParams(Params):
    flipped: bool

    def is_identity(self) -> bool:
        return not self.flipped


class GlobalFlip(Operator[Scene, FlipConfig, FlipParams]):
    """The scene mirrored left–right (y → −y, headings mirrored): left-hand traffic from
    right-hand data. Points, boxes and the ROI mirror; other channels are kept as they are
    (a mirrored sweep would run anticlockwise: ``time`` is not reversed)."""

    name = "global_flip"
    family = "geometric"
    deterministic = True
    relation = Relation.EQUIVARIANT
    harmless_up_to = 5
    harmless_because = "the mirrored street (left-hand traffic) holds the same objects with the same points"
    targets = GEOMETRY
    ConfigModel = FlipConfig
    ParamsModel = FlipParams
    IDENTITY: ClassVar = {"probability": 0.0}
    SEVERITIES: ClassVar = {s: {"probability": 1.0} for s in range(1, 6)}

    def sample(self, rng: np.random.Generator, sample: Scene) -> FlipParams:
        return FlipParams(flipped=bool(rng.random() < self.config.probability))

    def transform(self, params: FlipParams) -> NDArray[np.float64]:
        return np.diag([1.0, -1.0 if params.flipped else 1.0, 1.0, 1.0])

    def apply(self, sample: Scene, params: FlipParams) -> Scene:
        if params.is_identity():
            return sample
        xyz = sample.points.xyz.copy()
        xyz[:, 1] = -xyz[:, 1]
        boxes = sample.boxes
        if len(boxes):
            centers = boxes.centers.copy()
            centers[:, 1] = -centers[:, 1]
            boxes = relabel_in_image(boxes.with_geometry(centers=centers, yaw=-boxes.yaw), sample.calib)
        roi = sample.roi.transformed(self.transform(params)) if sample.roi is not None else None
        return sample.replace(points=sample.points.with_xyz(xyz), boxes=boxes, roi=roi)
