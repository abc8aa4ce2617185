"""Fuzz targets for every user file that is not a point-cloud frame: KITTI labels, calibration and
side files, data-set maps, logs (ROS 1, ROS 2, MCAP), camera tables, campaign, scene and sensor files.

Each target's seeds are valid files written by lidarfuzz's own writers (or shipped with it) and kept
small, so one case runs in milliseconds. A case that is one file of a folder (a label file of a KITTI
data set, the ``.db3`` of a ROS 2 bag) is read as that folder: ``read`` puts the case into a valid
folder of its process's own (made once) and opens it the way a user's folder is opened.
"""

from __future__ import annotations

import functools
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

from lidarfuzz.io.logs.writers import write_log
from tests.fuzz.harness import Target

#: Frame ids of the small KITTI folder every KITTI target is read in.
_FRAMES = ("000000", "000001")


@functools.cache
def _scenes() -> tuple[object, ...]:
    """Two tiny labelled frames: 40 points, one car, calibration, timestamp, pose, ROI, a ring channel."""
    from shapely.geometry import MultiPolygon, Polygon

    from lidarfuzz.scene.boxes import Boxes3D
    from lidarfuzz.scene.calib import KittiCalibration
    from lidarfuzz.scene.points import PointCloud
    from lidarfuzz.scene.roi import RoiMap
    from lidarfuzz.scene.scene import Scene

    rng = np.random.default_rng(0)
    scenes = []
    for index, frame_id in enumerate(_FRAMES):
        xyz = rng.uniform([2.0, -5.0, -1.5], [20.0, 5.0, 1.0], size=(40, 3))
        data = np.column_stack([xyz, rng.uniform(0, 1, 40), np.arange(40) % 16]).astype(np.float32)
        boxes = Boxes3D.from_array(np.array([[8.0 + index, 1.0, -0.8, 4.0, 1.8, 1.5, 0.3]]), ["Car"],
                                   track_ids=np.array([7]))
        pose = np.eye(4)
        pose[0, 3] = float(index)
        roi = RoiMap(MultiPolygon([Polygon([(0, -6), (30, -6), (30, 6), (0, 6)])]))
        scenes.append(Scene(PointCloud(data, ("x", "y", "z", "intensity", "ring")), boxes,
                            KittiCalibration.default(), frame_id=frame_id, timestamp=0.1 * index, pose=pose,
                            roi=roi, metadata={"objects": {"num_points": [12]}}))
    return tuple(scenes)


@functools.cache
def _kitti_template() -> Path:
    """A valid two-frame KITTI folder (written once per process) that KITTI cases are placed in."""
    import tempfile

    from lidarfuzz.io.kitti import write_kitti

    root = Path(tempfile.mkdtemp(prefix="lidarfuzz-fuzz-kitti-")) / "kitti"
    write_kitti(root, _scenes(), image_sets={"train": list(_FRAMES)})  # type: ignore[arg-type]
    (root / "ego.txt").write_text("# frame speed yaw_rate curvature steering\n"
                                  + "".join(f"{f} 5.0 0.01 0.002 0.03\n" for f in _FRAMES), encoding="utf-8")
    image = _png(4, 6)
    for frame_id in _FRAMES:
        (root / "image_2").mkdir(exist_ok=True)
        (root / "image_2" / f"{frame_id}.png").write_bytes(image)
    (root / "steering.csv").write_text("frame_id,steering,speed\n"
                                       + "".join(f"{f},0.05,4.0\n" for f in _FRAMES), encoding="utf-8")
    return root


def _png(height: int, width: int) -> bytes:
    import cv2

    pixels = (np.arange(height * width * 3) % 251).astype(np.uint8).reshape(height, width, 3)
    ok, buffer = cv2.imencode(".png", pixels)
    assert ok
    return bytes(buffer.tobytes())


def _kitti_seed(relative: str) -> Callable[[Path], list[bytes]]:
    def seeds(scratch: Path) -> list[bytes]:
        return [(_kitti_template() / relative).read_bytes()]
    return seeds


def _png_seeds(scratch: Path) -> list[bytes]:
    """The folder's PNG, and the same with bytes after its IEND chunk (which decoders ignore, as some
    cameras' files carry): every chunk of a PNG has a CRC, so nearly any change to the first is refused,
    while changes to the second's tail must still read."""
    image = (_kitti_template() / "image_2" / "000000.png").read_bytes()
    return [image, image + bytes(range(256))]


def _npz_seeds(scratch: Path) -> list[bytes]:
    """The folder's extra channels, and the same archive with a comment (not covered by the members' CRCs)."""
    import io
    import zipfile

    data = (_kitti_template() / "velodyne_extra" / "000000.npz").read_bytes()
    buffer = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as source, zipfile.ZipFile(buffer, "w") as copy:
        for member in source.infolist():
            copy.writestr(member, source.read(member))
        copy.comment = b"written by lidarfuzz's fuzz targets; " * 8
    return [data, buffer.getvalue()]


def _kitti_around(case: Path, relative: str) -> Path:
    """A valid KITTI folder (this process's own, made once per ``relative``) with ``case`` as its file
    ``relative``: only that file changes between cases (building the folder anew took most of a case)."""
    root = _kitti_folder(relative)
    shutil.copyfile(case, root / relative)
    return root


@functools.cache
def _kitti_folder(relative: str) -> Path:
    import tempfile

    root = Path(tempfile.mkdtemp(prefix="lidarfuzz-fuzz-case-")) / "kitti"
    shutil.copytree(_kitti_template(), root)
    return root


def _read_kitti(relative: str, **options: object) -> Callable[[Path], object]:
    """Open the folder around the case (strict, as a campaign does) and load every frame."""
    def read(case: Path) -> object:
        from lidarfuzz.io.open import open_dataset

        dataset = open_dataset(_kitti_around(case, relative), **options)  # type: ignore[call-overload]
        return [dataset.load(frame_id) for frame_id in dataset.frame_ids()]
    return read


def _read_kitti_images(relative: str) -> Callable[[Path], object]:
    """The camera modality of the folder around the case (its images, calibration and steering.csv)."""
    def read(case: Path) -> object:
        from lidarfuzz.io.open import open_dataset

        dataset = open_dataset(_kitti_around(case, relative), modality="camera")
        return [dataset.load(frame_id) for frame_id in dataset.frame_ids()]
    return read


def _kitti_target(name: str, relative: str, **options: object) -> Target:
    return Target(name=name, filename=Path(relative).name, seeds=_kitti_seed(relative),
                  read=_read_kitti(relative, **options))


# -- data-set maps ----------------------------------------------------------------------------------

def _map_seeds(scratch: Path) -> list[bytes]:
    lidar = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {
            "type": "Polygon", "coordinates": [[[0, -6], [30, -6], [30, 6], [0, 6], [0, -6]]]}}]}
    world = {"type": "MultiPolygon", "frame": "world",
             "coordinates": [[[[0, -6], [30, -6], [30, 6], [0, 6], [0, -6]], [[5, -1], [6, -1], [6, 1], [5, 1]]]]}
    return [json.dumps(lidar).encode(), json.dumps(world, indent=1).encode()]


def _read_map(case: Path) -> object:
    from lidarfuzz.io.options import load_dataset_map

    dataset_map = load_dataset_map(case)
    return [dataset_map.for_scene(scene) for scene in _scenes()]  # type: ignore[arg-type]


# -- logs -------------------------------------------------------------------------------------------

def _log_bytes(scratch: Path, name: str, **options: object) -> Path:
    out = scratch / name
    scratch.mkdir(parents=True, exist_ok=True)
    if not out.exists():
        write_log(out, _scenes(), **options)  # type: ignore[arg-type]
    return out


def _read_log(case: Path, **options: object) -> object:
    """Open the log, load each frame by id (the index's way) and stream it (one pass), with its times."""
    from lidarfuzz.io.open import open_dataset

    dataset = open_dataset(case, **options)  # type: ignore[call-overload]
    loaded = [dataset.load(frame_id) for frame_id in dataset.frame_ids()]
    return loaded, list(dataset), dataset.timestamps()  # type: ignore[attr-defined]


def _image_log_seed(suffix: str) -> Callable[[Path], list[bytes]]:
    """A log of one raw (bgr8, padded rows) and one compressed (PNG) image topic, written as the camera
    readers' tests write them; the target reads the raw topic, then the compressed one."""
    def seeds(scratch: Path) -> list[bytes]:
        from tests.io.images.test_image_logs import ROS1, ROS2, bgr8_padded, compressed, write_mcap, write_ros1

        scratch.mkdir(parents=True, exist_ok=True)
        write, store = (write_ros1, ROS1) if suffix == ".bag" else (write_mcap, ROS2)
        out = write(scratch / f"images{suffix}", {"/raw": [bgr8_padded(store, i) for i in range(2)],
                                                  "/png": [compressed(store, i) for i in range(2)]})
        return [out.read_bytes()]
    return seeds


def _read_image_log(case: Path) -> object:
    return [_read_log(case, modality="camera", topic=topic) for topic in ("/raw", "/png")]


@functools.cache
def _ros2_template() -> Path:
    import tempfile

    return _log_bytes(Path(tempfile.mkdtemp(prefix="lidarfuzz-fuzz-ros2-")), "bag")


def _ros2_seed(member: str) -> Callable[[Path], list[bytes]]:
    def seeds(scratch: Path) -> list[bytes]:
        return [(_ros2_template() / member).read_bytes()]
    return seeds


@functools.cache
def _ros2_folder(member: str) -> Path:
    """This process's copy of the valid ROS 2 bag, whose ``member`` each case replaces."""
    import tempfile

    bag = Path(tempfile.mkdtemp(prefix="lidarfuzz-fuzz-case-")) / "bag"
    shutil.copytree(_ros2_template(), bag)
    return bag


def _read_ros2(member: str) -> Callable[[Path], object]:
    """The ROS 2 bag folder around the case (the case as its ``member``), opened and read."""
    def read(case: Path) -> object:
        bag = _ros2_folder(member)
        shutil.copyfile(case, bag / member)
        return _read_log(bag)
    return read


# -- camera tables ----------------------------------------------------------------------------------

def _table_seeds(scratch: Path) -> list[bytes]:
    return [b"image,steering,timestamp,speed\nimg/a.png,0.1,0.0,3.0\nimg/b.png,-0.2,0.1,3.5\n",
            b"center,left,right,steering,throttle,brake,speed\nimg/a.png,img/b.png,img/a.png,0.1,0.5,0,20\n"]


def _read_table(case: Path) -> object:
    from lidarfuzz.io.open import open_dataset

    images = case.parent / "img"
    images.mkdir(exist_ok=True)
    for name in ("a.png", "b.png"):
        if not (images / name).exists():
            (images / name).write_bytes(_png(3, 4))
    dataset = open_dataset(case, modality="camera")
    return [dataset.load(frame_id) for frame_id in dataset.frame_ids()]


def _udacity_seeds(scratch: Path) -> list[bytes]:
    return [b"index,timestamp,width,height,frame_id,filename,angle,torque,speed,lat,long,alt\n"
            b"0,1479424215880976321,4,3,center_camera,center/a.png,0.05,0.1,4.0,37.4,-122.1,0\n"
            b"1,1479424215930976321,4,3,center_camera,center/b.png,0.06,0.1,4.0,37.4,-122.1,0\n"]


def _read_udacity(case: Path) -> object:
    from lidarfuzz.io.open import open_dataset

    images = case.parent / "center"
    images.mkdir(exist_ok=True)
    for name in ("a.png", "b.png"):
        if not (images / name).exists():
            (images / name).write_bytes(_png(3, 4))
    dataset = open_dataset(case, modality="camera")
    return [dataset.load(frame_id) for frame_id in dataset.frame_ids()]


def _image_seeds(scratch: Path) -> list[bytes]:
    import cv2

    ok, jpeg = cv2.imencode(".jpg", np.full((8, 8, 3), 90, dtype=np.uint8))
    assert ok
    return [_png(3, 4), bytes(jpeg.tobytes())]


def _read_image(case: Path) -> object:
    """An image named by a camera table, decoded as a campaign's worker decodes it."""
    from lidarfuzz.io.open import open_dataset

    table = case.parent / "images.csv"
    table.write_text(f"image,steering\n{case.name},0.1\n", encoding="utf-8")
    dataset = open_dataset(table, modality="camera")
    return [dataset.load(frame_id) for frame_id in dataset.frame_ids()]


# -- campaign, scene and sensor files ----------------------------------------------------------------

_CAMPAIGN = """\
name: fog-vs-classic
dataset: sim
sut: classic
operators:
  - name: fog
    severities: [1, 3, 5]
  - name: rotate_z
    config: {angle_range: [10, 20]}
relations: auto
seed: 0
frames: 50
frame_order: first
"""

_STRUCTURAL = """\
kind: structural
dataset: [drive-0, drive-1]
sut: controller
coverage:
  targets: [lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process]
segments: 5
heuristics: [greedy_edges, decision_change, random]
strategies: [HGT, AVG]
"""


def _campaign_yaml_seeds(scratch: Path) -> list[bytes]:
    return [_CAMPAIGN.encode(), _STRUCTURAL.encode()]


def _campaign_json_seeds(scratch: Path) -> list[bytes]:
    return [json.dumps(yaml.safe_load(text), indent=2).encode() for text in (_CAMPAIGN, _STRUCTURAL)]


def _read_campaign(case: Path) -> object:
    from lidarfuzz.campaign.spec import load_campaign

    return load_campaign(case)


def _warm_campaigns() -> None:
    """Import what validating a structural campaign imports (seconds, once): done when the targets are
    loaded, not inside the first structural case's time limit, where it read as a hang on a busy machine."""
    import lidarfuzz.campaign.structural
    import lidarfuzz.operators  # noqa: F401


def _scene_seeds(scratch: Path) -> list[bytes]:
    shipped = Path(__file__).resolve().parents[2] / "docs" / "scenes"
    return [path.read_bytes() for path in sorted(shipped.glob("*.yaml"))]


def _read_scene(case: Path) -> object:
    from lidarfuzz.sim.spec import load_scene

    return load_scene(case)


def _sensor_seeds(scratch: Path) -> list[bytes]:
    from lidarfuzz.sim.sensor import SENSOR_PRESETS

    vlp16 = SENSOR_PRESETS["VLP-16"].model_dump(mode="json")
    return [yaml.safe_dump(vlp16).encode(), b"preset: HDL-64E\nmount_height: 1.9\nelevations_deg: [2.0, 0.0, -2.0]\n"]


def _read_sensor(case: Path) -> object:
    from lidarfuzz.sim.sensor import load_sensor

    return load_sensor(case)


_warm_campaigns()

TARGETS: list[Target] = [
    _kitti_target("kitti-label", "label_2/000000.txt"),
    _kitti_target("kitti-calib", "calib/000000.txt"),
    _kitti_target("kitti-timestamps", "timestamps.txt"),
    _kitti_target("kitti-poses", "poses.txt"),
    _kitti_target("kitti-ego", "ego.txt"),
    _kitti_target("kitti-roi", "roi/000000.json"),
    _kitti_target("kitti-label-extra", "label_2_extra/000000.json"),
    Target(name="kitti-velodyne-extra", filename="000000.npz", seeds=_npz_seeds,
           read=_read_kitti("velodyne_extra/000000.npz")),
    _kitti_target("kitti-imagesets", "ImageSets/train.txt", subset="train"),
    Target(name="kitti-image-png", filename="000000.png", seeds=_png_seeds,
           read=_read_kitti_images("image_2/000000.png")),
    Target(name="kitti-steering-csv", filename="steering.csv", seeds=_kitti_seed("steering.csv"),
           read=_read_kitti_images("steering.csv")),
    Target(name="dataset-map", filename="map.geojson", seeds=_map_seeds, read=_read_map),
    Target(name="ros1-bag", filename="log.bag", seeds=lambda d: [_log_bytes(d, "seed.bag").read_bytes()],
           read=_read_log, cli=("convert", "{path}", "{path}.kitti")),
    Target(name="mcap", filename="log.mcap", seeds=lambda d: [_log_bytes(d, "seed.mcap").read_bytes()],
           read=_read_log, cli=("logs", "partition", "{path}", "--size", "1")),
    Target(name="image-log-ros1", filename="images.bag", seeds=_image_log_seed(".bag"), read=_read_image_log),
    Target(name="image-log-mcap", filename="images.mcap", seeds=_image_log_seed(".mcap"), read=_read_image_log),
    Target(name="ros2-db3", filename="bag.db3", seeds=_ros2_seed("bag.db3"), read=_read_ros2("bag.db3")),
    Target(name="ros2-metadata", filename="metadata.yaml", seeds=_ros2_seed("metadata.yaml"),
           read=_read_ros2("metadata.yaml")),
    Target(name="image-table", filename="images.csv", seeds=_table_seeds, read=_read_table),
    Target(name="udacity-table", filename="interpolated.csv", seeds=_udacity_seeds, read=_read_udacity),
    Target(name="image-file", filename="frame.png", seeds=_image_seeds, read=_read_image),
    # a valid campaign stops at its data set "sim", which the case's fresh workspace does not hold
    Target(name="campaign-yaml", filename="campaign.yaml", seeds=_campaign_yaml_seeds, read=_read_campaign,
           cli=("run", "{path}")),
    Target(name="campaign-json", filename="campaign.json", seeds=_campaign_json_seeds, read=_read_campaign),
    Target(name="scene", filename="scene.yaml", seeds=_scene_seeds, read=_read_scene,
           cli=("gen", "--scene", "{path}", "--frames", "1", "--workers", "1", "--out", "{path}.out")),
    Target(name="sensor", filename="sensor.yaml", seeds=_sensor_seeds, read=_read_sensor,
           cli=("gen", "--sensor", "{path}", "--frames", "1", "--workers", "1", "--out", "{path}.out")),
]
