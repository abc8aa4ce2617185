"""Neuron coverage of learned systems under test (DeepTest, DeepGauge, DeepHunter).

``criteria`` holds the criteria (numpy only); ``hooks`` records neuron values from any
``torch.nn.Module`` in the forward pass the system makes anyway; ``profile`` streams the
training-set ranges KMNC, NBC and SNAC need, keyed by model fingerprint. PyTorch (extra
``learned``) is imported only by the functions that run a model.
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
    make_criteria,
    make_criterion,
)
from lidarfuzz.coverage.hooks import ActivationRecorder, default_layers, layer_sizes, module_fingerprint, neuron_values
from lidarfuzz.coverage.profile import NeuronProfile, ProfileStore, build_profile

__all__ = [
    "CRITERIA",
    "ActivationRecorder",
    "CoverageError",
    "Criterion",
    "KMultisectionCoverage",
    "NeuronBoundaryCoverage",
    "NeuronCoverage",
    "NeuronProfile",
    "ProfileStore",
    "StrongActivationCoverage",
    "TopKCoverage",
    "TopKPatterns",
    "build_profile",
    "default_layers",
    "layer_sizes",
    "make_criteria",
    "make_criterion",
    "module_fingerprint",
    "neuron_values",
]
