"""Frame files of any supported format, by suffix, and folders of them as data sets.

========== ====================== =========================================
suffix     module                 notes
========== ====================== =========================================
``.bin``   formats.bin            KITTI Velodyne scan, memory-mapped
``.pcd``   formats.pcd            ascii, binary, binary_compressed
``.ply``   formats.ply            binary little-endian or ascii
``.las``   formats.las            LAS 1.4 (laspy)
``.laz``   formats.las            LAZ (laspy + lazrs)
``.npy``   formats.npy            structured or N×C array
``.npz``   formats.npy            lidarfuzz full-scene archive
========== ====================== =========================================
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from os import PathLike
from pathlib import Path
from types import ModuleType
from typing import Any

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import NonFinitePolicy
from lidarfuzz.io.dataset import Dataset, check_unique_ids
from lidarfuzz.scene.scene import Scene

FRAME_FORMATS: dict[str, str] = {
    ".bin": "bin",
    ".pcd": "pcd",
    ".ply": "ply",
    ".las": "las",
    ".laz": "las",
    ".npy": "npy",
    ".npz": "npy",
}


def format_module(path: str | PathLike[str]) -> ModuleType:
    """The reader/writer module for a frame file, chosen by its suffix."""
    suffix = Path(path).suffix.lower()
    if suffix not in FRAME_FORMATS:
        raise DataFormatError(
            path, f"unsupported frame format {suffix or '(no suffix)'!r}",
            hint=f"supported: {', '.join(sorted(FRAME_FORMATS))}",
        )
    return importlib.import_module(f"lidarfuzz.io.formats.{FRAME_FORMATS[suffix]}")


def is_frame_file(path: str | PathLike[str]) -> bool:
    return Path(path).suffix.lower() in FRAME_FORMATS


def read_frame(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> Scene:
    """Read one frame file of any supported format."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "file not found" if not path.exists() else "not a file")
    scene: Scene = format_module(path).read(path, nonfinite=nonfinite)
    return scene


def write_frame(path: str | PathLike[str], scene: Scene, *, overwrite: bool = False, **options: Any) -> Path:
    """Write one frame in the format its suffix names (atomically; never over an existing file
    unless ``overwrite``)."""
    written: Path = format_module(path).write(path, scene, overwrite=overwrite, **options)
    return written


class FrameFolder(Dataset[Scene]):
    """A folder of frame files (any supported formats); ids are the file stems, sorted."""

    def __init__(self, path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> None:
        super().__init__(path)
        if not self.path.is_dir():
            raise DataFormatError(self.path, "not a folder")
        files = sorted(p for p in self.path.iterdir() if p.is_file() and is_frame_file(p))
        if not files:
            raise DataFormatError(
                self.path, "no point-cloud frames found", hint=f"expected files ending in {', '.join(FRAME_FORMATS)}"
            )
        ids = [p.stem for p in files]
        check_unique_ids(ids, files, self.path)
        self._files = dict(zip(ids, files, strict=True))
        self._ids = ids
        self.nonfinite: NonFinitePolicy = nonfinite

    @property
    def format(self) -> str:
        kinds = sorted({FRAME_FORMATS[p.suffix.lower()] for p in self._files.values()})
        return "+".join(kinds)

    def frame_ids(self) -> Sequence[str]:
        return self._ids

    def _id_set(self) -> set[str]:
        return set(self._files)

    def load(self, frame_id: str) -> Scene:
        return read_frame(self._files[frame_id], nonfinite=self.nonfinite)


class SingleFrame(Dataset[Scene]):
    """One frame file seen as a data set of one frame."""

    def __init__(self, path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop") -> None:
        super().__init__(path)
        format_module(self.path)
        self.nonfinite: NonFinitePolicy = nonfinite

    @property
    def format(self) -> str:
        return FRAME_FORMATS[self.path.suffix.lower()]

    def frame_ids(self) -> Sequence[str]:
        return [self.path.stem]

    def load(self, frame_id: str) -> Scene:
        return read_frame(self.path, nonfinite=self.nonfinite)
