"""The learned detector as a system under test: ``pillars``.

``PillarsDetector`` wraps :class:`~lidarfuzz.suts.learned.network.PillarNet` with the
weights trained on the simulator (``weights/pillars-sim.pt``, see the card beside it) or a
user's own file (``pillars?weights=PATH``). Points outside the camera's field of view
are dropped before the network sees them (KITTI labels, and so the training, only cover
that view; OpenPCDet does the same for KITTI); without a calibration every point in the
network's range is used.

PyTorch is the ``learned`` extra; it is imported when the detector is loaded, so listing
or naming the SUT works without it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import iou_bev
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import SystemUnderTest

WEIGHTS_DIR = Path(__file__).with_name("weights")
DEFAULT_WEIGHTS = WEIGHTS_DIR / "pillars-sim.pt"


class MissingTorchError(LidarfuzzError, ImportError):
    """PyTorch is not installed."""


def import_torch() -> Any:
    """``torch``, or an error that says which extra installs it."""
    try:
        import torch
    except ImportError:
        raise MissingTorchError(
            "the learned detector and neuron coverage need PyTorch: pip install 'lidarfuzz[learned]'"
        ) from None
    return torch


class PillarsOptions(BaseModel):
    """Options of the ``pillars`` SUT (all part of its fingerprint)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    weights: str | None = Field(None, description="weights file (default: the built-in simulator-trained ones)")
    score_threshold: float = Field(0.1, ge=0.0, le=1.0, description="lowest score kept")
    nms_iou: float = Field(0.1, ge=0.0, le=1.0,
                           description="rotated BEV IoU above which a lower-scored box of the same class is dropped")
    top_k: int = Field(100, ge=1, description="heat-map peaks decoded per frame")
    fov_only: bool = Field(True, description="drop points outside the camera's field of view (when calibrated)")
    threads: int = Field(2, ge=1, description="CPU threads PyTorch may use")


def intensity_divisor(scene: Scene) -> float:
    """What a scene's intensities are divided by for the network, which reads them in [0, 1].

    A data set read with a 0–255 intensity scale (nuScenes, Argoverse 2) records it in
    ``metadata["intensity_scale"]``; training and detection both divide by it, so a
    network trained on one scale sees the same values on the other.
    """
    scale = scene.metadata.get("intensity_scale")
    try:
        value = float(scale) if scale is not None else 1.0
    except (TypeError, ValueError):
        return 1.0
    return value if value > 1.0 else 1.0


def rotated_nms(boxes: NDArray[np.float64], scores: NDArray[np.float64], iou_threshold: float) -> NDArray[np.intp]:
    """Greedy non-maximum suppression with rotated bird's-eye-view IoU; indices kept, best first."""
    if len(boxes) == 0:
        return np.zeros(0, dtype=np.intp)
    order = np.argsort(-scores, kind="stable")
    iou = iou_bev(boxes[order], boxes[order])
    suppressed = np.zeros(len(order), dtype=bool)
    keep = []
    for i in range(len(order)):
        if suppressed[i]:
            continue
        keep.append(order[i])
        suppressed |= iou[i] > iou_threshold
    return np.asarray(keep, dtype=np.intp)


def load_weights(path: Path) -> tuple[Any, dict[str, Any]]:
    """(network in eval mode, metadata) from a weights file written by the training script."""
    torch = import_torch()
    from lidarfuzz.suts.learned.network import PillarConfig, PillarNet

    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        config = PillarConfig.from_json(json.loads(payload["config"]))
        meta = json.loads(payload.get("meta", "{}"))
        net = PillarNet(config)
        net.load_state_dict(payload["state_dict"])
    except FileNotFoundError:
        raise LidarfuzzError(f"{path}: weights file not found") from None
    except Exception as exc:  # a corrupt or foreign file: say which and why
        raise LidarfuzzError(f"{path}: not a PillarNet weights file ({type(exc).__name__}: {exc})") from None
    return net.eval(), meta


class PillarsDetector(SystemUnderTest[Scene, Boxes3D]):
    """PointPillars-style learned 3D detector (pure PyTorch, CPU), trained on the simulator."""

    name = "pillars"
    version = "1"

    def __init__(self, **options: Any) -> None:
        self.options = PillarsOptions(**options)
        self.net: Any = None
        self.meta: dict[str, Any] = {}

    @property
    def weights_path(self) -> Path:
        return Path(self.options.weights) if self.options.weights else DEFAULT_WEIGHTS

    def config(self) -> dict[str, Any]:
        data = self.options.model_dump(mode="json")
        data.pop("threads")  # speed only
        data["weights"] = self.weights_path.name
        return data

    def weight_files(self) -> list[Path]:
        return [self.weights_path] if self.weights_path.exists() else []

    def code(self) -> dict[str, str]:
        """The Python code (all of ``lidarfuzz/suts/``, the network included) and torch's version."""
        from lidarfuzz.suts.code import distribution_version

        return {**super().code(), "dist:torch": distribution_version("torch") or "not installed"}

    def load(self) -> None:
        if self.net is not None:
            return
        torch = import_torch()
        torch.set_num_threads(self.options.threads)
        self.net, self.meta = load_weights(self.weights_path)

    def close(self) -> None:
        self.net = None

    def profile_dirs(self) -> list[Path]:
        """Where the training profiles of the built-in weights are shipped (for KMNC, NBC, SNAC)."""
        return [WEIGHTS_DIR]

    @property
    def module(self) -> Any:
        """The ``torch.nn.Module`` (loaded on first use), for neuron coverage."""
        self.load()
        return self.net

    def network_input(self, scene: Scene) -> NDArray[np.float32]:
        """The N×4 points the network sees."""
        points = np.ascontiguousarray(scene.points.data[:, :4], dtype=np.float32)
        if self.options.fov_only and scene.calib is not None and len(points):
            points = points[scene.calib.in_view(points[:, :3])]
        divisor = intensity_divisor(scene)
        if divisor != 1.0:
            points = points.copy()
            points[:, 3] /= np.float32(divisor)
        return points

    def batch_tensors(self, scenes: list[Scene]) -> tuple[Any, Any, int]:
        """(points, batch index, batch size) tensors for a forward pass over several frames."""
        torch = import_torch()
        arrays = [self.network_input(s) for s in scenes]
        points = torch.from_numpy(np.concatenate(arrays) if arrays else np.zeros((0, 4), np.float32))
        index = torch.from_numpy(np.repeat(np.arange(len(arrays)), [len(a) for a in arrays]))
        return points, index, len(arrays)

    def detect(self, sample: Scene) -> Boxes3D:
        return self.detect_batch([sample])[0]

    def detect_batch(self, samples: Any) -> list[Boxes3D]:
        torch = import_torch()
        from lidarfuzz.suts.learned.network import apply_size_prior, decode

        self.load()
        opts, cfg = self.options, self.net.config
        device = next(self.net.parameters()).device  # CPU, unless a caller moved the network
        points, index, size = self.batch_tensors(list(samples))
        with torch.inference_mode():
            heatmap, regression = self.net(points.to(device), index.to(device), size)
            decoded = decode(heatmap, regression, cfg, top_k=opts.top_k, score_threshold=opts.score_threshold)
        out = []
        for boxes_t, scores_t, classes_t in decoded:
            boxes = apply_size_prior(boxes_t, classes_t, cfg).double().cpu().numpy()
            scores = scores_t.double().cpu().numpy()
            classes = classes_t.cpu().numpy()
            keep: list[int] = []
            for c in np.unique(classes):
                idx = np.flatnonzero(classes == c)
                keep.extend(idx[rotated_nms(boxes[idx], scores[idx], opts.nms_iou)])
            keep_arr = np.asarray(sorted(keep, key=lambda i: -scores[i]), dtype=np.intp)
            labels = np.asarray(cfg.classes)[classes[keep_arr]] if len(keep_arr) else []
            out.append(
                Boxes3D.create(
                    boxes[keep_arr, :3], boxes[keep_arr, 3:6], boxes[keep_arr, 6], labels, scores=scores[keep_arr]
                )
            )
        return out
