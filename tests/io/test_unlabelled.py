"""A KITTI folder where some frames have no label file: the commands that need no labels (info,
detect, mutate, convert, datasets add) work on it; unlabelled frames stay unlabelled (no boxes,
``metadata["labelled"]`` False — unlike a labelled frame with no objects) through every writer."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.io import KittiDataset, open_dataset
from lidarfuzz.io.inspect import inspect_source

runner = CliRunner()


@pytest.fixture
def mixed(kitti_log: Path, tmp_path: Path) -> Path:
    """The 3-frame labelled log with frame 000001's label file removed, and 000002's emptied
    (a labelled frame with no objects)."""
    root = tmp_path / "mixed"
    shutil.copytree(kitti_log, root)
    (root / "label_2" / "000001.txt").unlink()
    (root / "label_2" / "000002.txt").write_text("")
    for stem in ("000001", "000002"):  # per-object side files go with the labels
        (root / "label_2_extra" / f"{stem}.json").unlink(missing_ok=True)
    return root


def test_unlabelled_frames_are_told_from_frames_without_objects(mixed: Path) -> None:
    dataset = KittiDataset(mixed)  # strict, yet not refused
    assert dataset.has_labels() and dataset.unlabelled_ids() == ["000001"]
    labelled, unlabelled, empty = (dataset.load(f) for f in ("000000", "000001", "000002"))
    assert labelled.metadata["labelled"] is True and len(labelled.boxes) > 0
    assert unlabelled.metadata["labelled"] is False and len(unlabelled.boxes) == 0
    assert empty.metadata["labelled"] is True and len(empty.boxes) == 0
    warning = [p for p in dataset.problems() if "no label file" in p.message]
    assert len(warning) == 1 and warning[0].severity == "warning"
    assert "1 of 3 frame(s) have no label file in label_2/ (000001)" in warning[0].message


def test_a_folder_without_any_label_file_is_unlabelled_throughout(mixed: Path) -> None:
    shutil.rmtree(mixed / "label_2")
    dataset = KittiDataset(mixed)
    assert not dataset.has_labels() and dataset.unlabelled_ids() == []  # nothing to refuse: no AP at all
    assert all(scene.metadata["labelled"] is False for scene in dataset)


def test_info_counts_them_as_a_warning(mixed: Path, tmp_path: Path) -> None:
    report = inspect_source(mixed)
    assert report.unlabelled_frames == 1 and not report.errors
    out = tmp_path / "info.json"
    result = runner.invoke(app, ["info", str(mixed), "--json", str(out)], env={"COLUMNS": "200"})
    assert result.exit_code == 0, result.output
    assert "unlabelled frames (no label file): 1" in result.output
    assert "have no label file in label_2/ (000001)" in result.output
    assert json.loads(out.read_text())["unlabelled_frames"] == 1
    allowed = runner.invoke(app, ["info", str(mixed), "--allow-unlabelled"], env={"COLUMNS": "200"})
    assert allowed.exit_code == 0 and "no problems found" in allowed.output


def test_detect_runs_every_frame(mixed: Path, tmp_path: Path) -> None:
    out = tmp_path / "detections"
    result = runner.invoke(app, ["detect", "classic", str(mixed), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in out.iterdir()) == ["000000.txt", "000001.txt", "000002.txt"]
    # eval needs labels: the unlabelled frame's detections are refused, naming the flag …
    refused = runner.invoke(app, ["eval", str(mixed), str(out)])
    assert refused.exit_code != 0 and "000001.txt: detection file without a ground-truth frame" in str(
        refused.exception) and "--allow-unlabelled" in str(refused.exception)
    # … and left out with it (AP over the two labelled frames)
    report = tmp_path / "eval.json"
    allowed = runner.invoke(app, ["eval", str(mixed), str(out), "--allow-unlabelled", "--json", str(report)])
    assert allowed.exit_code == 0, allowed.output
    assert json.loads(report.read_text())["num_frames"] == 2


@pytest.mark.parametrize("command", [
    ["convert", "{src}", "{dst}"],
    ["mutate", "{src}", "{dst}", "--op", "UPD", "--severity", "2"],
])
def test_convert_and_mutate_keep_unlabelled_frames_unlabelled(mixed: Path, tmp_path: Path,
                                                              command: list[str]) -> None:
    dst = tmp_path / "out"
    result = runner.invoke(app, [part.format(src=mixed, dst=dst) for part in command])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (dst / "label_2").iterdir()) == ["000000.txt", "000002.txt"]
    written = open_dataset(dst)
    assert written.unlabelled_ids() == ["000001"]
    assert written.load("000002").metadata["labelled"] is True  # still a frame with no objects


def test_datasets_add_records_it(mixed: Path, tmp_path: Path) -> None:
    result = runner.invoke(app, ["datasets", "add", "mixed", str(mixed), "--workspace", str(tmp_path / "ws")])
    assert result.exit_code == 0, result.output
    assert "3 frame(s)" in result.output
