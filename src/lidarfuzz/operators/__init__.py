"""Mutation operators: one frame in, a realistic test case out, replayable from its params.

    from lidarfuzz.operators import get, generator
    op = get("UPD").at_severity(3)
    mutant, params = op(scene, generator(campaign_seed=0, frame_id="000042", operator_index=0, trial=0))
    again = op.apply(scene, params)          # the same mutant, from the stored params
"""

from lidarfuzz.operators.base import (
    Config,
    Operator,
    Params,
    Relation,
    Target,
    generator,
    seed_sequence,
)
from lidarfuzz.operators.compose import Compose, Maybe, OneOf
from lidarfuzz.operators.registry import available, from_spec, get

__all__ = [
    "Compose", "Config", "Maybe", "OneOf", "Operator", "Params", "Relation", "Target", "available", "from_spec",
    "generator", "get", "seed_sequence",
]
