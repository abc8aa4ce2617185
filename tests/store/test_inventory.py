"""The store's inventory: registering data sets and systems under test, from the library and the CLI."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store import Store, Task
from lidarfuzz.store.inventory import add_dataset, add_model, list_datasets, list_models, remove_dataset, remove_model

runner = CliRunner()


def test_add_list_remove(kitti_log: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    ds = add_dataset(store, "sim", kitti_log, notes="3 frames")
    assert (ds.frame_count, ds.format) == (3, "kitti")
    model = add_model(store, "classic", "classic", {"ground": "grid"})
    assert len(model.fingerprint) == 16 and model.options == {"ground": "grid"}
    assert [d.name for d in list_datasets(store)] == ["sim"] and [m.name for m in list_models(store)] == ["classic"]
    with pytest.raises(LidarfuzzError, match="exists already"):
        add_dataset(store, "sim", kitti_log)
    with pytest.raises(LidarfuzzError, match="ground"):
        add_model(store, "bad", "classic?ground=magic")
    with store.session() as s:
        s.add(Task(dataset_id=ds.id, model_id=model.id))
    with pytest.raises(LidarfuzzError, match="used by 1 task"):
        remove_dataset(store, "sim")
    with store.session() as s:
        s.delete(s.query(Task).one())
    remove_dataset(store, "sim")
    remove_model(store, "classic")
    assert list_datasets(store) == [] and list_models(store) == []
    assert (kitti_log / "velodyne").is_dir()  # the data itself is untouched
    with pytest.raises(LidarfuzzError, match="no data set called"):
        remove_dataset(store, "sim")


def test_cli(kitti_log: Path, tmp_path: Path) -> None:
    ws = str(tmp_path / "ws")
    result = runner.invoke(app, ["datasets", "add", "sim", str(kitti_log), "--workspace", ws])
    assert result.exit_code == 0 and "3 frame(s)" in result.output
    result = runner.invoke(app, ["models", "add", "pp", "classic", "--option", "cluster_cell=0.4", "--workspace", ws])
    assert result.exit_code == 0 and "fingerprint" in result.output
    listing = runner.invoke(app, ["models", "list", "--workspace", ws])
    assert "pp" in listing.output and "classic" in listing.output
    assert "sim" in runner.invoke(app, ["datasets", "list", "--workspace", ws]).output
    assert runner.invoke(app, ["models", "remove", "pp", "--workspace", ws]).exit_code == 0
    assert runner.invoke(app, ["datasets", "remove", "sim", "--workspace", ws]).exit_code == 0
