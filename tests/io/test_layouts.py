"""Point layouts: every named layout round-trips, a scan is never read with the wrong column count
(even when its size fits both), explicit specs parse (and bad ones fail in one line), the
intensity scale is recorded, and data-set options (a GeoJSON ROI map) reach the frames.

Synthetic scans take their statistics from real ones (checked locally, never read here):
KITTI training 000000 has 115,384 points, x, y, z within ±80 m and about 0.1 % of them whole
numbers, intensities in [0, 1] in steps of 0.01 with 10.4 % zeros; the nuScenes LIDAR_TOP
excerpt of mmdetection3d's test data has 400 points (8,000 bytes: 500 KITTI records too),
intensities 0–234 as whole numbers with 20.7 % zeros, rings 0–31.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io import open_dataset, read_frame, write_kitti
from lidarfuzz.io.formats import bin as bin_format
from lidarfuzz.io.formats import feather, semantickitti
from lidarfuzz.io.layouts import LAYOUTS, LayoutError, layout_from_structure, parse_layout
from lidarfuzz.io.options import DatasetOptions, load_dataset_map, options_from_flags
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene
from lidarfuzz.scene.semantics import SEMANTIC_ID


def scan(n: int, seed: int = 0, *, intensity_max: float = 1.0, rings: int = 0) -> dict[str, np.ndarray]:
    """Columns of a real-like spinning-LiDAR scan (see the module docstring)."""
    rng = np.random.default_rng(seed)
    distance = rng.uniform(2.0, 80.0, n)
    azimuth = rng.uniform(-np.pi, np.pi, n)
    elevation = rng.uniform(-0.43, 0.03, n)
    columns = {
        "x": (distance * np.cos(azimuth) * np.cos(elevation)).astype(np.float32),
        "y": (distance * np.sin(azimuth) * np.cos(elevation)).astype(np.float32),
        "z": (distance * np.sin(elevation) + 1.73).astype(np.float32),
    }
    if intensity_max == 1.0:  # KITTI: hundredths, a tenth of them zero
        intensity = np.round(rng.uniform(0, 1, n), 2) * (rng.random(n) > 0.1)
    else:  # nuScenes: whole numbers 0–234, a fifth of them zero
        intensity = rng.integers(0, 235, n) * (rng.random(n) > 0.2)
    columns["intensity"] = intensity.astype(np.float32)
    if rings:
        columns["ring"] = rng.integers(0, rings, n).astype(np.float32)
    return columns


def cloud_of(columns: dict[str, np.ndarray]) -> PointCloud:
    return PointCloud.from_channels(columns)


def write_records(path: Path, columns: dict[str, np.ndarray], order: tuple[str, ...]) -> Path:
    np.column_stack([columns[c] for c in order]).astype("<f4").tofile(path)
    return path


# ------------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("name, extra", [
    ("kitti", {}), ("kitti360", {}),
    ("nuscenes", {"ring": 32}),
    ("waymo", {"elongation": None, "range_index": None}),
])
def test_each_bin_layout_round_trips(tmp_path: Path, name: str, extra: dict[str, int | None]) -> None:
    columns = scan(500, intensity_max=255.0 if name == "nuscenes" else 1.0, rings=extra.get("ring") or 0)
    rng = np.random.default_rng(1)
    if name == "waymo":
        columns["elongation"] = rng.uniform(0, 1.5, 500).astype(np.float32)
        columns["range_index"] = rng.integers(-1, 300_000, 500).astype(np.float32)
    cloud = cloud_of(columns)
    path = tmp_path / ("frame.pcd.bin" if name == "nuscenes" else "frame.bin")
    bin_format.write_points(path, cloud, layout=name)
    assert path.stat().st_size == 500 * LAYOUTS[name].record_size
    scene = read_frame(path, layout=name)
    assert scene.points == cloud  # the same points and channels, bit for bit
    assert scene.metadata["layout"] == name


def test_explicit_spec_with_per_column_types_round_trips(tmp_path: Path) -> None:
    layout = parse_layout("x,y,z:f4,intensity:u1,_:u1,ring:u2")
    # 3×4 + 1 + 1 (padding) + 2 bytes
    assert layout.record_size == 16 and layout.channels == ("x", "y", "z", "intensity", "ring")
    columns = scan(300, intensity_max=255.0, rings=128)
    cloud = cloud_of(columns)
    bin_format.write_points(tmp_path / "a.bin", cloud, layout=layout)
    assert read_frame(tmp_path / "a.bin", layout="x,y,z:f4,intensity:u1,_:u1,ring:u2").points == cloud


def test_semantickitti_round_trips_with_its_label_file(tmp_path: Path) -> None:
    sequence = tmp_path / "sequences" / "00"
    columns = scan(400)
    raw = np.array([10, 252, 40, 48, 13, 0, 51, 30], dtype=np.float32)[np.arange(400) % 8]
    columns["semantickitti_label"] = raw
    columns["label"] = np.array([SEMANTIC_ID[n] for n in ("car", "car", "road", "sidewalk", "unlabelled",
                                                         "unlabelled", "wall", "pedestrian")],
                                dtype=np.float32)[np.arange(400) % 8]
    columns["instance"] = np.where(np.isin(raw, (10, 252, 30)), np.arange(400) % 5 + 1, -1).astype(np.float32)
    cloud = cloud_of(columns)
    bin_format.write_points(sequence / "velodyne" / "000000.bin", cloud, layout="semantickitti")
    label_file = sequence / "labels" / "000000.label"
    words = np.fromfile(label_file, dtype="<u4")
    # worked by hand: point 0 is a car (10) of instance 1 → 1 << 16 | 10 = 65546
    assert words[0] == 65546 and words[4] == 13  # a bus keeps its raw id, instance 0 (none)
    assert layout_from_structure(sequence) is LAYOUTS["semantickitti"]
    scene = open_dataset(sequence)[0]  # the folder's structure says semantickitti
    assert scene.metadata["layout"] == "semantickitti"
    back = scene.points
    for channel in ("x", "y", "z", "intensity", "label", "instance", "semantickitti_label"):
        np.testing.assert_array_equal(back.channel(channel), cloud.channel(channel))


def test_semantickitti_label_file_of_the_wrong_size_names_it(tmp_path: Path) -> None:
    sequence = tmp_path / "sequences" / "03"
    (sequence / "velodyne").mkdir(parents=True)
    (sequence / "labels").mkdir()
    write_records(sequence / "velodyne" / "000000.bin", scan(100), ("x", "y", "z", "intensity"))
    np.zeros(99, dtype="<u4").tofile(sequence / "labels" / "000000.label")
    with pytest.raises(DataFormatError, match=r"000000\.label: holds 396 bytes; the scan has 100 points"):
        open_dataset(sequence)[0]


def test_argoverse2_feather_round_trips(tmp_path: Path) -> None:
    pytest.importorskip("pyarrow", reason="the argoverse extra (pyarrow) is not installed")
    columns = scan(500, intensity_max=255.0, rings=64)
    # firing times within the 100 ms sweep, whole nanoseconds ≥ 1/64 s (float32 resolves them)
    columns["time"] = (np.random.default_rng(2).integers(16_000_000, 99_000_000, 500) * 1e-9).astype(np.float32)
    cloud = cloud_of(columns)
    path = tmp_path / "315967376859506000.feather"
    feather.write(path, Scene(cloud))
    import pyarrow.feather as pf

    table = pf.read_table(path)
    assert table.column_names == ["x", "y", "z", "intensity", "laser_number", "offset_ns"]
    assert str(table.schema.field("intensity").type) == "uint8"
    scene = read_frame(path)
    assert scene.metadata["layout"] == "argoverse2" and scene.metadata["intensity_scale"] == 255.0
    assert scene.timestamp == pytest.approx(315967376.859506)
    for channel in ("x", "y", "z", "intensity", "ring"):
        np.testing.assert_array_equal(scene.points.channel(channel), cloud.channel(channel))
    np.testing.assert_allclose(scene.points.channel("time"), cloud.channel("time"), rtol=0, atol=1e-9)


def test_feather_without_pyarrow_names_the_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import builtins

    real_import = builtins.__import__

    def no_pyarrow(name: str, *args: object, **kwargs: object) -> object:
        if name.startswith("pyarrow"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(builtins, "__import__", no_pyarrow)
    (tmp_path / "1.feather").write_bytes(b"ARROW1")
    with pytest.raises(ImportError, match=r"lidarfuzz\[argoverse\]"):
        read_frame(tmp_path / "1.feather")


# ------------------------------------------------------------------------------- never a misread
def test_a_nuscenes_sweep_is_never_read_as_four_columns(tmp_path: Path) -> None:
    # 400 points × 20 bytes = 8,000 bytes = 500 × 16: the size alone cannot tell
    path = write_records(tmp_path / "sweep.bin", scan(400, intensity_max=255.0, rings=32),
                         ("x", "y", "z", "intensity", "ring"))
    assert path.stat().st_size % 16 == 0
    for layout in (None, "kitti"):  # by default, and even when the user says kitti
        with pytest.raises(DataFormatError) as info:
            read_frame(path, layout=layout)
        message = str(info.value)
        assert message.startswith(str(path)) and "\n" not in message
        assert "read as kitti (4 columns)" in message and "try --layout nuscenes" in message
    assert read_frame(path, layout="nuscenes").points.channel("ring").max() <= 31


def test_a_kitti_scan_is_never_read_as_five_columns(tmp_path: Path) -> None:
    # 500 points × 16 bytes = 8,000 bytes = 400 × 20
    columns = scan(500)
    for name in ("frame.bin", "frame.pcd.bin"):  # told nuscenes, or a .pcd.bin name says so
        path = write_records(tmp_path / name, columns, ("x", "y", "z", "intensity"))
        with pytest.raises(DataFormatError, match=r"read as nuscenes \(5 columns\).*try --layout kitti"):
            read_frame(path, layout="nuscenes" if name == "frame.bin" else None)
    assert read_frame(tmp_path / "frame.bin").points == cloud_of(columns)


def test_a_five_column_scan_with_an_unnamed_column_is_not_read_as_four(tmp_path: Path) -> None:
    # x y z intensity time: no ring to give it away, but the 4-column reading puts coordinates
    # into the intensity column (negative values); the 5-column reading fits
    columns = scan(400)
    columns["time"] = np.linspace(-0.05, 0.05, 400, dtype=np.float32)
    path = write_records(tmp_path / "t.bin", columns, ("x", "y", "z", "intensity", "time"))
    with pytest.raises(DataFormatError, match=r"try --layout x,y,z,intensity,c4:f4 \(name the extra columns"):
        read_frame(path)
    assert read_frame(path, layout="x,y,z,intensity,time:f4").points.channel("time")[-1] == np.float32(0.05)


def test_waymo_and_kitti_are_told_apart(tmp_path: Path) -> None:
    columns = scan(400)
    columns["elongation"] = np.zeros(400, np.float32)
    columns["range_index"] = np.arange(400, dtype=np.float32)
    six = write_records(tmp_path / "w.bin", columns, ("x", "y", "z", "intensity", "elongation", "range_index"))
    with pytest.raises(DataFormatError, match=r"try --layout waymo"):
        read_frame(six)
    four = write_records(tmp_path / "k.bin", scan(600), ("x", "y", "z", "intensity"))  # 9,600 B = 400 × 24
    with pytest.raises(DataFormatError, match=r"read as waymo \(6 columns\).*try --layout kitti"):
        read_frame(four, layout="waymo")


def test_a_size_that_is_not_whole_records_names_the_layout_it_fits(tmp_path: Path) -> None:
    path = write_records(tmp_path / "odd.bin", scan(401, intensity_max=255.0, rings=32),
                         ("x", "y", "z", "intensity", "ring"))  # 8,020 bytes: 16 × 501 + 4
    with pytest.raises(DataFormatError, match=r"size 8020 bytes is not a multiple of 16.*try --layout nuscenes"):
        read_frame(path)


def test_odd_values_with_no_better_layout_are_doubts_when_the_user_chose(tmp_path: Path) -> None:
    columns = scan(200)
    columns["x"] = np.round(columns["x"])  # a grid-like synthetic scan: whole-number x
    path = write_records(tmp_path / "grid.bin", columns, ("x", "y", "z", "intensity"))
    with pytest.raises(DataFormatError, match=r"does not look like a kitti \(4 columns\) scan.*say so with "
                                              r"--layout kitti"):
        read_frame(path)
    scene = read_frame(path, layout="kitti")
    assert "whole numbers" in scene.metadata["layout_doubts"][0]


def test_tiny_and_empty_scans_are_not_judged(tmp_path: Path) -> None:
    (tmp_path / "empty.bin").write_bytes(b"")
    assert len(read_frame(tmp_path / "empty.bin").points) == 0
    np.array([[1, 2, 3, 0]], dtype="<f4").tofile(tmp_path / "one.bin")  # one point proves nothing
    assert len(read_frame(tmp_path / "one.bin").points) == 1


# ------------------------------------------------------------------------------- specs
def test_explicit_specs_parse() -> None:
    layout = parse_layout("x,y,z,intensity,ring:f4")
    assert layout.record_size == 20 and layout.float32_only and layout.intensity_scale is None
    assert parse_layout("X,Y,Z,reflectance,laser_id:f4").channels == ("x", "y", "z", "intensity", "ring")
    assert parse_layout(" NuScenes ") is LAYOUTS["nuscenes"]
    assert parse_layout("x,y,z:f8").record_size == 24


@pytest.mark.parametrize("spec, part", [
    ("x,y,z:f9", "unknown type 'f9'"),
    ("x,y,z", "give the columns' type after the last one"),
    ("x,y,z,x:f4", "x given twice"),
    ("x,y,intensity:f4", "no 'z' column"),
    ("x,y,z,in-tensity:f4", "'in-tensity' is not a name"),
    ("velodyne", "not a layout name"),
])
def test_bad_specs_fail_in_one_line(spec: str, part: str) -> None:
    with pytest.raises(LayoutError) as info:
        parse_layout(spec)
    assert part in str(info.value) and "\n" not in str(info.value) and repr(spec) in str(info.value)


def test_a_bad_layout_flag_is_named_as_the_flag() -> None:
    with pytest.raises(Exception, match=r"^--layout 'x,y:f4': no 'z' column"):
        options_from_flags("x,y:f4")


# ------------------------------------------------------------------------------- intensity scale
def test_intensity_scale_is_recorded(tmp_path: Path) -> None:
    kitti = write_records(tmp_path / "k.bin", scan(300), ("x", "y", "z", "intensity"))
    nuscenes = write_records(tmp_path / "n.pcd.bin", scan(300, intensity_max=255.0, rings=32),
                             ("x", "y", "z", "intensity", "ring"))
    assert read_frame(kitti).metadata["intensity_scale"] == 1.0
    assert read_frame(nuscenes).metadata["intensity_scale"] == 255.0
    # a KITTI-shaped file with 0–255 readings (lidarfuzz convert of a nuScenes sweep writes one)
    bright = write_records(tmp_path / "b.bin", scan(300, intensity_max=255.0), ("x", "y", "z", "intensity"))
    assert read_frame(bright).metadata["intensity_scale"] == 255.0
    six = scan(300)
    six["elongation"], six["range_index"] = np.zeros(300, np.float32), np.zeros(300, np.float32)
    waymo = write_records(tmp_path / "w.bin", six, ("x", "y", "z", "intensity", "elongation", "range_index"))
    assert "intensity_scale" not in read_frame(waymo, layout="waymo").metadata  # raw, unbounded
    given = open_dataset(bright, options=DatasetOptions(intensity_scale=100.0))[0]
    assert given.metadata["intensity_scale"] == 100.0


def test_structure_picks_the_layout(tmp_path: Path) -> None:
    top = tmp_path / "nuscenes" / "samples" / "LIDAR_TOP"
    top.mkdir(parents=True)
    write_records(top / "a.bin", scan(200, intensity_max=255.0, rings=32), ("x", "y", "z", "intensity", "ring"))
    assert layout_from_structure(top / "a.bin") is LAYOUTS["nuscenes"]
    dataset = open_dataset(tmp_path / "nuscenes")  # a nuScenes root opens its keyframes
    assert list(dataset.frame_ids()) == ["a"] and dataset[0].points.has("ring")
    assert layout_from_structure(tmp_path / "x.feather") is LAYOUTS["argoverse2"]
    assert layout_from_structure(tmp_path / "x.bin") is None


# ------------------------------------------------------------------------------- data-set ROI maps
def _square(half: float, centre: tuple[float, float] = (0.0, 0.0)) -> list[list[float]]:
    cx, cy = centre
    return [[cx - half, cy - half], [cx + half, cy - half], [cx + half, cy + half], [cx - half, cy + half],
            [cx - half, cy - half]]


def test_a_dataset_map_reaches_frames_without_their_own(tmp_path: Path, sample_scenes: list[Scene]) -> None:
    scenes = [sample_scenes[0].replace(roi=None, frame_id="000000"), sample_scenes[1].replace(frame_id="000001")]
    assert scenes[1].roi is not None
    root = write_kitti(tmp_path / "ds", scenes)
    geojson = tmp_path / "map.geojson"
    geojson.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": [_square(5.0)]}}]}))
    dataset = open_dataset(root, options=DatasetOptions(roi_map=str(geojson)))
    first, second = dataset.load("000000"), dataset.load("000001")
    assert first.metadata["roi_source"] == "dataset_map" and first.roi.area == pytest.approx(100.0)
    assert second.metadata["roi_source"] == "frame_map" and second.roi == scenes[1].roi


def test_a_world_frame_map_is_moved_by_each_pose(tmp_path: Path, sample_scenes: list[Scene]) -> None:
    pose = np.eye(4)
    pose[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # the sensor faces world +y …
    pose[:3, 3] = [100.0, 50.0, 0.0]  # … from (100, 50)
    scene = sample_scenes[0].replace(roi=None, frame_id="000000", pose=pose, timestamp=0.0)
    root = write_kitti(tmp_path / "log", [scene])
    geojson = tmp_path / "world.geojson"
    # a 2 m square around world (100, 60): 10 m ahead of the sensor, i.e. LiDAR (10, 0)
    geojson.write_text(json.dumps({"type": "Polygon", "frame": "world", "coordinates": [_square(1.0, (100, 60))]}))
    roi = open_dataset(root, options=DatasetOptions(roi_map=str(geojson)))[0].roi
    assert roi.contains_xy([[10.0, 0.0], [0.0, 10.0]]).tolist() == [True, False]


@pytest.mark.parametrize("text, where", [
    ('{"type": "Polygon", "coordinates": [[[0, 0], [1, 0]', ":1: not valid JSON"),
    ('{"type": "Point", "coordinates": [0, 0]}', "field 'type': type 'Point'"),
    ('{"type": "FeatureCollection", "features": [{"type": "Feature", "geometry": {"type": "Polygon", '
     '"coordinates": [[[0, 0], ["a", 1]]]}}]}', "field 'features.0.geometry.coordinates'"),
    ('{"type": "Polygon", "frame": "camera", "coordinates": []}', "field 'frame': 'camera' is not"),
])
def test_a_malformed_map_is_one_line_naming_file_and_field(tmp_path: Path, text: str, where: str) -> None:
    path = tmp_path / "bad.geojson"
    path.write_text(text)
    with pytest.raises(DataFormatError) as info:
        load_dataset_map(path)
    message = str(info.value)
    assert message.startswith(str(path)) and where in message and "\n" not in message


def test_semantickitti_ids_map_onto_lidarfuzz_classes() -> None:
    assert semantickitti.TO_LIDARFUZZ[252] == "car" and semantickitti.TO_LIDARFUZZ[44] == "other-ground"
    assert 13 not in semantickitti.TO_LIDARFUZZ  # bus: lidarfuzz has no such class, the raw id is kept
