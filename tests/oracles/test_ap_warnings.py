"""AP computed from few objects or one frame says so (CLI, JSON and HTML).

The devkit picks at most one score threshold per true positive, so with ``n`` counted objects a
perfect detector fills only the first ``n`` of the 41 precision samples. Worked by hand:

* n = 2: R40 averages samples 1..40, one of which (sample 1) is filled → 1/40 = 2.5 %;
  R11 averages samples 0, 4, …, 40, one of which (sample 0) is filled → 1/11 = 9.09 %.
* n = 5: samples 1..4 filled → 4/40 = 10 %; samples 0 and 4 → 2/11 = 18.18 %.
* n = 41: every sample filled → 100 %.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lidarfuzz.cli.app import app
from lidarfuzz.oracles.kitti_eval import KittiEvalResult, KittiFrame, ap_ceiling, evaluate_kitti
from lidarfuzz.scene.boxes import Boxes3D
from tests.oracles.test_kitti_files import write_set

runner = CliRunner()


def cars(n: int) -> Boxes3D:
    """``n`` fully visible cars 8–14 m ahead (2D height > 40 px: counted at every difficulty)."""
    x = 8.0 + 1.5 * (np.arange(n) % 5)
    y = -6.0 + 3.0 * (np.arange(n) // 5)
    return Boxes3D.create(np.column_stack([x, y, np.full(n, -0.9)]), [[3.9, 1.6, 1.5]] * n, [0.0] * n,
                          ["Car"] * n, truncation=[0.0] * n, occlusion=[0] * n)


@pytest.mark.parametrize(("n", "r40", "r11"), [(1, 0.0, 100 / 11), (2, 2.5, 100 / 11), (5, 10.0, 200 / 11),
                                               (41, 100.0, 100.0), (500, 100.0, 100.0)])
def test_ceiling_matches_the_hand_worked_values(n: int, r40: float, r11: float) -> None:
    assert ap_ceiling(n) == pytest.approx((r40, r11))


@pytest.mark.parametrize("n", [2, 5])
def test_a_perfect_detector_on_few_objects_scores_the_ceiling_and_is_warned(n: int) -> None:
    gt = cars(n)
    result = evaluate_kitti([KittiFrame(gt, gt.replace(scores=np.linspace(0.9, 0.5, n)))], classes=["Car"])
    assert result.num_objects == {"Car": {"easy": n, "moderate": n, "hard": n}}
    assert result.get("3d", "Car", "moderate", "R40") == pytest.approx(ap_ceiling(n)[0])
    notes = result.sample_warnings()
    assert notes[0].startswith("AP from a single frame")
    assert notes[1].startswith(f"Car: too few objects to score (easy {n}, moderate {n}, hard {n}; fewer than 41)")
    assert f"at most {ap_ceiling(n)[0]:.1f} AP|R40" in notes[1]
    assert result.to_dict()["warnings"] == notes


def test_enough_objects_over_several_frames_give_no_warning() -> None:
    frames = [KittiFrame(cars(15), cars(15).replace(scores=np.full(15, 0.9))) for _ in range(3)]  # 45 cars
    result = evaluate_kitti(frames, classes=["Car"])
    assert result.get("3d", "Car", "moderate", "R40") == pytest.approx(100.0)
    assert result.sample_warnings() == []


def test_a_class_without_objects_is_named() -> None:
    frames = [KittiFrame(cars(15), cars(15).replace(scores=np.full(15, 0.9))) for _ in range(3)]
    notes = evaluate_kitti(frames, classes=["Car", "Cyclist"]).sample_warnings()
    assert len(notes) == 1 and notes[0].startswith("Cyclist: too few objects") and "AP is 0" in notes[0]


def test_round_trip_and_older_records() -> None:
    gt = cars(3)
    result = evaluate_kitti([KittiFrame(gt, gt.replace(scores=np.full(3, 0.9)))], classes=["Car"])
    again = KittiEvalResult.from_dict(json.loads(result.to_json()))
    assert again.sample_warnings() == result.sample_warnings()
    legacy = {k: v for k, v in result.to_dict().items() if k not in ("num_objects", "warnings")}
    assert KittiEvalResult.from_dict(legacy).sample_warnings() == ["AP from a single frame: it describes that frame, "
                                                                   "not the detector"]


def test_cli_eval_warns_and_the_json_holds_the_warnings(tmp_path: Path) -> None:
    _, dets = write_set(tmp_path / "kitti" / "training", frames=2, cars=3)  # 6 cars in all
    out = tmp_path / "ap.json"
    result = runner.invoke(app, ["eval", str(tmp_path / "kitti"), str(dets), "--classes", "Car", "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "warning: Car: too few objects to score" in result.output
    assert any(w.startswith("Car: too few objects") for w in json.loads(out.read_text())["warnings"])


def test_a_class_with_objects_at_some_difficulties_only_gets_each_ceiling() -> None:
    # moderate and hard count 1 object, easy none: a perfect detector scores 0 / 0 at easy, and with
    # one object 0 AP|R40 (no sample after recall 0) and 1/11 = 9.1 AP|R11 at moderate and hard
    result = KittiEvalResult(ap={}, overlaps={}, num_frames=3, num_objects={"Car": {"easy": 0, "moderate": 1,
                                                                                    "hard": 1}})
    assert result.sample_warnings() == [
        "Car: too few objects to score (easy 0, moderate 1, hard 1; fewer than 41): a perfect detector reaches at "
        "most 0.0 AP|R40 and 0.0 AP|R11 (easy); 0.0 AP|R40 and 9.1 AP|R11 (moderate, hard)"]


def test_a_campaign_names_the_original_classes_once_and_new_ones_per_mutant() -> None:
    from lidarfuzz.campaign.results import ap_warnings

    def stored(car: int, cyclist: int) -> dict[str, object]:
        counts = {"Car": {d: car for d in ("easy", "moderate", "hard")},
                  "Cyclist": {d: cyclist for d in ("easy", "moderate", "hard")}}
        return KittiEvalResult(ap={}, overlaps={}, num_frames=10, num_objects=counts).to_dict()

    from lidarfuzz.store.contracts import SubtaskSummary

    entries = [{"label": "original", "ap": stored(60, 5)},
               {"label": "fog@1", "ap": stored(58, 4)},  # Cyclist already named: not again
               {"label": "object_removal@5", "ap": stored(30, 2)},  # Car falls under 41
               {"label": "rotate_z@5", "ap": None}]  # no AP: nothing to say
    notes = ap_warnings([SubtaskSummary.model_validate({"id": i, "operator": e["label"].split("@")[0], **e})
                         for i, e in enumerate(entries)])
    assert [n.split(" (")[0] for n in notes] == ["Cyclist: too few objects to score",
                                                 "object_removal@5: Car: too few objects to score"]
