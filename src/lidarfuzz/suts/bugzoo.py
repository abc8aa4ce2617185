"""The bug zoo: the classic pipeline with one realistic fault seeded in each variant.

Each variant overrides exactly one stage of :class:`~lidarfuzz.suts.classic.ClassicPipeline`
with a bug a perception engineer could write, stays (mostly) hidden on ordinary frames, and
names the operator and relation expected to reveal it. The zoo is how lidarfuzz's
bug-finding is judged: which operators and relations find which bugs, at what cost.
Variants are registered as SUTs (``classic-bug-<name>``); ``BUGS`` lists them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.scene.roi import RoiMap
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.classic.classify import Measurement
from lidarfuzz.suts.classic.pipeline import ClassicPipeline


@dataclass(frozen=True)
class Reveal:
    """How the bug is expected to show: an operator (spec), and the relation that flags it."""

    operator: str
    severity: int
    relation: str
    why: str


class BuggyPipeline(ClassicPipeline):
    """Base of the variants: the bug's story, what reveals it, where it hides."""

    bug: ClassVar[str]
    reveal: ClassVar[Reveal]
    hidden: ClassVar[str]

    def config(self) -> dict[str, Any]:
        return {**super().config(), "bug": self.bug}


class PercentileIntensityNorm(BuggyPipeline):
    """Intensity is normalised by the 99th percentile of the *whole* cloud before a "dust" filter
    drops clusters whose normalised mean intensity is below 0.2 — so points added far outside
    the ROI change which objects inside it survive (the class of bug Zhou & Sun found in Apollo)."""

    name = "classic-bug-intensity-norm"
    bug = "dust filter on intensity normalised over the whole cloud, outside-ROI points included"
    reveal = Reveal("outside_roi_scatter", 5, "preservation",
                    "points scattered outside the ROI move the percentile; dark cars inside fall below the cut")
    hidden = "bright and mid-grey objects on ordinary frames (very dark cars already fall below the cut)"
    DUST_LEVEL: ClassVar[float] = 0.2

    def points_xyzi(self, scene: Scene) -> NDArray[np.float32]:
        points = super().points_xyzi(scene)
        self._scale = float(np.percentile(points[:, 3], 99)) if len(points) else 1.0
        return points

    def classify(self, m: Measurement, points: NDArray[np.float32]) -> tuple[str, float]:
        if self._scale > 0 and float(points[:, 3].mean()) / self._scale < self.DUST_LEVEL:
            return "Unknown", 0.0
        return super().classify(m, points)


class NearestPointCap(BuggyPipeline):
    """A latency guard keeps at most 116,000 points, the nearest first: an extra point near the
    sensor silently pushes a far, real one out."""

    name = "classic-bug-point-cap"
    bug = "per-frame cap of 116,000 points, nearest kept: the far tail is dropped silently"
    reveal = Reveal("uniform_noise_addition", 5, "preservation",
                    "8 % more points push the cloud over the cap; the farthest objects lose theirs")
    # The simulator's HDL-64E frames hold 103-112k points since they have drop-outs (real KITTI
    # frames 115-127k, where the cap already bites on some): 116k hides the bug on them and 8 %
    # more points (uniform_noise_addition at severity 5) push most of them over.
    hidden = "frames under the cap (simulator HDL-64E frames hold 103-112k points; some real KITTI scans are over it)"
    CAP: ClassVar[int] = 116_000

    def points_xyzi(self, scene: Scene) -> NDArray[np.float32]:
        points = super().points_xyzi(scene)
        if len(points) > self.CAP:
            distance = np.hypot(points[:, 0], points[:, 1])
            points = points[np.sort(np.argpartition(distance, self.CAP)[: self.CAP])]
        return points


class DenseCloudCell(BuggyPipeline):
    """"A dense cloud means close range": above 115,000 points the clustering switches to a
    0.2 m cell — which splits far objects into fragments too small to classify."""

    name = "classic-bug-dense-cell"
    bug = "clustering cell chosen from the cloud's point count (0.2 m above 115k points)"
    reveal = Reveal("outside_roi_scatter", 5, "preservation",
                    "points outside the ROI raise the count past the threshold; far cars inside fragment and vanish")
    # Above the simulator's HDL-64E frames (103-112k points with drop-outs): outside_roi_scatter's
    # 10,000 points at severity 5 cross it from 105k up.
    hidden = "frames with fewer points than the threshold (simulator HDL-64E frames hold 103-112k)"
    DENSE: ClassVar[int] = 115_000

    def points_xyzi(self, scene: Scene) -> NDArray[np.float32]:
        points = super().points_xyzi(scene)
        self._dense = len(points) > self.DENSE
        return points

    def cluster(self, points: NDArray[np.float32]) -> list[NDArray[np.int64]]:
        if not self._dense:
            return super().cluster(points)
        from lidarfuzz.suts.classic.cluster import grid_clusters, split_clusters

        cfg = self.settings
        return split_clusters(grid_clusters(points[:, :2], 0.2), cfg.min_points, cfg.max_points)


class QuarterTurnYaw(BuggyPipeline):
    """The heading is wrapped to a quarter turn — the L-shape search's interval leaking into the
    output — so a box turned more than 45° is reported turned back by 90°, length and width kept."""

    name = "classic-bug-yaw-wrap"
    bug = "heading wrapped to [-π/4, π/4) (the L-shape search's interval) instead of [-π/2, π/2)"
    reveal = Reveal("rotate_z", 5, "equivariance",
                    "rotating the scene by 90–180° turns the street's cars past 45°; their boxes come back turned")
    hidden = "cars within 45° of the x axis (the ego's street), whose heading wraps to itself"

    def build_box(self, points: NDArray[np.float32], height: NDArray[np.float64], cls: str, m: Measurement,
                  fp: Any) -> NDArray[np.float64]:
        box = super().build_box(points, height, cls, m, fp)
        box[6] = (box[6] + np.pi / 4.0) % (np.pi / 2.0) - np.pi / 4.0
        return box


class StaleRoiCache(BuggyPipeline):
    """The ROI raster is cached per frame id — but a mutant keeps its source's id, so a rotated
    or shifted frame is filtered with the source's map."""

    name = "classic-bug-roi-cache"
    bug = "HD-map ROI cached by frame id only (the map's pose is not part of the key)"
    reveal = Reveal("rotate_z", 3, "equivariance",
                    "the rotated frame is cut with the unrotated map: objects off the old road are lost")
    hidden = "every frame seen once, as in ordinary evaluation"

    def roi_filter(self, scene: Scene, points: NDArray[np.float32]) -> NDArray[np.bool_]:
        cache: dict[str, RoiMap | None] = self.__dict__.setdefault("_roi_cache", {})
        return super().roi_filter(scene.replace(roi=cache.setdefault(scene.frame_id, scene.roi)), points)


class FixedGroundHeight(BuggyPipeline):
    """Ground is "everything within the threshold of 1.73 m under the sensor" — KITTI's rig,
    hard-coded — instead of the fitted plane."""

    name = "classic-bug-fixed-ground"
    bug = "ground removed below a hard-coded sensor height instead of a fitted plane"
    reveal = Reveal("height_shift", 5, "equivariance",
                    "raising the cloud lifts the road above the cut: ground clutter joins every object")
    hidden = "nowhere entirely: it already shows where kerbs and verges differ from the road; a flat road at 1.73 m"
    MOUNT: ClassVar[float] = 1.73

    def ground_height(self, points: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return points[:, 2].astype(np.float64) + self.MOUNT, np.array([0.0, 0.0, 1.0, self.MOUNT])


class AbsoluteIntensitySigns(BuggyPipeline):
    """Retro-reflective road signs are rejected by *raw* intensity above 0.6 — a threshold that
    holds for one sensor's calibration only."""

    name = "classic-bug-sign-filter"
    bug = "sign filter on an absolute intensity threshold (0.6) tied to one sensor's calibration"
    reveal = Reveal("intensity_scaling", 5, "preservation",
                    "brighter returns push cars over the threshold: they are taken for signs")
    hidden = "objects under the threshold in the calibration it was tuned on (most; a few bright cars already show)"
    SIGN_LEVEL: ClassVar[float] = 0.6

    def classify(self, m: Measurement, points: NDArray[np.float32]) -> tuple[str, float]:
        if float(points[:, 3].mean()) > self.SIGN_LEVEL:
            return "Unknown", 0.0
        return super().classify(m, points)


class ForwardGroundSeeds(BuggyPipeline):
    """The ground plane is fitted only on points of the corridor ahead (5–30 m forward, ±4 m
    sideways), "because the lane ahead is always road" — until the road is not ahead."""

    name = "classic-bug-forward-ground"
    bug = "ground plane fitted on the corridor ahead only (assumes road in front of the sensor)"
    reveal = Reveal("rotate_z", 5, "equivariance",
                    "turning the scene by 90–180° puts kerbs, verges or cars in the corridor; the plane tilts")
    hidden = "frames with open road ahead of the sensor"

    def ground_height(self, points: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        from lidarfuzz.suts.classic.ground import height_above_plane, ransac_plane

        cfg = self.settings
        ahead = (points[:, 0] > 5.0) & (points[:, 0] < 30.0) & (np.abs(points[:, 1]) < 4.0)
        seeds = points[ahead] if np.count_nonzero(ahead) >= 3 else points
        plane = ransac_plane(
            seeds[:, :3], iterations=cfg.ransac_iterations, threshold=cfg.ground_threshold,
            sample=cfg.ransac_sample, max_tilt_deg=90.0, seed=cfg.seed,
        )
        return height_above_plane(points[:, :3], plane), plane


BUGS: tuple[type[BuggyPipeline], ...] = (
    PercentileIntensityNorm,
    NearestPointCap,
    DenseCloudCell,
    QuarterTurnYaw,
    StaleRoiCache,
    FixedGroundHeight,
    AbsoluteIntensitySigns,
    ForwardGroundSeeds,
)
