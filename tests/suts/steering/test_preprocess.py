"""Preprocessing: crop rows, resize, colour space and scaling, checked on hand-made frames."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from lidarfuzz.suts.steering.preprocess import Preprocess, as_preprocess, split_options


def test_crop_keeps_the_middle_rows_and_resize_keeps_a_uniform_colour() -> None:
    # 10 rows: rows 0-2 red (cut by crop_top 0.3 = 3 rows), rows 3-7 grey 100, rows 8-9 blue
    # (cut by crop_bottom 0.2 = 2 rows). What remains is uniform grey, so any resize is grey 100,
    # and /255 gives 100/255 = 0.392157 everywhere.
    image = np.full((10, 20, 3), 100, np.uint8)
    image[:3] = (255, 0, 0)
    image[8:] = (0, 0, 255)
    p = Preprocess(height=4, width=5, crop_top=0.3, crop_bottom=0.2)
    assert p.crop_rows(10) == (3, 8)
    out = p.apply(image)
    assert out.shape == (4, 5, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out, 100 / 255, rtol=1e-6)


def test_yuv_of_a_uniform_colour_against_the_formula() -> None:
    # RGB (200, 100, 50): Y = 0.299·200 + 0.587·100 + 0.114·50 = 124.2 → 124;
    # U = 0.492·(B − Y) + 128 = 0.492·(50 − 124) + 128 = 91.6 → 92;
    # V = 0.877·(R − Y) + 128 = 0.877·(200 − 124) + 128 = 194.65 → 195 (OpenCV rounds Y first).
    image = np.empty((6, 8, 3), np.uint8)
    image[:] = (200, 100, 50)
    raw = Preprocess(height=3, width=4, color="yuv", scale=1.0).apply(image)
    np.testing.assert_allclose(raw, np.broadcast_to([124, 92, 195], (3, 4, 3)), atol=1)
    # DAVE-2's scaling x / 127.5 − 1: Y 124 → −0.027451, U 92 → −0.278431, V 195 → 0.529412
    dave = Preprocess(height=3, width=4, color="yuv", scale=1 / 127.5, offset=-1.0).apply(image)
    np.testing.assert_allclose(dave[0, 0], [124 / 127.5 - 1, 92 / 127.5 - 1, 195 / 127.5 - 1], atol=1 / 127.5)


def test_bgr_swaps_channels_and_batch_stacks() -> None:
    image = np.zeros((2, 2, 3), np.uint8)
    image[:] = (10, 20, 30)
    p = Preprocess(height=2, width=2, color="bgr", scale=1.0)
    np.testing.assert_array_equal(p.apply(image)[0, 0], [30, 20, 10])
    batch = p.batch([image, image])
    assert batch.shape == (2, 2, 2, 3)


def test_resize_averages_with_area_interpolation() -> None:
    # a 2×4 frame, left half 0 and right half 200, shrunk to 1×2 with INTER_AREA: each output pixel
    # is the mean of its 2×2 block, 0 and 200.
    image = np.zeros((2, 4, 3), np.uint8)
    image[:, 2:] = 200
    out = Preprocess(height=1, width=2, scale=1.0).apply(image)
    np.testing.assert_allclose(out[0, :, 0], [0, 200])


def test_bad_configurations_and_inputs_are_refused_naming_the_field() -> None:
    with pytest.raises(ValidationError, match="crop_top"):
        Preprocess(crop_top=1.0)
    with pytest.raises(ValidationError, match="crop_top \\+ crop_bottom"):
        Preprocess(crop_top=0.6, crop_bottom=0.4)
    with pytest.raises(ValidationError, match="color"):
        Preprocess(color="hsv")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="H×W×3 uint8"):
        Preprocess().apply(np.zeros((4, 4), np.uint8))  # type: ignore[arg-type]


def test_split_options_and_as_preprocess() -> None:
    pre, rest = split_options({"height": 66, "color": "yuv", "threads": 2})
    assert pre == {"height": 66, "color": "yuv"} and rest == {"threads": 2}
    assert as_preprocess(pre).color == "yuv"
    assert as_preprocess(None) == Preprocess()
