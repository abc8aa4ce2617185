"""Binary frame payloads (``LFZ1``): point clouds as float32 blocks, boxes and highlights as JSON.

Layout (little-endian)::

    0-3      magic b"LFZ1"
    4-7      uint32 H, the header's length
    8..8+H   UTF-8 JSON header, padded with spaces so that 8 + H is a multiple of 4
    then     one float32 block per cloud, count × channels, row-major

The header lists the clouds (``name``, ``count``, ``channels``, ``offset`` in bytes from the
first block), the boxes of each cloud (``gt`` and ``detections`` as ``[x, y, z, l, w, h, yaw]``
rows in the LiDAR frame, with labels, scores and the ``missing`` / ``spurious`` / ``lost``
highlights) and, for a finding, the finding. Boxes without a 3D geometry (KITTI's DontCare
regions) are left out and every index refers to the lists as sent.

A pair's clouds carry one more channel, ``change``: 0 for a point present in both clouds
(the same x, y, z bit for bit), 1 for a point only the mutant has (added or moved), 2 for a
point only the original has (removed or moved).

Example:
    >>> import numpy as np
    >>> blob = encode([Cloud("frame", np.zeros((2, 4), np.float32), ("x", "y", "z", "intensity"))], {})
    >>> header, arrays = decode(blob)
    >>> header["clouds"][0]["count"], arrays["frame"].shape
    (2, (2, 4))
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.scene import Scene

MAGIC = b"LFZ1"
MEDIA_TYPE = "application/octet-stream"
SAME, ONLY_MUTANT, ONLY_ORIGINAL = 0, 1, 2


@dataclass(frozen=True)
class Cloud:
    """One cloud of a payload: an N×C array and its channel names."""

    name: str
    data: NDArray[np.float32]
    channels: tuple[str, ...]


def encode(clouds: Sequence[Cloud], boxes: Mapping[str, Any], **extra: Any) -> bytes:
    """The ``LFZ1`` bytes of ``clouds`` with ``boxes`` and any ``extra`` header keys."""
    entries, blocks, offset = [], [], 0
    for cloud in clouds:
        block = np.ascontiguousarray(cloud.data, dtype="<f4")
        if block.ndim != 2 or block.shape[1] != len(cloud.channels):
            raise ValueError(f"cloud {cloud.name!r}: {block.shape} does not match channels {cloud.channels}")
        entries.append({"name": cloud.name, "count": int(block.shape[0]), "channels": list(cloud.channels),
                        "offset": offset})
        blocks.append(block.tobytes())
        offset += block.nbytes
    header = json.dumps({"clouds": entries, "boxes": boxes, **extra}, separators=(",", ":"),
                        allow_nan=False).encode("utf-8")
    header += b" " * (-(8 + len(header)) % 4)
    return b"".join([MAGIC, struct.pack("<I", len(header)), header, *blocks])


def decode(blob: bytes) -> tuple[dict[str, Any], dict[str, NDArray[np.float32]]]:
    """The header and the clouds (by name) of an ``LFZ1`` payload (what the viewer does, in numpy)."""
    if blob[:4] != MAGIC:
        raise ValueError(f"not an LFZ1 payload (starts with {blob[:4]!r})")
    (length,) = struct.unpack_from("<I", blob, 4)
    header = json.loads(blob[8:8 + length].decode("utf-8"))
    start = 8 + length
    arrays = {}
    for entry in header["clouds"]:
        count, width = entry["count"], len(entry["channels"])
        arrays[entry["name"]] = np.frombuffer(blob, dtype="<f4", count=count * width,
                                              offset=start + entry["offset"]).reshape(count, width)
    return header, arrays


# -- boxes ---------------------------------------------------------------------------------
def _finite(values: NDArray[np.float64]) -> list[float | None]:
    return [float(v) if np.isfinite(v) else None for v in values]


def box_lists(boxes: Boxes3D | None, prefix: str) -> tuple[dict[str, Any], NDArray[np.int64]]:
    """``{prefix: rows, prefix_labels / labels: ..., scores}`` for the boxes with a geometry, and
    the map from each original index to its index as sent (-1: left out)."""
    if boxes is None or len(boxes) == 0:
        empty: dict[str, Any] = {prefix: [], "gt_labels" if prefix == "gt" else "labels": []}
        if prefix != "gt":
            empty["scores"] = []
        return empty, np.zeros(0, np.int64)
    keep = boxes.has_geometry
    index = np.full(len(boxes), -1, np.int64)
    index[keep] = np.arange(int(keep.sum()))
    rows = boxes.as_array()[keep]
    out: dict[str, Any] = {prefix: np.round(rows, 5).tolist()}
    if prefix == "gt":
        out["gt_labels"] = [str(v) for v in boxes.labels[keep]]
    else:
        out["labels"] = [str(v) for v in boxes.labels[keep]]
        out["scores"] = _finite(boxes.scores[keep])
    return out, index


def _remap(indices: Sequence[int], index: NDArray[np.int64]) -> list[int]:
    return sorted(int(index[i]) for i in indices if 0 <= i < len(index) and index[i] >= 0)


def frame_boxes(gt: Boxes3D, detections: Boxes3D | None = None, *, missing: Sequence[int] = (),
                spurious: Sequence[int] = (), lost: Sequence[int] = ()) -> dict[str, Any]:
    """The boxes of one cloud: ground truth, detections (None: the system failed there) and the
    highlighted indices (into ``gt`` for ``missing``, into ``detections`` for the others)."""
    gt_part, gt_index = box_lists(gt, "gt")
    det_part, det_index = box_lists(detections, "detections")
    return {**gt_part, **det_part, "failed": detections is None, "missing": _remap(missing, gt_index),
            "spurious": _remap(spurious, det_index), "lost": _remap(lost, det_index)}


# -- clouds --------------------------------------------------------------------------------
def _xyz_keys(data: NDArray[np.float32]) -> tuple[NDArray[np.uint64], NDArray[np.uint32]]:
    """Two integer keys per point that hold its x, y, z bit for bit: (x << 32 | y, z)."""
    bits = np.ascontiguousarray(data[:, :3], dtype="<f4").view(np.uint32)
    return (bits[:, 0].astype(np.uint64) << np.uint64(32)) | bits[:, 1].astype(np.uint64), bits[:, 2]


def change_flags(original: NDArray[np.float32], mutant: NDArray[np.float32]) -> tuple[
        NDArray[np.float32], NDArray[np.float32]]:
    """The ``change`` channel of each cloud, by exact x, y, z matching (see the module docstring).

    Both clouds are sorted together by their keys, so equal points become neighbours; each run
    of equal points is a group, and a point is the same in both clouds when its group holds
    points of both (one sort: about three times faster than two ``np.isin`` on 12-byte keys).
    """
    count = len(original)
    high_a, low_a = _xyz_keys(original)
    high_b, low_b = _xyz_keys(mutant)
    high, low = np.concatenate([high_a, high_b]), np.concatenate([low_a, low_b])
    if len(high) == 0:
        return np.zeros(0, np.float32), np.zeros(0, np.float32)
    order = np.lexsort((low, high))
    high, low = high[order], low[order]
    starts = np.ones(len(order), bool)
    starts[1:] = (high[1:] != high[:-1]) | (low[1:] != low[:-1])
    group = np.cumsum(starts) - 1  # of each sorted point
    from_original = order < count
    in_original = np.zeros(int(group[-1]) + 1, bool)
    in_original[group[from_original]] = True
    in_mutant = np.zeros_like(in_original)
    in_mutant[group[~from_original]] = True
    group_of = np.empty_like(group)
    group_of[order] = group
    return (np.where(in_mutant[group_of[:count]], SAME, ONLY_ORIGINAL).astype(np.float32),
            np.where(in_original[group_of[count:]], SAME, ONLY_MUTANT).astype(np.float32))


def scene_payload(scene: Scene, name: str = "frame", **extra: Any) -> bytes:
    """One frame: its points (every channel) and ground truth."""
    cloud = Cloud(name, scene.points.data, tuple(scene.points.channels))
    return encode([cloud], {name: frame_boxes(scene.boxes)}, frame_id=scene.frame_id, **extra)


def pair_payload(pair: Any) -> bytes:
    """A finding's original and mutant (a :class:`~lidarfuzz.report.bev.FindingPair`), with the
    ``change`` channel, both sides' ground truth and detections, and the finding's highlights:
    on the original, ``missing`` = ground truth the follow-up lost and ``lost`` = detections it
    lost; on the mutant, ``missing`` = where those objects are now and ``spurious`` = detections
    nothing maps to."""
    source = pair.source
    mutant = pair.mutant if pair.mutant is not None else pair.source
    original_data, mutant_data = source.points.data, mutant.points.data
    before, after = change_flags(original_data, mutant_data)
    clouds = [Cloud("original", np.column_stack([original_data, before]), (*source.points.channels, "change")),
              Cloud("mutant", np.column_stack([mutant_data, after]), (*mutant.points.channels, "change"))]
    source_detections = None if pair.source_failed else pair.source_detections
    boxes = {
        "original": frame_boxes(source.boxes, source_detections, missing=pair.lost_gt, lost=pair.lost_source),
        "mutant": frame_boxes(mutant.boxes, pair.follow_detections,
                              missing=[i for i in pair.lost_gt_follow if i >= 0], spurious=pair.spurious),
    }
    finding = {**dict(pair.finding), "has_mutant": pair.mutant is not None}
    return encode(clouds, boxes, finding=finding, frame_id=source.frame_id)


__all__ = ["MAGIC", "MEDIA_TYPE", "Cloud", "change_flags", "decode", "encode", "frame_boxes", "pair_payload",
           "scene_payload"]
