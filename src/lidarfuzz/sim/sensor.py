"""Spinning LiDAR sensor models: beam tables, sweep timing, noise and return physics.

A sensor is a frozen pydantic model, so a user-defined beam table is a YAML or JSON
file validated like any other input. Presets describe real sensors:

========== ===== ======================== ========= =======
preset     beams elevation                columns   range
========== ===== ======================== ========= =======
HDL-64E    64    +2° … −24.8° (two blocks) 2083      120 m
HDL-32E    32    +10.67° … −30.67°         2250      100 m
VLP-16     16    +15° … −15°               1800      100 m
OS1-64     64    +22.5° … −22.5°           1024      120 m
========== ===== ======================== ========= =======

Conventions: the LiDAR frame has x forward, y left, z up, origin at the sensor. The
head spins clockwise seen from above (as Velodyne heads do), starting behind the car,
so it faces forward half-way through the sweep; the frame's timestamp is that instant
(when KITTI's cameras are triggered), and each point's ``time`` channel is its firing
time relative to it, in ``[-period/2, period/2)``. Ring 0 is the lowest beam.

The receiver (:class:`Receiver`) and the losses (:class:`Dropouts`) default to what a
real HDL-64E records in KITTI: intensities quantised to 0.01 with 8–10 % of them 0,
64 differently calibrated lasers, dark and far returns reading 0, glossy paint and
glass lost at grazing angles, the lowest beams cut off by the roof rack. The figures
come from KITTI object-benchmark scans (training 000000–000002) and the HDL-64E
datasheet; each constant says which.
"""

from __future__ import annotations

import json
from functools import cached_property, lru_cache
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from lidarfuzz.errors import DataFormatError, validation_error
from lidarfuzz.io.guards import reading
from lidarfuzz.io.textfiles import load_structured


class ShadowSector(BaseModel):
    """Rays the vehicle itself blocks: those fired within ``azimuth_deg`` (from, to; degrees,
    counter-clockwise from ahead, −180…180) at or below ``below_deg`` elevation."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    azimuth_deg: tuple[float, float]
    below_deg: float = Field(ge=-90, le=90)

    @model_validator(mode="after")
    def _ordered(self) -> ShadowSector:
        lo, hi = self.azimuth_deg
        if not -180.0 <= lo < hi <= 180.0:
            raise ValueError("azimuth_deg must be (from, to) with -180 <= from < to <= 180")
        return self


#: Where KITTI's roof rack (cameras ahead of the Velodyne, GPS/IMU mast and rack behind it)
#: hides the ground from the lowest lasers: no return in any of KITTI training 000000–000002
#: in these sectors (counts per 4° of azimuth per laser), e.g. nothing within ±24° behind below −13.5°.
KITTI_ROOF_SHADOW: tuple[ShadowSector, ...] = (
    ShadowSector(azimuth_deg=(-180.0, -156.0), below_deg=-13.5),
    ShadowSector(azimuth_deg=(156.0, 180.0), below_deg=-13.5),
    ShadowSector(azimuth_deg=(-84.0, -64.0), below_deg=-15.5),
    ShadowSector(azimuth_deg=(-4.0, 8.0), below_deg=-20.3),
    ShadowSector(azimuth_deg=(100.0, 112.0), below_deg=-19.3),
)


#: What KITTI's HDL-64E reports for a retro-reflector: the top of its scale.
RETRO_READING = 0.99


class Receiver(BaseModel):
    """How the receiver turns a return into an intensity reading.

    A surface of reflectivity ρ hit at incidence θ at range r scatters back
    ``e = ρ · (1 − incidence_weight + incidence_weight · cos θ) · exp(−r / 400 m)``. The sensor
    reports

        ``reading = gain[beam] · scale · response(e) · falloff(r) + offset[beam] + noise``

    clipped to [0, 1] and rounded down to ``step``, where ``response(e) = 1 − exp(−(e − dark)⁺ /
    knee)`` (``e`` itself when ``knee`` is None). This reproduces what KITTI's HDL-64E records:

    * dark surfaces (black paint, tyres, glass: ρ ≲ 0.03) read 0, and near returns that read 0
      come in runs along a ring (70 % of them have both neighbours at 0 in KITTI training
      000000–000002), i.e. from dark surfaces, not from noise;
    * the reading saturates: the road (ρ ≈ 0.1, hit at grazing angles) reads 0.25–0.35, walls
      and vegetation barely more, and 2–5 % of the returns read above 0.5;
    * the incidence angle matters little (``incidence_weight``): the road far ahead reads as
      bright as the road beside the car;
    * ``falloff(r) = exp(−((r − falloff_start)⁺ / falloff_length)²)`` is the range compensation
      running out: the mean reading is flat to ~25 m and halves by ~45 m, and 50–65 % of the
      returns at 40–60 m and ~90 % at 60–80 m read exactly 0 (they are still returns: the
      point was measured);
    * each laser has its own gain (log-normal, σ = ``gain_spread``) and offset (normal,
      ``offset_mean`` ± ``offset_spread``), drawn from ``calibration_seed``: KITTI's 64 lasers
      read the same road 0.5–1.5× their neighbours' median (σ 10–16 %);
    * retro-reflectors (number plates, traffic signs, lamps' reflectors: reflectivity ≥
      ``retro_reflectivity``) send the pulse back towards the sensor far more strongly than any
      diffuse surface and read the top of the scale, 0.99, at any range: 0.03–0.18 % of the
      returns of KITTI training 000000–000002 read ≥ 0.9 and each frame's maximum is 0.99, while
      its 99th percentile is only 0.58–0.61.

    ``Receiver.clean()`` is the idealised reading of earlier versions: ``e`` itself.
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    scale: float = Field(default=0.45, gt=0, le=10)
    dark: float = Field(default=0.065, ge=0, le=1, description="backscatter that reads 0")
    knee: float | None = Field(default=0.06, gt=0, description="backscatter above dark where the reading "
                                                                "reaches 63 % of scale; None: linear")
    incidence_weight: float = Field(default=0.25, ge=0, le=1)
    falloff_start: float = Field(default=15.0, ge=0)
    falloff_length: float | None = Field(default=20.0, gt=0, description="None: no range fall-off")
    gain_spread: float = Field(default=0.18, ge=0, le=1)
    offset_mean: float = Field(default=-0.07, ge=-0.5, le=0.5)
    offset_spread: float = Field(default=0.06, ge=0, le=0.5)
    step: float = Field(default=0.01, ge=0, le=0.1, description="quantisation step; 0 = continuous")
    calibration_seed: int = Field(default=0, ge=0)
    retro_reflectivity: float | None = Field(default=0.8, gt=0, le=1, description="surfaces at least this "
                                             "reflective are retro-reflectors and read 0.99; None: none are")

    @staticmethod
    def clean() -> Receiver:
        """The idealised receiver: reading = e, no calibration differences, no quantisation."""
        return Receiver(scale=1.0, dark=0.0, knee=None, incidence_weight=0.65, falloff_length=None,
                        gain_spread=0.0, offset_mean=0.0, offset_spread=0.0, step=0.0, retro_reflectivity=None)

    def calibration(self, beams: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Each ring's gain and offset (ring 0 the lowest), fixed by ``calibration_seed``."""
        return _calibration(self, beams)

    def _draw_calibration(self, beams: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        rng = np.random.default_rng(np.random.SeedSequence([self.calibration_seed, beams, 0xCA1B]))
        gain = np.exp(np.clip(rng.standard_normal(beams), -2.5, 2.5) * self.gain_spread).astype(np.float32)
        spread = np.clip(rng.standard_normal(beams), -2.5, 2.5) * self.offset_spread
        offset = (self.offset_mean + spread).astype(np.float32)
        gain.flags.writeable = offset.flags.writeable = False  # shared by every frame (cached)
        return gain, offset

    def read(self, reflectivity: NDArray[np.float32], cos_incidence: NDArray[np.float32],
             distance: NDArray[np.float32], ring: NDArray[np.intp], noise: NDArray[np.float32],
             beams: int) -> NDArray[np.float32]:
        """Intensity readings of returns from surfaces of ``reflectivity`` hit at ``cos_incidence``
        at ``distance`` on ``ring``, with ``noise`` already drawn (its deviation applied); float32
        throughout.

        Each step runs in place on one of two working arrays (a frame reads ~110k returns, and
        a fresh temporary per step cost a fifth of the time); every step is the same float32
        operation on the same operands as the formula reads (a product or sum with its operands
        swapped is the same IEEE result), so the readings are the same bits.
        """
        reflectivity, cos_incidence, distance, noise = (np.asarray(v, np.float32) for v in
                                                        (reflectivity, cos_incidence, distance, noise))
        gain, offset = self.calibration(beams)
        weight = np.float32(self.incidence_weight)
        # scatter = ρ · (1 − w + w · cos θ) · exp(−r / 400)
        reading = weight * cos_incidence
        reading += np.float32(1.0) - weight
        reading *= reflectivity
        work = np.negative(distance)
        work /= np.float32(400.0)
        reading *= np.exp(work, out=work)
        # response: (scatter − dark)⁺, or 1 − exp(−(scatter − dark)⁺ / knee)
        reading -= np.float32(self.dark)
        np.maximum(reading, np.float32(0.0), out=reading)
        if self.knee is not None:
            np.negative(reading, out=reading)
            reading /= np.float32(self.knee)
            np.exp(reading, out=reading)
            np.subtract(np.float32(1.0), reading, out=reading)
        reading *= np.float32(self.scale)
        if self.falloff_length is not None:  # × exp(−((r − start)⁺ / length)²)
            np.subtract(distance, np.float32(self.falloff_start), out=work)
            np.maximum(work, np.float32(0.0), out=work)
            work /= np.float32(self.falloff_length)
            np.square(work, out=work)
            np.negative(work, out=work)
            reading *= np.exp(work, out=work)
        reading *= gain[ring]
        reading += offset[ring]
        reading += noise
        if self.retro_reflectivity is not None:
            reading[reflectivity >= np.float32(self.retro_reflectivity)] = np.float32(RETRO_READING)
        np.clip(reading, 0.0, 1.0, out=reading)
        if self.step > 0:
            # Down to the step, as an integer reading is stored: k / 100 as float32 in KITTI (a
            # float32 division is correctly rounded, so k / 100 is exactly KITTI's value).
            per_unit = round(1.0 / self.step)
            if abs(per_unit * self.step - 1.0) < 1e-9:
                reading *= np.float32(per_unit)
                reading += np.float32(1e-3)
                np.floor(reading, out=reading)
                reading /= np.float32(per_unit)
            else:
                reading /= np.float32(self.step)
                reading += np.float32(1e-3)
                np.floor(reading, out=reading)
                reading *= np.float32(self.step)
        return reading


@lru_cache(maxsize=64)
def _calibration(receiver: Receiver, beams: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    return receiver._draw_calibration(beams)


class Dropouts(BaseModel):
    """Returns a real sensor loses besides weak ones (:attr:`LidarSensor.detection_threshold`)
    and random ones (:attr:`LidarSensor.drop_rate`).

    * **glossy surfaces at grazing angles**: a surface of gloss g (clear-coated paint 0.5,
      glass 1) hit at incidence cos θ < ``specular_cos`` mirrors the beam away and returns with
      probability ``1 − g · (specular_cos − cos θ) / specular_cos`` — car bonnets, roofs and
      flanks seen edge-on lose points, as they do in real scans;
    * **per-beam losses**: each laser's random loss rate is ``drop_rate`` times a log-normal
      factor (σ = ``beam_loss_spread``), fixed by the receiver's calibration seed;
    * **azimuth gaps**: a Poisson number (mean ``azimuth_gaps``) of sectors of
      ``gap_columns`` columns per sweep with no return on any laser (lost packets). KITTI's
      scans show none (0 empty columns in training 000000–000002), hence 0 by default;
    * **the vehicle's shadow**: rays blocked by the car and its roof rack (:class:`ShadowSector`).
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    specular_cos: float = Field(default=0.4, ge=0, le=1)
    beam_loss_spread: float = Field(default=0.5, ge=0, le=3)
    azimuth_gaps: float = Field(default=0.0, ge=0, le=50)
    gap_columns: tuple[int, int] = (2, 12)
    shadow: tuple[ShadowSector, ...] = ()

    @staticmethod
    def none() -> Dropouts:
        """No losses beyond the detection threshold and the random drop rate."""
        return Dropouts(specular_cos=0.0, beam_loss_spread=0.0, azimuth_gaps=0.0, shadow=())

    @field_validator("gap_columns")
    @classmethod
    def _gap_order(cls, value: tuple[int, int]) -> tuple[int, int]:
        if not 1 <= value[0] <= value[1]:
            raise ValueError("gap_columns must be (min, max) with 1 <= min <= max")
        return value


#: Most beams a simulated sensor may have (the largest made have 128).
MAX_BEAMS = 1024
#: Most rays per revolution (beams × columns) simulated: 16 times a 128-beam sensor at 2,048 columns.
MAX_RAYS = 1 << 22


class LidarSensor(BaseModel):
    """A spinning multi-beam LiDAR.

    Attributes:
        name: Display name.
        elevations_deg: One elevation per beam, degrees above the horizontal (any order;
            rings are numbered from the lowest beam up).
        columns: Firings per revolution (azimuth step = 360° / columns).
        max_range: Farthest return, metres.
        min_range: Nearest return (closer hits, e.g. the car's own roof, are discarded).
        mount_height: Sensor height above the ground, metres.
        rotation_hz: Revolutions per second; one frame is one revolution.
        range_noise: Standard deviation of the Gaussian range error, metres.
        drop_rate: Probability that a return is lost at random (the mean over the beams).
        detection_threshold: Minimum return signal (reflectivity · √cos(incidence) ·
            (100 m / range)²); weaker returns (dark surfaces far away, grazing angles)
            are lost, as on a real receiver. 0.4 is the HDL-64E datasheet's: 10 %
            reflectivity (pavement) is seen to 50 m, 80 % (cars, foliage) to 120 m.
        intensity_noise: Standard deviation of the additive intensity noise.
        mount_pitch_deg: The sensor's mounting tilt about its y axis relative to the
            vehicle (positive: nose down, the ground ahead rises in the sensor frame).
        mount_roll_deg: Mounting tilt about its x axis (positive: left side up).
        receiver: The intensity reading (:class:`Receiver`).
        dropouts: Losses of returns (:class:`Dropouts`).
    """

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    name: str = "custom"
    elevations_deg: tuple[float, ...] = Field(min_length=1, max_length=MAX_BEAMS)
    columns: int = Field(gt=0, le=100_000)
    # bounds far beyond any sensor made: a value past them (1e300) overflowed the simulator's arithmetic
    max_range: float = Field(gt=0, le=10_000)
    min_range: float = Field(default=0.9, ge=0, le=10_000)
    mount_height: float = Field(default=1.73, gt=0, le=100)
    rotation_hz: float = Field(default=10.0, ge=0.1, le=1000)
    range_noise: float = Field(default=0.02, ge=0, le=100)
    drop_rate: float = Field(default=0.01, ge=0, le=1)
    detection_threshold: float = Field(default=0.4, ge=0, le=1e9)
    intensity_noise: float = Field(default=0.03, ge=0, le=100)
    mount_pitch_deg: float = Field(default=0.0, ge=-10, le=10)
    mount_roll_deg: float = Field(default=0.0, ge=-10, le=10)
    receiver: Receiver = Field(default_factory=Receiver)
    dropouts: Dropouts = Field(default_factory=Dropouts)

    @field_validator("elevations_deg")
    @classmethod
    def _elevations_in_range(cls, value: tuple[float, ...]) -> tuple[float, ...]:
        if any(not -90.0 < e < 90.0 for e in value):
            raise ValueError("every elevation must lie strictly between -90 and 90 degrees")
        return value

    @model_validator(mode="after")
    def _rays_bounded(self) -> LidarSensor:
        if self.rays > MAX_RAYS:
            raise ValueError(f"{self.beams} beams × {self.columns} columns = {self.rays:,} rays per revolution; "
                             f"at most {MAX_RAYS:,} are simulated")
        return self

    @property
    def beams(self) -> int:
        return len(self.elevations_deg)

    @property
    def rays(self) -> int:
        return self.beams * self.columns

    @property
    def period(self) -> float:
        """Seconds per revolution (one frame)."""
        return 1.0 / self.rotation_hz

    @cached_property
    def ring_elevations(self) -> NDArray[np.float64]:
        """Elevations in radians, sorted so that index = ring (0 = lowest beam)."""
        return np.deg2rad(np.sort(np.asarray(self.elevations_deg, dtype=np.float64)))

    @cached_property
    def column_azimuths(self) -> NDArray[np.float64]:
        """Azimuth of each firing in radians: π (behind) clockwise through 0 (ahead) to −π."""
        return np.pi - 2.0 * np.pi * np.arange(self.columns) / self.columns

    @cached_property
    def column_times(self) -> NDArray[np.float64]:
        """Firing time of each column relative to the frame timestamp (forward-facing instant)."""
        return (np.arange(self.columns) / self.columns - 0.5) * self.period

    @cached_property
    def local_directions(self) -> NDArray[np.float64]:
        """Unit ray directions in the sensor frame, shape (columns, beams, 3), in firing order
        (shared, read-only, by every sensor with the same beam table: each generated frame has
        its own sensor instance, its mounting tilt drawn, but the same beams)."""
        return _local_directions(tuple(float(e) for e in self.ring_elevations), self.columns)

    @cached_property
    def mount_rotation(self) -> NDArray[np.float64]:
        """3×3 rotation from the sensor frame to the vehicle's (its mounting tilt)."""
        p, r = np.deg2rad(self.mount_pitch_deg), np.deg2rad(self.mount_roll_deg)
        pitch = np.array([[np.cos(p), 0.0, np.sin(p)], [0.0, 1.0, 0.0], [-np.sin(p), 0.0, np.cos(p)]])
        roll = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(r), -np.sin(r)], [0.0, np.sin(r), np.cos(r)]])
        return pitch @ roll

    @cached_property
    def shadowed(self) -> NDArray[np.bool_]:
        """Rays (columns × beams, firing order) blocked by the vehicle (:attr:`Dropouts.shadow`)."""
        return _shadowed(tuple(float(e) for e in self.ring_elevations), self.columns, self.dropouts.shadow)

    @cached_property
    def beam_drop_rates(self) -> NDArray[np.float32]:
        """Each ring's random loss rate (:attr:`Dropouts.beam_loss_spread`), averaging ``drop_rate``."""
        spread = self.dropouts.beam_loss_spread
        if not spread or not self.drop_rate:
            return np.full(self.beams, self.drop_rate, np.float32)
        rng = np.random.default_rng(np.random.SeedSequence([self.receiver.calibration_seed, self.beams, 0xD40]))
        factor = np.exp(np.clip(rng.standard_normal(self.beams), -2.5, 2.5) * spread)
        return np.clip(self.drop_rate * factor / factor.mean(), 0.0, 1.0).astype(np.float32)

    def column_of_azimuth(self, azimuth: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Fractional column index at which the head points at ``azimuth`` (radians)."""
        turns = np.mod(np.pi - np.asarray(azimuth, dtype=np.float64), 2.0 * np.pi) / (2.0 * np.pi)
        return turns * self.columns

    def time_of_azimuth(self, azimuth: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Firing time (relative to the frame timestamp) at which the head points at ``azimuth``."""
        return (self.column_of_azimuth(azimuth) / self.columns - 0.5) * self.period


@lru_cache(maxsize=16)
def _local_directions(ring_elevations: tuple[float, ...], columns: int) -> NDArray[np.float64]:
    az = (np.pi - 2.0 * np.pi * np.arange(columns) / columns)[:, None]
    el = np.asarray(ring_elevations)[None, :]
    cos_el = np.cos(el)
    out = np.empty((columns, len(ring_elevations), 3))
    out[..., 0] = cos_el * np.cos(az)
    out[..., 1] = cos_el * np.sin(az)
    out[..., 2] = np.broadcast_to(np.sin(el), (columns, len(ring_elevations)))
    out.flags.writeable = False
    return out


@lru_cache(maxsize=16)
def _shadowed(ring_elevations: tuple[float, ...], columns: int,
              shadow: tuple[ShadowSector, ...]) -> NDArray[np.bool_]:
    out = np.zeros((columns, len(ring_elevations)), bool)
    azimuth = np.rad2deg(np.angle(np.exp(1j * (np.pi - 2.0 * np.pi * np.arange(columns) / columns))))[:, None]
    elevation = np.rad2deg(np.asarray(ring_elevations))[None, :]
    for sector in shadow:
        lo, hi = sector.azimuth_deg
        out |= (azimuth >= lo) & (azimuth <= hi) & (elevation <= sector.below_deg)
    out.flags.writeable = False
    return out


def _hdl64e_elevations() -> tuple[float, ...]:
    # Two blocks of 32 lasers: the upper block is denser (≈1/3°) than the lower (≈1/2°).
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.8, 32)
    return tuple(round(float(e), 4) for e in np.concatenate([upper, lower]))


SENSOR_PRESETS: dict[str, LidarSensor] = {
    "HDL-64E": LidarSensor(name="HDL-64E", elevations_deg=_hdl64e_elevations(), columns=2083, max_range=120.0,
                           dropouts=Dropouts(shadow=KITTI_ROOF_SHADOW)),
    "HDL-32E": LidarSensor(name="HDL-32E", elevations_deg=tuple(np.round(np.linspace(10.67, -30.67, 32), 4)),
                           columns=2250, max_range=100.0),
    "VLP-16": LidarSensor(name="VLP-16", elevations_deg=tuple(np.linspace(15.0, -15.0, 16)), columns=1800,
                          max_range=100.0, range_noise=0.03),
    "OS1-64": LidarSensor(name="OS1-64", elevations_deg=tuple(np.round(np.linspace(22.5, -22.5, 64), 4)),
                          columns=1024, max_range=120.0, range_noise=0.03),
}
DEFAULT_SENSOR = "HDL-64E"


def clean_sensor(sensor: LidarSensor) -> LidarSensor:
    """``sensor`` with the idealised receiver and return model of lidarfuzz before 0.2: a linear
    intensity, no calibration differences or quantisation, a permissive detection threshold
    (0.05), 1 % intensity noise and no losses but the random ones."""
    return sensor_with(sensor, receiver=Receiver.clean(), dropouts=Dropouts.none(), detection_threshold=0.05,
                       intensity_noise=0.01)


def sensor_with(sensor: LidarSensor, **fields: Any) -> LidarSensor:
    """A validated copy of ``sensor`` with some fields replaced (``model_copy`` would keep the
    cached beam tables of the original)."""
    return LidarSensor.model_validate({**sensor.model_dump(), **fields})


def preset_names() -> list[str]:
    return list(SENSOR_PRESETS)


def load_sensor(spec: str | PathLike[str] | LidarSensor | dict[str, Any]) -> LidarSensor:
    """A sensor from a preset name (case-insensitive), a YAML/JSON file, a mapping, or a sensor.

    A file or mapping may name a ``preset`` and override some of its fields::

        preset: HDL-64E
        mount_height: 1.9
        elevations_deg: [2.0, 0.0, -2.0, -4.0]

    Example:
        >>> load_sensor("vlp-16").beams
        16
    """
    if isinstance(spec, LidarSensor):
        return spec
    if isinstance(spec, dict):
        return _sensor_from_mapping(spec, source=None)
    text = str(spec)
    for name, sensor in SENSOR_PRESETS.items():
        if text.lower() == name.lower():
            return sensor
    path = Path(text)
    if not path.exists():
        raise DataFormatError(path, f"is neither a sensor preset ({', '.join(SENSOR_PRESETS)}) nor a file")
    raw = load_structured(path, "a sensor description")
    if not isinstance(raw, dict):
        raise DataFormatError(path, "a sensor description must be a mapping of fields such as preset, "
                              "elevations_deg, columns, max_range, mount_height (see docs/simulator.md)")
    return _sensor_from_mapping(raw, source=path)


def _sensor_from_mapping(raw: dict[str, Any], source: Path | None) -> LidarSensor:
    raw = dict(raw)
    base: dict[str, Any] = {}
    preset = raw.pop("preset", None)
    where = source or Path("<sensor>")
    if preset is not None:
        # a preset's name only: a file naming a file (itself, say) would be read again and again
        known = {name.lower(): sensor for name, sensor in SENSOR_PRESETS.items()}
        if not isinstance(preset, str) or preset.lower() not in known:
            raise DataFormatError(where, f"{preset!r} is not a sensor preset ({', '.join(SENSOR_PRESETS)})",
                                  field="preset")
        base = known[preset.lower()].model_dump()
    base.update(raw)
    with reading(where, "read the sensor description"):  # what pydantic's validators do not turn into errors
        try:
            return LidarSensor.model_validate(base)
        except ValidationError as exc:
            raise validation_error(where, exc) from None


def sensor_summary(sensor: LidarSensor) -> dict[str, Any]:
    """JSON-able description stored with generated data."""
    return json.loads(sensor.model_dump_json())
