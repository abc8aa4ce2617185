"""An ONNX model as a system under test, run by ONNX Runtime on CPU (extra ``onnx``).

Pre- and post-processing are pluggable (``module:function`` names or callables):

* ``pre(scene, input_names) -> {input_name: array}`` — default :func:`points_input`: the
  N×4 float32 ``x, y, z, intensity`` cloud as the model's first input;
* ``post(outputs, scene, class_names) -> Boxes3D`` — default :func:`boxes_output`: outputs
  named ``boxes`` (M×7), ``scores`` (M) and ``labels`` (M integer ids), or a single M×9
  output ``[x, y, z, l, w, h, yaw, score, label]``, in the declared box ``convention``.

Class names come from the ``class_names`` option or from the model's metadata (key
``class_names``, a JSON list).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError, MissingDependencyError
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import SystemUnderTest
from lidarfuzz.suts.code import distribution_version
from lidarfuzz.suts.conventions import Convention, detections
from lidarfuzz.suts.specs import import_target

Pre = Callable[[Scene, Sequence[str]], Mapping[str, NDArray[Any]]]
Post = Callable[[Mapping[str, NDArray[Any]], Scene, Sequence[str] | None], Boxes3D]


def points_input(scene: Scene, input_names: Sequence[str]) -> dict[str, NDArray[Any]]:
    """The cloud's ``x, y, z, intensity`` as an N×4 float32 array for the first input."""
    return {input_names[0]: np.ascontiguousarray(scene.points.data[:, :4], dtype=np.float32)}


def boxes_output(
    outputs: Mapping[str, NDArray[Any]], scene: Scene, class_names: Sequence[str] | None,
    convention: Convention = "lidarfuzz",
) -> Boxes3D:
    """``boxes``/``scores``/``labels`` outputs, or one M×9 output, as detections."""
    if {"boxes", "scores", "labels"} <= set(outputs):
        boxes, scores, labels = outputs["boxes"], outputs["scores"], outputs["labels"]
    elif len(outputs) == 1:
        (rows,) = outputs.values()
        rows = np.asarray(rows).reshape(-1, 9)
        boxes, scores, labels = rows[:, :7], rows[:, 7], rows[:, 8].round().astype(np.int64)
    else:
        raise ValueError(f"expected outputs boxes/scores/labels or one M×9 output, got {sorted(outputs)}")
    labels = np.asarray(labels).reshape(-1)
    if np.issubdtype(labels.dtype, np.integer) and class_names is None:
        raise ValueError("the model outputs class ids: give class_names (option or model metadata)")
    return detections(np.asarray(boxes).reshape(-1, 7), labels, np.asarray(scores).reshape(-1), convention, class_names)


def _resolve(value: Any) -> Any:
    return import_target(value) if isinstance(value, str) else value



def onnx_session(path: Path, threads: int) -> Any:
    """An ONNX Runtime CPU session on the model at ``path`` (``threads`` intra-op threads).

    Raises:
        MissingDependencyError: ONNX Runtime (extra ``onnx``) is not installed.
        DataFormatError: ONNX Runtime cannot load the file (named).
    """
    try:
        import onnxruntime as ort  # optional extra 'onnx', needed only to run a model
    except ImportError:
        raise MissingDependencyError("onnxruntime", "onnx", "running ONNX models") from None
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    try:
        return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # ONNX Runtime raises its own exception types for bad files
        raise DataFormatError(path, f"ONNX Runtime cannot load the model: {exc}") from None

class OnnxSut(SystemUnderTest[Scene, Boxes3D]):
    """An ONNX model.

    Args:
        path: The ``.onnx`` file.
        pre: Pre-processing (callable or ``module:function``).
        post: Post-processing (callable or ``module:function``).
        class_names: Names of the model's class ids (else from its metadata).
        convention: Box convention of the default post-processing.
        threads: ONNX Runtime intra-op threads.
        name: Report name (default: the file's stem).
        version: Its version.
    """

    def __init__(
        self,
        path: str,
        *,
        pre: str | Pre = points_input,
        post: str | Post | None = None,
        class_names: Sequence[str] | None = None,
        convention: Convention = "lidarfuzz",
        threads: int = 1,
        name: str | None = None,
        version: str = "0",
    ) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise DataFormatError(self.path, "no such ONNX model file")
        self.pre: Pre = _resolve(pre)
        self.post: Post | None = _resolve(post) if post is not None else None
        self.class_names = list(class_names) if class_names is not None else None
        self.convention = convention
        self.threads = int(threads)
        self.name = name or self.path.stem  # type: ignore[misc]
        self.version = version  # type: ignore[misc]
        self._session: Any = None

    def config(self) -> dict[str, Any]:
        def label(fn: Any) -> str | None:
            return None if fn is None else f"{getattr(fn, '__module__', '')}:{getattr(fn, '__qualname__', fn)}"

        return {"pre": label(self.pre), "post": label(self.post), "class_names": self.class_names,
                "convention": self.convention}

    def weight_files(self) -> Sequence[Path]:
        return [self.path]

    def code_objects(self) -> tuple[Any, ...]:
        """The adapter and the pre- and post-processing hooks (their modules' source)."""
        return tuple(obj for obj in (type(self), self.pre, self.post) if obj is not None)

    def code(self) -> dict[str, str]:
        """The Python code, with the installed ONNX Runtime's version (it computes the output)."""
        return {**super().code(), "dist:onnxruntime": distribution_version("onnxruntime") or "not installed"}

    def load(self) -> None:
        if self._session is not None:
            return
        self._session = onnx_session(self.path, self.threads)
        if self.class_names is None:
            meta = self._session.get_modelmeta().custom_metadata_map
            if "class_names" in meta:
                self.class_names = list(json.loads(meta["class_names"]))

    def close(self) -> None:
        self._session = None

    def detect(self, sample: Scene) -> Boxes3D:
        self.load()
        inputs = [i.name for i in self._session.get_inputs()]
        names = [o.name for o in self._session.get_outputs()]
        values = self._session.run(None, dict(self.pre(sample, inputs)))
        outputs = dict(zip(names, values, strict=True))
        if self.post is not None:
            return self.post(outputs, sample, self.class_names)
        return boxes_output(outputs, sample, self.class_names, self.convention)
