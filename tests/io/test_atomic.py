"""Atomic writes: nothing partial at a final name, and outputs with the modes an ordinary open gives."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from lidarfuzz.io.atomic import OutputExistsError, atomic_folder, atomic_path, write_text


def test_a_failed_write_leaves_nothing_and_the_old_file_whole(tmp_path: Path) -> None:
    out = write_text(tmp_path / "a.txt", "old")
    with pytest.raises(RuntimeError), atomic_path(out, overwrite=True) as tmp:
        tmp.write_text("half")
        raise RuntimeError("disk full")
    assert out.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]
    with pytest.raises(OutputExistsError):
        write_text(out, "new")


def test_a_failed_folder_leaves_nothing(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError), atomic_folder(tmp_path / "log") as tmp:
        (tmp / "0.bin").write_bytes(b"x")
        raise RuntimeError("frame 2 failed")
    assert list(tmp_path.iterdir()) == []


def test_outputs_get_the_modes_of_an_ordinary_open_under_the_umask(tmp_path: Path) -> None:
    # mkstemp/mkdtemp make 0600/0700; under umask 022 an ordinary open gives 0644 and mkdir 0755,
    # and a report must be readable by the colleague the user shares the folder with
    code = (
        "import os, stat, sys; os.umask(0o022)\n"
        "from lidarfuzz.io.atomic import atomic_folder, write_text\n"
        "f = write_text(sys.argv[1] + '/r.html', 'x')\n"
        "with atomic_folder(sys.argv[1] + '/out') as t: (t / 'a').write_text('y')\n"
        "print(oct(stat.S_IMODE(os.stat(f).st_mode)), oct(stat.S_IMODE(os.stat(sys.argv[1] + '/out').st_mode)))\n"
    )
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["0o644", "0o755"]
    assert stat.S_IMODE(os.stat(tmp_path).st_mode) & 0o700 == 0o700
