"""Zhou & Sun's MR1 forms (:mod:`lidarfuzz.oracles.mr1`): verdicts worked out by hand per class."""

from __future__ import annotations

import pytest

from lidarfuzz.oracles.mr1 import ALL, PAPER_CLASSES, Mr1Verdict, mr1_forms, tally
from lidarfuzz.scene.boxes import Boxes3D
from lidarfuzz.scene.roi import RoiMap

CAR = [4.0, 2.0, 1.5]
PED = [0.8, 0.6, 1.75]
CYC = [1.8, 0.6, 1.7]


def boxes(rows: list[tuple[str, float, float, list[float]]], scores: list[float] | None = None) -> Boxes3D:
    """``(label, x, y, size)`` rows, heading 0."""
    if not rows:
        return Boxes3D.empty()
    return Boxes3D.create([[x, y, 0.0] for _, x, y, _ in rows], [s for *_, s in rows], [0.0] * len(rows),
                          [label for label, *_ in rows], scores=scores or [0.9] * len(rows))


def test_identical_outputs_violate_nothing() -> None:
    out = boxes([("Car", 10, 0, CAR), ("Pedestrian", 5, 3, PED)])
    verdicts = mr1_forms(out, out)
    assert set(verdicts) == {ALL, "Car", "Pedestrian"}
    assert all(not v.strict_violated for v in verdicts.values())
    assert verdicts[ALL] == Mr1Verdict(source=2, follow=2, lost=0, new=0)


def test_lost_new_and_moved_objects_per_class() -> None:
    # source: cars A (10, 0) and B (20, 5), pedestrian C (5, 3)
    # follow-up: car A, C moved 0.05 m (BEV IoU (0.75*0.6)/(2*0.48-0.45) = 0.88: matched), cyclist D new
    source = boxes([("Car", 10, 0, CAR), ("Car", 20, 5, CAR), ("Pedestrian", 5, 3, PED)])
    follow = boxes([("Car", 10, 0, CAR), ("Pedestrian", 5.05, 3, PED), ("Cyclist", 15, -4, CYC)])
    v = mr1_forms(source, follow)
    # overall: |O| = |O'| = 3, so the count form holds; B is lost and D is new
    assert v[ALL] == Mr1Verdict(3, 3, 1, 1)
    assert (v[ALL].count_violated, v[ALL].subset_violated, v[ALL].strict_violated) == (False, True, True)
    # cars: 2 -> 1, every form violated
    assert v["Car"] == Mr1Verdict(2, 1, 1, 0)
    assert v["Car"].count_violated
    # pedestrians: found again
    assert not v["Pedestrian"].strict_violated
    # cyclists: only a new one, so only the strict form
    assert v["Cyclist"] == Mr1Verdict(0, 1, 0, 1)
    assert (v["Cyclist"].count_violated, v["Cyclist"].subset_violated, v["Cyclist"].strict_violated) == (
        False, False, True)


def test_a_class_change_keeps_the_overall_count() -> None:
    # a car reported as Unknown in the follow-up: |O| = |O'| overall, but the car is lost
    v = mr1_forms(boxes([("Car", 10, 0, CAR)]), boxes([("Unknown", 10, 0, CAR)]))
    assert not v[ALL].count_violated and v[ALL].subset_violated
    assert v["Car"].count_violated
    assert v["Unknown"] == Mr1Verdict(0, 1, 0, 1)


def test_only_objects_inside_the_roi_that_count() -> None:
    roi = RoiMap.from_polygons([[(0, -10), (30, -10), (30, 10), (0, 10)]])
    source = boxes([("Car", 10, 0, CAR), ("Car", 40, 0, CAR), ("Car", 20, 0, CAR), ("DontCare", 5, 5, CAR)],
                   scores=[0.9, 0.9, 0.04, 0.9])
    follow = boxes([("Car", 10, 0, CAR)])
    # the car at x = 40 is outside the ROI, the don't-care region never counts
    assert mr1_forms(source, follow, roi, min_score=0.05)[ALL] == Mr1Verdict(1, 1, 0, 0)
    # with every score counting, the low-score car at x = 20 is an obstacle, and it is lost
    assert mr1_forms(source, follow, roi)[ALL] == Mr1Verdict(2, 1, 1, 0)
    # without an ROI, the car at x = 40 counts too
    assert mr1_forms(source, follow)[ALL] == Mr1Verdict(3, 1, 2, 0)


def test_tally_per_class() -> None:
    car = boxes([("Car", 10, 0, CAR)])
    ped = boxes([("Pedestrian", 5, 3, PED)])
    both = boxes([("Car", 10, 0, CAR), ("Pedestrian", 5, 3, PED)])
    # pair 1: unchanged; pair 2: the pedestrian lost; pair 3: the car lost, a pedestrian found
    table = tally([mr1_forms(both, both), mr1_forms(both, car), mr1_forms(car, ped)])
    assert table.names() == (ALL, *PAPER_CLASSES)
    overall, cars, peds = table.get(ALL), table.get("Car"), table.get("Pedestrian")
    assert (overall.pairs, overall.present, overall.count, overall.subset, overall.strict) == (3, 3, 1, 2, 2)
    assert (cars.pairs, cars.present, cars.count, cars.subset, cars.strict) == (3, 3, 1, 1, 1)
    assert (peds.pairs, peds.present, peds.count, peds.subset, peds.strict) == (3, 2, 1, 1, 2)
    assert table.get("Unknown").pairs == 3 and table.get("Unknown").strict == 0
    assert overall.rate("subset") == pytest.approx(2 / 3)


def test_a_class_first_seen_late_counts_the_earlier_pairs() -> None:
    car = boxes([("Car", 10, 0, CAR)])
    truck = boxes([("Truck", 10, 0, [8.0, 2.5, 3.0])])
    table = tally([mr1_forms(car, car), mr1_forms(car, car), mr1_forms(truck, Boxes3D.empty())])
    assert table.names()[-1] == "Truck"
    assert (table.get("Truck").pairs, table.get("Truck").count) == (3, 1)


def test_unknown_form_is_refused() -> None:
    with pytest.raises(ValueError, match="form 'loose'"):
        tally([]).get(ALL).rate("loose")
