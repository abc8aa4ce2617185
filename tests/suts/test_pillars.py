"""The learned detector: target encoding and decoding, rotated NMS, weights files, and the
committed network on simulator frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.oracles.matching import match_boxes
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim.dataset import GenerationConfig, render_frames
from lidarfuzz.suts.base import validate_detections
from lidarfuzz.suts.registry import create

torch = pytest.importorskip("torch")

from lidarfuzz.suts.learned.network import (  # noqa: E402
    REGRESSION,
    PillarConfig,
    PillarNet,
    apply_size_prior,
    build_targets,
    decode,
)
from lidarfuzz.suts.learned.sut import PillarsDetector, load_weights, rotated_nms  # noqa: E402

pytestmark = pytest.mark.torch


@pytest.fixture(scope="module")
def frames() -> list[Scene]:
    return list(render_frames(GenerationConfig(frames=4, seed=3)))


@pytest.fixture(scope="module")
def sut() -> PillarsDetector:
    return create("pillars")


# -- targets and decoding ---------------------------------------------------------------------
def test_decoding_the_training_targets_gives_back_the_boxes() -> None:
    """Heat map and regression built from boxes, decoded again, give the same boxes and classes."""
    config = PillarConfig()
    boxes = torch.tensor(
        [
            [12.3, -4.1, -0.9, 4.2, 1.7, 1.5, 0.3],
            [30.7, 10.2, -1.0, 0.7, 0.6, 1.8, -2.5],
            [45.1, -20.9, -0.8, 1.9, 0.6, 1.7, 3.0],
            [8.0, 25.0, -0.7, 3.8, 1.6, 1.5, -0.1],
        ],
        dtype=torch.float64,
    )
    classes = torch.tensor([0, 1, 2, 0])
    batch_index = torch.tensor([0, 0, 1, 1])
    heatmap, cell, regression, valid = build_targets(boxes, classes, batch_index, 2, config)
    assert valid.all()
    height, width = config.out_grid
    assert heatmap.shape == (2, 3, height, width)
    # each centre cell is a peak of exactly 1 on its class's channel; the rest stays below 1
    local = cell - batch_index * height * width
    flat = heatmap.view(2, 3, -1)
    assert torch.all(flat[batch_index, classes, local] == 1.0)
    assert int((heatmap == 1.0).sum()) == len(boxes)

    logits = torch.logit(heatmap.clamp(1e-6, 1 - 1e-6))
    reg_map = torch.zeros(2, len(REGRESSION), height * width, dtype=torch.float64)
    reg_map[batch_index, :, local] = regression
    decoded = decode(logits, reg_map.view(2, len(REGRESSION), height, width), config, top_k=10, score_threshold=0.5)
    for b in range(2):
        out_boxes, scores, out_classes = decoded[b]
        expected = boxes[batch_index == b]
        order = torch.argsort(out_boxes[:, 0])
        got = apply_size_prior(out_boxes[order], out_classes[order], config)
        exp_order = torch.argsort(expected[:, 0])
        assert torch.equal(out_classes[order], classes[batch_index == b][exp_order])
        assert torch.allclose(got[:, :6], expected[exp_order, :6], atol=1e-6)
        yaw_diff = torch.remainder(got[:, 6] - expected[exp_order, 6] + torch.pi, 2 * torch.pi) - torch.pi
        assert torch.all(yaw_diff.abs() < 1e-6)
        assert torch.all(scores > 0.99)


def test_boxes_outside_the_grid_are_not_targets() -> None:
    config = PillarConfig()
    boxes = torch.tensor([[-5.0, 0.0, -1.0, 4.0, 1.6, 1.5, 0.0], [10.0, 50.0, -1.0, 4.0, 1.6, 1.5, 0.0]])
    heatmap, _, _, valid = build_targets(boxes, torch.tensor([0, 0]), torch.tensor([0, 0]), 1, config)
    assert not valid.any()
    assert float(heatmap.max()) == 0.0


# -- rotated NMS --------------------------------------------------------------------------------
def test_rotated_nms_suppresses_by_rotated_bev_iou() -> None:
    boxes = np.array(
        [
            [0.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0],  # best
            [0.5, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0],  # IoU with the best: 7 / 9
            [0.0, 0.0, 0.0, 4.0, 2.0, 1.5, np.pi / 2],  # crossed: IoU 4 / 12
            [20.0, 0.0, 0.0, 4.0, 2.0, 1.5, 0.0],  # far away
        ]
    )
    scores = np.array([0.9, 0.8, 0.7, 0.1])
    assert rotated_nms(boxes, scores, 0.5).tolist() == [0, 2, 3]
    assert rotated_nms(boxes, scores, 0.3).tolist() == [0, 3]
    assert rotated_nms(boxes, scores, 0.8).tolist() == [0, 1, 2, 3]
    assert rotated_nms(boxes[:0], scores[:0], 0.5).tolist() == []


# -- weights files --------------------------------------------------------------------------------
def test_missing_and_foreign_weights_files_are_named(tmp_path: Path) -> None:
    with pytest.raises(LidarfuzzError, match=r"nowhere\.pt: weights file not found"):
        load_weights(tmp_path / "nowhere.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(LidarfuzzError, match=r"junk\.pt: not a PillarNet weights file"):
        load_weights(junk)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {}, "config": "{}"}, foreign)
    with pytest.raises(LidarfuzzError, match=r"foreign\.pt: not a PillarNet weights file"):
        load_weights(foreign)


def test_coverage_layers_are_the_frame_level_relus() -> None:
    net = PillarNet()
    names = net.coverage_layers()
    modules = dict(net.named_modules())
    assert names and all(isinstance(modules[n], torch.nn.ReLU) for n in names)
    assert "pillars.relu" not in names


# -- the committed network ----------------------------------------------------------------------
def test_committed_network_is_deterministic_valid_and_finds_near_cars(sut: PillarsDetector, frames) -> None:
    found = total = 0
    for scene in frames:
        a, b = sut.detect(scene), sut.detect(scene)
        assert a.allclose(b, atol=0) and np.array_equal(a.scores, b.scores)
        assert validate_detections(a, sut.classes) is None
        assert np.all((a.scores >= sut.options.score_threshold) & (a.scores <= 1))
        boxes = scene.boxes
        near = (boxes.centers[:, 0] > 0) & (np.hypot(*boxes.centers[:, :2].T) < 40)
        gt = boxes.select((boxes.labels == "Car") & near & (boxes.occlusion == 0) & (boxes.truncation < 0.3))
        gt = gt.select(scene.calib.in_view(gt.centers))
        found += len(match_boxes(gt, a, metric="3d", min_iou=0.5).pairs)
        total += len(gt)
    assert total >= 3 and found / total >= 0.8, (found, total)


def test_a_batch_gives_what_single_frames_give(sut: PillarsDetector, frames) -> None:
    batch = sut.detect_batch(frames[:2])
    for scene, dets in zip(frames[:2], batch, strict=True):
        single = sut.detect(scene)
        assert len(single) == len(dets)
        assert dets.allclose(single, atol=1e-4)


def test_an_empty_frame_gives_no_detections(sut: PillarsDetector, frames) -> None:
    scene = frames[0]
    empty = scene.with_points(np.zeros((0, len(scene.points.channels)), np.float32))
    dets = sut.detect(empty)
    assert validate_detections(dets, sut.classes) is None
    assert len(dets) == 0
