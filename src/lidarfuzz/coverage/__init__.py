"""Neuron coverage of learned systems under test (DeepTest, DeepGauge, DeepHunter).

Neuron values are recorded by forward hooks on any ``torch.nn.Module`` — by default on the
outputs of its activation modules, or the layers its ``coverage_layers()`` names — one value
per neuron and input: a dense unit's output, or a convolution channel's feature map averaged
over its positions. Criteria read ``{layer: array (N, units)}`` and need no PyTorch. With v
a neuron's value on one input, and low, high, std the neuron's minimum, maximum and standard
deviation over the training set (a :class:`NeuronProfile`):

* **NC** (DeepTest, threshold t = 0.2): per input and layer, v scaled to
  ``(v − min_layer) / (max_layer − min_layer)`` (0 when the layer is constant); a neuron is
  activated when that is strictly above t. NC = activated neurons / neurons.
* **KMNC** (DeepGauge, k = 10): [low, high] in k equal sections; v covers section
  ``floor((v − low) / (high − low) · k)``, v = high the last one, values outside none.
  KMNC = covered sections / (k · neurons).
* **NBC** (σ = 0): corners v > high + σ·std and v < low − σ·std. NBC = covered / (2 · neurons).
* **SNAC** (σ = 0): the upper corner only. SNAC = covered / neurons.
* **TKNC** (k = 2): the k largest neurons of each layer per input (ties: lower index).
  TKNC = covered / neurons.
* **TKNP** (k = 2): the number of distinct per-input tuples of per-layer top-k sets (a count).

Modules: :mod:`~lidarfuzz.coverage.criteria` (the criteria, numpy only),
:mod:`~lidarfuzz.coverage.hooks` (recorder, fingerprint), :mod:`~lidarfuzz.coverage.profile`
(training profiles keyed by fingerprint) and :mod:`~lidarfuzz.coverage.tracker` (one forward
pass feeds every criterion). PyTorch (extra ``learned``) is imported only by functions that
run or hash a model; without it they raise an ImportError naming the extra.

Example:
    >>> import torch
    >>> net = torch.nn.Sequential(torch.nn.Conv2d(1, 4, 3), torch.nn.ReLU())
    >>> tracker = CoverageTracker(net, ["nc:0.2", "tknc:1", "tknp:1"])
    >>> new = tracker.observe(torch.randn(8, 1, 5, 5))  # {"nc": (8,) bool, ...}
    >>> sorted(tracker.summary())
    ['nc', 'tknc', 'tknp']
"""

from lidarfuzz.coverage.criteria import (
    CRITERIA,
    CoverageError,
    Criterion,
    KMultisectionCoverage,
    NeuronBoundaryCoverage,
    NeuronCoverage,
    StrongActivationCoverage,
    TopKCoverage,
    TopKPatterns,
    check_values,
    make_criteria,
    make_criterion,
)
from lidarfuzz.coverage.hooks import (
    ActivationRecorder,
    default_layers,
    layer_sizes,
    module_fingerprint,
    neuron_values,
)
from lidarfuzz.coverage.profile import NeuronProfile, ProfileFileError, ProfileStore, build_profile
from lidarfuzz.coverage.tracker import CoverageTracker

__all__ = [
    "CRITERIA",
    "ActivationRecorder",
    "CoverageError",
    "CoverageTracker",
    "Criterion",
    "KMultisectionCoverage",
    "NeuronBoundaryCoverage",
    "NeuronCoverage",
    "NeuronProfile",
    "ProfileFileError",
    "ProfileStore",
    "StrongActivationCoverage",
    "TopKCoverage",
    "TopKPatterns",
    "build_profile",
    "check_values",
    "default_layers",
    "layer_sizes",
    "make_criteria",
    "make_criterion",
    "module_fingerprint",
    "neuron_values",
]
