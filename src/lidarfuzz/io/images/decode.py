"""Image bytes → RGB arrays: PNG and JPEG files through OpenCV, raw ``sensor_msgs/Image`` pixels,
depth PNGs — each checked before anything large is allocated.

OpenCV says only "no image" for a damaged file (OpenCV 5 returns ``None`` for a cut PNG or JPEG;
libjpeg in OpenCV 4 returned a cut JPEG's decoded part above grey rows, with a warning on stderr),
so the container is walked first, and the error says what is wrong: a PNG must reach its ``IEND``
chunk and a JPEG its end-of-image marker (``FFD9``) after the last scan. The size in the header
is checked against :data:`MAX_PIXELS` before decoding, so a header claiming 10⁹ pixels is
refused instead of allocated; the decoded array must have the size the header gave. EXIF
orientation is ignored (pixels as stored: the labels and the camera matrix refer to them).

Example:
    >>> import cv2
    >>> bgr = np.zeros((2, 3, 3), np.uint8); bgr[0, 0] = (255, 0, 0)  # blue in OpenCV's order
    >>> rgb = decode_image(cv2.imencode(".png", bgr)[1].tobytes(), "x.png")
    >>> rgb.shape, rgb[0, 0].tolist()
    ((2, 3, 3), [0, 0, 255])
"""

from __future__ import annotations

import re
import zlib
from os import PathLike
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError

#: The largest image read (pixels; 8192 × 8192): a bigger header is taken as damage, not a photo.
MAX_PIXELS = 1 << 26
#: Depth PNGs store metres × this (KITTI's depth benchmark and ``lidarfuzz gen --camera``).
DEPTH_SCALE = 256.0

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_SOI = b"\xff\xd8\xff"
#: Start-of-frame markers that carry the image size (not DHT C4, JPG C8, DAC CC).
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: In entropy-coded data 0xFF is followed by 0x00 (stuffing), a restart marker or fill 0xFF;
#: anything else ends the scan.
_SCAN_END = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")

ImageKind = Literal["png", "jpeg"]


def image_kind(data: bytes | memoryview) -> ImageKind | None:
    """``png`` or ``jpeg`` from the first bytes; None for anything else."""
    head = bytes(data[:8])
    if head.startswith(_PNG_SIGNATURE):
        return "png"
    if head.startswith(_JPEG_SOI):
        return "jpeg"
    return None


def _png_walk(data: bytes) -> tuple[tuple[int, int] | None, bool]:
    """(height, width) from IHDR and whether the chunks reach IEND intact."""
    size = None
    at, end = 8, len(data)
    while at + 8 <= end:
        length = int.from_bytes(data[at:at + 4], "big")
        kind = data[at + 4:at + 8]
        if kind == b"IHDR" and at + 16 <= end:
            size = int.from_bytes(data[at + 12:at + 16], "big"), int.from_bytes(data[at + 8:at + 12], "big")
        stop = at + 12 + length  # length, type, data, CRC
        if stop > end:
            return size, False
        if kind == b"IEND":
            return size, True
        at = stop
    return size, False


def _png_damage(data: bytes, height: int, width: int) -> str | None:
    """Why a complete PNG's chunks are damaged (a CRC that does not match, image data that is not a
    whole zlib stream), or None: checked here so that libpng neither prints to stderr nor decodes it."""
    at, stream = 8, zlib.decompressobj()
    # 8 bytes per pixel (16-bit RGBA) and a filter byte per row: no valid image inflates to more
    budget = height * (1 + width * 8)
    inflated, ended = 0, False
    while at + 12 <= len(data):
        length = int.from_bytes(data[at:at + 4], "big")
        kind, body = data[at + 4:at + 8], data[at + 8:at + 8 + length]
        crc = int.from_bytes(data[at + 8 + length:at + 12 + length], "big")
        name = kind.decode("latin-1")
        if zlib.crc32(kind + body) != crc:
            return f"chunk {name!r} at byte {at} fails its CRC check"
        if kind == b"IDAT" and not ended:
            try:
                while body and inflated <= budget:
                    inflated += len(stream.decompress(body, 1 << 20))
                    body = stream.unconsumed_tail
                ended = stream.eof
            except zlib.error as exc:
                return f"its image data is not a valid zlib stream ({exc})"
            if inflated > budget:
                return f"its image data inflates to more than {width}×{height} pixels hold"
        if kind == b"IEND":
            break
        at += 12 + length
    return None if ended else "its image data ends before the zlib stream does"


def _jpeg_walk(data: bytes) -> tuple[tuple[int, int] | None, bool]:
    """(height, width) from the first start-of-frame and whether an end-of-image marker follows the scans."""
    size = None
    at, end = 2, len(data)
    while at < end:
        if data[at] != 0xFF:
            return size, False  # not a marker where one must be: damaged
        while at < end and data[at] == 0xFF:
            at += 1
        if at >= end:
            break
        marker = data[at]
        at += 1
        if marker == 0xD9:
            return size, True
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            continue  # markers without a length
        if at + 2 > end:
            break
        length = int.from_bytes(data[at:at + 2], "big")
        if marker in _SOF and size is None and at + 7 <= end:
            size = int.from_bytes(data[at + 3:at + 5], "big"), int.from_bytes(data[at + 5:at + 7], "big")
        at += length
        if at > end:
            break
        if marker == 0xDA:  # start of scan: entropy-coded data runs to the next real marker
            found = _SCAN_END.search(data, at)
            if found is None:
                break
            at = found.start()
    return size, False


def image_header(data: bytes, source: str | PathLike[str]) -> tuple[ImageKind, int, int]:
    """The kind and (height, width) of PNG/JPEG bytes, checked complete and not oversized.

    Raises:
        DataFormatError: Not a PNG or JPEG, truncated (no ``IEND`` / end-of-image marker),
            no size in the header, a zero size, or more than :data:`MAX_PIXELS` pixels.
    """
    kind = image_kind(data)
    if kind is None:
        found = "the file is empty" if not data else f"it starts with {bytes(data[:8])!r}"
        raise DataFormatError(source, f"not a PNG or JPEG image ({found})")
    size, complete = _png_walk(data) if kind == "png" else _jpeg_walk(data)
    name = kind.upper()
    if size is None:
        raise DataFormatError(source, f"corrupt {name}: no image size in the header ({len(data)} bytes)")
    if not complete:
        end = "IEND chunk" if kind == "png" else "end-of-image marker (FFD9)"
        raise DataFormatError(source, f"truncated {name}: no {end} after {len(data)} bytes",
                              hint="the file was cut short; copy it again")
    height, width = size
    check_size(height, width, source)
    damage = _png_damage(bytes(data), height, width) if kind == "png" else None
    if damage is not None:
        raise DataFormatError(source, f"corrupt PNG: {damage}")
    return kind, height, width


def check_size(height: int, width: int, source: str | PathLike[str], *, field: str | None = None) -> None:
    """Refuse an empty image or one above :data:`MAX_PIXELS`, before allocating it."""
    if height <= 0 or width <= 0:
        raise DataFormatError(source, f"image size {width}×{height} is empty", field=field)
    if height * width > MAX_PIXELS:
        raise DataFormatError(source, f"image size {width}×{height} ({height * width:,} pixels) exceeds the "
                              f"{MAX_PIXELS:,} lidarfuzz reads", field=field, hint="a damaged header, or resize it")


def decode_image(data: bytes, source: str | PathLike[str]) -> NDArray[np.uint8]:
    """PNG or JPEG bytes as an H×W×3 uint8 RGB array (grey and alpha images made RGB).

    Raises:
        DataFormatError: See :func:`image_header`; also bytes OpenCV cannot decode, or a
            decoded size other than the header's.
    """
    import cv2  # OpenCV takes a fifth of a second to import: loaded when an image is decoded

    kind, height, width = image_header(data, source)
    flags = cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if bgr is None:
        raise DataFormatError(source, f"corrupt {kind.upper()}: OpenCV cannot decode it")
    if bgr.shape[:2] != (height, width):
        raise DataFormatError(source, f"corrupt {kind.upper()}: decoded {bgr.shape[1]}×{bgr.shape[0]} but the "
                              f"header says {width}×{height}")
    return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))


def decode_depth(data: bytes, source: str | PathLike[str]) -> NDArray[np.float32]:
    """A uint16 depth PNG (metres × 256, 0 = nothing measured: sky) as H×W float32 metres, 0 → ``inf``.

    Raises:
        DataFormatError: Not a complete PNG (see :func:`image_header`), or not one 16-bit channel.
    """
    import cv2  # OpenCV takes a fifth of a second to import: loaded when an image is decoded

    kind, _, _ = image_header(data, source)
    if kind != "png":
        raise DataFormatError(source, "a depth map must be a 16-bit PNG, not a JPEG")
    raw = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise DataFormatError(source, "corrupt PNG: OpenCV cannot decode it")
    if raw.dtype != np.uint16 or raw.ndim != 2:
        channels = 1 if raw.ndim == 2 else raw.shape[2]
        raise DataFormatError(source, f"a depth map must be one 16-bit channel, found {channels} channel(s) of "
                              f"{raw.dtype}", hint="metres × 256 as uint16, 0 where nothing was hit")
    depth = raw.astype(np.float32) / np.float32(DEPTH_SCALE)
    depth[raw == 0] = np.inf
    return depth


#: ``sensor_msgs/Image`` encodings read: channels and OpenCV's conversion to RGB (None: already RGB).
RAW_ENCODINGS: dict[str, tuple[int, str | None]] = {
    "rgb8": (3, None),
    "bgr8": (3, "COLOR_BGR2RGB"),
    "mono8": (1, "COLOR_GRAY2RGB"),
    "rgba8": (4, "COLOR_RGBA2RGB"),
    "bgra8": (4, "COLOR_BGRA2RGB"),
}


def decode_raw(height: int, width: int, encoding: str, step: int, data: bytes | memoryview | NDArray[np.uint8],
               source: str | PathLike[str], where: str) -> NDArray[np.uint8]:
    """The pixels of a ``sensor_msgs/Image`` as H×W×3 RGB; ``step`` (bytes per row) may pad rows.

    Args:
        height, width, encoding, step, data: The message's fields.
        source: The log (named in errors).
        where: ``topic /camera, message 3`` — placed before each message.

    Raises:
        DataFormatError: An encoding not in :data:`RAW_ENCODINGS`, an empty or oversized image, a
            step shorter than a row, or data whose length is not height × step.
    """
    if encoding not in RAW_ENCODINGS:
        raise DataFormatError(source, f"{where}: encoding {encoding!r} is not one of {', '.join(RAW_ENCODINGS)}",
                              field="encoding")
    channels, conversion = RAW_ENCODINGS[encoding]
    check_size(height, width, source, field="height")
    if step < width * channels:
        raise DataFormatError(source, f"{where}: step {step} is shorter than a row of {width} {encoding} pixels "
                              f"({width * channels} bytes)", field="step")
    buffer = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1)
    if buffer.size != height * step:
        raise DataFormatError(source, f"{where}: data has {buffer.size} bytes but height × step is "
                              f"{height} × {step} = {height * step}", field="data")
    pixels = buffer.reshape(height, step)[:, :width * channels].reshape(height, width, channels)
    if conversion is None:
        return np.ascontiguousarray(pixels)
    import cv2  # OpenCV takes a fifth of a second to import: loaded when an image is decoded

    return np.ascontiguousarray(cv2.cvtColor(np.ascontiguousarray(pixels), getattr(cv2, conversion)))
