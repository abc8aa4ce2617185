"""A tiny steering network for the web tests' camera tasks (``tests.web.camera_system:Net``).

Fixed weights, no training: a 5×5 convolution (stride 4) of the default 66×200 input, ReLU, a
global mean and a linear head. Its angle follows the image's brightness (every convolution weight
is positive), so fog, which whitens the image, turns it and DeepTest's relation has something to
find; the ReLU units give the guided search neurons to cover.
"""

from __future__ import annotations

import torch


class Net(torch.nn.Module):
    """Brightness in, steering out: the same weights in every process (seeded generator)."""

    def __init__(self) -> None:
        super().__init__()
        generator = torch.Generator().manual_seed(0)
        self.conv = torch.nn.Conv2d(3, 4, kernel_size=5, stride=4)
        self.act = torch.nn.ReLU()
        self.head = torch.nn.Linear(4, 1)
        with torch.no_grad():
            self.conv.weight.copy_(torch.rand(self.conv.weight.shape, generator=generator) / 75.0)
            self.conv.bias.copy_(  # type: ignore[union-attr]
                torch.tensor([-0.1, -0.2, -0.3, -0.4]))
            self.head.weight.copy_(torch.tensor([[3.0, 2.0, 1.0, 0.5]]))
            self.head.bias.fill_(-0.63)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        features = self.act(self.conv(images)).mean(dim=(2, 3))
        return self.head(features).squeeze(1)
