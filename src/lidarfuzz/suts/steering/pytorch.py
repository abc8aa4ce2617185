"""Any PyTorch module as a steering system (extra ``learned``).

The module takes an N×3×H×W float32 tensor — frames after its declared
:class:`~lidarfuzz.suts.steering.preprocess.Preprocess` — and returns N steering angles
(shape (N,) or (N, 1)). It runs on the CPU in eval mode under ``torch.inference_mode()``.

Example:
    >>> import torch
    >>> net = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(3 * 2 * 2, 1))
    >>> system = TorchSteering(net, preprocess={"height": 2, "width": 2})
    >>> system.preprocess.height, system.steering_range[1] > 0
    (2, True)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import MissingDependencyError
from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.base import FailureKind
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.steering.base import Steering, SteeringSystem, checked_range
from lidarfuzz.suts.steering.preprocess import Preprocess, as_preprocess


def import_torch() -> Any:
    """``torch``, or an ImportError naming the extra that installs it."""
    try:
        import torch
    except ImportError:
        raise MissingDependencyError("torch", "learned", "PyTorch steering networks") from None
    return torch


def angles(output: Any, count: int, where: str) -> NDArray[np.float64]:
    """A network's output for ``count`` frames as (count,) float64 angles.

    Raises:
        SutError: ``invalid_output`` when it does not hold exactly one number per frame.
    """
    array = np.asarray(output.detach().cpu().numpy() if hasattr(output, "detach") else output, dtype=np.float64)
    if array.size != count or (array.ndim > 1 and array.shape[0] != count):
        raise SutError(FailureKind.INVALID_OUTPUT, f"{where}: expected one steering value per frame ({count}), "
                       f"got an output of shape {tuple(array.shape)}")
    return array.reshape(count)


class TorchSteering(SteeringSystem):
    """A ``torch.nn.Module`` as a steering system.

    Args:
        module: The network (its class's source and its state dict are part of the fingerprint).
        preprocess: What the network eats (a :class:`Preprocess` or its fields).
        steering_range: (low, high) of a valid answer (default ±π/2).
        threads: Threads PyTorch may use (``torch.set_num_threads`` on load).
        batch_size: Frames per forward pass in :meth:`detect_batch`.
        name: Report name (default: the module's class name).
        version: Its version.
    """

    def __init__(self, module: Any, *, preprocess: Preprocess | Mapping[str, Any] | None = None,
                 steering_range: Sequence[float] | None = None, threads: int = 1, batch_size: int = 64,
                 name: str | None = None, version: str = "0") -> None:
        if not hasattr(module, "state_dict") or not callable(module):
            raise TypeError(f"TorchSteering needs a torch.nn.Module, got {type(module).__name__}")
        self.module = module
        self.preprocess = as_preprocess(preprocess)
        self.steering_range = checked_range(steering_range)  # type: ignore[misc]
        if threads < 1 or batch_size < 1:
            raise ValueError(f"threads and batch_size must be ≥ 1, got {threads} and {batch_size}")
        self.threads = int(threads)
        self.batch_size = int(batch_size)
        self.name = name or type(module).__name__  # type: ignore[misc]
        self.version = version  # type: ignore[misc]

    def config(self) -> dict[str, Any]:
        from lidarfuzz.coverage.hooks import module_fingerprint

        return {"preprocess": self.preprocess.model_dump(mode="json"), "steering_range": list(self.steering_range),
                "module": f"{type(self.module).__module__}:{type(self.module).__qualname__}",
                "state": module_fingerprint(self.module)}

    def code_objects(self) -> tuple[Any, ...]:
        """The adapter and the network's class (its module's source)."""
        return type(self), type(self.module)

    def code(self) -> dict[str, str]:
        """The Python code and torch's version (it computes the output)."""
        from lidarfuzz.suts.code import distribution_version

        return {**super().code(), "dist:torch": distribution_version("torch") or "not installed"}

    def load(self) -> None:
        torch = import_torch()
        torch.set_num_threads(self.threads)
        self.module.eval()

    @property
    def coverage_module(self) -> Any:
        """The ``torch.nn.Module`` neuron coverage watches."""
        return self.module

    def inputs(self, samples: Sequence[ImageSample]) -> Any:
        """The N×3×H×W float32 tensor the network sees for these frames."""
        torch = import_torch()
        batch = self.preprocess.batch([s.image for s in samples])
        return torch.from_numpy(np.ascontiguousarray(batch.transpose(0, 3, 1, 2)))

    def forward(self, batch: Any) -> NDArray[np.float64]:
        """Angles of a preprocessed N×3×H×W batch (one forward pass, no gradients)."""
        torch = import_torch()
        with torch.inference_mode():
            return angles(self.module(batch), int(batch.shape[0]), f"{self.name} output")

    def detect_batch(self, samples: Sequence[ImageSample]) -> list[Steering]:
        out: list[Steering] = []
        for start in range(0, len(samples), self.batch_size):
            chunk = samples[start:start + self.batch_size]
            out.extend(Steering(float(v)) for v in self.forward(self.inputs(chunk)))
        return out

    def weight_files(self) -> Sequence[Path]:
        return ()
