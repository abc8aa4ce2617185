"""Matching two sets of boxes: detections to ground truth, or source detections to follow-up ones.

Boxes match only within a class (unless ``class_aware=False``) and only when their
overlap (rotated BEV or 3D IoU) is at least ``min_iou``. Two methods:

* ``hungarian`` — the assignment maximising the total IoU of the kept pairs
  (:func:`scipy.optimize.linear_sum_assignment`), the optimal one-to-one matching;
* ``greedy`` — boxes of the first set in descending score, each taking the unmatched box
  of the second set it overlaps most (the rule of detection benchmarks).

:func:`detection_counts` turns a detections-vs-ground-truth matching into TP/FP/FN per
class and range bin.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.geometry import iou_3d, iou_bev

Metric = Literal["bev", "3d"]
Method = Literal["hungarian", "greedy"]
#: Range bins (metres from the sensor, in the ground plane) for per-range counts.
RANGE_BINS: tuple[float, ...] = (0.0, 20.0, 40.0, float("inf"))
#: Labels that never take part in matching (regions without geometry).
IGNORED_LABELS: frozenset[str] = frozenset({"dontcare"})


@dataclass(frozen=True)
class Matching:
    """A one-to-one matching between boxes ``a`` and boxes ``b``.

    Attributes:
        pairs: K×2 indices ``(i in a, j in b)``.
        iou: IoU of each pair.
        unmatched_a: Indices of ``a`` without a partner.
        unmatched_b: Indices of ``b`` without a partner.
    """

    pairs: NDArray[np.int64]
    iou: NDArray[np.float64]
    unmatched_a: NDArray[np.int64]
    unmatched_b: NDArray[np.int64]

    def partner_of_a(self, n: int) -> NDArray[np.int64]:
        """For each of the ``n`` boxes of ``a``, its partner in ``b`` or -1."""
        out = np.full(n, -1, dtype=np.int64)
        out[self.pairs[:, 0]] = self.pairs[:, 1]
        return out

    def partner_of_b(self, n: int) -> NDArray[np.int64]:
        out = np.full(n, -1, dtype=np.int64)
        out[self.pairs[:, 1]] = self.pairs[:, 0]
        return out


def _threshold(min_iou: float | Mapping[str, float], labels: NDArray[np.str_]) -> NDArray[np.float64]:
    if isinstance(min_iou, Mapping):
        lowered = {k.lower(): float(v) for k, v in min_iou.items()}
        default = lowered.get("*", 0.5)
        return np.array([lowered.get(label, default) for label in labels], dtype=np.float64)
    return np.full(len(labels), float(min_iou))


def overlap_matrix(a: Boxes3D, b: Boxes3D, metric: Metric = "bev") -> NDArray[np.float64]:
    """|a|×|b| rotated IoU in the bird's-eye view or in 3D."""
    if metric not in ("bev", "3d"):
        raise ValueError(f"metric must be 'bev' or '3d', got {metric!r}")
    fn = iou_bev if metric == "bev" else iou_3d
    return fn(a.as_array(), b.as_array())


def match_boxes(
    a: Boxes3D,
    b: Boxes3D,
    *,
    metric: Metric = "bev",
    min_iou: float | Mapping[str, float] = 0.5,
    method: Method = "hungarian",
    class_aware: bool = True,
) -> Matching:
    """Match boxes ``a`` to boxes ``b``.

    Args:
        a: First set (for ``greedy``, its scores give the order; NaN scores keep input order).
        b: Second set.
        metric: ``bev`` or ``3d`` IoU.
        min_iou: Smallest IoU of a match (inclusive); a float or a mapping class → IoU,
            keyed by ``a``'s labels (``"*"`` for the rest, default 0.5).
        method: ``hungarian`` (optimal) or ``greedy`` (by score).
        class_aware: Only boxes with the same label (case-insensitive) match.

    Example:
        >>> one = Boxes3D.create([[10, 0, 0]], [[4, 2, 1.5]], [0.0], ["Car"])
        >>> m = match_boxes(one, one)
        >>> m.pairs.tolist(), m.iou.round(3).tolist()
        ([[0, 0]], [1.0])
    """
    if method not in ("hungarian", "greedy"):
        raise ValueError(f"method must be 'hungarian' or 'greedy', got {method!r}")
    la = np.char.lower(a.labels.astype(str))
    lb = np.char.lower(b.labels.astype(str))
    overlap = overlap_matrix(a, b, metric)
    allowed = overlap >= _threshold(min_iou, la)[:, None]
    allowed &= ~np.isin(la, list(IGNORED_LABELS))[:, None] & ~np.isin(lb, list(IGNORED_LABELS))[None, :]
    if class_aware:
        allowed &= la[:, None] == lb[None, :]
    pairs: list[tuple[int, int]] = []
    if allowed.any():
        if method == "hungarian":
            rows, cols = np.nonzero(allowed.any(axis=1))[0], np.nonzero(allowed.any(axis=0))[0]
            gain = np.where(allowed, overlap, 0.0)[np.ix_(rows, cols)]
            r, c = linear_sum_assignment(gain, maximize=True)
            keep = allowed[rows[r], cols[c]]
            pairs = list(zip(rows[r][keep].tolist(), cols[c][keep].tolist(), strict=True))
        else:
            scores = np.nan_to_num(a.scores, nan=-np.inf)
            taken = np.zeros(len(b), dtype=bool)
            for i in np.argsort(-scores, kind="stable"):
                options = np.where(allowed[i] & ~taken, overlap[i], -1.0)
                j = int(np.argmax(options)) if len(b) else 0
                if len(b) and options[j] >= 0.0:
                    pairs.append((int(i), j))
                    taken[j] = True
            pairs.sort()
    pair_array = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return Matching(
        pairs=pair_array,
        iou=overlap[pair_array[:, 0], pair_array[:, 1]] if len(pair_array) else np.zeros(0),
        unmatched_a=np.setdiff1d(np.arange(len(a)), pair_array[:, 0]).astype(np.int64),
        unmatched_b=np.setdiff1d(np.arange(len(b)), pair_array[:, 1]).astype(np.int64),
    )


def ground_range(boxes: Boxes3D) -> NDArray[np.float64]:
    """Distance of each box centre from the sensor in the ground plane (metres)."""
    return np.hypot(boxes.centers[:, 0], boxes.centers[:, 1])


def range_bin_labels(bins: Sequence[float] = RANGE_BINS) -> list[str]:
    """``"0-20"``, ``"20-40"``, ``"40+"`` for the default bins."""
    return [f"{lo:g}+" if np.isinf(hi) else f"{lo:g}-{hi:g}" for lo, hi in pairwise(bins)]


def _bin(distance: NDArray[np.float64], bins: Sequence[float]) -> NDArray[np.int64]:
    index = np.searchsorted(np.asarray(bins), distance, side="right") - 1
    return np.clip(index, 0, len(bins) - 2).astype(np.int64)


@dataclass(frozen=True)
class CountRow:
    cls: str
    range_bin: str
    tp: int
    fp: int
    fn: int

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else float("nan")

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else float("nan")


def detection_counts(
    detections: Boxes3D,
    ground_truth: Boxes3D,
    *,
    metric: Metric = "bev",
    min_iou: float | Mapping[str, float] = 0.5,
    method: Method = "hungarian",
    range_bins: Sequence[float] = RANGE_BINS,
    min_score: float = 0.0,
) -> list[CountRow]:
    """TP/FP/FN per class and range bin of one frame's detections against its ground truth.

    A TP is binned by its ground-truth box's range, an FN by its own, an FP by the
    detection's. Detections scoring below ``min_score`` are left out; DontCare regions
    neither match nor count.
    """
    dets = detections.select(~(detections.scores < min_score))
    m = match_boxes(dets, ground_truth, metric=metric, min_iou=min_iou, method=method)
    gt_labels = ground_truth.labels.astype(str)
    dt_labels = dets.labels.astype(str)
    gt_bin = _bin(ground_range(ground_truth), range_bins)
    dt_bin = _bin(ground_range(dets), range_bins)
    names = range_bin_labels(range_bins)
    table: dict[tuple[str, str], list[int]] = {}

    def add(cls: str, bin_index: int, column: int) -> None:
        if cls.lower() in IGNORED_LABELS:
            return
        table.setdefault((cls, names[bin_index]), [0, 0, 0])[column] += 1

    for _, j in m.pairs:
        add(gt_labels[j], int(gt_bin[j]), 0)
    for i in m.unmatched_a:
        add(dt_labels[i], int(dt_bin[i]), 1)
    for j in m.unmatched_b:
        add(gt_labels[j], int(gt_bin[j]), 2)
    return [CountRow(cls, rb, *counts) for (cls, rb), counts in sorted(table.items())]
