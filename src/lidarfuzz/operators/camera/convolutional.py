"""Blur, DeepTest's convolutional transformation: averaging, Gaussian, median and bilateral filters.

Each filter is OpenCV's (:func:`cv2.blur`, :func:`cv2.GaussianBlur`, :func:`cv2.medianBlur`,
:func:`cv2.bilateralFilter`); borders are reflected without repeating the edge pixel
(``BORDER_REFLECT_101``, OpenCV's default, ``dcb|abcd|cba``) except for the median filter, which
OpenCV always computes with a replicated border (``aaa|abcd``). Only the pixels change; depth,
camera matrix and label are kept.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import cv2
import numpy as np
from pydantic import Field, field_validator

from lidarfuzz.operators.base import Config, Operator, Params, Relation
from lidarfuzz.operators.camera.common import CAMERA, IMAGE
from lidarfuzz.scene.image import ImageSample

Kind = Literal["averaging", "gaussian", "median", "bilateral"]
KINDS: tuple[str, ...] = ("averaging", "gaussian", "median", "bilateral")

#: Table 4's ten blur filters, ordered by measured strength: the mean absolute change they make to
#: KITTI image_2/000000.png resized to 640×480 (0–255 units): median 3: 4.5, Gaussian 3: 5.2,
#: bilateral 9: 6.3, averaging 3: 6.8, Gaussian 5: 7.1, median 5: 8.1, Gaussian 7: 9.2,
#: averaging 4: 9.7, averaging 5: 10.5, averaging 6: 12.3. Severity s uses the (2s−1)-th and 2s-th.
FILTERS_BY_STRENGTH = ["median:3", "gaussian:3", "bilateral:9", "averaging:3", "gaussian:5", "median:5",
                       "gaussian:7", "averaging:4", "averaging:5", "averaging:6"]


def parse_filter(text: str) -> tuple[str, int]:
    """``"gaussian:5"`` → ``("gaussian", 5)``, with a one-line error naming what is wrong."""
    kind, _, size = str(text).partition(":")
    if kind not in KINDS:
        raise ValueError(f"blur filter {text!r}: kind must be one of {', '.join(KINDS)}")
    if not size.isdigit() or int(size) < 1:
        raise ValueError(f"blur filter {text!r}: give the size as a positive integer after ':' (e.g. {kind}:5)")
    n = int(size)
    if kind in ("gaussian", "median") and n % 2 == 0:
        raise ValueError(f"blur filter {text!r}: {kind} kernels need an odd size")
    return kind, n


class BlurConfig(Config):
    filters: tuple[str, ...] = Field(("median:3", "gaussian:3"), min_length=1,
                                     description="filters drawn from (kind:size; kinds averaging, gaussian, median, "
                                                 "bilateral; the bilateral size is its diameter)")
    sigma_color: float = Field(75.0, gt=0, description="bilateral filter: range sigma, 0–255 units")
    sigma_space: float = Field(75.0, gt=0, description="bilateral filter: spatial sigma, pixels")

    @field_validator("filters")
    @classmethod
    def _known_filters(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for text in value:
            parse_filter(text)
        return value


class BlurParams(Params):
    kind: Kind
    size: int = Field(ge=0, description="kernel size (bilateral: diameter); 0: no blur")
    sigma_color: float = 75.0
    sigma_space: float = 75.0

    def is_identity(self) -> bool:
        return self.size <= 1


def blur(image: np.ndarray, params: BlurParams) -> np.ndarray:
    """``image`` through one OpenCV filter (borders as the module docstring says)."""
    image = np.ascontiguousarray(image)
    k = params.size
    if params.kind == "averaging":
        return cv2.blur(image, (k, k), borderType=cv2.BORDER_REFLECT_101)
    if params.kind == "gaussian":
        # sigma 0: OpenCV derives it from the size, 0.3·((k − 1)/2 − 1) + 0.8, as DeepTest's calls did
        return cv2.GaussianBlur(image, (k, k), 0, borderType=cv2.BORDER_REFLECT_101)
    if params.kind == "median":
        return cv2.medianBlur(image, k)
    return cv2.bilateralFilter(image, k, params.sigma_color, params.sigma_space, borderType=cv2.BORDER_REFLECT_101)


class Blur(Operator[ImageSample, BlurConfig, BlurParams]):
    """A blurred picture (defocus, a dirty lens, motion): one of Table 4's filters.

    Table 4's blur row: averaging 3×3, 4×4, 5×5, 6×6; Gaussian 3×3, 5×5, 7×7 (σ from the size);
    median 3, 5; bilateral (diameter 9, σ_color 75, σ_space 75). The table gives no order of
    strength, so the ten are ordered by the change each makes to a real photo
    (:data:`FILTERS_BY_STRENGTH`), and severity s draws one of the (2s−1)-th and 2s-th:
    1: median 3 or Gaussian 3; 2: bilateral 9 or averaging 3; 3: Gaussian 5 or median 5;
    4: Gaussian 7 or averaging 4; 5: averaging 5 or 6. ``filters`` takes any list (one filter
    to sweep Table 4 filter by filter). Changes the image only; depth, camera matrix and label
    are kept. Invariant at every severity.
    """

    name = "image_blur"
    aliases = ("blur",)
    family = "photometric"
    modality = CAMERA
    relation = Relation.INVARIANT
    harmless_up_to = 5
    harmless_because = "even a 6×6 average keeps the road's edges and lane markings, only sharp detail is lost"
    targets = IMAGE
    ConfigModel = BlurConfig
    ParamsModel = BlurParams
    IDENTITY: ClassVar = {"filters": ("averaging:1",)}
    SEVERITIES: ClassVar = {s: {"filters": tuple(FILTERS_BY_STRENGTH[2 * s - 2:2 * s])} for s in range(1, 6)}

    def harmless(self) -> bool:
        """Every filter the config draws from is one of the severities' up to :attr:`harmless_up_to`."""
        allowed = {f for s in range(1, self.harmless_up_to + 1) for f in self.SEVERITIES[s]["filters"]}
        return all(f in allowed or parse_filter(f)[1] <= 1 for f in self.config.filters)

    def sample(self, rng: np.random.Generator, sample: ImageSample) -> BlurParams:
        chosen = self.config.filters[int(rng.integers(len(self.config.filters)))]
        kind, size = parse_filter(chosen)
        return BlurParams(kind=kind, size=size, sigma_color=self.config.sigma_color,  # type: ignore[arg-type]
                          sigma_space=self.config.sigma_space)

    def apply(self, sample: ImageSample, params: BlurParams) -> ImageSample:
        if params.is_identity():
            return sample
        return sample.with_image(blur(sample.image, params))
