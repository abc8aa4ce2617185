"""``roi_map: estimate``: frames without a map get the drivable region estimated from their own
points when loaded, so the system under test and every mutant of a frame see the same region."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.io import open_dataset
from lidarfuzz.io.options import DatasetOptions, options_from_flags
from lidarfuzz.operators import generator
from lidarfuzz.operators import get as get_operator
from lidarfuzz.scene.drivable import estimate_drivable


@pytest.fixture
def without_maps(kitti_log: Path, tmp_path: Path) -> Path:
    """The labelled 3-frame log with frame 000001's own map removed."""
    root = tmp_path / "nomap"
    shutil.copytree(kitti_log, root)
    (root / "roi" / "000001.json").unlink()
    return root


def test_frames_without_a_map_get_the_estimate_and_say_so(without_maps: Path) -> None:
    dataset = open_dataset(without_maps, options=DatasetOptions(roi_map="estimate"))
    own, estimated = dataset.load("000000"), dataset.load("000001")
    assert own.metadata["roi_source"] == "frame_map"  # a frame's own map is never replaced
    assert estimated.metadata["roi_source"] == "estimated"
    plain = open_dataset(without_maps).load("000001")
    assert plain.roi is None and "roi_source" not in plain.metadata
    # the estimate is the points' alone: labels removed, the same region
    unlabelled = plain.replace(boxes=plain.boxes.select(np.zeros(len(plain.boxes), bool)))
    assert estimated.roi is not None
    assert estimated.roi.geometry.equals(estimate_drivable(unlabelled, use_labels=False).geometry)
    # the ego vehicle stands on the road it estimates
    assert estimated.roi.contains_xy(np.array([[0.0, 0.0]]))[0]


def test_scatter_on_the_estimate_replays_and_names_the_region(without_maps: Path) -> None:
    frame = open_dataset(without_maps, options=DatasetOptions(roi_map="estimate")).load("000001")
    op = get_operator("outside_roi_scatter").at_severity(2)
    mutant, params = op(frame, generator(0, frame.frame_id, 0, 0))
    assert params.region == "estimated"
    assert len(mutant.points) == len(frame.points) + 100
    added = mutant.points.xyz[len(frame.points):, :2]
    assert not frame.roi.contains_xy(added).any()  # outside the region the system sees
    assert op.apply(frame, params).points == mutant.points


def test_the_word_is_kept_as_it_is_through_the_flags_and_the_store() -> None:
    options = options_from_flags(roi_map="estimate")
    assert options.roi_map == "estimate" and options.estimates_map and options.dataset_map() is None
    assert DatasetOptions.from_stored(options.stored()) == options
