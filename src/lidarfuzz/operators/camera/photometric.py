"""Photometric transformations of DeepTest (its "linear" group): brightness and contrast.

Both change pixel values only, with OpenCV's saturating arithmetic (:func:`cv2.addWeighted`:
``saturate_cast<uint8>(α·x + β)``, rounded to the nearest integer and clipped to 0–255, each
channel alike). Nothing moves, so the depth map, the camera matrix and the steering label are kept.
The relation is *invariant*: the road is where it was, so a correct steering system steers the same.
"""

from __future__ import annotations

from typing import ClassVar

import cv2
import numpy as np
from pydantic import Field

from lidarfuzz.operators.base import Config, NonNegativeRange, Operator, Params, Relation, uniform
from lidarfuzz.operators.camera.common import CAMERA, IMAGE, Range, table_pairs
from lidarfuzz.scene.image import ImageSample


def linear(image: np.ndarray, gain: float, bias: float) -> np.ndarray:
    """``gain·x + bias`` per channel, saturated to uint8 by OpenCV."""
    return cv2.addWeighted(np.ascontiguousarray(image), float(gain), image, 0.0, float(bias))


# --------------------------------------------------------------------------- brightness
#: Table 4, brightness β (bias): 10 to 100 with step 10.
BRIGHTNESS_BIASES = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0]


class BrightnessConfig(Config):
    bias_range: Range = Field((10.0, 20.0), description="β added to every channel, 0–255 units (negative: darker)")


class BrightnessParams(Params):
    bias: float = Field(ge=-255, le=255)

    def is_identity(self) -> bool:
        return self.bias == 0


class Brightness(Operator[ImageSample, BrightnessConfig, BrightnessParams]):
    """A brighter (or darker) exposure: ``x + β`` on every channel, saturating at 0 and 255.

    DeepTest Table 4, brightness β (bias): 10, 20, …, 100. Severity s draws β uniformly between the
    (2s−1)-th and 2s-th of those values: 1: 10–20, 2: 30–40, 3: 50–60, 4: 70–80, 5: 90–100;
    ``bias_range`` takes any interval (e.g. ``(30, 30)`` for one table value, negative to darken).
    Changes the image only; depth, camera matrix and label are kept.
    """

    name = "image_brightness"
    aliases = ("brightness",)
    family = "photometric"
    modality = CAMERA
    relation = Relation.INVARIANT
    harmless_up_to = 3
    harmless_because = ("adding at most 60 of 255 saturates little of the road (1 % in the built-in world, 7 % of a "
                        "sunlit KITTI pavement), so its markings and edges stay visible")
    targets = IMAGE
    ConfigModel = BrightnessConfig
    ParamsModel = BrightnessParams
    IDENTITY: ClassVar = {"bias_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"bias_range": r} for s, r in table_pairs(BRIGHTNESS_BIASES).items()}

    def sample(self, rng: np.random.Generator, sample: ImageSample) -> BrightnessParams:
        return BrightnessParams(bias=uniform(rng, self.config.bias_range))

    def apply(self, sample: ImageSample, params: BrightnessParams) -> ImageSample:
        if params.is_identity():
            return sample
        return sample.with_image(linear(sample.image, 1.0, params.bias))


# --------------------------------------------------------------------------- contrast
#: Table 4, contrast α (gain): 1.2 to 3.0 with step 0.2.
CONTRAST_GAINS = [1.2, 1.4, 1.6, 1.8, 2.0, 2.2, 2.4, 2.6, 2.8, 3.0]


class ContrastConfig(Config):
    gain_range: NonNegativeRange = Field((1.2, 1.4), description="α multiplying every channel (1: unchanged)")


class ContrastParams(Params):
    gain: float = Field(ge=0)

    def is_identity(self) -> bool:
        return self.gain == 1


class Contrast(Operator[ImageSample, ContrastConfig, ContrastParams]):
    """A stronger (or weaker) contrast: ``α·x`` on every channel, saturating at 255.

    As in DeepTest (Table 4's α is a gain), the pivot is 0, not mid-grey: a gain above 1 also
    brightens, and bright regions (sky) saturate first. Table 4, contrast α: 1.2, 1.4, …, 3.0.
    Severity s draws α uniformly between the (2s−1)-th and 2s-th values: 1: 1.2–1.4, 2: 1.6–1.8,
    3: 2.0–2.2, 4: 2.4–2.6, 5: 2.8–3.0; ``gain_range`` takes any interval (below 1: lower contrast).
    Changes the image only; depth, camera matrix and label are kept. Invariant up to severity 1:
    from a gain of 1.6 on, a third of a sunlit pavement (KITTI image_2/000000.png) is pure white.
    """

    name = "image_contrast"
    aliases = ("contrast",)
    family = "photometric"
    modality = CAMERA
    relation = Relation.INVARIANT
    harmless_up_to = 1
    harmless_because = ("a gain of at most 1.4 saturates little of the road (1 % in the built-in world, 17 % of a "
                        "sunlit KITTI pavement) and keeps lane markings apart from it")
    targets = IMAGE
    ConfigModel = ContrastConfig
    ParamsModel = ContrastParams
    IDENTITY: ClassVar = {"gain_range": (1.0, 1.0)}
    SEVERITIES: ClassVar = {s: {"gain_range": r} for s, r in table_pairs(CONTRAST_GAINS).items()}

    def sample(self, rng: np.random.Generator, sample: ImageSample) -> ContrastParams:
        return ContrastParams(gain=uniform(rng, self.config.gain_range))

    def apply(self, sample: ImageSample, params: ContrastParams) -> ImageSample:
        if params.is_identity():
            return sample
        return sample.with_image(linear(sample.image, params.gain, 0.0))
