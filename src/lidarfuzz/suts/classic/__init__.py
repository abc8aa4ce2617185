"""The built-in classic pipeline (Apollo-like): ROI filter, ground removal, clustering, MinBox, rules."""

from lidarfuzz.suts.classic.config import ClassicConfig
from lidarfuzz.suts.classic.pipeline import ClassicPipeline

__all__ = ["ClassicConfig", "ClassicPipeline"]
