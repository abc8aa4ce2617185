"""Whether an object kept its evidence through a mutation: the assumption every harmlessness
relation makes before it blames the system for losing the object.

A relation that says "the object found before must be found after" is only fair when the
mutant still shows the object as the original did. An object whose points the operator
deleted (a lost sector, a cut-out, a thinned object), moved out of the sensor's view, or crowded
with points that were not there (clutter, spray, inserted objects beside it) no longer carries
the evidence the system found it by; losing it is not a bug. This module measures that, per
object, in the object's own frame — so an object the operator moved or the scene's transform
carried along is compared with itself:

* ``before`` — source points inside the object's box;
* ``kept`` — of those, how many the follow-up still has (a follow-up point within
  ``same_point_m`` of it, both expressed in their box's frame);
* ``added`` — follow-up points in the box grown by ``neighbourhood_m`` that match no source point
  there (what would join the object's cluster).

An object is checked when ``kept >= min_kept_share · before`` and ``added <= max_added_share ·
before``; otherwise the relation leaves it out and counts why.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field
from scipy.spatial import cKDTree

from lidarfuzz.oracles.relations.base import RelationConfig
from lidarfuzz.scene.geometry import points_in_boxes

#: Why an object was not checked (keys of :attr:`RelationOutcome.skipped`).
LOST = "lost most of its points"
CROWDED = "crowded by added points"
EMPTY = "no points in its box"


class EvidenceConfig(RelationConfig):
    """When an object counts as still shown by the mutant (see the module's docstring)."""

    evidence: bool = Field(default=True, description="check only objects that keep their evidence")
    min_kept_share: float = Field(default=0.5, ge=0.0, le=1.0,
                                  description="share of an object's points the mutant must keep")
    max_added_share: float = Field(default=0.1, ge=0.0,
                                   description="most points added around an object, as a share of its points")
    neighbourhood_m: float = Field(default=0.5, ge=0.0, description="how far around the box added points count (m)")
    same_point_m: float = Field(default=0.1, gt=0.0, description="a point within this distance is the same point (m)")


@dataclass(frozen=True)
class Evidence:
    """One object's points before and after the mutation (see the module's docstring)."""

    before: int
    kept: int
    added: int

    def verdict(self, cfg: EvidenceConfig) -> str:
        """``""`` when the object is checked, else why not (:data:`LOST`, :data:`CROWDED`, :data:`EMPTY`)."""
        if self.before == 0:
            return EMPTY
        if self.kept < cfg.min_kept_share * self.before:
            return LOST
        if self.added > cfg.max_added_share * self.before:
            return CROWDED
        return ""

    def as_dict(self) -> dict[str, int]:
        return {"points_before": self.before, "points_kept": self.kept, "points_added": self.added}


def _local(xyz: NDArray[np.float64], box: NDArray[np.float64]) -> NDArray[np.float64]:
    """Points in a box's frame (centre at the origin, x along its heading)."""
    d = xyz - box[:3]
    c, s = np.cos(box[6]), np.sin(box[6])
    return np.column_stack([d[:, 0] * c + d[:, 1] * s, -d[:, 0] * s + d[:, 1] * c, d[:, 2]])


def _xyz(sample: Any) -> NDArray[np.float64]:
    points = getattr(sample, "points", None)
    if points is None:
        return np.zeros((0, 3))
    return np.asarray(points.xyz if hasattr(points, "xyz") else points, dtype=np.float64)[:, :3]


def object_evidence(source: Any, source_boxes: NDArray[np.float64], follow: Any,
                    follow_boxes: NDArray[np.float64], cfg: EvidenceConfig,
                    transform: NDArray[np.float64] | None = None) -> list[Evidence]:
    """The evidence of each object: its box in the source (``source_boxes``, K×7) and the same
    object's box in the follow-up (``follow_boxes``: the same boxes for an operator that moves
    nothing, the transformed ones, or the moved object's label). With ``transform`` (the
    operator's 4×4 map, which may mirror) source points are mapped by it and compared in the
    follow-up box's frame; without, each side is read in its own box's frame."""
    src_boxes = np.asarray(source_boxes, dtype=np.float64).reshape(-1, 7)
    fol_boxes = np.asarray(follow_boxes, dtype=np.float64).reshape(-1, 7)
    if len(src_boxes) == 0:
        return []
    src_xyz, fol_xyz = _xyz(source), _xyz(follow)
    margin = cfg.neighbourhood_m
    src_near = points_in_boxes(src_xyz, src_boxes, margin=margin)
    fol_near = points_in_boxes(fol_xyz, fol_boxes, margin=margin)
    out = []
    for k in range(len(src_boxes)):
        src_points = src_xyz[src_near[:, k]]
        inside = np.all(np.abs(_local(src_points, src_boxes[k])) <= src_boxes[k, 3:6] / 2.0, axis=1)
        if transform is not None:
            src_local = _local(src_points @ transform[:3, :3].T + transform[:3, 3], fol_boxes[k])
        else:
            src_local = _local(src_points, src_boxes[k])
        fol_local = _local(fol_xyz[fol_near[:, k]], fol_boxes[k])
        before = int(inside.sum())
        if before == 0 or len(fol_local) == 0:
            out.append(Evidence(before, 0, len(fol_local)))
            continue
        tol = cfg.same_point_m
        kept = int(np.count_nonzero(cKDTree(fol_local).query(src_local[inside], distance_upper_bound=tol)[0] <= tol))
        if len(src_local):
            added = int(np.count_nonzero(cKDTree(src_local).query(fol_local, distance_upper_bound=tol)[0] > tol))
        else:
            added = len(fol_local)
        out.append(Evidence(before, kept, added))
    return out


def with_evidence(source: Any, source_boxes: NDArray[np.float64], follow: Any, follow_boxes: NDArray[np.float64],
                  cfg: EvidenceConfig, transform: NDArray[np.float64] | None = None,
                  ) -> tuple[NDArray[np.bool_], list[Evidence], dict[str, int]]:
    """Which objects to check (a mask), the evidence of each, and how many were left out by reason.
    With ``cfg.evidence`` off, or a source without points (nothing to judge by), every object is checked."""
    n = len(np.asarray(source_boxes).reshape(-1, 7))
    if not cfg.evidence or n == 0 or len(_xyz(source)) == 0:
        return np.ones(n, dtype=bool), [], {}
    evidence = object_evidence(source, source_boxes, follow, follow_boxes, cfg, transform)
    verdicts = [e.verdict(cfg) for e in evidence]
    skipped: dict[str, int] = {}
    for v in verdicts:
        if v:
            skipped[v] = skipped.get(v, 0) + 1
    return np.array([not v for v in verdicts], dtype=bool), evidence, skipped


__all__ = ["CROWDED", "EMPTY", "LOST", "Evidence", "EvidenceConfig", "object_evidence", "with_evidence"]
