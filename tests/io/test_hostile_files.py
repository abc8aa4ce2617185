"""Hostile files other than point-cloud frames: each escape the fuzzer found (``tests/fuzz/targets_files.py``)
with its minimised input built here, refused in one line that names the file and, where there is one,
the line or field. Expected messages are written from the file format's rules, not from the code's output."""

from __future__ import annotations

import io
import json
import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from lidarfuzz.campaign.spec import load_campaign
from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.open import open_dataset
from lidarfuzz.io.options import load_dataset_map
from lidarfuzz.io.textfiles import MAX_DEPTH
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.sim.sensor import load_sensor
from lidarfuzz.sim.spec import load_scene
from tests.fuzz.targets_files import _kitti_template


def refused(call: Callable[[], object], path: Path, pattern: str, *, line: int | None = None,
            field: str | None = None) -> DataFormatError:
    """``call()`` raises a one-line DataFormatError naming ``path`` (and ``line``/``field``) matching ``pattern``."""
    with pytest.raises(DataFormatError, match=pattern) as info:
        call()
    error = info.value
    text = str(error)
    assert "\n" not in text, text
    assert error.path == path, text
    assert text.startswith(str(path)), text
    assert error.line == line, text
    assert error.field == field, text
    return error


@pytest.fixture
def kitti(tmp_path: Path) -> Path:
    """A valid two-frame KITTI folder (labels, calib, timestamps, poses, ROI, extras) to damage."""
    root = tmp_path / "kitti"
    shutil.copytree(_kitti_template(), root)
    return root


def load_all(root: Path, **options: object) -> list[object]:
    dataset = open_dataset(root, **options)  # type: ignore[call-overload]
    return [dataset.load(frame_id) for frame_id in dataset.frame_ids()]


# -- KITTI side files --------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["timestamps.txt", "poses.txt", "ego.txt"])
def test_a_side_file_that_is_not_utf8_is_refused_naming_the_byte(kitti: Path, name: str) -> None:
    # was: UnicodeDecodeError from Path.read_text; byte 0xbe cannot start a UTF-8 sequence
    (kitti / name).write_bytes(b"000\xbe00 0.0\n")
    refused(lambda: load_all(kitti), kitti / name, r"not UTF-8 text \(byte 0xbe at offset 3\)")


def test_a_singular_pose_is_refused_naming_its_line(kitti: Path) -> None:
    # a world-frame map is moved by the pose's inverse; a zero rotation has none (numpy's LinAlgError)
    poses = kitti / "poses.txt"
    poses.write_text("000000 1 0 0 0 0 1 0 0 0 0 1 0\n000001 0 0 0 1 0 0 0 0 0 0 0 0\n", encoding="utf-8")
    refused(lambda: load_all(kitti), poses, r"the pose of frame '000001' has no inverse", line=2)


def test_an_infinite_timestamp_is_refused_naming_its_line(kitti: Path) -> None:
    stamps = kitti / "timestamps.txt"
    stamps.write_text("000000 0.0\n000001 1e999\n", encoding="utf-8")  # 1e999 overflows float64 to inf
    refused(lambda: load_all(kitti), stamps, r"not a finite number", line=2)


def test_an_image_set_that_is_not_utf8_is_refused(kitti: Path) -> None:
    listing = kitti / "ImageSets" / "train.txt"
    listing.write_bytes(b"\x81\n")  # 0x81 is a continuation byte: never first in UTF-8
    refused(lambda: load_all(kitti, subset="train"), listing, r"not UTF-8 text \(byte 0x81 at offset 0\)")


def test_a_frame_map_of_an_unknown_geometry_type_is_refused(kitti: Path) -> None:
    # was: shapely's GeometryTypeError from shape()
    roi = kitti / "roi" / "000000.json"
    roi.write_text('{"type": "multi/olygon", "coordinates": []}', encoding="utf-8")
    refused(lambda: load_all(kitti), roi, r"cannot read the drivable-area map: .*multi/olygon")


def test_a_frame_map_nested_too_deeply_is_refused_before_parsing(kitti: Path) -> None:
    roi = kitti / "roi" / "000000.json"
    roi.write_text("[" * 100_000, encoding="utf-8")
    refused(lambda: load_all(kitti), roi, rf"nested deeper than {MAX_DEPTH} levels", line=1)


@pytest.mark.parametrize(("track_ids", "field", "pattern"), [
    ([float("inf")], "track_ids.0", r"inf is not a 64-bit integer"),  # was: OverflowError in Boxes3D
    ([{"a": 1}], "track_ids.0", r"\{'a': 1\} is not a 64-bit integer"),  # was: TypeError in Boxes3D
    ([2**64], "track_ids.0", r"18446744073709551616 is not a 64-bit integer"),
    ([1, 2], "track_ids", r"expected a list of 1 integer\(s\), one per label line; found 2 value\(s\)"),
])
def test_track_ids_must_be_one_integer_per_label_line(kitti: Path, track_ids: list[object], field: str,
                                                      pattern: str) -> None:
    extra = kitti / "label_2_extra" / "000000.json"
    # json.dumps writes inf as Infinity, which json.loads reads back as float('inf')
    extra.write_text(json.dumps({"track_ids": track_ids}), encoding="utf-8")
    refused(lambda: load_all(kitti), extra, pattern, field=field)


def test_per_object_fields_that_are_not_an_object_are_refused(kitti: Path) -> None:
    extra = kitti / "label_2_extra" / "000000.json"
    extra.write_text("[1, 2]", encoding="utf-8")
    refused(lambda: load_all(kitti), extra, r"expected a JSON object, found list", field="<root>")


def _npz(**columns: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **columns)  # type: ignore[arg-type]
    return buffer.getvalue()


def test_extra_channels_that_are_not_a_zip_are_refused(kitti: Path) -> None:
    extra = kitti / "velodyne_extra" / "000000.npz"
    extra.write_bytes(b"PK\x05\x06" + b"\x00" * 10)  # an end-of-directory record cut short (was: BadZipFile)
    refused(lambda: load_all(kitti), extra, r"cannot read extra channels: .*zip")


def test_extra_channels_with_a_bad_crc_are_refused(kitti: Path) -> None:
    extra = kitti / "velodyne_extra" / "000000.npz"
    data = bytearray(_npz(ring=np.zeros(40, dtype=np.uint8)))
    data[data.index(b"\x93NUMPY") + 130] ^= 1  # the 40 values follow the 128-byte .npy header (stored, not deflated)
    extra.write_bytes(bytes(data))
    refused(lambda: load_all(kitti), extra, r"cannot read extra channels: BadZipFile: Bad CRC-32")


def test_extra_channels_claiming_a_huge_shape_are_refused_before_allocating(kitti: Path) -> None:
    # the header claims 10^12 values of 8 bytes (8 TB); the scan has 40 points
    header = b"{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000,), }"
    npy = b"\x93NUMPY\x01\x00" + (len(header) + 1).to_bytes(2, "little") + header + b"\n"
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("ring.npy", npy)
    extra = kitti / "velodyne_extra" / "000000.npz"
    extra.write_bytes(buffer.getvalue())
    refused(lambda: load_all(kitti), extra, r"holds values of shape \(1000000000000,\) \(float64\) but the scan "
            r"has 40 points", field="ring")


def test_extra_channels_of_text_are_refused(kitti: Path) -> None:
    extra = kitti / "velodyne_extra" / "000000.npz"
    extra.write_bytes(_npz(ring=np.array(["a"] * 40)))
    refused(lambda: load_all(kitti), extra, r"holds values of shape \(40,\) \(<U1\)", field="ring")


# -- calibration -------------------------------------------------------------------------------------

@pytest.mark.parametrize(("key", "line"), [("R0_rect", 5), ("Tr_velo_to_cam", 6)])
def test_a_singular_calibration_is_refused_naming_the_matrix(kitti: Path, key: str, line: int) -> None:
    # was: numpy's LinAlgError when labels were moved into the LiDAR frame; the default calib's lines are
    # P0, P1, P2, P3, R0_rect, Tr_velo_to_cam, Tr_imu_to_velo (1-based)
    calib = kitti / "calib" / "000000.txt"
    lines = calib.read_text(encoding="utf-8").splitlines()
    assert lines[line - 1].startswith(f"{key}:")
    lines[line - 1] = f"{key}: " + " ".join(["0"] * (9 if key == "R0_rect" else 12))
    calib.write_text("\n".join(lines) + "\n", encoding="utf-8")
    refused(lambda: load_all(kitti), calib, r"not invertible", line=line, field=key)


def test_a_nearly_singular_rotation_is_refused() -> None:
    # rows 1 and 2 differ by 1e-14: the condition number is ~1e14, past the 1e12 that keeps digits
    text = KittiCalibration.default().to_text().replace("R0_rect: 1.0 0.0 0.0 0.0 1.0 0.0",
                                                        "R0_rect: 1.0 0.0 0.0 1.0 1e-14 0.0")
    refused(lambda: KittiCalibration.parse(text, Path("c.txt")), Path("c.txt"), r"not invertible", line=5,
            field="R0_rect")


def test_a_label_file_that_is_not_utf8_is_refused(kitti: Path) -> None:
    label = kitti / "label_2" / "000000.txt"
    label.write_bytes(b"Car \xff")
    refused(lambda: load_all(kitti), label, r"not UTF-8 text \(byte 0xff at offset 4\): expected KITTI label lines")


def test_a_log_whose_timestamps_cannot_be_read_says_why(kitti: Path) -> None:
    # inspected leniently (lidarfuzz info), the reason the log has no timestamps is the file's problem,
    # not "a log needs timestamps.txt" beside a timestamps.txt that is there
    stamps = kitti / "timestamps.txt"
    stamps.write_text("000000 zero\n", encoding="utf-8")
    refused(lambda: open_dataset(kitti, strict=False), stamps, r"^.*:1: not a number$", line=1)


# -- logs --------------------------------------------------------------------------------------------

@pytest.fixture
def ros2_bag(tmp_path: Path) -> Path:
    from tests.fuzz.targets_files import _ros2_template

    bag = tmp_path / "bag"
    shutil.copytree(_ros2_template(), bag)
    return bag


def test_a_ros2_metadata_nested_too_deeply_is_refused_before_rosbags_parses_it(ros2_bag: Path) -> None:
    # was: over 10 s in rosbags' YAML parser (the fuzzer's hang) for 2,000 "[" on one line
    metadata = ros2_bag / "metadata.yaml"
    text = metadata.read_text(encoding="utf-8")
    metadata.write_text(text.replace("rosbag2_bagfile_information:\n",
                                     "rosbag2_bagfile_information:\n  ros_distro: " + "[" * 2000 + "\n", 1),
                        encoding="utf-8")
    refused(lambda: load_all(ros2_bag), metadata, rf"nested deeper than {MAX_DEPTH} levels", line=2)


def test_a_ros2_topic_without_a_name_is_refused(ros2_bag: Path) -> None:
    # was: TypeError joining the topic names (None among them) for the error message
    metadata = ros2_bag / "metadata.yaml"
    text = metadata.read_text(encoding="utf-8")
    assert text.count("name: /points") == 1
    metadata.write_text(text.replace("name: /points", "name:"), encoding="utf-8")
    refused(lambda: load_all(ros2_bag), ros2_bag, r"cannot list the topics: ValueError: a topic is named None")


# -- camera images -----------------------------------------------------------------------------------

def _png(height: int = 3, width: int = 4) -> bytes:
    ok, buffer = cv2.imencode(".png", np.full((height, width, 3), 77, dtype=np.uint8))
    assert ok
    return bytes(buffer.tobytes())


def test_a_png_with_a_bad_crc_is_refused_before_libpng_sees_it(kitti: Path) -> None:
    # was: "libpng error: IHDR: CRC error" on stderr beside the refusal; the IHDR chunk starts at byte 8
    data = bytearray(_png())
    data[23] ^= 1  # the height's low byte (IHDR's data: width at bytes 16-19, height at 20-23): 3 becomes 2
    image = kitti / "image_2" / "000000.png"
    image.write_bytes(bytes(data))
    refused(lambda: load_all(kitti, modality="camera"), image, r"corrupt PNG: chunk 'IHDR' at byte 8 fails its CRC")


def test_a_png_whose_image_data_is_not_zlib_is_refused(kitti: Path) -> None:
    # an IDAT chunk of bytes that are no zlib stream, with a CRC that matches them
    import zlib

    data = _png()
    start = data.index(b"IDAT") - 4
    length = int.from_bytes(data[start:start + 4], "big")
    body = b"\xff" * length
    chunk = length.to_bytes(4, "big") + b"IDAT" + body + zlib.crc32(b"IDAT" + body).to_bytes(4, "big")
    image = kitti / "image_2" / "000000.png"
    image.write_bytes(data[:start] + chunk + data[start + 12 + length:])
    refused(lambda: load_all(kitti, modality="camera"), image, r"corrupt PNG: its image data is not a valid zlib")


def test_a_singular_camera_projection_is_refused_by_the_camera_only(kitti: Path) -> None:
    # LiDAR-only data sets may write a placeholder P2 of zeros: the LiDAR frames still load; the camera
    # modality needs P2's inverse (the camera's pose: numpy's LinAlgError) and refuses it
    calib = kitti / "calib" / "000000.txt"
    lines = calib.read_text(encoding="utf-8").splitlines()
    assert lines[2].startswith("P2:")
    lines[2] = "P2: " + " ".join(["0"] * 12)
    calib.write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert len(load_all(kitti)) == 2
    refused(lambda: load_all(kitti, modality="camera"), calib, r"its 3×3 part is not invertible: not a camera "
            r"projection", field="P2")


def test_a_missing_camera_projection_is_refused_naming_it(kitti: Path) -> None:
    shutil.copytree(kitti / "image_2", kitti / "image_3")
    calib = kitti / "calib" / "000000.txt"
    calib.write_text("".join(line + "\n" for line in calib.read_text(encoding="utf-8").splitlines()
                             if not line.startswith("P3:")), encoding="utf-8")
    refused(lambda: load_all(kitti, modality="camera", camera="image_3"), calib, r"no P3", field="P3")


def test_a_table_naming_an_image_too_long_for_the_system_is_refused(tmp_path: Path) -> None:
    # was: OSError [Errno 36] File name too long from Path.is_file
    table = tmp_path / "images.csv"
    table.write_text("image,steering\n" + "a" * 5000 + ".png,0.1\n", encoding="utf-8")
    refused(lambda: load_all(table, modality="camera"), table, r"does not exist", line=2, field="image")


# -- data-set maps -----------------------------------------------------------------------------------

def test_a_map_number_of_5000_digits_is_refused(tmp_path: Path) -> None:
    # was: ValueError "Exceeds the limit (4300 digits) for integer string conversion" from json.loads
    path = tmp_path / "map.geojson"
    path.write_text('{"type": "Polygon", "coordinates": [[[' + "9" * 5000 + ", 0]]]}", encoding="utf-8")
    refused(lambda: load_dataset_map(path), path, r"cannot read the ROI map: .*4300 digits")


def test_a_map_whose_polygons_cannot_be_joined_is_refused(tmp_path: Path) -> None:
    # a bow tie crossing itself at (0.5, 0.5) beside a square: GEOS's TopologyException on the union
    path = tmp_path / "map.geojson"
    path.write_text(json.dumps({"type": "MultiPolygon", "coordinates": [
        [[[0, 0], [1, 1], [1, 0], [0, 1], [0, 0]]], [[[0, 0], [2, 0], [2, 2], [0, 2], [0, 0]]]]}), encoding="utf-8")
    refused(lambda: load_dataset_map(path), path, r"cannot join the map's polygons: .*TopologyException")


def test_a_map_nested_too_deeply_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "map.geojson"
    path.write_text('{"type": "Polygon", "coordinates":\n' + "[" * 5000 + "]" * 5000 + "}", encoding="utf-8")
    refused(lambda: load_dataset_map(path), path, rf"nested deeper than {MAX_DEPTH} levels", line=2)


# -- campaign, scene and sensor files ----------------------------------------------------------------

@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 50_000])  # ours to refuse; libyaml >= 0.2.6 stops at 1,000
@pytest.mark.parametrize("load", [load_campaign, load_scene, load_sensor])
def test_a_description_nested_too_deeply_is_refused_with_its_line(tmp_path: Path, load: Callable[[Path], object],
                                                                  depth: int) -> None:
    # was: RecursionError from PyYAML's composer
    path = tmp_path / "deep.yaml"
    path.write_text("name: x\noperators: " + "[" * depth + "]" * depth + "\n", encoding="utf-8")
    refused(lambda: load(path), path, rf"nested deeper than {MAX_DEPTH} levels", line=2)


def test_a_json_campaign_nested_too_deeply_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "campaign.json"
    path.write_text('{"dataset": "sim",\n "sut": ' + '{"a": ' * 200 + "1" + "}" * 200 + "}", encoding="utf-8")
    refused(lambda: load_campaign(path), path, rf"nested deeper than {MAX_DEPTH} levels", line=2)


@pytest.mark.parametrize("load", [load_campaign, load_scene, load_sensor])
def test_a_number_of_5000_digits_is_refused_with_its_line(tmp_path: Path, load: Callable[[Path], object]) -> None:
    # was: ValueError "Exceeds the limit (4300 digits)" from PyYAML's int constructor
    path = tmp_path / "big.yaml"
    path.write_text("name: x\nseed: " + "9" * 5000 + "\n", encoding="utf-8")
    refused(lambda: load(path), path, r"a number of 5,000 digits \(at most 4,000\)", line=2)


def test_aliases_that_expand_without_bound_are_refused(tmp_path: Path) -> None:
    # nine levels of ten aliases each: 10^9 values once expanded, from a file of 400 bytes
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    path = tmp_path / "laughs.yaml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    # a list counts with its items: a0 holds 11 values, a1 1 + 10 × 11 = 111, ..., a5 (line 6) 1,111,111,
    # the first past the 10^6 allowed
    refused(lambda: load_campaign(path), path, r"expands to more than 1,000,000 values", line=6)


def test_a_control_character_is_refused_in_one_line(tmp_path: Path) -> None:
    # was: PyYAML's two-line "unacceptable character" message, with a "  in <unicode string>" line
    path = tmp_path / "campaign.yaml"
    path.write_text("name: a\x01b\n", encoding="utf-8")
    refused(lambda: load_campaign(path), path, r"not valid YAML/JSON: unacceptable character #x0001", line=1)


def test_a_control_character_is_refused_naming_its_line(tmp_path: Path) -> None:
    path = tmp_path / "scene.yaml"
    path.write_text("name: a\nroad: b\x1dc\n", encoding="utf-8")  # 0x1d (group separator) on line 2
    refused(lambda: load_scene(path), path, r"unacceptable character #x001d", line=2)


def test_a_campaign_that_is_not_utf8_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "campaign.yaml"
    path.write_bytes(b"name: \xc3\x28\n")  # 0xc3 needs a continuation byte; 0x28 is not one
    refused(lambda: load_campaign(path), path, r"not UTF-8 text \(byte 0xc3 at offset 6\): expected a campaign file")


def test_a_sensor_with_more_rays_than_simulated_is_refused(tmp_path: Path) -> None:
    # 1,024 beams × 100,000 columns = 102,400,000 rays: a frame's buffers of several GB; at most 2^22 = 4,194,304
    path = tmp_path / "sensor.yaml"
    path.write_text("elevations_deg: [" + ", ".join(["0.0"] * 1024) + "]\ncolumns: 100000\nmax_range: 100\n",
                    encoding="utf-8")
    error = refused(lambda: load_sensor(path), path, r"1024 beams × 100000 columns = 102,400,000 rays per revolution",
                    field="<root>")
    assert "4,194,304" in str(error)


def test_a_sensor_with_too_many_beams_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "sensor.yaml"
    path.write_text("elevations_deg: [" + ", ".join(["0.0"] * 1025) + "]\ncolumns: 10\nmax_range: 100\n",
                    encoding="utf-8")
    refused(lambda: load_sensor(path), path, r"at most 1024 items", field="elevations_deg")


@pytest.mark.parametrize(("load", "text", "field"), [
    (load_sensor, "preset: VLP-16\nmax_range: .inf\n", "max_range"),  # YAML's infinity
    (load_scene, "ego: {speed: .nan}\n", "ego.speed"),
])
def test_non_finite_numbers_are_refused_naming_the_key(tmp_path: Path, load: Callable[[Path], object], text: str,
                                                       field: str) -> None:
    path = tmp_path / "file.yaml"
    path.write_text(text, encoding="utf-8")
    refused(lambda: load(path), path, r"finite number", field=field)


@pytest.mark.parametrize(("stamp", "pattern"), [
    ("-1.0", r"scene 0 \(frame '000000'\): timestamp -1.0 cannot be stored in a log"),
    # 1e300 s after the epoch is past ROS 1's unsigned 32-bit seconds (2^31 s is where the writer stops)
    ("1e300", r"timestamp 1e\+300 s is too large for this log kind \(at most 2,147,483,648 s\)"),
])
def test_converting_a_timestamp_no_log_can_hold_is_refused(kitti: Path, tmp_path: Path, stamp: str,
                                                           pattern: str) -> None:
    # was: a ValueError's traceback from `lidarfuzz convert` (and nothing is left at the destination)
    from lidarfuzz.io.convert import convert

    (kitti / "timestamps.txt").write_text(f"000000 {stamp}\n000001 0.5\n", encoding="utf-8")
    destination = tmp_path / "out.bag"
    # frames are in time order: a negative stamp is scene 0, 1e300 is scene 1; both are frame 000000
    refused(lambda: convert(kitti, destination), kitti / "velodyne" / "000000.bin", pattern, field="timestamp")
    assert not destination.exists()


def test_a_udacity_timestamp_of_5000_digits_is_refused(tmp_path: Path) -> None:
    # was: ValueError "Exceeds the limit (4300 digits)" from int(); as a float the number is infinite
    (tmp_path / "center").mkdir()
    (tmp_path / "center" / "a.png").write_bytes(_png())
    table = tmp_path / "interpolated.csv"
    table.write_text("index,timestamp,width,height,frame_id,filename,angle\n"
                     f"0,{'9' * 5000},4,3,center_camera,center/a.png,0.05\n", encoding="utf-8")
    refused(lambda: load_all(table, modality="camera"), table, r"'99999999999999999999'… \(5,000 characters\) is not a "
            r"finite number$", line=2, field="timestamp")


def test_a_sensor_naming_a_file_as_its_preset_is_refused(tmp_path: Path) -> None:
    # was: the file read as its own preset again and again, until RecursionError
    path = tmp_path / "sensor.yaml"
    path.write_text(f"preset: {path}\ncolumns: 10\n", encoding="utf-8")
    refused(lambda: load_sensor(path), path, r"is not a sensor preset \(HDL-64E, HDL-32E, VLP-16, OS1-64\)",
            field="preset")


def test_an_operator_without_a_name_is_refused_naming_it(tmp_path: Path) -> None:
    # was: AttributeError ('NoneType' object has no attribute 'strip') from the default-severities validator
    path = tmp_path / "campaign.yaml"
    path.write_text("dataset: sim\nsut: classic\noperators:\n  - name:\n", encoding="utf-8")
    refused(lambda: load_campaign(path), path, r"Input should be a valid string", field="operators.0.name")


def test_a_map_coordinate_too_large_for_a_float_is_refused(tmp_path: Path) -> None:
    # was: OverflowError "int too large to convert to float" from shapely (a 400-digit integer < 4,300 digits)
    path = tmp_path / "map.geojson"
    path.write_text('{"type": "Polygon", "coordinates": [[[0, 0], [' + "1" * 400 + ", 0], [0, 1], [0, 0]]]}",
                    encoding="utf-8")
    refused(lambda: load_dataset_map(path), path, r"not a valid Polygon: OverflowError: int too large to convert",
            field="coordinates")


def test_an_mcap_chunk_claiming_a_terabyte_is_refused_before_decompressing(tmp_path: Path) -> None:
    # MCAP's footer (opcode 0x02: summary_start u64, summary_offset_start u64, summary_crc u32) sits before the
    # closing 8-byte magic; the summary's ChunkIndex record (opcode 0x08) ends with uncompressed_size (u64)
    import struct

    from lidarfuzz.io.logs.writers import write_log
    from tests.fuzz.targets_files import _scenes

    path = write_log(tmp_path / "log.mcap", _scenes())  # type: ignore[arg-type]
    data = bytearray(path.read_bytes())
    footer = len(data) - 8 - 29
    assert data[footer] == 0x02
    at = struct.unpack_from("<Q", data, footer + 9)[0]
    while data[at] != 0x08:
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    end = at + 9 + struct.unpack_from("<Q", data, at + 1)[0]
    struct.pack_into("<Q", data, end - 8, 1 << 40)
    struct.pack_into("<I", data, footer + 25, 0)  # summary CRC 0: not checked
    path.write_bytes(bytes(data))
    refused(lambda: load_all(path), path, r"chunk 0 claims 1,099,511,627,776 bytes once decompressed "
            r"\(at most 1,073,741,824\)", field="chunk index")


def test_a_ros2_metadata_value_of_600000_characters_is_refused(ros2_bag: Path) -> None:
    # was: over 10 s (the fuzzer's hang) in rosbags' pure-Python YAML parser; rosbag2 writes values of ~1 KB
    metadata = ros2_bag / "metadata.yaml"
    text = metadata.read_text(encoding="utf-8")
    assert text.count("path: bag.db3") == 1
    metadata.write_text(text.replace("path: bag.db3", "path: bag.db3" + "A" * 600_000), encoding="utf-8")
    line = text[:text.index("path: bag.db3")].count("\n") + 1
    refused(lambda: load_all(ros2_bag), metadata, r"a value of 600,007 characters \(at most 65,536\)", line=line)


@pytest.mark.parametrize("load", [load_scene, load_campaign])
def test_a_negative_seed_is_refused_naming_it(tmp_path: Path, load: Callable[[Path], object]) -> None:
    # was: `lidarfuzz gen --scene` printed numpy's traceback (SeedSequence takes non-negative integers)
    path = tmp_path / "file.yaml"
    path.write_text("dataset: sim\nsut: classic\noperators: [{name: fog}]\nseed: -5\n", encoding="utf-8")
    if load is load_scene:
        path.write_text("seed: -5\n", encoding="utf-8")
    refused(lambda: load(path), path, r"greater than or equal to 0", field="seed")


def test_a_ros2_metadata_that_is_not_yaml_is_refused_with_its_line(ros2_bag: Path) -> None:
    # was: 25 s in rosbags' pure-Python parser to find the missing ':' after a line of a million characters
    metadata = ros2_bag / "metadata.yaml"
    text = metadata.read_text(encoding="utf-8")
    lines = text.splitlines()
    lines.insert(3, "  " + "1 " * 500_000)  # a plain scalar where a key is expected: no ':' follows
    metadata.write_text("\n".join(lines) + "\n", encoding="utf-8")
    # inserted as line 4; the scanner finds the ':' missing where the next line (5) begins
    refused(lambda: load_all(ros2_bag), metadata, r"not valid YAML: could not find expected ':'", line=5)


@pytest.mark.parametrize(("line", "field", "pattern"), [
    # was: IndexError (a ring index of -9.2e18) and ValueError (NaN to int) tracebacks from `lidarfuzz gen --sensor`
    ("mount_height: -1.0e+300", "mount_height", r"greater than 0"),
    ("rotation_hz: 1.0e-300", "rotation_hz", r"greater than or equal to 0.1"),
    ("max_range: 1.0e+300", "max_range", r"less than or equal to 10000"),
])
def test_a_sensor_value_beyond_any_sensor_is_refused(tmp_path: Path, line: str, field: str, pattern: str) -> None:
    path = tmp_path / "sensor.yaml"
    path.write_text(f"preset: VLP-16\n{line}\n", encoding="utf-8")
    refused(lambda: load_sensor(path), path, pattern, field=field)


def test_a_scene_number_beyond_10_km_is_refused_naming_its_key(tmp_path: Path) -> None:
    # was: numpy's "Maximum allowed size exceeded" traceback from `lidarfuzz gen --scene`: a building wall of
    # 10^300 m asked for a window pane every 3 m
    path = tmp_path / "scene.yaml"
    path.write_text("objects:\n  - {kind: building, footprint: [[5, -9.5], [1e300, -9.5], [40, -30]], height: 12}\n",
                    encoding="utf-8")
    refused(lambda: load_scene(path), path, r"1e\+300 is beyond ±10,000", field="objects.0.footprint.1.0")


@pytest.mark.parametrize(("target", "index", "field"), [
    ("mcap", 4412, "point_step"),  # a PointCloud2 declaring 2^31 + 20 bytes per point: numpy's dtype overflowed
    ("image-log-mcap", 1156, "log_time"),  # a message stamped past 2^63 - 1 ns: an OverflowError building int64 times
])
def test_escapes_of_the_full_fuzzing_run_are_refused(tmp_path: Path, target: str, index: int, field: str) -> None:
    # the cases benchmarks/fuzz_files.py --cases 10000 (seed 23) found, regenerated from the seeds: the
    # harness's mutations are a function of (seed, target, case index)
    from tests.fuzz.harness import mutate
    from tests.fuzz.targets_files import TARGETS

    chosen = next(t for t in TARGETS if t.name == target)
    seeds = [s for s in chosen.seeds(tmp_path / "seeds") if s]
    case = tmp_path / "case" / chosen.filename
    case.parent.mkdir()
    case.write_bytes(mutate(seeds, 23, target, index))
    with pytest.raises(DataFormatError, match=f"field '{field}'"):
        chosen.read(case)
