import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from lidarfuzz import __version__
from lidarfuzz.cli.app import app
from lidarfuzz.io import open_dataset

runner = CliRunner()


def lidarfuzz(*args: str) -> subprocess.CompletedProcess[str]:
    """Run the real entry point, as a user would."""
    return subprocess.run([sys.executable, "-c", "from lidarfuzz.cli.app import main; main()", *args],
                          capture_output=True, text=True, timeout=120)


def test_version_and_help():
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and __version__ in result.output
    for command in ([], ["info"], ["convert"], ["demo"], ["gen"], ["operators"], ["mutate"]):
        result = runner.invoke(app, [*command, "--help"])
        assert result.exit_code == 0, result.output
        assert "Usage" in result.output


def test_info_on_kitti_log_reports_no_problems(kitti_log, tmp_path):
    out = tmp_path / "report.json"
    result = runner.invoke(app, ["info", str(kitti_log), "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "no problems found" in result.output
    report = json.loads(out.read_text())
    assert report["frames"] == 3 and report["classes"]["Car"] > 0 and report["ordered"]
    assert set(report["channels"]) == {"x", "y", "z", "intensity", "ring", "time", "label", "instance"}


def test_info_exit_code_and_problem_listing(kitti_log, tmp_path):
    import shutil

    root = tmp_path / "broken"
    shutil.copytree(kitti_log, root)
    (root / "label_2" / "000002.txt").write_text("Car 0 0 0 1 2 3\n")
    result = runner.invoke(app, ["info", str(root)])
    assert result.exit_code == 1
    assert "000002.txt:1" in result.output and "expected 15 fields" in result.output


def test_convert_log_to_mcap_and_back_to_kitti(kitti_log, tmp_path):
    mcap = tmp_path / "log.mcap"
    result = runner.invoke(app, ["convert", str(kitti_log), str(mcap)])
    assert result.exit_code == 0, result.output
    back = tmp_path / "back"
    assert runner.invoke(app, ["convert", str(mcap), str(back)]).exit_code == 0
    original, converted = open_dataset(kitti_log), open_dataset(back)
    assert [s.points for s in original] == [s.points for s in converted]


def test_convert_frame_to_each_format(kitti_log, tmp_path):
    frame = kitti_log / "velodyne" / "000000.bin"
    for suffix in (".pcd", ".ply", ".las", ".laz", ".npy", ".npz"):
        result = runner.invoke(app, ["convert", str(frame), str(tmp_path / f"f{suffix}")])
        assert result.exit_code == 0, result.output
        assert np.array_equal(open_dataset(tmp_path / f"f{suffix}")[0].points.data,
                              open_dataset(frame)[0].points.data)


def test_convert_folder_of_pcd(kitti_log, tmp_path):
    result = runner.invoke(app, ["convert", str(kitti_log), str(tmp_path / "pcds"), "--to", "pcd"])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "pcds").iterdir()) == ["000000.pcd", "000001.pcd", "000002.pcd"]


@pytest.mark.parametrize(
    ("make", "args", "message"),
    [
        (lambda d: (d / "bad.bin").write_bytes(b"\0" * 17), ["convert", "{d}/bad.bin", "{d}/x.pcd"],
         "not a multiple of 16"),
        (lambda d: None, ["info", "{d}/missing.bin"], "no such file or folder"),
        (lambda d: (d / "x.txt").write_text("hi"), ["info", "{d}/x.txt"], "unsupported file type '.txt'"),
        (lambda d: (d / "a.bin").write_bytes(b"\0" * 16), ["convert", "{d}/a.bin", "{d}/a.bin"],
         "the destination is the source"),
        (lambda d: (d / "a.bin").write_bytes(b"\0" * 16), ["convert", "{d}/a.bin", "{d}/out", "--to", "xyz"],
         "'xyz' is not one of"),
    ],
)
def test_user_errors_are_one_clear_line(tmp_path, make, args, message):
    make(tmp_path)
    result = lidarfuzz(*(a.format(d=tmp_path) for a in args))
    assert result.returncode == 2, result.stderr
    assert message in result.stderr and "Traceback" not in result.stderr


def test_info_reports_a_broken_frame_as_a_problem(tmp_path):
    (tmp_path / "bad.bin").write_bytes(b"\0" * 17)
    result = lidarfuzz("info", str(tmp_path / "bad.bin"))
    assert result.returncode == 1
    assert "bad.bin: size 17 bytes is not a multiple of 16" in result.stdout


def test_convert_refuses_to_overwrite(tmp_path, kitti_log):
    (tmp_path / "out.pcd").write_text("keep me")
    result = lidarfuzz("convert", str(kitti_log / "velodyne" / "000000.bin"), str(tmp_path / "out.pcd"))
    assert result.returncode == 2 and "already exists" in result.stderr
    assert (tmp_path / "out.pcd").read_text() == "keep me"


# ---------------------------------------------------------------- gen
def test_gen_writes_a_data_set_that_info_accepts(tmp_path):
    out = tmp_path / "world"
    result = lidarfuzz("gen", "--frames", "2", "--seed", "5", "--out", str(out), "--sensor", "VLP-16", "--workers", "1")
    assert result.returncode == 0, result.stderr
    assert "wrote 2 frame(s)" in result.stdout and "frames/s" in result.stdout
    info = lidarfuzz("info", str(out))
    assert info.returncode == 0 and "no problems found" in info.stdout
    again = lidarfuzz("gen", "--frames", "2", "--seed", "5", "--out", str(out), "--sensor", "VLP-16")
    assert again.returncode == 2 and "--overwrite" in again.stderr and str(out) in again.stderr


def test_gen_sequence_from_a_scene_file(tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text("roads:\n  - centerline: [[-100, 0], [200, 0]]\n"
                     "actors:\n  - {class: Pedestrian, position: [30, -5.6], yaw: 90, speed: 1.2}\n"
                     "ego: {speed: 8, position: [0, -1.75]}\n")
    out = tmp_path / "log"
    result = runner.invoke(app, ["gen", "--frames", "3", "--out", str(out), "--scene", str(scene),
                                 "--sensor", "VLP-16", "--workers", "1"])
    assert result.exit_code == 0, result.output
    log = open_dataset(out)
    assert log.ordered and len(log) == 3
    assert (out / "scene.yaml").is_file()


def test_gen_bad_inputs_give_one_clear_line(tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("actors:\n  - {class: Tractor, position: [1, 2]}\n")
    result = lidarfuzz("gen", "--frames", "1", "--out", str(tmp_path / "a"), "--scene", str(broken))
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and str(broken) in result.stderr and "actors.0" in result.stderr
    result = lidarfuzz("gen", "--frames", "1", "--out", str(tmp_path / "b"), "--sensor", "HDL-128")
    assert result.returncode == 2 and "HDL-128" in result.stderr and "preset" in result.stderr
    result = lidarfuzz("gen", "--frames", "1", "--out", str(tmp_path / "c"), "--kind", "rural")
    assert result.returncode == 2 and "--kind" in result.stderr
    assert not (tmp_path / "a").exists() and not (tmp_path / "c").exists()


def test_gen_killed_midway_resumes_to_the_same_bytes(tmp_path):
    import hashlib
    import os
    import signal
    import time

    def digest(root):
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file() and p.name != "lidarfuzz_sim.json"}

    args = ["gen", "--frames", "12", "--seed", "2", "--sensor", "VLP-16", "--workers", "1"]
    out = tmp_path / "killed"
    process = subprocess.Popen([sys.executable, "-c", "from lidarfuzz.cli.app import main; main()", *args,
                                "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while len(list((out / "velodyne").glob("*.bin"))) < 3 and time.monotonic() < deadline:
        time.sleep(0.02)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    written = len(list((out / "velodyne").glob("*.bin")))
    assert 3 <= written < 12, "the run finished before it could be killed"
    again = lidarfuzz(*args, "--out", str(out))
    assert again.returncode == 2 and "--resume" in again.stderr
    resumed = lidarfuzz(*args, "--out", str(out), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    assert "kept from the interrupted run" in resumed.stdout
    fresh = tmp_path / "fresh"
    assert lidarfuzz(*args, "--out", str(fresh)).returncode == 0
    assert digest(out) == digest(fresh)


# ---------------------------------------------------------------- operators, mutate
def test_operators_lists_the_registry_and_shows_one():
    result = runner.invoke(app, ["operators"], env={"COLUMNS": "200"})
    assert result.exit_code == 0 and "uniform_point_deletion" in result.output and "UPD" in result.output
    result = runner.invoke(app, ["operators", "RAR"], env={"COLUMNS": "200"})
    assert result.exit_code == 0 and "angle_range" in result.output and "equivariant" in result.output


def test_mutate_a_data_set_writes_mutants_and_replayable_params(kitti_log, tmp_path):
    from lidarfuzz.operators import from_spec

    out = tmp_path / "rotated"
    result = runner.invoke(app, ["mutate", str(kitti_log), str(out), "--op", "RAR", "--severity", "4", "--seed", "3"])
    assert result.exit_code == 0, result.output
    source, mutants = open_dataset(kitti_log), open_dataset(out)
    records = [json.loads(line) for line in (out / "mutations.jsonl").read_text().splitlines()]
    assert [r["frame_id"] for r in records] == list(source.frame_ids()) == list(mutants.frame_ids())
    for original, mutant, record in zip(source, mutants, records, strict=True):
        op = from_spec(record["operator"])
        replayed = op.apply(original, op.parse_params(record["params"]))
        np.testing.assert_allclose(mutant.points.xyz, replayed.points.xyz, atol=1e-6)
        assert mutant.boxes.allclose(replayed.boxes, atol=1e-6)
        assert not np.allclose(mutant.points.xyz, original.points.xyz)
    again = runner.invoke(app, ["mutate", str(kitti_log), str(out), "--op", "RAR"])
    assert again.exit_code != 0


def test_mutate_bad_arguments_give_one_line(kitti_log, tmp_path):
    result = lidarfuzz("mutate", str(kitti_log), str(tmp_path / "x"), "--op", "UPD", "--param", "rate=0.3")
    assert result.returncode == 2 and "ratio_range" in result.stderr
    result = lidarfuzz("mutate", str(kitti_log), str(tmp_path / "z"), "--op", "UPD", "--param", "ratio=2")
    assert result.returncode == 2 and result.stderr.count("\n") == 1 and "less than or equal to 1" in result.stderr
    result = lidarfuzz("mutate", str(kitti_log), str(tmp_path / "y"), "--op", "teleport")
    assert result.returncode == 2 and "unknown operator" in result.stderr
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_mutate_interleave_writes_the_logs_of_neves_et_al(kitti_log, tmp_path):
    result = runner.invoke(app, ["mutate", str(kitti_log), str(tmp_path / "hgt.mcap"), "--op", "HGT", "--interleave"])
    assert result.exit_code == 0, result.output
    log = open_dataset(tmp_path / "hgt.mcap")
    assert len(log) == 6 and list(log.timestamps()) == sorted(log.timestamps())
    result = runner.invoke(app, ["mutate", str(kitti_log), str(tmp_path / "avg"), "--op", "AVG", "--interleave"])
    assert result.exit_code == 0, result.output
    assert len(open_dataset(tmp_path / "avg")) == 5
    result = runner.invoke(app, ["mutate", str(kitti_log), str(tmp_path / "avg2"), "--op", "AVG"])
    assert result.exit_code != 0 and "--interleave" in result.output


@pytest.mark.parametrize(("args", "expected"), [
    (["gen", "--frames", "-3"], "error: lidarfuzz gen: Invalid value for '--frames'"),
    (["no-such-command"], "error: lidarfuzz: No such command 'no-such-command'."),
    (["run", "--bogus"], "error: lidarfuzz run: No such option: --bogus"),
])
def test_a_usage_mistake_is_one_line_from_the_entry_point(args, expected, tmp_path):
    # typer's default is a five-line box; a user (and a script reading stderr) gets one line and exit 2
    done = subprocess.run([sys.executable, "-c", "from lidarfuzz.cli.app import main; main()", *args],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert done.returncode == 2
    assert done.stderr.startswith(expected) and done.stderr.count("\n") == 1, done.stderr


@pytest.mark.parametrize(("text", "message"), [
    ("fog@3,rotate_z@3", "--op 'fog@3,rotate_z@3': one operator per --op, e.g. --op fog@3 --op rotate_z@3"),
    ("fog@1,3,rotate_z@2,5", "--op 'fog@1,3,rotate_z@2,5': one operator per --op, e.g. --op fog@1,3 --op rotate_z@2,5"),
    ("fog@high", "--op 'fog@high': severities are integers, e.g. fog@1,3,5"),
])
def test_an_op_that_is_not_one_operator_says_how_to_write_it(text: str, message: str) -> None:
    from lidarfuzz.cli.campaign import parse_op
    from lidarfuzz.errors import LidarfuzzError

    with pytest.raises(LidarfuzzError) as raised:
        parse_op(text)
    assert str(raised.value) == message


def test_an_op_names_an_operator_and_its_severities() -> None:
    from lidarfuzz.cli.campaign import parse_op

    assert parse_op("fog@1, 3,5") == {"name": "fog", "severities": [1, 3, 5]}
    assert parse_op("rotate_z") == {"name": "rotate_z"}
