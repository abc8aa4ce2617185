"""Objects inserted from a library built from data, occlusion handled both ways."""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from lidarfuzz.operators.base import Config, NonNegativeRange, Operator, Params, PositiveRange, Relation, uniform
from lidarfuzz.operators.lidar.common import relabel_in_image
from lidarfuzz.operators.lidar.objects.corruptions import _to_box_frame
from lidarfuzz.operators.lidar.objects.support import (
    _GROUND_MIN_CELLS,
    F64,
    POINTS_BOXES,
    Range,
    _clutter,
    _draw_count,
    _footprint_free,
    _frozen,
    _Grown,
    _intensity_scale,
    _local_ground,
    _memoised,
    _object_points,
    _occlude,
    _on_roi,
    _Pts,
    _rotation_z,
    _rows,
    _wedge_of,
)
from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.labels import image_boxes, image_coverage, occlusion_level
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.scene.semantics import OBJECT_SEMANTIC, SEMANTIC_ID
from lidarfuzz.settings import settings


def _cache_dir() -> Path:
    return settings().cache


@dataclass(frozen=True)
class ObjectLibrary:
    """Labelled objects cut out of real or simulated frames, for insertion.

    Each entry holds its points in the box frame (centred, heading along +x), intensity
    normalised to [0, 1], with the class, box size, the source's range and observation angle
    (heading minus the azimuth of the centre: which side faced the sensor), the box bottom's
    height above the local ground (a record of the source's labelling and fit, a few centimetres;
    an inserted box's bottom is put on its new place's ground), the source sensor's angular
    resolution and a source id ``frame_id:track_id``. Saved and loaded as one ``.npz``.

    Example:
        >>> library = ObjectLibrary.from_scenes(scenes)          # doctest: +SKIP
        >>> library.save("objects.npz"); ObjectLibrary.load("objects.npz")  # doctest: +SKIP
    """

    points: NDArray[np.float32]  # N×4: x, y, z in the box frame, intensity in [0, 1]
    offsets: NDArray[np.int64]  # M+1
    classes: NDArray[np.str_]
    sizes: F64  # M×3
    ranges: F64
    views: F64
    ground_offsets: F64
    angular_steps: F64  # M×2: elevation and azimuth step of the source sensor, radians
    sources: NDArray[np.str_]

    def __len__(self) -> int:
        return len(self.classes)

    def entry_points(self, i: int) -> NDArray[np.float32]:
        return self.points[self.offsets[i]:self.offsets[i + 1]]

    @property
    def counts(self) -> NDArray[np.int64]:
        return np.diff(self.offsets)

    @classmethod
    def from_scenes(cls, scenes: Sequence[Scene], min_points: int = 20) -> ObjectLibrary:
        """Every labelled object with at least ``min_points`` points above the ground band."""
        parts: list[NDArray[np.float32]] = []
        rows: list[tuple[str, F64, float, float, float, tuple[float, float], str]] = []
        for scene in scenes:
            cloud, arr = scene.points, scene.boxes.as_array()
            if len(cloud) == 0:
                continue
            scale = _intensity_scale(cloud)
            pts = _Pts(cloud.xyz)
            steps: tuple[float, float] | None = None
            for i in np.flatnonzero(scene.boxes.has_geometry):
                box = arr[i]
                ground = _local_ground(pts, box)
                own = _object_points(pts, box, ground, cloud, int(scene.boxes.track_ids[i]))
                if len(own) < min_points:
                    continue
                if steps is None:
                    ring = cloud.channel("ring") if cloud.has("ring") else None
                    wedge = _wedge_of(cloud.xyz, ring, np.arange(len(cloud)), 0.0)
                    steps = (wedge.elev_step, wedge.az_step)
                local = _to_box_frame(cloud.xyz[own], box)
                parts.append(np.column_stack([local, cloud.intensity[own] / scale]).astype(np.float32))
                azimuth = float(np.arctan2(box[1], box[0]))
                bottom = box[2] - box[5] / 2 - float(ground.height(box[None, :2])[0])
                rows.append((str(scene.boxes.labels[i]), box[3:6].copy(), float(np.hypot(box[0], box[1])),
                             float(wrap_angle(box[6] - azimuth)), bottom, steps,
                             f"{scene.frame_id}:{int(scene.boxes.track_ids[i])}"))
        counts = [len(p) for p in parts]
        return cls(
            points=np.concatenate(parts) if parts else np.zeros((0, 4), np.float32),
            offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            classes=np.array([r[0] for r in rows], dtype=np.str_),
            sizes=np.array([r[1] for r in rows], np.float64).reshape(-1, 3),
            ranges=np.array([r[2] for r in rows], np.float64),
            views=np.array([r[3] for r in rows], np.float64),
            ground_offsets=np.array([r[4] for r in rows], np.float64),
            angular_steps=np.array([r[5] for r in rows], np.float64).reshape(-1, 2),
            sources=np.array([r[6] for r in rows], dtype=np.str_),
        )

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the library (an ``.npz``; written to a temporary name, then renamed into place)."""
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        temporary = target.with_name(f".{target.name}.{os.getpid()}.tmp.npz")
        np.savez_compressed(temporary, **{f: getattr(self, f) for f in self.__dataclass_fields__})
        os.replace(temporary, target)
        return target

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> ObjectLibrary:
        try:
            with np.load(Path(path), allow_pickle=False) as data:
                return cls(**{f: data[f] for f in cls.__dataclass_fields__})
        except (OSError, KeyError, ValueError) as exc:
            raise ValueError(f"{path}: not an object library written by ObjectLibrary.save ({exc})") from exc

    @classmethod
    def default(cls) -> ObjectLibrary:
        """A small library built from four simulated HDL-64E frames at first use, cached as
        ``$LIDARFUZZ_CACHE/object_library_sim_v2.npz`` (default cache: ``~/.cache/lidarfuzz``)."""
        path = _cache_dir() / "object_library_sim_v2.npz"
        if path.exists():
            return _load_cached(str(path))
        from lidarfuzz.sim import GenerationConfig, render_frames

        library = cls.from_scenes(list(render_frames(GenerationConfig(frames=4, seed=11))))
        with contextlib.suppress(OSError):  # a read-only home: the library is rebuilt next time
            library.save(path)
        return library

    def fingerprint(self) -> str:
        """A short hash of the entries (their sources and points), computed once per library."""
        cached: str | None = self.__dict__.get("_fingerprint")
        if cached is None:
            cached = hashlib.sha1(self.sources.tobytes() + self.points.tobytes()).hexdigest()[:12]
            object.__setattr__(self, "_fingerprint", cached)  # a library is not changed once built
        return cached


_LIBRARIES: dict[str, ObjectLibrary] = {}


def _load_cached(path: str) -> ObjectLibrary:
    key = f"{path}:{os.stat(path).st_mtime_ns}"
    if key not in _LIBRARIES:
        _LIBRARIES[key] = ObjectLibrary.load(path)
    return _LIBRARIES[key]


# =========================================================================== insertion
#: The most of an inserted object the image may cut off where labels are the camera's: KITTI's
#: easy limit, so the new object counts at every difficulty its size and occlusion allow.
MAX_INSERTED_TRUNCATION = 0.15


class Insertion(BaseModel):
    """One inserted object: which library entry, where, at which heading, with which track id."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    entry: int = Field(ge=0)
    source: str = Field(description="the entry's source id, checked on replay")
    center: tuple[float, float, float]
    yaw: float = Field(description="radians, LiDAR frame")
    track_id: int


class ObjectInsertionConfig(Config):
    library: str | None = Field(None, description="path of an ObjectLibrary .npz; None: the cached simulator one")
    count_range: NonNegativeRange = Field((1, 1), description="objects inserted")
    classes: tuple[str, ...] | None = Field(None, description="only library entries of these classes")
    distance_ratio_range: PositiveRange = Field((0.8, 1.25), description="new range / the entry's source range")
    azimuth_range: Range = Field((-180.0, 180.0), description="azimuths of the new positions, degrees")
    attempts: int = Field(40, ge=1, description="positions tried per object before giving up")
    min_points: int = Field(5, ge=1, description="returns the sensor must get from an inserted object, or the "
                                                 "place is refused")
    in_camera_view: bool | None = Field(None, description="only places the camera sees (at most 15 % cut off by "
                                                          "the image); None: when the frame has a calibration")


class ObjectInsertionParams(Params):
    insertions: tuple[Insertion, ...]
    library: str = Field(description="fingerprint of the library the entries come from")
    reason: str = Field(default="", description="why fewer objects were inserted than drawn ('' when none is missing)")

    def is_identity(self) -> bool:
        return not self.insertions


@dataclass(frozen=True)
class _Inserted:
    """A frame with one more object's points: the grown frame's changes (not the frame itself: this
    is kept in the frame's memo, which must neither keep the frame alive nor hold a copy of it), which
    of the objects inserted before keep their points, how many of this object's points are in, and
    how many returns the sensor got from it alone (visibility's denominator)."""

    dropped: NDArray[np.intp]
    added: NDArray[np.float32]
    pts: _Pts
    keep_added: NDArray[np.bool_]  # over the earlier insertions' rows
    visible: int
    sensed: int

    def grown(self, frame: PointCloud) -> _Grown:
        return _Grown(frame, self.dropped, self.added, self.pts)


def _camera_azimuths(calib: KittiCalibration) -> tuple[float, float]:
    """(lowest, highest) LiDAR azimuth, radians, of the image's left and right edges."""
    height, width = calib.image_shape
    edges = calib.image_to_lidar([[width - 1.0, height / 2], [0.0, height / 2]], [20.0, 20.0])
    right, left = np.arctan2(edges[:, 1], edges[:, 0])
    return float(right), float(left)


def _pick(rng: np.random.Generator, entries: NDArray[np.intp]) -> np.intp:
    """``rng.choice(entries)``: the same draw and the same generator state after it (``choice``
    draws one bounded 64-bit integer), without ``choice``'s argument handling (4 times slower, and a
    place search draws tens of entries)."""
    return entries[rng.integers(0, len(entries), dtype=np.int64)]  # type: ignore[no-any-return]


def _truncation(calib: KittiCalibration, box: F64) -> float:
    """``camera_labels(calib, box).truncation[0]`` without the alpha, and without the 2D box where
    the share of the box in the image already refuses the place (a box with no 2D box is truncated
    by 1, more than any allowed share)."""
    boxes = box[None]
    share, front_pixels = image_coverage(calib, boxes)
    truncation = float(np.clip(1.0 - share, 0.0, 1.0).round(2)[0])
    if truncation > MAX_INSERTED_TRUNCATION:
        return truncation
    return truncation if np.isfinite(image_boxes(calib, boxes, front_pixels)).all() else 1.0


class ObjectInsertion(Operator[Scene, ObjectInsertionConfig, ObjectInsertionParams]):
    """Objects that were not there: entries of an :class:`ObjectLibrary` (cut out of labelled
    frames) placed where the sensor would see them, standing on the local ground.

    Each object is tried at up to ``attempts`` places drawn from the seeded generator: at a range
    near the entry's source range (so its point density is plausible), with the heading that shows
    the sensor the same side as in the source, on the drivable area when the frame has an ROI map,
    30 cm clear of other boxes and of anything standing there (a wall, a hedge, a pole). Its box's
    bottom is put on the ground under the footprint, a plane fitted to the lowest returns around it
    (and in it: nothing stands there; see ``_local_ground``: slopes and camber are followed, walls,
    cars and kerbs rejected); a place where no ground was seen is refused. Where labels are the
    camera's (``in_camera_view``; by default whenever the frame has a calibration, as KITTI's and
    the simulator's labels are), the place must be in the image, at most 15 % of the box cut off.
    Then the sensor must see it: the range-image z-buffer keeps the object's points in the frame's
    beams, scanned columns (a camera-cropped scan has none beside the image) and range, one per beam
    and firing (a denser source is thinned to the frame's resolution), not behind nearer returns;
    fewer than ``min_points`` (default 5: the simulator's rule for a labelled object, and
    OpenPCDet's KITTI database filter) and the place is refused; so is one that would hide an
    earlier inserted object below it. When no place works, nothing more is inserted and ``reason``
    in the params says why (an identity mutant when nothing is, never an object without points).

    Occlusion both ways: background points behind the object are removed. New points get the
    ring and time of their beam and azimuth, ``instance`` = a new track id and ``label`` = the
    class's semantic id when those channels exist; intensity is rescaled to the frame's scale. The
    box label is computed as the simulator's are: truncation, 2D box and alpha from the camera
    (``lidarfuzz.scene.labels``), occlusion from the share of its sensed returns no nearer return
    hides. Existing points elsewhere, boxes, calibration and map stay.

    The library is the config's ``library`` path, or a small one built from simulated frames at
    first use and cached (see :meth:`ObjectLibrary.default`); a library can also be passed to
    the constructor (``ObjectInsertion(library=path)`` keeps ``spec()`` replayable)."""

    name = "object_insertion"
    aliases = ("OBJ_INSERT",)
    family = "object"
    relation = Relation.DEGRADING
    harmless_up_to = 5
    harmless_because = ("inserted objects take no point from the others; an object they hide or crowd loses its "
                        "evidence and is not checked")
    targets = POINTS_BOXES
    ConfigModel = ObjectInsertionConfig
    ParamsModel = ObjectInsertionParams
    IDENTITY: ClassVar = {"count_range": (0, 0)}
    SEVERITIES: ClassVar = {s: {"count_range": (c, c)} for s, c in [(1, 1), (2, 2), (3, 3), (4, 4), (5, 5)]}

    def __init__(self, config: ObjectInsertionConfig | None = None, *, objects: ObjectLibrary | None = None,
                 **fields: Any) -> None:
        super().__init__(config, **fields)
        self._library = objects
        self._in_memory = objects is not None

    @property
    def library(self) -> ObjectLibrary:
        if self._library is None:
            path = self.config.library
            self._library = _load_cached(path) if path is not None else ObjectLibrary.default()
        return self._library

    def _in_view(self, sample: Scene) -> bool:
        wanted = self.config.in_camera_view
        return sample.calib is not None and (wanted is None or wanted)

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectInsertionParams:
        count = _draw_count(rng, self.config.count_range)
        if count == 0:
            return ObjectInsertionParams(insertions=(), library="")
        library = self.library
        entries = np.arange(len(library))
        if self.config.classes is not None:
            entries = entries[np.isin(library.classes, list(self.config.classes))]
        if len(entries) == 0:
            return ObjectInsertionParams(insertions=(), library=library.fingerprint(),
                                         reason=f"the library has no entries of classes {self.config.classes}")
        points = sample.points
        labelled = -1
        if points.has("instance") and len(points):
            labelled = _memoised(_Pts.of(points), "instance_top",
                                 lambda: int(points.channel("instance").astype(np.int64).max()))
        next_id = max(int(np.max(sample.boxes.track_ids, initial=-1)), labelled) + 1
        inserted: list[Insertion] = []
        refused: Counter[str] = Counter()
        # owner: which inserted object each added row is (the frame's own rows are nobody's)
        grown, owner = _Grown.start(points), np.zeros(0, np.int64)
        for _ in range(count):
            found = self._place(rng, sample, grown, owner, entries, inserted, next_id, refused)
            if found is None:
                break  # the next object would meet the same crowded frame
            insertion, step = found
            inserted.append(insertion)
            owner = np.concatenate([owner[step.keep_added], np.full(step.visible, len(inserted) - 1)])
            grown = step.grown(points)
            next_id += 1
        reason = ""
        if len(inserted) < count:
            tried = ", ".join(f"{why} {n}" for why, n in refused.most_common())
            reason = (f"inserted {len(inserted)} of {count}: no place among {self.config.attempts} tried "
                      f"({tried or 'none'})")
        return ObjectInsertionParams(insertions=tuple(inserted), library=library.fingerprint(), reason=reason)

    def _box(self, insertion: Insertion) -> F64:
        return np.array([*insertion.center, *self.library.sizes[insertion.entry], insertion.yaw])

    def _place(self, rng: np.random.Generator, sample: Scene, grown: _Grown, owner: NDArray[np.int64],
               entries: NDArray[np.intp], placed: list[Insertion], track_id: int,
               refused: Counter[str]) -> tuple[Insertion, _Inserted] | None:
        """A place for one more object in ``grown`` (the frame with ``placed`` already inserted,
        ``owner`` the object of each of its added rows), or None; ``refused`` counts why places
        were turned down."""
        library, pts = self.library, _Pts.of(sample.points)
        others = Boxes3D.from_array(np.array([self._box(p) for p in placed]).reshape(-1, 7), ["Car"] * len(placed))
        occupied = Boxes3D.concat([sample.boxes, others])
        lo, hi = np.deg2rad(self._azimuths_deg())
        in_view = self._in_view(sample)
        if in_view:
            right, left = _camera_azimuths(sample.calib)  # type: ignore[arg-type]
            lo, hi = max(lo, right), min(hi, left)
            if lo >= hi:
                refused["azimuth_range outside the camera's view"] += self.config.attempts
                return None
        min_points = self.config.min_points
        for _ in range(self.config.attempts):
            entry, distance, azimuth = self._draw_place(rng, entries, float(lo), float(hi))
            yaw = float(wrap_angle(library.views[entry] + azimuth))
            box = np.array([distance * np.cos(azimuth), distance * np.sin(azimuth), 0.0, *library.sizes[entry], yaw])
            if not _on_roi(sample, box):
                refused["off the drivable area"] += 1
                continue
            if not _footprint_free(occupied, box, skip=-1, margin=0.3):
                refused["on another object"] += 1
                continue
            ground = _local_ground(pts, box, free=True)
            if ground.cells < _GROUND_MIN_CELLS:
                refused["no ground seen there"] += 1
                continue
            box[2] = float(ground.height(box[None, :2])[0]) + box[5] / 2
            clearance = box.copy()
            clearance[3:5] += 2 * 0.3  # the same 30 cm clearance as from other boxes
            if _clutter(pts, clearance, ground, np.zeros(0, np.intp)) > 3:
                refused["something stands there"] += 1
                continue
            if in_view and _truncation(sample.calib, box) > MAX_INSERTED_TRUNCATION:  # type: ignore[arg-type]
                refused["outside the camera's view"] += 1
                continue
            insertion = Insertion(entry=entry, source=str(library.sources[entry]),
                                  center=tuple(float(v) for v in box[:3]), yaw=yaw,  # type: ignore[arg-type]
                                  track_id=track_id)
            step = self._insert(grown, tuple(placed), insertion)
            if step.visible < min_points:
                refused[f"fewer than {min_points} points seen (hidden or out of the sensor's view)"] += 1
                continue
            survivors = np.bincount(owner[step.keep_added], minlength=len(placed))
            if len(placed) and survivors.min() < min_points:
                refused["would hide an object inserted before"] += 1
                continue
            return insertion, step
        return None

    def _azimuths_deg(self) -> tuple[float, float]:
        """The azimuths places are drawn from, degrees (subclasses that place by bearing override it)."""
        return self.config.azimuth_range

    def _draw_place(self, rng: np.random.Generator, entries: NDArray[np.intp], lo: float,
                    hi: float) -> tuple[int, float, float]:
        """One candidate place: a library entry, its range from the sensor (metres, near the entry's
        source range) and its azimuth (radians, in [lo, hi])."""
        entry = int(_pick(rng, entries))
        distance = self.library.ranges[entry] * uniform(rng, self.config.distance_ratio_range)
        return entry, float(distance), uniform(rng, (lo, hi))

    def _insert(self, grown: _Grown, placed: tuple[Insertion, ...], ins: Insertion) -> _Inserted:
        """``grown`` (the frame with ``placed`` inserted) with the entry's points placed as ``ins``
        says, occlusion applied both ways (computed once per frame, library and insertions:
        ``apply`` finds what ``sample`` placed)."""
        key = ("insert", self.library.fingerprint(), placed, ins)
        return _memoised(_Pts.of(grown.frame), key, lambda: self._inserted(grown, ins))

    def _inserted(self, grown: _Grown, ins: Insertion) -> _Inserted:
        library = self.library
        local = library.entry_points(ins.entry).astype(np.float64)
        new_xyz = local[:, :3] @ _rotation_z(ins.yaw).T + np.asarray(ins.center)
        steps = library.angular_steps[ins.entry]
        ratio = library.ranges[ins.entry] / max(float(np.hypot(*ins.center[:2])), 1e-3)
        occlusion = _occlude(grown, grown.pts, new_xyz, ratio, (float(steps[0]), float(steps[1])))
        data = np.zeros((len(new_xyz), len(grown.channels)), np.float32)
        data[:, :3] = new_xyz
        data[:, 3] = local[:, 3] * grown.intensity_scale()
        if grown.has("ring"):
            data[:, grown.index("ring")] = occlusion.ring
        if grown.has("time"):
            data[:, grown.index("time")] = occlusion.time if occlusion.time is not None else 0.0
        if grown.has("label"):
            semantic = OBJECT_SEMANTIC.get(str(library.classes[ins.entry]))
            data[:, grown.index("label")] = SEMANTIC_ID.get(semantic, 0) if semantic else 0
        if grown.has("instance"):
            data[:, grown.index("instance")] = ins.track_id
        after = grown.grow(occlusion.keep_background, _rows(data, occlusion.keep_new))
        return _Inserted(_frozen(after.dropped), _frozen(after.added), after.pts,
                         _frozen(occlusion.keep_background[grown.frame_rows:].copy()),  # not a view of it all
                         int(np.count_nonzero(occlusion.keep_new)), int(np.count_nonzero(occlusion.sensed)))

    def apply(self, sample: Scene, params: ObjectInsertionParams) -> Scene:
        if params.is_identity():
            return sample
        library = self.library
        if params.library != library.fingerprint():
            raise ValueError(f"{self.name}: params were drawn from object library {params.library}, "
                             f"this operator has {library.fingerprint()} (configure the same library path)")
        grown, owner = _Grown.start(sample.points), np.zeros(0, np.int64)  # owner: as in sample
        sensed = []
        for k, ins in enumerate(params.insertions):
            if not (0 <= ins.entry < len(library)) or library.sources[ins.entry] != ins.source:
                raise ValueError(f"{self.name}: library entry {ins.entry} is not {ins.source!r}")
            step = self._insert(grown, params.insertions[:k], ins)
            owner = np.concatenate([owner[step.keep_added], np.full(step.visible, k)])
            grown = step.grown(sample.points)
            sensed.append(step.sensed)
        cloud = grown.cloud()
        # Occlusion as the simulator labels it: the share of the returns the object would give
        # alone that it gives in the scene (later insertions may hide part of earlier ones).
        visible = np.bincount(owner, minlength=len(params.insertions))
        visibility = visible / np.maximum(np.asarray(sensed), 1)
        added = Boxes3D.from_array(np.array([self._box(ins) for ins in params.insertions]),
                                   [str(library.classes[ins.entry]) for ins in params.insertions],
                                   track_ids=[ins.track_id for ins in params.insertions],
                                   occlusion=occlusion_level(visibility))
        added = relabel_in_image(added, sample.calib)
        return sample.replace(points=cloud, boxes=Boxes3D.concat([sample.boxes, added]))

    def spec(self) -> dict[str, Any]:
        if self._in_memory and self.config.library is None:
            raise ValueError(f"{self.name}: an operator built from an in-memory library cannot be rebuilt from its "
                             "spec; save the library and pass its path as library=...")
        return super().spec()
