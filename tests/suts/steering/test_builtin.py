"""The built-in steering networks: architectures (parameter counts by hand), the committed weights
(load, finite answers, validation MSE below the mean baseline), neuron coverage layers and profiles."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from lidarfuzz.errors import LidarfuzzError, MissingDependencyError
from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.guard import run_guarded
from lidarfuzz.suts.registry import available_camera, create_camera
from lidarfuzz.suts.steering.builtin import BUILTINS, STEERING_RANGE, WEIGHTS_DIR, Chauffeur, Dave2, Epoch

NAMES = ("epoch", "dave2", "chauffeur")


def test_registered_under_the_camera_group_without_torch_at_construction() -> None:
    assert {"epoch", "dave2", "chauffeur"} <= set(available_camera())
    system = create_camera("dave2?threads=1")
    assert isinstance(system, Dave2) and system.weights_path == WEIGHTS_DIR / "dave2.pt"
    assert system.profile_dirs() == [WEIGHTS_DIR]


def test_missing_torch_is_one_line_naming_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "torch", None)  # import torch now raises ImportError
    with pytest.raises(MissingDependencyError, match=r"lidarfuzz\[learned\]") as missing:
        Epoch().load()
    assert "\n" not in str(missing.value)


def test_committed_weights_are_small_and_the_validation_beats_the_mean_baseline() -> None:
    files = [WEIGHTS_DIR / f"{name}.pt" for name in NAMES]
    assert sum(f.stat().st_size for f in files) <= 10 * 1024 * 1024
    figures = json.loads((WEIGHTS_DIR / "steering.json").read_text())
    for name in NAMES:
        row = figures["networks"][name]
        # the network must beat always answering the training labels' mean on the held-out frames
        assert row["val_mse"] < row["baseline_mean_mse"], name
        assert row["file_bytes"] == (WEIGHTS_DIR / f"{name}.pt").stat().st_size  # the figures are these weights'


torch = pytest.importorskip("torch")

from lidarfuzz.coverage import ActivationRecorder, ProfileStore, module_fingerprint  # noqa: E402
from lidarfuzz.suts.steering.networks import ChauffeurNet, Dave2Net, EpochNet  # noqa: E402


def frames(n: int, shape: tuple[int, int] = (240, 320), seed: int = 0) -> list[ImageSample]:
    rng = np.random.default_rng(seed)
    return [ImageSample(rng.integers(0, 256, (*shape, 3), dtype=np.uint8), frame_id=str(i)) for i in range(n)]


@pytest.mark.torch
def test_parameter_counts_worked_out_by_hand() -> None:
    # every convolution has no bias and a batch norm after it (2 parameters per channel)
    # Epoch: 3×3 convs 3→16 (432 + 32), 16→32 (4,608 + 64), 32→48 (13,824 + 96); dense 48·6·12 = 3,456 → 64
    # (221,248); 64 → 1 (65)
    assert EpochNet().parameter_count() == 464 + 4_672 + 13_920 + 221_248 + 65 == 240_369
    # DAVE-2: 5×5 convs 3→24 (1,800 + 48), 24→36 (21,600 + 72), 36→48 (43,200 + 96); 3×3 48→64 (27,648 + 128),
    # 64→64 (36,864 + 128); dense 64·1·18 = 1,152 → 100 (115,300), 100 → 50 (5,050), 50 → 10 (510), 10 → 1 (11)
    by_hand = 1_848 + 21_672 + 43_296 + 27_776 + 36_992 + 115_300 + 5_050 + 510 + 11
    assert Dave2Net().parameter_count() == by_hand == 252_455
    # Chauffeur: 3×3 convs 3→16 (432 + 32), 16→20 (2,880 + 40), 20→40 (7,200 + 80), 40→60 (21,600 + 120),
    # 60→80 (43,200 + 160), 80→128 (92,160 + 256); dense 128·2·3 = 768 → 64 (49,216); 64 → 1 (65)
    by_hand = 464 + 2_920 + 7_280 + 21_720 + 43_360 + 92_416 + 49_216 + 65
    assert ChauffeurNet().parameter_count() == by_hand == 217_441


@pytest.mark.torch
@pytest.mark.parametrize("name", NAMES)
def test_builtins_load_and_answer_finite_angles_in_range(name: str) -> None:
    with create_camera(name) as system:
        answers = system.detect_batch(frames(3) + frames(1, (375, 1242), seed=1))
        assert len(answers) == 4
        for answer in answers:
            assert np.isfinite(answer.steering) and STEERING_RANGE[0] <= answer.steering <= STEERING_RANGE[1]
        single = run_guarded(system, frames(1)[0])
        assert single.ok and single.output.steering == pytest.approx(answers[0].steering, abs=1e-6)
        assert system.meta["network"] == name


@pytest.mark.torch
def test_coverage_layers_are_recorded_one_neuron_per_channel_or_unit() -> None:
    system = Dave2()
    module = system.module
    recorder = ActivationRecorder(module)
    assert recorder.layers == module.coverage_layers() == [
        "features.conv1_relu", "features.conv2_relu", "features.conv3_relu", "features.conv4_relu",
        "features.conv5_relu", "head.fc1_relu", "head.fc2_relu", "head.fc3_relu"]
    with torch.inference_mode(), recorder:
        module(system.inputs(frames(2)))
    sizes = {name: values.shape for name, values in recorder.values().items()}
    assert sizes == {"features.conv1_relu": (2, 24), "features.conv2_relu": (2, 36), "features.conv3_relu": (2, 48),
                     "features.conv4_relu": (2, 64), "features.conv5_relu": (2, 64), "head.fc1_relu": (2, 100),
                     "head.fc2_relu": (2, 50), "head.fc3_relu": (2, 10)}
    assert all(np.all(v >= 0) for v in recorder.values().values())  # post-activation: ReLU outputs


@pytest.mark.torch
@pytest.mark.parametrize("system_class", [Epoch, Dave2, Chauffeur])
def test_the_training_profile_of_the_committed_weights_ships_beside_them(system_class: type) -> None:
    system = system_class()
    profile = ProfileStore(folder=WEIGHTS_DIR / "no-cache-here", extra=system.profile_dirs()).get(
        module_fingerprint(system.module))
    assert profile is not None, f"no profile of {system.name}'s weights in {WEIGHTS_DIR}"
    assert profile.layer_names == system.module.coverage_layers()
    assert profile.inputs >= 500


@pytest.mark.torch
def test_other_weights_change_the_fingerprint_and_a_foreign_file_is_refused(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from lidarfuzz.suts.steering.builtin import save_network

    other = save_network(Dave2Net(), "dave2", tmp_path / "mine.pt", {})
    assert Dave2(weights=str(other)).fingerprint() != Dave2().fingerprint()
    with pytest.raises(LidarfuzzError, match=r"mine\.pt: not epoch steering weights .*'dave2' weights"):
        Epoch(weights=str(other)).load()
    assert set(BUILTINS) == set(NAMES)
