"""What a steering network eats: crop, resize, colour space and scaling of an RGB frame.

A :class:`Preprocess` is declared with the network (part of its fingerprint) and applied with
OpenCV in this order:

1. **crop**: ``crop_top`` and ``crop_bottom`` are fractions of the frame's rows removed at the
   top (sky) and bottom (bonnet); fractions, so one declaration serves frames of any size;
2. **resize** to ``height`` × ``width`` (``interpolation``: ``area`` — OpenCV's INTER_AREA, the
   right filter for shrinking — or ``linear``);
3. **colour space** on the uint8 pixels: ``rgb`` (as read), ``bgr`` (OpenCV's and Caffe's order)
   or ``yuv`` (OpenCV's ``COLOR_RGB2YUV``: Y = 0.299 R + 0.587 G + 0.114 B,
   U = 0.492 (B − Y) + 128, V = 0.877 (R − Y) + 128, rounded; DAVE-2's input);
4. **scaling**: ``value · scale + offset`` as float32 (default ``/255``: [0, 1]; DAVE-2's
   ``x / 127.5 − 1`` is ``scale=1/127.5, offset=-1``).

The result is N×H×W×C float32 (channels last, as OpenCV and Keras hold images); wrappers put
the channels first for PyTorch, or for an ONNX model declared ``layout="nchw"``.

Example:
    >>> import numpy as np
    >>> frame = np.full((4, 6, 3), 255, np.uint8)
    >>> Preprocess(height=2, width=3).apply(frame).shape
    (2, 3, 3)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

_INTERPOLATION = {"area": cv2.INTER_AREA, "linear": cv2.INTER_LINEAR}


class Preprocess(BaseModel):
    """How a frame becomes a network input (see the module docstring for the order)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    height: int = Field(default=66, ge=1, le=4096, description="input rows of the network")
    width: int = Field(default=200, ge=1, le=4096, description="input columns of the network")
    crop_top: float = Field(default=0.0, ge=0.0, lt=1.0, description="fraction of the frame's rows cut at the top")
    crop_bottom: float = Field(default=0.0, ge=0.0, lt=1.0,
                               description="fraction of the frame's rows cut at the bottom")
    color: Literal["rgb", "bgr", "yuv"] = Field(default="rgb", description="colour space of the input")
    scale: float = Field(default=1.0 / 255.0, description="each 8-bit value is multiplied by this")
    offset: float = Field(default=0.0, description="then this is added")
    interpolation: Literal["area", "linear"] = Field(default="area", description="OpenCV resize filter")

    @model_validator(mode="after")
    def _crop_leaves_rows(self) -> Preprocess:
        if self.crop_top + self.crop_bottom >= 1.0:
            raise ValueError(f"crop_top + crop_bottom must be < 1 (some rows must remain), got "
                             f"{self.crop_top} + {self.crop_bottom}")
        return self

    def crop_rows(self, rows: int) -> tuple[int, int]:
        """The [first, end) rows kept of a frame with ``rows`` rows (at least one)."""
        first = round(rows * self.crop_top)
        end = rows - round(rows * self.crop_bottom)
        return min(first, rows - 1), max(end, min(first, rows - 1) + 1)

    def apply(self, image: NDArray[np.uint8]) -> NDArray[np.float32]:
        """One H×W×3 uint8 RGB frame → ``height`` × ``width`` × 3 float32."""
        return self.scaled(self.pixels(image))

    def pixels(self, image: NDArray[np.uint8]) -> NDArray[np.uint8]:
        """Steps 1–3 (crop, resize, colour space): ``height`` × ``width`` × 3 uint8, what a training
        set caches (8 bits a value instead of 32)."""
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"image must be H×W×3 uint8 RGB, got {image.dtype} of shape {image.shape}")
        first, end = self.crop_rows(image.shape[0])
        pixels: NDArray[Any] = np.ascontiguousarray(image[first:end])
        if pixels.shape[:2] != (self.height, self.width):
            pixels = cv2.resize(pixels, (self.width, self.height), interpolation=_INTERPOLATION[self.interpolation])
        if self.color == "yuv":
            pixels = cv2.cvtColor(pixels, cv2.COLOR_RGB2YUV)
        elif self.color == "bgr":
            pixels = np.ascontiguousarray(pixels[:, :, ::-1])
        return pixels

    def scaled(self, pixels: NDArray[np.uint8]) -> NDArray[np.float32]:
        """Step 4 on the output of :meth:`pixels` (any leading shape): ``value · scale + offset``."""
        out = np.asarray(pixels).astype(np.float32) * np.float32(self.scale)
        if self.offset:
            out += np.float32(self.offset)
        return out

    def batch(self, images: Sequence[NDArray[np.uint8]]) -> NDArray[np.float32]:
        """Several frames → N×H×W×3 float32 (channels last)."""
        out = np.empty((len(images), self.height, self.width, 3), np.float32)
        for i, image in enumerate(images):
            out[i] = self.apply(image)
        return out


def split_options(options: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Spec options → (the :class:`Preprocess` fields among them, the rest)."""
    fields = set(Preprocess.model_fields)
    return ({k: v for k, v in options.items() if k in fields}, {k: v for k, v in options.items() if k not in fields})


def as_preprocess(value: Preprocess | Mapping[str, Any] | None, default: Preprocess | None = None) -> Preprocess:
    """A :class:`Preprocess` from itself, a mapping of its fields, or None (``default``, else the defaults)."""
    if isinstance(value, Preprocess):
        return value
    if value is None:
        return default if default is not None else Preprocess()
    return Preprocess(**dict(value))
