"""The dual-return operator: duplicated firings, second returns behind edges, the scan order kept."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators import generator
from lidarfuzz.operators.lidar.returns import DualReturn, DualReturnParams, far_neighbour
from lidarfuzz.operators.registry import get
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


def ring_scene() -> Scene:
    """One ring, five firings 0.5° apart: a wall 10 m ahead, except the middle firing, which hits
    a pole 5 m ahead (label 2, instance 7) in front of the wall (label 1, instance 3)."""
    azimuth = np.radians([-1.0, -0.5, 0.0, 0.5, 1.0])
    distance = np.array([10.0, 10.0, 5.0, 10.0, 10.0])
    xyz = np.c_[distance * np.cos(azimuth), distance * np.sin(azimuth), np.zeros(5)]
    intensity = np.array([0.4, 0.4, 0.9, 0.4, 0.4])
    label = np.array([1, 1, 2, 1, 1.0])
    instance = np.array([3, 3, 7, 3, 3.0])
    data = np.c_[xyz, intensity, np.zeros(5), label, instance].astype(np.float32)
    return Scene(PointCloud(data, ("x", "y", "z", "intensity", "ring", "label", "instance")))


def params(ratio: float, seed: int = 0) -> DualReturnParams:
    return DualReturnParams(ratio=ratio, edge_m=1.0, max_gap_deg=1.0, behind_share=0.5, ring_source="channel",
                            seed=seed)


def test_every_firing_gets_its_pair_right_after_it() -> None:
    scene = ring_scene()
    out = DualReturn().apply(scene, params(1.0)).points.data
    assert len(out) == 10
    first, second = out[0::2], out[1::2]
    np.testing.assert_array_equal(first, scene.points.data)  # the original firings in their order
    # the wall's firings had one echo: their second return is the same measurement
    np.testing.assert_array_equal(second[[0, 1, 3, 4]], scene.points.data[[0, 1, 3, 4]])
    # the pole's firing straddles its edge: the second return is the wall, 10 m along the same
    # direction (x = 10, y = 0), with half the wall's intensity (0.2) and the wall's label/instance
    np.testing.assert_allclose(second[2, :4], [10.0, 0.0, 0.0, 0.2], atol=1e-5)
    assert second[2, 5:].tolist() == [1.0, 3.0]


def test_only_a_neighbour_on_the_same_ring_and_close_in_azimuth_makes_an_edge() -> None:
    scene = ring_scene()
    ring = np.zeros(5, np.int64)
    found = far_neighbour(scene.points, ring, 1.0, 1.0).tolist()
    assert found[:2] + found[3:] == [-1] * 4 and found[2] in (1, 3)  # the pole's two wall neighbours
    assert far_neighbour(scene.points, ring, 6.0, 1.0).tolist() == [-1] * 5  # the wall is only 5 m behind
    assert far_neighbour(scene.points, ring, 1.0, 0.4).tolist() == [-1] * 5  # neighbours 0.5° away: too far
    assert far_neighbour(scene.points, np.array([0, 0, 1, 2, 2]), 1.0, 1.0).tolist() == [-1] * 5
    assert far_neighbour(scene.points, np.full(5, -1), 1.0, 1.0).tolist() == [-1] * 5  # unknown rings


@pytest.mark.parametrize("severity, added", [(1, 1), (3, 3), (5, 4)])
def test_severity_sets_the_share_of_firings_with_a_pair(severity: int, added: int) -> None:
    # ratio 0.2 / 0.6 / 0.9 of 5 firings: round(1.0), round(3.0), round(4.5) = 4 second returns
    scene = ring_scene()
    out, drawn = DualReturn.at_severity(severity)(scene, generator(0, "f", 0, 0))
    assert len(out.points) == 5 + added and drawn.ring_source == "channel"
    assert out.boxes is scene.boxes or len(out.boxes) == len(scene.boxes)


def test_registered_under_its_alias_and_not_harmless() -> None:
    assert get("DUAL") is DualReturn and DualReturn.harmless_up_to == 0
    scene = ring_scene()
    assert DualReturn().apply(scene, params(0.0)) is scene  # no firing chosen: the sample itself
