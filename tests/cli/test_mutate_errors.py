"""``lidarfuzz mutate`` on logs and data sets that fail it: one line on stderr, exit code 2, and
nothing at the destination (issue 23).

The escape reported: ``mutate --op AVG --interleave`` on a log without rings printed a traceback and
left a partial folder. AVG now pairs points without rings (nearest neighbours); what is left to hold is
that any failure half-way (a frame that cannot be read, the operator failing on a frame) gives one line
and leaves no folder, for every kind of destination, and that option mistakes give one line, not a
usage box.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io import open_dataset, write_kitti
from lidarfuzz.operators import get
from lidarfuzz.operators.lidar.log import FrameAverage
from lidarfuzz.operators.mutate import mutate, mutate_log
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene

runner = CliRunner()


def lidarfuzz(*args: str) -> subprocess.CompletedProcess[str]:
    """Run the real entry point, as a user would."""
    return subprocess.run([sys.executable, "-c", "from lidarfuzz.cli.app import main; main()", *args],
                          capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def ringless_log(tmp_path_factory: pytest.TempPathFactory, sample_scenes: list[Scene]) -> Path:
    """The 3-frame sample log without its ring channel; frame 000001's scan truncated to 1,001 bytes
    (not a multiple of the 16-byte point: that frame cannot be read)."""
    root = tmp_path_factory.mktemp("ringless") / "log"
    write_kitti(root, [s.replace(points=s.points.without_channels(["ring"])) for s in sample_scenes])
    scan = root / "velodyne" / "000001.bin"
    scan.write_bytes(scan.read_bytes()[:1001])
    return root


def left_at(folder: Path) -> list[str]:
    """What a failed command left in ``folder``, temporary files included."""
    return sorted(p.name for p in folder.iterdir())


def test_avg_on_a_ringless_log_with_a_bad_frame_is_one_line_and_leaves_nothing(
        ringless_log: Path, tmp_path: Path) -> None:
    # Frame 000000 is read and written before 000001 fails: a partial destination would exist.
    result = lidarfuzz("mutate", str(ringless_log), str(tmp_path / "avg"), "--op", "AVG", "--interleave")
    assert result.returncode == 2, result.stderr
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("error: ")
    assert "000001.bin" in result.stderr and "not a multiple of 16" in result.stderr
    assert left_at(tmp_path) == []
    # the same through the API for the other kinds of destination: a log file, a ROS 1 bag, a folder of PCD
    for name, to in (("avg.mcap", None), ("avg.bag", None), ("avg_pcd", "pcd"), ("avg_db3", "ros2")):
        with pytest.raises(DataFormatError, match=r"000001\.bin"):
            mutate_log(ringless_log, tmp_path / name, FrameAverage(), to=to)
        assert left_at(tmp_path) == [], name


def test_avg_on_a_ringless_log_averages_nearest_points(sample_scenes: list[Scene], tmp_path: Path) -> None:
    # 3 readable frames without rings -> 3 frames and the 2 averages between them, paired by nearest
    # neighbours (no traceback, no refusal).
    src = tmp_path / "log"
    write_kitti(src, [s.replace(points=s.points.without_channels(["ring"])) for s in sample_scenes])
    result = runner.invoke(app, ["mutate", str(src), str(tmp_path / "avg"), "--op", "AVG", "--interleave"])
    assert result.exit_code == 0, result.output
    written = list(open_dataset(tmp_path / "avg"))
    assert len(written) == 5 and all(len(scene.points) for scene in written)


def test_mutating_a_data_set_with_a_bad_frame_leaves_no_folder(ringless_log: Path, tmp_path: Path) -> None:
    # Without --interleave: frame 000000's mutant was written before 000001 failed (the folder, its
    # calib/, label_2/ and velodyne/ were left behind before issue 23).
    for name, to in (("out", None), ("out_ply", "ply")):
        with pytest.raises(DataFormatError, match=r"000001\.bin"):
            mutate(ringless_log, tmp_path / name, get("HGT").at_severity(2), to=to)
    assert left_at(tmp_path) == []


def test_an_operator_failing_on_a_frame_is_one_line_naming_it(sample_scenes: list[Scene], tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    src = tmp_path / "src"
    write_kitti(src, sample_scenes)
    out = tmp_path / "out"

    def breaks(self: FrameAverage, first: Scene, second: Scene) -> Scene:
        raise FloatingPointError("overflow in the average")

    monkeypatch.setattr(FrameAverage, "apply", breaks)
    # interleave reads 000000, yields it, reads 000001, then averages the two: it fails after 000000
    with pytest.raises(LidarfuzzError, match="frame_average failed after frame 000000: FloatingPointError: overflow"):
        mutate_log(src, out, FrameAverage())
    hgt = get("HGT").at_severity(2)
    monkeypatch.setattr(type(hgt), "apply", lambda self, scene, params: breaks(FrameAverage(), scene, scene))
    with pytest.raises(LidarfuzzError, match="height_shift failed on frame 000000: FloatingPointError"):
        mutate(src, out, hgt)
    assert left_at(tmp_path) == ["src"]


def test_nearest_pairs_skip_points_that_are_not_finite() -> None:
    # a: NaN, (1, 1, 1), (5, 5, 5); b: (1.2, 1, 1), inf. Only (1, 1, 1)-(1.2, 1, 1) are within 0.5 m of
    # each other; the NaN and inf points have no neighbour (cKDTree refuses them: they were its error).
    a = PointCloud(np.array([[np.nan, 0, 0, 0], [1, 1, 1, 0], [5, 5, 5, 1]], np.float32), ("x", "y", "z", "intensity"))
    b = PointCloud(np.array([[1.2, 1, 1, 1], [np.inf, 0, 0, 0]], np.float32), ("x", "y", "z", "intensity"))
    pairs = FrameAverage().nearest_pairs(a, b)
    assert pairs[0].tolist() == [1] and pairs[1].tolist() == [0]
    averaged = FrameAverage().apply(Scene(a), Scene(b)).points
    assert len(averaged) == 4  # the pair averaged, the other three points kept
    np.testing.assert_allclose(averaged.data[0], [1.1, 1, 1, 0.5], rtol=1e-6)


def test_the_source_is_never_the_destination_nor_inside_it(sample_scenes: list[Scene], tmp_path: Path) -> None:
    src = tmp_path / "src"
    write_kitti(src, sample_scenes)
    before = sorted(str(p.relative_to(src)) for p in src.rglob("*"))
    hgt = get("HGT").at_severity(2)
    for dst in (src, src / "inside", tmp_path):  # tmp_path holds the source: replacing it would delete it
        with pytest.raises(LidarfuzzError, match="originals are never modified"):
            mutate(src, dst, hgt, overwrite=True)
        with pytest.raises(LidarfuzzError, match="originals are never modified"):
            mutate_log(src, dst, hgt, overwrite=True)
    assert sorted(str(p.relative_to(src)) for p in src.rglob("*")) == before


def test_option_mistakes_are_one_line(sample_scenes: list[Scene], tmp_path: Path) -> None:
    src = tmp_path / "src"
    write_kitti(src, sample_scenes)
    cases = [
        (["mutate", str(src), str(tmp_path / "a"), "--op", "AVG"], "error: --op: AVG combines consecutive frames"),
        (["mutate", str(src), str(tmp_path / "b"), "--op", "blur"], "error: --op: image_blur is a camera operator"),
        (["operators", "--modality", "radar"], "error: --modality: expected one of camera, lidar, got 'radar'"),
    ]
    for args, message in cases:
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output and "Usage:" not in result.output and "╭" not in result.output, result.output
    with pytest.raises(LidarfuzzError, match="unknown target format 'tiff'"):  # was a ValueError's traceback
        mutate(src, tmp_path / "c", get("HGT").at_severity(2), to="tiff")
    shutil.rmtree(src)
    assert left_at(tmp_path) == []
