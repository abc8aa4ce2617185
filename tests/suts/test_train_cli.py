"""``lidarfuzz train`` and the domain randomisation it trains with.

The data sets are written here, not rendered: a flat ground grid 1.73 m under the sensor
(KITTI's mounting height) and cars as clusters of points filling their boxes, so the tests
do not depend on the simulator and run in seconds.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.kitti import KittiWriter
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

torch = pytest.importorskip("torch")

from lidarfuzz.suts.learned.augment import Augmentation, add_walls, augment, box_index_of_points  # noqa: E402
from lidarfuzz.suts.learned.network import PillarConfig, PillarNet, detection_loss  # noqa: E402
from lidarfuzz.suts.learned.sut import DEFAULT_WEIGHTS, PillarsDetector, load_weights  # noqa: E402
from lidarfuzz.suts.learned.training import (  # noqa: E402
    TrainConfig,
    frame_arrays,
    initial_weights,
    open_training_data,
    save_weights,
    train,
)

pytestmark = pytest.mark.torch
runner = CliRunner()
CLASSES = ("Car", "Pedestrian", "Cyclist")
#: A network a tenth the built-in one's cost, over the synthetic frames' cars, so training tests take seconds.
SMALL = PillarConfig(x_range=(0.0, 51.2), y_range=(-12.8, 12.8), pillar=0.4, pillar_channels=8,
                     block_channels=(8, 16, 32), block_layers=(1, 1, 1), neck_channels=8, head_channels=16)


def synthetic_scene(index: int) -> Scene:
    """Ground about every 0.5 m in front of the sensor and two cars filled with points (seeded by ``index``)."""
    rng = np.random.default_rng(index)
    gx, gy = np.meshgrid(np.arange(3.0, 45.0, 0.5), np.arange(-15.0, 15.0, 0.5))
    # jittered like a real scan's ground (a grid of whole numbers reads as a shifted ring column)
    gx, gy = gx.ravel() + rng.uniform(-0.2, 0.2, gx.size), gy.ravel() + rng.uniform(-0.2, 0.2, gy.size)
    ground = np.column_stack([gx, gy, np.full(gx.size, -1.73), rng.uniform(0.1, 0.4, gx.size)])
    centres = np.array([[12.0 + 3 * index, -3.0, -0.95], [25.0 + 2 * index, 4.0, -0.95]])
    sizes = np.array([[3.9, 1.6, 1.56], [4.2, 1.7, 1.5]])
    yaw = np.array([0.1 * index, -0.2])
    cars = []
    for centre, size, heading in zip(centres, sizes, yaw, strict=True):
        local = rng.uniform(-0.45, 0.45, (300, 3)) * size
        c, s = math.cos(heading), math.sin(heading)
        world = np.column_stack([local[:, 0] * c - local[:, 1] * s, local[:, 0] * s + local[:, 1] * c, local[:, 2]])
        cars.append(np.column_stack([world + centre, rng.uniform(0.2, 0.9, 300)]))
    points = np.vstack([ground, *cars]).astype(np.float32)
    boxes = Boxes3D.create(centres, sizes, yaw, ["Car", "Car"], truncation=[0.0, 0.0], occlusion=[0, 0])
    return Scene(PointCloud(points), boxes, KittiCalibration.default(), frame_id=f"{index:06d}")


def write_data(root: Path, frames: int = 4, val: int = 2, unlabelled: tuple[int, ...] = ()) -> Path:
    """A labelled KITTI layout: frames 0..frames-1 in train, the last ``val`` of them also in val."""
    scenes = [synthetic_scene(i) for i in range(frames)]
    with KittiWriter(root) as writer:
        for scene in scenes:
            writer.add(scene)
        writer.close({"train": [s.frame_id for s in scenes], "val": [s.frame_id for s in scenes[-val:]]})
    for index in unlabelled:
        (root / "label_2" / f"{index:06d}.txt").unlink()
    return root


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_data(tmp_path_factory.mktemp("train") / "kitti")


# -- the command ---------------------------------------------------------------------------------
def test_a_tiny_run_writes_weights_that_pillars_loads(data: Path, tmp_path: Path) -> None:
    """From a small network's weights file (--init PATH), so the run takes seconds; the file's
    configuration travels into the new weights."""
    start = tmp_path / "small.pt"
    torch.manual_seed(0)
    save_weights(PillarNet(SMALL), start, {})
    out = tmp_path / "mine.pt"
    args = ["train", str(data), "--out", str(out), "--epochs", "1", "--batch", "4", "--device", "cpu",
            "--init", str(start), "--workers", "1", "--seed", "3"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "wrote" in result.output and "val split" in result.output
    net, meta = load_weights(out)
    assert net.config == SMALL
    assert meta["classes"] == list(CLASSES) and meta["init"] == str(start)
    assert meta["point_range"] == {"x": [0.0, 51.2], "y": [-12.8, 12.8], "z": [-3.0, 1.0]}
    assert meta["data"]["frames"] == 4 and meta["data"]["split"] == "train" and meta["seed"] == 3
    assert meta["data"]["objects"] == {"Car": 8, "Pedestrian": 0, "Cyclist": 0}  # two cars in each of 4 frames
    assert len(meta["history"]["epochs"]) == 1 and meta["val"]["frames"] == 2
    detector = PillarsDetector(weights=str(out))
    boxes = detector.detect(synthetic_scene(0))  # loads and runs; an untrained network may find anything
    assert np.all(np.isfinite(boxes.as_array()))
    again = runner.invoke(app, args)
    assert isinstance(again.exception, LidarfuzzError) and "--overwrite" in str(again.exception)


def test_fine_tuning_starts_from_the_builtin_weights(data: Path) -> None:
    """The first step's loss is the committed network's loss on that batch, computed here independently,
    and the step moves the weights away from the committed ones."""
    from lidarfuzz.io.kitti import open_kitti

    dataset = open_kitti(data)
    frames = [frame_arrays(dataset.load(f), CLASSES) for f in dataset.frame_ids()[:2]]
    config, state, path = initial_weights("builtin")
    assert path == DEFAULT_WEIGHTS
    # batch 2 of 2 frames: the first batch is both (in some order; the loss does not depend on it)
    cfg = TrainConfig(epochs=1, batch_size=2, augment="none", seed=0, lr=1e-3)
    tuned, history = train(frames, config=cfg, network_config=config, initial=state, device="cpu", log=lambda _: None)

    reference = PillarNet(config)
    reference.load_state_dict(state)
    reference.train()  # as in the first step: batch statistics in the batch norms
    points = torch.cat([torch.from_numpy(p[:, :4]) for p, _, _ in frames])
    index = torch.cat([torch.full((len(p),), i) for i, (p, _, _) in enumerate(frames)])
    boxes = torch.cat([torch.from_numpy(b) for _, b, _ in frames])
    classes = torch.cat([torch.from_numpy(c) for _, _, c in frames])
    box_index = torch.cat([torch.full((len(b),), i) for i, (_, b, _) in enumerate(frames)])
    with torch.no_grad():
        heatmap, regression = reference(points, index, 2)
        expected, _ = detection_loss(heatmap, regression, boxes, classes, box_index, config)
    assert history["first_step_loss"] == pytest.approx(float(expected), rel=1e-4)
    moved = [not torch.equal(tuned.state_dict()[k], v) for k, v in state.items() if v.is_floating_point()]
    assert any(moved)


def test_training_on_the_cpu_is_deterministic(data: Path) -> None:
    from lidarfuzz.io.kitti import open_kitti

    dataset = open_kitti(data)
    frames = [frame_arrays(dataset.load(f), CLASSES) for f in dataset.frame_ids()]
    cfg = TrainConfig(epochs=2, batch_size=2, seed=5)  # 4 steps, every augmentation on
    first, _ = train(frames, config=cfg, network_config=SMALL, device="cpu", log=lambda _: None)
    second, _ = train(frames, config=cfg, network_config=SMALL, device="cpu", log=lambda _: None)
    for key, value in first.state_dict().items():
        assert torch.equal(value, second.state_dict()[key]), key


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("not_kitti", "not a KITTI layout"),
        ("no_labels", "label_2: no labels"),
        ("no_split", "ImageSets/train.txt: no 'train' split"),
        ("unlabelled", "000001"),
    ],
)
def test_bad_data_gets_a_one_line_error(tmp_path: Path, case: str, expected: str) -> None:
    root = tmp_path / "kitti"
    if case == "not_kitti":
        root.mkdir()
        (root / "points.txt").write_text("1 2 3\n")
    else:
        write_data(root, frames=3, val=1, unlabelled=(1,) if case == "unlabelled" else ())
        if case == "no_labels":
            for label in (root / "label_2").iterdir():
                label.unlink()
            (root / "label_2").rmdir()
        if case == "no_split":
            (root / "ImageSets" / "train.txt").unlink()
    result = runner.invoke(app, ["train", str(root), "--out", str(tmp_path / "w.pt"), "--device", "cpu"])
    # the CLI's entry point prints a LidarfuzzError as one line and exits with code 2
    assert isinstance(result.exception, DataFormatError), result.output
    message = str(result.exception)
    assert expected in message and "\n" not in message
    assert not (tmp_path / "w.pt").exists()


def test_unlabelled_frames_are_left_out_when_allowed(tmp_path: Path) -> None:
    root = write_data(tmp_path / "kitti", frames=3, val=1, unlabelled=(1,))
    with pytest.raises(DataFormatError, match="000001"):
        open_training_data(root, "train")
    chosen = open_training_data(root, "train", allow_unlabelled=True)
    assert chosen.frame_ids == ["000000", "000002"] and chosen.skipped == ["000001"]


# -- augmentation --------------------------------------------------------------------------------
def _frame(seed: int, n_boxes: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Non-overlapping boxes along x (8 m apart) with points strictly inside them, plus ground and clutter."""
    rng = np.random.default_rng(seed)
    boxes, points = [], []
    for k in range(n_boxes):
        size = rng.uniform([0.6, 0.5, 1.4], [4.5, 2.0, 1.8])
        # 5 cm above the ground, so no ground point lies on a bottom face where rounding decides
        centre = np.array([8.0 + 8.0 * k, rng.uniform(-10, 10), -1.73 + 0.05 + size[2] / 2])
        yaw = rng.uniform(-math.pi, math.pi)
        boxes.append([*centre, *size, yaw])
        # strictly inside (0.95 of the half sizes), so float rounding cannot move them across a face
        local = rng.uniform(-0.475, 0.475, (50, 3)) * size
        c, s = math.cos(yaw), math.sin(yaw)
        xyz = np.column_stack([local[:, 0] * c - local[:, 1] * s, local[:, 0] * s + local[:, 1] * c, local[:, 2]])
        points.append(np.column_stack([xyz + centre, rng.uniform(0, 1, 50), rng.integers(0, 64, 50)]))
    clutter = np.column_stack([rng.uniform(2, 56, (400, 2)) * [1, 0.5], np.full(400, -1.73),
                               rng.uniform(0, 1, 400), rng.integers(0, 64, 400)])
    return (torch.tensor(np.vstack([*points, clutter]), dtype=torch.float32),
            torch.tensor(np.array(boxes).reshape(-1, 7), dtype=torch.float32))


@pytest.mark.parametrize("preset", ["default", "walls"])
@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_boxes=st.integers(0, 6), ring=st.booleans())
def test_augmentation_keeps_every_point_in_its_box(preset: str, seed: int, n_boxes: int, ring: bool) -> None:
    points, boxes = _frame(seed, n_boxes)
    if not ring:  # a KITTI .bin has no ring channel: beams come from elevation bins
        points[:, 4] = -1
    original = points.clone()
    before = box_index_of_points(torch, points[:, :3], boxes)
    generator = torch.Generator().manual_seed(seed)
    out, out_boxes, source = augment(torch, points, boxes, generator, Augmentation.preset(preset))
    assert out_boxes.shape == boxes.shape and out.shape[1] == 5
    after = box_index_of_points(torch, out[:, :3], out_boxes)
    real = source >= 0  # a wall's returns have no source point
    inside_before = before[source[real]]
    moved_out = (inside_before >= 0) & (after[real] != inside_before)
    assert not bool(moved_out.any())
    assert not bool((after[~real] >= 0).any())  # no wall return lies inside a labelled object
    assert bool((out[:, 3] >= 0).all()) and bool((out[:, 3] <= 1).all())
    assert torch.equal(points, original)  # the input is untouched


def test_same_seed_same_augmentation() -> None:
    points, boxes = _frame(7, 3)
    first = augment(torch, points, boxes, torch.Generator().manual_seed(11), Augmentation())
    second = augment(torch, points, boxes, torch.Generator().manual_seed(11), Augmentation())
    for a, b in zip(first, second, strict=True):
        assert torch.equal(a, b)


def test_ground_lift_moves_points_and_boxes_together() -> None:
    """Only a vertical offset of exactly 0.15 m (no slope, no curvature, nothing else): every z grows by
    0.15, x, y and intensities stay."""
    points, boxes = _frame(3, 2)
    only_lift = Augmentation(
        flip=False, rotation=0.0, scale_range=(1.0, 1.0), ground_probability=1.0, ground_dz_range=(0.15, 0.15),
        ground_slope_deg=0.0, ground_curvature=0.0, intensity_probability=0.0, intensity_noise_probability=0.0,
        intensity_absent_probability=0.0, drop_point_probability=0.0, drop_beam_probability=0.0,
        drop_half_beams_probability=0.0, drop_sector_probability=0.0)
    out, out_boxes, source = augment(torch, points, boxes, torch.Generator().manual_seed(0), only_lift)
    assert torch.equal(source, torch.arange(len(points)))
    assert torch.allclose(out[:, 2], points[:, 2] + 0.15, atol=1e-6)
    assert torch.allclose(out_boxes[:, 2], boxes[:, 2] + 0.15, atol=1e-6)
    assert torch.equal(out[:, [0, 1, 3, 4]], points[:, [0, 1, 3, 4]])


def test_dark_returns_read_zero_in_the_share_asked_farthest_first() -> None:
    """With a zero share of exactly 20 % and no other intensity change, round(0.2 · 500) = 100 of 500
    readings become 0 (none were 0 before), and they lie farther out on average than the rest."""
    rng = np.random.default_rng(0)
    n = 500
    xyz = np.column_stack([rng.uniform(2, 60, n), rng.uniform(-5, 5, n), np.full(n, -1.7)])
    points = torch.tensor(np.column_stack([xyz, rng.uniform(0.05, 0.9, n), np.zeros(n)]), dtype=torch.float32)
    zeros_only = Augmentation(
        flip=False, rotation=0.0, scale_range=(1.0, 1.0), ground_probability=0.0, intensity_probability=1.0,
        intensity_beam_gain_sigma=0.0, intensity_beam_offset=0.0, intensity_gain_range=(1.0, 1.0),
        intensity_gamma_range=(1.0, 1.0), intensity_zero_probability=1.0, intensity_zero_share_range=(0.2, 0.2),
        intensity_quantise_probability=0.0, intensity_noise_probability=0.0, intensity_absent_probability=0.0,
        drop_point_probability=0.0, drop_beam_probability=0.0, drop_half_beams_probability=0.0,
        drop_sector_probability=0.0)
    out, _, _ = augment(torch, points, torch.zeros(0, 7), torch.Generator().manual_seed(1), zeros_only)
    zero = out[:, 3] == 0
    assert int(zero.sum()) == 100
    distance = torch.hypot(out[:, 0], out[:, 1])
    assert float(distance[zero].mean()) > float(distance[~zero].mean()) + 5.0
    assert torch.equal(out[~zero, 3], points[~zero, 3])


def test_a_wall_stands_beside_the_object_on_its_far_side_and_hides_what_is_behind_it() -> None:
    # a car at (15, 3) heading along x, 4 × 1.7 × 1.5 m, bottom at z = -1.65; the wall: 20 m long,
    # 2 m high, 1 m from the car's far side, so in the plane y = 3 + 0.85 + 1 = 4.85, z in
    # [-1.65, 0.35], covering x = 15 whatever its shift (at most ±8 m for a 20 m wall and a 4 m car)
    car = torch.tensor([[15.0, 3.0, -0.9, 4.0, 1.7, 1.5, 0.0]])
    inside = torch.tensor([[15.0, 3.0, -0.9, 0.2, -1.0], [16.5, 3.5, -1.5, 0.2, -1.0]])
    behind = torch.tensor([[30.0, 9.7, -3.0, 0.5, -1.0]])  # its ray meets y = 4.85 at (15, 4.85, -1.5)
    beside = torch.tensor([[30.0, -9.7, -3.0, 0.5, -1.0]])  # the near side: no wall there
    points = torch.cat([inside, behind, beside])
    cfg = Augmentation(wall_probability=1.0, wall_per_object=1.0, wall_gap_range=(1.0, 1.0),
                       wall_length_range=(20.0, 20.0), wall_height_range=(2.0, 2.0))
    out, source = add_walls(torch, points, car, torch.Generator().manual_seed(0), cfg)
    assert sorted(source[source >= 0].tolist()) == [0, 1, 3]  # the car keeps its points; the hidden one goes
    wall = out[source < 0]
    assert len(wall) > 100
    assert float(wall[:, 1].min()) >= 4.85 - 0.03 and float(wall[:, 1].max()) <= 4.85 + 0.03
    assert float(wall[:, 2].min()) >= -1.65 - 1e-4 and float(wall[:, 2].max()) <= 0.35 + 1e-4
    assert float(wall[:, 0].max()) - float(wall[:, 0].min()) > 15.0


def test_no_wall_where_it_would_hide_another_object() -> None:
    # a second car right behind the first one's far side: a wall there would stand in front of it
    cars = torch.tensor([[15.0, 3.0, -0.9, 4.0, 1.7, 1.5, 0.0], [15.0, 8.0, -0.9, 4.0, 1.7, 1.5, 0.0]])
    points = torch.tensor([[15.0, 3.0, -0.9, 0.2, -1.0], [15.0, 8.0, -0.9, 0.2, -1.0]])
    cfg = Augmentation(wall_probability=1.0, wall_per_object=1.0, wall_gap_range=(1.0, 1.0),
                       wall_length_range=(20.0, 20.0), wall_height_range=(2.0, 2.0))
    out, source = add_walls(torch, points, cars[:1], torch.Generator().manual_seed(0), cfg)
    assert (source < 0).any()  # alone, the first car gets its wall
    out, source = add_walls(torch, points, cars, torch.Generator().manual_seed(0), cfg)
    walls = out[source < 0]
    # the second car's own wall (beyond it, y = 8 + 0.85 + 1) may stand; none between the two cars
    assert not bool(((walls[:, 1] > 3.85) & (walls[:, 1] < 7.15)).any())
