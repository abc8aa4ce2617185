"""What a path holds — a ROS 1 bag, a ROS 2 bag or an MCAP file — and errors of the libraries
that read them turned into :class:`~lidarfuzz.errors.DataFormatError` naming the file."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import Literal

from lidarfuzz.errors import DataFormatError, LidarfuzzError
from lidarfuzz.io import guards

LogKind = Literal["ros1", "ros2", "mcap"]

_ROS1_MAGIC = b"#ROSBAG"
_MCAP_MAGIC = b"\x89MCAP"


def _hint_for(err: BaseException) -> str | None:
    text = str(err).lower()
    if "reindex" in text or "not indexed" in text or "index looks damaged" in text:
        return "the bag looks truncated or was not closed properly; 'rosbag reindex' on a copy may repair it"
    if isinstance(err, McapFooterError):
        return "the file looks truncated or damaged; 'mcap recover' can often repair it"
    return None


class McapFooterError(Exception):
    """An MCAP file's footer or summary section cannot be read."""


@contextlib.contextmanager
def reading(path: Path, what: str) -> Iterator[None]:
    """Turn any library error on malformed input into a DataFormatError naming the file
    (:func:`lidarfuzz.io.guards.reading`, with advice for a truncated bag or MCAP file)."""
    try:
        yield
    except LidarfuzzError:
        raise
    except Exception as err:
        with guards.reading(path, what, hint=_hint_for(err)):
            raise err from None


def detect_kind(path: str | PathLike[str]) -> tuple[Path, LogKind]:
    """Find what a path holds: ``(path to open, kind)``; raises DataFormatError when it is no log.

    A ROS 2 bag may be named by its directory, its ``metadata.yaml`` or its ``.db3`` file.
    """
    path = Path(path)
    if not path.exists():
        raise DataFormatError(path, "file not found")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return path, "ros2"
        raise DataFormatError(
            path,
            "directory has no metadata.yaml, so it is not a ROS 2 bag",
            hint="pass a ROS 1 .bag file, a ROS 2 bag directory or an .mcap file",
        )
    if path.name == "metadata.yaml" or (path.suffix == ".db3" and (path.parent / "metadata.yaml").is_file()):
        return path.parent, "ros2"
    with reading(path, "read the file"), open(path, "rb") as handle:
        head = handle.read(16)
    if head.startswith(_ROS1_MAGIC):
        return path, "ros1"
    if head.startswith(_MCAP_MAGIC):
        return path, "mcap"
    found = "the file is empty" if not head else f"it starts with {head[:8]!r}"
    raise DataFormatError(
        path,
        f"not a ROS 1 bag, ROS 2 bag or MCAP file ({found})",
        hint="a ROS 1 bag starts with '#ROSBAG V2.0', an MCAP file with '\\x89MCAP0'",
    )
