"""Training the steering networks: reading gen --camera data sets, caching, and a fit that learns."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.suts.steering.preprocess import Preprocess
from lidarfuzz.suts.steering.training import mse, read_frames, read_labels


def write_set(root: Path, labels: dict[str, float], images: dict[str, np.ndarray]) -> Path:
    (root / "image_2").mkdir(parents=True)
    rows = ["frame_id,steering,speed"] + [f"{k},{v},5.0" for k, v in labels.items()]
    (root / "steering.csv").write_text("\n".join(rows) + "\n")
    for frame_id, image in images.items():
        cv2.imwrite(str(root / "image_2" / f"{frame_id}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    return root


def sided(bright_left: bool) -> np.ndarray:
    image = np.full((24, 32, 3), 40, np.uint8)
    if bright_left:
        image[:, :16] = 220
    else:
        image[:, 16:] = 220
    return image


def test_read_labels_and_frames_with_cache(tmp_path: Path) -> None:
    root = write_set(tmp_path / "a", {"000000": 0.1, "000001": -0.25},
                     {"000000": sided(True), "000001": sided(False)})
    assert read_labels(root) == {"000000": 0.1, "000001": -0.25}
    pre = Preprocess(height=6, width=8)
    frames = read_frames([root], pre, cache=tmp_path / "cache")
    assert frames.images.shape == (2, 6, 8, 3) and frames.images.dtype == np.uint8
    assert frames.labels.tolist() == [0.1, -0.25] and frames.frame_ids == ("a/000000", "a/000001")
    # frame 0 is bright on the left: its first column 220, its last 40
    assert frames.images[0, 0, 0, 0] == 220 and frames.images[0, 0, -1, 0] == 40
    assert len(list((tmp_path / "cache").glob("steering-*.npz"))) == 1
    again = read_frames([root], pre, cache=tmp_path / "cache")
    np.testing.assert_array_equal(again.images, frames.images)


def test_bad_label_files_name_the_file_and_line(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match=r"no steering\.csv"):
        read_labels(tmp_path)
    (tmp_path / "steering.csv").write_text("frame_id,angle\n000000,0.1\n")
    with pytest.raises(DataFormatError, match="expected columns frame_id,steering"):
        read_labels(tmp_path)
    (tmp_path / "steering.csv").write_text("frame_id,steering\n000000,left\n")
    with pytest.raises(DataFormatError, match=r"steering\.csv:2: steering 'left' is not a number"):
        read_labels(tmp_path)


def test_mse() -> None:
    # ((0.1 − 0)² + (−0.3 − 0.1)²) / 2 = (0.01 + 0.16) / 2 = 0.085
    assert mse(np.array([0.1, -0.3]), np.array([0.0, 0.1])) == pytest.approx(0.085)


@pytest.mark.torch
@pytest.mark.slow  # 10 epochs of 64 frames: about 10 s on an idle core
def test_a_network_learns_which_side_is_bright(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    from lidarfuzz.suts.steering.networks import EpochNet
    from lidarfuzz.suts.steering.training import TrainConfig, predict, train_network

    rng = np.random.default_rng(0)
    sides = rng.random(96) < 0.5
    labels = {f"{i:06d}": (0.2 if left else -0.2) for i, left in enumerate(sides)}
    images = {}
    for i, left in enumerate(sides):
        image = sided(bool(left)).astype(np.int16) + rng.integers(-20, 21, (24, 32, 3))
        images[f"{i:06d}"] = np.clip(image, 0, 255).astype(np.uint8)
    frames = read_frames([write_set(tmp_path / "s", labels, images)], Preprocess(height=48, width=96))
    train, val = frames.subset(np.arange(96) < 64), frames.subset(np.arange(96) >= 64)
    net = EpochNet()
    # a bright left half is +0.2 and the mirrored frame −0.2: flips keep the rule, so they stay on
    history = train_network(net, Preprocess(height=48, width=96), train,
                            TrainConfig(epochs=10, batch_size=8, lr=3e-3, threads=1), val, log=lambda _: None)
    baseline = mse(np.full(len(val), train.labels.mean()), val.labels)  # about 0.04
    got = mse(predict(net, Preprocess(height=48, width=96), val.images), val.labels)
    assert got < 0.5 * baseline, (got, baseline, history["epochs"][-1])
