"""Intensity units: the same readings expressed in another unit or range."""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from lidarfuzz.operators.base import Config, Operator, Params, Relation, Target
from lidarfuzz.operators.lidar.common import scene_intensity_scale
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

Unit = Literal["unit", "percent", "uint8", "uint16"]
#: Full scale of each unit, and whether its values are integers.
UNITS: dict[str, tuple[float, bool]] = {"unit": (1.0, False), "percent": (100.0, False), "uint8": (255.0, True),
                                        "uint16": (65535.0, True)}


class IntensityUnitsConfig(Config):
    units: tuple[Unit, ...] = Field(("unit", "percent", "uint8"), description="units the mutant's intensities are "
                                    "expressed in, one drawn per mutant among those unlike the frame's own: unit "
                                    "(0-1 floats), percent (0-100), uint8 (0-255 integers), uint16 (0-65535 integers)")
    declare_scale: bool = Field(True, description="the mutant's metadata declares the new scale (a converting reader); "
                                                  "false: it keeps the old one (a driver that converts silently)")


class IntensityUnitsParams(Params):
    source_scale: float = Field(gt=0, description="the frame's full scale (declared by its reader, else inferred)")
    unit: Unit | None = Field(description="the unit drawn; None: nothing changes")
    declare_scale: bool = True

    def is_identity(self) -> bool:
        return self.unit is None


class IntensityUnits(Operator[Scene, IntensityUnitsConfig, IntensityUnitsParams]):
    """The same reflectances in another unit, as a driver update or a data set conversion gives
    them: [0, 1] floats (KITTI, the simulator), 0-100 percent (some drivers' "reflectivity"),
    0-255 integers (Velodyne's and nuScenes' raw bytes) or 0-65535 (LAS). Every intensity is
    divided by the frame's full scale (declared by its reader, else inferred: 1, 255 or 65535)
    and multiplied by the new unit's, rounded to integers for the integer units; the mutant's
    ``metadata["intensity_scale"]`` declares the new scale, as a converting reader would (with
    ``declare_scale: false`` it keeps the old one, as a driver that converts silently leaves it).
    Positions, every other channel, boxes, calibration and map stay. The severity table draws no
    randomness: severities 1-3 convert to percent, 0-255 and 0-65535 (a frame already in that unit
    goes to [0, 1] instead), 4 and 5 to 0-255 and 0-65535 without declaring it.

    Relation: **degrading**, never harmless (``harmless_up_to`` 0). A system that normalises its
    input by the declared scale is invariant to this operator, and one that assumes its training
    data's units is not — and which of the two a system must be is its input contract, which
    lidarfuzz cannot know. So no harmlessness relation checks it; the finding is the accuracy lost
    (ΔAP against the original), which is zero for a system that normalises and large for one that
    is handed 0-255 values where it learned [0, 1] (a known defect of public tools).
    """

    name = "intensity_units"
    aliases = ("INTENSITY_SCALE",)
    family = "intensity"
    relation = Relation.DEGRADING
    targets = frozenset({Target.POINTS})
    harmless_up_to: ClassVar[int] = 0
    harmless_because: ClassVar[str] = ("whether a system must accept other intensity units is its input contract, "
                                       "which lidarfuzz cannot know")
    ConfigModel = IntensityUnitsConfig
    ParamsModel = IntensityUnitsParams
    deterministic = True
    IDENTITY: ClassVar = {"units": ()}
    # For [0, 1] data: ×100, ×255, ×65535, then the last two with the scale left undeclared.
    SEVERITIES: ClassVar = {1: {"units": ("percent",)}, 2: {"units": ("uint8",)}, 3: {"units": ("uint16",)},
                            4: {"units": ("uint8",), "declare_scale": False},
                            5: {"units": ("uint16",), "declare_scale": False}}

    def sample(self, rng: np.random.Generator, sample: Scene) -> IntensityUnitsParams:
        source = scene_intensity_scale(sample)
        if not self.config.units:
            return IntensityUnitsParams(source_scale=source, unit=None)
        others = [u for u in self.config.units if UNITS[u][0] != source]
        # a frame already in the only unit asked for goes to [0, 1], or from [0, 1] to 0-255
        choices = others or (["unit"] if source != 1.0 else ["uint8"])
        return IntensityUnitsParams(source_scale=source, unit=choices[int(rng.integers(0, len(choices)))],
                                    declare_scale=self.config.declare_scale)

    def apply(self, sample: Scene, params: IntensityUnitsParams) -> Scene:
        if params.unit is None:
            return sample
        scale, integer = UNITS[params.unit]
        cloud = sample.points
        # clip(round(i / source · scale), 0, scale): the same float64 steps in one buffer, rounded
        # to float32 as they are written into the one copy of the data
        values = cloud.intensity.astype(np.float64)
        values /= params.source_scale
        values *= scale
        if integer:
            np.round(values, out=values)
        np.clip(values, 0.0, scale, out=values)
        data = cloud.data.copy()
        data[:, 3] = values
        points = PointCloud(data, cloud.channels)
        if not params.declare_scale:
            return sample.replace(points=points)
        return sample.replace(points=points, metadata={**sample.metadata, "intensity_scale": scale})

__all__ = ["UNITS", "IntensityUnits", "IntensityUnitsConfig", "IntensityUnitsParams"]
