"""The classic pipeline's parameters: one frozen model, every field a documented knob."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class ClassicConfig(BaseModel):
    """Parameters of :class:`~lidarfuzz.suts.classic.pipeline.ClassicPipeline` (defaults tuned on
    the simulator's train split)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    # HD-map ROI filter
    use_roi: bool = Field(default=True, description="keep points on the drivable area (plus a margin) if known")
    roi_margin: float = Field(default=3.0, ge=0.0, description="metres added around the drivable area")
    roi_cell: float = Field(default=0.25, gt=0.0, description="raster cell of the ROI lookup (metres)")
    max_range: float = Field(default=70.0, gt=0.0, description="points farther than this (ground plane) are dropped")
    # ground removal
    ground: Literal["ransac", "grid"] = Field(default="ransac", description="ground model")
    ground_threshold: float = Field(default=0.25, gt=0.0, description="height above the ground model still ground (m)")
    ransac_iterations: int = Field(default=60, ge=1)
    ransac_sample: int = Field(default=4000, ge=3, description="points the RANSAC hypotheses are scored on")
    ransac_max_tilt_deg: float = Field(default=10.0, ge=0.0, description="planes steeper than this are rejected")
    grid_cell: float = Field(default=2.0, gt=0.0, description="cell of the grid ground model (m)")
    seed: int = Field(default=0, description="seed of RANSAC's generator (the pipeline is deterministic)")
    max_object_height: float = Field(default=3.0, gt=0.0, description="points higher above ground are ignored (m)")
    # clustering
    cluster: Literal["grid", "euclidean"] = Field(default="grid", description="connected components method")
    cluster_cell: float = Field(default=0.5, gt=0.0, description="BEV cell of grid clustering (m)")
    split_cell: float = Field(
        default=0.2, gt=0.0, description="finer cell re-clustering footprints too big for any class (0 = never)"
    )
    cluster_radius: float = Field(default=0.45, gt=0.0, description="neighbour radius of Euclidean clustering (m)")
    min_points: int = Field(default=8, ge=1, description="smaller clusters are dropped")
    max_points: int = Field(default=30000, ge=1, description="larger clusters (buildings) are dropped")
    # box building
    box: Literal["lshape", "min_area"] = Field(default="lshape", description="MinBox method")
    angle_step_deg: float = Field(default=1.0, gt=0.0, le=15.0, description="heading search step")
    complete_to_prior: bool = Field(default=True, description="grow partly seen boxes to the class's typical size")
    merge_iou: float = Field(
        default=0.2, ge=0.0, le=1.0,
        description="two boxes of one class overlapping this much (BEV IoU) are one object cut in two, joined when "
                    "their points together still fit the class (0 = never)")
    # classification and score
    min_score: float = Field(default=0.05, ge=0.0, le=1.0, description="objects scoring lower are not reported")
    report_unknown: bool = Field(
        default=False, description="also report clusters no class rule fits, as Unknown (Apollo's obstacle "
                                   "perception reports them; off: they are dropped)")
