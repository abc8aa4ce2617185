"""Objects translated, rotated or scaled with their boxes, occlusion recomputed."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from lidarfuzz.operators.base import NonNegativeRange, Operator, Params, PositiveRange, Relation, draw_seed, uniform
from lidarfuzz.operators.lidar.common import relabel_in_image
from lidarfuzz.operators.lidar.objects.support import (
    F64,
    POINTS_BOXES,
    ObjectChoiceConfig,
    _check_objects,
    _choose_objects,
    _clutter,
    _draw_count,
    _footprint_free,
    _Ground,
    _ground_infill,
    _local_ground,
    _object_points,
    _occlude,
    _on_roi,
    _Pts,
    _rotation_z,
    _stack_rows,
)
from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


def _splice_box(scene: Scene, i: int, new_box: F64) -> Boxes3D:
    """The frame's boxes with box ``i`` given a new geometry (alpha, 2D box and truncation
    re-derived from the camera as the simulator labels a box, occlusion unknown); every other
    box is kept exactly."""
    boxes = scene.boxes
    one = boxes.select([i])
    one = one.with_geometry(centers=new_box[None, :3], sizes=new_box[None, 3:6], yaw=new_box[None, 6])
    one = relabel_in_image(one, scene.calib).replace(occlusion=[-1])
    fields = {}
    for name in ("centers", "sizes", "yaw", "truncation", "occlusion", "alpha", "bbox2d"):
        values = np.array(getattr(boxes, name))
        values[i] = getattr(one, name)[0]
        fields[name] = values
    return boxes.replace(**fields)


def _move_points(cloud: PointCloud, pts: _Pts, old: NDArray[np.intp], new_xyz: F64, fill: PointCloud,
                 range_ratio: float) -> PointCloud:
    """The frame with points ``old`` replaced by ``new_xyz`` (their other channels kept; ring and
    time follow where they land), ``fill`` added, and occlusion recomputed both ways relative to
    where the frame observed the object (see :func:`_occlude`: a zero move changes nothing)."""
    occlusion = _occlude(cloud, pts, new_xyz, range_ratio, exclude=old, extra=fill,
                         source_xyz=cloud.xyz[old].astype(np.float64))
    keep = occlusion.keep_background
    keep[old] = False
    moved = cloud.data[old].copy()
    moved[:, :3] = new_xyz
    if cloud.has("ring") and np.any(occlusion.ring >= 0) and occlusion.same_row is not None:
        ring = cloud.index("ring")
        moved[:, ring] = np.where(occlusion.same_row, moved[:, ring], occlusion.ring)
    if cloud.has("time") and occlusion.time_shift is not None:
        moved[:, cloud.index("time")] += occlusion.time_shift.astype(np.float32)
    data = _stack_rows((cloud.data, keep[:len(cloud)]), (fill.data, keep[len(cloud):]), (moved, occlusion.keep_new))
    return PointCloud(data, cloud.channels)


class ObjectMoveParams(Params):
    object: int = Field(description="index into the frame's boxes; −1: nothing moved")
    track_id: int
    fill_ground: bool
    seed: int


class _ObjectMove:
    """Shared apply of the three object transforms: the subclass maps points and the box."""

    name: ClassVar[str]

    def _map(self, xyz: F64, box: F64, params: Any) -> tuple[F64, F64]:
        raise NotImplementedError

    def _moved(self, sample: Scene, params: Any) -> Scene:
        i = params.object
        _check_objects(self.name, sample, [i], [params.track_id])
        cloud, box = sample.points, sample.boxes.as_array()[i]
        pts = _Pts.of(cloud)
        ground = _local_ground(pts, box)
        own = _object_points(pts, box, ground, cloud, params.track_id)
        new_xyz, new_box = self._map(cloud.xyz[own].astype(np.float64), box, params)
        fill = PointCloud.empty(cloud.channels)
        if params.fill_ground:
            fill = _ground_infill(cloud, own, box, ground, np.random.default_rng(params.seed))
        old_range, new_range = float(np.hypot(*box[:2])), float(np.hypot(*new_box[:2]))
        points = _move_points(cloud, pts, own, new_xyz, fill, old_range / max(new_range, 1e-3))
        return sample.replace(points=points, boxes=_splice_box(sample, i, new_box))

    @staticmethod
    def _free(sample: Scene, pts: _Pts, i: int, new_box: F64, ground: _Ground, own: NDArray[np.intp]) -> bool:
        return _footprint_free(sample.boxes, new_box, skip=i) and _clutter(pts, new_box, ground, own) <= 3

    def _fits_in_place(self, sample: Scene, pts: _Pts, arr: F64, i: int, params: Any) -> bool:
        """Whether object ``i``, transformed about its own place by ``params``, is free there."""
        ground = _local_ground(pts, arr[i])
        own = _object_points(pts, arr[i], ground, sample.points, int(sample.boxes.track_ids[i]))
        new_box = self._map(np.zeros((0, 3)), arr[i], params)[1]  # type: ignore[attr-defined]
        return self._free(sample, pts, i, new_box, ground, own)

    def _search(self, rng: np.random.Generator, sample: Scene, none: Any,
                propose: Callable[[int, _Pts, F64, int], Any]) -> Any:
        """Draw one object and try destinations until ``propose(index, points, boxes, seed)`` returns
        params (a free one) or the attempts run out (``none``: the identity)."""
        config = self.config  # type: ignore[attr-defined]
        count = min(_draw_count(rng, config.count_range), 1)
        candidates = _choose_objects(rng, sample, config, len(sample.boxes) if count else 0)
        if not candidates:
            return none
        order = rng.permutation(candidates)
        pts, arr = _Pts.of(sample.points), sample.boxes.as_array()
        seed = draw_seed(rng)
        for attempt in range(config.attempts):
            params = propose(int(order[attempt % len(order)]), pts, arr, seed)
            if params is not None:
                return params
        return none


# -- translation
class ObjectTranslateConfig(ObjectChoiceConfig):
    distance_range: NonNegativeRange = Field((1.0, 1.0), description="distance moved in the ground plane, metres")
    fill_ground: bool = Field(True, description="re-cast the vacated rays onto the local ground")
    attempts: int = Field(40, ge=1, description="destinations tried before giving up (identity)")


class ObjectTranslateParams(ObjectMoveParams):
    offset: tuple[float, float, float] = Field(description="dx, dy in the ground plane; dz follows the ground")

    def is_identity(self) -> bool:
        return self.object < 0 or self.offset == (0.0, 0.0, 0.0)


class ObjectTranslate(_ObjectMove, Operator[Scene, ObjectTranslateConfig, ObjectTranslateParams]):
    """One object displaced on the ground (a car parked a little further on, a pedestrian a step
    aside; the three object transforms move one object per mutant, ``count_range`` (0, 0) being
    the identity): its points and box move by (dx, dy) in a random direction, plus dz so the box keeps
    its height above the local ground. The destination is free: no other box within 20 cm, no
    other object's or structure's points above the ground inside it, and, when the frame has an
    ROI map, an object on the drivable area stays wholly on it while one off it (a pedestrian on
    the pavement) stays off it. Occlusion is recomputed with the range-image z-buffer: points the
    object now hides are removed, and so are its own points now behind something nearer, both
    relative to where the frame observed the object (a move of nothing changes nothing, a tiny
    one keeps over 99 % of its points on real scans; see ``_occlude``); the vacated rays are
    re-cast onto the ground (``fill_ground``). A moved point keeps its ring while it stays on its
    beam's row and takes the row's otherwise; its time shifts with the head's sweep from its old
    column to its new one. Not a global transform: other boxes, calibration and map stay; the
    moved box is re-labelled from the camera (alpha, 2D box, truncation), occlusion unknown."""

    name = "object_translate"
    aliases = ("OBJ_SHIFT",)
    family = "object"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "an object moved by 0.5 m keeps its points and stays at almost the same range"
    targets = POINTS_BOXES
    ConfigModel = ObjectTranslateConfig
    ParamsModel = ObjectTranslateParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"distance_range": (d, d)} for s, d in
                            [(1, 0.5), (2, 1.0), (3, 2.0), (4, 3.5), (5, 5.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectTranslateParams:
        none = ObjectTranslateParams(object=-1, track_id=-1, offset=(0.0, 0.0, 0.0),
                                     fill_ground=self.config.fill_ground, seed=0)

        def propose(i: int, pts: _Pts, arr: F64, seed: int) -> ObjectTranslateParams | None:
            box = arr[i]
            distance, theta = uniform(rng, self.config.distance_range), float(rng.uniform(-np.pi, np.pi))
            new_box = box.copy()
            new_box[:2] += distance * np.array([np.cos(theta), np.sin(theta)])
            here, there = _local_ground(pts, box), _local_ground(pts, new_box)
            new_box[2] += float(there.height(new_box[None, :2])[0] - here.height(box[None, :2])[0])
            if sample.roi is not None:
                on_road = bool(sample.roi.contains_xy(box[None, :2])[0])
                if (_on_roi(sample, new_box) if on_road else sample.roi.contains_xy(new_box[None, :2])[0]) != on_road:
                    return None
            own = _object_points(pts, box, here, sample.points, int(sample.boxes.track_ids[i]))
            if not self._free(sample, pts, i, new_box, there, own):
                return None
            offset = tuple(float(v) for v in new_box[:3] - box[:3])
            return ObjectTranslateParams(object=i, track_id=int(sample.boxes.track_ids[i]), offset=offset,  # type: ignore[arg-type]
                                         fill_ground=self.config.fill_ground, seed=seed)

        return self._search(rng, sample, none, propose)  # type: ignore[no-any-return]

    def _map(self, xyz: F64, box: F64, params: ObjectTranslateParams) -> tuple[F64, F64]:
        offset = np.asarray(params.offset, np.float64)
        new_box = box.copy()
        new_box[:3] += offset
        return xyz + offset, new_box

    def apply(self, sample: Scene, params: ObjectTranslateParams) -> Scene:
        return sample if params.is_identity() else self._moved(sample, params)


# -- rotation
class ObjectRotateConfig(ObjectChoiceConfig):
    angle_range: NonNegativeRange = Field((10.0, 10.0), description="rotation magnitude about the box's axis, degrees")
    both_directions: bool = Field(True, description="draw the sign too")
    fill_ground: bool = Field(True, description="re-cast the vacated rays onto the local ground")
    attempts: int = Field(20, ge=1, description="draws tried before giving up (identity)")


class ObjectRotateParams(ObjectMoveParams):
    angle: float = Field(description="degrees, counter-clockwise about the box's vertical axis")

    def is_identity(self) -> bool:
        return self.object < 0 or self.angle == 0


class ObjectRotate(_ObjectMove, Operator[Scene, ObjectRotateConfig, ObjectRotateParams]):
    """One object turned on the spot (a car at another heading): its points rotate about the
    box's vertical axis and the box's heading changes by the same angle. The turned footprint
    must be free (see ``object_translate``); occlusion is recomputed with the range-image
    z-buffer and the vacated rays are re-cast onto the ground. Other boxes, calibration and map
    stay; the turned box is re-labelled from the camera (alpha, 2D box, truncation), occlusion
    unknown."""

    name = "object_rotate"
    aliases = ("OBJ_ROTATE",)
    family = "object"
    relation = Relation.DEGRADING
    harmless_up_to = 1
    harmless_because = "an object turned by 5 degrees keeps its points"
    targets = POINTS_BOXES
    ConfigModel = ObjectRotateConfig
    ParamsModel = ObjectRotateParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"angle_range": (a, a)} for s, a in
                            [(1, 5.0), (2, 15.0), (3, 30.0), (4, 60.0), (5, 90.0)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectRotateParams:
        none = ObjectRotateParams(object=-1, track_id=-1, angle=0.0, fill_ground=self.config.fill_ground, seed=0)

        def propose(i: int, pts: _Pts, arr: F64, seed: int) -> ObjectRotateParams | None:
            angle = uniform(rng, self.config.angle_range)
            if self.config.both_directions and rng.random() < 0.5:
                angle = -angle
            params = ObjectRotateParams(object=i, track_id=int(sample.boxes.track_ids[i]), angle=angle,
                                        fill_ground=self.config.fill_ground, seed=seed)
            return params if self._fits_in_place(sample, pts, arr, i, params) else None

        return self._search(rng, sample, none, propose)  # type: ignore[no-any-return]

    def _map(self, xyz: F64, box: F64, params: ObjectRotateParams) -> tuple[F64, F64]:
        angle = np.deg2rad(params.angle)
        new_box = box.copy()
        new_box[6] = float(wrap_angle(box[6] + angle))
        return (xyz - box[:3]) @ _rotation_z(angle).T + box[:3], new_box

    def apply(self, sample: Scene, params: ObjectRotateParams) -> Scene:
        return sample if params.is_identity() else self._moved(sample, params)


# -- scaling
class ObjectScaleConfig(ObjectChoiceConfig):
    factor_range: PositiveRange = Field((0.9, 1.1), description="scale factor about the box's bottom centre")
    fill_ground: bool = Field(True, description="re-cast the vacated rays onto the local ground")
    attempts: int = Field(20, ge=1, description="draws tried before giving up (identity)")


class ObjectScaleParams(ObjectMoveParams):
    factor: float = Field(gt=0)

    def is_identity(self) -> bool:
        return self.object < 0 or self.factor == 1.0


class ObjectScale(_ObjectMove, Operator[Scene, ObjectScaleConfig, ObjectScaleParams]):
    """One object of another size (a bigger car, a smaller child): its points scale about the
    box's bottom centre, so it stays on the ground, and the box's length, width and height scale
    by the same factor. A grown footprint must be free (see ``object_translate``); occlusion is
    recomputed with the range-image z-buffer. Other boxes, calibration and map stay; the scaled
    box is re-labelled from the camera (alpha, 2D box, truncation), occlusion unknown."""

    name = "object_scale"
    aliases = ("OBJ_SCALE",)
    family = "object"
    relation = Relation.DEGRADING
    harmless_up_to = 0
    harmless_because = "a resized object may leave its class's sizes"
    targets = POINTS_BOXES
    ConfigModel = ObjectScaleConfig
    ParamsModel = ObjectScaleParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"factor_range": (1 - f, 1 + f)} for s, f in
                            [(1, 0.05), (2, 0.1), (3, 0.15), (4, 0.2), (5, 0.3)]}

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectScaleParams:
        none = ObjectScaleParams(object=-1, track_id=-1, factor=1.0, fill_ground=self.config.fill_ground, seed=0)

        def propose(i: int, pts: _Pts, arr: F64, seed: int) -> ObjectScaleParams | None:
            params = ObjectScaleParams(object=i, track_id=int(sample.boxes.track_ids[i]),
                                       factor=uniform(rng, self.config.factor_range),
                                       fill_ground=self.config.fill_ground, seed=seed)
            if params.factor <= 1.0:  # shrinking in place cannot collide
                return params
            return params if self._fits_in_place(sample, pts, arr, i, params) else None

        return self._search(rng, sample, none, propose)  # type: ignore[no-any-return]

    def _map(self, xyz: F64, box: F64, params: ObjectScaleParams) -> tuple[F64, F64]:
        bottom = box[:3] - np.array([0.0, 0.0, box[5] / 2])
        new_box = box.copy()
        new_box[3:6] *= params.factor
        new_box[2] = bottom[2] + new_box[5] / 2
        return bottom + (xyz - bottom) * params.factor, new_box

    def apply(self, sample: Scene, params: ObjectScaleParams) -> Scene:
        return sample if params.is_identity() else self._moved(sample, params)


# =========================================================================== object library
