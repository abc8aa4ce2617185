"""One model, several criteria, one forward pass per batch.

:class:`CoverageTracker` runs a batch through the model with the recorder's hooks on and
feeds the same neuron values to every criterion. A search that must decide before it
commits uses :meth:`~CoverageTracker.probe` (gains, state unchanged) and later
:meth:`~CoverageTracker.commit` with the values probe returned — no second forward.

Example:
    >>> import torch
    >>> net = torch.nn.Sequential(torch.nn.Linear(2, 4), torch.nn.ReLU())
    >>> tracker = CoverageTracker(net, ["nc:0.2", "tknc:1"])
    >>> gains, values = tracker.probe(torch.randn(3, 2))
    >>> sorted(gains), gains["nc"].shape
    (['nc', 'tknc'], (3,))
    >>> flags = tracker.commit(values)
    >>> 0.0 < tracker.summary()["tknc"] <= 1.0
    True
"""

from __future__ import annotations

import copy as _copy
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.coverage.criteria import CoverageError, Criterion, make_criteria
from lidarfuzz.coverage.hooks import ActivationRecorder, Reducer, import_torch

Values = dict[str, NDArray[np.float32]]


class CoverageTracker:
    """Coverage of one ``torch.nn.Module`` under several criteria.

    Args:
        model: Any ``torch.nn.Module``.
        criteria: :class:`~lidarfuzz.coverage.criteria.Criterion` objects or specs (``"nc:0.2"``),
            each name at most once.
        layers: Watched layers (default: the model's ``coverage_layers()`` or its activations).
        forward: How to run a batch (default ``model(batch)``); e.g. a SUT's ``detect_batch``.
        reducers: Per-layer reducers for layers whose first dimension is not the batch.
        profile: The training profile, for specs of KMNC, NBC or SNAC.

    Attributes:
        criteria: The criteria, in the order given.
        last_output: What the last forward returned (the detections, say), so a caller needs
            no second pass.
    """

    def __init__(self, model: Any, criteria: Sequence[Criterion | str], layers: Iterable[str] | None = None,
                 forward: Callable[[Any], Any] | None = None, reducers: Mapping[str, Reducer] | None = None,
                 profile: Any = None) -> None:
        specs = [c for c in criteria if isinstance(c, str)]
        built = iter(make_criteria(specs, profile)) if specs else iter(())
        self.criteria: list[Criterion] = [next(built) if isinstance(c, str) else c for c in criteria]
        if not self.criteria:
            raise CoverageError("a coverage tracker needs at least one criterion (e.g. ['nc:0.2'])")
        names = [c.name for c in self.criteria]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise CoverageError(f"criterion {twice[0]!r} is given twice; results are keyed by criterion name")
        self.model = model
        self.forward = forward
        self.recorder = ActivationRecorder(model, layers, reducers)
        self.last_output: Any = None

    @property
    def names(self) -> list[str]:
        """The criteria's names."""
        return [c.name for c in self.criteria]

    def criterion(self, name: str) -> Criterion:
        """The criterion called ``name``."""
        for c in self.criteria:
            if c.name == name:
                return c
        raise CoverageError(f"no criterion {name!r} here; this tracker has {self.names}")

    def values(self, batch: Any) -> Values:
        """Neuron values ``{layer: (N, units)}`` of one batch (one forward, without gradients)."""
        torch = import_torch()
        self.recorder.clear()
        with torch.inference_mode(), self.recorder:
            self.last_output = (self.forward or self.model)(batch)
        values = self.recorder.values()
        self.recorder.clear()
        if not values:
            raise CoverageError(f"the forward reached none of the watched layers {self.recorder.layers[:5]}; "
                                "does `forward` call this model?")
        return values

    def observe(self, batch: Any) -> dict[str, NDArray[np.bool_]]:
        """Run a batch and commit it to every criterion; per criterion, (N,) whether each input
        covered something new (judged after the inputs before it)."""
        return self.commit(self.values(batch))

    def probe(self, batch: Any) -> tuple[dict[str, NDArray[np.int64]], Values]:
        """Run a batch without changing any state; per criterion, (N,) how many new items each
        input alone would add, and the values to :meth:`commit` later."""
        values = self.values(batch)
        return self.gains(values), values

    def gains(self, values: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[np.int64]]:
        """Per criterion, (N,) gains of recorded values; state unchanged."""
        return {c.name: c.gain(values) for c in self.criteria}

    def commit(self, values: Mapping[str, NDArray[Any]]) -> dict[str, NDArray[np.bool_]]:
        """Commit recorded values (all inputs, in order; select rows first to commit fewer)."""
        return {c.name: c.update(values) for c in self.criteria}

    def summary(self) -> dict[str, float]:
        """Per criterion, its coverage (a fraction; TKNP: a pattern count)."""
        return {c.name: float(c.coverage()) for c in self.criteria}

    def reset(self) -> None:
        """Forget all coverage."""
        for c in self.criteria:
            c.reset()

    def state_dict(self) -> dict[str, Any]:
        """``{"layers": [...], "criteria": {name: criterion.state_dict()}}`` (numpy arrays inside)."""
        return {"layers": list(self.recorder.layers), "criteria": {c.name: c.state_dict() for c in self.criteria}}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`state_dict` output; the criteria must be the same."""
        saved = state.get("criteria", {})
        if sorted(saved) != sorted(self.names):
            raise CoverageError(f"the state holds criteria {sorted(saved)}, this tracker has {sorted(self.names)}")
        if "layers" in state and list(state["layers"]) != self.recorder.layers:
            raise CoverageError("the state was recorded on other layers; build the tracker with the same layers")
        for c in self.criteria:
            c.load_state_dict(saved[c.name])

    def copy(self) -> CoverageTracker:
        """A tracker on the same model with independent copies of the criteria."""
        twin = _copy.copy(self)
        twin.criteria = [c.copy() for c in self.criteria]
        twin.recorder = ActivationRecorder(self.model, self.recorder.layers, self.recorder.reducers)
        twin.last_output = None
        return twin

    def __repr__(self) -> str:
        return f"<CoverageTracker {self.summary()}>"
