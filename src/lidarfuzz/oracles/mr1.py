"""Zhou & Sun's MR1 in the forms their experiment counts, overall and per class.

MR1 (Zhou & Sun, "Metamorphic Testing of Driverless Cars", CACM 2019): points added outside the
region of interest must not change the obstacles a system finds inside it. For one source /
follow-up pair, with ``O`` and ``O'`` the obstacles inside the ROI (matched one to one, same class,
by IoU), three verdicts, each nested in the next:

* **count form** — ``|O| > |O'|``, what the paper checked ("less strict than MR1");
* **subset form** — some obstacle of ``O`` has no match in ``O'`` (``O ⊆ O'`` fails: MR1 as stated);
* **strict form** — the obstacle set changed at all: an obstacle lost or a new one found.

A count-form violation is a subset violation (more source obstacles than follow-up ones leave one
unmatched), and a subset violation is a strict one. Per class ``c`` the same verdicts on ``O_c``
and ``O'_c``: an object whose class changed (a car now reported as unknown) leaves the overall
count unchanged but shows in its class's count form and in the strict form.

Unlike :class:`~lidarfuzz.oracles.relations.detection.Preservation` (MR1 as a campaign relation),
nothing is left out for lost evidence and, by default, every reported object counts whatever its
score, as the paper compared the obstacle lists Apollo reported.

Example:
    >>> from lidarfuzz.scene.boxes import Boxes3D
    >>> before = Boxes3D.create([[10, 0, 0], [20, 0, 0]], [[4, 2, 1.5], [4, 2, 1.5]], [0, 0], ["Car", "Car"])
    >>> verdicts = mr1_forms(before, before.select([0]))
    >>> v = verdicts[ALL]
    >>> (v.source, v.follow, v.lost, v.new, v.count_violated, v.strict_violated)
    (2, 1, 1, 0, True, True)
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.oracles.matching import IGNORED_LABELS, Metric, match_boxes
from lidarfuzz.scene.boxes import Boxes3D

#: The key of the verdict over every class together.
ALL = "all"
#: The classes Apollo's obstacle perception reported in the paper's Figure 3, in its order.
PAPER_CLASSES: tuple[str, ...] = ("Car", "Pedestrian", "Cyclist", "Unknown")


@dataclass(frozen=True)
class Mr1Verdict:
    """MR1 on one pair, for one class or all of them.

    Attributes:
        source: ``|O|``, obstacles inside the ROI in the source output.
        follow: ``|O'|``, the same in the follow-up output.
        lost: Obstacles of ``O`` without a match in ``O'``.
        new: Obstacles of ``O'`` without a match in ``O``.
    """

    source: int
    follow: int
    lost: int
    new: int

    @property
    def count_violated(self) -> bool:
        """The paper's checked form: ``|O| > |O'|``."""
        return self.source > self.follow

    @property
    def subset_violated(self) -> bool:
        """MR1 as stated: ``O ⊆ O'`` fails (an obstacle lost)."""
        return self.lost > 0

    @property
    def strict_violated(self) -> bool:
        """The obstacle set changed: an obstacle lost or a new one found."""
        return self.lost > 0 or self.new > 0


def _kept(boxes: Boxes3D, roi: Any, min_score: float) -> Boxes3D:
    """The reported obstacles that count: score at least ``min_score``, not a don't-care region,
    centre inside ``roi`` (a :class:`~lidarfuzz.scene.roi.RoiMap`; None: everywhere)."""
    labels = np.char.lower(boxes.labels.astype(str))
    keep: NDArray[np.bool_] = ~(boxes.scores < min_score) & ~np.isin(labels, list(IGNORED_LABELS))
    if roi is not None and len(boxes):
        keep &= roi.contains_xy(boxes.centers[:, :2])
    return boxes.select(np.flatnonzero(keep))


def mr1_forms(source: Boxes3D, follow: Boxes3D, roi: Any = None, *, min_score: float = 0.0,
              metric: Metric = "bev", min_iou: float = 0.5) -> dict[str, Mr1Verdict]:
    """MR1's verdicts on one pair: under :data:`ALL` and under each class either output reports.

    Args:
        source: The system's output on the source frame.
        follow: Its output on the follow-up frame (points added outside the ROI).
        roi: The region of interest (an object counts when its centre is inside); None: all objects.
        min_score: Objects scoring lower are not obstacles (0: every reported object).
        metric: ``bev`` or ``3d`` IoU for matching.
        min_iou: Smallest IoU of a match (same class only).

    Returns:
        ``{ALL: verdict, class: verdict, ...}``; classes as the system names them.
    """
    before, after = _kept(source, roi, min_score), _kept(follow, roi, min_score)
    matching = match_boxes(before, after, metric=metric, min_iou=min_iou, class_aware=True)
    lost_labels = before.labels[matching.unmatched_a].astype(str)
    new_labels = after.labels[matching.unmatched_b].astype(str)
    source_labels, follow_labels = before.labels.astype(str), after.labels.astype(str)
    out = {ALL: Mr1Verdict(len(before), len(after), len(lost_labels), len(new_labels))}
    for cls in sorted(set(source_labels.tolist()) | set(follow_labels.tolist())):
        out[cls] = Mr1Verdict(int((source_labels == cls).sum()), int((follow_labels == cls).sum()),
                              int((lost_labels == cls).sum()), int((new_labels == cls).sum()))
    return out


@dataclass
class Mr1Tally:
    """MR1's verdicts over many pairs, for one class (or :data:`ALL`).

    Attributes:
        pairs: Pairs tallied (every pair counts for every class, as in the paper's 100 % columns).
        present: Pairs whose source output has an obstacle of the class.
        count: Pairs violating the count form.
        subset: Pairs violating the subset form.
        strict: Pairs violating the strict form.
    """

    pairs: int = 0
    present: int = 0
    count: int = 0
    subset: int = 0
    strict: int = 0

    def add(self, verdict: Mr1Verdict | None) -> None:
        """One more pair (``None``: the class appears in neither output: nothing violated)."""
        self.pairs += 1
        if verdict is None:
            return
        self.present += verdict.source > 0
        self.count += verdict.count_violated
        self.subset += verdict.subset_violated
        self.strict += verdict.strict_violated

    def rate(self, form: str) -> float:
        """Share of pairs violating ``form`` (``count``, ``subset`` or ``strict``; 0 with no pairs)."""
        if form not in ("count", "subset", "strict"):
            raise ValueError(f"MR1 form {form!r}: choose count, subset or strict")
        return getattr(self, form) / self.pairs if self.pairs else 0.0


@dataclass
class Mr1Table:
    """Tallies per class over many pairs; classes as they come, :data:`ALL` and ``classes`` always."""

    classes: tuple[str, ...] = PAPER_CLASSES
    tallies: dict[str, Mr1Tally] = field(default_factory=dict)

    def add(self, verdicts: Mapping[str, Mr1Verdict]) -> None:
        """Tally one pair's verdicts (from :func:`mr1_forms`)."""
        for cls in (*self.names(), *(c for c in verdicts if c not in self.tallies and c not in self.classes)):
            self.tallies.setdefault(cls, Mr1Tally(pairs=self._pairs()))
        for cls, tally in self.tallies.items():
            tally.add(verdicts.get(cls))

    def _pairs(self) -> int:
        return self.tallies[ALL].pairs if ALL in self.tallies else 0

    def names(self) -> tuple[str, ...]:
        """:data:`ALL`, the expected classes, then any other class seen, in that order."""
        extra = sorted(c for c in self.tallies if c != ALL and c not in self.classes)
        return (ALL, *self.classes, *extra)

    def get(self, cls: str) -> Mr1Tally:
        """The tally of ``cls`` (an empty one for a class never tallied)."""
        return self.tallies.get(cls) or Mr1Tally(pairs=self._pairs())


def tally(verdicts: Iterable[Mapping[str, Mr1Verdict]], classes: tuple[str, ...] = PAPER_CLASSES) -> Mr1Table:
    """Tally many pairs' verdicts per class.

    Example:
        >>> car = Boxes3D.create([[10, 0, 0]], [[4, 2, 1.5]], [0], ["Car"])
        >>> table = tally([mr1_forms(car, car), mr1_forms(car, Boxes3D.empty())])
        >>> table.get("Car").count, table.get("Car").pairs, table.get("Unknown").count
        (1, 2, 0)
    """
    table = Mr1Table(classes=classes)
    for item in verdicts:
        table.add(item)
    return table


__all__ = ["ALL", "PAPER_CLASSES", "Mr1Table", "Mr1Tally", "Mr1Verdict", "mr1_forms", "tally"]
