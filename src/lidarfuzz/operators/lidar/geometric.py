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
from lidarfuzz.operators.lidar.common import relabel_in_image
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

#: Points per block of the float64 work: 8192 × 8 bytes per column stays in the L2 cache, where a
#: whole-cloud float64 copy (N×3, 2.7 MB for an HDL-64E frame) would not.
CHUNK = 8192


def transformed_points(points: PointCloud, matrix: NDArray[np.float64], *, offset: bool = True) -> PointCloud:
    """``points`` with x, y, z mapped by the affine 4×4 ``matrix`` in float64 and rounded to
    float32 once, every other channel kept.

    Computes, per output axis i, ``Σ_k x_k · m[i, k] + m[i, 3]`` column by column in blocks of
    :data:`CHUNK` points: each block of rows is copied into the output and transformed there while
    it is in the cache, the input columns it needs widened to float64 once into preallocated
    buffers, so there is neither an N×3 float64 copy nor a BLAS call (a 120k×3 by 3×3 product
    spends more time waking BLAS than multiplying), and the sums are rounded to float32 as they
    are written back. Terms whose coefficient is exactly 0 are skipped: adding
    ±0 to a sum leaves it unchanged, and the offset, added last (even when 0), turns −0 into +0
    as the full product does. A coefficient of exactly 1 multiplies exactly, so an axis the
    matrix leaves alone costs one float64 addition. ``offset=False`` skips the offset column (a
    pure scaling, x · f: then −0 stays −0, as that product leaves it).
    """
    source = points.data
    n = len(source)
    if n == 0:
        return points
    data = np.empty_like(source)
    m = np.asarray(matrix, np.float64)
    block = min(CHUNK, n)
    terms = [[(k, float(m[i, k])) for k in range(3) if m[i, k] != 0.0] for i in range(3)]
    shifts = [float(m[i, 3]) if offset else None for i in range(3)]
    # an axis mapped to itself with no shift: x + 0 in float32 is float32(float64(x) + 0), exactly
    unchanged = [terms[i] == [(i, 1.0)] and not shifts[i] for i in range(3)]
    # the input columns some output needs, each widened to float64 once per block (contiguous:
    # the products are then vectorised, where multiplying the strided float32 column casts it again)
    needed = sorted({k for i in range(3) if not unchanged[i] for k, _ in terms[i]})
    inputs = {k: np.empty(block) for k in needed}
    outputs, term = np.empty((3, block)), np.empty(block)
    for start in range(0, n, block):
        rows = data[start:start + block]
        np.copyto(rows, source[start:start + block])
        count = len(rows)
        for k in needed:
            np.copyto(inputs[k][:count], rows[:, k])
        sums = []
        for i in range(3):
            sums.append(outputs[i, :count])
            if unchanged[i]:
                continue
            if len(terms[i]) == 1 and terms[i][0][1] == 1.0:  # x_k itself: its widened column, no copy
                sums[i] = inputs[terms[i][0][0]][:count]
                continue
            a, t = outputs[i, :count], term[:count]
            if not terms[i]:
                a.fill(0.0)
            for j, (k, coefficient) in enumerate(terms[i]):
                target = a if j == 0 else t
                if coefficient == 1.0:
                    np.copyto(target, inputs[k][:count])
                else:
                    np.multiply(inputs[k][:count], coefficient, out=target)
                if j:
                    a += t
        for i in range(3):  # written once every output of the block is computed from its inputs
            shift = shifts[i]
            if unchanged[i]:
                if offset:
                    rows[:, i] += np.float32(0.0)  # −0 becomes +0, as adding a zero offset in float64 does
            elif shift is not None:
                # the offset added in float64 and the sum rounded to float32 in one pass
                np.add(sums[i], shift, out=rows[:, i], casting="same_kind")
            else:
                rows[:, i] = sums[i]
    return PointCloud(data, points.channels)


def rigid_transform(scene: Scene, matrix: NDArray[np.float64]) -> Scene:
    """Points (:func:`transformed_points`), boxes (heading included) and the ROI moved by a 4×4
    rigid transform about z; labels re-derived from the camera."""
    m = np.asarray(matrix, np.float64)
    points = transformed_points(scene.points, m)
    boxes = scene.boxes
    if len(boxes):
        geometric = boxes.has_geometry
        centers = boxes.centers.copy()
        centers[geometric] = centers[geometric] @ m[:3, :3].T + m[:3, 3]
        yaw = boxes.yaw + np.arctan2(m[1, 0], m[0, 0])
        boxes = relabel_in_image(boxes.with_geometry(centers=centers, yaw=yaw), scene.calib)
    roi = scene.roi.transformed(m) if scene.roi is not None else None
    return scene.replace(points=points, boxes=boxes, roi=roi)

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
        points = transformed_points(sample.points, self.transform(params), offset=False)  # x·f in float64
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
        data = sample.points.data.copy()  # one copy; y negated in place (exact)
        np.negative(data[:, 1], out=data[:, 1])
        boxes = sample.boxes
        if len(boxes):
            centers = boxes.centers.copy()
            centers[:, 1] = -centers[:, 1]
            boxes = relabel_in_image(boxes.with_geometry(centers=centers, yaw=-boxes.yaw), sample.calib)
        roi = sample.roi.transformed(self.transform(params)) if sample.roi is not None else None
        return sample.replace(points=PointCloud(data, sample.points.channels), boxes=boxes, roi=roi)
