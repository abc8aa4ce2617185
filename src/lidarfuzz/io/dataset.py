"""Data sets: lazily iterated collections of frames with stable ids; logs add order and time.

A :class:`Dataset` lists its frame ids when opened (cheap: a directory scan or a bag
index) and loads a frame only when asked. A :class:`Log` is a data set whose frames
are ordered in time, each with a timestamp and, when known, an ego pose — the shape
of a field-test recording that Neves et al. replay and segment.

The classes are generic in the sample type so that later modalities (camera images)
reuse them unchanged.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from os import PathLike
from pathlib import Path
from typing import Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.common import Problem
from lidarfuzz.io.options import DatasetMap, DatasetOptions
from lidarfuzz.scene.drivable import ESTIMATED, estimate_drivable
from lidarfuzz.scene.scene import Sample, Scene

S = TypeVar("S", bound=Sample)


class Dataset(ABC, Generic[S]):
    """An indexable, lazily loaded collection of frames.

    Subclasses implement :meth:`frame_ids` and :meth:`load`; iteration, ``len`` and
    indexing by position or id come for free.
    """

    #: True for logs, whose frame order is the order of time.
    ordered: bool = False

    def __init__(self, path: str | PathLike[str], name: str | None = None) -> None:
        self.path = Path(path)
        self.name = name or self.path.name
        self._problems: list[Problem] = []
        self.options = DatasetOptions()
        self._map: DatasetMap | None = None

    def configure(self, options: DatasetOptions) -> None:
        """Apply data-set options to every frame loaded from now on (the ROI map is read now, so a
        malformed one fails when the data set is opened, not mid-campaign)."""
        self.options = options
        self._map = options.dataset_map()

    def _finish(self, scene: S) -> S:
        """What the data-set options add to a loaded frame: the data-set ROI map where the frame
        has none of its own (``roi_source``: ``dataset_map``; a frame's own: ``frame_map``) and
        the intensity scale the user gave."""
        if not isinstance(scene, Scene):
            return scene
        meta = dict(scene.metadata)
        roi = scene.roi
        if roi is not None:
            meta.setdefault("roi_source", "frame_map")
        elif self._map is not None:
            roi = self._map.for_scene(scene)
            meta["roi_source"] = "dataset_map"
        elif self.options.estimates_map:
            roi = estimate_drivable(scene, use_labels=False)  # never the labels: the system sees this map
            meta["roi_source"] = ESTIMATED
        if self.options.intensity_scale is not None:
            meta["intensity_scale"] = self.options.intensity_scale
        if roi is scene.roi and meta == scene.metadata:
            return scene
        return scene.replace(roi=roi, metadata=meta)  # type: ignore[return-value]

    def has_labels(self) -> bool:
        """Whether the data set carries box labels at all (a KITTI ``label_2/``)."""
        return False

    def unlabelled_ids(self) -> list[str]:
        """Frames without labels in a data set that has them (campaigns score AP on the others
        only when allowed); empty when every frame is labelled or the data set has no labels."""
        return []

    @abstractmethod
    def frame_ids(self) -> Sequence[str]:
        """Ids of all frames, in data set order; unique and stable across runs."""

    @abstractmethod
    def load(self, frame_id: str) -> S:
        """Read one frame."""

    @property
    def format(self) -> str:
        """Short name of the storage format (``kitti``, ``pcd``, ``ros1`` ...)."""
        return type(self).__name__

    def problems(self) -> list[Problem]:
        """Structural problems found when the data set was opened (for ``lidarfuzz info``)."""
        return list(self._problems)

    def __len__(self) -> int:
        return len(self.frame_ids())

    def __iter__(self) -> Iterator[S]:
        for frame_id in self.frame_ids():
            yield self.load(frame_id)

    def __getitem__(self, key: int | str) -> S:
        if isinstance(key, str):
            if key not in self._id_set():
                raise KeyError(f"{self.path}: no frame with id {key!r}")
            return self.load(key)
        ids = self.frame_ids()
        return self.load(ids[key])

    def __contains__(self, frame_id: object) -> bool:
        return frame_id in self._id_set()

    def _id_set(self) -> set[str]:
        return set(self.frame_ids())

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r}, frames={len(self)})"


class Log(Dataset[S]):
    """An ordered data set: frames in time order, each with a timestamp and maybe a pose."""

    ordered = True

    @abstractmethod
    def timestamps(self) -> NDArray[np.float64]:
        """Seconds, one per frame, non-decreasing."""

    def poses(self) -> NDArray[np.float64] | None:
        """F×4×4 LiDAR → world poses, or ``None`` when the log has none."""
        return None


def check_unique_ids(ids: Sequence[str], sources: Sequence[Path], root: Path) -> None:
    """Raise when two files map to the same frame id (e.g. ``000001.bin`` and ``000001.pcd``)."""
    seen: dict[str, Path] = {}
    for frame_id, source in zip(ids, sources, strict=True):
        if frame_id in seen:
            raise DataFormatError(
                root,
                f"duplicate frame id {frame_id!r}: {seen[frame_id]} and {source}",
                hint="frame ids come from file names and must be unique",
            )
        seen[frame_id] = source
