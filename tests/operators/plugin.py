"""A third-party operator, as a plugin package would ship it (used by the registry test)."""

from typing import ClassVar

import numpy as np

from lidarfuzz.operators.base import Config, Operator, Params, Relation, Target


class _Config(Config):
    pass


class _Params(Params):
    pass


class UpsideDown(Operator):
    name = "upside_down"
    family = "geometric"
    relation = Relation.DEGRADING
    targets = frozenset({Target.POINTS})
    ConfigModel = _Config
    ParamsModel = _Params
    IDENTITY: ClassVar = {}
    SEVERITIES: ClassVar = {1: {}}

    def sample(self, rng: np.random.Generator, sample):
        return _Params()

    def apply(self, sample, params):
        xyz = sample.points.xyz.copy()
        xyz[:, 2] = -xyz[:, 2]
        return sample.with_points(sample.points.with_xyz(xyz))
