"""Boxes stored compactly: one float32 row of 16 numbers per box, labels as a JSON list, kept
together as one value (:class:`StoredBoxes`) wherever they cross a layer.

Columns: ``x y z l w h yaw score truncation occlusion alpha x1 y1 x2 y2 track``. A detection
has NaN in the KITTI extras; ground truth has NaN as its score. float32 keeps centimetre
positions to well under a millimetre at 100 m, which is far below what AP or a relation
can see, and a frame's 30 boxes take under 2 kB.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lidarfuzz.scene.boxes import Boxes3D

COLUMNS: tuple[str, ...] = ("x", "y", "z", "l", "w", "h", "yaw", "score", "truncation", "occlusion", "alpha",
                            "x1", "y1", "x2", "y2", "track")
WIDTH = len(COLUMNS)


def encode_boxes(boxes: Boxes3D) -> tuple[bytes, list[str]]:
    """``boxes`` as (float32 bytes, labels)."""
    n = len(boxes)
    rows = np.empty((n, WIDTH), dtype=np.float32)
    rows[:, 0:3] = boxes.centers
    rows[:, 3:6] = boxes.sizes
    rows[:, 6] = boxes.yaw
    rows[:, 7] = boxes.scores
    rows[:, 8] = boxes.truncation
    rows[:, 9] = boxes.occlusion
    rows[:, 10] = boxes.alpha
    rows[:, 11:15] = boxes.bbox2d
    rows[:, 15] = boxes.track_ids
    return rows.tobytes(), [str(label) for label in boxes.labels]


def decode_boxes(blob: bytes | None, labels: Sequence[Any]) -> Boxes3D:
    """The inverse of :func:`encode_boxes` (an empty or missing blob is no boxes)."""
    if not blob:
        return Boxes3D.empty()
    rows = np.frombuffer(blob, dtype=np.float32)
    if rows.size % WIDTH or rows.size // WIDTH != len(labels):
        raise ValueError(f"a stored box blob of {len(blob)} bytes does not hold {len(labels)} boxes")
    rows = rows.reshape(-1, WIDTH).astype(np.float64)
    return Boxes3D.create(
        rows[:, 0:3], rows[:, 3:6], rows[:, 6], list(labels),
        scores=rows[:, 7], truncation=rows[:, 8], occlusion=np.nan_to_num(rows[:, 9], nan=-1).astype(np.int64),
        alpha=rows[:, 10], bbox2d=rows[:, 11:15], track_ids=np.nan_to_num(rows[:, 15], nan=-1).astype(np.int64),
    )


@dataclass(frozen=True)
class StoredBoxes:
    """A set of boxes as the store holds them: the float32 rows and their labels, one value.

    ``FrameResult.detections`` and ``.ground_truth`` and ``SutOutput.output`` are these (SQLAlchemy
    composites over two columns each), so no reader pairs a blob with a label list by hand.

    Attributes:
        data: The rows (:func:`encode_boxes`); None when there is no output (the system failed).
        labels: One per row.
    """

    data: bytes | None
    labels: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "labels", tuple(str(label) for label in self.labels or ()))

    @classmethod
    def of(cls, boxes: Boxes3D | None) -> StoredBoxes:
        """``boxes`` encoded (None: no output)."""
        if boxes is None:
            return cls(None)
        data, labels = encode_boxes(boxes)
        return cls(data, tuple(labels))

    @property
    def missing(self) -> bool:
        """There is no output (the system failed on this input)."""
        return self.data is None

    def boxes(self) -> Boxes3D:
        """The boxes (none when missing)."""
        return decode_boxes(self.data, self.labels)

    def __composite_values__(self) -> tuple[bytes | None, list[str]]:
        return self.data, list(self.labels)

    def columns(self, data: str = "boxes", labels: str = "labels") -> dict[str, Any]:
        """The two column values, for a Core insert."""
        return {data: self.data, labels: list(self.labels)}
