"""Generated data sets: deterministic bytes, KITTI layout that the readers and `info` accept, logs, resume."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io import open_dataset
from lidarfuzz.io.inspect import inspect_source
from lidarfuzz.io.kitti import KittiDataset, KittiLog
from lidarfuzz.sim import GenerationConfig, generate_dataset, load_sensor, parse_scene
from lidarfuzz.sim.dataset import SUMMARY_FILE, is_complete
from tests.sim.helpers import street

SMALL = {"sensor": "VLP-16"}  # fewer rays: fast tests, same code path


def digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != SUMMARY_FILE}


@pytest.fixture(scope="module")
def independent(tmp_path_factory):
    root = tmp_path_factory.mktemp("gen") / "independent"
    summary = generate_dataset(root, GenerationConfig(frames=4, seed=3, **SMALL), workers=1)
    return root, summary


def test_same_seed_gives_identical_bytes(independent, tmp_path):
    root, _ = independent
    again = tmp_path / "again"
    generate_dataset(again, GenerationConfig(frames=4, seed=3, **SMALL), workers=1)
    assert digest(again) == digest(root)
    other = tmp_path / "other"
    generate_dataset(other, GenerationConfig(frames=1, seed=4, **SMALL), workers=1)
    assert digest(other)["velodyne/000000.bin"] != digest(root)["velodyne/000000.bin"]


def test_worker_processes_do_not_change_the_bytes(independent, tmp_path):
    root, _ = independent
    parallel = tmp_path / "parallel"
    generate_dataset(parallel, GenerationConfig(frames=4, seed=3, **SMALL), workers=2)
    assert digest(parallel) == digest(root)


def test_generated_data_set_reads_back_and_info_reports_no_problem(independent):
    root, summary = independent
    dataset = open_dataset(root)
    assert isinstance(dataset, KittiDataset) and not isinstance(dataset, KittiLog)  # independent scenes
    assert len(dataset) == 4
    report = inspect_source(root)
    assert report.problems == [] and report.labelled_frames == report.calibrated_frames == report.roi_frames == 4
    assert set(report.channels) == {"x", "y", "z", "intensity", "ring", "time", "label", "instance"}
    assert report.channels["intensity"].minimum >= 0.0 and report.channels["intensity"].maximum <= 1.0
    assert sum(report.classes.values()) == sum(summary.label_counts.values()) > 0
    assert (root / "ImageSets" / "train.txt").read_text().split() == ["000000", "000001"]
    assert (root / "ImageSets" / "val.txt").read_text().split() == ["000002", "000003"]
    assert len(KittiDataset(root, subset="val")) == 2
    info = json.loads((root / SUMMARY_FILE).read_text())
    assert info["complete"] and info["config"]["frames"] == 4 and info["label_counts"] == summary.label_counts
    # Each frame's scene is saved and renders the same frame again.
    scene = parse_scene(json.loads((root / "scenes" / "000001.json").read_text()))
    # The sensor is stored whole: the preset with the pitch and roll drawn for this frame.
    assert load_sensor(scene.sensor).name == "VLP-16"


def test_side_files_store_integer_channels_compactly(independent):
    root, _ = independent
    with np.load(root / "velodyne_extra" / "000000.npz") as extra:
        assert extra["ring"].dtype == np.uint8 and extra["label"].dtype == np.uint8
        assert extra["instance"].dtype == np.int8 and extra["time"].dtype == np.float32
    scene = open_dataset(root)[0]
    assert scene.points.data.dtype == np.float32 and scene.metadata["objects"]["num_points"]


def test_sequence_is_an_ordered_log_with_poses(tmp_path):
    root = tmp_path / "seq"
    spec = parse_scene(street(ego={"position": [0, -1.75], "speed": 10},
                              actors=[{"class": "Car", "position": [20, 1.75], "yaw": 180, "speed": 5, "id": 7}]))
    generate_dataset(root, GenerationConfig(frames=5, seed=0, scene=spec, **SMALL), workers=1)
    log = open_dataset(root)
    assert isinstance(log, KittiLog)
    np.testing.assert_allclose(log.timestamps(), [0.0, 0.1, 0.2, 0.3, 0.4])
    poses = log.poses()
    np.testing.assert_allclose(np.diff(poses[:, 0, 3]), 1.0)  # 10 m/s × 0.1 s along x
    np.testing.assert_allclose(poses[:, 2, 3], 1.73)
    # The oncoming car closes in at 15 m/s relative speed, keeping its track id.
    xs = []
    for scene in log:
        car = scene.boxes.select(scene.boxes.track_ids == 7)
        assert len(car) == 1
        xs.append(car.centers[0, 0])
    np.testing.assert_allclose(np.diff(xs), -1.5, atol=0.02)
    assert (root / "scene.yaml").is_file() and not (root / "scenes").exists()


def test_refuses_to_replace_a_folder_and_resumes_an_interrupted_run(independent, tmp_path):
    root, _ = independent
    config = GenerationConfig(frames=4, seed=3, **SMALL)
    with pytest.raises(DataFormatError, match="not empty"):
        generate_dataset(root, config)
    # An interrupted run: two frames lost, the summary says incomplete.
    partial = tmp_path / "partial"
    shutil.copytree(root, partial)
    for path in [*partial.glob("*/000002.*"), *partial.glob("*/000003.*"), *partial.glob("ImageSets/*")]:
        path.unlink()
    summary = json.loads((partial / SUMMARY_FILE).read_text())
    (partial / SUMMARY_FILE).write_text(json.dumps({**summary, "complete": False}))
    assert not is_complete(partial, config)
    result = generate_dataset(partial, config, resume=True, workers=1)
    assert (result.generated, result.resumed) == (2, 2)
    assert digest(partial) == digest(root) and is_complete(partial, config)
    with pytest.raises(LidarfuzzError, match="different configuration"):
        generate_dataset(partial, GenerationConfig(frames=4, seed=4, **SMALL), resume=True)


def test_overwrite_refuses_folders_it_did_not_generate(tmp_path):
    precious = tmp_path / "precious"
    precious.mkdir()
    (precious / "notes.txt").write_text("mine")
    with pytest.raises(DataFormatError, match="refusing"):
        generate_dataset(precious, GenerationConfig(frames=1, **SMALL), overwrite=True)
    assert (precious / "notes.txt").read_text() == "mine"


def test_ego_follows_its_route_through_a_turn(tmp_path):
    spec = parse_scene({
        "roads": [{"centerline": [[-50, 0], [20, 0], [20, 80]]}],
        "ego": {"route": [[0, -1.75], [21.75, -1.75], [21.75, 60]], "speed": 10},
    })
    root = tmp_path / "turn"
    generate_dataset(root, GenerationConfig(frames=40, seed=0, scene=spec, **SMALL), workers=1)
    poses = open_dataset(root).poses()
    yaw = np.arctan2(poses[:, 1, 0], poses[:, 0, 0])
    assert yaw[0] == pytest.approx(0.0) and yaw[-1] == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(poses[-1, :2, 3], [21.75, -1.75 + (3.9 * 10 - 21.75)], atol=1e-6)
