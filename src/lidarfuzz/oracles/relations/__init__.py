"""Metamorphic relations: the contract, the built-ins for 3D detection, the registry."""

from lidarfuzz.oracles.relations.base import MetamorphicRelation, Pair, RelationConfig, RelationOutcome, Violation
from lidarfuzz.oracles.relations.detection import (
    DeepTestTolerance,
    Equivariance,
    GroundTruthRecall,
    Invariance,
    Preservation,
    gt_correspondence,
)
from lidarfuzz.oracles.relations.registry import available, for_operator, from_spec, get

__all__ = [
    "DeepTestTolerance",
    "Equivariance",
    "GroundTruthRecall",
    "Invariance",
    "MetamorphicRelation",
    "Pair",
    "Preservation",
    "RelationConfig",
    "RelationOutcome",
    "Violation",
    "available",
    "for_operator",
    "from_spec",
    "get",
    "gt_correspondence",
]
