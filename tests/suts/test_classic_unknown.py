"""The classic pipeline's ``report_unknown``: clusters no class rule fits are reported as Unknown
(as Apollo's obstacle perception reports them), and nothing else changes."""

from __future__ import annotations

import numpy as np

from lidarfuzz.scene import Scene
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.suts.classic.pipeline import ClassicPipeline


def test_unknown_obstacles_are_added_and_nothing_else_changes(sample_scenes: list[Scene]) -> None:
    plain, with_unknown = ClassicPipeline(), ClassicPipeline(report_unknown=True)
    unknown_seen = 0
    for scene in sample_scenes:
        before, after = plain.detect(scene), with_unknown.detect(scene)
        assert "Unknown" not in set(before.labels.tolist())
        classed = after.select(np.flatnonzero(after.labels != "Unknown"))
        # the classed objects are the plain pipeline's, box for box (the queue order is the same)
        np.testing.assert_array_equal(classed.as_array(), before.as_array())
        assert classed.labels.tolist() == before.labels.tolist()
        unknown_seen += int((after.labels == "Unknown").sum())
        assert with_unknown.validate(after) is None
    # the simulator's frames have poles, trees and walls by the road: some are reported now
    assert unknown_seen > 0


def test_unknown_is_a_valid_class_only_when_reported() -> None:
    box = Boxes3D.create([[10.0, 0.0, 0.0]], [[1.0, 1.0, 2.0]], [0.0], ["Unknown"], scores=[0.4])
    assert ClassicPipeline(report_unknown=True).validate(box) is None
    assert "Unknown" in (ClassicPipeline().validate(box) or "")
    # the option is part of the configuration, hence of the fingerprint
    assert ClassicPipeline(report_unknown=True).config()["report_unknown"] is True
    assert ClassicPipeline().fingerprint() != ClassicPipeline(report_unknown=True).fingerprint()
