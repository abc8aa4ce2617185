"""Steering systems for the camera task's tests, named by spec (``tests.campaign.camera_systems:MeanRed``).

``MeanRed`` steers by the mean red value of the image, ``θ = mean(R) / 255 − 0.5``, so a test can work
out by hand what it answers on a uniform image; ``TinyNet`` is a small seeded CNN (a torch module with
neurons for coverage-guided search)."""

from __future__ import annotations

from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.steering.base import Steering, SteeringSystem


class MeanRed(SteeringSystem):
    name = "mean-red"

    def detect(self, sample: ImageSample) -> Steering:
        return Steering(float(sample.image[:, :, 0].mean()) / 255.0 - 0.5)


def TinyNet():  # a factory, named as the module it returns
    """A seeded 2-conv CNN on the image (a fresh module per call, identical weights)."""
    import torch
    from torch import nn

    torch.manual_seed(0)
    return nn.Sequential(nn.Conv2d(3, 8, 5, stride=2), nn.ReLU(), nn.Conv2d(8, 16, 5, stride=2), nn.ReLU(),
                         nn.AdaptiveAvgPool2d(1), nn.Flatten(), nn.Linear(16, 8), nn.ReLU(), nn.Linear(8, 1),
                         nn.Flatten(0))
