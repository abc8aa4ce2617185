"""Weather on camera frames: fog by Koschmieder's law, rain as streaks.

DeepTest composed Photoshop filters for its fog and rain; these are physically motivated instead.

**Fog.** Koschmieder's law: a surface at distance d along the pixel's ray is seen as
``I = I0·t + A·(1 − t)`` with transmission ``t = exp(−β·d)`` and ``β = 3.912 / V`` (V the
visibility, the distance at which a black target's contrast falls to 2 %; ln 50 = 3.912), A the
airlight (the fog's own brightness). The distance is the length of the ray to the depth map's
point, ``d = z·‖K⁻¹·[u, v, 1]ᵀ‖`` (z the z-depth, K the camera matrix); sky (``inf``) gets the
airlight. A sample without depth (a photo) gets a documented *ground prior* instead: the road is
a flat plane ``camera_height`` below a level camera, so a row v below the horizon row ``v_h``
(K's principal point, else the image centre) is at ``z = f_y·h / (v − v_h)``, at most
``horizon_distance`` (60 m by default); rows at or above the horizon (buildings, trees, sky) are
all put at ``horizon_distance``: a photo says nothing of how far they are, and 60 m, a street's
far side, fogs them little in light fog and hides them in dense fog, as it should. A sample
without K (with or without depth) is taken as a centred pinhole camera with a ``fov``-degree
horizontal field of view. Pixels of unknown depth (``nan``) get the prior too. The params say
which (``depth_source``).

**Rain.** Seeded drops drawn as short lines (:func:`cv2.polylines`) at a wind angle,
smeared along that angle by a motion-blur kernel (:func:`cv2.filter2D`), and blended as light
streaks over the picture, which is first darkened and loses contrast (overcast light, wet air).
All randomness comes from the ``seed`` in the params.

Both change the image only; depth, camera matrix and steering label are kept. DeepTest expects a
steering system to keep its output under them ("same output"): *invariant*, checked up to
``harmless_up_to``.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import ClassVar, Literal, cast

import cv2
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
    draw_seed,
    uniform,
)
from lidarfuzz.operators.camera.common import CAMERA, IMAGE, Range
from lidarfuzz.scene.image import ImageSample

F32 = NDArray[np.float32]
U8 = NDArray[np.uint8]
#: ln(1/0.02): the contrast threshold of Koschmieder's visibility.
KOSCHMIEDER = 3.912


# =========================================================================== fog
class FogConfig(Config):
    visibility_range: PositiveRange | None = Field((600.0, 1000.0), description="meteorological visibility V, metres "
                                           "(β = 3.912 / V); None: no fog")
    airlight: float = Field(210.0, ge=0, le=255, description="brightness of the fog itself (grey), 0–255")
    camera_height: float = Field(1.65, gt=0, description="ground prior (no depth): camera above the road, metres")
    horizon_distance: float = Field(60.0, gt=0, description="ground prior: distance of the horizon and of "
                                    "everything above it (a street's far side), metres")
    fov: float = Field(60.0, gt=0, lt=180, description="ground prior without K: horizontal field of view, degrees")


class FogParams(Params):
    extinction: float = Field(ge=0, description="β = 3.912 / visibility, 1/m")
    airlight: float = Field(210.0, ge=0, le=255)
    depth_source: Literal["depth", "ground_prior"] = Field(
        "depth", description="the sample's depth map, or the flat-ground prior (a sample without depth)")
    camera_height: float = Field(1.65, gt=0)
    horizon_distance: float = Field(60.0, gt=0)
    fov: float = Field(60.0, gt=0, lt=180)

    def is_identity(self) -> bool:
        return self.extinction == 0


def assumed_intrinsics(shape: tuple[int, int], fov: float) -> NDArray[np.float64]:
    """A pinhole K for a photo without one: square pixels, ``fov`` degrees across, centred."""
    height, width = shape
    f = (width / 2) / math.tan(math.radians(fov) / 2)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


@lru_cache(maxsize=8)
def _ray_lengths(k_bytes: bytes, height: int, width: int) -> F32:
    k = np.frombuffer(k_bytes, dtype=np.float64).reshape(3, 3)
    inverse = np.linalg.inv(k)
    u = np.arange(width, dtype=np.float64)
    v = np.arange(height, dtype=np.float64)[:, None]
    x = inverse[0, 0] * u + inverse[0, 1] * v + inverse[0, 2]
    y = inverse[1, 0] * u + inverse[1, 1] * v + inverse[1, 2]
    z = inverse[2, 0] * u + inverse[2, 1] * v + inverse[2, 2]
    lengths = (np.sqrt(x * x + y * y + z * z) / np.abs(z)).astype(np.float32)
    lengths.flags.writeable = False
    return lengths


def ray_lengths(intrinsics: NDArray[np.float64], shape: tuple[int, int]) -> F32:
    """Per pixel, the distance along its ray per metre of z-depth: ``‖K⁻¹[u, v, 1]ᵀ‖`` divided by the
    ray's own z (1 for an upper-triangular K), cached per camera and size."""
    return _ray_lengths(np.ascontiguousarray(intrinsics, dtype=np.float64).tobytes(), *shape)


def ground_prior(intrinsics: NDArray[np.float64], shape: tuple[int, int], camera_height: float,
                 horizon_distance: float) -> F32:
    """The flat-road z-depth of each pixel row (see the module docstring), H×W."""
    height = shape[0]
    horizon_row, fy = float(intrinsics[1, 2]), float(intrinsics[1, 1])
    below = np.arange(height, dtype=np.float64) - horizon_row
    z = np.full(height, horizon_distance)
    ground = below > 0
    z[ground] = np.minimum(fy * camera_height / below[ground], horizon_distance)
    return np.broadcast_to(z.astype(np.float32)[:, None], shape)


def transmission(sample: ImageSample, params: FogParams) -> F32:
    """``t = exp(−β·d)`` per pixel (0 for the sky)."""
    shape = sample.shape
    if params.depth_source == "depth" and sample.depth is None:
        raise ValueError("image_fog: params say depth_source 'depth' but the sample has no depth map")
    k = sample.intrinsics if sample.intrinsics is not None else assumed_intrinsics(shape, params.fov)
    if params.depth_source == "depth":
        z = np.asarray(sample.depth)
        unknown = np.isnan(z)
        if unknown.any():
            z = np.where(unknown, ground_prior(k, shape, params.camera_height, params.horizon_distance), z)
    else:
        z = ground_prior(k, shape, params.camera_height, params.horizon_distance)
    t = np.multiply(z, ray_lengths(k, shape), dtype=np.float32)
    t *= np.float32(-params.extinction)  # β > 0 here (no fog returns earlier): sky gives −inf, t = 0
    return np.exp(t, out=t)


class Fog(Operator[ImageSample, FogConfig, FogParams]):
    """Fog by Koschmieder's law, ``I = I0·t + A·(1 − t)``, ``t = exp(−3.912·d / V)`` (module docstring).

    Severity → visibility V (metres, drawn uniformly): 1: 600–1000, 2: 300–600, 3: 150–300,
    4: 75–150, 5: 40–75 (fog is visibility below 1 km; dense fog below 50 m). Airlight 210.
    Uses the sample's depth and K; without depth, the flat-ground prior (``depth_source:
    ground_prior`` in the params). Blending by :func:`cv2.blendLinear`. Changes the image only.
    """

    name = "image_fog"
    family = "weather"
    modality = CAMERA
    relation = Relation.INVARIANT
    harmless_up_to = 2
    harmless_because = "with 300 m of visibility or more the road ahead keeps most of its contrast"
    targets = IMAGE
    ConfigModel = FogConfig
    ParamsModel = FogParams
    IDENTITY: ClassVar = {"visibility_range": None}
    SEVERITIES: ClassVar = {s: {"visibility_range": r} for s, r in
                            [(1, (600.0, 1000.0)), (2, (300.0, 600.0)), (3, (150.0, 300.0)), (4, (75.0, 150.0)),
                             (5, (40.0, 75.0))]}

    def sample(self, rng: np.random.Generator, sample: ImageSample) -> FogParams:
        c = self.config
        extinction = 0.0 if c.visibility_range is None else KOSCHMIEDER / uniform(rng, c.visibility_range)
        return FogParams(extinction=extinction, airlight=c.airlight,
                         depth_source="depth" if sample.depth is not None else "ground_prior",
                         camera_height=c.camera_height, horizon_distance=c.horizon_distance, fov=c.fov)

    def apply(self, sample: ImageSample, params: FogParams) -> ImageSample:
        if params.is_identity():
            return sample
        t = transmission(sample, params)
        air = np.full_like(sample.image, round(params.airlight))
        return sample.with_image(cast(U8, cv2.blendLinear(np.ascontiguousarray(sample.image), air, t, 1.0 - t)))


# =========================================================================== rain
class RainConfig(Config):
    density_range: NonNegativeRange = Field((500.0, 1000.0), description="drops per megapixel")
    length_range: NonNegativeRange = Field((0.02, 0.04), description="streak length as a share of the image height")
    angle_range: Range = Field((-20.0, 20.0), description="wind: streak angle from the vertical, degrees "
                                                          "(positive: falling to the right)")
    opacity: float = Field(0.6, ge=0, le=1, description="how much a streak's core replaces the pixel")
    streak_value: float = Field(220.0, ge=0, le=255, description="brightness of the streaks, 0–255")
    darkening: float = Field(0.0, ge=0, lt=1, description="share of brightness the scene loses (overcast light)")
    contrast_loss: float = Field(0.0, ge=0, le=1, description="share of contrast lost towards the mean (wet air)")


class RainParams(Params):
    density: float = Field(ge=0)
    length: float = Field(ge=0)
    angle: float
    opacity: float = Field(ge=0, le=1)
    streak_value: float = Field(ge=0, le=255)
    darkening: float = Field(ge=0, lt=1)
    contrast_loss: float = Field(ge=0, le=1)
    seed: int

    def is_identity(self) -> bool:
        return (self.density == 0 or self.length == 0 or self.opacity == 0) and self.darkening == 0 \
            and self.contrast_loss == 0


def streak_mask(shape: tuple[int, int], params: RainParams) -> NDArray[np.uint8]:
    """0–255 coverage of the rain streaks (seeded by ``params.seed``), H×W."""
    height, width = shape
    mask = np.zeros(shape, np.uint8)
    count = round(params.density * height * width / 1e6)
    length = params.length * height
    if count == 0 or length <= 0:
        return mask
    rng = np.random.default_rng(params.seed)
    angle = np.radians(params.angle + rng.uniform(-3.0, 3.0, count))
    lengths = length * rng.uniform(0.6, 1.4, count)
    dx, dy = np.sin(angle) * lengths, np.cos(angle) * lengths
    # starts above and beside the frame too, so streaks cross its edges like the rest
    x0 = rng.uniform(-np.abs(dx).max(), width + np.abs(dx).max(), count)
    y0 = rng.uniform(-lengths.max(), height, count)
    lines = np.stack([np.stack([x0, y0], 1), np.stack([x0 + dx, y0 + dy], 1)], 1)
    thickness = max(1, round(height / 480))
    # 8-connected lines: the motion blur below softens them (anti-aliased ones cost four times as much)
    cv2.polylines(mask, list(np.round(lines).astype(np.int32)), False, 255, thickness, cv2.LINE_8)
    return motion_blur(mask, params.angle, max(3, round(length / 4) | 1))


def motion_blur(mask: NDArray[np.uint8], angle: float, size: int) -> NDArray[np.uint8]:
    """``mask`` smeared along ``angle`` (degrees from the vertical) by a normalised line kernel."""
    kernel = np.zeros((size, size), np.float32)
    c = (size - 1) / 2
    half = (size - 1) / 2
    a = math.radians(angle)
    end = (round(c + math.sin(a) * half), round(c + math.cos(a) * half))
    start = (round(c - math.sin(a) * half), round(c - math.cos(a) * half))
    cv2.line(kernel, start, end, 1.0, 1)
    kernel /= kernel.sum()
    return cast(U8, cv2.filter2D(mask, -1, kernel, borderType=cv2.BORDER_CONSTANT))


class Rain(Operator[ImageSample, RainConfig, RainParams]):
    """Rain streaks over a darker, flatter picture (module docstring).

    Severity → (drops per megapixel, streak length as a share of the height, darkening, contrast
    loss): 1: 500–1000, 0.02–0.04, 0, 0; 2: 1000–2000, 0.03–0.05, 0.05, 0.05; 3: 2000–3500,
    0.04–0.07, 0.1, 0.1; 4: 3500–5500, 0.05–0.08, 0.15, 0.15; 5: 5500–8000, 0.06–0.1, 0.2, 0.2.
    Wind angle −20° to 20° from the vertical at every severity. Severity 1 only adds streaks: the
    pixels away from them are untouched. Changes the image only.
    """

    name = "image_rain"
    family = "weather"
    modality = CAMERA
    relation = Relation.INVARIANT
    harmless_up_to = 2
    harmless_because = "light rain (up to 2,000 thin streaks per megapixel) hides little of the road"
    targets = IMAGE
    ConfigModel = RainConfig
    ParamsModel = RainParams
    IDENTITY: ClassVar = {"density_range": (0.0, 0.0)}
    SEVERITIES: ClassVar = {s: {"density_range": d, "length_range": n, "darkening": k, "contrast_loss": k}
                            for s, d, n, k in [(1, (500.0, 1000.0), (0.02, 0.04), 0.0),
                                               (2, (1000.0, 2000.0), (0.03, 0.05), 0.05),
                                               (3, (2000.0, 3500.0), (0.04, 0.07), 0.1),
                                               (4, (3500.0, 5500.0), (0.05, 0.08), 0.15),
                                               (5, (5500.0, 8000.0), (0.06, 0.1), 0.2)]}

    def sample(self, rng: np.random.Generator, sample: ImageSample) -> RainParams:
        c = self.config
        return RainParams(density=uniform(rng, c.density_range), length=uniform(rng, c.length_range),
                          angle=uniform(rng, c.angle_range), opacity=c.opacity, streak_value=c.streak_value,
                          darkening=c.darkening, contrast_loss=c.contrast_loss, seed=draw_seed(rng))

    def apply(self, sample: ImageSample, params: RainParams) -> ImageSample:
        if params.is_identity():
            return sample
        image = np.ascontiguousarray(sample.image)
        if params.darkening or params.contrast_loss:
            keep = (1.0 - params.contrast_loss) * (1.0 - params.darkening)
            mean = float(np.mean(cv2.mean(image)[:3])) * params.contrast_loss * (1.0 - params.darkening)
            image = cast(U8, cv2.addWeighted(image, keep, image, 0.0, mean))
        weight = streak_mask(sample.shape, params).astype(np.float32) * np.float32(params.opacity / 255.0)
        streaks = np.full_like(image, round(params.streak_value))
        return sample.with_image(cast(U8, cv2.blendLinear(image, streaks, 1.0 - weight, weight)))
