"""A disk that fills, on demand: run ``lidarfuzz`` commands in a child process whose store or files
hit "no space left" at a chosen point (used by tests/cli/test_disk_full.py and
benchmarks/store_faults.py).

Two ways, both deterministic for a given limit:

* ``store_pages``: SQLite's ``max_page_count`` on every connection the child opens, so the
  database is full once it would grow past that many pages — SQLite then fails exactly as on a
  full disk (SQLITE_FULL, "database or disk is full").
* ``write_bytes``: every file the child opens for writing shares a budget of bytes; the write that
  exceeds it raises ``OSError(ENOSPC)``, as ``write(2)`` does on a full disk.

:func:`run_commands` runs several commands in one child (one interpreter start), each through
:func:`lidarfuzz.cli.app.main` as the ``lidarfuzz`` command does, each with its own fault.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]

CHILD = r"""
import builtins, contextlib, errno, io, json, sys
import sqlalchemy
from sqlalchemy import event

budget = {"pages": None, "bytes": None}

@event.listens_for(sqlalchemy.engine.Engine, "connect")
def _cap(connection, _record):
    if budget["pages"] is not None:
        cursor = connection.cursor()
        cursor.execute(f"PRAGMA max_page_count={int(budget['pages'])}")
        cursor.close()

class Filling:
    '''A file opened for writing on a disk with budget["bytes"] bytes free.'''
    def __init__(self, handle):
        self._handle = handle
    def write(self, data):
        size = len(data.encode("utf-8")) if isinstance(data, str) else len(data)
        if size > budget["bytes"]:
            budget["bytes"] = 0
            raise OSError(errno.ENOSPC, "No space left on device")
        budget["bytes"] -= size
        return self._handle.write(data)
    def writelines(self, lines):
        for line in lines:
            self.write(line)
    def __enter__(self):
        return self
    def __exit__(self, *exc):
        self._handle.close()
    def __iter__(self):
        return iter(self._handle)
    def __getattr__(self, name):
        return getattr(self._handle, name)

real_open = io.open

def filling_open(file, mode="r", *args, **kwargs):
    handle = real_open(file, mode, *args, **kwargs)
    if budget["bytes"] is not None and any(flag in mode for flag in "wax+"):
        return Filling(handle)
    return handle

io.open = builtins.open = filling_open

from lidarfuzz.cli.app import main
for fault, args in json.loads(sys.argv[1]):
    budget["pages"], budget["bytes"] = fault.get("store_pages"), fault.get("write_bytes")
    out, err = io.StringIO(), io.StringIO()
    code = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        sys.argv = ["lidarfuzz", *args]
        try:
            main()
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        except BaseException as exc:  # a traceback: what the tests look for
            import traceback
            err.write(traceback.format_exc())
            code = 99
    print(json.dumps({"args": args, "code": code, "out": out.getvalue(), "err": err.getvalue()}), flush=True)
"""


def run_commands(commands: list[tuple[dict[str, Any], list[str]]], *, cwd: Path | None = None,
                 timeout: float = 600) -> list[dict[str, Any]]:
    """Each ``(fault, args)`` run in one child process in turn: ``fault`` is ``{}`` (a sound disk),
    ``{"store_pages": N}`` or ``{"write_bytes": N}``. Returns ``{"args", "code", "out", "err"}``
    per command."""
    env = {**os.environ, "COLUMNS": "200", "PYTHONPATH": os.pathsep.join(
        p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)}
    done = subprocess.run([sys.executable, "-c", CHILD, json.dumps(commands)], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=timeout)
    results = [json.loads(line) for line in done.stdout.splitlines() if line.startswith('{"args"')]
    assert len(results) == len(commands), f"the child stopped early ({done.returncode}):\n{done.stderr[-3000:]}"
    return results


__all__ = ["CHILD", "run_commands"]
