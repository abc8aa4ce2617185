"""DeepTest's nine image transformations against pixels worked out by hand on tiny images."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from lidarfuzz.operators.camera.affine import (
    Rotation,
    RotationParams,
    Scale,
    ScaleParams,
    Shear,
    ShearParams,
    Translation,
    TranslationParams,
)
from lidarfuzz.operators.camera.convolutional import Blur, BlurParams, parse_filter
from lidarfuzz.operators.camera.photometric import Brightness, BrightnessParams, Contrast, ContrastParams
from lidarfuzz.operators.camera.weather import Fog, FogParams, Rain
from lidarfuzz.scene.image import ImageSample

# A 4×5 grey image with known values (every channel alike).
GREY = np.array([[0, 100, 200, 250, 255],
                 [10, 20, 30, 40, 50],
                 [60, 70, 80, 90, 100],
                 [4, 8, 12, 16, 20]], dtype=np.uint8)


def grey_sample(values: np.ndarray = GREY, **fields) -> ImageSample:
    return ImageSample(np.repeat(values[:, :, None], 3, axis=2), frame_id="t", steering=0.1, **fields)


def channel(sample: ImageSample) -> np.ndarray:
    assert np.array_equal(sample.image[..., 0], sample.image[..., 2])
    return sample.image[..., 0].astype(int)


# ------------------------------------------------------------------ photometric
def test_brightness_adds_the_bias_and_saturates_at_255_and_0():
    out = channel(Brightness().apply(grey_sample(), BrightnessParams(bias=10)))
    # 0+10, 100+10, 200+10, 250+10 = 260 → 255, 255+10 → 255
    assert out[0].tolist() == [10, 110, 210, 255, 255]
    out = channel(Brightness().apply(grey_sample(), BrightnessParams(bias=-20)))
    assert out[0].tolist() == [0, 80, 180, 230, 235]  # 0-20 → 0


def test_contrast_multiplies_by_the_gain_and_saturates():
    out = channel(Contrast().apply(grey_sample(), ContrastParams(gain=1.2)))
    # 100·1.2 = 120, 200·1.2 = 240, 250·1.2 = 300 → 255; row 1: 10·1.2 = 12, 20·1.2 = 24, ...
    assert out[0].tolist() == [0, 120, 240, 255, 255]
    assert out[1].tolist() == [12, 24, 36, 48, 60]
    out = channel(Contrast().apply(grey_sample(), ContrastParams(gain=0.5)))
    assert out[0, 1:4].tolist() == [50, 100, 125]


# ------------------------------------------------------------------ affine
def test_translation_moves_column_0_to_column_1_with_black_at_column_0():
    depth = np.arange(20, dtype=np.float32).reshape(4, 5)
    k = np.array([[10.0, 0, 2], [0, 10, 1.5], [0, 0, 1]])
    sample = grey_sample(depth=depth, intrinsics=k)
    out = Translation().apply(sample, TranslationParams(tx=1, ty=0))
    assert (channel(out)[:, 0] == 0).all()
    assert np.array_equal(channel(out)[:, 1:], GREY[:, :-1])
    # the depth map moves with the pixels, inf where nothing came from
    assert np.isinf(out.depth[:, 0]).all() and np.array_equal(out.depth[:, 1:], depth[:, :-1])
    # K's principal point moves with them: cx 2 → 3
    assert np.allclose(out.intrinsics, [[10, 0, 3], [0, 10, 1.5], [0, 0, 1]])
    assert out.steering == 0.1 and out.frame_id == "t"


def test_a_fractional_translation_interpolates_bilinearly():
    out = channel(Translation().apply(grey_sample(), TranslationParams(tx=0.5, ty=0)))
    # output x comes from input x − 0.5: column 2 ← (100 + 200)/2 = 150, column 3 ← (200 + 250)/2 = 225
    assert out[0, 2] == 150 and out[0, 3] == 225


def test_translation_down_blackens_the_top_row():
    out = channel(Translation().apply(grey_sample(), TranslationParams(tx=0, ty=1)))
    assert (out[0] == 0).all() and np.array_equal(out[1:], GREY[:-1])


def test_a_90_degree_rotation_about_the_centre_turns_a_square_image_clockwise():
    square = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9]], dtype=np.uint8) * 20
    out = channel(Rotation().apply(grey_sample(square), RotationParams(angle=90)))
    # Table 2's [[cos, −sin], [sin, cos]] about (1, 1) in image coordinates (y down):
    # x' = 1 − (y − 1), y' = 1 + (x − 1): top-left (0, 0) → (2, 0) top-right, top-right (2, 0) → (2, 2)
    # bottom-right, bottom-right → bottom-left, bottom-left → top-left; the centre stays.
    assert out[0, 2] == square[0, 0] and out[2, 2] == square[0, 2]
    assert out[2, 0] == square[2, 2] and out[0, 0] == square[2, 0] and out[1, 1] == square[1, 1]
    assert np.array_equal(out, np.rot90(square, k=-1))


def test_a_90_degree_rotation_of_an_even_square_keeps_every_pixel():
    square = np.arange(16, dtype=np.uint8).reshape(4, 4) * 10
    out = channel(Rotation().apply(grey_sample(square), RotationParams(angle=90)))
    assert np.array_equal(out, np.rot90(square, k=-1))  # centre (1.5, 1.5): pixels land on pixels


def test_shear_moves_each_row_by_sx_times_its_index():
    values = np.array([[10, 20, 30, 40], [50, 60, 70, 80], [90, 100, 110, 120]], dtype=np.uint8)
    out = channel(Shear().apply(grey_sample(values), ShearParams(sx=-1.0, sy=0.0)))
    # x' = x − y: row 0 stays, row 1 moves one pixel left, row 2 two; black where nothing lands
    assert out.tolist() == [[10, 20, 30, 40], [60, 70, 80, 0], [110, 120, 0, 0]]


def test_scale_by_two_about_the_origin_is_table_2s_matrix():
    values = np.array([[0, 40, 80, 120, 160], [40, 80, 120, 160, 200], [80, 120, 160, 200, 240],
                       [120, 160, 200, 240, 240]], dtype=np.uint8)
    out = channel(Scale().apply(grey_sample(values), ScaleParams(factor=2.0, about="origin")))
    # output (x, y) comes from input (x/2, y/2): (2, 2) ← (1, 1) = 80, (4, 2) ← (2, 1) = 120, the
    # origin stays; bilinear between: (1, 0) ← (0.5, 0) = (0 + 40)/2 = 20, (1, 1) ← mean of 0, 40, 40, 80 = 40
    assert out[0, 0] == 0 and out[2, 2] == 80 and out[2, 4] == 120
    assert out[0, 1] == 20 and out[1, 1] == 40


def test_scale_about_the_centre_keeps_the_centre_and_is_the_default():
    values = np.arange(25, dtype=np.uint8).reshape(5, 5) * 10
    out = channel(Scale().apply(grey_sample(values), ScaleParams(factor=2.0)))
    # centre (2, 2) is fixed; (3, 2) ← (2.5, 2) = (120 + 130)/2 = 125
    assert out[2, 2] == 120 and out[2, 3] == 125
    assert Scale.at_severity(1).config.about == "centre" and Scale.at_severity(1).harmless()
    assert not Scale(factor_range=(1.5, 2.0), about="origin").harmless()


def test_affine_depth_uses_nearest_neighbour_not_interpolation():
    depth = np.array([[5.0, 50.0], [5.0, 50.0]], dtype=np.float32)
    sample = grey_sample(np.zeros((2, 2), np.uint8), depth=depth)
    out = Scale().apply(sample, ScaleParams(factor=2.0, about="origin"))
    # bilinear would put 27.5 between a car at 5 m and a wall at 50 m; nearest keeps one of them
    assert set(np.unique(out.depth[np.isfinite(out.depth)])) <= {5.0, 50.0}


# ------------------------------------------------------------------ blur
def impulse(size: int, row: int, col: int, value: int) -> ImageSample:
    values = np.zeros((size, size), np.uint8)
    values[row, col] = value
    return grey_sample(values)


def test_averaging_3x3_on_an_impulse_gives_a_ninth_in_its_neighbourhood():
    out = channel(Blur().apply(impulse(7, 3, 3, 90), BlurParams(kind="averaging", size=3)))
    expected = np.zeros((7, 7), int)
    expected[2:5, 2:5] = 10  # 90 / 9
    assert np.array_equal(out, expected)


def test_averaging_reflects_the_border_without_repeating_the_edge_pixel():
    out = channel(Blur().apply(impulse(7, 0, 3, 90), BlurParams(kind="averaging", size=3)))
    # BORDER_REFLECT_101: row −1 mirrors row 1 (0), so the edge pixel counts once: 10, not 20
    assert out[0, 3] == 10 and out[1, 3] == 10 and out[2, 3] == 0


def test_median_removes_an_impulse():
    values = np.full((5, 5), 50, np.uint8)
    values[2, 2] = 255
    out = channel(Blur().apply(grey_sample(values), BlurParams(kind="median", size=3)))
    assert (out == 50).all()


def test_gaussian_3x3_is_the_outer_product_of_opencvs_kernel():
    kernel_1d = cv2.getGaussianKernel(3, 0).ravel()
    assert kernel_1d.tolist() == [0.25, 0.5, 0.25] and math.isclose(kernel_1d.sum(), 1.0)
    kernel = np.outer(kernel_1d, kernel_1d)
    assert math.isclose(kernel.sum(), 1.0)
    out = channel(Blur().apply(impulse(5, 2, 2, 255), BlurParams(kind="gaussian", size=3)))
    # 255 · [1/16, 1/8, 1/4] = 15.9, 31.9, 63.75 → 16, 32, 64
    assert out[1:4, 1:4].tolist() == [[16, 32, 16], [32, 64, 32], [16, 32, 16]]
    assert np.array_equal(out[1:4, 1:4], np.round(255 * kernel).astype(int))
    assert out.sum() - out[1:4, 1:4].sum() == 0


def test_bilateral_keeps_an_edge_that_averaging_smears():
    values = np.zeros((7, 7), np.uint8)
    values[:, 4:] = 200
    bilateral = channel(Blur().apply(grey_sample(values), BlurParams(kind="bilateral", size=9)))
    averaged = channel(Blur().apply(grey_sample(values), BlurParams(kind="averaging", size=3)))
    # across a 200 step with σ_color 75 the other side weighs exp(−200²/(2·75²)) ≈ 0.03
    assert np.abs(bilateral - values).max() < 20
    assert averaged[3, 3] == 67  # 3 of 9 pixels are 200: 66.7


def test_blur_filters_are_parsed_with_errors_naming_the_filter():
    assert parse_filter("gaussian:5") == ("gaussian", 5)
    with pytest.raises(ValueError, match=r"'gaussian:4'.*odd"):
        parse_filter("gaussian:4")
    with pytest.raises(ValueError, match=r"'boxcar:3'.*kind"):
        Blur(filters=("boxcar:3",))


# ------------------------------------------------------------------ fog
K3 = np.array([[2.0, 0.0, 1.0], [0.0, 2.0, 1.0], [0.0, 0.0, 1.0]])


def test_fog_follows_koschmieders_law_along_each_pixels_ray():
    depth = np.full((3, 3), 100.0, np.float32)
    depth[0, 2] = np.inf  # sky
    sample = grey_sample(np.full((3, 3), 100, np.uint8), depth=depth, intrinsics=K3)
    params = FogParams(extinction=3.912 / 500, airlight=210, depth_source="depth")
    out = channel(Fog().apply(sample, params))
    # centre pixel: its ray is the optical axis, d = z = 100 m, V = 500 m:
    # t = exp(−3.912·100/500) = 0.45731, I = 100·t + 210·(1 − t) = 159.70 → 160
    assert out[1, 1] == 160
    # corner (0, 0): K⁻¹[0, 0, 1] = (−0.5, −0.5, 1), length √1.5, d = 122.47 m:
    # t = exp(−3.912·122.47/500) = 0.38357, I = 38.36 + 129.45 = 167.81 → 168
    assert out[0, 0] == 168
    assert out[0, 2] == 210  # sky: airlight


def test_fog_without_depth_uses_the_flat_ground_prior():
    sample = grey_sample(np.full((5, 3), 0, np.uint8), intrinsics=np.array([[100.0, 0, 1], [0, 100, 1], [0, 0, 1]]))
    op = Fog(visibility_range=(391.2, 391.2), camera_height=1.0, horizon_distance=60.0)
    params = op.sample(np.random.default_rng(0), sample)
    assert params.depth_source == "ground_prior" and math.isclose(params.extinction, 0.01)
    out = channel(op.apply(sample, params))
    # horizon row 1 (K's cy). Row 3: z = 100·1.0/2 = 50 m; at u = cx the ray length is
    # √(1 + (2/100)²) = 1.0002, d = 50.01 m, t = exp(−0.5001) = 0.60647, I = 210·(1 − t) = 82.6 → 83.
    # Row 4: z = 33.33 m, d = 33.34, t = 0.71646, I = 59.54 → 60.
    # Rows 0–2 (at or above the horizon, and row 2 at z = 100 capped): 60 m, t = 0.54881, I = 94.75 → 95.
    assert out[3, 1] == 83 and out[4, 1] == 60
    assert out[0, 1] == out[1, 1] == out[2, 1] == 95


def test_fog_params_that_need_depth_refuse_a_sample_without_it():
    with pytest.raises(ValueError, match="depth_source"):
        Fog().apply(grey_sample(), FogParams(extinction=0.01, depth_source="depth"))


# ------------------------------------------------------------------ rain
def test_rain_is_deterministic_for_a_seed_and_light_at_severity_1():
    sample = ImageSample(np.full((480, 640, 3), 90, np.uint8))
    op = Rain.at_severity(1)
    params = op.sample(np.random.default_rng(3), sample)
    first, again = op.apply(sample, params), op.apply(sample, params)
    assert np.array_equal(first.image, again.image)
    other = op.apply(sample, params.model_copy(update={"seed": params.seed + 1}))
    assert not np.array_equal(first.image, other.image)
    changed = (first.image != sample.image).any(axis=2).mean()
    # ≤ 1,000 drops per megapixel · 0.307 MP = 307 streaks of ≤ 0.04·1.4·480 = 27 px, ~3 px wide with
    # anti-aliasing and the motion blur's 5 px: ≤ 307·32·4 px ≈ 13 % of the picture
    assert 0.002 < changed < 0.13
    # nothing darkens at severity 1: every changed pixel is brighter (a streak), none darker
    assert (first.image >= sample.image).all()


def test_rain_darkens_and_flattens_at_severity_5():
    values = np.tile(np.array([40, 200], np.uint8), (240, 320))
    sample = grey_sample(values)
    op = Rain.at_severity(5)
    out = op.apply(sample, op.sample(np.random.default_rng(0), sample))
    far = (out.image[..., 0] <= 200) & (values == 200)  # bright pixels not under a streak
    assert far.any() and out.image[..., 0][far].max() < 200
