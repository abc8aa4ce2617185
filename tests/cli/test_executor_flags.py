"""``--executor`` and ``--address`` mistakes, as a user sees them: one line on stderr, exit code 2,
refused before anything is created or served (issue 24)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from sqlalchemy import func, select

from lidarfuzz.store import Store, Task

SQLITE_REFUSAL = ("error: --executor ray needs a store that every node and driver reaches: an SQLite store is a file "
                  "on this machine, written by one process at a time; use PostgreSQL")


def lidarfuzz(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", "from lidarfuzz.cli.app import main; main()", *args],
                          capture_output=True, text=True, timeout=120)


@pytest.fixture
def data(tmp_path: Path) -> Path:
    done = lidarfuzz("gen", "--out", str(tmp_path / "data"), "--frames", "2", "--workers", "1")
    assert done.returncode == 0, done.stderr
    return tmp_path / "data"


def test_a_ray_run_on_sqlite_is_refused_before_a_task_exists(tmp_path: Path, data: Path) -> None:
    pytest.importorskip("ray")  # without Ray the refusal names the extra instead (below)
    workspace = tmp_path / "ws"
    done = lidarfuzz("run", "--dataset", str(data), "--sut", "classic", "--op", "fog@1", "--executor", "ray",
                     "--workspace", str(workspace))
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.startswith(SQLITE_REFUSAL) and done.stderr.count("\n") == 1, done.stderr
    store = Store(workspace)
    with store.session() as s:
        assert s.scalar(select(func.count()).select_from(Task)) == 0  # nothing was created
    store.close()


def test_a_server_for_a_cluster_on_sqlite_is_refused_before_serving(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    done = lidarfuzz("serve", "--executor", "ray", "--workspace", str(tmp_path / "ws"), "--port", "0")
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.startswith(SQLITE_REFUSAL) and done.stderr.count("\n") == 1, done.stderr


@pytest.mark.parametrize("command", [["run", "--dataset", "x", "--sut", "classic", "--op", "fog@1"], ["resume", "1"],
                                     ["serve"]])
def test_an_address_without_the_ray_executor_is_one_usage_line(tmp_path: Path, command: list[str]) -> None:
    done = lidarfuzz(*command, "--address", "auto", "--workspace", str(tmp_path / "ws"))
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == (f"error: lidarfuzz {command[0]}: Invalid value for '--address': the address of a Ray "
                           f"cluster goes with --executor ray (lidarfuzz {command[0]} --help)\n")


def test_inline_and_another_executor_disagree(tmp_path: Path) -> None:
    done = lidarfuzz("resume", "1", "--inline", "--executor", "ray", "--workspace", str(tmp_path / "ws"))
    assert done.returncode == 2
    assert done.stderr == ("error: lidarfuzz resume: Invalid value for '--inline': --inline and --executor ray "
                           "disagree; give one (lidarfuzz resume --help)\n")


def test_an_unknown_executor_names_the_choices(tmp_path: Path) -> None:
    done = lidarfuzz("resume", "1", "--executor", "dask", "--workspace", str(tmp_path / "ws"))
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert "'dask' is not one of 'pool', 'inline', 'ray'" in done.stderr
