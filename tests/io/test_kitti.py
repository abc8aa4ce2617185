import io
import mmap
import shutil
import warnings

import numpy as np
import pytest
from hypothesis import given, settings

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io import KittiDataset, KittiLog, KittiWriter, NonFiniteWarning, open_dataset, write_kitti
from lidarfuzz.io.atomic import OutputExistsError
from lidarfuzz.io.formats import bin as bin_format
from lidarfuzz.io.kitti import format_labels, parse_labels
from lidarfuzz.io.kitti.writer import compact_channel
from lidarfuzz.scene import Boxes3D, KittiCalibration, PointCloud, Scene, points_in_boxes
from tests.conftest import KITTI_000000_CALIB
from tests.strategies import boxes as box_strategy
from tests.strategies import clouds

CALIB = KittiCalibration.parse(KITTI_000000_CALIB)


# ---------------------------------------------------------------- .bin
def test_bin_round_trip_and_memory_map(tmp_path):
    cloud = PointCloud(np.random.default_rng(0).normal(size=(1000, 4)).astype(np.float32))
    bin_format.write_points(tmp_path / "a.bin", cloud)
    scene = bin_format.read(tmp_path / "a.bin")
    assert scene.points == cloud and scene.frame_id == "a"
    base = scene.points.data
    while isinstance(base, np.ndarray):
        base = base.base
    base = base.obj if isinstance(base, memoryview) else base
    assert isinstance(base, mmap.mmap)  # the file is mapped, not copied into memory


@settings(max_examples=25, deadline=None)
@given(clouds())
def test_bin_round_trip_property(tmp_path_factory, cloud):
    path = tmp_path_factory.mktemp("bin") / "f.bin"
    bin_format.write_points(path, cloud)
    # arbitrary floats are no scan: the layout is given, as a user gives it (tests/io/test_layouts.py
    # checks that implausible values are refused when it is not)
    back, dropped = bin_format.read_points(path, layout="kitti")
    assert dropped == 0
    assert np.array_equal(back.data, cloud.data[:, :4])


def test_bin_bad_size_names_file(tmp_path):
    path = tmp_path / "000007.bin"
    path.write_bytes(b"\0" * 20)
    with pytest.raises(DataFormatError, match=r"000007\.bin: size 20 bytes is not a multiple of 16"):
        bin_format.read(path)


def test_bin_empty_file_is_an_empty_cloud(tmp_path):
    (tmp_path / "e.bin").write_bytes(b"")
    assert len(bin_format.read(tmp_path / "e.bin").points) == 0


def test_bin_nonfinite_policy(tmp_path):
    data = np.ones((5, 4), np.float32)
    data[1, 0] = np.nan
    data[3, 2] = np.inf
    data.tofile(tmp_path / "n.bin")
    with pytest.warns(NonFiniteWarning, match="dropped 2 point"):
        scene = bin_format.read(tmp_path / "n.bin")
    assert len(scene.points) == 3 and scene.metadata["dropped_nonfinite"] == 2
    with pytest.raises(DataFormatError, match=r"n\.bin: 2 point\(s\) have NaN/Inf coordinates"):
        bin_format.read(tmp_path / "n.bin", nonfinite="reject")
    data[:, :] = 1
    data[4, 3] = np.nan  # NaN intensity cannot be repaired
    data.tofile(tmp_path / "i.bin")
    with pytest.raises(DataFormatError, match="field 'intensity'"):
        bin_format.read(tmp_path / "i.bin")


def test_writers_never_replace_an_existing_file(tmp_path):
    path = tmp_path / "orig.bin"
    path.write_bytes(b"original")
    with pytest.raises(OutputExistsError, match="already exists"):
        bin_format.write_points(path, PointCloud(np.zeros((1, 4))))
    assert path.read_bytes() == b"original"
    assert [p.name for p in tmp_path.iterdir()] == ["orig.bin"]  # no temporary left behind


# ---------------------------------------------------------------- labels
def test_label_round_trip_with_dontcare_and_scores():
    text = (
        "Car 0.0 1 -1.5 100.0 150.0 300.0 250.0 1.5 1.6 3.9 2.0 1.6 20.0 -1.2\n"
        "DontCare -1 -1 -10 500.5 170.0 530.0 190.0 -1 -1 -1 -1000 -1000 -1000 -10\n"
    )
    boxes = parse_labels(text, CALIB)
    assert boxes.labels.tolist() == ["Car", "DontCare"]
    assert not boxes.has_geometry[1] and np.isnan(boxes.alpha[1]) and boxes.bbox2d[1].tolist() == [500.5, 170, 530, 190]
    again = parse_labels(format_labels(boxes, CALIB), CALIB)
    assert again.allclose(boxes, atol=1e-9)
    dets = boxes.select([0]).replace(scores=[0.875])
    assert parse_labels(format_labels(dets, CALIB), CALIB).scores.tolist() == [0.875]


@settings(max_examples=40, deadline=None)
@given(box_strategy())
def test_label_round_trip_property(boxes):
    again = parse_labels(format_labels(boxes, CALIB), CALIB)
    assert again.allclose(boxes, atol=1e-6)


def test_complete_fills_alpha_and_2d_box():
    boxes = Boxes3D.create([[15.0, 1.0, -0.9]], [[3.9, 1.6, 1.5]], [0.2], ["Car"])
    back = parse_labels(format_labels(boxes, CALIB, complete=True), CALIB)
    assert back.alpha[0] == pytest.approx(CALIB.alpha(boxes.as_array())[0])
    np.testing.assert_allclose(back.bbox2d[0], CALIB.boxes_to_image(boxes.as_array())[0])


def test_complete_leaves_boxes_beside_the_image_without_a_2d_box():
    # A car 15 m ahead but 40 m to the left (LiDAR y = 40) is in front of the camera (depth 15 m >
    # 0.1) and projects left of the image: u ≈ 721.5 · (-40 / 15) + 609.6 ≈ -1315 px for its centre,
    # all 8 corners below u = 0, so the clipped box is [0, v1, 0, v2], zero wide. Written as such, the
    # devkit would score a sliver at the edge; it must stay -1 (no 2D box), as relabel_in_image has it.
    boxes = Boxes3D.create([[15.0, 40.0, -0.9], [15.0, 1.0, -0.9]], [[3.9, 1.6, 1.5]] * 2, [0.2, 0.2], ["Car", "Car"])
    corners_u = CALIB.boxes_to_image(boxes.as_array(), clip=False)[0, [0, 2]]
    assert (corners_u < 0).all()  # the premise: wholly left of the image
    back = parse_labels(format_labels(boxes, CALIB, complete=True), CALIB)
    assert np.isnan(back.bbox2d[0]).all()
    assert back.bbox2d[1, 2] - back.bbox2d[1, 0] > 10  # the car in view keeps its projected box


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("Car 0 0 0 1 2 3 4 1 1 1 0 0 10", r"labels\.txt:1: expected 15 fields \(16 with a score\), found 14"),
        ("Bus 0 0 0 1 2 3 4 1 1 1 0 0 10 0", r"labels\.txt:1: field 'type': unknown class 'Bus'"),
        ("Car 0 0 0 1 2 3 4 1 -1.5 1 0 0 10 0", r"labels\.txt:1: field 'width': negative size -1.5"),
        ("Car 0 0 0 1 2 3 4 1 1 1 0 zero 10 0", r"labels\.txt:1: field 'y': 'zero' is not a number"),
        ("Car 0 7 0 1 2 3 4 1 1 1 0 0 10 0", r"field 'occluded': occlusion must be"),
    ],
)
def test_bad_label_lines(line, match):
    with pytest.raises(DataFormatError, match=match):
        parse_labels("\n" * 0 + line + "\n", CALIB, "labels.txt")


def test_labels_need_calib():
    with pytest.raises(DataFormatError, match="calib"):
        parse_labels("Car 0 0 0 1 2 3 4 1 1 1 0 0 10 0\n", None, "l.txt")


# ---------------------------------------------------------------- data sets
def test_kitti_log_round_trip(kitti_log, sample_scenes):
    dataset = open_dataset(kitti_log)
    assert isinstance(dataset, KittiLog) and dataset.ordered
    assert list(dataset.frame_ids()) == ["000000", "000001", "000002"]
    np.testing.assert_allclose(dataset.timestamps(), [0.0, 0.1, 0.2])
    for original, scene in zip(sample_scenes, dataset, strict=True):
        assert scene.points == original.points  # all 8 channels via the side file, bit-exact
        assert scene.boxes.allclose(original.boxes, atol=1e-9)
        assert scene.calib == original.calib and scene.roi == original.roi
        assert np.array_equal(scene.pose, original.pose)
        labelled = scene.boxes.select(scene.boxes.has_geometry)
        mask = points_in_boxes(scene.points.xyz, labelled.as_array())
        assert np.all(mask.sum(axis=0) > 0)
        assert scene.metadata["objects"] == original.metadata["objects"]  # points per object, visibility
    assert len(KittiDataset(kitti_log, subset="val")) == 1


def test_kitti_training_subfolder(tmp_path, sample_scenes):
    write_kitti(tmp_path / "kitti" / "training", sample_scenes[:1])
    assert len(open_dataset(tmp_path / "kitti")) == 1


def _copy(src, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(src, dst)
    return dst


def test_label_without_frame_and_frame_without_label(kitti_log, tmp_path):
    root = _copy(kitti_log, tmp_path)
    (root / "label_2" / "000009.txt").write_text("")
    with pytest.raises(DataFormatError, match=r"000009\.txt: label file without a point-cloud frame"):
        KittiDataset(root)
    (root / "label_2" / "000009.txt").unlink()
    (root / "label_2" / "000001.txt").unlink()
    # a frame without a label file is unlabelled, not an error (tests/io/test_unlabelled.py)
    dataset = KittiDataset(root)
    assert dataset.unlabelled_ids() == ["000001"]
    assert any("have no label file" in p.message and p.severity == "warning" for p in dataset.problems())


def test_duplicate_ids_in_image_sets(kitti_log, tmp_path):
    root = _copy(kitti_log, tmp_path)
    (root / "ImageSets" / "train.txt").write_text("000000\n000001\n000000\n")
    with pytest.raises(DataFormatError, match=r"train\.txt:3: duplicate frame id '000000'"):
        KittiDataset(root, subset="train")


def test_bad_calib_in_dataset_names_file(kitti_log, tmp_path):
    root = _copy(kitti_log, tmp_path)
    text = (root / "calib" / "000001.txt").read_text().replace("R0_rect", "R9_rect")
    (root / "calib" / "000001.txt").write_text(text)
    dataset = KittiDataset(root)
    dataset.load("000000")
    with pytest.raises(DataFormatError, match=r"calib/000001\.txt: missing key R0_rect"):
        dataset.load("000001")


def test_writer_refuses_non_empty_folder(kitti_log):
    with pytest.raises(DataFormatError, match="not empty"):
        KittiWriter(kitti_log)


def test_frames_without_any_labels_are_fine(tmp_path):
    scene = Scene(PointCloud(np.zeros((3, 4))), frame_id="a")
    write_kitti(tmp_path / "ds", [scene])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = open_dataset(tmp_path / "ds")["a"]
    assert len(loaded.boxes) == 0 and loaded.calib is None


@pytest.mark.parametrize(("values", "dtype"), [
    ([0, 1, 63], np.uint8), ([-1, 5], np.int8), ([-129, 5], np.int16), ([-1, 200], np.int16),
    ([40000, -3], np.int32), ([2**24, 1], np.int32), ([2**25], np.float32), ([1.5, 2], np.float32),
    ([np.nan, 1], np.float32), ([np.inf, 1], np.float32), ([-np.inf], np.float32), ([0.5, np.nan], np.float32),
    ([-0.0, 3], np.uint8), ([], np.float32),
])
def test_an_extra_channel_is_stored_in_the_smallest_integer_type_that_holds_it(values: list[float],
                                                                              dtype: type) -> None:
    """Integers within a type's range (and float32's exact 2**24) shrink; fractions, NaN and ±inf stay float32."""
    channel = np.array(values, np.float32)
    stored = compact_channel(channel)
    assert stored.dtype == dtype
    assert np.array_equal(stored.astype(np.float32), channel, equal_nan=True)


def _compact_channel_with_trunc(values: np.ndarray) -> np.ndarray:
    """The former computation: extremes, then a trunc comparison, then the smallest type."""
    v = np.asarray(values)
    if v.size == 0:
        return v
    lo, hi = float(v.min()), float(v.max())
    if not (np.isfinite(lo) and np.isfinite(hi)) or not np.array_equal(np.trunc(v), v):
        return v
    for dtype in (np.uint8, np.int8, np.int16, np.int32):
        info = np.iinfo(dtype)
        if info.min <= lo and hi <= info.max and hi <= 2**24:
            return v.astype(dtype)
    return v


def test_compact_channel_of_a_cloud_column_is_the_trunc_test() -> None:
    """Strided columns of a cloud (integers of every range, fractions, -0.0, NaN, values just past a
    type's bounds): the same dtype and the same .npy bytes as the former trunc comparison."""
    rng = np.random.default_rng(25)
    columns = [rng.integers(0, 64, 5000), rng.integers(-1, 40, 5000), rng.integers(-300, 300, 5000),
               rng.integers(-70000, 70000, 5000), rng.uniform(-0.05, 0.05, 5000), rng.integers(0, 255, 5000) + 0.5,
               np.where(rng.random(5000) < 0.5, -0.0, 3.0), np.r_[rng.integers(0, 9, 4999), np.nan],
               np.r_[rng.integers(0, 9, 4999), 256], np.r_[rng.integers(0, 9, 4999), -129], np.full(5000, 2.0**24),
               np.r_[rng.integers(-5, 9, 4999), 7.000001]]
    data = np.stack(columns, axis=1).astype(np.float32)
    for k in range(data.shape[1]):
        column = data[:, k]  # a strided view, as PointCloud.channel gives
        got, expected = compact_channel(column), _compact_channel_with_trunc(column)
        assert got.dtype == expected.dtype, k
        saved = []
        for array in (got, expected):
            buffer = io.BytesIO()
            np.save(buffer, array)
            saved.append(buffer.getvalue())
        assert saved[0] == saved[1], k
