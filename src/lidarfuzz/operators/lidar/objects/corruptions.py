"""Objects removed (with ground infill) or corrupted in place: cutout, density loss, jitter."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import NonNegativeRange, Operator, Relation, ShareRange, draw_seed, uniform
from lidarfuzz.operators.lidar.objects.support import (
    F64,
    POINTS,
    POINTS_BOXES,
    ObjectChoiceConfig,
    ObjectsParams,
    _check_objects,
    _choose_objects,
    _draw_count,
    _ground_infill,
    _local_ground,
    _object_points,
    _Pts,
    _rotation_z,
    _rows,
)
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


class ObjectRemovalConfig(ObjectChoiceConfig):
    fill_ground: bool = Field(True, description="re-cast the object's rays onto the local ground")


class ObjectRemovalParams(ObjectsParams):
    fill_ground: bool


class ObjectRemoval(Operator[Scene, ObjectRemovalConfig, ObjectRemovalParams]):
    """Objects that are not there: each chosen object's points (inside its box grown by 5 cm,
    above the 15 cm ground band, see the module docs) are deleted and its label removed. With ``fill_ground`` the
    rays that hit the object are re-cast onto the local ground plane (fitted in a 2–12 m ring
    around the box), so the footprint and the near shadow get ground returns at the scan's own
    density (intensity and class drawn from the ring's ground points) instead of a tell-tale hole.

    Params: chosen box indices and track ids, a seed for the infill. Leaves other objects,
    their labels, the ground under the box, calibration and map alone."""

    name = "object_removal"
    aliases = ("OBJ_REMOVE",)
    family = "object"
    relation = Relation.DEGRADING
    harmless_up_to = 5
    harmless_because = "the objects left keep every point; the removed ones have no evidence and are not checked"
    targets = POINTS_BOXES
    ConfigModel = ObjectRemovalConfig
    ParamsModel = ObjectRemovalParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": c} for s, c in
                            [(1, (1, 1)), (2, (1, 2)), (3, (2, 2)), (4, (2, 3)), (5, (3, 4))]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectRemovalParams:
        chosen = _choose_objects(rng, sample, self.config, _draw_count(rng, self.config.count_range))
        return ObjectRemovalParams(objects=tuple(chosen), track_ids=tuple(int(sample.boxes.track_ids[i])
                                                                          for i in chosen),
                                   fill_ground=self.config.fill_ground, seed=draw_seed(rng))

    def apply(self, sample: Scene, params: ObjectRemovalParams) -> Scene:
        if params.is_identity():
            return sample
        _check_objects(self.name, sample, params.objects, params.track_ids)
        cloud, arr = sample.points, sample.boxes.as_array()
        rng = np.random.default_rng(params.seed)
        pts = _Pts.of(cloud)
        drop = np.zeros(len(cloud), bool)
        fills = []
        for i in params.objects:
            ground = _local_ground(pts, arr[i])
            own = _object_points(pts, arr[i], ground, cloud, int(sample.boxes.track_ids[i]))
            drop[own] = True
            if params.fill_ground:
                fills.append(_ground_infill(cloud, own, arr[i], ground, rng))
        keep_boxes = np.ones(len(sample.boxes), bool)
        keep_boxes[list(params.objects)] = False
        points = PointCloud(np.concatenate([_rows(cloud.data, ~drop), *(f.data for f in fills)]), cloud.channels)
        return sample.replace(points=points, boxes=sample.boxes.select(keep_boxes))


# =========================================================================== in-box corruptions
class ObjectCutoutConfig(ObjectChoiceConfig):
    fraction_range: ShareRange = Field((0.3, 0.3), description="sub-box edge as a share of the box's edges")


class ObjectCutoutParams(ObjectsParams):
    centers: tuple[tuple[float, float, float], ...] = Field(description="sub-box centres in each box's frame")
    sizes: tuple[tuple[float, float, float], ...] = Field(description="sub-box l, w, h, metres")


class ObjectCutout(Operator[Scene, ObjectCutoutConfig, ObjectCutoutParams]):
    """Part of an object unseen (a dark or glass panel, a partial occluder that was not
    scanned): the points in one random axis-aligned sub-box of each chosen object's box frame
    are deleted. The sub-box is centred on one of the object's points (so it always cuts
    something), clipped to the box. Labels, other objects and the ground stay."""

    name = "object_cutout"
    aliases = ("OBJ_CUTOUT",)
    family = "object"
    relation = Relation.DEGRADING
    harmless_up_to = 5
    harmless_because = ("objects left whole keep every point; a cut object whose evidence falls below half is not "
                        "checked")
    targets = POINTS
    ConfigModel = ObjectCutoutConfig
    ParamsModel = ObjectCutoutParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": c, "fraction_range": (f, f)} for s, c, f in
                            [(1, (1, 1), 0.2), (2, (1, 1), 0.3), (3, (1, 2), 0.4), (4, (2, 2), 0.5),
                             (5, (2, 3), 0.6)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectCutoutParams:
        chosen = _choose_objects(rng, sample, self.config, _draw_count(rng, self.config.count_range))
        arr, xyz = sample.boxes.as_array(), sample.points.xyz
        pts = _Pts.of(sample.points)
        centers, sizes = [], []
        for i in chosen:
            size = arr[i, 3:6] * uniform(rng, self.config.fraction_range)
            own = _object_points(pts, arr[i], _local_ground(pts, arr[i]), sample.points,
                                 int(sample.boxes.track_ids[i]))
            if len(own):
                local = _to_box_frame(xyz[own[rng.integers(len(own))]][None], arr[i])[0]
            else:
                local = rng.uniform(-0.5, 0.5, 3) * arr[i, 3:6]
            centers.append(tuple(float(v) for v in local))
            sizes.append(tuple(float(v) for v in size))
        return ObjectCutoutParams(objects=tuple(chosen), track_ids=tuple(int(sample.boxes.track_ids[i])
                                                                         for i in chosen),
                                  centers=tuple(centers), sizes=tuple(sizes), seed=draw_seed(rng))  # type: ignore[arg-type]

    def apply(self, sample: Scene, params: ObjectCutoutParams) -> Scene:
        if params.is_identity():
            return sample
        _check_objects(self.name, sample, params.objects, params.track_ids)
        xyz, arr = sample.points.xyz, sample.boxes.as_array()
        pts = _Pts.of(sample.points)
        drop = np.zeros(len(xyz), bool)
        for i, centre, size in zip(params.objects, params.centers, params.sizes, strict=True):
            own = _object_points(pts, arr[i], _local_ground(pts, arr[i]), sample.points,
                                 int(sample.boxes.track_ids[i]))
            local = _to_box_frame(xyz[own], arr[i])
            inside = np.all(np.abs(local - np.asarray(centre)) <= np.asarray(size) / 2, axis=1)
            drop[own[inside]] = True
        return sample.with_points(_rows(sample.points.data, ~drop)) if drop.any() else sample


def _to_box_frame(xyz: NDArray[np.floating], box: F64) -> F64:
    return (np.asarray(xyz, np.float64) - box[:3]) @ _rotation_z(box[6])


class ObjectDensityConfig(ObjectChoiceConfig):
    ratio_range: ShareRange = Field((0.3, 0.3), description="share of each chosen object's points dropped")


class ObjectDensityParams(ObjectsParams):
    ratio: float = Field(ge=0, le=1)


class ObjectDensityLoss(Operator[Scene, ObjectDensityConfig, ObjectDensityParams]):
    """A sparser object (a dark or wet surface, a far-away-looking object): a share of each
    chosen object's points, at least one, is dropped uniformly at random. Labels, other
    objects and the ground under the box stay."""

    name = "object_density_loss"
    aliases = ("OBJ_SPARSE",)
    family = "object"
    relation = Relation.DEGRADING
    harmless_up_to = 5
    harmless_because = ("objects left whole keep every point; a thinned object whose evidence falls below half is not "
                        "checked")
    targets = POINTS
    ConfigModel = ObjectDensityConfig
    ParamsModel = ObjectDensityParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": c, "ratio_range": (r, r)} for s, c, r in
                            [(1, (1, 1), 0.1), (2, (1, 1), 0.25), (3, (1, 2), 0.4), (4, (2, 2), 0.6),
                             (5, (2, 3), 0.8)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectDensityParams:
        chosen = _choose_objects(rng, sample, self.config, _draw_count(rng, self.config.count_range))
        return ObjectDensityParams(objects=tuple(chosen), track_ids=tuple(int(sample.boxes.track_ids[i])
                                                                          for i in chosen),
                                   ratio=uniform(rng, self.config.ratio_range), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: ObjectDensityParams) -> Scene:
        if params.is_identity() or params.ratio == 0:
            return sample
        _check_objects(self.name, sample, params.objects, params.track_ids)
        xyz, arr = sample.points.xyz, sample.boxes.as_array()
        pts = _Pts.of(sample.points)
        rng = np.random.default_rng(params.seed)
        drop = np.zeros(len(xyz), bool)
        for i in params.objects:
            own = _object_points(pts, arr[i], _local_ground(pts, arr[i]), sample.points,
                                 int(sample.boxes.track_ids[i]))
            if len(own):
                count = max(1, round(params.ratio * len(own)))
                drop[rng.choice(own, size=count, replace=False)] = True
        return sample.with_points(_rows(sample.points.data, ~drop)) if drop.any() else sample


class ObjectJitterConfig(ObjectChoiceConfig):
    sigma_range: NonNegativeRange = Field((0.05, 0.05), description="std of the Gaussian offset per axis, metres")


class ObjectJitterParams(ObjectsParams):
    sigma: float = Field(ge=0)


class ObjectJitter(Operator[Scene, ObjectJitterConfig, ObjectJitterParams]):
    """A noisy object (multipath, a vibrating or rain-covered surface): each chosen object's
    points get independent Gaussian offsets of std ``sigma`` on x, y and z. Intensity, the
    other channels, labels, other objects and the ground stay."""

    name = "object_jitter"
    aliases = ("OBJ_JITTER",)
    family = "object"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "2 cm of jitter on one object is within a HDL-64E's ranging noise"
    targets = POINTS
    ConfigModel = ObjectJitterConfig
    ParamsModel = ObjectJitterParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": c, "sigma_range": (g, g)} for s, c, g in
                            [(1, (1, 1), 0.02), (2, (1, 1), 0.05), (3, (1, 2), 0.1), (4, (2, 2), 0.15),
                             (5, (2, 3), 0.25)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectJitterParams:
        chosen = _choose_objects(rng, sample, self.config, _draw_count(rng, self.config.count_range))
        return ObjectJitterParams(objects=tuple(chosen), track_ids=tuple(int(sample.boxes.track_ids[i])
                                                                         for i in chosen),
                                  sigma=uniform(rng, self.config.sigma_range), seed=draw_seed(rng))

    def apply(self, sample: Scene, params: ObjectJitterParams) -> Scene:
        if params.is_identity() or params.sigma == 0:
            return sample
        _check_objects(self.name, sample, params.objects, params.track_ids)
        arr = sample.boxes.as_array()
        pts = _Pts.of(sample.points)
        rng = np.random.default_rng(params.seed)
        own = [_object_points(pts, arr[i], _local_ground(pts, arr[i]), sample.points,
                              int(sample.boxes.track_ids[i])) for i in params.objects]
        index = np.concatenate(own) if own else np.zeros(0, np.intp)
        if len(index) == 0:
            return sample
        data = sample.points.data.copy()
        data[index, :3] += rng.normal(0.0, params.sigma, (len(index), 3)).astype(np.float32)
        return sample.with_points(sample.points.with_data(data))


# =========================================================================== moving one object
