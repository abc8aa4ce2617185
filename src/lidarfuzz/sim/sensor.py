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
"""

from __future__ import annotations

import json
from functools import cached_property
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from lidarfuzz.errors import DataFormatError, validation_error


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
        drop_rate: Probability that a return is lost at random.
        detection_threshold: Minimum return signal (reflectivity · √cos(incidence) ·
            (100 m / range)²); weaker returns (dark surfaces far away, grazing angles)
            are lost, as on a real receiver.
        intensity_noise: Standard deviation of the additive intensity noise.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = "custom"
    elevations_deg: tuple[float, ...] = Field(min_length=1)
    columns: int = Field(gt=0, le=100_000)
    max_range: float = Field(gt=0)
    min_range: float = Field(default=0.9, ge=0)
    mount_height: float = 1.73
    rotation_hz: float = Field(default=10.0, gt=0)
    range_noise: float = Field(default=0.02, ge=0)
    drop_rate: float = Field(default=0.01, ge=0, le=1)
    detection_threshold: float = Field(default=0.05, ge=0)
    intensity_noise: float = Field(default=0.01, ge=0)

    @field_validator("elevations_deg")
    @classmethod
    def _elevations_in_range(cls, value: tuple[float, ...]) -> tuple[float, ...]:
        if any(not -90.0 < e < 90.0 for e in value):
            raise ValueError("every elevation must lie strictly between -90 and 90 degrees")
        return value

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
        """Unit ray directions in the sensor frame, shape (columns, beams, 3), in firing order."""
        az = self.column_azimuths[:, None]
        el = self.ring_elevations[None, :]
        cos_el = np.cos(el)
        out = np.empty((self.columns, self.beams, 3))
        out[..., 0] = cos_el * np.cos(az)
        out[..., 1] = cos_el * np.sin(az)
        out[..., 2] = np.broadcast_to(np.sin(el), (self.columns, self.beams))
        return out

    def column_of_azimuth(self, azimuth: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Fractional column index at which the head points at ``azimuth`` (radians)."""
        turns = np.mod(np.pi - np.asarray(azimuth, dtype=np.float64), 2.0 * np.pi) / (2.0 * np.pi)
        return turns * self.columns

    def time_of_azimuth(self, azimuth: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Firing time (relative to the frame timestamp) at which the head points at ``azimuth``."""
        return (self.column_of_azimuth(azimuth) / self.columns - 0.5) * self.period


def _hdl64e_elevations() -> tuple[float, ...]:
    # Two blocks of 32 lasers: the upper block is denser (≈1/3°) than the lower (≈1/2°).
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.8, 32)
    return tuple(round(float(e), 4) for e in np.concatenate([upper, lower]))


SENSOR_PRESETS: dict[str, LidarSensor] = {
    "HDL-64E": LidarSensor(name="HDL-64E", elevations_deg=_hdl64e_elevations(), columns=2083, max_range=120.0),
    "HDL-32E": LidarSensor(name="HDL-32E", elevations_deg=tuple(np.round(np.linspace(10.67, -30.67, 32), 4)),
                           columns=2250, max_range=100.0),
    "VLP-16": LidarSensor(name="VLP-16", elevations_deg=tuple(np.linspace(15.0, -15.0, 16)), columns=1800,
                          max_range=100.0, range_noise=0.03),
    "OS1-64": LidarSensor(name="OS1-64", elevations_deg=tuple(np.round(np.linspace(22.5, -22.5, 64), 4)),
                          columns=1024, max_range=120.0, range_noise=0.03),
}
DEFAULT_SENSOR = "HDL-64E"


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
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise DataFormatError(path, f"cannot read sensor description: {exc}") from None
    if not isinstance(raw, dict):
        raise DataFormatError(path, "a sensor description must be a mapping of fields such as preset, "
                              "elevations_deg, columns, max_range, mount_height (see docs/simulator.md)")
    return _sensor_from_mapping(raw, source=path)


def _sensor_from_mapping(raw: dict[str, Any], source: Path | None) -> LidarSensor:
    raw = dict(raw)
    base: dict[str, Any] = {}
    preset = raw.pop("preset", None)
    if preset is not None:
        base = load_sensor(str(preset)).model_dump()
    base.update(raw)
    try:
        return LidarSensor.model_validate(base)
    except ValidationError as exc:
        raise validation_error(source or Path("<sensor>"), exc) from None


def sensor_summary(sensor: LidarSensor) -> dict[str, Any]:
    """JSON-able description stored with generated data."""
    return json.loads(sensor.model_dump_json())
