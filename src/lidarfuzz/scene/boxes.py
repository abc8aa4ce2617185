"""Oriented 3D boxes in the LiDAR frame (struct of arrays).

Convention, used everywhere inside lidarfuzz (conversions to KITTI camera labels,
OpenPCDet or mmdetection3d conventions happen only at the I/O edge):

* x forward, y left, z up (metres, LiDAR frame);
* ``centers`` is the geometric centre of the box (not the bottom);
* ``sizes`` are ``length`` (along the heading), ``width``, ``height``;
* ``yaw`` is the heading, counter-clockwise from +x about +z, wrapped to [-π, π).

Per box there is also a class name, a score (NaN for ground truth), a track id
(-1 when unknown) and the KITTI annotation extras when known: truncation (NaN
unknown), occlusion (-1 unknown), observation angle ``alpha`` (NaN unknown) and
the 2D image box ``[x1, y1, x2, y2]`` (NaN unknown).

Boxes whose 3D geometry is unknown (KITTI ``DontCare`` regions) have NaN centre,
size and yaw; geometric helpers treat them as empty.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lidarfuzz.scene.points import frozen


def wrap_angle(angle: ArrayLike) -> NDArray[np.float64]:
    """Wrap angles to [-π, π)."""
    a = np.asarray(angle, dtype=np.float64)
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def _as(values: ArrayLike | None, n: int, shape: tuple[int, ...], dtype: Any, fill: Any) -> Any:
    if values is None:
        return np.full((n, *shape), fill, dtype=dtype)
    array = np.asarray(values, dtype=dtype)
    if array.size == 0 and n == 0:
        array = array.reshape(0, *shape)
    if array.shape != (n, *shape):
        raise ValueError(f"expected shape {(n, *shape)}, got {array.shape}")
    return array


@dataclass(frozen=True, eq=False)
class Boxes3D:
    """M oriented boxes; every array has M rows. Build with :meth:`create`.

    Example:
        >>> b = Boxes3D.create([[10, 2, -0.9]], [[3.9, 1.6, 1.5]], [0.3], ["Car"])
        >>> len(b), b.labels[0], b.as_array().shape
        (1, 'Car', (1, 7))
    """

    centers: NDArray[np.float64]
    sizes: NDArray[np.float64]
    yaw: NDArray[np.float64]
    labels: NDArray[np.str_]
    scores: NDArray[np.float64]
    track_ids: NDArray[np.int64]
    truncation: NDArray[np.float64]
    occlusion: NDArray[np.int64]
    alpha: NDArray[np.float64]
    bbox2d: NDArray[np.float64]

    @classmethod
    def create(
        cls,
        centers: ArrayLike,
        sizes: ArrayLike,
        yaw: ArrayLike,
        labels: Sequence[str] | ArrayLike,
        *,
        scores: ArrayLike | None = None,
        track_ids: ArrayLike | None = None,
        truncation: ArrayLike | None = None,
        occlusion: ArrayLike | None = None,
        alpha: ArrayLike | None = None,
        bbox2d: ArrayLike | None = None,
    ) -> Boxes3D:
        """Validate and freeze the arrays. Yaw is wrapped to [-π, π)."""
        labels_arr = np.asarray(labels, dtype=np.str_)
        n = labels_arr.shape[0] if labels_arr.ndim else 0
        labels_arr = labels_arr.reshape(n)
        centers_arr = _as(centers, n, (3,), np.float64, np.nan)
        sizes_arr = _as(sizes, n, (3,), np.float64, np.nan)
        if np.any(sizes_arr < 0):
            bad = int(np.argwhere(sizes_arr < 0)[0, 0])
            raise ValueError(f"box {bad} has a negative size {sizes_arr[bad].tolist()}")
        yaw_arr = wrap_angle(_as(yaw, n, (), np.float64, np.nan))
        return cls(
            centers=frozen(centers_arr),
            sizes=frozen(sizes_arr),
            yaw=frozen(yaw_arr),
            labels=frozen(labels_arr),
            scores=frozen(_as(scores, n, (), np.float64, np.nan)),
            track_ids=frozen(_as(track_ids, n, (), np.int64, -1)),
            truncation=frozen(_as(truncation, n, (), np.float64, np.nan)),
            occlusion=frozen(_as(occlusion, n, (), np.int64, -1)),
            alpha=frozen(_as(alpha, n, (), np.float64, np.nan)),
            bbox2d=frozen(_as(bbox2d, n, (4,), np.float64, np.nan)),
        )

    @classmethod
    def empty(cls) -> Boxes3D:
        return cls.create(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), [])

    @classmethod
    def from_array(
        cls, boxes: ArrayLike, labels: Sequence[str] | ArrayLike, **extras: Any
    ) -> Boxes3D:
        """From an M×7 ``[x, y, z, l, w, h, yaw]`` array (OpenPCDet's LiDAR convention)."""
        array = np.asarray(boxes, dtype=np.float64).reshape(-1, 7)
        return cls.create(array[:, :3], array[:, 3:6], array[:, 6], labels, **extras)

    # -- access -----------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.labels.shape[0])

    def as_array(self) -> NDArray[np.float64]:
        """M×7 ``[x, y, z, l, w, h, yaw]``, centre origin, LiDAR frame."""
        return np.concatenate([self.centers, self.sizes, self.yaw[:, None]], axis=1)

    @property
    def has_geometry(self) -> NDArray[np.bool_]:
        """True for boxes with a finite 3D geometry (False for DontCare regions)."""
        arr = self.as_array()
        return np.all(np.isfinite(arr), axis=1)

    @property
    def is_detection(self) -> bool:
        """True when every box has a score (a detector's output)."""
        return bool(len(self)) and bool(np.all(np.isfinite(self.scores)))

    def __repr__(self) -> str:
        classes, counts = np.unique(self.labels, return_counts=True)
        summary = ", ".join(f"{c}={k}" for c, k in zip(classes, counts, strict=True))
        return f"Boxes3D(n={len(self)}{', ' + summary if summary else ''})"

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Boxes3D):
            return NotImplemented
        return all(
            np.array_equal(getattr(self, f.name), getattr(other, f.name), equal_nan=f.name != "labels")
            for f in fields(self)
        )

    __hash__ = None  # type: ignore[assignment]

    def allclose(self, other: Boxes3D, atol: float = 1e-6) -> bool:
        """Equal labels/ids/occlusion and numerically close geometry (yaw compared on the circle)."""
        if len(self) != len(other):
            return False
        if not (
            np.array_equal(self.labels, other.labels)
            and np.array_equal(self.track_ids, other.track_ids)
            and np.array_equal(self.occlusion, other.occlusion)
        ):
            return False
        for name in ("centers", "sizes", "scores", "truncation", "alpha", "bbox2d"):
            if not np.allclose(getattr(self, name), getattr(other, name), atol=atol, equal_nan=True):
                return False
        dyaw = wrap_angle(self.yaw - other.yaw)
        both_nan = np.isnan(self.yaw) & np.isnan(other.yaw)
        return bool(np.all(both_nan | (np.abs(dyaw) <= atol)))

    # -- derivation -------------------------------------------------------------------
    def select(self, index: ArrayLike) -> Boxes3D:
        """Boxes picked by a boolean mask or an integer index array."""
        idx = np.asarray(index)
        return Boxes3D(**{f.name: frozen(getattr(self, f.name)[idx]) for f in fields(self)})

    def with_geometry(
        self,
        centers: ArrayLike | None = None,
        sizes: ArrayLike | None = None,
        yaw: ArrayLike | None = None,
    ) -> Boxes3D:
        """New boxes with some geometry replaced; everything else is kept."""
        return Boxes3D.create(
            self.centers if centers is None else centers,
            self.sizes if sizes is None else sizes,
            self.yaw if yaw is None else yaw,
            self.labels,
            scores=self.scores,
            track_ids=self.track_ids,
            truncation=self.truncation,
            occlusion=self.occlusion,
            alpha=self.alpha,
            bbox2d=self.bbox2d,
        )

    def replace(self, **changes: ArrayLike) -> Boxes3D:
        """New boxes with any fields replaced (validated like :meth:`create`)."""
        current = {f.name: getattr(self, f.name) for f in fields(self)}
        current.update(changes)
        return Boxes3D.create(
            current.pop("centers"), current.pop("sizes"), current.pop("yaw"),
            current.pop("labels"), **current,
        )

    @staticmethod
    def concat(parts: Sequence[Boxes3D]) -> Boxes3D:
        if not parts:
            return Boxes3D.empty()
        return Boxes3D(
            **{
                f.name: frozen(np.concatenate([getattr(p, f.name) for p in parts], axis=0))
                for f in fields(Boxes3D)
            }
        )


__all__ = ["Boxes3D", "wrap_angle"]
