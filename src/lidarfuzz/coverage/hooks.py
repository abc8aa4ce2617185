"""Neuron values from any ``torch.nn.Module``: forward hooks on post-activation outputs.

:class:`ActivationRecorder` hooks the layers coverage watches — by default the model's
``coverage_layers()`` when it defines one, else every activation module (ReLU, GELU, …),
so values are taken after the non-linearity — and turns each output into one value per
neuron and input:

* (N, C, *spatial) → the mean over the spatial positions, (N, C): a convolution channel
  is one neuron, its feature map averaged, as DeepTest counts them;
* (N, F) → kept;
* (N,) → (N, 1).

A layer whose first dimension is not the batch — a pillar or point feature layer of shape
(P, C), say — needs a ``reducers[name]`` callable from its (detached) output to (N, units).
The reducer gets only the output, so it takes whatever else it needs (the pillars' batch
index) from the model or a closure::

    def per_frame_mean(features):  # (P, C) → (N, C)
        index = model.last_batch_index  # (P,) frame of each pillar, kept by the model's forward
        sums = features.new_zeros(int(index.max()) + 1, features.shape[1]).index_add_(0, index, features)
        return sums / torch.bincount(index).unsqueeze(1)

    recorder = ActivationRecorder(model, ["pillars.relu"], reducers={"pillars.relu": per_frame_mean})

A module called more than once in one forward gives one layer per call: ``name``,
``name#2``, ``name#3``, … A forward starts when the model itself is called (or a recording
block is entered), so values of several forwards in one block are concatenated row-wise.

The recorder works in grad mode too; values are detached float32 copies on the CPU.
PyTorch (extra ``learned``) is imported only by the functions that need it.
"""

from __future__ import annotations

import difflib
import hashlib
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.coverage.criteria import CoverageError
from lidarfuzz.errors import MissingDependencyError

#: Activation module classes (names in ``torch.nn``) watched by default.
ACTIVATIONS = ("ReLU", "ReLU6", "LeakyReLU", "ELU", "GELU", "SiLU", "Sigmoid", "Tanh", "Hardswish", "Mish",
               "Softplus", "PReLU", "SELU", "CELU", "Hardtanh")

Reducer = Callable[[Any], Any]


def import_torch() -> Any:
    """``torch``, or an ImportError that names the extra to install."""
    try:
        import torch
    except ImportError:
        raise MissingDependencyError("torch", "learned", "neuron coverage") from None
    return torch


def default_layers(model: Any) -> list[str]:
    """``model.coverage_layers()`` if it has one, else the names of its activation modules (in
    ``named_modules()`` order)."""
    chooser = getattr(model, "coverage_layers", None)
    if callable(chooser):
        names = list(chooser())
        if not all(isinstance(n, str) for n in names):
            raise CoverageError(f"{type(model).__name__}.coverage_layers() must return module names (str), "
                                f"got {names[:3]}")
        return names
    torch = import_torch()
    kinds = tuple(getattr(torch.nn, k) for k in ACTIVATIONS if hasattr(torch.nn, k))
    return [name for name, module in model.named_modules() if name and isinstance(module, kinds)]


def reduce_output(output: Any) -> Any:
    """(N, C, *spatial) → channel means (N, C); (N, F) kept; (N,) → (N, 1)."""
    if output.dim() > 2:
        return output.flatten(2).mean(dim=2)
    if output.dim() == 1:
        return output[:, None]
    if output.dim() == 0:
        raise CoverageError("a layer output is a scalar; there is no batch dimension to read (give it a reducer)")
    return output


def _unknown_layers(model: Any, unknown: list[str], modules: Iterable[str]) -> CoverageError:
    names = [n for n in modules if n]
    close = sorted({m for n in unknown for m in difflib.get_close_matches(n, names, n=3)})
    hint = f"did you mean {close}? " if close else ""
    return CoverageError(f"{type(model).__name__} has no layer(s) {unknown}; {hint}"
                         f"its modules include {names[:6]} (names as in model.named_modules())")


class ActivationRecorder:
    """Records neuron values of chosen layers while hooks are on (``with recorder: model(x)``).

    Args:
        model: Any ``torch.nn.Module``.
        layers: Module names (as in ``model.named_modules()``); default: :func:`default_layers`.
        reducers: Per-layer functions from the raw (detached) output to (N, units), for layers
            whose first dimension is not the batch.

    Raises:
        CoverageError: (a ValueError) an unknown layer or reducer name, or no layer to watch.

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
                 reducers: Mapping[str, Reducer] | None = None) -> None:
        if not hasattr(model, "named_modules"):
            raise CoverageError(f"neuron coverage needs a torch.nn.Module, got {type(model).__name__}")
        self.model = model
        modules = dict(model.named_modules())
        names = list(layers) if layers is not None else default_layers(model)
        if not names:
            raise CoverageError(f"{type(model).__name__} has no activation modules to watch; name the layers "
                                f"(layers=[...], e.g. {[n for n in modules if n][:3]}) or define coverage_layers()")
        unknown = [n for n in names if n not in modules]
        if unknown:
            raise _unknown_layers(model, unknown, modules)
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise CoverageError(f"layer {twice[0]!r} is named twice")
        self.reducers = dict(reducers or {})
        strays = [n for n in self.reducers if n not in names]
        if strays:
            raise CoverageError(f"reducers for {strays}, which are not among the watched layers {names[:6]}")
        self.layers = names
        self._modules = {n: modules[n] for n in names}
        self._handles: list[Any] = []
        self._calls: dict[str, int] = {}
        self._values: dict[str, list[NDArray[np.float32]]] = {}

    def _hook(self, name: str) -> Callable[..., None]:
        def hook(_module: Any, _inputs: Any, output: Any) -> None:
            count = self._calls.get(name, 0) + 1
            self._calls[name] = count
            key = name if count == 1 else f"{name}#{count}"
            if not hasattr(output, "detach"):
                raise CoverageError(f"layer {name!r} returns {type(output).__name__}, not a tensor; watch another "
                                    "module or give this one a reducer")
            reduce = self.reducers.get(name, reduce_output)
            value = reduce(output.detach())
            value = value.detach().float().cpu().numpy() if hasattr(value, "detach") else np.asarray(value, np.float32)
            if value.ndim != 2:
                raise CoverageError(f"layer {name!r}: the reducer must return (inputs, units), got shape "
                                    f"{tuple(value.shape)}")
            self._values.setdefault(key, []).append(value.astype(np.float32, copy=False))
        return hook

    def __enter__(self) -> ActivationRecorder:
        if self._handles:
            raise CoverageError("this recorder is already recording; leave its block before entering it again")
        self._calls = {}

        # each call of the model itself starts a new forward: calls per module are counted anew
        def new_forward(*_args: Any) -> None:
            self._calls = {}

        try:
            for name, module in self._modules.items():
                self._handles.append(module.register_forward_hook(self._hook(name)))
            self._handles.append(self.model.register_forward_pre_hook(new_forward))
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        for handle in self._handles:
            handle.remove()
        self._handles = []

    @property
    def active(self) -> bool:
        """Whether the hooks are on."""
        return bool(self._handles)

    def clear(self) -> None:
        """Forget the recorded values."""
        self._values, self._calls = {}, {}

    def values(self) -> dict[str, NDArray[np.float32]]:
        """``{layer: (N, units)}`` float32 for every input of the forwards since :meth:`clear`, in
        the order the layers ran."""
        return {name: np.concatenate(parts, axis=0) for name, parts in self._values.items()}


def neuron_values(model: Any, batch: Any, layers: Iterable[str] | None = None,
                  forward: Callable[[Any], Any] | None = None,
                  reducers: Mapping[str, Reducer] | None = None) -> dict[str, NDArray[np.float32]]:
    """Neuron values of one batch: runs ``forward(batch)`` (default ``model(batch)``) under
    ``torch.inference_mode()`` with hooks on; one forward feeds every criterion.

    Example:
        >>> import torch
        >>> net = torch.nn.Sequential(torch.nn.Linear(2, 3), torch.nn.ReLU())
        >>> {name: v.shape for name, v in neuron_values(net, torch.ones(4, 2)).items()}
        {'1': (4, 3)}
    """
    torch = import_torch()
    recorder = ActivationRecorder(model, layers, reducers)
    with torch.inference_mode(), recorder:
        (forward or model)(batch)
    return recorder.values()


def layer_sizes(values: Mapping[str, NDArray[Any]]) -> dict[str, int]:
    """Units per layer of neuron values ``{layer: (N, units)}``."""
    return {name: int(np.shape(array)[1]) for name, array in values.items()}


def module_fingerprint(model: Any) -> str:
    """16 hex characters identifying a module's class and weights, stable across processes.

    The sha256 of the class's module-qualified name, then of each ``state_dict`` entry in
    name order: ``name|dtype|shape`` and the raw bytes. Entries that are not tensors (extra
    state) count by their ``repr``.
    """
    torch = import_torch()
    digest = hashlib.sha256(f"{type(model).__module__}.{type(model).__qualname__}".encode())
    for name, entry in sorted(model.state_dict().items()):
        if not isinstance(entry, torch.Tensor):
            digest.update(f"{name}|{type(entry).__name__}|{entry!r}".encode())
            continue
        tensor = entry.detach().cpu().contiguous()
        try:
            array = tensor.numpy()
            dtype, shape, raw = str(array.dtype), array.shape, array.tobytes()
        except TypeError:  # dtypes numpy lacks (bfloat16, float8): the same bytes, viewed as uint8
            dtype, shape = str(tensor.dtype).removeprefix("torch."), tuple(tensor.shape)
            raw = tensor.reshape(-1).view(torch.uint8).numpy().tobytes()
        digest.update(f"{name}|{dtype}|{shape}".encode())
        digest.update(raw)
    return digest.hexdigest()[:16]
