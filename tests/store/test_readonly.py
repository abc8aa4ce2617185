"""A workspace this process cannot write: reading commands work, writing ones say so in one line.

The workspace is made read-only the way a user meets it: without write permission (``chmod a-w``)
when the tests run as a normal user; as root, who may write anything, by a read-only bind mount
in a private mount namespace (``unshare -rm``: EROFS, as on a read-only file system). The
commands run in one child process (through :func:`lidarfuzz.cli.app.main`, as the ``lidarfuzz``
command does), each reporting its exit code and output.

Expected values, by hand: the task has originals + rotate_z@3 on 1 frame = 2 units, done; the
workspace's store was at 0007 for the migration case, and the newest migrations are 0008
(task_claims) and 0009 (sut_outputs.source), so those two are named.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from lidarfuzz.campaign.executor import InlineExecutor
from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
from lidarfuzz.store import Store

ROOT = Path(__file__).resolve().parents[2]
#: Runs each command (a JSON list of argument lists) through main(); prints one JSON result each.
COMMANDS = r"""
import contextlib, io, json, sys
from lidarfuzz.cli.app import main
for args in json.loads(sys.argv[1]):
    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        sys.argv = ["lidarfuzz", *args]
        try:
            main()
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    print(json.dumps({"args": args, "code": code, "out": out.getvalue(), "err": err.getvalue()}))
"""


def _can_bind_read_only(folder: Path) -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-rm", "sh", "-c", f"mount --bind {folder} {folder} && "
                                                          f"mount -o remount,ro,bind {folder}"], capture_output=True)
    return probe.returncode == 0


@pytest.fixture(scope="module")
def done_workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A workspace holding one done task (2 units)."""
    root = tmp_path_factory.mktemp("readonly")
    world = root / "world"
    generate_dataset(world, GenerationConfig(frames=1, seed=0), workers=1, overwrite=True)
    store = Store(root / "ws")
    task = create_task(store, parse_campaign({"dataset": str(world), "sut": "classic",
                                              "operators": [{"name": "rotate_z", "severities": [3]}]}))
    run_task(store, task, executor=InlineExecutor())
    store.close()
    return root / "ws"


def _chmod(folder: Path, writable: bool) -> None:
    for path in [folder, *folder.rglob("*")]:
        mode = path.stat().st_mode
        path.chmod(mode | stat.S_IWUSR if writable else mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


@pytest.fixture
def read_only(tmp_path: Path) -> Iterator[object]:
    """``run(workspace, commands)``: the commands' results with ``workspace`` read-only."""
    if os.geteuid() == 0 and not _can_bind_read_only(tmp_path):
        pytest.skip("root writes anything, and unshare -rm (to mount the workspace read-only) is not allowed here")
    touched: list[Path] = []

    def run(workspace: Path, commands: list[list[str]]) -> list[dict[str, object]]:
        env = {**os.environ, "COLUMNS": "200", "PYTHONPATH": str(ROOT)}
        script = [sys.executable, "-c", COMMANDS, json.dumps(commands)]
        if os.geteuid() == 0:
            mount = f"mount --bind {workspace} {workspace} && mount -o remount,ro,bind {workspace} && exec \"$@\""
            script = ["unshare", "-rm", "sh", "-c", mount, "sh", *script]
        else:
            _chmod(workspace, writable=False)
            touched.append(workspace)
        done = subprocess.run(script, capture_output=True, text=True, env=env, timeout=240)
        assert done.returncode == 0, done.stderr
        return [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]

    yield run
    for folder in touched:
        _chmod(folder, writable=True)


def test_reading_commands_work_and_writing_ones_refuse_in_one_line(done_workspace: Path, read_only: object,
                                                                   tmp_path: Path) -> None:
    workspace = tmp_path / "ws"
    shutil.copytree(done_workspace, workspace)
    before = {p.name: p.read_bytes() for p in workspace.iterdir() if p.is_file()}
    ws = ["--workspace", str(workspace)]
    results = read_only(workspace, [  # type: ignore[operator]
        ["list", "--plain", *ws], ["status", "1", *ws], ["report", "1", "--out", "-", *ws],
        ["resume", "1", *ws], ["cancel", "1", *ws], ["delete", "1", *ws],
        ["run", "--dataset", str(tmp_path), "--sut", "classic", "--op", "fog@1", *ws],
        ["report", "1", "--quiet", *ws]])
    listed, status, page, *writers, report = results
    assert listed["code"] == 0 and listed["out"].split("\t")[:3] == ["1", "", "done"]
    assert status["code"] == 0 and "done" in status["out"] and "2/2 units" in status["out"]
    assert page["code"] == 0 and page["out"].startswith("<!DOCTYPE html>") and "task 1" in page["out"]
    for refused, command in zip(writers, ["lidarfuzz resume 1", "lidarfuzz cancel", "lidarfuzz delete",
                                          "lidarfuzz run"], strict=True):
        assert refused["code"] == 1, refused
        assert refused["err"] == (f"error: the workspace at {workspace} is read-only: {command} writes to it; run "
                                  f"it where you can write (or on a copy)\n")
    # the default report folder is in the workspace: one line naming it, nothing half-written
    assert report["code"] == 1 and report["err"].count("\n") == 1, report
    assert report["err"].startswith(f"error: cannot write {workspace / 'reports'}")
    assert "--out -" in report["err"]
    assert not (workspace / "reports").exists()
    assert {p.name: p.read_bytes() for p in workspace.iterdir() if p.is_file()} == before  # untouched


def test_a_read_only_workspace_that_needs_a_migration_says_which(tmp_path: Path, read_only: object) -> None:
    workspace = tmp_path / "old"
    Store(workspace, migrate=False).migrate("0007")  # as a lidarfuzz before task claims left it
    results = read_only(workspace, [["list", "--workspace", str(workspace)]])  # type: ignore[operator]
    assert results[0]["code"] == 1
    assert results[0]["err"] == (f"error: the workspace at {workspace} is read-only and needs migrations 0008, 0009; "
                                 f"run a command with write access once\n")
    assert Store(workspace).revision() == "0009"  # with write access, it migrates


def test_the_store_opens_read_only_and_refuses_a_write(done_workspace: Path, tmp_path: Path) -> None:
    """In this process (no bind mount): a database file and folder without write permission."""
    if os.geteuid() == 0:
        pytest.skip("root may write a file without write permission; covered through the CLI above")
    from sqlalchemy import update

    from lidarfuzz.store.errors import StorageError
    from lidarfuzz.store.models import Task

    workspace = tmp_path / "ws"
    shutil.copytree(done_workspace, workspace)
    _chmod(workspace, writable=False)
    try:
        store = Store(workspace)
        assert store.read_only and store.revision() == "0009"
        with pytest.raises(StorageError, match=r"is read-only: this command writes to it"), store.session() as s:
            s.execute(update(Task).where(Task.id == 1).values(notes="a note"))
    finally:
        _chmod(workspace, writable=True)
