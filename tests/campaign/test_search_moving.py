"""Scene-moving operators in a coverage-guided search: a test whose chain moves the scene is judged
by equivariance through the chain's composed transform, a chain that moves nothing as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")

from sqlalchemy import select

from lidarfuzz.campaign.coverage_search import StoredChain, search_relations
from lidarfuzz.campaign.replay import replay_finding
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.coverage import ActivationRecorder, make_criteria
from lidarfuzz.operators import Compose, get
from lidarfuzz.operators.base import Relation
from lidarfuzz.operators.compose import CompositeParams, Step
from lidarfuzz.oracles.relations.registry import from_spec
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.search.algorithms import SearchConfig, make_search
from lidarfuzz.search.evaluate import ChainStep, SearchEvaluator
from lidarfuzz.store.models import Finding, FrameResult, Status
from lidarfuzz.store.store import Store

#: Two cars: one ahead at 15 m, one to the left at 20 m turned by 1 rad.
CENTRES = [[15.0, 0.0, -0.9], [0.0, 20.0, -0.9]]
SIZES = [[4.0, 1.8, 1.6]] * 2
YAWS = [0.0, 1.0]


def _tiny_scene() -> Scene:
    """The two cars, each filled with a 10 × 5 × 4 grid of points inside its box (200 points)."""
    grid = np.stack(np.meshgrid(np.linspace(-1.8, 1.8, 10), np.linspace(-0.8, 0.8, 5), np.linspace(-0.7, 0.7, 4),
                                indexing="ij"), axis=-1).reshape(-1, 3)
    parts = []
    for centre, yaw in zip(CENTRES, YAWS, strict=True):
        c, s = np.cos(yaw), np.sin(yaw)
        turned = grid @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
        parts.append(turned + centre)
    xyz = np.concatenate(parts)
    cloud = PointCloud(np.column_stack([xyz, np.full(len(xyz), 0.5)]).astype(np.float32))
    boxes = Boxes3D.create(CENTRES, SIZES, YAWS, ["Car", "Car"], track_ids=[1, 2])
    return Scene(cloud, boxes, frame_id="000000")


class _OneFrame:
    def __init__(self, scene: Scene) -> None:
        self.scene = scene

    def load(self, frame_id: str) -> Scene:
        return self.scene


class _StandIn:
    """A system under test built on a tiny torch module (for the coverage hooks) that answers the
    labels of the scene it is shown (``equivariant``) or the seed frame's labels wherever the
    scene was moved (a system blind to the move)."""

    def __init__(self, seed: Scene, equivariant: bool) -> None:
        import torch

        self.module = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.ReLU())
        self.seed, self.equivariant = seed, equivariant

    def detect_batch(self, scenes: list[Scene]) -> list[Boxes3D]:
        import torch

        self.module(torch.tensor(np.stack([s.points.xyz.mean(axis=0) for s in scenes])))
        out = []
        for scene in scenes:
            boxes = scene.boxes if self.equivariant else self.seed.boxes
            out.append(boxes.replace(scores=np.full(len(boxes), 0.9)))
        return out


def _evaluator(equivariant: bool) -> SearchEvaluator:
    scene = _tiny_scene()
    config = SearchConfig(operators=("rotate_z", "gaussian_noise_addition"), criteria=("nc",))
    relations = [from_spec(spec) for spec in search_relations(config, "auto")]
    sut = _StandIn(scene, equivariant)
    return SearchEvaluator(_OneFrame(scene), sut, relations, ActivationRecorder(sut.module))


def _rotated_then_noisy(angle: float) -> list[ChainStep]:
    return [ChainStep(get("rotate_z").at_severity(3).spec(), {"angle": angle}),
            ChainStep(get("gaussian_noise_addition").at_severity(1).spec())]


def test_search_config_accepts_scene_moving_operators() -> None:
    config = SearchConfig(operators=("rotate_z", "gaussian_noise_addition"))
    assert config.operators == ("rotate_z", "gaussian_noise_addition")
    # the auto oracle: preservation for chains that move nothing, equivariance for those that do
    assert [s["name"] for s in search_relations(config, "auto")] == ["preservation", "equivariance"]
    assert [s["name"] for s in search_relations(SearchConfig(operators=("fog",)), "auto")] == ["preservation"]


def test_composed_transform_of_two_rotations_is_their_sum() -> None:
    chain = Compose([get("rotate_z")(), get("gaussian_noise_addition")(), get("rotate_z")()])
    params = CompositeParams(steps=[Step(operator="rotate_z", params={"angle": 30.0}),
                                    Step(operator="gaussian_noise_addition", params=None),
                                    Step(operator="rotate_z", params={"angle": 45.0})])
    # 30° then 45° is 75° about z: cos 75° = 0.258819, sin 75° = 0.965926 (tables)
    expected = np.array([[0.258819, -0.965926, 0, 0], [0.965926, 0.258819, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    moved = chain.transform(params)
    assert moved is not None
    np.testing.assert_allclose(moved, expected, atol=1e-6)
    # a chain that moves nothing has no transform
    still = Compose([get("gaussian_noise_addition")()])
    assert still.transform(CompositeParams(steps=[Step(operator="gaussian_noise_addition", params=None)])) is None


def test_moved_chain_is_judged_by_equivariance() -> None:
    blind, following = _evaluator(equivariant=False), _evaluator(equivariant=True)
    rng = np.random.default_rng
    moved_blind = blind.mutants("000000", [_rotated_then_noisy(30.0)], [rng(0)])[0]
    moved_following = following.mutants("000000", [_rotated_then_noisy(30.0)], [rng(0)])[0]
    for evaluation in (moved_blind, moved_following):
        assert evaluation.operator_relation == Relation.EQUIVARIANT
        np.testing.assert_allclose(evaluation.transform[:2, :2], [[0.866025, -0.5], [0.5, 0.866025]], atol=1e-6)
        # rotation keeps every point in its moved box: 200 of 200 per car, valid
        assert evaluation.valid, evaluation.validity
        # only equivariance: preservation compares boxes in place and does not apply to a moved test
        assert [r.relation for r in evaluation.relations] == ["equivariance"]
    (blind_outcome,), (following_outcome,) = moved_blind.relations, moved_following.relations
    assert following_outcome.holds and dict(following_outcome.checked) == {"Car": 2}
    # the blind system answers the unmoved boxes: each car's moved box has no match (the car at 15 m
    # moves 2 · 15 · sin 15° = 7.8 m, the one at 20 m 10.4 m), and each answered box is unaccounted for
    kinds = sorted(v.kind for v in blind_outcome.violations)
    assert not blind_outcome.holds and kinds == ["missing", "missing", "spurious", "spurious"]
    # the same chain without the rotation moves nothing: today's oracle, which the blind system passes
    still = blind.mutants("000000", [_rotated_then_noisy(30.0)[1:]], [rng(0)])[0]
    assert still.operator_relation == Relation.INVARIANT and still.transform is None
    assert [(r.relation, r.holds) for r in still.relations] == [("preservation", True)]


def test_interleaved_moves_compose_in_the_order_they_ran() -> None:
    following = _evaluator(equivariant=True)
    chain = [ChainStep(get("rotate_z").at_severity(5).spec(), {"angle": 90.0}),
             ChainStep(get("gaussian_noise_addition").at_severity(1).spec()),
             ChainStep(get("global_translate").at_severity(2).spec(), {"offset": [0.5, 0.0, 0.0]})]
    evaluation = following.mutants("000000", [chain], [np.random.default_rng(1)])[0]
    assert evaluation.transform is not None
    # the car at (15, 0): turned 90° to (0, 15), then moved 0.5 m along x to (0.5, 15) (the other
    # order would give (0, 15.5))
    np.testing.assert_allclose(evaluation.transform @ [15.0, 0.0, -0.9, 1.0], [0.5, 15.0, -0.9, 1.0], atol=1e-9)
    assert [(r.relation, r.holds) for r in evaluation.relations] == [("equivariance", True)]


def test_moving_severity_is_capped_at_its_harmless_range() -> None:
    config = SearchConfig(operators=("global_translate",), criteria=("nc",))
    search = make_search(config, ["000000"], make_criteria(["nc"]), 0)
    severities = {search.random_step(np.random.default_rng(i))[1] for i in range(200)}
    # global_translate is meant to be harmless up to severity 2 (0.5 m), the default top is 5
    assert severities == {1, 2}


def test_guided_search_with_rotate_z_stores_tests_that_replay(world: Path, tmp_path: Path) -> None:
    store = Store(tmp_path / "ws")
    spec = parse_campaign({
        "dataset": str(world), "sut": "pillars", "kind": "guided", "frames": 1, "seed": 0,
        "operators": [{"name": "rotate_z"}, {"name": "intensity_scaling"}],
        # a strict equivariance (IoU 0.97) so that a moved test violates it and becomes a finding
        "relations": ["preservation",
                      {"name": "equivariance", "config": {"min_iou": 0.97, "min_score": 0.2, "roi_only": False}}],
        "search": {"budget": 6, "criteria": ["nc:0.2", "tknc:2"], "max_failed_tries": 5}})
    task_id = create_task(store, spec)
    assert run_task(store, task_id).status == Status.DONE
    search_sub = next(sub.id for sub in get_task(store, task_id).subtasks if sub.name == "guided")
    with store.session() as s:
        rows = s.execute(select(FrameResult.params, FrameResult.relations).where(
            FrameResult.subtask_id == search_sub)).all()
        moved = [(p, r) for p, r in rows if any(st["operator"] == "rotate_z" for st in p["params"]["steps"])]
        assert moved, "with seed 0, three of the six tests draw rotate_z"
        for params, relations in rows:
            names = {r.relation for r in relations}
            angles = [st["params"]["angle"] for st in params["params"]["steps"] if st["operator"] == "rotate_z"]
            if params["valid"]:
                assert names == ({"equivariance"} if angles else {"preservation"})
            # what AP reads back from the stored chain: rotations about z add up (none: nothing moved)
            moved_by = StoredChain().transform(params)
            if angles:
                a = np.deg2rad(sum(angles))
                assert moved_by is not None
                np.testing.assert_allclose(moved_by[:2, :2], [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]],
                                           atol=1e-9)
            else:
                assert moved_by is None
        finding = s.scalars(select(Finding).where(Finding.task_id == task_id,
                                                  Finding.kind == "equivariance")).first()
        assert finding is not None
        assert finding.replay.operator_relation == "equivariant"
        recorded = s.get(FrameResult, finding.frame_result_id)
        assert recorded is not None
        recorded_violations = [len(r.violations) for r in recorded.relations if r.relation == "equivariance"]
        finding_id = finding.id
    replay = replay_finding(store, finding_id)
    assert replay.reproduced, replay.verdict
    assert [len(o.violations) for o in replay.outcomes_now] == recorded_violations

