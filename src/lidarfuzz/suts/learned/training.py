"""Training PillarNet on a KITTI-layout data set (the simulator's, or a user's own).

Reproducible: one seed drives the initial weights, the order of frames and every
augmentation, with PyTorch's deterministic algorithms on the CPU. On a GPU ``scatter``
and ``index_add`` accumulate in an order that varies, so GPU runs agree with each other
to rounding, not bit for bit. The augmentation is the domain randomisation of
:mod:`lidarfuzz.suts.learned.augment` (ground warps, real intensity statistics,
drop-outs, plus flip, rotation and scaling), which is what lets weights trained on the
simulator work on real scans; ``augment="none"`` turns all of it off.

Frames are loaded once, in parallel, reduced to what the network sees (points in the
camera's view, the boxes of the trained classes) and kept in memory (on the device when
training on a GPU), with the ring channel beside them (−1 where the data has none) for
the per-beam augmentations.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.io.kitti import open_kitti
from lidarfuzz.suts.learned.augment import Augmentation, augment
from lidarfuzz.suts.learned.sut import import_torch, intensity_divisor

FrameArrays = tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.int64]]


@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters of one training run (written to the weights' metadata)."""

    epochs: int = 40
    batch_size: int = 16
    lr: float = 3e-3
    weight_decay: float = 0.01
    seed: int = 0
    grad_clip: float = 10.0
    augment: str = "default"

    def augmentation(self) -> Augmentation | None:
        """The per-frame augmentation this run uses (``None``: frames as they are)."""
        return Augmentation.preset(self.augment)

    def to_json(self) -> dict[str, Any]:
        augmentation = self.augmentation()
        return {**asdict(self), "augmentation": augmentation.to_json() if augmentation else None}


_DATASET: Any = None
_CLASSES: tuple[str, ...] = ()


def _init_worker(root: str, classes: tuple[str, ...]) -> None:
    global _DATASET, _CLASSES
    _DATASET = open_kitti(root)
    _CLASSES = classes


def frame_arrays(scene: Any, classes: Sequence[str]) -> FrameArrays:
    """(points in the camera's view N×5 ``x y z intensity ring``, boxes M×7, class indices M) of one scene.

    The ring is −1 where the data has no ring channel; intensities are brought to [0, 1]
    (:func:`~lidarfuzz.suts.learned.sut.intensity_divisor`); boxes of other classes and
    DontCare regions are left out.
    """
    classes = tuple(classes)
    cloud = scene.points
    ring = cloud.channel("ring") if cloud.has("ring") else np.full(len(cloud), -1.0, np.float32)
    points = np.ascontiguousarray(np.column_stack([cloud.data[:, :4], ring]), dtype=np.float32)
    points[:, 3] /= np.float32(intensity_divisor(scene))
    if scene.calib is not None and len(points):
        points = points[scene.calib.in_view(points[:, :3])]
    boxes = scene.boxes
    keep = np.isin(boxes.labels, classes) & boxes.has_geometry
    geometry = boxes.as_array()[keep].astype(np.float32)
    labels = np.asarray([classes.index(c) for c in boxes.labels[keep]], dtype=np.int64)
    return points, geometry, labels


def _frame_arrays(frame_id: str) -> FrameArrays:
    return frame_arrays(_DATASET.load(frame_id), _CLASSES)




def load_frames(
    root: Path,
    frame_ids: Sequence[str],
    classes: Sequence[str],
    workers: int = 2,
    on_frame: Callable[[], None] | None = None,
) -> list[FrameArrays]:
    """(points in view N×5, boxes M×7, class indices M) of each frame (:func:`frame_arrays`), loaded in parallel.

    ``on_frame()`` is called as each frame arrives (for a progress bar).
    """
    classes = tuple(classes)
    out: list[FrameArrays] = []
    if workers <= 1:
        _init_worker(str(root), classes)
        for frame_id in frame_ids:
            out.append(_frame_arrays(frame_id))
            if on_frame is not None:
                on_frame()
        return out
    with ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(str(root), classes)) as pool:
        for arrays in pool.map(_frame_arrays, frame_ids, chunksize=8):
            out.append(arrays)
            if on_frame is not None:
                on_frame()
    return out


def split_ids(root: Path, split: str) -> list[str]:
    path = root / "ImageSets" / f"{split}.txt"
    if not path.exists():
        raise FileNotFoundError(f"{path}: no {split!r} split in this data set (ImageSets/{split}.txt)")
    return path.read_text().split()


def _with_ring(points: NDArray[np.float32]) -> NDArray[np.float32]:
    """N×4 frames (from older callers) get an unknown ring (−1) as fifth column."""
    if points.shape[1] >= 5:
        return points[:, :5]
    return np.column_stack([points, np.full(len(points), -1.0, np.float32)]).astype(np.float32)


def train(
    frames: list[FrameArrays],
    *,
    config: TrainConfig | None = None,
    network_config: Any = None,
    device: str = "auto",
    log: Callable[[str], None] = print,
    budget_seconds: float | None = None,
    on_epoch: Callable[[Any, dict[str, Any]], None] | None = None,
    initial: Any = None,
    on_step: Callable[[int, int, float], None] | None = None,
) -> tuple[Any, dict[str, Any]]:
    """Train a PillarNet on in-memory frames; returns (network in eval mode, history).

    The network starts from ``initial`` (a state dict: fine-tuning) or from seeded random
    weights. With ``budget_seconds`` the first two epochs are timed and the number of epochs
    (at most ``config.epochs``) set to what fits; the learning-rate schedule follows, so a
    run repeated with the recorded ``epochs_run`` matches it except for the learning rates
    of its first two epochs. ``on_epoch(net, row)`` is called after every epoch (to keep a
    checkpoint), ``on_step(step, total, loss)`` after every step (a progress bar; ``total``
    may change after the first two epochs under a budget). The
    history's ``first_step_loss`` is the loss of the very first batch, before any update:
    what the initial weights score on it.
    """
    torch = import_torch()
    from lidarfuzz.suts.learned.network import PillarConfig, PillarNet, detection_loss

    cfg = config or TrainConfig()
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    torch.manual_seed(cfg.seed)
    if device == "cpu":
        torch.use_deterministic_algorithms(True)
    else:
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
        torch.backends.cudnn.benchmark = True
    net = PillarNet(network_config or PillarConfig())
    if initial is not None:  # fine-tuning: start from these weights (a state dict)
        net.load_state_dict(initial)
    net = net.to(device)
    data = [
        (torch.from_numpy(_with_ring(p)).to(device), torch.from_numpy(b).to(device), torch.from_numpy(c).to(device))
        for p, b, c in frames
    ]
    augmentation = cfg.augmentation()
    x_max = float(net.config.x_range[1])
    steps_per_epoch = max(1, len(data) // cfg.batch_size)
    plan = {"epochs": cfg.epochs}
    optimiser = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)

    def lr_factor(step: int) -> float:
        # linear warm-up over the first 5 % of steps, then cosine decay to 1 % (revised with the plan)
        total = max(1, steps_per_epoch * plan["epochs"])
        warm = max(1, total // 20)
        if step < warm:
            return 0.1 + 0.9 * step / warm
        progress = min(1.0, (step - warm) / max(1, total - warm))
        return 0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * progress))

    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lr_factor)
    generator = torch.Generator().manual_seed(cfg.seed)
    history: dict[str, Any] = {"epochs": [], "device": device, "frames": len(data)}
    start = time.perf_counter()
    net.train()
    epoch = 0
    while epoch < plan["epochs"]:
        order = torch.randperm(len(data), generator=generator).tolist()
        sums = {"loss": 0.0, "heatmap": 0.0, "regression": 0.0}
        for step in range(steps_per_epoch):
            batch = [data[i] for i in order[step * cfg.batch_size:(step + 1) * cfg.batch_size]]
            pts, bxs, cls, pidx, bidx = [], [], [], [], []
            for b, (p, bx, c) in enumerate(batch):
                if augmentation is not None:
                    p, bx, _ = augment(torch, p, bx, generator, augmentation, x_max=x_max)
                pts.append(p[:, :4])
                bxs.append(bx)
                cls.append(c)
                pidx.append(torch.full((len(p),), b, dtype=torch.long, device=device))
                bidx.append(torch.full((len(bx),), b, dtype=torch.long, device=device))
            heatmap, regression = net(torch.cat(pts), torch.cat(pidx), len(batch))
            loss, parts = detection_loss(heatmap, regression, torch.cat(bxs), torch.cat(cls), torch.cat(bidx),
                                         net.config)
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.grad_clip)
            optimiser.step()
            schedule.step()
            sums["loss"] += float(loss.detach())
            if "first_step_loss" not in history:
                history["first_step_loss"] = float(loss.detach())
            if on_step is not None:
                on_step(epoch * steps_per_epoch + step + 1, plan["epochs"] * steps_per_epoch, float(loss.detach()))
            sums["heatmap"] += parts["heatmap"]
            sums["regression"] += parts["regression"]
        row = {k: v / steps_per_epoch for k, v in sums.items()}
        row["epoch"] = epoch + 1
        row["seconds"] = round(time.perf_counter() - start, 1)
        history["epochs"].append(row)
        if epoch < 2 and budget_seconds is not None:
            # planned on the first epoch, revised on the second: the first also pays for warming up
            # (cuDNN's autotuning, allocator growth), on a GPU often three times a later epoch
            took = row["seconds"] - (history["epochs"][-2]["seconds"] if epoch else 0.0)
            fits = epoch + 1 + int(max(0.0, budget_seconds - row["seconds"]) // max(took, 1e-6))
            fits = max(epoch + 1, min(cfg.epochs, fits))
            if fits != plan["epochs"]:
                log(f"epoch {epoch + 1} took {took:.0f} s: {fits} epochs fit in {budget_seconds:.0f} s")
                plan["epochs"] = fits
        log(f"epoch {epoch + 1}/{plan['epochs']}: loss {row['loss']:.3f} (heat map {row['heatmap']:.3f}, "
            f"regression {row['regression']:.3f}), {row['seconds']:.0f} s")
        if on_epoch is not None:
            on_epoch(net, row)
        epoch += 1
    history["epochs_run"] = plan["epochs"]
    history["seconds"] = round(time.perf_counter() - start, 1)
    return net.cpu().eval(), history


def save_weights(net: Any, path: Path, meta: dict[str, Any]) -> None:
    """Weights, network configuration and metadata in one file readable with ``weights_only=True``."""
    torch = import_torch()
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().clone() for k, v in net.state_dict().items()}
    payload = {"config": json.dumps(net.config.to_json()), "meta": json.dumps(meta), "state_dict": state}
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)


# --------------------------------------------------------------------------- a user's own data
INIT_CHOICES = ("builtin", "scratch")


@dataclass(frozen=True)
class TrainingData:
    """The frames of a user's KITTI-layout data set that training will use.

    Attributes:
        root: The folder holding ``velodyne/``.
        split: The ``ImageSets`` list used, or ``all``.
        frame_ids: Labelled frames to train on, in data set order.
        skipped: Frames left out because they have no label file (only with ``allow_unlabelled``).
    """

    root: Path
    split: str
    frame_ids: list[str]
    skipped: list[str]


def labelled_ids(dataset: Any) -> tuple[list[str], list[str]]:
    """(labelled, unlabelled) frame ids; unlabelled ones are those without a ``label_2/<id>.txt``."""
    ids = list(dataset.frame_ids())
    listed = getattr(dataset, "unlabelled_ids", None)
    if listed is not None:
        unlabelled = set(listed())
    else:  # readers that refuse unlabelled frames at opening never get here with any
        unlabelled = {f for f in ids if not (dataset.root / "label_2" / f"{f}.txt").is_file()}
    return [f for f in ids if f not in unlabelled], [f for f in ids if f in unlabelled]


def open_training_data(path: str | Path, split: str, *, allow_unlabelled: bool = False) -> TrainingData:
    """Check a KITTI-layout folder for training and list its usable frames.

    Args:
        path: The data set (the folder holding ``velodyne/``, or one with ``training/``).
        split: ``ImageSets/<split>.txt`` to train on, or ``all`` for every frame.
        allow_unlabelled: Leave frames without a label file out instead of refusing the data set.

    Raises:
        DataFormatError: One line naming the file: not a KITTI layout, no ``label_2/``, no such
            split, frames without labels (named; unless ``allow_unlabelled``), no labelled frame.
    """
    from lidarfuzz.errors import DataFormatError
    from lidarfuzz.io.kitti import find_kitti_root, unlabelled_note

    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, "no such data set folder")
    root = find_kitti_root(path)
    if root is None:
        raise DataFormatError(path, "not a KITTI layout: no velodyne/ folder here or under training/")
    if not (root / "label_2").is_dir():
        raise DataFormatError(root / "label_2", "no labels: training needs label_2/ with a label file per frame")
    subset = None if split == "all" else split
    if subset is not None and not any((p / "ImageSets" / f"{subset}.txt").is_file() for p in (root, path)):
        raise DataFormatError(root / "ImageSets" / f"{subset}.txt", f"no {subset!r} split in this data set",
                              hint="name another with --split, or --split all for every frame")
    dataset = open_kitti(path, subset=subset)
    labelled, unlabelled = labelled_ids(dataset)
    if unlabelled and not allow_unlabelled:
        raise DataFormatError(root / "label_2", unlabelled_note(unlabelled, len(labelled) + len(unlabelled)),
                              hint="add their labels, or pass --allow-unlabelled to train on the others")
    if not labelled:
        raise DataFormatError(root / "label_2", f"no labelled frame in the {split!r} split")
    return TrainingData(dataset.root, split, labelled, unlabelled)


def initial_weights(init: str) -> tuple[Any, dict[str, Any] | None, Path | None]:
    """(network configuration, state dict or None, weights file or None) to start from.

    ``builtin``: the committed weights (fine-tuning); ``scratch``: seeded random weights with
    the default configuration; anything else: a weights file written by this module.
    """
    from lidarfuzz.suts.learned.network import PillarConfig
    from lidarfuzz.suts.learned.sut import DEFAULT_WEIGHTS, load_weights

    if init == "scratch":
        return PillarConfig(), None, None
    path = DEFAULT_WEIGHTS if init == "builtin" else Path(init)
    net, _ = load_weights(path)
    return net.config, net.state_dict(), path
