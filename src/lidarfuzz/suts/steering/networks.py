"""Three steering networks in the spirit of DeepTest's subjects (Tian et al., ICSE 2018, Table 1).

DeepTest tested the Udacity self-driving challenge's top models — Chauffeur, Rambo, Epoch —
and Nvidia's DAVE-2. These are small PyTorch re-creations of three of those architectures,
sized for the built-in world and for a CPU (about 250k parameters, 1 MB as float32, each), with
batch normalisation after every convolution (the originals had none; without it they did not
train on a few thousand frames in minutes):

* :class:`EpochNet` — Epoch's shape: three 3×3 convolution + max-pool blocks with dropout,
  then a dense layer and dropout (the original has 32/64/128 channels on 128×128 and a
  1024-unit dense layer; here 16/32/48 channels on 48×96 and 64 units);
* :class:`Dave2Net` — Nvidia's PilotNet/DAVE-2 as published (Bojarski et al. 2016): a 66×200
  YUV input, five convolutions (24, 36, 48 channels 5×5 stride 2; 64, 64 channels 3×3), three
  dense layers (100, 50, 10) and the output;
* :class:`ChauffeurNet` — Chauffeur's CNN: six 3×3 convolutions (16, 20, 40, 60, 80, 128
  channels), max-pooling between them, then a dense layer (48×96 input; the original's
  recurrent part is left out, as DeepTest tested its CNN).

Every network takes N×3×H×W float32 (:data:`lidarfuzz.suts.steering.builtin.PREPROCESS` declares how a frame becomes
that), returns N angles, and names its post-activation modules in ``coverage_layers()`` —
the neurons DeepTest's neuron coverage counts (a convolution channel's feature map averaged
is one neuron; :mod:`lidarfuzz.coverage.hooks`). PyTorch (extra ``learned``) is needed to
import this module.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import torch
from torch import nn


def _conv(name: str, cin: int, cout: int, kernel: int, stride: int = 1, padding: int = 0) -> list[tuple[str, Any]]:
    """A convolution, batch normalisation (what lets these nets train in minutes on a few thousand
    frames; the originals had none) and its ReLU."""
    return [(name, nn.Conv2d(cin, cout, kernel, stride=stride, padding=padding, bias=False)),
            (f"{name}_bn", nn.BatchNorm2d(cout)), (f"{name}_relu", nn.ReLU())]


class SteeringNet(nn.Module):
    """A convolutional trunk and a dense head ending in one angle; ``coverage_layers()`` names
    every ReLU (each its own module, so every layer's neurons are recorded once per forward)."""

    #: The input size (height, width) the network was built for.
    input_size: tuple[int, int] = (0, 0)

    def __init__(self, features: list[tuple[str, Any]], head: list[tuple[str, Any]]) -> None:
        super().__init__()
        self.features = nn.Sequential(OrderedDict(features))
        self.head = nn.Sequential(OrderedDict(head))
        # the head answers in units of the training labels' spread (set before training, saved
        # with the weights), so that it learns targets of order 1 whatever the labels' units
        self.register_buffer("output_scale", torch.tensor(1.0))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(torch.flatten(self.features(x), 1)).squeeze(1) * self.output_scale

    def coverage_layers(self) -> list[str]:
        """Names (as in ``named_modules()``) of the post-activation modules, input to output."""
        return [name for name, module in self.named_modules() if isinstance(module, nn.ReLU)]

    def parameter_count(self) -> int:
        """Trainable parameters."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)


class EpochNet(SteeringNet):
    """Epoch-like: 3 × (3×3 convolution, ReLU, 2×2 max-pool, dropout 0.25), dense 64, dropout 0.5."""

    input_size = (48, 96)

    def __init__(self) -> None:
        features: list[tuple[str, Any]] = []
        for i, (cin, cout) in enumerate([(3, 16), (16, 32), (32, 48)], start=1):
            features += [*_conv(f"conv{i}", cin, cout, 3, padding=1), (f"pool{i}", nn.MaxPool2d(2)),
                         (f"drop{i}", nn.Dropout(0.25))]
        head = [("fc1", nn.Linear(48 * 6 * 12, 64)), ("fc1_relu", nn.ReLU()), ("drop_fc", nn.Dropout(0.5)),
                ("out", nn.Linear(64, 1))]
        super().__init__(features, head)


class Dave2Net(SteeringNet):
    """DAVE-2/PilotNet: 66×200 YUV in, convolutions 24/36/48 (5×5, stride 2) and 64/64 (3×3), dense
    100/50/10, one output."""

    input_size = (66, 200)

    def __init__(self) -> None:
        features = [*_conv("conv1", 3, 24, 5, 2), *_conv("conv2", 24, 36, 5, 2), *_conv("conv3", 36, 48, 5, 2),
                    *_conv("conv4", 48, 64, 3), *_conv("conv5", 64, 64, 3)]
        head = [("fc1", nn.Linear(64 * 1 * 18, 100)), ("fc1_relu", nn.ReLU()), ("drop_fc", nn.Dropout(0.2)),
                ("fc2", nn.Linear(100, 50)), ("fc2_relu", nn.ReLU()), ("fc3", nn.Linear(50, 10)),
                ("fc3_relu", nn.ReLU()), ("out", nn.Linear(10, 1))]
        super().__init__(features, head)


class ChauffeurNet(SteeringNet):
    """Chauffeur-like: six 3×3 convolutions (16, 20, 40, 60, 80, 128), 2×2 max-pools after the
    first five, dropout 0.25, dense 64, one output."""

    input_size = (48, 96)

    def __init__(self) -> None:
        features: list[tuple[str, Any]] = []
        channels = [3, 16, 20, 40, 60, 80, 128]
        for i in range(1, 7):
            features += _conv(f"conv{i}", channels[i - 1], channels[i], 3, padding=1)
            if i <= 5:
                features.append((f"pool{i}", nn.MaxPool2d(2, ceil_mode=True)))
        features.append(("drop", nn.Dropout(0.25)))
        head = [("fc1", nn.Linear(128 * 2 * 3, 64)), ("fc1_relu", nn.ReLU()), ("out", nn.Linear(64, 1))]
        super().__init__(features, head)


#: The built-in networks by name.
NETWORKS: dict[str, Callable[[], SteeringNet]] = {"epoch": EpochNet, "dave2": Dave2Net, "chauffeur": ChauffeurNet}
