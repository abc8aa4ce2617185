"""How far generated frames depart from an idealised world, and the ranges real scans span.

A detector trained on flat ground, clean intensities and perfect returns fails on real
scans (lidarfuzz's own ``pillars`` covered the empty real road with car boxes). Three
things matter most, each measured on KITTI object-benchmark scans (HDL-64E, training
000000–000002; the figures are written here, never read at run time):

* **the ground** (:class:`~lidarfuzz.sim.spec.Terrain`): near the car the road tilts by
  0.3–1.1 % along and 0.6–2 % across the sensor frame; at 50 m it lies 0.3–0.8 m above or
  below the plane under the car (crests and sags: the grade changes by several per cent
  per 100 m); across the road it falls towards the kerbs and rises onto sidewalks and
  verges by 0.1–0.5 m;
* **the intensity** (:class:`~lidarfuzz.sim.sensor.Receiver`): quantised to 0.01, 8.5–10.4 %
  of all returns read exactly 0 (8–26 % across KITTI), rising from ~5 % within 20 m to 50–65 %
  at 40–60 m and ~90 % at 60–80 m; the 64 lasers differ in gain by σ 10–16 %;
* **the returns** (:class:`~lidarfuzz.sim.sensor.Dropouts`): 115–127 thousand points per
  sweep; the lowest lasers return on only 55–75 % of their columns (the roof rack hides
  the ground ahead and behind); glossy and dark surfaces lose points.

:class:`RealismConfig` holds, per knob, the range each generated frame's value is drawn
from (from the frame's seed, so a data set is the same whatever the worker count). The
default draws the ground per scene within the ranges real roads have and renders every
frame with one sensor whose receiver and losses are KITTI's (as a real data set is
recorded with one sensor), its pitch and roll against the road varying a little, as a
car's do. A training script widens the sensor's ranges too
(:meth:`RealismConfig.randomised`) for domain randomisation;
:meth:`RealismConfig.off` gives the flat, clean world of earlier versions.

Example:
    >>> import numpy as np
    >>> terrain = RealismConfig().sample_terrain(np.random.default_rng(0))
    >>> 0.01 <= terrain["camber"] <= 0.03
    True
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, field_validator

from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim.sensor import LidarSensor, clean_sensor, sensor_with

Range = tuple[float, float]

#: Share of the returns of real KITTI scans (HDL-64E, training 000000–000002: 8.5–10.4 %) that read exactly 0.
KITTI_ZERO_SHARE = 0.09
#: Deciles (0 %, 10 %, …, 100 %) of those scans' non-zero intensities, averaged over the three frames.
KITTI_NONZERO_DECILES = np.array([0.01, 0.16, 0.21, 0.25, 0.28, 0.30, 0.32, 0.34, 0.37, 0.42, 0.99])

#: Where each receiver/loss knob lives on :class:`~lidarfuzz.sim.sensor.LidarSensor`:
#: ``RealismConfig`` field (without ``_range``) → (section, field); section ``None`` is the sensor itself.
SENSOR_KNOBS: dict[str, tuple[str | None, str]] = {
    "mount_pitch_deg": (None, "mount_pitch_deg"),
    "mount_roll_deg": (None, "mount_roll_deg"),
    "detection_threshold": (None, "detection_threshold"),
    "drop_rate": (None, "drop_rate"),
    "intensity_noise": (None, "intensity_noise"),
    "intensity_scale": ("receiver", "scale"),
    "intensity_dark": ("receiver", "dark"),
    "intensity_knee": ("receiver", "knee"),
    "incidence_weight": ("receiver", "incidence_weight"),
    "falloff_start": ("receiver", "falloff_start"),
    "falloff_length": ("receiver", "falloff_length"),
    "gain_spread": ("receiver", "gain_spread"),
    "offset_mean": ("receiver", "offset_mean"),
    "offset_spread": ("receiver", "offset_spread"),
    "specular_cos": ("dropouts", "specular_cos"),
    "beam_loss_spread": ("dropouts", "beam_loss_spread"),
    "azimuth_gaps": ("dropouts", "azimuth_gaps"),
}


class RealismConfig(BaseModel):
    """Ranges a generated frame's ground and sensor are drawn from.

    Every ``*_range`` is (low, high), drawn uniformly per scene from its seed; equal bounds fix
    the value. Sensor ranges left ``None`` keep the sensor's own value (the preset's, KITTI's
    by default).

    Attributes:
        terrain: Draw a terrain for generated scenes; ``False``: flat ground.
        grade_range: Longitudinal slope at the ego vehicle (urban streets: within ±5 %).
        grade_change_range: Change of grade per 100 m (vertical curves; KITTI training 000002
            lies on a crest whose grade falls by ~4 % per 100 m).
        cross_slope_range: Slope of the whole terrain across the road.
        camber_range: Road crown cross-fall (design guidance: 1–3 %, typically 2–2.5 %).
        sidewalk_slope_range: Sidewalks' fall towards the road (~2 %).
        undulation_range: Amplitude of gentle waves in the ground, metres.
        undulation_wavelength_range: Their wavelength, metres.
        ramps: Dropped kerbs at zebra crossings and driveways.
        clean_sensor: Render with the idealised receiver and return model of earlier versions
            (linear intensity, no quantisation, calibration differences or extra losses).
        calibration: ``"fixed"``: every frame from one sensor (the sensor's calibration seed);
            ``"per_frame"``: each frame's lasers calibrated anew from the frame's seed.
        mount_pitch_deg_range: The sensor's pitch against the road (nose down > 0): the road
            under KITTI's car rises ahead by 0.3–1.1 % in the sensor frame (a plane fitted to
            the road 4–15 m around the car in training 000000–000002: 0.17–0.64°).
        mount_roll_deg_range: Its roll against the road.
        detection_threshold_range … azimuth_gaps_range: the other sensor knobs of
            :data:`SENSOR_KNOBS`.

    Example:
        >>> RealismConfig.randomised().gain_spread_range
        (0.06, 0.2)
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    terrain: bool = True
    grade_range: Range = (-0.05, 0.05)
    grade_change_range: Range = (-0.05, 0.05)
    cross_slope_range: Range = (-0.01, 0.01)
    camber_range: Range = (0.01, 0.03)
    sidewalk_slope_range: Range = (0.01, 0.025)
    undulation_range: Range = (0.0, 0.04)
    undulation_wavelength_range: Range = (20.0, 80.0)
    ramps: bool = True
    clean_sensor: bool = False
    calibration: str = "fixed"
    mount_pitch_deg_range: Range | None = (0.15, 0.65)
    mount_roll_deg_range: Range | None = (-0.3, 0.3)
    detection_threshold_range: Range | None = None
    drop_rate_range: Range | None = None
    intensity_noise_range: Range | None = None
    intensity_scale_range: Range | None = None
    intensity_dark_range: Range | None = None
    intensity_knee_range: Range | None = None
    incidence_weight_range: Range | None = None
    falloff_start_range: Range | None = None
    falloff_length_range: Range | None = None
    gain_spread_range: Range | None = None
    offset_mean_range: Range | None = None
    offset_spread_range: Range | None = None
    specular_cos_range: Range | None = None
    beam_loss_spread_range: Range | None = None
    azimuth_gaps_range: Range | None = None

    @field_validator("calibration")
    @classmethod
    def _calibration_mode(cls, value: str) -> str:
        if value not in ("fixed", "per_frame"):
            raise ValueError("calibration must be 'fixed' or 'per_frame'")
        return value

    @field_validator("*")
    @classmethod
    def _ordered(cls, value: Any) -> Any:
        if isinstance(value, tuple) and len(value) == 2 and value[0] > value[1]:
            raise ValueError(f"a range must be (low, high), got {value}")
        return value

    @staticmethod
    def off() -> RealismConfig:
        """Flat ground and the idealised sensor: the world of lidarfuzz before 0.2."""
        return RealismConfig(terrain=False, ramps=False, clean_sensor=True, mount_pitch_deg_range=None,
                             mount_roll_deg_range=None)

    @staticmethod
    def randomised() -> RealismConfig:
        """Broad ranges for domain randomisation: the ground as by default, and every frame from
        a differently calibrated and mounted sensor with its own receiver and losses."""
        return RealismConfig(
            calibration="per_frame",
            grade_range=(-0.07, 0.07), grade_change_range=(-0.07, 0.07), cross_slope_range=(-0.02, 0.02),
            camber_range=(0.0, 0.035), undulation_range=(0.0, 0.06),
            mount_pitch_deg_range=(-1.0, 1.0), mount_roll_deg_range=(-0.6, 0.6),
            detection_threshold_range=(0.25, 0.55), drop_rate_range=(0.003, 0.03),
            intensity_noise_range=(0.015, 0.05), intensity_scale_range=(0.3, 0.55),
            intensity_dark_range=(0.015, 0.05), intensity_knee_range=(0.05, 0.15),
            incidence_weight_range=(0.1, 0.6), falloff_start_range=(10.0, 30.0), falloff_length_range=(12.0, 35.0),
            gain_spread_range=(0.06, 0.2), offset_mean_range=(-0.06, 0.01), offset_spread_range=(0.0, 0.04),
            specular_cos_range=(0.2, 0.6), beam_loss_spread_range=(0.0, 1.0), azimuth_gaps_range=(0.0, 2.0),
        )

    # ------------------------------------------------------------------ sampling
    def sample_terrain(self, rng: np.random.Generator) -> dict[str, Any]:
        """A terrain description (the fields of :class:`~lidarfuzz.sim.spec.Terrain`, without
        ramps: those follow the layout). Always draws the same numbers, so the layout of a
        scene does not depend on these settings."""
        keys = ("grade", "grade_change", "cross_slope", "camber", "sidewalk_slope", "undulation",
                "undulation_wavelength")
        draws = rng.random(len(keys) + 1)
        if not self.terrain:
            return {}
        out: dict[str, Any] = {}
        for key, u in zip(keys, draws, strict=False):
            lo, hi = getattr(self, f"{key}_range")
            out[key] = round(float(lo + (hi - lo) * u), 4)
        out["undulation_phase"] = round(float(draws[-1] * 2 * np.pi), 4)
        return out

    def sample_sensor(self, sensor: LidarSensor, rng: np.random.Generator) -> LidarSensor:
        """``sensor`` with the drawn receiver and loss settings (itself when nothing is drawn).
        Always draws the same numbers, whatever is set."""
        draws = rng.random(len(SENSOR_KNOBS))
        seed = int(rng.integers(0, 2**31 - 1))
        if self.clean_sensor:
            sensor = clean_sensor(sensor)
        update: dict[str, Any] = {}
        sections: dict[str, dict[str, Any]] = {}
        for (knob, (section, name)), u in zip(SENSOR_KNOBS.items(), draws, strict=True):
            bounds = getattr(self, f"{knob}_range")
            if bounds is None:
                continue
            value = round(float(bounds[0] + (bounds[1] - bounds[0]) * u), 4)
            if section is None:
                update[name] = value
            else:
                sections.setdefault(section, {})[name] = value
        if self.calibration == "per_frame":
            sections.setdefault("receiver", {})["calibration_seed"] = seed
        if not update and not sections:
            return sensor
        for section, values in sections.items():
            update[section] = {**getattr(sensor, section).model_dump(), **values}
        return sensor_with(sensor, **update)


def real_intensities(scene: Scene) -> Scene:
    """``scene`` with its intensities mapped by rank onto the distribution of real KITTI scans.

    The order of the readings is kept: the lowest :data:`KITTI_ZERO_SHARE` of them read 0, the
    rest follow :data:`KITTI_NONZERO_DECILES` (linear between deciles). For frames whose
    intensity statistics should look like a real sensor's whatever the simulator's receiver
    produced (tests and benchmarks that compare with real frames); points, boxes and the rest
    of the scene are left alone.

    Example:
        >>> from lidarfuzz.scene.points import PointCloud
        >>> cloud = PointCloud(np.c_[np.zeros((100, 3)), np.arange(100.0)])
        >>> mapped = real_intensities(Scene(cloud)).points.intensity
        >>> int((mapped == 0).sum()), float(mapped.max()) <= 0.99
        (9, True)
    """
    values = scene.points.intensity.astype(np.float64)
    order = np.argsort(np.argsort(values, kind="stable"), kind="stable")
    rank: NDArray[np.float64] = (order + 0.5) / len(values)
    mapped = np.where(rank < KITTI_ZERO_SHARE, 0.0,
                      np.interp((rank - KITTI_ZERO_SHARE) / (1 - KITTI_ZERO_SHARE), np.linspace(0, 1, 11),
                                KITTI_NONZERO_DECILES))
    return scene.with_points(scene.points.with_channel("intensity", mapped.astype(np.float32)))


__all__ = ["KITTI_NONZERO_DECILES", "KITTI_ZERO_SHARE", "SENSOR_KNOBS", "Range", "RealismConfig", "real_intensities"]
