"""The training profile shipped beside the built-in ``pillars`` weights belongs to those weights:
named by their fingerprint, recording it, and of the network's layers and sizes (a retrained
``pillars-sim.pt`` without a rebuilt profile fails here, not in a user's guided campaign)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from lidarfuzz.coverage import ProfileStore, module_fingerprint  # noqa: E402
from lidarfuzz.coverage.hooks import layer_sizes, neuron_values  # noqa: E402
from lidarfuzz.coverage.profile import NeuronProfile  # noqa: E402
from lidarfuzz.scene.scene import Scene  # noqa: E402
from lidarfuzz.suts.learned.sut import WEIGHTS_DIR, PillarsDetector  # noqa: E402

pytestmark = pytest.mark.torch


@pytest.fixture(scope="module")
def detector() -> PillarsDetector:
    sut = PillarsDetector()
    sut.load()
    return sut


def test_the_shipped_profile_is_named_by_and_records_the_weights_fingerprint(detector: PillarsDetector) -> None:
    fingerprint = module_fingerprint(detector.module)
    assert sorted(p.name for p in WEIGHTS_DIR.glob("*.npz")) == [f"{fingerprint}.npz"], (
        f"the shipped weights' fingerprint is {fingerprint}: rebuild the profile (lidarfuzz profile pillars DATA) "
        f"and ship it as {WEIGHTS_DIR.name}/{fingerprint}.npz in place of the old one")
    profile = NeuronProfile.load(WEIGHTS_DIR / f"{fingerprint}.npz")
    assert profile.fingerprint == fingerprint
    assert profile.inputs > 0
    found = ProfileStore(extra=detector.profile_dirs()).get(fingerprint)  # the engine's own look-up
    assert found is not None and found.fingerprint == fingerprint


def test_the_shipped_profile_has_the_networks_layers_and_sizes(detector: PillarsDetector,
                                                               sample_scenes: list[Scene]) -> None:
    net = detector.module
    profile = NeuronProfile.load(WEIGHTS_DIR / f"{module_fingerprint(net)}.npz")
    assert set(profile.layer_names) == set(net.coverage_layers())
    points, index, size = detector.batch_tensors(sample_scenes[:1])
    values = neuron_values(net, (points, index, size), layers=profile.layer_names, forward=lambda b: net(*b))
    assert list(values) == profile.layer_names  # the order the forward pass runs them, as when it was built
    assert layer_sizes(values) == {name: int(layer["min"].size) for name, layer in profile.layers.items()}
    for name, layer in profile.layers.items():
        units = layer["min"].size
        assert all(layer[key].shape == (units,) for key in ("count", "min", "max", "mean", "std")), name
        seen = layer["count"] > 0
        assert seen.any(), f"{name}: no neuron had a value in the profile"
        assert np.all(layer["min"][seen] <= layer["max"][seen]), name
