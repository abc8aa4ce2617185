"""Affine transformations of DeepTest: translation, scale, shear and rotation (Table 2's matrices).

Each builds its 2×3 matrix as Table 2 gives it, in pixel coordinates (x to the right, y down, the
origin at the centre of the top-left pixel; rotation and scale about the image centre, i.e.
Table 2's matrix between a shift to the centre and back), and warps with :func:`cv2.warpAffine` (bilinear
interpolation, constant black border: what the moved picture does not cover is black, as in
DeepTest's OpenCV calls). The depth map moves with the pixels (nearest neighbour, ``inf`` where
uncovered) and the camera matrix becomes ``A·K`` (:func:`~lidarfuzz.operators.camera.common.warp_affine`);
the steering label is kept.

Relation: DeepTest assumes that the steering label survives these transformations, so they are
declared *invariant* — but only for small parameters (``harmless_up_to`` 1): a camera that is
shifted, zoomed, sheared or rolled a lot sees a road whose correct steering angle is no longer
the recorded one (a horizontal shift of 100 pixels is a yaw of several degrees; a rotation of 30°
tilts the lane lines the network reads the curve from).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import Config, Operator, Params, PositiveRange, Relation, uniform
from lidarfuzz.operators.camera.common import CAMERA, IMAGE, Range, table_pairs, warp_affine
from lidarfuzz.scene.image import ImageSample

F64 = NDArray[np.float64]


# --------------------------------------------------------------------------- translation
#: Table 4, translation (tx, ty): (10, 10) to (100, 100) with step (10, 10), pixels.
TRANSLATIONS = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0]


class TranslationConfig(Config):
    tx_range: Range = Field((10.0, 20.0), description="shift to the right, pixels (negative: left); "
                                                      "rounded to whole pixels")
    ty_range: Range | None = Field(None, description="shift downwards, pixels; None: ty = tx (Table 4's diagonal)")


class TranslationParams(Params):
    tx: float
    ty: float

    def is_identity(self) -> bool:
        return self.tx == 0 and self.ty == 0


class Translation(Operator[ImageSample, TranslationConfig, TranslationParams]):
    """The picture shifted by (tx, ty) pixels: Table 2's ``[[1, 0, tx], [0, 1, ty]]``.

    Table 4: (tx, ty) = (10, 10), (20, 20), …, (100, 100). Severity s draws t uniformly between the
    (2s−1)-th and 2s-th values and shifts by (t, t): 1: 10–20, 2: 30–40, 3: 50–60, 4: 70–80,
    5: 90–100 pixels; ``ty_range`` draws ty apart. Shifts are rounded to whole pixels (so the
    moved picture stays sharp); the uncovered border (left and top columns/rows) is black.
    Invariant up to severity 1 (see the module docstring); moves depth and K with the pixels.
    """

    name = "image_translation"
    aliases = ("translation",)
    family = "affine"
    modality = CAMERA
    relation = Relation.INVARIANT
    harmless_up_to = 1
    harmless_because = ("a shift of at most 20 pixels keeps the road in view and changes the camera's heading by "
                        "about a degree, within the steering label's tolerance")
    targets = IMAGE
    ConfigModel = TranslationConfig
    ParamsModel = TranslationParams
    IDENTITY: ClassVar = {"tx_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"tx_range": r} for s, r in table_pairs(TRANSLATIONS).items()}

    def sample(self, rng: np.random.Generator, sample: ImageSample) -> TranslationParams:
        tx = float(round(uniform(rng, self.config.tx_range)))
        ty = tx if self.config.ty_range is None else float(round(uniform(rng, self.config.ty_range)))
        return TranslationParams(tx=tx, ty=ty)

    @staticmethod
    def matrix(params: TranslationParams) -> F64:
        return np.array([[1.0, 0.0, params.tx], [0.0, 1.0, params.ty]])

    def apply(self, sample: ImageSample, params: TranslationParams) -> ImageSample:
        return sample if params.is_identity() else warp_affine(sample, self.matrix(params))


# --------------------------------------------------------------------------- scale
#: Table 4, scale (sx, sy): (1.5, 1.5) to (6, 6) with step (0.5, 0.5).
SCALES = [1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0]


class ScaleConfig(Config):
    factor_range: PositiveRange = Field((1.5, 2.0), description="zoom factor (sx = sy; below 1: smaller)")
    about: Literal["centre", "origin"] = Field("centre", description="fixed point: the image centre, or the "
                                               "top-left pixel (Table 2's matrix as printed)")


class ScaleParams(Params):
    factor: float = Field(gt=0)
    about: Literal["centre", "origin"] = "centre"

    def is_identity(self) -> bool:
        return self.factor == 1


class Scale(Operator[ImageSample, ScaleConfig, ScaleParams]):
    """The picture zoomed by s: Table 2's ``[[sx, 0, 0], [0, sy, 0]]`` with sx = sy = s, about the
    image centre ((W−1)/2, (H−1)/2) by default — as the rotation turns about it — or, with
    ``about: origin``, about the top-left pixel as Table 2 prints it. About the origin even the
    mildest zoom keeps only the top-left 1/1.5 of the picture: on a frame whose horizon is
    mid-height (the built-in world's) that is sky and little road, and the steering label
    cannot be meant to survive it; about the centre the road ahead stays in view, as through a
    longer lens.

    Table 4: (sx, sy) = (1.5, 1.5), (2, 2), …, (6, 6). Severity s draws the factor uniformly between
    the (2s−1)-th and 2s-th values: 1: 1.5–2, 2: 2.5–3, 3: 3.5–4, 4: 4.5–5, 5: 5.5–6. Bilinear
    interpolation; a factor below 1 leaves a black border. Invariant up to severity 1 (see the
    module docstring), as DeepTest assumes, about the centre; a config ``about: origin`` is
    checked at no severity (:meth:`harmless`). Moves depth and K with the pixels.
    """

    name = "image_scale"
    aliases = ("scale",)
    family = "affine"
    modality = CAMERA
    relation = Relation.INVARIANT
    harmless_up_to = 1
    harmless_because = ("a zoom of at most 2x about the centre keeps the road ahead in view, as a longer lens "
                        "would (DeepTest's mildest scaling)")
    targets = IMAGE
    ConfigModel = ScaleConfig
    ParamsModel = ScaleParams
    IDENTITY: ClassVar = {"factor_range": (1.0, 1.0)}
    SEVERITIES: ClassVar = {s: {"factor_range": r} for s, r in table_pairs(SCALES).items()}

    def harmless(self) -> bool:
        """As the severity table says, about the centre only (about the origin the road leaves the picture)."""
        return super().harmless() and (self.config.about == "centre" or self.config.factor_range == (1.0, 1.0))

    def sample(self, rng: np.random.Generator, sample: ImageSample) -> ScaleParams:
        return ScaleParams(factor=uniform(rng, self.config.factor_range), about=self.config.about)

    @staticmethod
    def matrix(params: ScaleParams, shape: tuple[int, int]) -> F64:
        s = params.factor
        m = np.array([[s, 0.0, 0.0], [0.0, s, 0.0]])
        if params.about == "centre":
            cy, cx = (shape[0] - 1) / 2, (shape[1] - 1) / 2
            m[:, 2] = [cx * (1 - s), cy * (1 - s)]
        return m

    def apply(self, sample: ImageSample, params: ScaleParams) -> ImageSample:
        return sample if params.is_identity() else warp_affine(sample, self.matrix(params, sample.shape))


# --------------------------------------------------------------------------- shear
#: Table 4, shear (sx, sy): (−1.0, 0) to (−0.1, 0) with step (0.1, 0); mildest first.
SHEARS = [-0.1, -0.2, -0.3, -0.4, -0.5, -0.6, -0.7, -0.8, -0.9, -1.0]


class ShearConfig(Config):
    sx_range: Range = Field((-0.2, -0.1), description="horizontal shear: x' = x + sx·y")
    sy_range: Range = Field((0.0, 0.0), description="vertical shear: y' = y + sy·x (0 in Table 4)")


class ShearParams(Params):
    sx: float
    sy: float = 0.0

    def is_identity(self) -> bool:
        return self.sx == 0 and self.sy == 0


class Shear(Operator[ImageSample, ShearConfig, ShearParams]):
    """The picture sheared: Table 2's ``[[1, sx, 0], [sy, 1, 0]]`` about the top-left pixel, so each
    row y moves sideways by sx·y pixels (with Table 4's negative sx the lower rows move left).

    Table 4: (sx, sy) = (−0.1, 0), (−0.2, 0), …, (−1.0, 0). Severity s draws sx uniformly between the
    (2s−1)-th and 2s-th values: 1: −0.1 to −0.2, 2: −0.3 to −0.4, …, 5: −0.9 to −1.0. Bilinear
    interpolation, black where uncovered. Invariant up to severity 1 (see the module docstring);
    moves depth and K with the pixels.
    """

    name = "image_shear"
    aliases = ("shear",)
    family = "affine"
    modality = CAMERA
    relation = Relation.INVARIANT
    harmless_up_to = 1
    harmless_because = ("a shear of at most 0.2 slants the picture a little (DeepTest's mildest); the label is "
                        "assumed kept, as the paper does")
    targets = IMAGE
    ConfigModel = ShearConfig
    ParamsModel = ShearParams
    IDENTITY: ClassVar = {"sx_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"sx_range": r} for s, r in table_pairs(SHEARS).items()}

    def sample(self, rng: np.random.Generator, sample: ImageSample) -> ShearParams:
        return ShearParams(sx=uniform(rng, self.config.sx_range), sy=uniform(rng, self.config.sy_range))

    @staticmethod
    def matrix(params: ShearParams) -> F64:
        return np.array([[1.0, params.sx, 0.0], [params.sy, 1.0, 0.0]])

    def apply(self, sample: ImageSample, params: ShearParams) -> ImageSample:
        return sample if params.is_identity() else warp_affine(sample, self.matrix(params))


# --------------------------------------------------------------------------- rotation
#: Table 4, rotation q (degrees): 3 to 30 with step 3.
ROTATIONS = [3.0, 6.0, 9.0, 12.0, 15.0, 18.0, 21.0, 24.0, 27.0, 30.0]


class RotationConfig(Config):
    angle_range: Range = Field((3.0, 6.0), description="rotation q, degrees; positive turns the picture clockwise "
                                                       "on screen (negative: anticlockwise)")


class RotationParams(Params):
    angle: float

    def is_identity(self) -> bool:
        return self.angle == 0


class Rotation(Operator[ImageSample, RotationConfig, RotationParams]):
    """The picture rotated by q about its centre: Table 2's ``[[cos q, −sin q], [sin q, cos q]]``
    conjugated by a shift to the centre of the image ((W−1)/2, (H−1)/2, the middle of the pixel grid,
    so a 90° turn of a square image maps pixels onto pixels). In image coordinates (y down) a
    positive q turns the picture clockwise on screen, a camera roll to the left.
    (:func:`cv2.getRotationMatrix2D` uses the opposite sign.)

    Table 4: q = 3°, 6°, …, 30°. Severity s draws q uniformly between the (2s−1)-th and 2s-th
    values: 1: 3–6°, 2: 9–12°, 3: 15–18°, 4: 21–24°, 5: 27–30°. Bilinear interpolation, black
    corners. Invariant up to severity 1 (see the module docstring: a large rotation changes what
    the correct steering angle is); moves depth and K with the pixels.
    """

    name = "image_rotation"
    aliases = ("rotation",)
    family = "affine"
    modality = CAMERA
    relation = Relation.INVARIANT
    harmless_up_to = 1
    harmless_because = "a roll of at most 6 degrees tilts the horizon but leaves the curve of the road as it was"
    targets = IMAGE
    ConfigModel = RotationConfig
    ParamsModel = RotationParams
    IDENTITY: ClassVar = {"angle_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"angle_range": r} for s, r in table_pairs(ROTATIONS).items()}

    def sample(self, rng: np.random.Generator, sample: ImageSample) -> RotationParams:
        return RotationParams(angle=uniform(rng, self.config.angle_range))

    @staticmethod
    def matrix(params: RotationParams, shape: tuple[int, int]) -> F64:
        q = math.radians(params.angle)
        c, s = math.cos(q), math.sin(q)
        cy, cx = (shape[0] - 1) / 2, (shape[1] - 1) / 2
        # p' = R (p − centre) + centre
        return np.array([[c, -s, cx - c * cx + s * cy], [s, c, cy - s * cx - c * cy]])

    def apply(self, sample: ImageSample, params: RotationParams) -> ImageSample:
        return sample if params.is_identity() else warp_affine(sample, self.matrix(params, sample.shape))
