"""Segments: a log cut into consecutive runs of frames (Neves et al., Section III).

The paper partitions each field-test log into segments of about five point clouds, "a small
part of the route", and measures coverage per segment. Here a log of F frames and a size n
gives ``ceil(F / n)`` segments: segment *i* holds frames ``i·n … min((i+1)·n, F) − 1``, so every
segment has n frames but the last, which holds the remainder (``F mod n`` frames when n does
not divide F) — it is kept rather than dropped or merged, so every frame of the log lies in
exactly one segment and the union of the segments' coverage is the log's.

A segment's id (:attr:`Segment.id`, ``s000003``) is its position and does not depend on the
frames' content: partitioning the same log with the same size always gives the same ids.
Its coverage is the union of its frames' (:func:`segment_coverage`).

Example:
    >>> [(s.id, s.first, s.last) for s in partition(["a", "b", "c", "d", "e", "f", "g"], size=3)]
    [('s000000', 0, 2), ('s000001', 3, 5), ('s000002', 6, 6)]
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from lidarfuzz.structural.requirements import Covered, union

#: The paper's segment size (five point clouds).
DEFAULT_SIZE = 5


@dataclass(frozen=True)
class Segment:
    """Frames ``first … last`` (positions in the log's replay order, both included).

    Attributes:
        index: The segment's position in the log (0-based).
        first: Position of its first frame.
        last: Position of its last frame.
        frame_ids: The ids of its frames, in order.
    """

    index: int
    first: int
    last: int
    frame_ids: tuple[str, ...]

    @property
    def id(self) -> str:
        """A stable id: ``s`` and the zero-padded index."""
        return f"s{self.index:06d}"

    @property
    def positions(self) -> range:
        """The log positions of its frames."""
        return range(self.first, self.last + 1)

    def __len__(self) -> int:
        return self.last - self.first + 1


def partition(frame_ids: Sequence[str], size: int = DEFAULT_SIZE) -> list[Segment]:
    """Cut a log's frames (in replay order) into segments of ``size`` frames; the last may be shorter.

    Raises:
        ValueError: ``size`` below 1, or no frames.
    """
    if isinstance(size, bool) or not isinstance(size, int) or size < 1:
        raise ValueError(f"segment size: expected a whole number of frames >= 1, got {size!r}")
    if not frame_ids:
        raise ValueError("frame_ids: a log with no frames cannot be partitioned")
    ids = tuple(frame_ids)
    return [Segment(i, start, min(start + size, len(ids)) - 1, ids[start:start + size])
            for i, start in enumerate(range(0, len(ids), size))]


def segment_coverage(segments: Sequence[Segment], per_frame: Sequence[Covered]) -> list[Covered]:
    """Each segment's coverage: the union of its frames' ``Covered`` sets.

    Args:
        segments: A partition of the log (:func:`partition`).
        per_frame: One ``Covered`` per frame of the log, in replay order.

    Raises:
        ValueError: ``per_frame`` does not have one entry per frame of the partitioned log.
    """
    frames = segments[-1].last + 1 if segments else 0
    if len(per_frame) != frames:
        raise ValueError(f"per_frame: expected one coverage set per frame of the log ({frames}), got {len(per_frame)}")
    return [union(*(per_frame[p] for p in s.positions)) for s in segments]


__all__ = ["DEFAULT_SIZE", "Segment", "partition", "segment_coverage"]
