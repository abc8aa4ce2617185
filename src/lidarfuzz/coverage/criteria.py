"""Neuron-coverage criteria: DeepTest's NC and DeepGauge / DeepHunter's KMNC, NBC, SNAC, TKNC, TKNP.

Every criterion reads *neuron values*: ``{layer: array (N, units)}`` for a batch of N
inputs, one value per neuron — a dense unit's output, or a convolution channel's feature
map averaged over its spatial positions (see :mod:`lidarfuzz.coverage.hooks`). Criteria
need no PyTorch.

Definitions (v is a neuron's value on one input):

* **NC** (DeepTest): per input and per layer, values are min-max scaled over that layer,
  ``(v − min_layer) / (max_layer − min_layer)`` (a layer whose values are all equal scales
  to 0); a neuron is activated when its scaled value is *strictly* above ``t`` (default
  0.2). NC = neurons ever activated / neurons.
* **KMNC** (DeepGauge): a neuron's training-profile range [low, high] split into k equal
  sections (default 10); v covers section ``floor((v − low) / (high − low) · k)``, with
  v = high in the last section (both ends closed) and values outside [low, high] in none.
  A neuron with low = high covers its first section when v = low; its other k − 1
  sections are unreachable but counted, as DeepGauge counts them. KMNC = covered
  sections / (k · neurons).
* **NBC**: a neuron's upper corner is covered when v > high + σ·std, its lower corner when
  v < low − σ·std (σ default 0). NBC = covered corners / (2 · neurons).
* **SNAC**: upper corners only: covered upper corners / neurons.
* **TKNC**: per input and per layer, the k neurons with the largest values (default 2;
  ties to the lower index) are covered. TKNC = covered / neurons.
* **TKNP**: the number of distinct top-k patterns, a pattern being one input's tuple of
  per-layer top-k neuron sets. ``coverage()`` returns the count (``is_count``).

Every criterion has ``update(values)`` (commit a batch in order; returns for each input
whether it covered anything new, judged after the inputs before it) and ``gain(values)``
(how many new items each input alone would add, state unchanged).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import LidarfuzzError

Values = Mapping[str, NDArray[Any]]


class CoverageError(LidarfuzzError, ValueError):
    """A criterion that cannot be built or fed as asked."""


def _layers(values: Values, names: Sequence[str] | None) -> list[str]:
    layers = list(values) if names is None else list(names)
    missing = [n for n in layers if n not in values]
    if missing:
        raise CoverageError(f"neuron values lack layer(s) {missing[:3]}; got {list(values)[:3]}")
    return layers


def _count(values: Values) -> int:
    first = next(iter(values.values()))
    return int(np.asarray(first).shape[0])


class Criterion:
    """Shared machinery: a boolean array of coverable items, flattened over layers."""

    name: ClassVar[str] = ""
    is_count: ClassVar[bool] = False

    def __init__(self) -> None:
        self.layers: list[str] | None = None
        self.covered_items: NDArray[np.bool_] | None = None

    # -- what a subclass provides ---------------------------------------------------------
    def items(self, values: Values) -> NDArray[np.bool_]:
        """(N, items) mask of what each input covers."""
        raise NotImplementedError

    def size(self, values: Values) -> int:
        """Number of coverable items for these layers."""
        raise NotImplementedError

    # -- shared -----------------------------------------------------------------------------
    def _ensure(self, values: Values) -> None:
        if self.layers is None:
            self.layers = list(values)
            self.covered_items = np.zeros(self.size(values), dtype=bool)

    def update(self, values: Values) -> NDArray[np.bool_]:
        self._ensure(values)
        assert self.covered_items is not None
        hits = self.items(values)
        new = np.zeros(hits.shape[0], dtype=bool)
        for i in range(hits.shape[0]):
            fresh = hits[i] & ~self.covered_items
            new[i] = bool(fresh.any())
            self.covered_items |= hits[i]
        return new

    def gain(self, values: Values) -> NDArray[np.int64]:
        self._ensure(values)
        assert self.covered_items is not None
        hits = self.items(values)
        return (hits & ~self.covered_items[None]).sum(axis=1).astype(np.int64)

    @property
    def total(self) -> int:
        return 0 if self.covered_items is None else int(self.covered_items.size)

    def covered(self) -> int:
        return 0 if self.covered_items is None else int(self.covered_items.sum())

    def coverage(self) -> float:
        return self.covered() / self.total if self.total else 0.0

    def reset(self) -> None:
        self.layers, self.covered_items = None, None

    def copy(self) -> Criterion:
        return copy.deepcopy(self)

    def state_dict(self) -> dict[str, Any]:
        """Numpy arrays and lists (``lidarfuzz.search.algorithms.pack`` makes them JSON)."""
        return {"layers": self.layers, "covered": self.covered_items}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.layers = None if state["layers"] is None else list(state["layers"])
        covered = state["covered"]
        self.covered_items = None if covered is None else np.asarray(covered, dtype=bool).copy()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.covered()}/{self.total}>"


class NeuronCoverage(Criterion):
    """DeepTest's neuron coverage (per-input, per-layer min-max scaling; strict threshold)."""

    name = "nc"

    def __init__(self, threshold: float = 0.2) -> None:
        super().__init__()
        self.threshold = float(threshold)

    def size(self, values: Values) -> int:
        return sum(int(np.asarray(values[n]).shape[1]) for n in _layers(values, self.layers))

    def items(self, values: Values) -> NDArray[np.bool_]:
        parts = []
        for name in _layers(values, self.layers):
            v = np.asarray(values[name], dtype=np.float64)
            low = v.min(axis=1, keepdims=True)
            span = v.max(axis=1, keepdims=True) - low
            with np.errstate(invalid="ignore", divide="ignore"):
                scaled = np.where(span > 0, (v - low) / np.where(span > 0, span, 1.0), 0.0)
            parts.append(scaled > self.threshold)
        return np.concatenate(parts, axis=1)


class _Profiled(Criterion):
    def __init__(self, profile: Any) -> None:
        super().__init__()
        if profile is None:
            raise CoverageError(f"{self.name.upper()} needs a training-set profile of the model's neurons "
                                "(lidarfuzz.coverage.build_profile, or `lidarfuzz coverage profile`)")
        self.profile = profile

    def _bounds(self, name: str) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        try:
            layer = self.profile.layers[name]
        except KeyError:
            raise CoverageError(
                f"the profile has no layer {name!r}; it was built for another model or layers") from None
        return layer["min"], layer["max"], layer["std"]

    def size(self, values: Values) -> int:
        return self.per_neuron * sum(int(np.asarray(values[n]).shape[1]) for n in _layers(values, self.layers))

    per_neuron: ClassVar[int] = 1


class KMultisectionCoverage(_Profiled):
    """DeepGauge's k-multisection neuron coverage."""

    name = "kmnc"

    def __init__(self, profile: Any, k: int = 10) -> None:
        super().__init__(profile)
        if k < 1:
            raise CoverageError("KMNC needs k >= 1")
        self.k = int(k)

    def size(self, values: Values) -> int:
        return self.k * sum(int(np.asarray(values[n]).shape[1]) for n in _layers(values, self.layers))

    def items(self, values: Values) -> NDArray[np.bool_]:
        parts = []
        for name in _layers(values, self.layers):
            v = np.asarray(values[name], dtype=np.float64)
            low, high, _ = self._bounds(name)
            span = high - low
            inside = (v >= low) & (v <= high)
            with np.errstate(invalid="ignore", divide="ignore"):
                section = np.where(span > 0, np.floor((v - low) / np.where(span > 0, span, 1.0) * self.k), 0)
            section = np.clip(section, 0, self.k - 1).astype(np.int64)  # v == high → last section
            hits = np.zeros((v.shape[0], v.shape[1], self.k), dtype=bool)
            n_idx, u_idx = np.nonzero(inside)
            hits[n_idx, u_idx, section[n_idx, u_idx]] = True
            parts.append(hits.reshape(v.shape[0], -1))
        return np.concatenate(parts, axis=1)


class NeuronBoundaryCoverage(_Profiled):
    """Neuron boundary coverage: both corner regions beyond the profile (σ margin optional)."""

    name = "nbc"

    def __init__(self, profile: Any, sigma: float = 0.0) -> None:
        super().__init__(profile)
        self.sigma = float(sigma)

    def size(self, values: Values) -> int:
        return 2 * sum(int(np.asarray(values[n]).shape[1]) for n in _layers(values, self.layers))

    def items(self, values: Values) -> NDArray[np.bool_]:
        uppers, lowers = [], []
        for name in _layers(values, self.layers):
            v = np.asarray(values[name], dtype=np.float64)
            low, high, std = self._bounds(name)
            uppers.append(v > high + self.sigma * std)
            lowers.append(v < low - self.sigma * std)
        return np.concatenate(uppers + lowers, axis=1)


class StrongActivationCoverage(_Profiled):
    """Strong neuron activation coverage: the upper corner region only."""

    name = "snac"

    def __init__(self, profile: Any, sigma: float = 0.0) -> None:
        super().__init__(profile)
        self.sigma = float(sigma)

    def items(self, values: Values) -> NDArray[np.bool_]:
        parts = []
        for name in _layers(values, self.layers):
            v = np.asarray(values[name], dtype=np.float64)
            _, high, std = self._bounds(name)
            parts.append(v > high + self.sigma * std)
        return np.concatenate(parts, axis=1)


def _top_k(v: NDArray[np.float64], k: int) -> NDArray[np.int64]:
    """(N, k) indices of each row's k largest values; ties to the lower index."""
    k = min(k, v.shape[1])
    order = np.argsort(-v, axis=1, kind="stable")  # stable: equal values keep index order
    return np.sort(order[:, :k], axis=1)


class TopKCoverage(Criterion):
    """Top-k neuron coverage: per input and layer, the k most active neurons are covered."""

    name = "tknc"

    def __init__(self, k: int = 2) -> None:
        super().__init__()
        self.k = int(k)

    def size(self, values: Values) -> int:
        return sum(int(np.asarray(values[n]).shape[1]) for n in _layers(values, self.layers))

    def items(self, values: Values) -> NDArray[np.bool_]:
        parts = []
        for name in _layers(values, self.layers):
            v = np.asarray(values[name], dtype=np.float64)
            hits = np.zeros(v.shape, dtype=bool)
            np.put_along_axis(hits, _top_k(v, self.k), True, axis=1)
            parts.append(hits)
        return np.concatenate(parts, axis=1)


class TopKPatterns(Criterion):
    """Top-k neuron patterns: the number of distinct per-input tuples of per-layer top-k sets."""

    name = "tknp"
    is_count = True

    def __init__(self, k: int = 2) -> None:
        super().__init__()
        self.k = int(k)
        self.patterns: set[bytes] = set()

    def _patterns(self, values: Values) -> list[bytes]:
        if self.layers is None:
            self.layers = list(values)
        tops = [_top_k(np.asarray(values[n], dtype=np.float64), self.k) for n in _layers(values, self.layers)]
        joined = np.concatenate(tops, axis=1).astype(np.int32)
        return [row.tobytes() for row in joined]

    def update(self, values: Values) -> NDArray[np.bool_]:
        new = []
        for pattern in self._patterns(values):
            new.append(pattern not in self.patterns)
            self.patterns.add(pattern)
        return np.asarray(new, dtype=bool)

    def gain(self, values: Values) -> NDArray[np.int64]:
        return np.asarray([int(p not in self.patterns) for p in self._patterns(values)], dtype=np.int64)

    @property
    def total(self) -> int:
        return len(self.patterns)

    def covered(self) -> int:
        return len(self.patterns)

    def coverage(self) -> float:
        return float(len(self.patterns))

    def reset(self) -> None:
        super().reset()
        self.patterns = set()

    def state_dict(self) -> dict[str, Any]:
        return {"layers": self.layers, "patterns": sorted(p.hex() for p in self.patterns)}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self.layers = None if state["layers"] is None else list(state["layers"])
        self.patterns = {bytes.fromhex(p) for p in state["patterns"]}


CRITERIA: dict[str, type[Criterion]] = {
    c.name: c for c in (NeuronCoverage, KMultisectionCoverage, NeuronBoundaryCoverage, StrongActivationCoverage,
                        TopKCoverage, TopKPatterns)
}


def make_criterion(spec: str, profile: Any = None) -> Criterion:
    """A criterion from ``name[:value]``: ``nc:0.2`` (threshold), ``kmnc:10`` (k), ``nbc:1.0`` /
    ``snac:0.5`` (σ), ``tknc:2`` / ``tknp:2`` (k)."""
    name, _, arg = spec.strip().partition(":")
    name = name.lower()
    if name not in CRITERIA:
        raise CoverageError(f"unknown coverage criterion {name!r} in {spec!r}; choose from {', '.join(CRITERIA)}")
    try:
        value = float(arg) if arg else None
    except ValueError:
        raise CoverageError(f"coverage criterion {spec!r}: {arg!r} is not a number") from None
    if name == "nc":
        return NeuronCoverage(0.2 if value is None else value)
    if name == "kmnc":
        return KMultisectionCoverage(profile, 10 if value is None else int(value))
    if name in ("nbc", "snac"):
        cls = NeuronBoundaryCoverage if name == "nbc" else StrongActivationCoverage
        return cls(profile, 0.0 if value is None else value)
    cls2 = TopKCoverage if name == "tknc" else TopKPatterns
    return cls2(2 if value is None else int(value))


def make_criteria(specs: Sequence[str], profile: Any = None) -> list[Criterion]:
    return [make_criterion(s, profile) for s in specs]
