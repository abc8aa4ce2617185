"""Frame files of any supported format, by suffix, and folders of them as data sets.

========== ====================== =========================================
suffix     module                 notes
========== ====================== =========================================
``.bin``   formats.bin            headerless scan by layout (KITTI by default;
                                  ``.pcd.bin``: nuScenes), memory-mapped
``.feather`` formats.feather      Argoverse 2 sweep (extra ``argoverse``)
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
from lidarfuzz.io.formats.bin import frame_id_of
from lidarfuzz.io.layouts import PointLayout
from lidarfuzz.scene.scene import Scene

FRAME_FORMATS: dict[str, str] = {
    ".bin": "bin",
    ".pcd": "pcd",
    ".ply": "ply",
    ".las": "las",
    ".laz": "las",
    ".npy": "npy",
    ".npz": "npy",
    ".feather": "feather",
}
#: Formats whose files have no self-description of their columns: a layout says what they hold.
LAYOUT_FORMATS = ("bin", "feather")


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


def read_frame(path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop",
               layout: PointLayout | str | None = None) -> Scene:
    """Read one frame file of any supported format.

    Args:
        path: The file; its suffix picks the format.
        nonfinite: ``drop`` or ``reject`` points with NaN/Inf coordinates.
        layout: For headerless ``.bin`` scans (and ``.feather``): the point layout (a name of
            :data:`~lidarfuzz.io.layouts.LAYOUTS` or a column spec); by default what the path
            says, else KITTI's. Self-describing formats (PCD, PLY, LAS, NumPy) ignore it.
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "file not found" if not path.exists() else "not a file")
    module = format_module(path)
    if FRAME_FORMATS[path.suffix.lower()] in LAYOUT_FORMATS:
        scene: Scene = module.read(path, nonfinite=nonfinite, layout=layout)
    else:
        scene = module.read(path, nonfinite=nonfinite)
    return scene


def write_frame(path: str | PathLike[str], scene: Scene, *, overwrite: bool = False, **options: Any) -> Path:
    """Write one frame in the format its suffix names (atomically; never over an existing file
    unless ``overwrite``)."""
    written: Path = format_module(path).write(path, scene, overwrite=overwrite, **options)
    return written


class FrameFolder(Dataset[Scene]):
    """A folder of frame files (any supported formats); ids are the file stems, sorted."""

    def __init__(self, path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop",
                 layout: PointLayout | str | None = None) -> None:
        super().__init__(path)
        self.layout = layout
        if not self.path.is_dir():
            raise DataFormatError(self.path, "not a folder")
        files = sorted(p for p in self.path.iterdir() if p.is_file() and is_frame_file(p))
        if not files:
            raise DataFormatError(
                self.path, "no point-cloud frames found", hint=f"expected files ending in {', '.join(FRAME_FORMATS)}"
            )
        ids = [frame_id_of(p) for p in files]
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
        return self._finish(read_frame(self._files[frame_id], nonfinite=self.nonfinite, layout=self.layout))


class SingleFrame(Dataset[Scene]):
    """One frame file seen as a data set of one frame."""

    def __init__(self, path: str | PathLike[str], *, nonfinite: NonFinitePolicy = "drop",
                 layout: PointLayout | str | None = None) -> None:
        super().__init__(path)
        format_module(self.path)
        self.nonfinite: NonFinitePolicy = nonfinite
        self.layout = layout

    @property
    def format(self) -> str:
        return FRAME_FORMATS[self.path.suffix.lower()]

    def frame_ids(self) -> Sequence[str]:
        return [frame_id_of(self.path)]

    def load(self, frame_id: str) -> Scene:
        return self._finish(read_frame(self.path, nonfinite=self.nonfinite, layout=self.layout))
