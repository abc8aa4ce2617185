"""Generating a labelled data set: many frames rendered in parallel and written in KITTI layout.

Two kinds of data set:

* **independent frames** (the default): frame *i* is its own procedurally generated
  scene, seeded by ``(seed, i)`` — the KITTI object benchmark's shape;
* **a sequence** (``sequence=True``, or a user's scene file): one scene, the ego
  vehicle driving through it at 10 Hz, written as an ordered log with
  ``timestamps.txt``, ``poses.txt`` and ``ego.txt`` (the ego vehicle's speed, yaw rate,
  curvature and steering angle per frame), for log-based testing.

With a camera (``camera=(width, height)``, :mod:`lidarfuzz.sim.camera`), every frame also has
``image_2/NNNNNN.png`` (8-bit RGB of KITTI's camera 2), ``depth_2/NNNNNN.png`` (16-bit z-depth,
metres × 256, 0 where nothing was hit or beyond 255 m) and a row of ``steering.csv``
(``frame_id,steering,speed``: the front-wheel angle in radians, left positive, that brings the
ego vehicle along its route, and its speed in m/s; :mod:`lidarfuzz.sim.steering`); ``calib/``
then describes that image. Independent frames then put their ego vehicle off its lane's centre
(:class:`~lidarfuzz.sim.steering.LaneOffset`), so their labels vary.

Besides the KITTI files, every frame's scene description is saved under ``scenes/``
(render it again with ``lidarfuzz gen --scene``), and ``lidarfuzz_sim.json`` records
the configuration and, once the last frame is written, ``"complete": true`` with
label statistics. Generation is deterministic: the same configuration gives the same
bytes whatever the number of worker processes, and an interrupted run can be
resumed, skipping the frames already on disk.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import sys
import time
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.atomic import write_bytes, write_text
from lidarfuzz.io.kitti import KittiWriter, write_kitti_frame
from lidarfuzz.io.kitti.dataset import EGO_COLUMNS, EGO_FILE
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.image import ImageSample
from lidarfuzz.scene.scene import Scene
from lidarfuzz.sim.generate import SCENE_KINDS, generate_scene
from lidarfuzz.sim.labels import LabelConfig
from lidarfuzz.sim.realism import RealismConfig
from lidarfuzz.sim.render import Renderer
from lidarfuzz.sim.sensor import DEFAULT_SENSOR, load_sensor
from lidarfuzz.sim.spec import SceneSpec
from lidarfuzz.sim.steering import LaneOffset, steering_labels
from lidarfuzz.sim.terrain import WHEELBASE
from lidarfuzz.sim.world import compile_world, ego_labels, trajectory_of

SUMMARY_FILE = "lidarfuzz_sim.json"
STEERING_FILE = "steering.csv"
#: A 16-bit depth PNG holds the z-depth in metres × this (so up to 255.99 m; 0: nothing hit, or farther).
DEPTH_SCALE = 256.0


@dataclass(frozen=True)
class GenerationConfig:
    """What to generate.

    Attributes:
        frames: Number of frames.
        seed: Seeds every scene and every frame's noise.
        scene: A user's scene; its frames form a sequence (time advances by one sweep per frame).
        sensor: Sensor preset or file overriding the scene's (default HDL-64E).
        sequence: One generated scene driven through, instead of independent scenes.
        drive: A generated drive log (implies ``sequence``): the ego vehicle stops, turns at a
            junction and drives on, with road users timed against it (:mod:`lidarfuzz.sim.drive`).
        kind: ``"urban"`` or ``"suburban"``; mixed when ``None``.
        val_fraction: Share of frames (the last ones) listed in ``ImageSets/val.txt``.
        labels: Which objects are labelled and which become DontCare.
        realism: The ranges each generated scene's ground and sensor are drawn from, from
            the scene's seed (:class:`~lidarfuzz.sim.realism.RealismConfig`; by default real
            roads' slopes and camber, and KITTI's receiver). A scene file is rendered as written.
        camera: (width, height) of camera images to render beside the LiDAR frames, with depth
            maps and steering labels; ``None``: LiDAR only (the files of earlier versions, bit for bit).
    """

    frames: int
    seed: int = 0
    scene: SceneSpec | None = None
    sensor: str | None = None
    sequence: bool = False
    kind: str | None = None
    drive: bool = False
    val_fraction: float = 0.5
    labels: LabelConfig = field(default_factory=LabelConfig)
    realism: RealismConfig = field(default_factory=RealismConfig)
    camera: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError("frames must be at least 1")
        if not 0.0 <= self.val_fraction <= 1.0:
            raise ValueError("val_fraction must lie in [0, 1]")
        if self.kind is not None and self.kind not in SCENE_KINDS:
            raise ValueError(f"unknown scene kind {self.kind!r}; choose one of {', '.join(SCENE_KINDS)}")
        if self.sensor is not None:
            load_sensor(self.sensor)  # fail early on a bad name or file
        if self.drive and self.scene is not None:
            raise ValueError("drive: a drive log is generated; it cannot render a scene file")
        if self.camera is not None and (len(self.camera) != 2 or not all(8 <= v <= 8192 for v in self.camera)):
            raise ValueError(f"camera: image size {self.camera} must be (width, height), each 8 … 8192")

    @property
    def is_sequence(self) -> bool:
        return self.sequence or self.drive or self.scene is not None

    def to_json(self) -> dict[str, Any]:
        out = {
            "frames": self.frames, "seed": self.seed, "sequence": self.is_sequence, "kind": self.kind,
            "sensor": self.sensor, "val_fraction": self.val_fraction, "labels": asdict(self.labels),
            "scene": json.loads(self.scene.model_dump_json(by_alias=True)) if self.scene is not None else None,
            "realism": self.realism.model_dump(mode="json"),
        }
        if self.drive:  # only then: the configurations of earlier data sets stay as they were (resume)
            out["drive"] = True
        if self.camera is not None:  # likewise
            out["camera"] = {"width": self.camera[0], "height": self.camera[1]}
        return out

    @property
    def calibration(self) -> KittiCalibration | None:
        """The calibration frames are rendered with: KITTI's, for the camera's image size when
        there is a camera (:func:`~lidarfuzz.sim.camera.camera_calibration`); None: the renderer's default."""
        if self.camera is None:
            return None
        from lidarfuzz.sim.camera import camera_calibration

        return camera_calibration(KittiCalibration.default(), self.camera)


@dataclass(frozen=True)
class FrameResult:
    """What a worker reports of a frame. ``labels`` counts the classes of the label file it
    wrote, in the file's order (empty when it wrote none); a frame ``skipped`` (resumed: on disk
    from an earlier run) reports none, its label file is read at the end."""

    frame_id: str
    timestamp: float | None
    pose: list[list[float]] | None
    points: int
    labels: dict[str, int]
    skipped: bool = False
    steering: float | None = None  # camera data sets: the frame's label (rad) and the ego's speed (m/s)
    speed: float | None = None


@dataclass
class GenerationSummary:
    root: Path
    frames: int
    generated: int
    resumed: int
    seconds: float
    points_per_frame: float
    label_counts: dict[str, int]
    images: int = 0


def frame_id_of(index: int) -> str:
    return f"{index:06d}"


def frame_seed(seed: int, index: int) -> int:
    """The seed of frame ``index``'s scene (independent frames)."""
    return int(np.random.SeedSequence([seed, index, 0xF4A]).generate_state(1)[0])


def sequence_scene(config: GenerationConfig) -> SceneSpec:
    """The one scene of a sequence data set."""
    if config.scene is not None:
        spec = config.scene
        if config.sensor is not None:
            spec = spec.model_copy(update={"sensor": config.sensor})
        return spec
    duration = config.frames * load_sensor(config.sensor or DEFAULT_SENSOR).period
    spec = generate_scene(config.seed, kind=config.kind, duration=duration,  # type: ignore[arg-type]
                          realism=config.realism, drive=config.drive)
    return _with_sensor(config, spec, config.seed)


def ego_file_text(spec: SceneSpec, frames: int) -> str:
    """``ego.txt`` of a sequence: per frame (at its reference time, one sweep apart) the ego
    vehicle's speed, yaw rate, curvature and steering angle (:func:`~lidarfuzz.sim.world.ego_labels`)."""
    ids = [frame_id_of(i) for i in range(frames)]
    times = np.arange(frames, dtype=np.float64) * float(load_sensor(spec.sensor).period)
    rows = ego_labels(trajectory_of(spec.ego, spec.ego.speed), times)
    header = (f"# frame_id {' '.join(EGO_COLUMNS)}: m/s, rad/s, 1/m, rad (left positive; steering = "
              f"atan(wheelbase * curvature), wheelbase {WHEELBASE} m)")
    lines = [f"{frame_id} " + " ".join(f"{round(float(v), 6) + 0.0:.6f}" for v in row)  # no "-0.000000"
             for frame_id, row in zip(ids, rows, strict=True)]
    return "\n".join([header, *lines]) + "\n"


def _frame_scene(config: GenerationConfig, index: int) -> tuple[SceneSpec, SceneSpec]:
    """An independent frame's scene, and its lane: the same scene before a camera data set
    moves the ego vehicle off its lane's centre (:class:`~lidarfuzz.sim.steering.LaneOffset`)."""
    seed = frame_seed(config.seed, index)
    spec = _with_sensor(config, generate_scene(seed, kind=config.kind, realism=config.realism),  # type: ignore[arg-type]
                        seed)
    if config.camera is None:
        return spec, spec
    return LaneOffset.draw(seed).applied(spec), spec


def _with_sensor(config: GenerationConfig, spec: SceneSpec, seed: int) -> SceneSpec:
    """A generated scene's sensor: the configured one, with the receiver and losses drawn from
    ``config.realism`` from the scene's seed (the preset's name kept when nothing is drawn)."""
    base = config.sensor if config.sensor is not None else spec.sensor
    sensor = load_sensor(base)
    drawn = config.realism.sample_sensor(sensor, np.random.default_rng(np.random.SeedSequence([seed, 0x5E4])))
    return spec.model_copy(update={"sensor": base if drawn is sensor else drawn})


_FRAME_FILES = (("velodyne", ".bin"), ("velodyne_extra", ".npz"), ("calib", ".txt"), ("label_2", ".txt"),
                ("roi", ".json"))
_CAMERA_FILES = (("image_2", ".png"), ("depth_2", ".png"))


def _frame_complete(root: Path, frame_id: str, camera: bool = False) -> bool:
    files = _FRAME_FILES + (_CAMERA_FILES if camera else ())
    return all((root / sub / f"{frame_id}{suffix}").is_file() for sub, suffix in files)


@dataclass(frozen=True)
class _Frame:
    """A frame to write: its scene (None when resuming skips it), its renderer, the frame's own
    spec (independent frames) and its lane (the spec before the ego was moved off it)."""

    index: int
    scene: Scene | None
    renderer: Renderer
    spec: SceneSpec | None
    lane: SceneSpec | None
    t_ref: float


def _frames(config: GenerationConfig, indices: list[int], skip: Callable[[str], bool] | None = None,
            threads: int | None = None) -> Iterator[_Frame]:
    """The frames ``indices``, rendered unless ``skip`` says they are on disk already."""
    renderer: Renderer | None = None
    calib = config.calibration
    if config.is_sequence:
        renderer = Renderer(compile_world(sequence_scene(config)), calib, labels=config.labels, threads=threads)
    for index in indices:
        frame_id = frame_id_of(index)
        if renderer is not None and config.is_sequence:
            t_ref = index * renderer.sensor.period
            if skip is not None and skip(frame_id):
                yield _Frame(index, None, renderer, None, None, t_ref)
                continue
            scene = renderer.render(t_ref, frame_id=frame_id, timestamp=t_ref, frame_seed=config.seed)
            yield _Frame(index, scene, renderer, None, None, t_ref)
        else:
            spec, lane = _frame_scene(config, index)
            frame_renderer = Renderer(compile_world(spec), calib, labels=config.labels, threads=threads)
            if skip is not None and skip(frame_id):
                yield _Frame(index, None, frame_renderer, spec, lane, 0.0)
                continue
            yield _Frame(index, frame_renderer.render(0.0, frame_id=frame_id).replace(pose=None), frame_renderer,
                         spec, lane, 0.0)


def render_frames(config: GenerationConfig) -> Iterator[Scene]:
    """The frames ``generate_dataset`` would write, in memory (for tests, notebooks and other tools)."""
    for frame in _frames(config, list(range(config.frames))):
        assert frame.scene is not None
        yield frame.scene


def frame_steering(config: GenerationConfig, frame: _Frame) -> tuple[float, float]:
    """A frame's steering label (rad, left positive) and the ego vehicle's speed (m/s)
    (:func:`~lidarfuzz.sim.steering.steering_labels`)."""
    spec = frame.spec if frame.spec is not None else frame.renderer.world.spec
    steering, speed = steering_labels(spec, np.array([frame.t_ref]), lane=frame.lane)
    return float(steering[0]), float(speed[0])


def render_camera_frames(config: GenerationConfig) -> Iterator[tuple[Scene, ImageSample]]:
    """Each frame with its camera image (``config.camera`` must be set), in memory."""
    from lidarfuzz.sim.camera import CameraRenderer

    if config.camera is None:
        raise ValueError("camera: set an image size to render camera frames")
    camera: CameraRenderer | None = None
    for frame in _frames(config, list(range(config.frames))):
        assert frame.scene is not None
        if camera is None or camera.renderer is not frame.renderer:
            camera = CameraRenderer(frame.renderer, config.camera)
        steering, speed = frame_steering(config, frame)
        yield frame.scene, camera.render(frame.t_ref, frame_id=frame.scene.frame_id, steering=steering,
                                         timestamp=frame.scene.timestamp, metadata={"speed": speed})


def write_camera_frame(root: Path, sample: ImageSample) -> None:
    """``image_2/`` (8-bit RGB PNG) and ``depth_2/`` (16-bit PNG, metres × 256, 0: nothing hit
    or beyond 255 m) of one camera frame."""
    import cv2

    depth = np.asarray(sample.depth, np.float64) * DEPTH_SCALE
    with np.errstate(invalid="ignore"):
        depth = np.where(np.isfinite(depth) & (depth < 65535.5), np.round(depth), 0.0).astype(np.uint16)
    for sub, pixels in (("image_2", np.ascontiguousarray(np.asarray(sample.image)[:, :, ::-1])), ("depth_2", depth)):
        ok, encoded = cv2.imencode(".png", pixels)
        if not ok:
            raise LidarfuzzError(f"{root / sub}: cannot encode frame {sample.frame_id} as PNG")
        write_bytes(root / sub / f"{sample.frame_id}.png", encoded.tobytes(), overwrite=True, durable=False)


def steering_file_text(results: list[FrameResult]) -> str:
    """``steering.csv``: ``frame_id,steering,speed`` per frame (rad, left positive; m/s)."""
    rows = [f"{r.frame_id},{round(float(r.steering or 0.0), 6) + 0.0:.6f},{round(float(r.speed or 0.0), 4) + 0.0:.4f}"
            for r in results]
    return "\n".join(["frame_id,steering,speed", *rows]) + "\n"


def _render_chunk(root: str, config: GenerationConfig, indices: list[int], resume: bool,
                  threads: int | None = None) -> list[FrameResult]:
    """Worker: render and write frames ``indices``; returns what the parent records."""
    from lidarfuzz.sim.camera import CameraRenderer

    out = Path(root)
    results = []
    camera_on = config.camera is not None
    skip = (lambda frame_id: _frame_complete(out, frame_id, camera_on)) if resume else None
    camera: CameraRenderer | None = None
    for frame in _frames(config, indices, skip, threads):
        frame_id, scene, renderer = frame_id_of(frame.index), frame.scene, frame.renderer
        steering, speed = frame_steering(config, frame) if camera_on else (None, None)
        if scene is None:
            t_ref = frame.t_ref if config.is_sequence else None
            pose = renderer.pose_matrix(t_ref).tolist() if t_ref is not None else None
            results.append(FrameResult(frame_id, t_ref, pose, 0, {}, skipped=True, steering=steering, speed=speed))
            continue
        if frame.spec is not None:
            write_text(out / "scenes" / f"{frame_id}.json", frame.spec.to_json(), overwrite=True, durable=False)
        if config.camera is not None:
            if camera is None or camera.renderer is not renderer:
                camera = CameraRenderer(renderer, config.camera)
            write_camera_frame(out, camera.render(frame.t_ref, frame_id=frame_id, steering=steering))
        labelled = write_kitti_frame(out, scene, frame_id, overwrite=True, durable=False, labelled_set=True)
        # One label line per box, in box order, starting with its class (format_labels).
        counts = Counter(str(c) for c in scene.boxes.labels) if labelled else Counter()
        results.append(FrameResult(frame_id, scene.timestamp,
                                   None if scene.pose is None else np.asarray(scene.pose).tolist(),
                                   len(scene.points), dict(counts), steering=steering, speed=speed))
    return results


def _chunks(frames: int, workers: int) -> list[list[int]]:
    size = max(1, min(16, frames // max(1, workers * 4)))
    return [list(range(start, min(start + size, frames))) for start in range(0, frames, size)]


def _pool(workers: int) -> ProcessPoolExecutor:
    # forkserver: children never inherit an Embree/TBB thread pool the parent may have started.
    method = "forkserver" if sys.platform.startswith("linux") else "spawn"
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context(method))


def generate_dataset(
    out: str | PathLike[str],
    config: GenerationConfig,
    *,
    workers: int | None = None,
    overwrite: bool = False,
    resume: bool = False,
    on_frame: Callable[[FrameResult], None] | None = None,
) -> GenerationSummary:
    """Render ``config.frames`` frames into a new KITTI-layout folder ``out``.

    Args:
        out: Destination; must not exist or be empty, unless ``overwrite`` (it is then
            emptied) or ``resume`` (frames already complete are kept).
        config: What to generate.
        workers: Worker processes (default: the number of CPU cores, at most the frame count).
        on_frame: Called in the parent after each frame (for progress).
    """
    root = Path(out)
    started = time.perf_counter()
    summary_path = root / SUMMARY_FILE
    record = {"generator": "lidarfuzz.sim", "version": _version(), "config": config.to_json(), "complete": False}
    if root.exists() and not root.is_dir():
        raise DataFormatError(root, "exists and is not a folder")
    if resume and root.is_dir() and any(root.iterdir()):
        previous = _read_summary(summary_path)
        if previous.get("config") != record["config"]:
            raise LidarfuzzError(f"{root}: was generated with a different configuration; "
                                 f"resume with the same options, or choose a new folder")
        for stray in root.glob("*/.*.tmp"):  # half-written files of a killed run (never renamed into place)
            stray.unlink()
    elif root.is_dir() and any(root.iterdir()):
        if not overwrite:
            raise DataFormatError(root, "folder exists and is not empty; choose a new folder, or pass --overwrite "
                                  "(replaces it) or --resume (finishes an interrupted run)")
        if summary_path.is_file() or (root / "velodyne").is_dir():
            shutil.rmtree(root)
        else:
            raise DataFormatError(root, "is not a data set lidarfuzz generated; refusing to empty it")
    root.mkdir(parents=True, exist_ok=True)
    write_text(summary_path, json.dumps(record, indent=1), overwrite=True)
    if config.is_sequence:
        spec = sequence_scene(config)
        write_text(root / "scene.yaml", spec.to_yaml(), overwrite=True)
        write_text(root / EGO_FILE, ego_file_text(spec, config.frames), overwrite=True)

    workers = max(1, min(workers or os.cpu_count() or 1, config.frames))
    results: dict[str, FrameResult] = {}
    for result in _run(root, config, workers, resume):
        results[result.frame_id] = result
        if on_frame is not None:
            on_frame(result)

    writer = KittiWriter(root, overwrite=True, durable=False)
    for index in range(config.frames):
        r = results[frame_id_of(index)]
        writer.record(r.frame_id, r.timestamp, None if r.pose is None else np.asarray(r.pose), True)
    n_val = round(config.frames * config.val_fraction)
    ids = [frame_id_of(i) for i in range(config.frames)]
    writer.close({"train": ids[: config.frames - n_val], "val": ids[config.frames - n_val:], "trainval": ids})

    label_counts = _count_labels(root, [results[frame_id] for frame_id in ids])
    generated = [r for r in results.values() if not r.skipped]
    images = 0
    if config.camera is not None:
        ordered = [results[frame_id] for frame_id in ids]
        write_text(root / STEERING_FILE, steering_file_text(ordered), overwrite=True)
        images = sum((root / "image_2" / f"{frame_id}.png").is_file() for frame_id in ids)
        labels = np.array([float(r.steering or 0.0) for r in ordered])
        record["camera"] = {"images": images, "size": list(config.camera), "steering": {
            "min": round(float(labels.min()), 6), "max": round(float(labels.max()), 6),
            "mean": round(float(labels.mean()), 6), "std": round(float(labels.std()), 6)}}
    summary = GenerationSummary(
        root=root, frames=config.frames, generated=len(generated), resumed=len(results) - len(generated),
        seconds=time.perf_counter() - started,
        points_per_frame=float(np.mean([r.points for r in generated])) if generated else 0.0,
        label_counts=dict(label_counts), images=images,
    )
    record.update(complete=True, label_counts=dict(label_counts), points_per_frame=round(summary.points_per_frame))
    write_text(summary_path, json.dumps(record, indent=1), overwrite=True)
    return summary


def _run(root: Path, config: GenerationConfig, workers: int, resume: bool) -> Iterator[FrameResult]:
    chunks = _chunks(config.frames, workers)
    if workers == 1:
        for chunk in chunks:
            yield from _render_chunk(str(root), config, chunk, resume)
        return
    threads = max(1, (os.cpu_count() or 1) // workers)  # the cores are shared out between the workers
    with _pool(workers) as pool:
        futures = [pool.submit(_render_chunk, str(root), config, chunk, resume, threads) for chunk in chunks]
        for future in futures:
            yield from future.result()


def _count_labels(root: Path, results: list[FrameResult]) -> Counter[str]:
    """The classes of the frames' label files, in frame order and each file's line order.

    A frame rendered in this run brings the counts of the label file it wrote; only a frame
    resumed from an earlier run has its file read (reading all of them cost ~18 ms per 1,000
    frames at the end of a run).
    """
    counts: Counter[str] = Counter()
    for result in results:
        if not result.skipped:
            counts.update(result.labels)
            continue
        path = root / "label_2" / f"{result.frame_id}.txt"
        if path.is_file():
            counts.update(line.split(" ", 1)[0] for line in path.read_text(encoding="utf-8").splitlines() if line)
    return counts


def _read_summary(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise DataFormatError(path.parent, f"has no {SUMMARY_FILE}: not a data set lidarfuzz generated; "
                              "choose a new folder")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise DataFormatError(path, f"cannot read: {exc}") from None
    if not isinstance(data, dict):
        raise DataFormatError(path, "expected a JSON object")
    return data


def is_complete(root: str | PathLike[str], config: GenerationConfig) -> bool:
    """True when ``root`` holds a finished data set generated with ``config``."""
    path = Path(root) / SUMMARY_FILE
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return bool(data.get("complete")) and data.get("config") == config.to_json()


def _version() -> str:
    from lidarfuzz import __version__

    return __version__
