"""Training the built-in steering networks: data from the simulator's camera, MSE, Adam, seeded, CPU.

The data are data sets written by ``lidarfuzz gen --camera`` (``image_2/*.png`` and
``steering.csv``: ``frame_id,steering,speed``, the front-wheel angle in radians, left
positive). :func:`read_frames` reads one; each network's input is cached as uint8 after its
crop, resize and colour conversion (:meth:`~lidarfuzz.suts.steering.preprocess.Preprocess.pixels`;
a few thousand frames at network resolution are tens of MB), scaled to float when a batch is
drawn. :func:`train_network` fits a network (mean squared error, Adam, one seed for the initial
weights, the order and the flips); :func:`mse` scores it. The recipe of the committed weights
is ``scripts/train_steering.py``.

PyTorch (extra ``learned``) is imported by the functions that need it.
"""

from __future__ import annotations

import csv
import hashlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.atomic import atomic_path
from lidarfuzz.suts.steering.preprocess import Preprocess
from lidarfuzz.suts.steering.pytorch import import_torch


@dataclass(frozen=True)
class Frames:
    """Frames of one or more data sets: ``images`` (N×H×W×3 uint8 at network resolution, after a
    :class:`Preprocess`'s pixels step), ``labels`` (N float64), and per frame its data set's index
    (``groups``, so that a split keeps whole logs apart) and id."""

    images: NDArray[np.uint8]
    labels: NDArray[np.float64]
    groups: NDArray[np.int64]
    frame_ids: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.labels)

    def subset(self, mask: NDArray[np.bool_]) -> Frames:
        ids = tuple(f for f, keep in zip(self.frame_ids, mask, strict=True) if keep)
        return Frames(self.images[mask], self.labels[mask], self.groups[mask], ids)


def read_labels(root: Path) -> dict[str, float]:
    """``steering.csv`` of a data set: {frame id: steering}.

    Raises:
        DataFormatError: no such file, no ``frame_id``/``steering`` columns, or a value that is not a number.
    """
    path = root / "steering.csv"
    if not path.is_file():
        raise DataFormatError(path, "no steering.csv (write the data set with `lidarfuzz gen --camera`)")
    labels: dict[str, float] = {}
    with path.open(newline="", encoding="utf-8") as handle:
        rows = csv.DictReader(handle)
        if rows.fieldnames is None or not {"frame_id", "steering"} <= set(rows.fieldnames):
            raise DataFormatError(path, f"expected columns frame_id,steering; got {rows.fieldnames}")
        for line, row in enumerate(rows, start=2):
            try:
                labels[row["frame_id"].strip()] = float(row["steering"])
            except (TypeError, ValueError):
                raise DataFormatError(path, f"steering {row['steering']!r} is not a number", line=line) from None
    return labels


def read_frames(roots: Sequence[Path], preprocess: Preprocess, cache: Path | None = None,
                on_frame: Callable[[], None] | None = None) -> Frames:
    """Every labelled frame of the data sets ``roots`` at ``preprocess``'s resolution.

    With ``cache`` the uint8 arrays are kept there (an ``.npz`` named by a hash of the data sets'
    paths, frame counts and the preprocessing) and read back on the next call.
    """
    key = hashlib.sha256(json.dumps([[str(Path(r).resolve()), len(read_labels(Path(r)))] for r in roots]
                                    + [preprocess.model_dump(mode="json")]).encode()).hexdigest()[:16]
    cached = cache / f"steering-{key}.npz" if cache is not None else None
    if cached is not None and cached.is_file():
        with np.load(cached) as data:
            return Frames(data["images"], data["labels"], data["groups"], tuple(str(f) for f in data["frame_ids"]))
    images: list[NDArray[np.uint8]] = []
    labels: list[float] = []
    groups: list[int] = []
    ids: list[str] = []
    for group, root in enumerate(roots):
        root = Path(root)
        for frame_id, label in sorted(read_labels(root).items()):
            path = root / "image_2" / f"{frame_id}.png"
            bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if bgr is None:
                raise DataFormatError(path, "missing or unreadable image")
            rgb = np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)
            images.append(preprocess.pixels(rgb))
            labels.append(label)
            groups.append(group)
            ids.append(f"{root.name}/{frame_id}")
            if on_frame is not None:
                on_frame()
    frames = Frames(np.stack(images) if images else np.zeros((0, preprocess.height, preprocess.width, 3), np.uint8),
                    np.asarray(labels, np.float64), np.asarray(groups, np.int64), tuple(ids))
    if cached is not None:
        with atomic_path(cached, overwrite=True) as tmp, open(tmp, "wb") as handle:  # never a truncated cache
            np.savez(handle, images=frames.images, labels=frames.labels, groups=frames.groups,
                     frame_ids=np.asarray(frames.frame_ids))
    return frames


@dataclass(frozen=True)
class TrainConfig:
    """How a network is fitted.

    Attributes:
        epochs: Passes over the training frames.
        batch_size: Frames per Adam step.
        lr: Adam's learning rate (cosine decay to 5 % of it over the run).
        weight_decay: Adam's L2 penalty.
        flip: Probability of mirroring a frame left–right with its label negated (the usual steering
            augmentation: a left bend mirrored is a right bend).
        seed: Seeds the initial weights, the order of the frames and the flips.
        threads: ``torch.set_num_threads``.
    """

    epochs: int = 12
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-5
    flip: float = 0.5
    seed: int = 0
    threads: int = 2

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def as_tensor(preprocess: Preprocess, pixels: NDArray[np.uint8]) -> Any:
    """N×H×W×3 uint8 pixels → the N×3×H×W float32 tensor the network eats."""
    torch = import_torch()
    return torch.from_numpy(np.ascontiguousarray(preprocess.scaled(pixels).transpose(0, 3, 1, 2)))


def predict(net: Any, preprocess: Preprocess, pixels: NDArray[np.uint8], batch_size: int = 256) -> NDArray[np.float64]:
    """The network's answers on cached pixels (eval mode, no gradients)."""
    torch = import_torch()
    net.eval()
    out = []
    with torch.inference_mode():
        for start in range(0, len(pixels), batch_size):
            out.append(net(as_tensor(preprocess, pixels[start:start + batch_size])).double().numpy().reshape(-1))
    return np.concatenate(out) if out else np.zeros(0)


def mse(predictions: NDArray[np.float64], labels: NDArray[np.float64]) -> float:
    """Mean squared error."""
    return float(np.mean((np.asarray(predictions) - np.asarray(labels)) ** 2))


def train_network(net: Any, preprocess: Preprocess, train: Frames, config: TrainConfig,
                  val: Frames | None = None, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Fit ``net`` in place on ``train`` (MSE, Adam); returns the history (loss and validation MSE
    per epoch, seconds). Deterministic for a seed and thread count on one machine."""
    torch = import_torch()
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    for module in net.modules():  # re-initialise from the seed: the same weights whatever ran before
        if hasattr(module, "reset_parameters"):
            module.reset_parameters()
    if hasattr(net, "output_scale"):  # targets of order 1 for the head (the spread of the labels, flips included)
        spread = float(np.sqrt(np.mean(train.labels**2))) if len(train) else 1.0
        net.output_scale.fill_(spread if spread > 0 else 1.0)
    rng = np.random.default_rng(config.seed)
    steps_per_epoch = max(1, len(train) // config.batch_size)
    total = steps_per_epoch * config.epochs
    optimiser = torch.optim.Adam(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=total, eta_min=config.lr * 0.05)
    history: dict[str, Any] = {"epochs": [], "steps_per_epoch": steps_per_epoch}
    start = time.perf_counter()
    for epoch in range(1, config.epochs + 1):
        net.train()
        order = rng.permutation(len(train))
        losses = []
        for step in range(steps_per_epoch):
            index = np.sort(order[step * config.batch_size:(step + 1) * config.batch_size])
            pixels = train.images[index]
            labels = train.labels[index].copy()
            flips = rng.random(len(index)) < config.flip
            if flips.any():
                pixels = pixels.copy()
                pixels[flips] = pixels[flips, :, ::-1]
                labels[flips] = -labels[flips]
            optimiser.zero_grad()
            loss = torch.nn.functional.mse_loss(net(as_tensor(preprocess, pixels)),
                                                torch.from_numpy(labels.astype(np.float32)))
            loss.backward()
            optimiser.step()
            schedule.step()
            losses.append(float(loss.detach()))
        row: dict[str, Any] = {"epoch": epoch, "loss": float(np.mean(losses)),
                               "seconds": round(time.perf_counter() - start, 1)}
        if val is not None and len(val):
            row["val_mse"] = mse(predict(net, preprocess, val.images), val.labels)
        history["epochs"].append(row)
        log(f"epoch {epoch}/{config.epochs}: loss {row['loss']:.5f}"
            + (f", val MSE {row['val_mse']:.5f}" if "val_mse" in row else "") + f", {row['seconds']:.0f} s")
    history["seconds"] = round(time.perf_counter() - start, 1)
    net.eval()
    return history
