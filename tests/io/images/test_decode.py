"""PNG/JPEG decoding (RGB order, truncation, oversized headers), depth PNGs and raw Image pixels."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.images.decode import MAX_PIXELS, decode_depth, decode_image, decode_raw, image_header
from tests.io.images.util import PIXELS, jpeg_bytes, png_bytes, solid


def test_png_decodes_to_the_written_rgb_pixels():
    image = decode_image(png_bytes(), "a.png")
    assert image.dtype == np.uint8 and image.shape == (2, 3, 3)
    assert image[0, 0].tolist() == [200, 100, 50]  # R, G, B as written — not reversed
    assert np.array_equal(image, PIXELS)


def test_jpeg_decodes_to_rgb_within_compression_error():
    red = solid(16, 16, (220, 30, 20))
    image = decode_image(jpeg_bytes(red), "a.jpg")
    assert image.shape == (16, 16, 3)
    # a flat colour survives quality-95 JPEG to within a few levels; channel order is R, G, B
    assert np.abs(image.astype(int) - red.astype(int)).max() <= 4
    assert image[8, 8, 0] > 200 and image[8, 8, 2] < 40


def test_grey_and_alpha_pngs_become_rgb():
    grey = cv2.imencode(".png", np.array([[7, 9]], dtype=np.uint8))[1].tobytes()
    assert decode_image(grey, "g.png").tolist() == [[[7, 7, 7], [9, 9, 9]]]
    bgra = np.array([[[30, 20, 10, 128]]], dtype=np.uint8)  # B=30 G=20 R=10, half transparent
    rgba = cv2.imencode(".png", bgra)[1].tobytes()
    assert decode_image(rgba, "a.png").tolist() == [[[10, 20, 30]]]  # alpha dropped, not blended


def test_header_gives_kind_and_size():
    assert image_header(png_bytes(), "a.png") == ("png", 2, 3)
    assert image_header(jpeg_bytes(solid(5, 7, (1, 2, 3))), "a.jpg") == ("jpeg", 5, 7)


def test_truncated_png_is_refused_naming_the_missing_iend():
    data = png_bytes()
    with pytest.raises(DataFormatError, match=r"^cut\.png: truncated PNG: no IEND chunk after \d+ bytes") as info:
        decode_image(data[:-12], "cut.png")  # the IEND chunk is the last 12 bytes
    assert str(info.value.path) == "cut.png"


def test_truncated_jpeg_is_refused_naming_the_missing_marker():
    data = jpeg_bytes(solid(64, 64, (100, 150, 200)))
    cut = data[: len(data) // 2]
    # OpenCV 4's libjpeg decoded a cut file into grey rows with only a warning: the marker walk catches it
    with pytest.raises(DataFormatError, match=r"^cut\.jpg: truncated JPEG: no end-of-image marker \(FFD9\)"):
        decode_image(cut, "cut.jpg")
    with pytest.raises(DataFormatError, match="truncated JPEG"):
        decode_image(data[:-2], "cut.jpg")  # everything but the end-of-image marker


def test_corrupt_data_after_a_good_header_is_refused():
    data = bytearray(png_bytes())
    idat = data.index(b"IDAT")
    data[idat + 4:idat + 10] = b"\x00" * 6  # break the zlib stream, keep the chunk structure
    with pytest.raises(DataFormatError, match=r"^bad\.png: corrupt PNG"):
        decode_image(bytes(data), "bad.png")


def _png_header_only(width: int, height: int) -> bytes:
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b"")


def test_a_header_claiming_a_billion_pixels_is_refused_before_decoding():
    data = _png_header_only(40_000, 25_000)  # 10^9 pixels: 3 GB as RGB
    with pytest.raises(DataFormatError, match=r"^huge\.png: image size 40000×25000 \(1,000,000,000 pixels\) "
                                              r"exceeds the 67,108,864"):
        decode_image(data, "huge.png")
    assert MAX_PIXELS == 8192 * 8192


def test_not_an_image():
    with pytest.raises(DataFormatError, match=r"^x\.png: not a PNG or JPEG image \(it starts with b'GIF89a"):
        decode_image(b"GIF89a\x01\x00\x01\x00", "x.png")
    with pytest.raises(DataFormatError, match="the file is empty"):
        decode_image(b"", "x.png")


def test_depth_png_metres_times_256_and_zero_is_sky():
    raw = np.array([[2560, 0], [1, 65535]], dtype=np.uint16)
    depth = decode_depth(cv2.imencode(".png", raw)[1].tobytes(), "d.png")
    assert depth.dtype == np.float32
    assert depth[0, 0] == 10.0  # 2560 / 256
    assert depth[0, 1] == np.inf  # 0: nothing hit
    assert depth[1, 0] == np.float32(1 / 256) and depth[1, 1] == np.float32(65535 / 256)


def test_depth_must_be_16_bit():
    eight = cv2.imencode(".png", np.array([[1, 2]], dtype=np.uint8))[1].tobytes()
    with pytest.raises(DataFormatError, match=r"^d\.png: a depth map must be one 16-bit channel, found 1 channel"):
        decode_depth(eight, "d.png")


@pytest.mark.parametrize(("encoding", "row", "expected"), [
    ("rgb8", [200, 100, 50, 1, 2, 3], [[200, 100, 50], [1, 2, 3]]),
    ("bgr8", [50, 100, 200, 3, 2, 1], [[200, 100, 50], [1, 2, 3]]),
    ("mono8", [9, 250], [[9, 9, 9], [250, 250, 250]]),
    ("rgba8", [200, 100, 50, 7, 1, 2, 3, 7], [[200, 100, 50], [1, 2, 3]]),
    ("bgra8", [50, 100, 200, 7, 3, 2, 1, 7], [[200, 100, 50], [1, 2, 3]]),
])
def test_raw_encodings_with_padded_rows(encoding, row, expected):
    # two rows of two pixels, each row padded by 3 bytes that must be ignored
    step = len(row) + 3
    second = [v // 2 for v in row]
    data = bytes([*row, 99, 99, 99, *second, 99, 99, 99])
    image = decode_raw(2, 2, encoding, step, data, "log.bag", "topic /cam, message 0")
    assert image.shape == (2, 2, 3)
    assert image[0].tolist() == expected
    assert 99 not in image[1].tolist()[0]  # the padding never leaks into pixels


def test_raw_data_length_must_be_height_times_step():
    with pytest.raises(DataFormatError, match=r"^log\.bag: field 'data': topic /cam, message 4: data has 11 bytes "
                                              r"but height × step is 2 × 6 = 12"):
        decode_raw(2, 2, "rgb8", 6, bytes(11), "log.bag", "topic /cam, message 4")


def test_raw_bad_encoding_step_and_size():
    with pytest.raises(DataFormatError, match=r"field 'encoding': .*'16UC1' is not one of rgb8"):
        decode_raw(1, 1, "16UC1", 2, bytes(2), "l.bag", "m")
    with pytest.raises(DataFormatError, match=r"field 'step': m: step 5 is shorter than a row of 2 rgb8 pixels"):
        decode_raw(1, 2, "rgb8", 5, bytes(5), "l.bag", "m")
    with pytest.raises(DataFormatError, match="exceeds"):
        decode_raw(100_000, 100_000, "mono8", 100_000, b"", "l.bag", "m")  # refused before any allocation


@pytest.mark.parametrize("progressive", [False, True])
def test_every_prefix_of_an_image_is_refused(progressive):
    """No cut point lets a partial file through, whatever the OpenCV version does with it."""
    rng = np.random.default_rng(0)
    noisy = rng.integers(0, 256, (24, 40, 3), dtype=np.uint8)  # noise: long entropy-coded scans with FF bytes
    jpeg = cv2.imencode(".jpg", noisy, [cv2.IMWRITE_JPEG_QUALITY, 90,
                                        cv2.IMWRITE_JPEG_PROGRESSIVE, int(progressive)])[1].tobytes()
    png = png_bytes(noisy)
    for data, name in ((jpeg, "a.jpg"), (png, "a.png")):
        assert decode_image(data, name).shape == (24, 40, 3)
        for cut in range(len(data)):
            with pytest.raises(DataFormatError):
                decode_image(data[:cut], name)
