"""Training-set profiles: per neuron count, min, max, mean and standard deviation, streamed.

KMNC, NBC and SNAC compare a value with the range the neuron showed on the training set.
:class:`NeuronProfile` accumulates that range batch by batch — Chan et al.'s parallel
combination of each batch's mean and sum of squared deviations (M2), exact and stable for
any number and size of batches — and is saved keyed by the model's fingerprint
(:func:`~lidarfuzz.coverage.hooks.module_fingerprint`), so a profile is never applied to
weights it was not built on. Non-finite values (NaN, ±inf) are skipped per neuron, hence a
count per neuron; a neuron that never had a finite value has NaN bounds and covers nothing.

Example:
    >>> import numpy as np
    >>> profile = NeuronProfile()
    >>> profile.update({"fc": np.array([[1.0, 0.0], [3.0, 0.0]])})
    >>> profile.update({"fc": np.array([[5.0, 2.0]])})
    >>> profile.layers["fc"]["mean"].tolist(), profile.layers["fc"]["max"].tolist()
    ([3.0, 0.6666666666666666], [5.0, 2.0])
"""

from __future__ import annotations

import json
import os
import re
import uuid
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.coverage.criteria import CoverageError
from lidarfuzz.errors import DataFormatError
from lidarfuzz.settings import settings

#: The ``.npz`` layout written by :meth:`NeuronProfile.save` (1: one count per layer; 2: per neuron).
FORMAT = 2
READABLE_FORMATS = (1, 2)
STATS = ("count", "min", "max", "mean", "std")
REBUILD = "rebuild it with lidarfuzz.coverage.build_profile or `lidarfuzz profile SUT DATA`"


class ProfileFileError(DataFormatError, CoverageError):
    """A profile file that is missing, unreadable or not what it should be (names the file)."""


def cache_dir() -> Path:
    """``$LIDARFUZZ_CACHE/profiles`` (default cache ``~/.cache/lidarfuzz``)."""
    return settings().cache / "profiles"


@dataclass
class NeuronProfile:
    """Per-layer statistics of every neuron over a training set.

    Attributes:
        fingerprint: The model's fingerprint ("" when unknown).
        layers: ``{layer: {"count": int64 (units,), "min", "max", "mean", "std": float64 (units,)}}``;
            ``std`` is the population standard deviation (ddof 0).
        inputs: Inputs folded in.
    """

    fingerprint: str = ""
    layers: dict[str, dict[str, NDArray[Any]]] = field(default_factory=dict)
    inputs: int = 0
    _m2: dict[str, NDArray[np.float64]] = field(default_factory=dict, repr=False)

    @property
    def layer_names(self) -> list[str]:
        """Layer names in the order they were first seen."""
        return list(self.layers)

    @property
    def total_neurons(self) -> int:
        """Neurons over all layers."""
        return sum(int(layer["min"].size) for layer in self.layers.values())

    def update(self, values: Mapping[str, NDArray[Any]]) -> None:
        """Fold in one batch ``{layer: (N, units)}``.

        Raises:
            CoverageError: A layer is not (inputs, units) or changed its number of neurons.
        """
        n_inputs = 0
        for name, raw in values.items():
            batch = np.asarray(raw, dtype=np.float64)
            if batch.ndim != 2:
                raise CoverageError(f"layer {name!r}: neuron values must be (inputs, units), got {batch.shape}")
            n_inputs = max(n_inputs, batch.shape[0])
            finite = np.isfinite(batch)
            count_b = finite.sum(axis=0).astype(np.int64)
            seen = count_b > 0
            mean_b = np.divide(np.where(finite, batch, 0.0).sum(axis=0), count_b,
                               out=np.zeros(batch.shape[1]), where=seen)
            m2_b = (np.where(finite, batch - mean_b, 0.0) ** 2).sum(axis=0)
            min_b = np.where(seen, np.where(finite, batch, np.inf).min(axis=0, initial=np.inf), np.nan)
            max_b = np.where(seen, np.where(finite, batch, -np.inf).max(axis=0, initial=-np.inf), np.nan)
            layer = self.layers.get(name)
            if layer is None:
                self.layers[name] = {"count": count_b, "min": min_b, "max": max_b, "mean": mean_b,
                                     "std": np.zeros_like(mean_b)}
                self._m2[name] = m2_b
            else:
                if layer["mean"].shape != mean_b.shape:
                    raise CoverageError(f"layer {name!r} had {layer['mean'].size} neurons, now {mean_b.size}; "
                                        "a profile follows one model and one set of layers")
                count_a = layer["count"]
                total = count_a + count_b
                delta = mean_b - layer["mean"]
                share = np.divide(count_b, total, out=np.zeros(total.shape), where=total > 0)
                layer["mean"] = layer["mean"] + delta * share
                self._m2[name] = self._m2[name] + m2_b + delta**2 * count_a * share
                layer["min"] = np.fmin(layer["min"], min_b)  # fmin/fmax: NaN (no value yet) gives way
                layer["max"] = np.fmax(layer["max"], max_b)
                layer["count"] = total
            layer = self.layers[name]
            layer["std"] = np.sqrt(np.divide(self._m2[name], layer["count"], out=np.zeros(layer["count"].shape),
                                             where=layer["count"] > 0))
        self.inputs += n_inputs

    def save(self, path: str | Path) -> Path:
        """Write an ``.npz`` (a JSON header and the arrays) atomically; returns the path."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        header = {"format": FORMAT, "fingerprint": self.fingerprint, "layers": self.layer_names,
                  "inputs": self.inputs}
        arrays: dict[str, Any] = {"__header__": np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)}
        for i, (name, layer) in enumerate(self.layers.items()):
            for key in STATS:
                arrays[f"{i}.{key}"] = layer[key]
            arrays[f"{i}.m2"] = self._m2[name]
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp.npz")
        try:
            np.savez(tmp, **arrays)
            os.replace(tmp, path)
        finally:
            tmp.unlink(missing_ok=True)
        return path

    @classmethod
    def load(cls, path: str | Path) -> NeuronProfile:
        """Read a profile written by :meth:`save`.

        Raises:
            ProfileFileError: (a DataFormatError and a CoverageError) naming the file when it is
                missing, unreadable, of an unknown format or inconsistent.
        """
        path = Path(path)
        if not path.is_file():
            raise ProfileFileError(path, "no such profile", hint=REBUILD)
        try:
            with np.load(path, allow_pickle=False) as data:
                if "__header__" not in data.files:
                    raise ProfileFileError(path, "not a neuron profile: no header", hint=REBUILD)
                header = json.loads(bytes(data["__header__"]).decode())
                if not isinstance(header, dict):
                    raise ProfileFileError(path, "not a neuron profile: the header is not a JSON object")
                if header.get("format") not in READABLE_FORMATS:
                    raise ProfileFileError(path, f"profile format {header.get('format')!r}, this lidarfuzz reads "
                                           f"{list(READABLE_FORMATS)}", field="format", hint=REBUILD)
                missing = [k for k in ("fingerprint", "layers", "inputs") if k not in header]
                if missing:
                    raise ProfileFileError(path, f"the header lacks {missing}", field=missing[0], hint=REBUILD)
                profile = cls(str(header["fingerprint"]), inputs=int(header["inputs"]))
                for i, name in enumerate(header["layers"]):
                    wanted = [f"{i}.{k}" for k in (*STATS, "m2")]
                    absent = [k for k in wanted if k not in data.files]
                    if absent:
                        raise ProfileFileError(path, f"layer {name!r}: arrays {absent} are missing", hint=REBUILD)
                    layer = {k: np.asarray(data[f"{i}.{k}"], dtype=np.float64) for k in STATS if k != "count"}
                    m2 = np.asarray(data[f"{i}.m2"], dtype=np.float64)
                    shapes = {a.shape for a in (*layer.values(), m2)}
                    if len(shapes) != 1 or len(next(iter(shapes))) != 1:
                        raise ProfileFileError(path, f"layer {name!r}: statistics of unequal shapes {sorted(shapes)}",
                                               hint=REBUILD)
                    count = np.asarray(data[f"{i}.count"])
                    if count.ndim == 0:  # format 1: one count per layer
                        count = np.full(m2.shape, int(count))
                    if count.shape != m2.shape:
                        raise ProfileFileError(path, f"layer {name!r}: {count.size} counts for {m2.size} neurons",
                                               hint=REBUILD)
                    profile.layers[str(name)] = {"count": count.astype(np.int64), **layer}
                    profile._m2[str(name)] = m2
        except ProfileFileError:
            raise
        except Exception as exc:
            raise ProfileFileError(path, f"not a readable neuron profile ({type(exc).__name__}: {exc})",
                                   hint=REBUILD) from None
        return profile


_FINGERPRINT = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")


class ProfileStore:
    """Profiles on disk keyed by model fingerprint: ``<folder>/<fingerprint>.npz``.

    Args:
        folder: Where profiles are written (default ``$LIDARFUZZ_CACHE/profiles``).
        extra: Read-only folders searched after it (profiles shipped with weights).
    """

    def __init__(self, folder: str | Path | None = None, extra: Iterable[str | Path] = ()) -> None:
        self.folder = Path(folder) if folder is not None else cache_dir()
        self.extra = [Path(f) for f in extra]

    @staticmethod
    def _check(fingerprint: str) -> str:
        if not _FINGERPRINT.fullmatch(fingerprint):
            raise CoverageError(f"{fingerprint!r} is not a model fingerprint (letters, digits, '-' and '_'); "
                                "use lidarfuzz.coverage.module_fingerprint(model)")
        return fingerprint

    def path_for(self, fingerprint: str) -> Path:
        """Where the profile of ``fingerprint`` is written."""
        return self.folder / f"{self._check(fingerprint)}.npz"

    def get(self, fingerprint: str) -> NeuronProfile | None:
        """The stored profile of ``fingerprint``, or None.

        Raises:
            ProfileFileError: The file is unreadable or holds another model's profile.
        """
        for folder in [self.folder, *self.extra]:
            path = folder / f"{self._check(fingerprint)}.npz"
            if path.exists():
                profile = NeuronProfile.load(path)
                if profile.fingerprint != fingerprint:
                    raise ProfileFileError(path, f"holds the profile of model {profile.fingerprint!r}, not "
                                           f"{fingerprint!r}", field="fingerprint", hint="delete or rename it")
                return profile
        return None

    def put(self, fingerprint: str, profile: NeuronProfile) -> Path:
        """Store ``profile`` under ``fingerprint`` (which it takes on); returns the path."""
        path = self.path_for(fingerprint)
        profile.fingerprint = fingerprint
        return profile.save(path)


def build_profile(model: Any, batches: Iterable[Any], layers: Iterable[str] | None = None,
                  forward: Callable[[Any], Any] | None = None, reducers: Mapping[str, Any] | None = None,
                  fingerprint: str | None = None) -> NeuronProfile:
    """Stream batches through ``forward(batch)`` (default ``model(batch)``) with hooks on and
    profile every watched neuron.

    Args:
        model: Any ``torch.nn.Module``.
        batches: What ``forward`` takes, one batch at a time.
        layers: Watched layers (default :func:`~lidarfuzz.coverage.hooks.default_layers`).
        forward: How to run a batch.
        reducers: See :class:`~lidarfuzz.coverage.hooks.ActivationRecorder`.
        fingerprint: Stored with the profile; default ``module_fingerprint(model)``.
    """
    from lidarfuzz.coverage.hooks import ActivationRecorder, import_torch, module_fingerprint

    torch = import_torch()
    recorder = ActivationRecorder(model, layers, reducers)
    profile = NeuronProfile(module_fingerprint(model) if fingerprint is None else fingerprint)
    for batch in batches:
        recorder.clear()
        with torch.inference_mode(), recorder:
            (forward or model)(batch)
        profile.update(recorder.values())
    if not profile.layers:
        raise CoverageError("no batch reached the watched layers; the profile is empty (were there any batches?)")
    return profile
