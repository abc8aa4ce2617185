"""Neuron values from forward hooks, model fingerprints and streamed training profiles (hand-built tiny nets)."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from torch import nn  # noqa: E402

from lidarfuzz.coverage import (  # noqa: E402
    ActivationRecorder,
    CoverageError,
    CoverageTracker,
    NeuronProfile,
    ProfileFileError,
    ProfileStore,
    build_profile,
    default_layers,
    layer_sizes,
    make_criterion,
    module_fingerprint,
    neuron_values,
)
from lidarfuzz.coverage.hooks import reduce_output  # noqa: E402
from lidarfuzz.errors import DataFormatError  # noqa: E402

pytestmark = pytest.mark.torch


def tiny_net() -> nn.Sequential:
    """Linear(2, 3) → ReLU → Linear(3, 2) → ReLU with hand-set weights.

    W1 = [[1, 0], [0, 1], [1, -1]], b1 = [0, 0, -1];  W2 = [[1, 1, 0], [0, -1, 1]], b2 = [0, 0.5]
    """
    net = nn.Sequential(nn.Linear(2, 3), nn.ReLU(), nn.Linear(3, 2), nn.ReLU())
    with torch.no_grad():
        net[0].weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, -1.0]]))
        net[0].bias.copy_(torch.tensor([0.0, 0.0, -1.0]))
        net[2].weight.copy_(torch.tensor([[1.0, 1.0, 0.0], [0.0, -1.0, 1.0]]))
        net[2].bias.copy_(torch.tensor([0.0, 0.5]))
    return net


X = [[1.0, 2.0], [3.0, -1.0]]
# layer "0" (pre-activation): x0 → [1, 2, 1 − 2 − 1 = −2];  x1 → [3, −1, 3 + 1 − 1 = 3]
PRE_1 = [[1.0, 2.0, -2.0], [3.0, -1.0, 3.0]]
# layer "1" = ReLU of that
RELU_1 = [[1.0, 2.0, 0.0], [3.0, 0.0, 3.0]]
# layer "3": [1, 2, 0] → ReLU([1 + 2, −2 + 0 + .5]) = [3, 0];  [3, 0, 3] → ReLU([3, 0 + 3 + .5]) = [3, 3.5]
RELU_3 = [[3.0, 0.0], [3.0, 3.5]]


def all_hooks_gone(model: nn.Module) -> bool:
    return all(not m._forward_hooks and not m._forward_pre_hooks for m in model.modules())


class Twice(nn.Module):
    """Applies the same ReLU twice: relu(relu(x) − 1)."""

    def __init__(self) -> None:
        super().__init__()
        self.relu = nn.ReLU()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.relu(self.relu(x) - 1)


class Chooser(nn.Module):
    """Watches its linear layer, not its activation, through ``coverage_layers()``."""

    def __init__(self) -> None:
        super().__init__()
        self.lin = nn.Linear(2, 2)
        self.act = nn.ReLU()
        with torch.no_grad():
            self.lin.weight.copy_(torch.tensor([[1.0, 1.0], [1.0, -1.0]]))
            self.lin.bias.zero_()

    def coverage_layers(self) -> list[str]:
        return ["lin"]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.lin(x))


# -- ActivationRecorder -------------------------------------------------------------------------


def test_recorder_watches_activations_after_the_nonlinearity() -> None:
    net = tiny_net()
    recorder = ActivationRecorder(net)
    assert recorder.layers == ["1", "3"]
    assert default_layers(net) == ["1", "3"]
    with recorder:
        assert recorder.active
        net(torch.tensor(X))
    assert not recorder.active
    got = recorder.values()
    assert list(got) == ["1", "3"]
    np.testing.assert_array_equal(got["1"], RELU_1)
    np.testing.assert_array_equal(got["3"], RELU_3)
    assert got["1"].dtype == np.float32
    assert layer_sizes(got) == {"1": 3, "3": 2}


def test_recorder_concatenates_forwards_until_clear() -> None:
    net = tiny_net()
    recorder = ActivationRecorder(net)
    with recorder:
        net(torch.tensor(X[:1]))
        net(torch.tensor(X[1:]))
    # two forwards of one input each → the same two rows as one forward of both
    np.testing.assert_array_equal(recorder.values()["1"], RELU_1)
    recorder.clear()
    assert recorder.values() == {}
    # outside the block nothing is recorded
    net(torch.tensor(X))
    assert recorder.values() == {}


def test_recorder_works_in_grad_mode() -> None:
    net = tiny_net()
    recorder = ActivationRecorder(net, layers=["3"])
    with recorder:
        out = net(torch.tensor(X, requires_grad=True))
    out.sum().backward()  # the graph is intact
    np.testing.assert_array_equal(recorder.values()["3"], RELU_3)


def test_conv_channels_are_spatial_means() -> None:
    conv = nn.Sequential(nn.Conv2d(1, 2, kernel_size=1), nn.ReLU())
    with torch.no_grad():
        conv[0].weight.copy_(torch.tensor([2.0, -1.0]).reshape(2, 1, 1, 1))
        conv[0].bias.copy_(torch.tensor([0.0, 1.0]))
    x = torch.tensor([[1.0, -2.0], [3.0, 0.0]]).reshape(1, 1, 2, 2)
    got = neuron_values(conv, x)
    # channel 0: 2x = [[2, −4], [6, 0]] → ReLU [[2, 0], [6, 0]] → mean 8 / 4 = 2
    # channel 1: −x + 1 = [[0, 3], [−2, 1]] → ReLU [[0, 3], [0, 1]] → mean 4 / 4 = 1
    assert list(got) == ["1"]
    np.testing.assert_allclose(got["1"], [[2.0, 1.0]])


def test_reduce_output_shapes() -> None:
    # (N,) → (N, 1); (N, F) kept; (N, C, L) → per-channel means over L
    np.testing.assert_array_equal(reduce_output(torch.tensor([1.0, 2.0])).numpy(), [[1.0], [2.0]])
    np.testing.assert_array_equal(reduce_output(torch.tensor([[1.0, 2.0]])).numpy(), [[1.0, 2.0]])
    # channel 0: (1 + 3) / 2 = 2; channel 1: (0 + 5) / 2 = 2.5
    np.testing.assert_array_equal(reduce_output(torch.tensor([[[1.0, 3.0], [0.0, 5.0]]])).numpy(), [[2.0, 2.5]])


def test_custom_reducer() -> None:
    net = tiny_net()
    got = neuron_values(net, torch.tensor(X), layers=["1"], reducers={"1": lambda out: out.sum(dim=1, keepdim=True)})
    # row sums of RELU_1: 1 + 2 + 0 = 3; 3 + 0 + 3 = 6
    np.testing.assert_array_equal(got["1"], [[3.0], [6.0]])


def test_explicit_layers_and_errors() -> None:
    net = tiny_net()
    assert ActivationRecorder(net, layers=["0", "3"]).layers == ["0", "3"]
    with pytest.raises(CoverageError, match=r"no layer\(s\) \['9'\]"):
        ActivationRecorder(net, layers=["1", "9"])
    # a model without activation modules needs its layers named
    with pytest.raises(CoverageError, match="no activation modules"):
        ActivationRecorder(nn.Sequential(nn.Linear(2, 2)))


def test_hooks_are_removed_after_the_block_and_after_an_exception() -> None:
    net = tiny_net()
    recorder = ActivationRecorder(net)
    with recorder:
        assert net[1]._forward_hooks and net[3]._forward_hooks and net._forward_pre_hooks
        net(torch.tensor(X))
    assert all_hooks_gone(net)

    with pytest.raises(RuntimeError), recorder:
        net(torch.ones(1, 5))  # 5 features into Linear(2, 3) → shape error inside the block
    assert not recorder.active
    assert all_hooks_gone(net)


def test_module_called_twice_gives_two_layers() -> None:
    model = Twice()
    assert default_layers(model) == ["relu"]
    x = torch.tensor([[2.0, -1.0], [0.5, 3.0]])
    got = neuron_values(model, x)
    # first call: ReLU(x) = [[2, 0], [.5, 3]];  second: ReLU([[1, −1], [−.5, 2]]) = [[1, 0], [0, 2]]
    assert list(got) == ["relu", "relu#2"]
    np.testing.assert_array_equal(got["relu"], [[2.0, 0.0], [0.5, 3.0]])
    np.testing.assert_array_equal(got["relu#2"], [[1.0, 0.0], [0.0, 2.0]])

    # each forward starts counting anew: two forwards → still two layers, of 2 + 2 rows
    recorder = ActivationRecorder(model)
    with recorder:
        model(x)
        model(x)
    got = recorder.values()
    assert list(got) == ["relu", "relu#2"]
    assert got["relu"].shape == got["relu#2"].shape == (4, 2)


def test_neuron_values() -> None:
    net = tiny_net()
    got = neuron_values(net, torch.tensor(X))
    np.testing.assert_array_equal(got["1"], RELU_1)
    np.testing.assert_array_equal(got["3"], RELU_3)
    # a named pre-activation layer keeps its negative values
    np.testing.assert_array_equal(neuron_values(net, torch.tensor(X), layers=["0"])["0"], PRE_1)
    # a custom forward: the batch is a dict
    got = neuron_values(net, {"points": torch.tensor(X)}, forward=lambda b: net(b["points"]))
    np.testing.assert_array_equal(got["3"], RELU_3)
    assert all_hooks_gone(net)


def test_coverage_layers_is_honoured() -> None:
    model = Chooser()
    assert default_layers(model) == ["lin"]
    recorder = ActivationRecorder(model)
    assert recorder.layers == ["lin"]
    got = neuron_values(model, torch.tensor([[1.0, 3.0]]))
    # lin: [1 + 3, 1 − 3] = [4, −2] (before the ReLU, which is not watched)
    assert list(got) == ["lin"]
    np.testing.assert_array_equal(got["lin"], [[4.0, -2.0]])


def test_values_feed_a_criterion() -> None:
    nc = make_criterion("nc:0.5")
    nc.update(neuron_values(tiny_net(), torch.tensor(X)))
    # "1": [1, 2, 0] → scaled [.5, 1, 0] → {1}; [3, 0, 3] → [1, 0, 1] → {0, 2}  → 3 of 3
    # "3": [3, 0] → [1, 0] → {0}; [3, 3.5] → [0, 1] → {1}                   → 2 of 2  → 5 / 5
    assert nc.coverage() == 1.0


# -- module_fingerprint -------------------------------------------------------------------------


def seeded_net() -> nn.Sequential:
    torch.manual_seed(1234)
    return nn.Sequential(nn.Linear(2, 3), nn.ReLU(), nn.Linear(3, 2))


def test_module_fingerprint() -> None:
    a, b = seeded_net(), seeded_net()
    fingerprint = module_fingerprint(a)
    assert len(fingerprint) == 16
    int(fingerprint, 16)  # hex
    assert fingerprint == module_fingerprint(b)
    with torch.no_grad():
        b[2].weight[0, 0] += 0.5
    assert module_fingerprint(b) != fingerprint
    assert module_fingerprint(a) == fingerprint  # a is untouched


# -- NeuronProfile ------------------------------------------------------------------------------


def test_profile_by_hand() -> None:
    profile = NeuronProfile("f")
    profile.update({"a": np.array([[1.0], [3.0]])})
    profile.update({"a": np.array([[5.0]])})
    layer = profile.layers["a"]
    # values 1, 3, 5: min 1, max 5, mean 3, population std sqrt((4 + 0 + 4) / 3) = sqrt(8 / 3)
    assert layer["count"].tolist() == [3]  # one count per neuron
    assert profile.inputs == 3
    np.testing.assert_allclose(layer["min"], [1.0])
    np.testing.assert_allclose(layer["max"], [5.0])
    np.testing.assert_allclose(layer["mean"], [3.0])
    np.testing.assert_allclose(layer["std"], [np.sqrt(8 / 3)])
    assert profile.layer_names == ["a"]
    assert profile.total_neurons == 1


def test_profile_streams_uneven_batches() -> None:
    rng = np.random.default_rng(7)
    sizes = (1, 5, 2)
    batches = [{"a": rng.normal(3.0, 2.0, (n, 4)), "b": rng.uniform(-1, 1, (n, 2)) * 100} for n in sizes]
    profile = NeuronProfile()
    for batch in batches:
        profile.update(batch)
    assert profile.inputs == 8  # 1 + 5 + 2
    assert profile.total_neurons == 6  # 4 + 2
    for name in ("a", "b"):
        everything = np.concatenate([batch[name] for batch in batches])
        layer = profile.layers[name]
        assert layer["count"].tolist() == [8] * everything.shape[1]
        np.testing.assert_allclose(layer["min"], everything.min(axis=0))
        np.testing.assert_allclose(layer["max"], everything.max(axis=0))
        np.testing.assert_allclose(layer["mean"], everything.mean(axis=0), rtol=1e-12)
        np.testing.assert_allclose(layer["std"], everything.std(axis=0, ddof=0), rtol=1e-12)


def test_profile_rejects_a_changed_layer_width() -> None:
    profile = NeuronProfile()
    profile.update({"a": np.zeros((2, 3))})
    with pytest.raises(CoverageError, match="3 neurons, now 2"):
        profile.update({"a": np.zeros((2, 2))})


def test_profile_save_load_round_trip(tmp_path) -> None:
    profile = NeuronProfile("0123456789abcdef")
    profile.update({"a": np.array([[1.0, 2.0], [3.0, 6.0]]), "b": np.array([[0.5], [1.5]])})
    path = profile.save(tmp_path / "sub" / "p.npz")
    assert path == tmp_path / "sub" / "p.npz" and path.exists()
    assert [p.name for p in path.parent.iterdir()] == ["p.npz"]  # no temporary file left

    loaded = NeuronProfile.load(path)
    assert loaded.fingerprint == "0123456789abcdef"
    assert loaded.inputs == 2
    assert loaded.layer_names == ["a", "b"]
    for name in ("a", "b"):
        for key in ("count", "min", "max", "mean", "std"):
            np.testing.assert_array_equal(loaded.layers[name][key], profile.layers[name][key])

    # the squared deviations travel too: both continue to the same numbers
    more = {"a": np.array([[5.0, -2.0]]), "b": np.array([[4.5]])}
    profile.update(more)
    loaded.update(more)
    # a: values 1, 3, 5 → mean 3, std sqrt(8 / 3);  2, 6, −2 → mean 2, std sqrt((0 + 16 + 16) / 3) = sqrt(32 / 3)
    np.testing.assert_allclose(loaded.layers["a"]["mean"], [3.0, 2.0])
    np.testing.assert_allclose(loaded.layers["a"]["std"], [np.sqrt(8 / 3), np.sqrt(32 / 3)])
    np.testing.assert_allclose(loaded.layers["a"]["std"], profile.layers["a"]["std"])
    # b: .5, 1.5, 4.5 → mean 6.5 / 3, population std = sqrt(mean of squares − mean²)
    mean_b = 6.5 / 3
    np.testing.assert_allclose(loaded.layers["b"]["mean"], [mean_b])
    np.testing.assert_allclose(loaded.layers["b"]["std"], [np.sqrt((0.25 + 2.25 + 20.25) / 3 - mean_b**2)])
    assert loaded.inputs == 3


def test_loading_a_corrupt_profile_names_the_file(tmp_path) -> None:
    bad = tmp_path / "corrupt.npz"
    bad.write_bytes(b"this is not a zip archive")
    with pytest.raises(CoverageError) as info:
        NeuronProfile.load(bad)
    assert str(bad) in str(info.value)
    missing = tmp_path / "missing.npz"
    with pytest.raises(CoverageError, match="no such profile") as info:
        NeuronProfile.load(missing)
    assert str(missing) in str(info.value)


def test_profile_store(tmp_path) -> None:
    store = ProfileStore(tmp_path / "profiles")
    profile = NeuronProfile()
    profile.update({"a": np.array([[1.0, -1.0], [2.0, 1.0]])})
    path = store.put("feedfacecafebeef", profile)
    assert path == tmp_path / "profiles" / "feedfacecafebeef.npz"
    assert profile.fingerprint == "feedfacecafebeef"

    got = store.get("feedfacecafebeef")
    assert got is not None and got.fingerprint == "feedfacecafebeef"
    np.testing.assert_array_equal(got.layers["a"]["min"], [1.0, -1.0])
    np.testing.assert_array_equal(got.layers["a"]["max"], [2.0, 1.0])
    assert store.get("0000000000000000") is None

    # read-only extra folders are searched too
    assert ProfileStore(tmp_path / "empty", extra=[tmp_path / "profiles"]).get("feedfacecafebeef") is not None
    # a file under another fingerprint's name is refused
    path.rename(path.with_name("0123012301230123.npz"))
    with pytest.raises(CoverageError, match="feedfacecafebeef"):
        store.get("0123012301230123")


def test_build_profile_on_the_tiny_net() -> None:
    net = tiny_net()
    profile = build_profile(net, [torch.tensor(X[:1]), torch.tensor(X[1:])], fingerprint=module_fingerprint(net))
    assert profile.fingerprint == module_fingerprint(net)
    assert profile.layer_names == ["1", "3"]
    assert profile.inputs == 2
    a, b = profile.layers["1"], profile.layers["3"]
    # "1": rows [1, 2, 0] and [3, 0, 3] → min [1, 0, 0], max [3, 2, 3], mean [2, 1, 1.5], std [1, 1, 1.5]
    np.testing.assert_allclose(a["min"], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(a["max"], [3.0, 2.0, 3.0])
    np.testing.assert_allclose(a["mean"], [2.0, 1.0, 1.5])
    np.testing.assert_allclose(a["std"], [1.0, 1.0, 1.5])
    # "3": rows [3, 0] and [3, 3.5] → min [3, 0], max [3, 3.5], mean [3, 1.75], std [0, 1.75]
    np.testing.assert_allclose(b["min"], [3.0, 0.0])
    np.testing.assert_allclose(b["max"], [3.0, 3.5])
    np.testing.assert_allclose(b["mean"], [3.0, 1.75])
    np.testing.assert_allclose(b["std"], [0.0, 1.75])
    assert all_hooks_gone(net)

    # the profile drives KMNC (k = 2): x0 → "1" [1, 2, 0]: neuron 0 at low → section 0; neuron 1 at high
    # → last section 1; neuron 2 at low → 0.  "3" [3, 0]: neuron 0 has low = high = 3 → section 0;
    # neuron 1 at low → 0.  5 sections of 2 · 5 = 10
    kmnc = make_criterion("kmnc:2", profile)
    kmnc.update(neuron_values(net, torch.tensor(X[:1])))
    assert (kmnc.covered(), kmnc.total) == (5, 10)


# -- more recorder behaviour --------------------------------------------------------------------


def test_conv_kernel_2_channel_means_feed_nc() -> None:
    conv = nn.Sequential(nn.Conv2d(1, 2, kernel_size=2), nn.ReLU())
    with torch.no_grad():
        conv[0].weight.copy_(torch.tensor([[[[1.0, 0.0], [0.0, 1.0]]], [[[0.0, -1.0], [1.0, 0.0]]]]))
        conv[0].bias.copy_(torch.tensor([0.0, 2.0]))
    x = torch.arange(9.0).reshape(1, 1, 3, 3)  # [[0, 1, 2], [3, 4, 5], [6, 7, 8]]
    got = neuron_values(conv, x)
    # channel 0 = top-left + bottom-right: [[0 + 4, 1 + 5], [3 + 7, 4 + 8]] = [[4, 6], [10, 12]] → mean 8
    # channel 1 = bottom-left − top-right + 2: [[3 − 1, 4 − 2], [6 − 4, 7 − 5]] + 2 = all 4 → mean 4
    np.testing.assert_allclose(got["1"], [[8.0, 4.0]])
    nc = make_criterion("nc:0.2")
    nc.update(got)
    # scaled [1, 0] → only channel 0 → 1 / 2
    assert nc.covered_items.tolist() == [True, False]


def test_unknown_layer_error_suggests_close_names() -> None:
    net = nn.Sequential()
    net.add_module("block", nn.Sequential(nn.Linear(2, 2), nn.ReLU()))
    # a typo: the message suggests the near names and lists some real ones
    with pytest.raises(ValueError, match=r"no layer\(s\) \['blok.1'\]; did you mean \[[^]]*'block.1'.*include"):
        ActivationRecorder(net, ["blok.1"])
    with pytest.raises(CoverageError, match="reducers for \\['zz'\\]"):
        ActivationRecorder(net, ["block.1"], reducers={"zz": lambda out: out})


class TupleOut(nn.Module):
    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return x, x


def test_non_tensor_output_and_bad_reducer_are_named() -> None:
    model = nn.Sequential()
    model.add_module("pair", TupleOut())
    with pytest.raises(CoverageError, match="layer 'pair' returns tuple"):
        neuron_values(model, torch.ones(1, 2), layers=["pair"])
    net = tiny_net()
    with pytest.raises(CoverageError, match=r"layer '1': the reducer must return \(inputs, units\)"):
        neuron_values(net, torch.tensor(X), layers=["1"], reducers={"1": lambda out: out.sum()})
    assert all_hooks_gone(net)


def test_recorder_cannot_be_entered_twice() -> None:
    net = tiny_net()
    recorder = ActivationRecorder(net)
    with recorder, pytest.raises(CoverageError, match="already recording"), recorder:
        pass
    assert all_hooks_gone(net)


class PillarNet(nn.Module):
    """Point-wise features (P, C) with a frame index per point, then a per-frame max."""

    def __init__(self) -> None:
        super().__init__()
        self.lin = nn.Linear(1, 2)
        self.act = nn.ReLU()
        with torch.no_grad():
            self.lin.weight.copy_(torch.tensor([[1.0], [-1.0]]))
            self.lin.bias.zero_()
        self.last_index = torch.zeros(0, dtype=torch.long)

    def forward(self, batch: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        points, index = batch
        self.last_index = index
        return self.act(self.lin(points))


def test_reducer_for_a_layer_that_is_not_batch_first() -> None:
    model = PillarNet()

    def per_frame_mean(features: torch.Tensor) -> torch.Tensor:  # (P, C) → (frames, C)
        index = model.last_index
        sums = features.new_zeros(int(index.max()) + 1, features.shape[1]).index_add_(0, index, features)
        return sums / torch.bincount(index).unsqueeze(1)

    points = torch.tensor([[1.0], [3.0], [-2.0]])  # points 0 and 1 in frame 0, point 2 in frame 1
    index = torch.tensor([0, 0, 1])
    got = neuron_values(model, (points, index), layers=["act"], reducers={"act": per_frame_mean})
    # features ReLU([p, −p]): [1, 0], [3, 0], [0, 2] → frame 0 mean [2, 0], frame 1 [0, 2]
    np.testing.assert_allclose(got["act"], [[2.0, 0.0], [0.0, 2.0]])
    # without the reducer the layer has one row per point: a criterion says what to do
    raw = neuron_values(model, (points, index), layers=["lin", "act"],
                        reducers={"lin": lambda f: f[:2]})  # 2 rows vs 3 rows
    with pytest.raises(CoverageError, match="reducer"):
        make_criterion("nc").update(raw)


# -- fingerprints -------------------------------------------------------------------------------


def test_module_fingerprint_is_a_fixed_function_of_class_and_weights() -> None:
    # a golden value: the same in every process, on every machine, and in earlier versions
    # (profiles shipped beside weights are found by it)
    assert module_fingerprint(tiny_net()) == "f5439136179a9627"
    half = tiny_net().to(torch.bfloat16)  # a dtype numpy lacks still hashes, to another value
    assert module_fingerprint(half) == "b934044000ea02bb"


class WithExtraState(nn.Module):
    def __init__(self, tag: str) -> None:
        super().__init__()
        self.tag = tag

    def get_extra_state(self) -> dict[str, str]:
        return {"tag": self.tag}

    def set_extra_state(self, state: dict[str, str]) -> None:
        self.tag = state["tag"]


def test_module_fingerprint_counts_extra_state_and_class() -> None:
    assert module_fingerprint(WithExtraState("a")) == module_fingerprint(WithExtraState("a"))
    assert module_fingerprint(WithExtraState("a")) != module_fingerprint(WithExtraState("b"))
    # same (no) weights, another class → another fingerprint
    assert module_fingerprint(nn.ReLU()) != module_fingerprint(nn.Tanh())


# -- profiles: non-finite values, old files, corruption -------------------------------------------


def test_profile_skips_non_finite_values_per_neuron() -> None:
    profile = NeuronProfile()
    profile.update({"a": np.array([[1.0, np.nan, np.nan], [3.0, 2.0, np.nan]])})
    profile.update({"a": np.array([[np.inf, 4.0, np.nan]])})
    layer = profile.layers["a"]
    # neuron 0: 1, 3 → count 2, mean 2, std 1;  neuron 1: 2, 4 → count 2, mean 3, std 1;  neuron 2: nothing
    assert layer["count"].tolist() == [2, 2, 0]
    np.testing.assert_allclose(layer["mean"][:2], [2.0, 3.0])
    np.testing.assert_allclose(layer["std"][:2], [1.0, 1.0])
    np.testing.assert_allclose(layer["min"][:2], [1.0, 2.0])
    np.testing.assert_allclose(layer["max"][:2], [3.0, 4.0])
    assert np.isnan(layer["min"][2]) and np.isnan(layer["max"][2])
    assert profile.inputs == 3
    # a neuron without a profiled value covers no corner
    assert make_criterion("nbc", profile).gain({"a": np.array([[0.0, 2.5, 1e9]])}).tolist() == [1]  # neuron 0 low
    profile.update({"a": np.array([[2.0, 3.0, 5.0]])})
    np.testing.assert_allclose(layer["min"], [1.0, 2.0, 5.0])
    np.testing.assert_allclose(profile.layers["a"]["mean"], [2.0, 3.0, 5.0])


def test_profile_of_the_first_format_loads(tmp_path) -> None:
    # format 1 kept one count per layer
    header = {"format": 1, "fingerprint": "f", "layers": ["a"], "inputs": 2}
    path = tmp_path / "old.npz"
    np.savez(path, __header__=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8),
             **{"0.count": np.array(2), "0.min": np.array([1.0, 2.0]), "0.max": np.array([3.0, 6.0]),
                "0.mean": np.array([2.0, 4.0]), "0.std": np.array([1.0, 2.0]), "0.m2": np.array([2.0, 8.0])})
    loaded = NeuronProfile.load(path)
    assert loaded.layers["a"]["count"].tolist() == [2, 2]
    loaded.update({"a": np.array([[5.0, 4.0]])})
    # neuron 0: 1, 3, 5 → mean 3, std sqrt(8 / 3);  neuron 1: 2, 6, 4 → mean 4, std sqrt(8 / 3)
    np.testing.assert_allclose(loaded.layers["a"]["mean"], [3.0, 4.0])
    np.testing.assert_allclose(loaded.layers["a"]["std"], [np.sqrt(8 / 3)] * 2)


def test_profile_file_errors_name_the_file_and_what_is_wrong(tmp_path) -> None:
    no_header = tmp_path / "no_header.npz"
    np.savez(no_header, a=np.zeros(2))
    header = {"format": 2, "fingerprint": "f", "layers": ["a"], "inputs": 1}
    encoded = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    ragged = tmp_path / "ragged.npz"
    np.savez(ragged, __header__=encoded, **{"0.count": np.ones(2), "0.min": np.zeros(2), "0.max": np.zeros(3),
                                             "0.mean": np.zeros(2), "0.std": np.zeros(2), "0.m2": np.zeros(2)})
    lacking = tmp_path / "lacking.npz"
    np.savez(lacking, __header__=encoded, **{"0.min": np.zeros(2)})
    future = tmp_path / "future.npz"
    np.savez(future, __header__=np.frombuffer(json.dumps({**header, "format": 9}).encode(), dtype=np.uint8))
    cases = {no_header: "no header", ragged: "unequal shapes", lacking: "are missing", future: "format 9"}
    for path, what in cases.items():
        with pytest.raises(ProfileFileError, match=what) as info:
            NeuronProfile.load(path)
        assert str(path) in str(info.value) and "lidarfuzz profile" in str(info.value)
        # one class for every way a profile file is wrong: a DataFormatError and a CoverageError
        assert isinstance(info.value, DataFormatError) and isinstance(info.value, CoverageError)


def test_profile_store_default_folder_and_fingerprint_check(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("LIDARFUZZ_CACHE", str(tmp_path / "cache"))
    store = ProfileStore()
    assert store.path_for("abc123") == tmp_path / "cache" / "profiles" / "abc123.npz"
    with pytest.raises(CoverageError, match="not a model fingerprint"):
        store.path_for("../escape")
    assert store.get("abc123") is None


def test_build_profile_fingerprints_the_model_by_default() -> None:
    net = tiny_net()
    assert build_profile(net, [torch.tensor(X)]).fingerprint == "f5439136179a9627"
    with pytest.raises(CoverageError, match="no batch"):
        build_profile(net, [])


# -- CoverageTracker ----------------------------------------------------------------------------


def test_tracker_probe_commit_observe() -> None:
    net = tiny_net()
    tracker = CoverageTracker(net, ["nc:0.5", "tknc:1", "tknp:1"])
    assert tracker.names == ["nc", "tknc", "tknp"]
    gains, got = tracker.probe(torch.tensor(X))
    # nc (t = .5, strict): input 0: "1" [1, 2, 0] → [.5, 1, 0] → {1}, "3" [3, 0] → {0}: items 1 and 3 → 2;
    #                      input 1: "1" [3, 0, 3] → {0, 2}, "3" [3, 3.5] → {1}: items 0, 2, 4 → 3
    # tknc (k = 1): input 0 → "1" index 1, "3" index 0 → 2;  input 1 → [3, 0, 3] tie → index 0, "3" index 1 → 2
    # tknp: patterns (1, 0) and (0, 1) → each new alone
    assert {k: v.tolist() for k, v in gains.items()} == {"nc": [2, 3], "tknc": [2, 2], "tknp": [1, 1]}
    assert tracker.summary() == {"nc": 0.0, "tknc": 0.0, "tknp": 0.0}  # probing changed nothing
    np.testing.assert_array_equal(got["3"], RELU_3)
    np.testing.assert_array_equal(tracker.last_output.numpy(), RELU_3)  # the forward's own output

    flags = tracker.commit(got)
    assert {k: v.tolist() for k, v in flags.items()} == {"nc": [True, True], "tknc": [True, True],
                                                        "tknp": [True, True]}
    # nc 5 / 5; tknc {1, 3, 0, 4} of 5 → 0.8; tknp 2 patterns
    assert tracker.summary() == pytest.approx({"nc": 1.0, "tknc": 0.8, "tknp": 2.0})
    # the first input again: nothing new anywhere
    again = tracker.observe(torch.tensor(X[:1]))
    assert {k: v.tolist() for k, v in again.items()} == {"nc": [False], "tknc": [False], "tknp": [False]}
    assert all_hooks_gone(net)


def test_tracker_state_copy_and_errors() -> None:
    net = tiny_net()
    tracker = CoverageTracker(net, [make_criterion("tknc:1"), "nc:0.5"])
    tracker.observe(torch.tensor(X[:1]))
    twin = tracker.copy()
    twin.observe(torch.tensor(X[1:]))
    assert (tracker.summary()["tknc"], twin.summary()["tknc"]) == pytest.approx((0.4, 0.8))

    fresh = CoverageTracker(net, ["nc:0.5", "tknc:1"])
    fresh.load_state_dict(twin.state_dict())
    assert fresh.summary() == twin.summary()
    assert fresh.observe(torch.tensor(X))["nc"].tolist() == [False, False]

    with pytest.raises(CoverageError, match="holds criteria"):
        CoverageTracker(net, ["nc:0.5"]).load_state_dict(twin.state_dict())
    with pytest.raises(CoverageError, match="other layers"):
        CoverageTracker(net, ["nc:0.5", "tknc:1"], layers=["1"]).load_state_dict(twin.state_dict())
    with pytest.raises(CoverageError, match="'nc' is given twice"):
        CoverageTracker(net, ["nc:0.5", make_criterion("nc")])
    with pytest.raises(CoverageError, match="needs a training-set profile"):
        CoverageTracker(net, ["kmnc"])
    # a forward that never reaches the model's layers
    with pytest.raises(CoverageError, match="reached none"):
        CoverageTracker(net, ["nc"], forward=lambda batch: batch).observe(torch.tensor(X))
