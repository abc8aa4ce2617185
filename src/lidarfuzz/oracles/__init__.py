"""Oracles: judge a system under test's output (detection metrics, consistency checks)."""

from lidarfuzz.oracles.kitti_eval import KittiEvalResult, KittiFrame, evaluate_kitti

__all__ = ["KittiEvalResult", "KittiFrame", "evaluate_kitti"]
