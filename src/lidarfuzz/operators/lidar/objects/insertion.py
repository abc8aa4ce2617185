"""Objects inserted from a library built from data, occlusion handled both ways."""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from lidarfuzz.operators.base import Config, Operator, Params, Relation, uniform
from lidarfuzz.operators.lidar.common import relabel_in_image
from lidarfuzz.operators.lidar.objects.corruptions import _to_box_frame
from lidarfuzz.operators.lidar.objects.support import (
    F64,
    POINTS_BOXES,
    Range,
    _clutter,
    _draw_count,
    _footprint_free,
    _intensity_scale,
    _local_ground,
    _object_points,
    _occlude,
    _on_roi,
    _Pts,
    _rotation_z,
    _rows,
    _wedge_of,
)
from lidarfuzz.scene.boxes import Boxes3D, wrap_angle
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.scene.semantics import OBJECT_SEMANTIC, SEMANTIC_ID


def _cache_dir() -> Path:
    return Path(os.environ.get("LIDARFUZZ_CACHE") or Path.home() / ".cache" / "lidarfuzz")


@dataclass(frozen=True)
class ObjectLibrary:
    """Labelled objects cut out of real or simulated frames, for insertion.

    Each entry holds its points in the box frame (centred, heading along +x), intensity
    normalised to [0, 1], with the class, box size, the source's range and observation angle
    (heading minus the azimuth of the centre: which side faced the sensor), the box bottom's
    height above the local ground, the source sensor's angular resolution and a source id
    ``frame_id:track_id``. Saved and loaded as one ``.npz``.

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
        ``$LIDARFUZZ_CACHE/object_library_sim_v1.npz`` (default cache: ``~/.cache/lidarfuzz``)."""
        path = _cache_dir() / "object_library_sim_v1.npz"
        if path.exists():
            return _load_cached(str(path))
        from lidarfuzz.sim import GenerationConfig, render_frames

        library = cls.from_scenes(list(render_frames(GenerationConfig(frames=4, seed=11))))
        with contextlib.suppress(OSError):  # a read-only home: the library is rebuilt next time
            library.save(path)
        return library

    def fingerprint(self) -> str:
        return hashlib.sha1(self.sources.tobytes() + self.points.tobytes()).hexdigest()[:12]


_LIBRARIES: dict[str, ObjectLibrary] = {}


def _load_cached(path: str) -> ObjectLibrary:
    key = f"{path}:{os.stat(path).st_mtime_ns}"
    if key not in _LIBRARIES:
        _LIBRARIES[key] = ObjectLibrary.load(path)
    return _LIBRARIES[key]


# =========================================================================== insertion
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
    count_range: Range = Field((1, 1), description="objects inserted")
    classes: tuple[str, ...] | None = Field(None, description="only library entries of these classes")
    distance_ratio_range: Range = Field((0.8, 1.25), description="new range / the entry's source range")
    azimuth_range: Range = Field((-180.0, 180.0), description="azimuths of the new positions, degrees")
    attempts: int = Field(40, ge=1, description="positions tried per object before giving up")


class ObjectInsertionParams(Params):
    insertions: tuple[Insertion, ...]
    library: str = Field(description="fingerprint of the library the entries come from")

    def is_identity(self) -> bool:
        return not self.insertions


class ObjectInsertion(Operator[Scene, ObjectInsertionConfig, ObjectInsertionParams]):
    """Objects that were not there: entries of an :class:`ObjectLibrary` (cut out of labelled
    frames) placed on free ground. The new position is on the drivable area when the frame has
    an ROI map, at a range near the entry's source range (so its point density is plausible),
    with the heading that shows the sensor the same side as in the source; the box sits at the
    local ground height. Occlusion both ways with the range-image z-buffer: background points
    behind the object are removed, and so are the object's points behind nearer returns; of
    several object points in one beam and firing only the nearest is kept (a denser source is
    thinned to the frame's resolution). New points get the ring and time of their beam and
    azimuth, ``instance`` = a new track id and ``label`` = the class's semantic id when those
    channels exist; intensity is rescaled to the frame's scale. The box label is added with
    alpha and 2D box projected through the calibration, occlusion unknown. Existing points
    elsewhere, boxes, calibration and map stay.

    The library is the config's ``library`` path, or a small one built from simulated frames at
    first use and cached (see :meth:`ObjectLibrary.default`); a library can also be passed to
    the constructor (``ObjectInsertion(library=path)`` keeps ``spec()`` replayable)."""

    name = "object_insertion"
    aliases = ("OBJ_INSERT",)
    family = "object"
    relation = Relation.DEGRADING
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

    def sample(self, rng: np.random.Generator, sample: Scene) -> ObjectInsertionParams:
        count = _draw_count(rng, self.config.count_range)
        if count == 0:
            return ObjectInsertionParams(insertions=(), library="")
        library = self.library
        entries = np.arange(len(library))
        if self.config.classes is not None:
            entries = entries[np.isin(library.classes, list(self.config.classes))]
        inserted: list[Insertion] = []
        if count and len(entries):
            boxes = sample.boxes
            ids = np.concatenate([boxes.track_ids, sample.points.channel("instance").astype(np.int64)
                                  if sample.points.has("instance") and len(sample.points) else []])
            next_id = int(ids.max(initial=-1)) + 1
            placed: list[F64] = []
            for _ in range(count):
                found = self._place(rng, sample, entries, placed, next_id)
                if found is not None:
                    inserted.append(found)
                    placed.append(self._box(found))
                    next_id += 1
        return ObjectInsertionParams(insertions=tuple(inserted), library=library.fingerprint())

    def _box(self, insertion: Insertion) -> F64:
        return np.array([*insertion.center, *self.library.sizes[insertion.entry], insertion.yaw])

    def _place(self, rng: np.random.Generator, sample: Scene, entries: NDArray[np.intp], placed: list[F64],
               track_id: int) -> Insertion | None:
        library, pts = self.library, _Pts(sample.points.xyz)
        others = Boxes3D.from_array(np.array(placed).reshape(-1, 7), ["Car"] * len(placed))
        occupied = Boxes3D.concat([sample.boxes, others])
        lo, hi = np.deg2rad(self.config.azimuth_range)
        for _ in range(self.config.attempts):
            entry = int(rng.choice(entries))
            distance = library.ranges[entry] * uniform(rng, self.config.distance_ratio_range)
            azimuth = uniform(rng, (float(lo), float(hi)))
            yaw = float(wrap_angle(library.views[entry] + azimuth))
            box = np.array([distance * np.cos(azimuth), distance * np.sin(azimuth), 0.0, *library.sizes[entry], yaw])
            if not _on_roi(sample, box) or not _footprint_free(occupied, box, skip=-1, margin=0.3):
                continue
            ground = _local_ground(pts, box, free=True)
            box[2] = float(ground.height(box[None, :2])[0]) + library.ground_offsets[entry] + box[5] / 2
            if _clutter(pts, box, ground, np.zeros(0, np.intp)) > 3:
                continue
            return Insertion(entry=entry, source=str(library.sources[entry]), center=tuple(float(v) for v in box[:3]),  # type: ignore[arg-type]
                             yaw=yaw, track_id=track_id)
        return None

    def apply(self, sample: Scene, params: ObjectInsertionParams) -> Scene:
        if params.is_identity():
            return sample
        library = self.library
        if params.library != library.fingerprint():
            raise ValueError(f"{self.name}: params were drawn from object library {params.library}, "
                             f"this operator has {library.fingerprint()} (configure the same library path)")
        cloud, boxes = sample.points, sample.boxes
        scale = _intensity_scale(cloud)
        channels = cloud.channels
        for ins in params.insertions:
            if not (0 <= ins.entry < len(library)) or library.sources[ins.entry] != ins.source:
                raise ValueError(f"{self.name}: library entry {ins.entry} is not {ins.source!r}")
            local = library.entry_points(ins.entry).astype(np.float64)
            new_xyz = local[:, :3] @ _rotation_z(ins.yaw).T + np.asarray(ins.center)
            steps = library.angular_steps[ins.entry]
            ratio = library.ranges[ins.entry] / max(float(np.hypot(*ins.center[:2])), 1e-3)
            occlusion = _occlude(cloud, _Pts(cloud.xyz), new_xyz, ratio, (float(steps[0]), float(steps[1])))
            data = np.zeros((len(new_xyz), len(channels)), np.float32)
            data[:, :3] = new_xyz
            data[:, 3] = local[:, 3] * scale
            if cloud.has("ring"):
                data[:, cloud.index("ring")] = occlusion.ring
            if cloud.has("time"):
                data[:, cloud.index("time")] = occlusion.time if occlusion.time is not None else 0.0
            if cloud.has("label"):
                semantic = OBJECT_SEMANTIC.get(str(library.classes[ins.entry]))
                data[:, cloud.index("label")] = SEMANTIC_ID.get(semantic, 0) if semantic else 0
            if cloud.has("instance"):
                data[:, cloud.index("instance")] = ins.track_id
            cloud = PointCloud(np.concatenate([_rows(cloud.data, occlusion.keep_background),
                                               _rows(data, occlusion.keep_new)]),
                               channels)
            added = Boxes3D.from_array(self._box(ins)[None], [str(library.classes[ins.entry])],
                                       track_ids=[ins.track_id], occlusion=[-1])
            added = relabel_in_image(added, sample.calib)
            if sample.calib is not None and np.isnan(added.truncation[0]):
                added = added.replace(truncation=[0.0])
            boxes = Boxes3D.concat([boxes, added])
        return sample.replace(points=cloud, boxes=boxes)

    def spec(self) -> dict[str, Any]:
        if self._in_memory and self.config.library is None:
            raise ValueError(f"{self.name}: an operator built from an in-memory library cannot be rebuilt from its "
                             "spec; save the library and pass its path as library=...")
        return super().spec()
