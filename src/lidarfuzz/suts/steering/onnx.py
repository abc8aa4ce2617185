"""An ONNX steering model run by ONNX Runtime on the CPU (extra ``onnx``).

The model's first input takes the frames after the declared
:class:`~lidarfuzz.suts.steering.preprocess.Preprocess`; its first output holds one angle
per frame ((N,) or (N, 1)).

**Input layout.** ``layout="nchw"`` (the default; what ``torch.onnx.export`` writes) puts the
channels first, N×3×H×W; ``layout="nhwc"`` keeps them last, N×H×W×3 — what Keras/TensorFlow
models exported with ``tf2onnx`` (``python -m tf2onnx.convert --saved-model DIR --output
model.onnx``) expect, since TensorFlow holds images channels last. A model whose batch
dimension is fixed at 1 is run one frame at a time.

Spec: ``onnx:model.onnx?height=66&width=200&color=yuv&layout=nhwc`` (Preprocess fields and the
options below).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.code import distribution_version
from lidarfuzz.suts.steering.base import Steering, SteeringSystem, checked_range
from lidarfuzz.suts.steering.preprocess import Preprocess, as_preprocess
from lidarfuzz.suts.steering.pytorch import angles


class OnnxSteering(SteeringSystem):
    """An ONNX steering model.

    Args:
        path: The ``.onnx`` file.
        preprocess: What the model eats (a :class:`Preprocess` or its fields).
        layout: ``nchw`` (PyTorch exports) or ``nhwc`` (Keras/TensorFlow exports via tf2onnx).
        steering_range: (low, high) of a valid answer (default ±π/2).
        threads: ONNX Runtime intra-op threads.
        name: Report name (default: the file's stem).
        version: Its version.
    """

    def __init__(self, path: str | Path, *, preprocess: Preprocess | Mapping[str, Any] | None = None,
                 layout: Literal["nchw", "nhwc"] = "nchw", steering_range: Sequence[float] | None = None,
                 threads: int = 1, name: str | None = None, version: str = "0") -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise DataFormatError(self.path, "no such ONNX model file")
        if layout not in ("nchw", "nhwc"):
            raise ValueError(f"layout must be 'nchw' or 'nhwc', got {layout!r}")
        self.preprocess = as_preprocess(preprocess)
        self.layout = layout
        self.steering_range = checked_range(steering_range)  # type: ignore[misc]
        self.threads = int(threads)
        self.name = name or self.path.stem  # type: ignore[misc]
        self.version = version  # type: ignore[misc]
        self._session: Any = None

    def config(self) -> dict[str, Any]:
        return {"preprocess": self.preprocess.model_dump(mode="json"), "layout": self.layout,
                "steering_range": list(self.steering_range)}

    def weight_files(self) -> Sequence[Path]:
        return [self.path]

    def code(self) -> dict[str, str]:
        """The Python code and the installed ONNX Runtime's version (it computes the output)."""
        return {**super().code(), "dist:onnxruntime": distribution_version("onnxruntime") or "not installed"}

    def load(self) -> None:
        if self._session is not None:
            return
        from lidarfuzz.suts.onnx import onnx_session

        self._session = onnx_session(self.path, self.threads)

    def close(self) -> None:
        self._session = None

    def inputs(self, samples: Sequence[ImageSample]) -> NDArray[np.float32]:
        """The array the model's first input gets for these frames (in its layout)."""
        batch = self.preprocess.batch([s.image for s in samples])
        return np.ascontiguousarray(batch.transpose(0, 3, 1, 2) if self.layout == "nchw" else batch)

    def detect_batch(self, samples: Sequence[ImageSample]) -> list[Steering]:
        self.load()
        first = self._session.get_inputs()[0]
        batch = self.inputs(samples)
        if first.shape and first.shape[0] == 1 and len(samples) > 1:  # a fixed batch of one
            values = np.concatenate([self._run(first.name, batch[i:i + 1]) for i in range(len(samples))])
        else:
            values = self._run(first.name, batch)
        return [Steering(float(v)) for v in values]

    def _run(self, input_name: str, batch: NDArray[np.float32]) -> NDArray[np.float64]:
        output = self._session.run(None, {input_name: batch})[0]
        return angles(output, int(batch.shape[0]), f"{self.name} output")
