"""Training-set profiles: per neuron min, max, mean and standard deviation, streamed.

KMNC, NBC and SNAC compare a value with the range the neuron showed on the training set.
:class:`NeuronProfile` accumulates that range batch by batch (Chan et al.'s parallel
update of mean and squared deviations, exact and stable for any number of batches) and is
saved keyed by the model's fingerprint (:func:`~lidarfuzz.coverage.hooks.module_fingerprint`
or a SUT's fingerprint), so a profile is never applied to weights it was not built on.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.coverage.criteria import CoverageError

FORMAT = 1


def cache_dir() -> Path:
    return Path(os.environ.get("LIDARFUZZ_CACHE") or Path.home() / ".cache" / "lidarfuzz") / "profiles"


class NeuronProfile:
    """Per-layer arrays ``count``, ``min``, ``max``, ``mean``, ``std`` (one entry per neuron)."""

    def __init__(self, fingerprint: str = "") -> None:
        self.fingerprint = fingerprint
        self.layers: dict[str, dict[str, NDArray[np.float64]]] = {}
        self.inputs = 0
        self._m2: dict[str, NDArray[np.float64]] = {}

    @property
    def layer_names(self) -> list[str]:
        return list(self.layers)

    @property
    def total_neurons(self) -> int:
        return sum(int(layer["min"].size) for layer in self.layers.values())

    def update(self, values: Mapping[str, NDArray[Any]]) -> None:
        """Fold in one batch ``{layer: (N, units)}``."""
        n_inputs = 0
        for name, raw in values.items():
            batch = np.asarray(raw, dtype=np.float64)
            n = batch.shape[0]
            n_inputs = max(n_inputs, n)
            if n == 0:
                continue
            mean_b = batch.mean(axis=0)
            m2_b = ((batch - mean_b) ** 2).sum(axis=0)
            layer = self.layers.get(name)
            if layer is None:
                self.layers[name] = {"count": np.array(n), "min": batch.min(axis=0), "max": batch.max(axis=0),
                                     "mean": mean_b, "std": np.zeros_like(mean_b)}
                self._m2[name] = m2_b
            else:
                if layer["mean"].shape != mean_b.shape:
                    raise CoverageError(f"layer {name!r} had {layer['mean'].size} neurons, now {mean_b.size}")
                count = int(layer["count"])
                total = count + n
                delta = mean_b - layer["mean"]
                layer["mean"] = layer["mean"] + delta * n / total
                self._m2[name] = self._m2[name] + m2_b + delta**2 * count * n / total
                layer["min"] = np.minimum(layer["min"], batch.min(axis=0))
                layer["max"] = np.maximum(layer["max"], batch.max(axis=0))
                layer["count"] = np.array(total)
            layer = self.layers[name]
            layer["std"] = np.sqrt(self._m2[name] / int(layer["count"]))
        self.inputs += n_inputs

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        header = {"format": FORMAT, "fingerprint": self.fingerprint, "layers": self.layer_names, "inputs": self.inputs}
        arrays: dict[str, Any] = {"__header__": np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)}
        for i, (_name, layer) in enumerate(self.layers.items()):
            for key in ("count", "min", "max", "mean", "std"):
                arrays[f"{i}.{key}"] = layer[key]
            arrays[f"{i}.m2"] = self._m2[_name]
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(tmp, **arrays)
        os.replace(tmp, path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> NeuronProfile:
        path = Path(path)
        try:
            with np.load(path) as data:
                header = json.loads(bytes(data["__header__"]).decode())
                if header.get("format") != FORMAT:
                    raise CoverageError(f"{path}: profile format {header.get('format')}, expected {FORMAT}")
                profile = cls(header["fingerprint"])
                profile.inputs = int(header["inputs"])
                for i, name in enumerate(header["layers"]):
                    profile.layers[name] = {k: np.asarray(data[f"{i}.{k}"], dtype=np.float64 if k != "count" else None)
                                            for k in ("count", "min", "max", "mean", "std")}
                    profile._m2[name] = np.asarray(data[f"{i}.m2"], dtype=np.float64)
        except CoverageError:
            raise
        except FileNotFoundError:
            raise CoverageError(f"{path}: no such profile") from None
        except Exception as exc:
            raise CoverageError(f"{path}: not a readable neuron profile ({type(exc).__name__}: {exc})") from None
        return profile


class ProfileStore:
    """Profiles on disk keyed by model fingerprint (default ``$LIDARFUZZ_CACHE/profiles``)."""

    def __init__(self, folder: str | Path | None = None, extra: Iterable[Path] = ()) -> None:
        self.folder = Path(folder) if folder is not None else cache_dir()
        self.extra = list(extra)  # read-only places searched too (profiles shipped with weights)

    def path_for(self, fingerprint: str) -> Path:
        return self.folder / f"{fingerprint}.npz"

    def get(self, fingerprint: str) -> NeuronProfile | None:
        for folder in [self.folder, *self.extra]:
            path = Path(folder) / f"{fingerprint}.npz"
            if path.exists():
                profile = NeuronProfile.load(path)
                if profile.fingerprint != fingerprint:
                    raise CoverageError(f"{path}: holds the profile of {profile.fingerprint}, not {fingerprint}")
                return profile
        return None

    def put(self, fingerprint: str, profile: NeuronProfile) -> Path:
        profile.fingerprint = fingerprint
        return profile.save(self.path_for(fingerprint))


def build_profile(model: Any, batches: Iterable[Any], layers: Iterable[str] | None = None,
                  forward: Callable[[Any], Any] | None = None, fingerprint: str = "") -> NeuronProfile:
    """Stream batches through ``model`` (or ``forward``) with hooks and profile every neuron."""
    from lidarfuzz.coverage.hooks import ActivationRecorder
    from lidarfuzz.suts.learned.sut import import_torch

    torch = import_torch()
    recorder = ActivationRecorder(model, layers)
    profile = NeuronProfile(fingerprint)
    for batch in batches:
        recorder.clear()
        with torch.inference_mode(), recorder:
            (forward or model)(batch)
        profile.update(recorder.values())
    return profile
