"""Logs: data sets with order, the input Neves et al. replay through a system under test.

A field-test log is replayed frame after frame through a system that keeps state, so the
order of its frames is part of the input. :func:`open_log` opens any data set lidarfuzz reads
and gives an :class:`OrderedLog` — the frame ids in replay order, their timestamps when known,
and how the order was established — or a one-line error saying why the source has no order:

==================================================  =====================================
source                                              order
==================================================  =====================================
ROS 1 bag, ROS 2 bag, MCAP (one PointCloud2 topic)  the container's (log-time) order; the
                                                    header stamps as timestamps
KITTI-layout folder with ``timestamps.txt``         by timestamp (ties by frame id), as
(``lidarfuzz gen --sequence`` writes one)           :class:`~lidarfuzz.io.kitti.KittiLog` sorts it
KITTI-layout folder with ``poses.txt`` only         by frame id (a sequence of poses is a
                                                    trajectory); no timestamps
KITTI-layout folder with neither, a folder of       refused: nothing says which frame came
frame files, one frame file                         first
==================================================  =====================================

A folder of frame files is refused even when its files are numbered: file names are not a
recording's clock, and segments cut from a wrong order mean nothing.

Example:
    >>> import tempfile, pathlib
    >>> import numpy as np
    >>> from lidarfuzz.io.kitti import KittiWriter
    >>> from lidarfuzz.scene.points import PointCloud
    >>> from lidarfuzz.scene.scene import Scene
    >>> root = pathlib.Path(tempfile.mkdtemp()) / "log"
    >>> with KittiWriter(root) as writer:
    ...     for i, t in enumerate([0.2, 0.1, 0.3]):
    ...         _ = writer.add(Scene(PointCloud(np.ones((3, 4))), frame_id=f"{i:06d}", timestamp=t))
    >>> log = open_log(root)
    >>> log.frame_ids, log.order
    (('000001', '000000', '000002'), 'timestamps')
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.dataset import Dataset, Log
from lidarfuzz.io.kitti import KittiDataset
from lidarfuzz.io.open import open_dataset
from lidarfuzz.io.options import DatasetOptions
from lidarfuzz.scene.scene import Scene

#: How a log's order was established (see the module docstring).
Order = Literal["timestamps", "container", "frame_ids"]


class NotALogError(DataFormatError):
    """A data set without order: no timestamps, no poses, not a recording."""


@dataclass(frozen=True)
class OrderedLog:
    """A data set's frames in replay order.

    Attributes:
        dataset: The opened data set (frames are loaded from it lazily).
        frame_ids: Frame ids in replay order.
        timestamps: Seconds, one per frame in :attr:`frame_ids` order; ``None`` when the log has
            no clock (a KITTI folder with poses only).
        order: What the order comes from: ``timestamps`` (sorted by them), ``container`` (a
            bag's or MCAP's own message order) or ``frame_ids`` (a sequence of poses).
    """

    dataset: Dataset[Scene]
    frame_ids: tuple[str, ...]
    timestamps: NDArray[np.float64] | None
    order: Order

    @property
    def path(self) -> Path:
        return self.dataset.path

    @property
    def format(self) -> str:
        return self.dataset.format

    def __len__(self) -> int:
        return len(self.frame_ids)

    def frame(self, position: int) -> Scene:
        """The frame at ``position`` (0-based, in replay order)."""
        return self.dataset.load(self.frame_ids[position])

    def frames(self, positions: Sequence[int] | None = None) -> Iterator[Scene]:
        """Frames in replay order (or those at ``positions``, in the order given)."""
        for position in range(len(self)) if positions is None else positions:
            yield self.frame(position)

    def __iter__(self) -> Iterator[Scene]:
        return self.frames()


def order_of(dataset: Dataset[Scene]) -> OrderedLog:
    """The replay order of an opened data set, or :class:`NotALogError` saying what is missing."""
    if isinstance(dataset, Log):
        ids = tuple(dataset.frame_ids())
        stamps = np.asarray(dataset.timestamps(), dtype=np.float64)
        order: Order = "container" if dataset.format in ("ros1", "ros2", "mcap") else "timestamps"
        return _checked(OrderedLog(dataset, ids, stamps, order))
    if isinstance(dataset, KittiDataset):
        if (dataset.root / "poses.txt").is_file() and not dataset.layout.point_labels:
            return _checked(OrderedLog(dataset, tuple(dataset.frame_ids()), None, "frame_ids"))
        raise NotALogError(dataset.root, "not a log: a KITTI-layout folder without timestamps.txt or poses.txt has "
                           "no frame order", hint="add timestamps.txt ('<frame_id> <seconds>' a line) or generate "
                           "a sequence with 'lidarfuzz gen --sequence'")
    what = "one frame file" if dataset.path.is_file() else "a folder of frame files"
    raise NotALogError(dataset.path, f"not a log: {what} has no timestamps and no sequence, so its frames have no "
                       "order", hint="use a bag or MCAP file, or a KITTI-layout folder with timestamps.txt")


def _checked(log: OrderedLog) -> OrderedLog:
    if not log.frame_ids:
        raise NotALogError(log.path, "the log has no frames")
    return log


def open_log(path: str | PathLike[str], *, options: DatasetOptions | None = None, topic: str | None = None,
             ) -> OrderedLog:
    """Open ``path`` (anything :func:`~lidarfuzz.io.open.open_dataset` reads) as an ordered log.

    Raises:
        NotALogError: The source has no order (named, with what is missing).
        DataFormatError: The source cannot be read at all.
    """
    return order_of(open_dataset(path, options=options, topic=topic))


__all__ = ["NotALogError", "Order", "OrderedLog", "open_log", "order_of"]
