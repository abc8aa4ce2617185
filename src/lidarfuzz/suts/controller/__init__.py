"""The built-in controller: obstacle avoidance (RANSAC ground, elevation classes, a Vector Field
Histogram) and a speed controller with hysteresis and an emergency stop — a system that consumes
logs in order (:mod:`lidarfuzz.suts.sequence`), in the spirit of Neves et al.'s program."""

from lidarfuzz.suts.controller.avoidance import Diagnosis, Mode, ObstacleAvoidance
from lidarfuzz.suts.controller.config import ControllerConfig
from lidarfuzz.suts.controller.vfh import VFH, VfhResult

__all__ = ["VFH", "ControllerConfig", "Diagnosis", "Mode", "ObstacleAvoidance", "VfhResult"]
