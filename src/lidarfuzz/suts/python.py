"""Any Python callable or object as a system under test.

The callable receives the sample (a :class:`~lidarfuzz.scene.scene.Scene`) — or, with
``input="points"``, the N×4 float32 array ``x, y, z, intensity`` most detectors eat — and
returns detections in one of the shapes detectors return them:

* a :class:`~lidarfuzz.scene.boxes.Boxes3D`;
* OpenPCDet's prediction dict ``{"pred_boxes", "pred_scores", "pred_labels"}`` (1-based ids);
* mmdetection3d's ``{"bboxes_3d", "scores_3d", "labels_3d"}`` (0-based ids, bottom origin);
* a plain ``{"boxes", "scores", "labels"}`` dict or a ``(boxes, labels, scores)`` tuple, in
  the declared ``convention``.

Tensors are accepted wherever arrays are (anything with ``.numpy()`` or ``__array__``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal

import numpy as np

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import SystemUnderTest
from lidarfuzz.suts.conventions import Convention, detections
from lidarfuzz.suts.processes import MAX_BOXES


def _numpy(value: Any) -> Any:
    if hasattr(value, "detach"):
        value = value.detach()
    if hasattr(value, "cpu"):
        value = value.cpu()
    if hasattr(value, "tensor"):  # mmdet3d box structures keep their array in .tensor
        value = value.tensor
        return _numpy(value)
    return np.asarray(value)


def to_detections(
    output: Any, convention: Convention = "lidarfuzz", class_names: Sequence[str] | None = None
) -> Boxes3D:
    """Normalise a detector's return value (see the module docstring) to lidarfuzz detections."""
    if isinstance(output, Boxes3D):
        return output
    if isinstance(output, Mapping):
        if "pred_boxes" in output:
            return detections(
                _numpy(output["pred_boxes"]), _numpy(output["pred_labels"]), _numpy(output["pred_scores"]),
                "openpcdet", class_names,
            )
        if "bboxes_3d" in output:
            conv: Convention = convention if convention.startswith("mmdet3d") else "mmdet3d"
            return detections(
                _numpy(output["bboxes_3d"]), _numpy(output["labels_3d"]), _numpy(output["scores_3d"]), conv, class_names
            )
        if "boxes" in output:
            return detections(
                _numpy(output["boxes"]), _numpy(output["labels"]), _numpy(output["scores"]), convention, class_names
            )
        raise TypeError(f"unrecognised detection dict with keys {sorted(output)}")
    if isinstance(output, tuple) and len(output) == 3:
        boxes, labels, scores = output
        return detections(_numpy(boxes), _numpy(labels), _numpy(scores), convention, class_names)
    expected = "Boxes3D, a detection dict or a (boxes, labels, scores) tuple"
    raise TypeError(f"expected {expected}, got {type(output).__name__}")


class PythonSut(SystemUnderTest[Scene, Boxes3D]):
    """A callable (or an object with ``detect``/``__call__``) as a SUT.

    Args:
        target: The detector.
        name: Report name (default: the callable's qualified name).
        version: Its version (part of the fingerprint).
        input: ``"scene"`` or ``"points"`` (N×4 x, y, z, intensity).
        convention: Box convention of plain outputs.
        class_names: Names of integer class ids.
        classes: Classes it may output (None: any).
        config: Extra JSON-able configuration for the fingerprint (e.g. a checkpoint hash).
        max_boxes: Most detections accepted per sample (default 10,000; more are an
            ``invalid_output`` when the call is guarded).
    """

    def __init__(
        self,
        target: Callable[[Any], Any],
        *,
        name: str | None = None,
        version: str = "0",
        input: Literal["scene", "points"] = "scene",
        convention: Convention = "lidarfuzz",
        class_names: Sequence[str] | None = None,
        classes: Sequence[str] | None = ("Car", "Pedestrian", "Cyclist"),
        config: Mapping[str, Any] | None = None,
        max_boxes: int = MAX_BOXES,
    ) -> None:
        self.target = target
        self.name = name or str(getattr(target, "__qualname__", type(target).__name__))  # type: ignore[misc]
        self.version = version  # type: ignore[misc]
        self.input = input
        self.convention = convention
        self.class_names = list(class_names) if class_names is not None else None
        self.classes = tuple(classes) if classes is not None else None  # type: ignore[misc]
        self._config = dict(config or {})
        if isinstance(max_boxes, bool) or not isinstance(max_boxes, int) or max_boxes < 0:
            raise ValueError(f"max_boxes: expected a whole number >= 0, got {max_boxes!r}")
        self.max_boxes = max_boxes

    def config(self) -> dict[str, Any]:
        module = getattr(self.target, "__module__", "")
        return {
            "target": f"{module}:{getattr(self.target, '__qualname__', type(self.target).__name__)}",
            "input": self.input,
            "convention": self.convention,
            "class_names": self.class_names,
            **self._config,
        }

    def code_objects(self) -> tuple[Any, ...]:
        """The adapter's class and the target (its module, or its class's for an object)."""
        return type(self), self.target

    def load(self) -> None:
        loader = getattr(self.target, "load", None)
        if callable(loader):
            loader()

    def close(self) -> None:
        closer = getattr(self.target, "close", None)
        if callable(closer):
            closer()

    def detect(self, sample: Scene) -> Boxes3D:
        fn = getattr(self.target, "detect", self.target)
        arg: Any = sample
        if self.input == "points":
            arg = np.ascontiguousarray(sample.points.data[:, :4], dtype=np.float32)
        return to_detections(fn(arg), self.convention, self.class_names)
