"""Neuron values from any ``torch.nn.Module``: forward hooks on post-activation outputs.

:class:`ActivationRecorder` hooks the layers coverage watches — by default the model's
``coverage_layers()`` when it defines one, else every activation module (ReLU, GELU, …),
so values are taken after the non-linearity — and turns each output into one value per
neuron and input: an (N, C, *spatial) output is averaged over its spatial positions (a
convolution channel is one neuron, as DeepTest counts them), (N, F) is kept, (N,) becomes
(N, 1). A layer whose first dimension is not the batch (a point-wise layer, say) needs a
``reducers[name]`` callable that returns (N, units). A module called twice in one forward
gives two layers, ``name`` and ``name#2``.

The recorder works in grad mode too; values are detached copies on the CPU.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.coverage.criteria import CoverageError

ACTIVATIONS = ("ReLU", "ReLU6", "LeakyReLU", "ELU", "GELU", "SiLU", "Sigmoid", "Tanh", "Hardswish", "Mish",
               "Softplus", "PReLU", "SELU", "CELU", "Hardtanh")


def _torch() -> Any:
    from lidarfuzz.suts.learned.sut import import_torch

    return import_torch()


def default_layers(model: Any) -> list[str]:
    """``model.coverage_layers()`` if it has one, else the names of its activation modules."""
    chooser = getattr(model, "coverage_layers", None)
    if callable(chooser):
        return list(chooser())
    torch = _torch()
    kinds = tuple(getattr(torch.nn, k) for k in ACTIVATIONS if hasattr(torch.nn, k))
    return [name for name, module in model.named_modules() if name and isinstance(module, kinds)]


def reduce_output(output: Any) -> Any:
    """(N, C, *spatial) → channel means (N, C); (N, F) kept; (N,) → (N, 1)."""
    if output.dim() > 2:
        return output.flatten(2).mean(dim=2)
    if output.dim() == 1:
        return output[:, None]
    return output


class ActivationRecorder:
    """Records neuron values of chosen layers while hooks are on (``with recorder: model(x)``).

    Args:
        model: Any ``torch.nn.Module``.
        layers: Module names (``model.named_modules()``); default: :func:`default_layers`.
        reducers: Per-layer functions from the raw output to (N, units).

    Example:
        >>> import torch
        >>> net = torch.nn.Sequential(torch.nn.Linear(2, 3), torch.nn.ReLU())
        >>> recorder = ActivationRecorder(net)
        >>> with recorder:
        ...     _ = net(torch.ones(4, 2))
        >>> recorder.values()["1"].shape
        (4, 3)
    """

    def __init__(self, model: Any, layers: Iterable[str] | None = None,
                 reducers: Mapping[str, Callable[[Any], Any]] | None = None) -> None:
        self.model = model
        modules = dict(model.named_modules())
        names = list(layers) if layers is not None else default_layers(model)
        if not names:
            raise CoverageError(f"{type(model).__name__} has no activation modules to watch; name the layers")
        unknown = [n for n in names if n not in modules]
        if unknown:
            some = ", ".join(n for n in list(modules)[1:6])
            raise CoverageError(f"{type(model).__name__} has no layer(s) {unknown}; its modules include {some}")
        self.layers = names
        self.reducers = dict(reducers or {})
        self._modules = {n: modules[n] for n in names}
        self._handles: list[Any] = []
        self._calls: dict[str, int] = {}
        self._values: dict[str, list[NDArray[np.float32]]] = {}

    def _hook(self, name: str) -> Callable[..., None]:
        def hook(_module: Any, _inputs: Any, output: Any) -> None:
            count = self._calls.get(name, 0) + 1
            self._calls[name] = count
            key = name if count == 1 else f"{name}#{count}"
            reduce = self.reducers.get(name, reduce_output)
            value = reduce(output.detach())
            self._values.setdefault(key, []).append(value.float().cpu().numpy())
        return hook

    def __enter__(self) -> ActivationRecorder:
        self._handles = [m.register_forward_hook(self._hook(n)) for n, m in self._modules.items()]

        # each top-level forward starts a new count of calls per module
        def reset_pre_hook(*_args: Any) -> None:
            self._calls = {}

        self._handles.append(self.model.register_forward_pre_hook(reset_pre_hook))
        return self

    def __exit__(self, *exc: object) -> None:
        for handle in self._handles:
            handle.remove()
        self._handles = []

    @property
    def active(self) -> bool:
        return bool(self._handles)

    def clear(self) -> None:
        self._values, self._calls = {}, {}

    def values(self) -> dict[str, NDArray[np.float32]]:
        """``{layer: (N, units)}`` for every input of the forwards since :meth:`clear`."""
        return {name: np.concatenate(parts, axis=0) for name, parts in self._values.items()}


def neuron_values(model: Any, batch: Any, layers: Iterable[str] | None = None,
                  forward: Callable[[Any], Any] | None = None,
                  reducers: Mapping[str, Callable[[Any], Any]] | None = None) -> dict[str, NDArray[np.float32]]:
    """Neuron values of one batch: runs ``forward(batch)`` (default ``model(batch)``) without gradients."""
    torch = _torch()
    recorder = ActivationRecorder(model, layers, reducers)
    with torch.inference_mode(), recorder:
        (forward or model)(batch)
    return recorder.values()


def layer_sizes(values: Mapping[str, NDArray[Any]]) -> dict[str, int]:
    return {name: int(array.shape[1]) for name, array in values.items()}


def module_fingerprint(model: Any) -> str:
    """16 hex characters identifying a module's class and weights (stable across processes)."""
    digest = hashlib.sha256(f"{type(model).__module__}.{type(model).__qualname__}".encode())
    for name, tensor in sorted(model.state_dict().items()):
        array = tensor.detach().cpu().contiguous().numpy()
        digest.update(f"{name}|{array.dtype}|{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()[:16]
