"""Atomic writes: a temporary file in the destination's folder, fsync, then rename.

A reader never sees a half-written file and an interrupted write leaves nothing
behind. Writers refuse to replace an existing file unless asked to, so an original
can never be overwritten by accident.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from os import PathLike
from pathlib import Path

from lidarfuzz.errors import LidarfuzzError


def _umask() -> int:
    mask = os.umask(0o022)  # reading the mask means setting it; set it back at once
    os.umask(mask)
    return mask


#: The process's umask, read once at import (reading it later from threads would race). mkstemp and
#: mkdtemp create 0600 files and 0700 folders; outputs get the modes an ordinary ``open`` would give.
_UMASK = _umask()
_FILE_MODE = 0o666 & ~_UMASK
_FOLDER_MODE = 0o777 & ~_UMASK


class OutputExistsError(LidarfuzzError, FileExistsError):
    """The destination exists and overwriting was not requested."""

    def __init__(self, path: Path) -> None:
        self.path = path
        super().__init__(f"{path}: already exists; choose a new path or pass overwrite=True (--overwrite)")


def check_destination(path: str | PathLike[str], overwrite: bool) -> Path:
    path = Path(path)
    if path.exists() and not overwrite:
        raise OutputExistsError(path)
    return path


@contextlib.contextmanager
def atomic_path(path: str | PathLike[str], *, overwrite: bool = False, durable: bool = True) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it is renamed onto ``path``.

    With ``durable`` the data is flushed to disk (fsync) before the rename, so even a
    power cut leaves the old file or the whole new one. Bulk writers of regenerable
    data (the simulator) pass ``durable=False``: the rename alone still guarantees
    that no reader sees a half-written file after a crash of the process.

    Example:
        >>> import tempfile, pathlib
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
        >>> with atomic_path(out) as tmp:
        ...     _ = tmp.write_text("hello")
        >>> out.read_text()
        'hello'
    """
    target = check_destination(path, overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.fchmod(fd, _FILE_MODE)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        if durable and tmp.is_file():
            with open(tmp, "rb+") as handle:
                os.fsync(handle.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        raise


def write_bytes(path: str | PathLike[str], data: bytes | memoryview, *, overwrite: bool = False,
                durable: bool = True) -> Path:
    with atomic_path(path, overwrite=overwrite, durable=durable) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | PathLike[str], text: str, *, overwrite: bool = False, durable: bool = True) -> Path:
    with atomic_path(path, overwrite=overwrite, durable=durable) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


@contextlib.contextmanager
def atomic_folder(path: str | PathLike[str], *, overwrite: bool = False) -> Iterator[Path]:
    """Yield a new temporary folder next to ``path``; on success it is renamed onto ``path``.

    A failure (an exception inside the block) removes the temporary folder, so a reader never
    sees a half-written data set and nothing is left behind. An existing ``path`` is refused
    unless ``overwrite`` (an empty folder counts as absent); with it, the old folder is replaced
    only once the new one is complete.

    Example:
        >>> import tempfile, pathlib
        >>> out = pathlib.Path(tempfile.mkdtemp()) / "log"
        >>> with atomic_folder(out) as tmp:
        ...     _ = (tmp / "a.txt").write_text("hello")
        >>> sorted(p.name for p in out.iterdir())
        ['a.txt']
    """
    import shutil

    target = Path(path)
    if target.exists() and not (target.is_dir() and not any(target.iterdir())) and not overwrite:
        raise OutputExistsError(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    tmp.chmod(_FOLDER_MODE)
    try:
        yield tmp
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
            os.replace(target, old / target.name)
            os.replace(tmp, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
