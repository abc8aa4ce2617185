"""Steering systems of the camera modality: the contract, adapters and the built-in networks.

* :mod:`~lidarfuzz.suts.steering.base` — :class:`Steering` (the answer) and :class:`SteeringSystem`;
* :mod:`~lidarfuzz.suts.steering.preprocess` — crop, resize, colour space, scaling (OpenCV);
* adapters: :mod:`~lidarfuzz.suts.steering.pytorch` (any ``torch.nn.Module``),
  :mod:`~lidarfuzz.suts.steering.onnx` (ONNX Runtime; Keras models via tf2onnx),
  :mod:`~lidarfuzz.suts.steering.worker` (a program over the worker protocol);
* built-ins: :mod:`~lidarfuzz.suts.steering.builtin` (``epoch``, ``dave2``, ``chauffeur``;
  architectures in :mod:`~lidarfuzz.suts.steering.networks`, weights and model card in ``weights/``).

Spec strings (``dave2``, ``onnx:model.onnx?...``, ``worker:COMMAND``, ``pkg.module:Net``) are
read by :func:`lidarfuzz.suts.registry.create_camera`.
"""

from lidarfuzz.suts.steering.base import DEFAULT_RANGE, Steering, SteeringSystem, validate_steering
from lidarfuzz.suts.steering.preprocess import Preprocess

__all__ = ["DEFAULT_RANGE", "Preprocess", "Steering", "SteeringSystem", "validate_steering"]
