"""Opening camera data sets through lidarfuzz.io.open and describing them with ``lidarfuzz info``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.frames import FrameFolder
from lidarfuzz.io.images import KittiImages, TableImages
from lidarfuzz.io.kitti import KittiDataset
from lidarfuzz.io.open import open_dataset, source_kind, source_modality
from lidarfuzz.io.options import DatasetOptions
from tests.io.images.test_image_logs import ROS2, STAMP, compressed, write_mcap
from tests.io.images.test_kitti_images import kitti
from tests.io.images.test_tables import plain, udacity

runner = CliRunner()


def test_image_only_sources_are_their_own_kind(tmp_path):
    root = udacity(tmp_path / "udacity")
    assert source_kind(root) == "images" and source_modality(root) == "camera"
    assert source_kind(root / "interpolated.csv") == "images"
    with pytest.raises(DataFormatError, match=r"udacity: holds camera images, not LiDAR scans .*modality='camera'"):
        open_dataset(root)
    assert isinstance(open_dataset(root, modality="camera"), TableImages)


def test_lidar_dispatch_is_unchanged_for_scans(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    np.zeros((40, 4), np.float32).tofile(frames / "000000.bin")
    (frames / "notes.csv").write_text("image,steering\nx.png,0\n")  # a stray CSV does not make it images
    assert source_kind(frames) == "folder" and isinstance(open_dataset(frames), FrameFolder)
    root = kitti(tmp_path / "kitti")
    assert source_kind(root) == "kitti" and source_modality(root) == "lidar"
    assert isinstance(open_dataset(root), KittiDataset)


def test_a_kitti_folder_opened_as_the_camera_modality(tmp_path):
    root = kitti(tmp_path)
    by_kwarg = open_dataset(root, modality="camera")
    by_option = open_dataset(root, options=DatasetOptions.model_validate({"modality": "camera"}))
    assert isinstance(by_kwarg, KittiImages) and isinstance(by_option, KittiImages)
    lidar = open_dataset(root)
    assert list(by_kwarg.frame_ids()) == list(lidar.frame_ids()) == ["000000", "000001"]
    with pytest.raises(DataFormatError, match=r"field 'layout': a point layout .* does not apply to camera images"):
        open_dataset(root, modality="camera", options=DatasetOptions(layout="nuscenes"))


def test_info_describes_an_image_data_set(tmp_path):
    root = plain(tmp_path, ["frames/a.png,0.1,3", "frames/b.png,-0.2,4"])
    out = tmp_path / "report.json"
    result = runner.invoke(app, ["info", str(root), "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "images: 3×2 (1), 5×4 (1)" in result.output
    assert "steering: 2 labelled, from -0.2 to 0.1" in result.output
    report = json.loads(out.read_text())
    assert report["modality"] == "camera" and report["format"] == "csv" and report["frames"] == 2
    assert report["images"]["sizes"] == [{"height": 2, "width": 3, "images": 1}, {"height": 4, "width": 5, "images": 1}]
    assert report["images"]["steering"] == {"min": -0.2, "max": 0.1}
    assert [p["message"] for p in report["problems"]] == [
        "images of 2 sizes: 3×2 (1), 5×4 (1) (allowed: a steering system resizes its input)"]


def test_info_lists_bad_rows_and_exits_1(tmp_path):
    root = plain(tmp_path, ["frames/a.png,0.1,3", "frames/gone.png,0.2,3"])
    result = runner.invoke(app, ["info", str(root)])
    assert result.exit_code == 1
    assert "labels.csv:3: field 'image': image 'frames/gone.png' does not exist" in result.output


def test_info_on_kitti_with_modality_camera(tmp_path):
    root = kitti(tmp_path)
    result = runner.invoke(app, ["info", str(root), "--modality", "camera", "--json", "-"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["modality"] == "camera" and report["images"]["with_intrinsics"] == 2
    lidar = runner.invoke(app, ["info", str(root), "--json", "-"])
    assert json.loads(lidar.output)["modality"] == "lidar"


def test_several_csvs_beside_images_say_which_to_open(tmp_path):
    root = plain(tmp_path, ["frames/a.png,0.1,3"])
    (root / "other.csv").write_text("x\n")
    assert source_kind(root) == "images"
    result = runner.invoke(app, ["info", str(root)])  # the entry point prints the error as one line
    assert isinstance(result.exception, DataFormatError)
    assert "2 CSV files (labels.csv, other.csv): which one lists the images?" in str(result.exception)


def test_info_on_a_log_of_images(tmp_path):
    path = write_mcap(tmp_path / "cam.mcap", {"/cam": [compressed(ROS2, STAMP), compressed(ROS2, STAMP + 10**8)]})
    result = runner.invoke(app, ["info", str(path), "--json", "-"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["modality"] == "camera" and report["format"] == "mcap" and report["frames"] == 2
    assert report["time_span"] == [1_700_000_000.25, 1_700_000_000.35]
    assert [t["name"] for t in report["log"]["topics"]] == ["/cam"]
    assert report["images"]["labelled"] == 0
    assert [p["message"] for p in report["problems"]] == ["2 of 2 image(s) have no steering label"]
