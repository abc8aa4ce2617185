"""The built-in steering networks as systems under test: ``epoch``, ``dave2``, ``chauffeur``.

Each loads its committed weights (``weights/<name>.pt``, trained on the simulator's camera
frames by ``scripts/train_steering.py``; ``weights/MODEL_CARD.md`` says on what and how well)
or a user's own file (``dave2?weights=PATH``, a file the training script wrote). Answers are
the simulator's label: the front-wheel angle in radians, left positive.

PyTorch is the ``learned`` extra; it is imported when a network is loaded, so listing or
naming the systems works without it, and loading says which extra to install.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.scene.image import ImageSample
from lidarfuzz.suts.steering.base import Steering, SteeringSystem
from lidarfuzz.suts.steering.preprocess import Preprocess
from lidarfuzz.suts.steering.pytorch import import_torch

WEIGHTS_DIR = Path(__file__).with_name("weights")

#: What each network eats. The sky above the horizon carries no steering cue, so the top 40 % of
#: the frame is cut (the horizon of the simulator's camera is at mid-height); DAVE-2 reads YUV as
#: published, the others RGB; all scaled to [−1, 1].
PREPROCESS: dict[str, Preprocess] = {
    "epoch": Preprocess(height=48, width=96, crop_top=0.4, color="rgb", scale=1 / 127.5, offset=-1.0),
    "dave2": Preprocess(height=66, width=200, crop_top=0.4, color="yuv", scale=1 / 127.5, offset=-1.0),
    "chauffeur": Preprocess(height=48, width=96, crop_top=0.4, color="rgb", scale=1 / 127.5, offset=-1.0),
}

#: Front-wheel angles beyond ±0.7 rad (40°) are no answer for a car: the simulator's largest is
#: arctan(2.71 m / 5 m) ≈ 0.50 rad for a junction's tightest corner.
STEERING_RANGE = (-0.7, 0.7)


class BuiltinOptions(BaseModel):
    """Options of a built-in steering network (weights are part of the fingerprint)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    weights: str | None = Field(default=None,
                                description="weights file (default: the committed, simulator-trained ones)")
    threads: int = Field(default=1, ge=1, description="CPU threads PyTorch may use")
    batch_size: int = Field(default=64, ge=1, description="frames per forward pass")


def load_network(network: str, path: Path) -> tuple[Any, dict[str, Any]]:
    """(network in eval mode, metadata) from a weights file of the training script.

    Raises:
        LidarfuzzError: the file is missing or is not ``network``'s weights (naming the file).
    """
    torch = import_torch()
    from lidarfuzz.suts.steering.networks import NETWORKS

    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        meta = json.loads(payload.get("meta", "{}"))
        if meta.get("network", network) != network:
            raise ValueError(f"it holds {meta['network']!r} weights, not {network!r}")
        net = NETWORKS[network]()
        net.load_state_dict(payload["state_dict"])
    except FileNotFoundError:
        raise LidarfuzzError(f"{path}: weights file not found") from None
    except Exception as exc:  # a corrupt or foreign file: say which and why
        raise LidarfuzzError(f"{path}: not {network} steering weights ({type(exc).__name__}: {exc})") from None
    return net.eval(), meta


def save_network(net: Any, network: str, path: Path, meta: dict[str, Any]) -> Path:
    """Write a network's float32 state dict with its metadata (what :func:`load_network` reads)."""
    torch = import_torch()
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().float().contiguous() for k, v in net.state_dict().items()}
    with atomic_path(path, overwrite=True) as tmp:  # a full disk leaves no truncated weights at ``path``
        torch.save({"state_dict": state, "meta": json.dumps({"network": network, **meta})}, tmp)
    return path


class BuiltinSteering(SteeringSystem):
    """A built-in steering network (subclasses name it)."""

    network: ClassVar[str] = ""
    version = "1"
    steering_range = STEERING_RANGE

    def __init__(self, **options: Any) -> None:
        self.options = BuiltinOptions(**options)
        self._system: Any = None
        self.meta: dict[str, Any] = {}

    @property
    def preprocess(self) -> Preprocess:
        """What the network eats."""
        return PREPROCESS[self.network]

    @property
    def weights_path(self) -> Path:
        return Path(self.options.weights) if self.options.weights else WEIGHTS_DIR / f"{self.network}.pt"

    def config(self) -> dict[str, Any]:
        return {"weights": self.weights_path.name, "preprocess": self.preprocess.model_dump(mode="json"),
                "steering_range": list(self.steering_range)}

    def weight_files(self) -> Sequence[Path]:
        return [self.weights_path] if self.weights_path.exists() else []

    def code(self) -> dict[str, str]:
        """The Python code (all of ``lidarfuzz/suts/``, the networks included) and torch's version."""
        from lidarfuzz.suts.code import distribution_version

        return {**super().code(), "dist:torch": distribution_version("torch") or "not installed"}

    def profile_dirs(self) -> list[Path]:
        """Where the training profiles of the committed weights ship (for KMNC, NBC, SNAC)."""
        return [WEIGHTS_DIR]

    def load(self) -> None:
        if self._system is not None:
            return
        from lidarfuzz.suts.steering.pytorch import TorchSteering

        net, self.meta = load_network(self.network, self.weights_path)
        self._system = TorchSteering(net, preprocess=self.preprocess, steering_range=self.steering_range,
                                     threads=self.options.threads, batch_size=self.options.batch_size,
                                     name=self.name, version=self.version)
        self._system.load()

    def close(self) -> None:
        self._system = None

    @property
    def module(self) -> Any:
        """The ``torch.nn.Module`` (loaded on first use), for neuron coverage."""
        self.load()
        return self._system.module

    def inputs(self, samples: Sequence[ImageSample]) -> Any:
        """The N×3×H×W tensor the network sees for these frames."""
        self.load()
        return self._system.inputs(samples)

    def forward(self, batch: Any) -> NDArray[np.float64]:
        """Angles of a preprocessed batch (:meth:`inputs`)."""
        self.load()
        return np.asarray(self._system.forward(batch))

    def detect_batch(self, samples: Sequence[ImageSample]) -> list[Steering]:
        self.load()
        return list(self._system.detect_batch(samples))


class Epoch(BuiltinSteering):
    """Epoch-like CNN (three convolution blocks, dropout, dense) on 48×96 RGB; 240,369 parameters."""

    name = "epoch"
    network = "epoch"


class Dave2(BuiltinSteering):
    """DAVE-2 (PilotNet) on 66×200 YUV: five convolutions, three dense layers; 252,455 parameters."""

    name = "dave2"
    network = "dave2"


class Chauffeur(BuiltinSteering):
    """Chauffeur-like CNN, six convolutions on 48×96 RGB; 217,441 parameters."""

    name = "chauffeur"
    network = "chauffeur"


BUILTINS: dict[str, type[BuiltinSteering]] = {"epoch": Epoch, "dave2": Dave2, "chauffeur": Chauffeur}
