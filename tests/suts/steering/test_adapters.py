"""The PyTorch and ONNX adapters, and camera spec strings: a tiny module with hand-set weights,
an ONNX export equal to its module (NCHW and NHWC), specs naming modules and classes."""

from __future__ import annotations

import sys
import types
import warnings
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.base import FailureKind
from lidarfuzz.suts.errors import SutError
from lidarfuzz.suts.registry import SutSpecError, create_camera
from lidarfuzz.suts.steering.base import Steering

torch = pytest.importorskip("torch")

from lidarfuzz.suts.steering.onnx import OnnxSteering  # noqa: E402
from lidarfuzz.suts.steering.pytorch import TorchSteering  # noqa: E402

pytestmark = pytest.mark.torch


class ChannelMix(torch.nn.Module):
    """Mean of each channel, then a linear layer: weights (1, −1, 0.5), bias 0.1."""

    def __init__(self) -> None:
        super().__init__()
        self.pool = torch.nn.AdaptiveAvgPool2d(1)
        self.linear = torch.nn.Linear(3, 1)
        with torch.no_grad():
            self.linear.weight.copy_(torch.tensor([[1.0, -1.0, 0.5]]))
            self.linear.bias.fill_(0.1)

    def forward(self, x):  # type: ignore[no-untyped-def]
        return self.linear(torch.flatten(self.pool(x), 1))


class ChannelsLast(torch.nn.Module):
    """The same network taking N×H×W×C, as a Keras model exported with tf2onnx does."""

    def __init__(self, inner: torch.nn.Module) -> None:
        super().__init__()
        self.inner = inner

    def forward(self, x):  # type: ignore[no-untyped-def]
        return self.inner(x.permute(0, 3, 1, 2))


def uniform(rgb: tuple[int, int, int], frame_id: str = "f") -> ImageSample:
    image = np.empty((8, 12, 3), np.uint8)
    image[:] = rgb
    return ImageSample(image, frame_id=frame_id)


def random_frames(n: int, seed: int = 0) -> list[ImageSample]:
    rng = np.random.default_rng(seed)
    return [ImageSample(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), frame_id=str(i)) for i in range(n)]


def test_torch_wrapper_on_hand_set_weights() -> None:
    # RGB (100, 50, 200) /255, channel means the same: 1·100/255 − 1·50/255 + 0.5·200/255 + 0.1
    # = 150/255 + 0.1 = 0.688235
    system = TorchSteering(ChannelMix(), preprocess={"height": 2, "width": 2})
    with system:
        (answer,) = system.detect_batch([uniform((100, 50, 200))])
        assert answer.steering == pytest.approx(150 / 255 + 0.1, abs=1e-6)
        # (0, 255, 0): −1 + 0.1 = −0.9; a batch of two answers in order
        two = system.detect_batch([uniform((0, 255, 0)), uniform((100, 50, 200))])
        assert [round(s.steering, 6) for s in two] == [-0.9, round(150 / 255 + 0.1, 6)]
        assert system.detect(uniform((0, 0, 0))).steering == pytest.approx(0.1, abs=1e-7)
    assert system.module.training is False  # loaded in eval mode


def test_torch_wrapper_batches_in_chunks_and_rejects_wrong_output_shapes() -> None:
    system = TorchSteering(ChannelMix(), preprocess={"height": 2, "width": 2}, batch_size=2)
    frames = [uniform((v, 0, 0), str(v)) for v in (0, 51, 102, 153, 204)]
    # red only: v/255 + 0.1 → 0.1, 0.3, 0.5, 0.7, 0.9 over three forward passes of ≤ 2
    assert [round(s.steering, 6) for s in system.detect_batch(frames)] == [0.1, 0.3, 0.5, 0.7, 0.9]
    wide = TorchSteering(torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(12, 2)),
                         preprocess={"height": 2, "width": 2})
    with pytest.raises(SutError, match=r"one steering value per frame \(1\), got an output of shape \(1, 2\)") as bad:
        wide.detect(uniform((1, 2, 3)))
    assert bad.value.kind is FailureKind.INVALID_OUTPUT


def test_fingerprint_follows_weights_and_preprocessing() -> None:
    a = TorchSteering(ChannelMix(), preprocess={"height": 2, "width": 2})
    b = TorchSteering(ChannelMix(), preprocess={"height": 2, "width": 2})
    assert a.fingerprint() == b.fingerprint()
    with torch.no_grad():
        b.module.linear.bias.fill_(0.2)
    assert a.fingerprint() != b.fingerprint()
    c = TorchSteering(ChannelMix(), preprocess={"height": 2, "width": 2, "color": "yuv"})
    assert a.fingerprint() != c.fingerprint()


def export(module: torch.nn.Module, example: torch.Tensor, path: Path) -> Path:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
        torch.onnx.export(module.eval(), (example,), str(path), input_names=["image"], output_names=["steering"],
                          dynamic_axes={"image": {0: "batch"}, "steering": {0: "batch"}}, dynamo=False)
    return path


def test_onnx_equals_the_torch_model_it_was_exported_from(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from lidarfuzz.suts.steering.networks import Dave2Net

    torch.manual_seed(0)
    net = Dave2Net().eval()
    pre = {"height": 66, "width": 200, "color": "yuv", "crop_top": 0.25, "scale": 1 / 127.5, "offset": -1.0}
    path = export(net, torch.zeros(1, 3, 66, 200), tmp_path / "dave2.onnx")
    frames = random_frames(3)
    expected = np.array([s.steering for s in TorchSteering(net, preprocess=pre).detect_batch(frames)])
    with OnnxSteering(path, preprocess=pre) as onnx_system:
        got = np.array([s.steering for s in onnx_system.detect_batch(frames)])
    np.testing.assert_allclose(got, expected, atol=1e-5)
    assert np.ptp(expected) > 0  # different frames, different answers: the comparison means something

    # the same network behind a channels-last input: layout="nhwc" feeds it N×H×W×C
    nhwc = export(ChannelsLast(net), torch.zeros(1, 66, 200, 3), tmp_path / "dave2_nhwc.onnx")
    spec = f"onnx:{nhwc}?layout=nhwc&height=66&width=200&color=yuv&crop_top=0.25"
    keras_like = create_camera(spec, scale=1 / 127.5, offset=-1.0)
    assert isinstance(keras_like, OnnxSteering) and keras_like.layout == "nhwc"
    got_nhwc = np.array([s.steering for s in keras_like.detect_batch(frames)])
    np.testing.assert_allclose(got_nhwc, expected, atol=1e-5)


def test_onnx_model_with_a_fixed_batch_of_one(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    path = tmp_path / "fixed.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(ChannelMix().eval(), (torch.zeros(1, 3, 2, 2),), str(path), dynamo=False)
    system = OnnxSteering(path, preprocess={"height": 2, "width": 2})
    answers = system.detect_batch([uniform((0, 255, 0)), uniform((0, 0, 0))])
    assert [round(s.steering, 5) for s in answers] == [-0.9, 0.1]


def test_camera_specs_name_modules_classes_and_builtins(monkeypatch: pytest.MonkeyPatch) -> None:
    module = types.ModuleType("steering_spec_fixture")
    module.ChannelMix = ChannelMix  # type: ignore[attr-defined]
    module.instance = ChannelMix()  # type: ignore[attr-defined]
    module.system = TorchSteering(ChannelMix(), preprocess={"height": 2, "width": 2})  # type: ignore[attr-defined]
    module.not_a_net = lambda: 42  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "steering_spec_fixture", module)

    from_class = create_camera("steering_spec_fixture:ChannelMix?height=2&width=2", threads=2)
    assert isinstance(from_class, TorchSteering) and from_class.threads == 2
    assert from_class.preprocess.height == 2
    assert from_class.detect(uniform((100, 50, 200))).steering == pytest.approx(150 / 255 + 0.1, abs=1e-6)
    assert isinstance(create_camera("steering_spec_fixture:instance?width=2&height=2"), TorchSteering)
    assert create_camera("steering_spec_fixture:system") is module.system  # type: ignore[attr-defined]
    with pytest.raises(SutSpecError, match="an instance; it takes no options"):
        create_camera("steering_spec_fixture:system?height=3")
    with pytest.raises(SutSpecError, match=r"gave int, which is neither a SteeringSystem nor a torch\.nn\.Module"):
        create_camera("steering_spec_fixture:not_a_net")
    with pytest.raises(SutSpecError, match="color"):
        create_camera("steering_spec_fixture:ChannelMix?color=hsv")
    with pytest.raises(SutSpecError, match="LiDAR system"):
        create_camera("classic")
    with pytest.raises(SutSpecError, match="not subprocess:"):
        create_camera("subprocess:prog {points} {output}")
    assert create_camera("dave2").name == "dave2"


def test_answers_are_steering_objects() -> None:
    answer = TorchSteering(ChannelMix(), preprocess={"height": 2, "width": 2}).detect(uniform((0, 0, 0)))
    assert isinstance(answer, Steering)
