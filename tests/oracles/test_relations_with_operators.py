"""Relations against the real operators: an oracle detector that answers the ground truth
satisfies every relation an operator claims, so a violation in a campaign is the SUT's fault."""

from __future__ import annotations

import numpy as np
import pytest

from lidarfuzz.operators import available, generator
from lidarfuzz.operators.base import Relation
from lidarfuzz.oracles.relations import Equivariance, GroundTruthRecall, Pair, Preservation, for_operator
from lidarfuzz.scene.scene import Scene

EQUIVARIANT = sorted(n for n, c in available().items() if c.relation is Relation.EQUIVARIANT and c.modality == "lidar")


def perfect(scene: Scene) -> object:
    """Detections equal to the ground truth (score 1)."""
    boxes = scene.boxes.select(scene.boxes.has_geometry)
    return boxes.replace(scores=np.ones(len(boxes)))


@pytest.mark.parametrize("name", EQUIVARIANT)
def test_an_exact_detector_is_equivariant_under_every_equivariant_operator(
    name: str, sample_scenes: list[Scene]
) -> None:
    source = sample_scenes[0]
    op = available()[name].at_severity(3)
    follow, params = op(source, generator(1, source.frame_id, 0, 0))
    t = op.transform(params)
    assert t is not None, f"{name} claims equivariance but exposes no transform"
    pair = Pair(source, follow, perfect(source), perfect(follow), op.relation, transform=t)
    outcome = Equivariance(min_iou=0.9)(pair)
    assert outcome.applicable and outcome.holds, [v.message for v in outcome.violations]
    assert GroundTruthRecall()(pair).holds


def test_an_exact_detector_preserves_objects_under_invariant_operators(sample_scenes: list[Scene]) -> None:
    source = sample_scenes[1]
    invariant = [n for n, c in available().items() if c.relation is Relation.INVARIANT and c.modality == "lidar"][:6]
    assert invariant
    for name in invariant:
        op = available()[name].at_severity(2)
        follow, _ = op(source, generator(1, source.frame_id, 0, 0))
        pair = Pair(source, follow, perfect(source), perfect(follow), op.relation)
        for relation in for_operator(op.relation):
            outcome = relation(pair)
            assert outcome.holds, (name, relation.name, [v.message for v in outcome.violations])
        assert Preservation()(pair).checked  # something was checked
