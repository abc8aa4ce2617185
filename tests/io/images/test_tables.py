"""CSV-described image data sets: Udacity's interpolated.csv, driving_log.csv, a plain CSV."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io.dataset import Log
from lidarfuzz.io.images import TableImages, open_image_dataset
from tests.io.images.util import PIXELS, solid, write_jpeg, write_png

UDACITY_HEADER = "index,timestamp,width,height,frame_id,filename,angle,torque,speed,lat,long,alt"


def udacity(root: Path) -> Path:
    """Three cameras at two instants (rows not all of one camera; the centre rows in time order)."""
    write_png(root / "center" / "1479424215880976321.png")
    write_png(root / "center" / "1479424215930976321.png", PIXELS[::-1].copy())
    write_png(root / "left" / "1479424215880976000.png", solid(2, 3, (9, 9, 9)))
    write_png(root / "right" / "1479424215880977000.png", solid(2, 3, (8, 8, 8)))
    rows = [
        "0,1479424215880976321,3,2,center_camera,center/1479424215880976321.png,-0.0523598776,0.1,8.5,37.4,-122.1,-9.5",
        "1,1479424215880976000,3,2,left_camera,left/1479424215880976000.png,-0.0523598776,0.1,8.5,37.4,-122.1,-9.5",
        "2,1479424215880977000,3,2,right_camera,right/1479424215880977000.png,-0.0523598776,0.1,8.5,37.4,-122.1,-9.5",
        "3,1479424215930976321,3,2,center_camera,center/1479424215930976321.png,0.25,0.0,8.75,37.4,-122.1,-9.5",
    ]
    (root / "interpolated.csv").write_text("\n".join([UDACITY_HEADER, *rows]) + "\n", encoding="utf-8")
    return root


def test_udacity_centre_camera_is_an_ordered_log(tmp_path):
    ds = open_image_dataset(udacity(tmp_path))
    assert isinstance(ds, Log) and ds.format == "udacity"
    assert list(ds.frame_ids()) == ["1479424215880976321", "1479424215930976321"]  # the centre rows only
    first, second = ds[0], ds[1]
    assert np.array_equal(first.image, PIXELS) and np.array_equal(second.image, PIXELS[::-1])
    assert first.steering == -0.0523598776 and second.steering == 0.25  # radians, as written
    # 1479424215880976321 ns → s (float64 keeps ~0.2 µs at this magnitude)
    assert first.timestamp == pytest.approx(1479424215.880976321, abs=1e-6)
    assert ds.timestamps().tolist() == [first.timestamp, second.timestamp]
    assert first.metadata["speed"] == 8.5 and first.metadata["row"] == 2 and first.metadata["camera"] == "center"
    assert first.metadata["size"] == [2, 3]


def test_udacity_left_camera(tmp_path):
    ds = open_image_dataset(udacity(tmp_path), camera="left")
    assert list(ds.frame_ids()) == ["1479424215880976000"]
    assert ds[0].image[0, 0].tolist() == [9, 9, 9]


def test_udacity_unknown_camera_and_missing_column(tmp_path):
    root = udacity(tmp_path)
    with pytest.raises(LidarfuzzError, match="camera 'top' is not one of center, left, right"):
        open_image_dataset(root, camera="top")
    text = (root / "interpolated.csv").read_text().replace(",angle,", ",steer,")
    (root / "interpolated.csv").write_text(text)
    with pytest.raises(DataFormatError, match=r"interpolated\.csv:1: field 'angle': no column 'angle'; the header "
                                              "has index, timestamp"):
        open_image_dataset(root)


def test_udacity_size_column_is_checked_against_the_image(tmp_path):
    root = udacity(tmp_path)
    text = (root / "interpolated.csv").read_text().replace("0,1479424215880976321,3,2,", "0,1479424215880976321,4,2,")
    (root / "interpolated.csv").write_text(text)
    ds = open_image_dataset(root)
    with pytest.raises(DataFormatError, match=r"interpolated\.csv:2: field 'width': the image is 3×2 but the row "
                                              r"says 4×2"):
        ds.load("1479424215880976321")


def driving_log(root: Path, *, header: bool = False, absolute: str | None = None) -> Path:
    write_jpeg(root / "IMG" / "center_2016_12_01_13_30_48_287.jpg", solid(16, 16, (220, 30, 20)))
    write_jpeg(root / "IMG" / "left_2016_12_01_13_30_48_287.jpg", solid(16, 16, (20, 30, 220)))
    write_jpeg(root / "IMG" / "right_2016_12_01_13_30_48_287.jpg", solid(16, 16, (20, 220, 30)))
    prefix = absolute if absolute is not None else "IMG/"
    lines = ["center,left,right,steering,throttle,brake,speed"] if header else []
    lines.append(f"{prefix}center_2016_12_01_13_30_48_287.jpg, {prefix}left_2016_12_01_13_30_48_287.jpg, "
                 f"{prefix}right_2016_12_01_13_30_48_287.jpg,-0.05,0.9855,0,30.18")
    (root / "driving_log.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return root


@pytest.mark.parametrize("header", [False, True])
def test_driving_log_with_or_without_header(tmp_path, header):
    ds = open_image_dataset(driving_log(tmp_path, header=header))
    assert ds.format == "driving_log" and not ds.ordered
    assert list(ds.frame_ids()) == ["center_2016_12_01_13_30_48_287"]
    sample = ds[0]
    assert sample.steering == -0.05  # the simulator's normalised units, kept
    assert sample.image[8, 8, 0] > 200 and sample.image[8, 8, 2] < 40  # red stays red (RGB order)
    assert sample.metadata["throttle"] == 0.9855 and sample.metadata["speed"] == 30.18
    assert sample.metadata["row"] == (2 if header else 1)


def test_driving_log_left_camera_and_paths_of_another_machine(tmp_path):
    ds = open_image_dataset(driving_log(tmp_path, absolute="C:\\Users\\me\\Desktop\\data\\IMG\\"), camera="left")
    sample = ds[0]
    assert sample.image[8, 8, 2] > 200  # the left image (blue), found as IMG/<file name> beside the CSV
    assert sample.metadata["source"] == str(tmp_path / "IMG" / "left_2016_12_01_13_30_48_287.jpg")


def plain(root: Path, rows: list[str], header: str = "image,steering,speed") -> Path:
    write_png(root / "frames" / "a.png")
    write_png(root / "frames" / "b.png", solid(4, 5, (1, 2, 3)))
    (root / "labels.csv").write_text("\n".join([header, *rows]) + "\n", encoding="utf-8")
    return root


def test_plain_csv_and_mixed_sizes(tmp_path):
    ds = open_image_dataset(plain(tmp_path, ["frames/a.png,0.1,3", "frames/b.png,-0.2,4"]))
    assert isinstance(ds, TableImages) and ds.format == "csv"
    assert list(ds.frame_ids()) == ["a", "b"]
    assert ds["a"].steering == 0.1 and ds["b"].steering == -0.2 and ds["b"].metadata["speed"] == 4.0
    assert np.array_equal(ds["a"].image, PIXELS)
    # different sizes are allowed: each sample says its size and the data set counts them
    assert ds["b"].metadata["size"] == [4, 5]
    assert ds.image_sizes() == {(2, 3): 1, (4, 5): 1}


def test_plain_csv_named_columns(tmp_path):
    root = plain(tmp_path, ["frames/a.png,x,0.5"], header="img,note,wheel")
    with pytest.raises(DataFormatError, match=r"labels\.csv:1: field 'image': no image column \(looked for image, "):
        open_image_dataset(root)
    ds = open_image_dataset(root, image_column="img", steering_column="wheel")
    assert ds["a"].steering == 0.5 and ds["a"].metadata["note"] == "x"
    with pytest.raises(DataFormatError, match=r"labels\.csv:1: field 'angle': no column 'angle'"):
        open_image_dataset(root, image_column="img", steering_column="angle")


@pytest.mark.parametrize(("row", "message"), [
    ("frames/missing.png,0.1,3", r"labels\.csv:3: field 'image': image 'frames/missing\.png' does not exist"),
    ("frames/b.png,left,3", r"labels\.csv:3: field 'steering': 'left' is not a number"),
    ("frames/b.png,nan,3", r"labels\.csv:3: field 'steering': 'nan' is not a finite number"),
    ("frames/b.png,inf,3", r"labels\.csv:3: field 'steering': 'inf' is not a finite number"),
    ("frames/b.png,,3", r"labels\.csv:3: field 'steering': empty, expected a number"),
    ("frames/b.png,0.1,fast", r"labels\.csv:3: field 'speed': 'fast' is not a number"),
    ("frames/a.png,0.3,3", r"labels\.csv:3: field 'image': image 'frames/a\.png' is listed twice \(first on line 2\)"),
    ("frames/b.png", r"labels\.csv:3: field 'steering': the row has 1 cell\(s\), no value for this column"),
])
def test_bad_rows_name_file_line_and_column(tmp_path, row, message):
    root = plain(tmp_path, ["frames/a.png,0.1,3", row])
    with pytest.raises(DataFormatError, match=message) as info:
        open_image_dataset(root)
    assert info.value.path == root / "labels.csv" and info.value.line == 3


def test_lenient_opening_lists_bad_rows_and_keeps_the_good(tmp_path):
    root = plain(tmp_path, ["frames/a.png,0.1,3", "frames/missing.png,0.1,3", "frames/b.png,x,3"])
    ds = open_image_dataset(root, strict=False)
    assert list(ds.frame_ids()) == ["a"]
    assert [(p.severity, p.line) for p in ds.problems()] == [("error", 3), ("error", 4)]
    with pytest.raises(DataFormatError, match=r"labels\.csv:3: field 'image': image 'frames/missing\.png' does not "
                                              r"exist .*\(and 1 more problem"):
        open_image_dataset(root)


def test_truncated_image_names_the_file_and_the_csv_row(tmp_path):
    root = plain(tmp_path, ["frames/a.png,0.1,3"])
    path = root / "frames" / "a.png"
    path.write_bytes(path.read_bytes()[:-12])
    ds = open_image_dataset(root)  # opening checks existence only; decoding finds the damage
    with pytest.raises(DataFormatError, match=r"frames/a\.png: truncated PNG: no IEND chunk after \d+ bytes "
                                              r"\(named on line 2 of labels\.csv\)"):
        ds.load("a")


def test_several_csvs_are_ambiguous_but_the_file_itself_opens(tmp_path):
    root = plain(tmp_path, ["frames/a.png,0.1,3"])
    (root / "other.csv").write_text("x\n")
    with pytest.raises(DataFormatError, match=r"2 CSV files \(labels\.csv, other\.csv\)"):
        open_image_dataset(root)
    assert list(open_image_dataset(root / "labels.csv").frame_ids()) == ["a"]


def test_same_stem_in_two_folders_gets_path_ids(tmp_path):
    write_png(tmp_path / "run1" / "0001.png")
    write_png(tmp_path / "run2" / "0001.png")
    (tmp_path / "labels.csv").write_text("filename,angle\nrun1/0001.png,0\nrun2/0001.png,1\n")
    assert list(open_image_dataset(tmp_path).frame_ids()) == ["run1/0001", "run2/0001"]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(angles=st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64), min_size=1, max_size=6),
       bad=st.one_of(st.none(), st.sampled_from(["nan", "-inf", "0.1.2", "1e", "abc", "--1"])))
def test_angles_round_trip_exactly_and_a_bad_one_is_named(tmp_path, angles, bad):
    with tempfile.TemporaryDirectory(dir=tmp_path) as folder:
        root = Path(folder)
        write_png(root / "img.png")
        rows = [f"img.png,{angle!r}" for angle in angles[:1]]  # one image: each row below names a copy
        for i, angle in enumerate(angles[1:], start=1):
            write_png(root / f"img{i}.png")
            rows.append(f"img{i}.png,{angle!r}")
        if bad is not None:
            rows.insert(len(rows) // 2, f"img.png,{bad}")  # a bad angle (checked before the repeated image)
        (root / "labels.csv").write_text("image,steering\n" + "\n".join(rows) + "\n")
        if bad is None:
            ds = open_image_dataset(root)
            assert [ds[i].steering for i in range(len(ds))] == angles  # repr → float is exact
        else:
            line = 2 + rows.index(f"img.png,{bad}")  # the header is line 1
            with pytest.raises(DataFormatError) as info:
                open_image_dataset(root)
            assert info.value.line == line and info.value.field == "steering"
            assert str(info.value).startswith(f"{root / 'labels.csv'}:{line}: field 'steering': {bad!r} is not")
