"""The classic LiDAR obstacle-perception pipeline, in the stages of Apollo's:

1. **HD-map ROI filter** — points on the drivable area plus a margin (:mod:`.roi`);
2. **ground removal** — RANSAC plane or grid lowest point (:mod:`.ground`);
3. **clustering** — BEV grid components or Euclidean (:mod:`.cluster`);
4. **MinBox** — L-shape or minimum-area rectangle, completed to a class prior (:mod:`.boxes`);
5. **classification** — rules on size (:mod:`.classify`);
6. **score** — from the number of points and the classification margin.

Readable numpy, deterministic (RANSAC draws from a seeded generator), and configurable
(:class:`~lidarfuzz.suts.classic.config.ClassicConfig`). Each stage is a method, so the
bug-zoo variants (:mod:`lidarfuzz.suts.bugzoo`) override exactly one.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import iou_bev
from lidarfuzz.scene.scene import Scene
from lidarfuzz.suts.base import SystemUnderTest, validate_detections
from lidarfuzz.suts.classic.boxes import Footprint, box_from_footprint, end_on, fit_footprint, long_axis_first
from lidarfuzz.suts.classic.classify import PRIORS, Measurement, classify
from lidarfuzz.suts.classic.cluster import euclidean_clusters, grid_clusters, split_clusters
from lidarfuzz.suts.classic.config import ClassicConfig
from lidarfuzz.suts.classic.ground import height_above_grid, height_above_plane, ransac_plane
from lidarfuzz.suts.classic.roi import roi_mask


@dataclass
class StageTimes:
    """Seconds spent in each stage of the last call (for the benchmark)."""

    seconds: dict[str, float] = field(default_factory=dict)

    def add(self, stage: str, start: float) -> float:
        now = time.perf_counter()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - start
        return now


class ClassicPipeline(SystemUnderTest[Scene, Boxes3D]):
    """Apollo-style obstacle perception: ROI filter, ground removal, clustering, MinBox, rules."""

    name = "classic"
    version = "1"

    def __init__(self, config: ClassicConfig | None = None, **fields: Any) -> None:
        if config is not None and fields:
            raise TypeError("pass a config or fields, not both")
        self.settings = config if config is not None else ClassicConfig(**fields)
        self.times = StageTimes()

    def config(self) -> dict[str, Any]:
        return self.settings.model_dump(mode="json")

    def validate(self, output: Boxes3D) -> str | None:
        """Outputs of the declared classes, and ``Unknown`` as well with ``report_unknown``."""
        classes = self.classes
        if self.settings.report_unknown and classes is not None:
            classes = (*classes, "Unknown")
        return validate_detections(output, classes)

    # -- stages ---------------------------------------------------------------------------
    def points_xyzi(self, scene: Scene) -> NDArray[np.float32]:
        """The N×4 ``x, y, z, intensity`` the pipeline works on."""
        return np.ascontiguousarray(scene.points.data[:, :4], dtype=np.float32)

    def roi_filter(self, scene: Scene, points: NDArray[np.float32]) -> NDArray[np.bool_]:
        cfg = self.settings
        keep = np.hypot(points[:, 0], points[:, 1]) <= cfg.max_range
        if cfg.use_roi and scene.roi is not None:
            near = np.flatnonzero(keep)
            keep[near] = roi_mask(points[near, :2], scene.roi, cfg.roi_margin, cfg.roi_cell)
        return keep

    def ground_height(self, points: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Height of each point above the ground model, and the plane used for box bottoms."""
        cfg = self.settings
        plane = ransac_plane(
            points[:, :3], iterations=cfg.ransac_iterations, threshold=cfg.ground_threshold,
            sample=cfg.ransac_sample, max_tilt_deg=cfg.ransac_max_tilt_deg, seed=cfg.seed,
        )
        if cfg.ground == "grid":
            return height_above_grid(points[:, :3], cfg.grid_cell), plane
        return height_above_plane(points[:, :3], plane), plane

    def cluster(self, points: NDArray[np.float32]) -> list[NDArray[np.int64]]:
        cfg = self.settings
        if cfg.cluster == "euclidean":
            labels = euclidean_clusters(points[:, :3], cfg.cluster_radius)
        else:
            labels = grid_clusters(points[:, :2], cfg.cluster_cell)
        return split_clusters(labels, cfg.min_points, cfg.max_points)

    def measure(self, points: NDArray[np.float32], height: NDArray[np.float64]) -> tuple[Measurement, Footprint]:
        cfg = self.settings
        fp = long_axis_first(fit_footprint(points[:, :2].astype(np.float64), cfg.box, cfg.angle_step_deg))
        top = float(height.max())
        upper = points[height > 0.67 * top, :2].astype(np.float64)
        axis = np.array([np.cos(fp.angle), np.sin(fp.angle)])
        top_length = float(np.ptp(upper @ axis)) if len(upper) else 0.0
        extent = fp.extent
        m = Measurement(float(extent[0]), float(extent[1]), top, len(points), top_length, end_on(fp))
        return m, fp

    def merged(self, m: Measurement) -> bool:
        """A footprint too wide or long for any class, but not a building: worth splitting."""
        return self.settings.split_cell > 0 and (m.width > 2.4 or m.length > 5.8 or m.height > 2.0) and m.length < 25.0

    def classify(self, m: Measurement, points: NDArray[np.float32]) -> tuple[str, float]:
        return classify(m)

    def build_box(
        self, points: NDArray[np.float32], height: NDArray[np.float64], cls: str, m: Measurement, fp: Footprint
    ) -> NDArray[np.float64]:
        # bottom: the ground under the cluster (its lowest point minus its height above ground)
        z_bottom = float(np.min(points[:, 2] - height))
        z_top = float(points[:, 2].max())
        prior = PRIORS.get(cls) if self.settings.complete_to_prior else None
        # a car showing a side no longer than a car is wide, squarely to the sensor, shows its rear or front
        width_seen = cls == "Car" and m.end_on and m.length <= 2.3
        return box_from_footprint(fp, z_bottom, z_top, prior, width_seen)

    def score(self, m: Measurement, margin: float) -> float:
        """More points and a squarer fit to the class rule: more confidence (in [0, 1])."""
        return float(np.clip((1.0 - np.exp(-m.points / 30.0)) * (0.6 + 0.4 * np.clip(margin, 0.0, 1.0)), 0.0, 1.0))

    def merge_fragments(self, points: NDArray[np.float32], height: NDArray[np.float64],
                        rows: list[NDArray[np.float64]], labels: list[str], scores: list[float],
                        members: list[NDArray[np.int64]]) -> None:
        """Join an object the grid cut in two (a car's bumper and its roof, with the glass between
        them returning nothing): two boxes of one class overlapping by ``merge_iou`` in bird's-eye
        view become one when their points together still fit that class. In place."""
        threshold = self.settings.merge_iou
        if threshold <= 0 or len(rows) < 2:
            return
        refused: set[tuple[int, int]] = set()  # pairs (by member size and first index) that do not fit
        while True:
            iou = iou_bev(np.array(rows), np.array(rows))
            np.fill_diagonal(iou, 0.0)
            same = np.array(labels)[:, None] == np.array(labels)[None, :]
            order = np.argsort(-(iou * same), axis=None)
            for flat in order:
                i, j = divmod(int(flat), len(rows))
                if iou[i, j] * same[i, j] < threshold:
                    return
                key = (int(members[i][0]), int(members[j][0]))
                if i >= j or key in refused:
                    continue
                index = np.concatenate([members[i], members[j]])
                m, fp = self.measure(points[index], height[index])
                cls, margin = self.classify(m, points[index])
                if cls != labels[i]:
                    refused.add(key)
                    continue
                rows[i] = self.build_box(points[index], height[index], cls, m, fp)
                scores[i], members[i] = self.score(m, margin), index
                for bucket in (rows, labels, scores, members):
                    del bucket[j]
                break
            else:
                return

    # -- the whole -----------------------------------------------------------------------
    def detect(self, sample: Scene) -> Boxes3D:
        cfg = self.settings
        times = self.times = StageTimes()
        t = time.perf_counter()
        points = self.points_xyzi(sample)
        points = points[self.roi_filter(sample, points)]
        t = times.add("roi", t)
        if len(points) < 3:
            return Boxes3D.empty()
        height, _plane = self.ground_height(points)
        obstacle = (height > cfg.ground_threshold) & (height < cfg.max_object_height)
        points, height = points[obstacle], height[obstacle]
        t = times.add("ground", t)
        clusters = self.cluster(points)
        t = times.add("cluster", t)
        rows: list[NDArray[np.float64]] = []
        labels: list[str] = []
        scores: list[float] = []
        members: list[NDArray[np.int64]] = []
        queue = [(index, True) for index in clusters]
        while queue:
            index, may_split = queue.pop(0)
            cluster_points, cluster_height = points[index], height[index]
            m, fp = self.measure(cluster_points, cluster_height)
            cls, margin = self.classify(m, cluster_points)
            if cls not in PRIORS:
                if may_split and self.merged(m):
                    # objects standing close together: separate them on a finer grid
                    parts = split_clusters(grid_clusters(cluster_points[:, :2], cfg.split_cell), cfg.min_points,
                                           cfg.max_points)
                    if len(parts) > 1:
                        queue.extend((index[part], False) for part in parts)
                        continue
                if not cfg.report_unknown:
                    continue
            score = self.score(m, margin)
            if score < cfg.min_score:
                continue
            rows.append(self.build_box(cluster_points, cluster_height, cls, m, fp))
            labels.append(cls)
            scores.append(score)
            members.append(index)
        self.merge_fragments(points, height, rows, labels, scores, members)
        times.add("boxes", t)
        if not rows:
            return Boxes3D.empty()
        return Boxes3D.from_array(np.array(rows), labels, scores=scores)
