"""The contract every registered LiDAR operator must honour, run over the registry's LiDAR operators
(the camera ones have theirs in tests/operators/camera/test_contract.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarfuzz.operators import Relation, available, from_spec, generator
from lidarfuzz.operators.base import Operator
from lidarfuzz.scene.geometry import points_in_boxes
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

OPERATORS = sorted(name for name, cls in available().items() if cls.modality == "lidar")
SEVERITIES = [1, 3, 5]


def rng(trial: int = 0) -> np.random.Generator:
    return generator(campaign_seed=7, frame_id="000000", operator_index=0, trial=trial)


@pytest.fixture(scope="module")
def scene(sample_scenes) -> Scene:
    return sample_scenes[0]


def same(a: Scene, b: Scene) -> bool:
    return a.points == b.points and a.boxes == b.boxes and a.roi == b.roi


@pytest.mark.parametrize("name", OPERATORS)
def test_severity_zero_is_the_identity(name, scene):
    op = available()[name].at_severity(0)
    mutant, params = op(scene, rng())
    assert params.is_identity()
    assert same(mutant, scene)


@pytest.mark.parametrize("severity", SEVERITIES)
@pytest.mark.parametrize("name", OPERATORS)
def test_same_seed_same_mutant_other_seed_other_mutant(name, severity, scene):
    op = available()[name].at_severity(severity)
    first, p1 = op(scene, rng(0))
    again, p2 = op(scene, rng(0))
    assert p1 == p2 and same(first, again)
    other, p3 = op(scene, rng(1))
    if not op.deterministic:
        assert p3 != p1 and not same(other, first)
    assert not same(first, scene)


@pytest.mark.parametrize("severity", SEVERITIES)
@pytest.mark.parametrize("name", OPERATORS)
def test_input_untouched_and_cloud_layout_kept(name, severity, scene):
    before = (scene.points.data.copy(), scene.boxes.as_array().copy(), scene.roi.to_geojson())
    op = available()[name].at_severity(severity)
    mutant, _ = op(scene, rng())
    assert np.array_equal(scene.points.data, before[0])
    assert np.array_equal(scene.boxes.as_array(), before[1], equal_nan=True)
    assert scene.roi.to_geojson() == before[2]
    assert mutant.points.data.dtype == np.float32
    assert mutant.points.channels == scene.points.channels
    assert np.all(np.isfinite(mutant.points.data))
    assert mutant.calib == scene.calib and mutant.frame_id == scene.frame_id


@pytest.mark.parametrize("name", OPERATORS)
def test_empty_cloud(name, scene):
    empty = scene.replace(points=PointCloud.empty(scene.points.channels))
    op = available()[name].at_severity(3)
    mutant, params = op(empty, rng())
    assert mutant.points.channels == empty.points.channels
    assert np.all(np.isfinite(mutant.points.data))
    assert same(op.apply(empty, params), mutant)


@pytest.mark.parametrize("name", OPERATORS)
def test_json_round_trip_replays_exactly(name, scene):
    op = available()[name].at_severity(4)
    mutant, params = op(scene, rng(3))
    rebuilt = from_spec(json.loads(json.dumps(op.spec())))
    stored = json.loads(params.model_dump_json())
    replayed = rebuilt.apply(scene, rebuilt.parse_params(stored))
    assert rebuilt.config == op.config and same(replayed, mutant)


@pytest.mark.parametrize("severity", SEVERITIES)
@pytest.mark.parametrize("name", [n for n in OPERATORS if available()[n].relation is Relation.EQUIVARIANT])
def test_geometric_operators_move_each_objects_points_with_its_box(name, severity, scene):
    op: Operator = available()[name].at_severity(severity)
    mutant, params = op(scene, rng(severity))
    labelled = scene.boxes.has_geometry
    before = points_in_boxes(scene.points.xyz, scene.boxes.as_array()[labelled])
    after = points_in_boxes(mutant.points.xyz, mutant.boxes.as_array()[labelled])
    assert before.any()
    # Points on a box face may flip by float rounding; away from the faces membership is exact.
    inner = points_in_boxes(scene.points.xyz, scene.boxes.as_array()[labelled], margin=-1e-3)
    outer = points_in_boxes(scene.points.xyz, scene.boxes.as_array()[labelled], margin=1e-3)
    stable = (inner == outer).all(axis=1)
    assert np.array_equal(before[stable], after[stable])
    t = op.transform(params)
    expected = scene.points.xyz.astype(np.float64) @ t[:3, :3].T + t[:3, 3]
    np.testing.assert_allclose(mutant.points.xyz, expected, atol=1e-4)
