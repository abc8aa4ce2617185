"""Neuron-coverage criteria: DeepTest's NC and DeepGauge / DeepHunter's KMNC, NBC, SNAC, TKNC, TKNP.

Every criterion reads *neuron values*: ``{layer: array (N, units)}`` for a batch of N
inputs, one value per neuron — a dense unit's output, or a convolution channel's feature
map averaged over its spatial positions (see :mod:`lidarfuzz.coverage.hooks`). Criteria
need no PyTorch.

Definitions (v is a neuron's value on one input; low, high and std are the neuron's
minimum, maximum and standard deviation over the training set, from a
:class:`~lidarfuzz.coverage.profile.NeuronProfile`):

* **NC** (DeepTest): per input and per layer, values are min-max scaled over that layer,
  ``(v − min_layer) / (max_layer − min_layer)`` (a layer whose values are all equal scales
  to 0); a neuron is activated when its scaled value is *strictly* above ``t`` (default
  0.2). NC = neurons ever activated / neurons.
* **KMNC** (DeepGauge): [low, high] split into k equal sections (default 10); v covers
  section ``floor((v − low) / (high − low) · k)``, with v = high in the last section (both
  ends closed) and values outside [low, high] in none. A neuron with low = high covers its
  first section when v = low; its other k − 1 sections are unreachable but counted, as
  DeepGauge counts them. KMNC = covered sections / (k · neurons).
* **NBC** (DeepGauge): a neuron's upper corner is covered when v > high + σ·std, its lower
  corner when v < low − σ·std (σ default 0). NBC = covered corners / (2 · neurons).
* **SNAC** (DeepGauge): upper corners only: covered upper corners / neurons.
* **TKNC** (DeepGauge): per input and per layer, the k neurons with the largest values
  (default 2; ties to the lower index) are covered. TKNC = covered / neurons.
* **TKNP** (DeepGauge): the number of distinct top-k patterns, a pattern being one input's
  tuple of per-layer top-k neuron sets. ``coverage()`` returns the count (``is_count``).

Non-finite values (NaN, ±inf) cover nothing, and NC leaves them out of a layer's min and max.

Every criterion has ``update(values)`` (commit a batch in order; returns for each input
whether it covered anything new, judged after the inputs before it) and ``gain(values)``
(how many new items each input alone would add, state unchanged). The layers and their
widths are fixed by the first batch a criterion sees.

Example:
    >>> import numpy as np
    >>> nc = NeuronCoverage(threshold=0.25)
    >>> nc.update({"fc": np.array([[0.0, 1, 2, 3, 4]])}).tolist()  # scaled [0, .25, .5, .75, 1]
    [True]
    >>> nc.coverage()
    0.6
"""

from __future__ import annotations

import copy as _copy
import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import LidarfuzzError

Values = Mapping[str, NDArray[Any]]


class CoverageError(LidarfuzzError, ValueError):
    """A criterion, recorder or profile that cannot be built or fed as asked."""


def check_values(values: Values, layers: Sequence[str] | None = None) -> list[NDArray[np.float64]]:
    """The arrays of ``layers`` (default: all, in order) as float64 (N, units), checked.

    Raises:
        CoverageError: A layer is missing, is not two-dimensional, or has another number of
            rows (inputs) than the first layer.
    """
    names = list(values) if layers is None else list(layers)
    if not names:
        raise CoverageError("no neuron values: the batch holds no layers (were the hooks on during the forward?)")
    missing = [n for n in names if n not in values]
    if missing:
        raise CoverageError(f"neuron values lack layer(s) {missing[:3]}; got {list(values)[:5]}")
    arrays: list[NDArray[np.float64]] = []
    for name in names:
        array = np.asarray(values[name], dtype=np.float64)
        if array.ndim != 2:
            raise CoverageError(f"layer {name!r}: neuron values must be (inputs, units), got shape {array.shape}")
        if arrays and array.shape[0] != arrays[0].shape[0]:
            raise CoverageError(
                f"layer {name!r} has {array.shape[0]} rows but layer {names[0]!r} has {arrays[0].shape[0]}: every "
                "layer needs one row per input (give a layer whose first dimension is not the batch a reducer)")
        arrays.append(array)
    return arrays


def _first_new(hits: NDArray[np.bool_], covered: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """For each row of ``hits``, whether it covers an item that neither ``covered`` nor an
    earlier row covers; ``covered`` is updated in place."""
    fresh = hits & ~covered[None]
    reached = fresh.any(axis=0)
    new = np.zeros(hits.shape[0], dtype=bool)
    new[fresh.argmax(axis=0)[reached]] = True  # the first row that reaches an item claims it
    covered |= reached
    return new


class Criterion:
    """A coverage criterion: a bit set of coverable items, flattened over layers.

    Subclasses give :meth:`hits`, the (N, items) mask of what each input covers, and
    ``per_neuron``, the items a neuron owns (1; k for KMNC; 2 for NBC).

    Attributes:
        name: Short id (``nc``, ``kmnc``, ``nbc``, ``snac``, ``tknc``, ``tknp``).
        is_count: True when :meth:`coverage` is a count rather than a fraction (TKNP).
        layers: Layer names, fixed by the first batch (None before it).
        sizes: Units per layer, same order.
        covered_items: The bit set (None before the first batch).
    """

    name: ClassVar[str] = ""
    is_count: ClassVar[bool] = False
    per_neuron: int = 1

    def __init__(self) -> None:
        self.layers: list[str] | None = None
        self.sizes: list[int] | None = None
        self.covered_items: NDArray[np.bool_] | None = None

    # -- what a subclass provides ---------------------------------------------------------
    def params(self) -> dict[str, Any]:
        """The criterion's parameters (part of its state, checked on load)."""
        return {}

    def hits(self, arrays: Sequence[NDArray[np.float64]]) -> NDArray[np.bool_]:
        """(N, items) mask of what each input covers, from the checked per-layer arrays."""
        raise NotImplementedError

    # -- shared -----------------------------------------------------------------------------
    def _arrays(self, values: Values) -> list[NDArray[np.float64]]:
        """Checked arrays of this criterion's layers; the first batch fixes layers and sizes."""
        arrays = check_values(values, self.layers)
        widths = [int(a.shape[1]) for a in arrays]
        if self.layers is None:
            self.layers = list(values)
        if self.sizes is None:
            expected = None if self.covered_items is None else self.covered_items.size
            if expected is not None and expected != self.per_neuron * sum(widths):
                raise CoverageError(f"{self.name}: the loaded state has {expected} items but these layers give "
                                    f"{self.per_neuron * sum(widths)}; was it recorded on another model?")
            self.sizes = widths
        elif widths != self.sizes:
            name, had, got = next((n, a, b) for n, a, b in zip(self.layers, self.sizes, widths, strict=True) if a != b)
            raise CoverageError(f"{self.name}: layer {name!r} had {had} neurons, now {got}; "
                                "a criterion follows one model and one set of layers (reset() it to start over)")
        if self.covered_items is None:
            self.covered_items = np.zeros(self.per_neuron * sum(widths), dtype=bool)
        return arrays

    def update(self, values: Values) -> NDArray[np.bool_]:
        """Commit a batch, input after input.

        Returns:
            (N,) bool: whether each input covered an item not covered before it (by the
            state before the batch or by an earlier input of the batch).
        """
        arrays = self._arrays(values)
        assert self.covered_items is not None
        return _first_new(self.hits(arrays), self.covered_items)

    def gain(self, values: Values) -> NDArray[np.int64]:
        """(N,) how many new items each input would add on its own; the state is unchanged."""
        arrays = self._arrays(values)
        assert self.covered_items is not None
        return (self.hits(arrays) & ~self.covered_items[None]).sum(axis=1).astype(np.int64)

    @property
    def total(self) -> int:
        """Number of coverable items (0 before the first batch)."""
        return 0 if self.covered_items is None else int(self.covered_items.size)

    def covered(self) -> int:
        """Number of covered items."""
        return 0 if self.covered_items is None else int(self.covered_items.sum())

    def coverage(self) -> float:
        """Covered items / all items, in [0, 1] (0 before the first batch)."""
        return self.covered() / self.total if self.total else 0.0

    def reset(self) -> None:
        """Forget everything covered, and the layers."""
        self.layers, self.sizes, self.covered_items = None, None, None

    def copy(self) -> Criterion:
        """An independent copy of the state; a profile is shared (it is only read)."""
        twin = _copy.copy(self)
        twin.layers = None if self.layers is None else list(self.layers)
        twin.sizes = None if self.sizes is None else list(self.sizes)
        twin.covered_items = None if self.covered_items is None else self.covered_items.copy()
        return twin

    def state_dict(self) -> dict[str, Any]:
        """The state as plain values and numpy arrays.

        Keys: ``name``, ``params``, ``layers`` and ``sizes`` (lists or None) and ``covered``
        (a bool numpy array, or None). Not JSON as is: encode the array (for instance with
        ``lidarfuzz.search.algorithms.pack``) or use ``covered.tolist()``; both load back.
        """
        return {"name": self.name, "params": self.params(), "layers": self.layers, "sizes": self.sizes,
                "covered": None if self.covered_items is None else self.covered_items.copy()}

    def _check_state(self, state: Mapping[str, Any]) -> None:
        if state.get("name", self.name) != self.name:
            raise CoverageError(f"cannot load the state of criterion {state['name']!r} into {self.name!r}")
        saved = state.get("params")
        if saved is not None and saved != self.params():
            raise CoverageError(f"{self.name}: the state was recorded with {saved}, this criterion has {self.params()}")

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`state_dict` output (also the older form without name, params and sizes)."""
        self._check_state(state)
        self.layers = None if state["layers"] is None else list(state["layers"])
        sizes = state.get("sizes")
        self.sizes = None if sizes is None else [int(s) for s in sizes]
        covered = state["covered"]
        self.covered_items = None if covered is None else np.asarray(covered, dtype=bool).reshape(-1).copy()
        if self.sizes is not None and self.covered_items is not None and \
                self.covered_items.size != self.per_neuron * sum(self.sizes):
            raise CoverageError(f"{self.name}: state has {self.covered_items.size} items for layers of "
                                f"{sum(self.sizes)} neurons; it is corrupt")

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.params()} {self.covered()}/{self.total}>"


class NeuronCoverage(Criterion):
    """DeepTest's neuron coverage (per-input, per-layer min-max scaling; strict threshold).

    Args:
        threshold: t in [0, 1); a neuron is activated when its scaled value is > t.
    """

    name = "nc"

    def __init__(self, threshold: float = 0.2) -> None:
        super().__init__()
        if not 0.0 <= float(threshold) < 1.0:
            raise CoverageError(f"NC threshold must be in [0, 1) (scaled values lie in [0, 1]), got {threshold}")
        self.threshold = float(threshold)

    def params(self) -> dict[str, Any]:
        return {"threshold": self.threshold}

    def hits(self, arrays: Sequence[NDArray[np.float64]]) -> NDArray[np.bool_]:
        parts = []
        for v in arrays:
            finite = np.isfinite(v)
            v = np.where(finite, v, np.nan)
            with np.errstate(invalid="ignore"):  # rows without a finite value stay NaN and activate nothing
                low = np.fmin.reduce(v, axis=1, keepdims=True)
                span = np.fmax.reduce(v, axis=1, keepdims=True) - low
                scaled = np.where(span > 0, (v - low) / np.where(span > 0, span, 1.0), 0.0)
            parts.append((scaled > self.threshold) & finite)
        return np.concatenate(parts, axis=1)


class _Profiled(Criterion):
    """A criterion that compares values with the training profile's per-neuron ranges."""

    def __init__(self, profile: Any) -> None:
        super().__init__()
        if profile is None:
            raise CoverageError(
                f"{self.name.upper()} needs a training-set profile of the model's neurons; build one with "
                "lidarfuzz.coverage.build_profile(model, batches) or `lidarfuzz profile SUT DATA`")
        if not isinstance(getattr(profile, "layers", None), Mapping):
            raise CoverageError(f"{self.name.upper()}: {type(profile).__name__} is not a NeuronProfile")
        self.profile = profile

    def _bounds(self, index: int, v: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        assert self.layers is not None
        name = self.layers[index]
        layer = self.profile.layers.get(name)
        if layer is None:
            known = list(self.profile.layers)[:5]
            raise CoverageError(f"{self.name}: the profile has no layer {name!r} (it has {known}); it was built "
                                "for another model or other layers")
        low, high, std = (np.asarray(layer[key], dtype=np.float64) for key in ("min", "max", "std"))
        if low.shape != (v.shape[1],):
            raise CoverageError(f"{self.name}: layer {name!r} has {v.shape[1]} neurons but its profile "
                                f"{low.size}; the profile belongs to another model")
        return low, high, std


class KMultisectionCoverage(_Profiled):
    """DeepGauge's k-multisection neuron coverage.

    Args:
        profile: The model's :class:`~lidarfuzz.coverage.profile.NeuronProfile`.
        k: Sections per neuron (≥ 1).
    """

    name = "kmnc"

    def __init__(self, profile: Any, k: int = 10) -> None:
        super().__init__(profile)
        if int(k) != k or k < 1:
            raise CoverageError(f"KMNC needs a whole number k >= 1 of sections, got {k}")
        self.k = int(k)
        self.per_neuron = self.k

    def params(self) -> dict[str, Any]:
        return {"k": self.k}

    def hits(self, arrays: Sequence[NDArray[np.float64]]) -> NDArray[np.bool_]:
        parts = []
        for i, v in enumerate(arrays):
            low, high, _ = self._bounds(i, v)
            span = high - low
            inside = (v >= low) & (v <= high)
            with np.errstate(invalid="ignore", divide="ignore"):
                section = np.where(span > 0, np.floor((v - low) / np.where(span > 0, span, 1.0) * self.k), 0)
            section = np.clip(np.nan_to_num(section), 0, self.k - 1).astype(np.int64)  # v == high → last section
            hits = np.zeros((v.shape[0], v.shape[1], self.k), dtype=bool)
            hits[np.arange(v.shape[0])[:, None], np.arange(v.shape[1])[None, :], section] = inside
            parts.append(hits.reshape(v.shape[0], -1))  # item = neuron · k + section
        return np.concatenate(parts, axis=1)


class _Corners(_Profiled):
    """Corner regions beyond the training range, σ standard deviations out."""

    def __init__(self, profile: Any, sigma: float = 0.0) -> None:
        super().__init__(profile)
        if not (math.isfinite(sigma) and sigma >= 0):
            raise CoverageError(f"{self.name.upper()} needs a margin σ >= 0 (in standard deviations), got {sigma}")
        self.sigma = float(sigma)

    def params(self) -> dict[str, Any]:
        return {"sigma": self.sigma}


class NeuronBoundaryCoverage(_Corners):
    """DeepGauge's neuron boundary coverage: both corner regions beyond the profile.

    Items are every neuron's upper corner (in layer order), then every lower corner.

    Args:
        profile: The model's :class:`~lidarfuzz.coverage.profile.NeuronProfile`.
        sigma: σ ≥ 0; the corners start σ standard deviations beyond the training range.
    """

    name = "nbc"
    per_neuron = 2

    def hits(self, arrays: Sequence[NDArray[np.float64]]) -> NDArray[np.bool_]:
        uppers, lowers = [], []
        for i, v in enumerate(arrays):
            low, high, std = self._bounds(i, v)
            uppers.append(v > high + self.sigma * std)
            lowers.append(v < low - self.sigma * std)
        return np.concatenate(uppers + lowers, axis=1)


class StrongActivationCoverage(_Corners):
    """DeepGauge's strong neuron activation coverage: the upper corner regions only.

    Args:
        profile: The model's :class:`~lidarfuzz.coverage.profile.NeuronProfile`.
        sigma: σ ≥ 0; the corner starts σ standard deviations above the training maximum.
    """

    name = "snac"

    def hits(self, arrays: Sequence[NDArray[np.float64]]) -> NDArray[np.bool_]:
        parts = []
        for i, v in enumerate(arrays):
            _, high, std = self._bounds(i, v)
            parts.append(v > high + self.sigma * std)
        return np.concatenate(parts, axis=1)


def top_k(v: NDArray[np.float64], k: int) -> NDArray[np.int64]:
    """(N, min(k, units)) ascending indices of each row's k largest values; ties to the lower
    index, non-finite values last."""
    k = min(k, v.shape[1])
    order = np.argsort(-np.where(np.isfinite(v), v, -np.inf), axis=1, kind="stable")  # stable: ties keep index order
    return np.sort(order[:, :k], axis=1)


def _check_k(name: str, k: int) -> int:
    if int(k) != k or k < 1:
        raise CoverageError(f"{name.upper()} needs a whole number k >= 1 of top neurons per layer, got {k}")
    return int(k)


class TopKCoverage(Criterion):
    """DeepGauge's top-k neuron coverage: per input and layer, the k most active neurons are covered.

    Args:
        k: Neurons per layer and input (≥ 1; a layer with fewer units covers them all).
    """

    name = "tknc"

    def __init__(self, k: int = 2) -> None:
        super().__init__()
        self.k = _check_k(self.name, k)

    def params(self) -> dict[str, Any]:
        return {"k": self.k}

    def hits(self, arrays: Sequence[NDArray[np.float64]]) -> NDArray[np.bool_]:
        parts = []
        for v in arrays:
            hits = np.zeros(v.shape, dtype=bool)
            np.put_along_axis(hits, top_k(v, self.k), True, axis=1)
            parts.append(hits)
        return np.concatenate(parts, axis=1)


class TopKPatterns(Criterion):
    """DeepGauge's top-k neuron patterns: the number of distinct per-input tuples of per-layer
    top-k sets. :meth:`coverage` is that count (``is_count``); :meth:`gain` is 0 or 1.

    Args:
        k: Neurons per layer in a pattern (≥ 1).
    """

    name = "tknp"
    is_count = True

    def __init__(self, k: int = 2) -> None:
        super().__init__()
        self.k = _check_k(self.name, k)
        self.patterns: set[bytes] = set()

    def params(self) -> dict[str, Any]:
        return {"k": self.k}

    def _patterns(self, values: Values) -> list[bytes]:
        arrays = check_values(values, self.layers)
        widths = [int(a.shape[1]) for a in arrays]
        if self.layers is None:
            self.layers = list(values)
        if self.sizes is None:
            self.sizes = widths
        elif widths != self.sizes:
            raise CoverageError(f"tknp: layer widths changed from {self.sizes} to {widths}; "
                                "a criterion follows one model and one set of layers")
        joined = np.concatenate([top_k(v, self.k) for v in arrays], axis=1).astype(np.int32)
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
        """The number of patterns seen (TKNP has no fixed denominator)."""
        return len(self.patterns)

    def covered(self) -> int:
        return len(self.patterns)

    def coverage(self) -> float:
        """The number of distinct patterns (a count, not a fraction)."""
        return float(len(self.patterns))

    def reset(self) -> None:
        super().reset()
        self.patterns = set()

    def copy(self) -> TopKPatterns:
        twin = _copy.copy(self)
        twin.layers = None if self.layers is None else list(self.layers)
        twin.sizes = None if self.sizes is None else list(self.sizes)
        twin.patterns = set(self.patterns)
        return twin

    def state_dict(self) -> dict[str, Any]:
        """``name``, ``params``, ``layers``, ``sizes`` and ``patterns`` (sorted hex strings of the
        int32 neuron indices): JSON as is."""
        return {"name": self.name, "params": self.params(), "layers": self.layers, "sizes": self.sizes,
                "patterns": sorted(p.hex() for p in self.patterns)}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        self._check_state(state)
        self.layers = None if state["layers"] is None else list(state["layers"])
        sizes = state.get("sizes")
        self.sizes = None if sizes is None else [int(s) for s in sizes]
        self.patterns = {bytes.fromhex(p) for p in state["patterns"]}


CRITERIA: dict[str, type[Criterion]] = {
    c.name: c for c in (NeuronCoverage, KMultisectionCoverage, NeuronBoundaryCoverage, StrongActivationCoverage,
                        TopKCoverage, TopKPatterns)
}
#: What the number after the colon of a spec sets, and its default.
SPEC_PARAMETER: dict[str, tuple[str, float]] = {
    "nc": ("threshold", 0.2), "kmnc": ("k", 10), "nbc": ("sigma", 0.0), "snac": ("sigma", 0.0),
    "tknc": ("k", 2), "tknp": ("k", 2),
}
PROFILED = ("kmnc", "nbc", "snac")


def parse_spec(spec: str) -> tuple[str, float | None]:
    """``name[:value]`` → (the criterion's name, the value or None), checked without building it.

    Raises:
        CoverageError: Unknown name, or a value that is not a number.
    """
    name, _, arg = spec.strip().partition(":")
    name = name.strip().lower()
    if name not in CRITERIA:
        raise CoverageError(f"unknown coverage criterion {name!r} in {spec!r}; choose from {', '.join(CRITERIA)}")
    if not arg.strip():
        return name, None
    try:
        return name, float(arg)
    except ValueError:
        parameter = SPEC_PARAMETER[name][0]
        raise CoverageError(f"coverage criterion {spec!r}: {arg!r} is not a number (the {parameter})") from None


def make_criterion(spec: str, profile: Any = None, default: float | None = None) -> Criterion:
    """A criterion from ``name[:value]``.

    ``nc:0.2`` (threshold), ``kmnc:10`` (k), ``nbc:1.0`` / ``snac:0.5`` (σ), ``tknc:2`` /
    ``tknp:2`` (k). Without a value: ``default``, else the criterion's own default.

    Args:
        spec: The spec (case and surrounding spaces do not matter).
        profile: The training profile KMNC, NBC and SNAC need.
        default: The value when the spec has none.

    Raises:
        CoverageError: Unknown name, bad value, or a profiled criterion without a profile.
    """
    name, given = parse_spec(spec)
    value = given if given is not None else (SPEC_PARAMETER[name][1] if default is None else float(default))
    try:
        if name == "nc":
            return NeuronCoverage(value)
        if name in PROFILED:
            cls = {"kmnc": KMultisectionCoverage, "nbc": NeuronBoundaryCoverage, "snac": StrongActivationCoverage}
            return cls[name](profile, value)  # type: ignore[arg-type]
        return (TopKCoverage if name == "tknc" else TopKPatterns)(value)  # type: ignore[arg-type]
    except CoverageError as exc:
        raise CoverageError(f"coverage criterion {spec!r}: {exc}") from None


def make_criteria(specs: Sequence[str] | str, profile: Any = None, **options: float) -> list[Criterion]:
    """Criteria from specs (see :func:`make_criterion`), each name at most once.

    Args:
        specs: Specs, or one comma-separated string (``"nc:0.2,tknc:2"``).
        profile: The training profile KMNC, NBC and SNAC need.
        **options: Per-criterion value for specs that give none, keyed by name
            (``make_criteria(["nc", "kmnc"], profile, nc=0.5, kmnc=4)``).

    Example:
        >>> [c.name for c in make_criteria("nc:0.5, tknc:1, tknp")]
        ['nc', 'tknc', 'tknp']
    """
    if isinstance(specs, str):
        specs = [s for s in specs.split(",") if s.strip()]
    unknown = sorted(set(options) - set(CRITERIA))
    if unknown:
        raise CoverageError(f"unknown criterion option(s) {unknown}; options are keyed by criterion name "
                            f"({', '.join(CRITERIA)})")
    criteria = [make_criterion(s, profile, options.get(s.strip().partition(":")[0].strip().lower())) for s in specs]
    names = [c.name for c in criteria]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise CoverageError(f"criterion {twice[0]!r} is asked for twice in {list(specs)}; keep one "
                            "(results are keyed by criterion name)")
    return criteria
