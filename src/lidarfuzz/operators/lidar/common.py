"""Helpers shared by the LiDAR operators."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import DTypeLike, NDArray

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.calib import KittiCalibration
from lidarfuzz.scene.labels import camera_labels
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


def with_added_points(cloud: PointCloud, xyz: NDArray[np.floating], intensity: NDArray[np.floating]) -> PointCloud:
    """``cloud`` plus new points; their other channels get the channel defaults (``label`` 0 =
    unlabelled, ``instance`` −1 = no object, ``ring`` −1 = unknown, ``time`` 0)."""
    if len(xyz) == 0:
        return cloud
    added = PointCloud(np.column_stack([xyz, intensity]).astype(np.float32)).conform(cloud.channels)
    return PointCloud.concat([cloud, added])


def cloud_extent(cloud: PointCloud) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(min, max) of x, y, z; a unit box at the origin for an empty cloud."""
    if len(cloud) == 0:
        return np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    xyz = cloud.xyz
    # Column by column: a reduction along axis 0 of the strided N×3 view is ~15× slower.
    low = np.array([float(xyz[:, i].min()) for i in range(3)])
    high = np.array([float(xyz[:, i].max()) for i in range(3)])
    return low, high


#: Largest scratch array (elements) kept for the next call: 2²¹ covers every sensor's frame and a
#: 2M-point cloud (16 MiB a float64 array); a longer one is made for its call and freed after it.
SCRATCH_KEEP_LIMIT = 1 << 21

_scratch = threading.local()


def scratch(name: str, n: int, dtype: DTypeLike = np.float64) -> NDArray[Any]:
    """This thread's reusable array ``name`` of ``n`` elements of ``dtype``; its contents are
    undefined (whatever the last user left).

    Why: an operator's per-point temporaries are a few fresh N-long arrays per call, and the
    allocator gives the freed top of the heap back to the system between calls, so every call
    faulted the same pages in again (~2,400 pages a fog call, ~4,000 a rain call: 3–4.6 ms of
    system time on a 120k-point frame). Kept per thread (``threading.local``: two threads never
    share one), grown when a longer cloud comes, kept up to :data:`SCRATCH_KEEP_LIMIT` elements.

    Rules for callers: a name is one temporary of one computation (two arrays alive at once need
    two names; a helper another caller's arrays are passed to uses names of its own), and a
    scratch array or a view of one never leaves the operator: outputs are fresh arrays.

    >>> a = scratch("doc.values", 4)
    >>> a.shape, scratch("doc.values", 3).base is a.base
    ((4,), True)
    """
    pool: dict[tuple[str, np.dtype[Any]], NDArray[Any]] = _scratch.__dict__.setdefault("pool", {})
    key = (name, np.dtype(dtype))
    buffer = pool.get(key)
    if buffer is None or len(buffer) < n:
        buffer = np.empty(n, key[1])
        if n <= SCRATCH_KEEP_LIMIT:
            pool[key] = buffer
    return buffer[:n]


def release_scratch() -> None:
    """Drop this thread's scratch arrays (:func:`scratch`): their memory goes back to the
    allocator, and the next call makes them afresh (what a memory measurement must see)."""
    _scratch.__dict__.pop("pool", None)


#: Rows per block of :func:`column_blocks` (16384 × 32 bytes for an eight-channel frame: in the L2 cache).
COLUMN_BLOCK = 16384


def column_blocks(data: NDArray[np.float32], columns: tuple[int, ...],
                  block: int = COLUMN_BLOCK) -> Iterator[tuple[slice, NDArray[np.float32]]]:
    """The rows of ``data`` block by block, as ``(rows, values)`` with ``values[j]`` the block's
    column ``columns[j]``, contiguous: one pass over the N×C array for any number of columns
    (each strided column of the whole frame read on its own brings the whole array through the
    cache again), and vectorised arithmetic and reductions on the block. ``values`` is a reused
    buffer: use it before the next block."""
    n = len(data)
    buffer = np.empty((len(columns), min(block, n)), data.dtype)
    for start in range(0, n, block):
        rows = slice(start, min(start + block, n))
        values = buffer[:, :rows.stop - start]
        for j, column in enumerate(columns):
            np.copyto(values[j], data[rows, column])
        yield rows, values


def mod_period(values: NDArray[np.floating], period: float, out: NDArray[np.floating] | None = None,
               ) -> NDArray[np.floating]:
    """``np.mod(values, period, out=out)`` for a positive, finite period: the same bits, ~10× faster
    where every value lies in [−period, 2·period) (an angle shifted by less than a turn).

    np.mod calls fmod per value and corrects its sign (``r + period`` for a negative ``r``; +0 for
    a zero). On that interval fmod's result is known without calling it: ``x`` on [−period,
    period) and ``x − period`` on [period, 2·period), exact by Sterbenz's lemma; so the result is
    ``x + period`` for negative x (the same rounded addition as np.mod's correction), ``x − period``
    for x ≥ period, else x (−0 made +0, as np.mod makes a zero). The period is rounded to the
    values' precision first, as numpy rounds a Python float for a float32 array. Other inputs
    (NaN, infinities, values farther out) go to np.mod itself.
    """
    p = values.dtype.type(period)
    if values.size == 0 or not (float(values.min()) >= -p and float(values.max()) < 2 * p):
        return np.mod(values, period, out=out)
    below = np.multiply(values < 0, p, dtype=values.dtype)  # p where x < 0, else +0
    above = np.multiply(values >= p, p, dtype=values.dtype)
    result = np.add(values, values.dtype.type(0), out=out)  # x + 0: −0 becomes +0
    result += below
    result -= above
    return result


def in_axis_box(xyz: NDArray[np.floating], center: tuple[float, float, float],
                size: tuple[float, float, float]) -> NDArray[np.bool_]:
    inside = np.ones(len(xyz), bool)
    for i in range(3):  # column by column: no N×3 temporaries
        inside &= np.abs(xyz[:, i] - np.float32(center[i])) <= np.float32(size[i] / 2)
    return inside


def relabel_in_image(boxes: Boxes3D, calib: KittiCalibration | None) -> Boxes3D:
    """After a geometric change: truncation, 2D box and alpha recomputed as the simulator labels a
    box (:func:`lidarfuzz.scene.labels.camera_labels`: truncation is the share of the box outside
    the image or behind the camera, the 2D box the devkit's clipped projection). A box with no area
    in the image gets truncation 1 and no 2D box: KITTI labels exist only in the camera's view, so
    the devkit ignores it instead of counting an object no camera-based label could have.
    Occlusion is kept: it describes the source frame (callers that know better set it)."""
    if calib is None or len(boxes) == 0:
        return boxes
    geometric = boxes.has_geometry
    if not geometric.any():
        return boxes
    index = np.flatnonzero(geometric)
    fields = camera_labels(calib, boxes.as_array()[index])
    alpha, bbox2d, truncation = boxes.alpha.copy(), boxes.bbox2d.copy(), boxes.truncation.copy()
    alpha[index], bbox2d[index], truncation[index] = fields.alpha, fields.bbox2d, fields.truncation
    return boxes.replace(alpha=alpha, bbox2d=bbox2d, truncation=truncation)


def intensity_scale(values: NDArray[np.floating]) -> float:
    """The data's intensity full scale, inferred: 1 for [0, 1] data (KITTI, the simulator), 255 for
    8-bit, 65535 for 16-bit, else the maximum itself. Operators that model physics convert with
    it explicitly (a model fed 0–255 units with [0, 1] data is a known defect of public tools)."""
    return scale_of_maximum(float(values.max()) if len(values) else 0.0)


def scale_of_maximum(top: float) -> float:
    """:func:`intensity_scale` of values whose maximum is ``top`` (0 for no values)."""
    for scale in (1.0, 255.0, 65535.0):
        if top <= scale:
            return scale
    return top


def copy_with_maximum(data: NDArray[np.float32], column: int,
                      block: int = COLUMN_BLOCK) -> tuple[NDArray[np.float32], float]:
    """A copy of the non-empty N×C ``data`` and the maximum of one of its columns (NaN if it holds
    a NaN, as ``ndarray.max`` gives it), read block by block from the copy while the block is in
    the cache: the strided column of the whole frame read on its own would bring the whole array
    through the cache a second time."""
    out = np.empty_like(data)
    tops = np.empty(-(-len(data) // block), data.dtype)
    for k, start in enumerate(range(0, len(data), block)):
        rows = out[start:start + block]
        np.copyto(rows, data[start:start + block])
        tops[k] = rows[:, column].max()
    return out, float(tops.max())


#: Integer intensity types a reader may record instead of a number (LAS: ``"uint16"``).
_TYPE_SCALES = {"uint8": 255.0, "uint16": 65535.0}


def declared_intensity_scale(scene: Scene) -> float | None:
    """The full scale a reader recorded in ``scene.metadata["intensity_scale"]`` (a positive
    number, or an integer type name such as ``"uint16"``); None when absent or unusable."""
    value = scene.metadata.get("intensity_scale")
    if isinstance(value, str):
        value = _TYPE_SCALES.get(value.strip().lower(), value)
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        return None
    try:
        scale = float(value)
    except ValueError:
        return None
    return scale if np.isfinite(scale) and scale > 0 else None


def scene_intensity_scale(scene: Scene) -> float:
    """The frame's intensity full scale: the one its reader declared (1 for KITTI, 255 for
    nuScenes, …) when there is one, else :func:`intensity_scale` inferred from the values — a
    dark 8-bit frame whose readings all stay under 1 would otherwise pass for [0, 1] data."""
    declared = declared_intensity_scale(scene)
    return declared if declared is not None else intensity_scale(scene.points.intensity)
