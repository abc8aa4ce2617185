"""DeepTest's relaxed relation as the paper defines it: MSE_orig over the original data set (Eq. 2),
the ε filter per transformation (Eq. 3) and Table 7's λ × ε counts, on a worked example.

The example (boxes 4 m long, moved along x only, so each squared centre error is dx²; every
shift is below 4/3 m, so BEV IoU = (4 − dx)/(4 + dx) >= 0.5 and every object is matched):

Originals — three frames:
    A: objects at x = 10, 20; detected at 10.1, 20.3        errors 0.01, 0.09
    B: object at x = 15; detected at 15.2                   error  0.04
    C: objects at x = 25, 40; detected at 25.4 (40 missed)  error  0.16 (the missed one is not counted)
    MSE_orig = (0.01 + 0.09 + 0.04 + 0.16) / 4 = 0.075;  λ = 2: limit 0.15

Transformation T1 (its follow-ups of A, B, C):
    A': dx 0.2, 0.3 -> 0.04, 0.09 (max 0.09)   B': dx 0.4 -> 0.16   C': dx 0.1 -> 0.01
    λ = 2: only B' violates (0.16 > 0.15).  MSE_T1 = (0.04 + 0.09 + 0.16 + 0.01) / 4 = 0.075
Transformation T2:
    A': dx 0.5, 0.6 -> 0.25, 0.36 (max 0.36)   B': dx 0.1 -> 0.01   C': dx 0.7 -> 0.49
    λ = 2: A' (both objects) and C' violate.   MSE_T2 = (0.25 + 0.36 + 0.01 + 0.49) / 4 = 0.2775

Eq. 3: |MSE_T1 − MSE_orig| = 0 (kept at any ε); |MSE_T2 − MSE_orig| = 0.2025 (kept only from ε = 0.2025).

Table 7 on the grid λ ∈ {1, 2, 4} (limits 0.075, 0.15, 0.30), ε ∈ {0.03, 0.2, 0.5}:
    erroneous mutants T1 (max 0.09, 0.16, 0.01): λ=1: 2, λ=2: 1, λ=4: 0
    erroneous mutants T2 (max 0.36, 0.01, 0.49): λ=1: 2, λ=2: 2, λ=4: 2
    T1 counts in every column, T2 only at ε = 0.5:
        λ=1: 2, 2, 4   (no filter 4)
        λ=2: 1, 1, 3   (no filter 3)
        λ=4: 0, 0, 2   (no filter 2)
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarfuzz.operators.base import Relation
from lidarfuzz.oracles.deeptest import EPSILONS, LAMBDAS, erroneous_table, keeps, transformation_errors
from lidarfuzz.oracles.relations import DeepTestTolerance, Pair
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.points import PointCloud
from lidarfuzz.scene.scene import Scene


def boxes(xs: list[float], detected: bool = True) -> Boxes3D:
    n = len(xs)
    return Boxes3D.create([[x, 0.0, -0.8] for x in xs], [[4.0, 1.8, 1.5]] * n, [0.0] * n, ["Car"] * n,
                          scores=[0.9] * n if detected else None)


def scene(xs: list[float]) -> Scene:
    return Scene(PointCloud(np.zeros((0, 4))), boxes=boxes(xs, detected=False))


FRAMES = {"A": [10.0, 20.0], "B": [15.0], "C": [25.0, 40.0]}
ORIGINAL = {"A": [10.1, 20.3], "B": [15.2], "C": [25.4]}
T1 = {"A": [10.2, 20.3], "B": [15.4], "C": [25.1]}
T2 = {"A": [10.5, 20.6], "B": [15.1], "C": [25.7]}


def outcomes(relation: DeepTestTolerance, follow: dict[str, list[float]]) -> list:
    return [relation(Pair(scene(FRAMES[f]), scene(FRAMES[f]), boxes(ORIGINAL[f]), boxes(follow[f]),
                          Relation.INVARIANT)) for f in "ABC"]


def test_mse_orig_is_over_every_object_found_on_the_original_data_set() -> None:
    mse, n = DeepTestTolerance().mse_orig_of((boxes(FRAMES[f], detected=False), boxes(ORIGINAL[f])) for f in "ABC")
    assert n == 4 and mse == pytest.approx(0.075)
    assert math.isnan(DeepTestTolerance().mse_orig_of([(boxes([10.0], detected=False), boxes([]))])[0])


def test_eq2_judges_each_follow_up_by_the_data_sets_mse_orig() -> None:
    relation = DeepTestTolerance(**{"lambda": 2, "mse_orig": 0.075})
    a, b, c = outcomes(relation, T1)
    assert a.holds and c.holds and not b.holds
    (v,) = b.violations
    assert v.magnitude == pytest.approx(0.16) and "0.15" in v.message
    assert b.stats["mse_orig"] == 0.075 and b.stats["mse_orig_from"] == "data set"
    assert b.stats["squared_errors"] == [pytest.approx(0.16)]
    a2, b2, c2 = outcomes(relation, T2)
    assert [len(o.violations) for o in (a2, b2, c2)] == [2, 0, 1]
    # without a data-set MSE_orig, frame B's own error (0.04, limit 0.08) stands in, and says so
    alone = DeepTestTolerance(**{"lambda": 2})(Pair(scene(FRAMES["B"]), scene(FRAMES["B"]), boxes(ORIGINAL["B"]),
                                                    boxes(T1["B"]), Relation.INVARIANT))
    assert alone.stats["mse_orig_from"] == "frame" and alone.stats["mse_orig"] == pytest.approx(0.04)
    assert "this frame alone" in alone.violations[0].message


def test_eq3_and_table_7_on_the_worked_example() -> None:
    relation = DeepTestTolerance(**{"lambda": 2, "mse_orig": 0.075, "epsilon": 0.03})
    grid = (1.0, 2.0, 4.0)
    t1 = transformation_errors(((o.stats, o.holds) for o in outcomes(relation, T1)), lambdas=grid)
    t2 = transformation_errors(((o.stats, o.holds) for o in outcomes(relation, T2)), lambdas=grid)
    assert t1 is not None and t2 is not None
    assert t1.mse == pytest.approx(0.075) and t2.mse == pytest.approx(0.2775)
    assert (t1.objects, t1.mutants, t1.violated) == (4, 3, 1) and (t2.mutants, t2.violated) == (3, 2)
    assert t1.erroneous == (2, 1, 0) and t2.erroneous == (2, 2, 2)
    assert t1.kept and not t2.kept  # at the relation's ε = 0.03
    assert relation.keeps_transformation(t1.mse, 0.075) and not relation.keeps_transformation(t2.mse, 0.075)
    table = erroneous_table([t1, t2], epsilons=(0.03, 0.2, 0.5))
    assert table.mse_orig == 0.075
    assert table.counts == ((2, 2, 4), (1, 1, 3), (0, 0, 2))
    assert table.unfiltered == (4, 3, 2)
    assert table.kept == ((True, True, True), (False, False, True))
    assert table.notes == ()


def test_a_per_frame_mse_orig_is_left_out_of_the_table() -> None:
    frame = transformation_errors([({"mse_orig": 0.04, "mse_orig_from": "frame", "squared_errors": [0.16]}, False)],
                                  lambdas=(1.0,))
    kept = transformation_errors([({"mse_orig": 0.1, "mse_orig_from": "data set", "squared_errors": [0.3]}, False)],
                                 lambdas=(1.0,))
    assert frame is not None and kept is not None and not frame.kept
    table = erroneous_table([frame, kept], epsilons=(0.25,))
    # |0.3 − 0.1| = 0.2 <= 0.25: kept; 0.3 > 1 × 0.1: erroneous. The per-frame one counts nowhere.
    assert table.counts == ((1,),) and table.unfiltered == (1,) and table.kept == ((False,), (True,))
    assert "each frame's own error" in table.notes[0]
    assert transformation_errors([({"mse_orig": 0.1, "n": 1}, True)]) is None  # stored before per-object errors
    # a frame with no object found has no MSE_orig of its own: NaN, stored as null, never erroneous
    empty = transformation_errors([({"mse_orig": None, "mse_orig_from": "frame", "squared_errors": [0.3]}, True)],
                                  lambdas=(1.0,))
    assert empty is not None and empty.erroneous == (0,) and math.isnan(empty.mse_orig)


def test_the_grid_is_table_7s_and_eq3_is_inclusive() -> None:
    assert LAMBDAS == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0)
    assert EPSILONS[:5] == (0.01, 0.02, 0.03, 0.04, 0.05) and len(EPSILONS) == 10
    assert keeps(0.75, 0.5, 0.25) and not keeps(0.75, 0.5, 0.125) and not keeps(math.nan, 0.5, 1.0)
