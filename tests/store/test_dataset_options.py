"""Data-set options survive the store (SQLite and PostgreSQL) and reach every place that opens a
registered data set again: a campaign worker reads it with its layout and its ROI map."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.campaign.work import WorkContext, Worker
from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.store import Store
from lidarfuzz.store.inventory import add_dataset, dataset_options, get_dataset, open_registered


@pytest.fixture
def sweeps(tmp_path: Path) -> Path:
    """Two nuScenes-like sweeps saved as plain .bin (nothing in their names says nuScenes):
    x y z intensity ring, 300 points each (6,000 bytes: 375 KITTI records too)."""
    folder = tmp_path / "sweeps"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):
        xyz = rng.uniform(-40, 40, (300, 3)) + np.array([0, 0, 0.37])
        columns = [xyz, rng.integers(0, 235, (300, 1)), rng.integers(0, 32, (300, 1))]
        np.hstack(columns).astype("<f4").tofile(folder / f"{i:06d}.bin")
    return folder


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Store:
    if request.param == "sqlite":
        return Store(str(tmp_path / "ws"))
    return Store(request.getfixturevalue("fresh_postgres_url"))


def test_options_survive_the_store_and_reach_the_workers(store: Store, sweeps: Path, tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match=r"try --layout nuscenes"):
        add_dataset(store, "plain", sweeps)  # read as KITTI they would be garbage: refused on adding
    roi = tmp_path / "road.geojson"
    roi.write_text(json.dumps({"type": "Polygon", "coordinates": [[[0, -4], [60, -4], [60, 4], [0, 4], [0, -4]]]}))
    options = DatasetOptions(layout="nuscenes", allow_unlabelled=True, intensity_scale=255.0, roi_map=str(roi))
    add_dataset(store, "sweeps", sweeps, options=options)

    row = get_dataset(Store(store.url), "sweeps")  # a new connection: what was stored, not a cache
    assert dataset_options(row) == options.resolved()
    assert row.options == {"layout": "nuscenes", "allow_unlabelled": True, "intensity_scale": 255.0,
                           "roi_map": str(roi.resolve())}
    scene = open_registered(row)[0]
    assert scene.points.channels == ("x", "y", "z", "intensity", "ring")
    assert scene.metadata["roi_source"] == "dataset_map" and scene.roi.area == pytest.approx(480.0)

    worker = Worker(WorkContext(row.path, "classic", {}, "", dataset_options=row.options))
    loaded = worker.load("000001")
    assert loaded.points.has("ring") and loaded.metadata["roi_source"] == "dataset_map"
