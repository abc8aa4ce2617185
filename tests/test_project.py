"""Project-level promises: ruff-clean, no network at import or run time, the demo runs."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Runs the real CLI with every network socket operation turned into an error (local
# AF_UNIX sockets, which multiprocessing uses between worker processes, stay allowed).
NO_NETWORK = """
import socket, sys
_connect, _connect_ex = socket.socket.connect, socket.socket.connect_ex
def refuse(*args, **kwargs):
    raise OSError("network access attempted")
def local_only(original):
    def guarded(self, address):
        if self.family != socket.AF_UNIX:
            refuse()
        return original(self, address)
    return guarded
socket.socket.connect = local_only(_connect)
socket.socket.connect_ex = local_only(_connect_ex)
socket.create_connection = refuse
socket.getaddrinfo = refuse
from lidarfuzz.cli.app import main
sys.argv = ["lidarfuzz", *sys.argv[1:]]
main()
"""


def test_ruff_clean():
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "src", "tests", "benchmarks", "docs", "scripts",
                             "experiments"], cwd=ROOT,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_demo_runs_the_main_job_offline(tmp_path):
    result = subprocess.run([sys.executable, "-c", NO_NETWORK, "demo", "--workspace", str(tmp_path), "--frames", "2"],
                            capture_output=True, text=True, timeout=600,
                            env={**os.environ, "PYTHONIOENCODING": "utf-8", "COLUMNS": "160"})
    assert result.returncode == 0, result.stdout + result.stderr
    out = result.stdout
    assert "KITTI AP|R40" in out and "metamorphic relations" in out
    for operator in ("rotate_z@3", "global_flip@1", "intensity_units@5", "fog@1", "beam_missing@5"):
        assert operator in out  # the default set, at the severities that configure it differently
    report = tmp_path / "reports" / "task-1" / "report.html"
    assert report.is_file() and "data:image/png;base64" in report.read_text(encoding="utf-8")
    assert (tmp_path / "lidarfuzz.db").is_file()
    assert (tmp_path / "datasets" / "sim-world-s0-n2" / "velodyne" / "000001.bin").is_file()


@pytest.mark.torch
def test_demo_camera_runs_deeptest_offline(tmp_path):
    pytest.importorskip("torch")
    result = subprocess.run([sys.executable, "-c", NO_NETWORK, "demo", "--camera", "--workspace", str(tmp_path),
                             "--frames", "3"], capture_output=True, text=True, timeout=600,
                            env={**os.environ, "PYTHONIOENCODING": "utf-8", "COLUMNS": "160"})
    assert result.returncode == 0, result.stdout + result.stderr
    out = result.stdout
    assert "MSE_orig =" in out and "over 3 labelled of 3 original images" in out
    for setting in ("image_brightness@1", "image_rotation@5", "image_fog@3", "image_rain@5", "guided"):
        assert setting in out  # the nine transformations at 1, 3, 5, then the search
    assert "Table 7's form" in out and "guided search (Algorithm 1)" in out
    world = tmp_path / "datasets" / "sim-camera-s0-n3"
    assert (world / "image_2" / "000002.png").is_file() and (world / "steering.csv").is_file()
    assert (tmp_path / "reports" / "task-1" / "report.html").is_file()


@pytest.mark.parametrize("module", ["lidarfuzz.io.logs", "lidarfuzz.io.formats.las", "lidarfuzz.io.formats.pcd"])
def test_imports_do_not_touch_the_network(module):
    code = NO_NETWORK.split("from lidarfuzz")[0] + f"import {module}\n"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
