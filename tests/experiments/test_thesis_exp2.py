"""experiments/thesis_exp2.py: options, the per-class rows and table from a hand-made summary, the
thesis's conclusions checked against rows, the split's folder of links, and (slow) the whole
experiment on two frames with the thesis's eight operators."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]


def load_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("thesis_exp2", ROOT / "experiments" / "thesis_exp2.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["thesis_exp2"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def ap_record(car: tuple[float, float, float], ped: tuple[float, float, float], objects: int = 20) -> Any:
    """An AP record with moderate AP|R40 of Car and Pedestrian as (bbox, BEV, 3D); other cells 0."""
    from lidarfuzz.store.contracts import APRecord

    def cells(value: float) -> dict[str, dict[str, float]]:
        return {d: {"R11": 0.0, "R40": value if d == "moderate" else 0.0} for d in ("easy", "moderate", "hard")}

    ap = {metric: {"Car": cells(car[k]), "Pedestrian": cells(ped[k]), "Cyclist": cells(0.0)}
          for k, metric in enumerate(("bbox", "bev", "3d"))}
    counts = {cls: {"easy": objects, "moderate": objects, "hard": objects} for cls in ("Car", "Pedestrian", "Cyclist")}
    return APRecord.model_validate({"ap": ap, "num_frames": 5, "num_objects": counts})


def hand_summary() -> list[Any]:
    """original, UPD and RAR (no AP: every labelled object moved out of view)."""
    return [SimpleNamespace(label="original", operator="original", ap=ap_record((80, 60, 40), (50, 40, 30))),
            SimpleNamespace(label="uniform_point_deletion@3", operator="uniform_point_deletion",
                            ap=ap_record((70, 60, 10), (50, 20, 12))),
            SimpleNamespace(label="rotate_z@3", operator="rotate_z", ap=None)]


def test_options_are_checked() -> None:
    script = load_script()
    for bad in (["--frames", "0"], ["--severity", "6"], ["--workers", "0"], ["--operators", "no_such_operator"]):
        with pytest.raises(SystemExit):
            script.parse_args(bad)
    args = script.parse_args(["--operators", "thesis", "UNA", "fog"])
    # the thesis's eight by their registered names, in its order; UNA again adds nothing; fog after them
    assert args.operators == ["uniform_noise_addition", "uniform_point_deletion", "gaussian_noise_addition",
                              "random_region_noise_addition", "random_region_point_deletion", "rotate_z",
                              "intensity_scaling", "region_intensity_scaling", "fog"]
    from lidarfuzz.operators.registry import available

    every = script.parse_args([]).operators  # every registered operator (lidarfuzz operators), the thesis's first
    assert len(every) == len(set(every)) and set(every) == set(available())
    assert every[:9] == [*args.operators[:8], "beam_missing"]
    assert [script.thesis_label(n) for n in ("rotate_z", "fog")] == ["RAR", "fog"]


def test_rows_and_table_from_a_hand_made_summary() -> None:
    script = load_script()
    rows = script.class_rows(hand_summary(), "Car")
    assert [r.label for r in rows] == ["original", "UPD", "RAR"]
    # UPD − original: bbox 70 − 80 = −10, BEV 60 − 60 = 0, 3D 10 − 40 = −30 (−30/40 = −75 %)
    assert rows[1].ap == {"bbox": 70.0, "bev": 60.0, "3d": 10.0}
    assert rows[1].delta == {"bbox": -10.0, "bev": 0.0, "3d": -30.0}
    assert rows[2].ap == {"bbox": None, "bev": None, "3d": None} and rows[2].delta["3d"] is None
    assert rows[0].objects == 20 and rows[2].objects is None
    table = script.table_markdown(rows).splitlines()
    assert table[2] == "| original | — | 80.0 |  | 60.0 |  | 40.0 |  |  | 20 |"
    assert table[3] == "| UPD | `uniform_point_deletion` | 70.0 | -10.0 | 60.0 | +0.0 | 10.0 | -30.0 | -75 % | 20 |"
    assert table[4] == "| RAR | `rotate_z` | — | — | — | — | — | — | — | — |"


def test_the_thesis_conclusions_against_rows() -> None:
    script = load_script()
    subtasks = hand_summary()
    by_class = {cls: script.class_rows(subtasks, cls) for cls in ("Car", "Cyclist", "Pedestrian")}
    # Car 3D: UPD −30 (RAR has none); Pedestrian 3D: UPD 12 − 30 = −18, −18/30 = −60 %
    assert [r.label for r in script.lowered(by_class["Car"])] == ["UPD"]
    assert script.mean_change(by_class["Car"]) == -30.0 and script.mean_change(by_class["Pedestrian"]) == -18.0
    assert script.mean_change(by_class["Cyclist"]) == 0.0  # 20 objects, AP 0 before and after
    text = script.thesis_checks(by_class)
    # more than 5 points: UPD's −30 (one of the thesis's four); mean changes −30/40 = −75 %, −18/30 = −60 %
    assert "by more than 5 points by 1 of 2 operators: UPD (-30.0) of those four, and none |" in text
    assert "mean change over the operators: Car -30.0 (-75 %), Pedestrian -18.0 (-60 %), Cyclist +0.0 |" in text
    assert "Pedestrian 3D AP 30.0 → 12.0 (-60 %)" in text
    # with no object of a class in the original frames its AP says nothing
    none = [SimpleNamespace(label="original", operator="original", ap=ap_record((1, 1, 1), (1, 1, 1), objects=0))]
    assert script.mean_change(script.class_rows(none, "Car")) is None


def test_split_view_links_only_the_split(tmp_path: Path) -> None:
    script = load_script()
    root = tmp_path / "kitti"
    for sub, suffix in (("velodyne", ".bin"), ("label_2", ".txt"), ("calib", ".txt")):
        (root / sub).mkdir(parents=True)
        for frame in ("000000", "000001", "000002"):
            (root / sub / f"{frame}{suffix}").write_text(frame)
    (root / "ImageSets").mkdir()
    (root / "ImageSets" / "val.txt").write_text("000001\n000002\n")
    (root / "meta.json").write_text("{}")
    view = script.split_view(root, "val", tmp_path / "view")
    assert sorted(p.name for p in (view / "velodyne").iterdir()) == ["000001.bin", "000002.bin"]
    assert (view / "calib" / "000002.txt").read_text() == "000002"
    assert (view / "meta.json").is_symlink() and not (view / "ImageSets").exists()
    assert script.split_view(root, "val", tmp_path / "view") == view  # reused
    with pytest.raises(SystemExit, match=r"test\.txt does not exist"):
        script.split_view(root, "test", tmp_path / "other")


@pytest.mark.slow
def test_two_frames_with_the_thesis_operators(tmp_path: Path) -> None:
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.store import Store

    script = load_script()
    out = tmp_path / "docs" / "exp2.md"
    by_class = script.main(["--frames", "2", "--operators", "thesis", "--out", str(out),
                            "--workspace", str(tmp_path / "ws")])
    text = out.read_text()
    assert "Regenerate: `python experiments/thesis_exp2.py --frames 2 --operators thesis" in text
    for number, cls in (("6-1", "Car"), ("6-2", "Cyclist"), ("6-3", "Pedestrian")):
        image = tmp_path / "docs" / "images" / f"exp2_fig{number}.png"
        assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"## Figure {number}: {cls}" in text and f"(images/exp2_fig{number}.png)" in text
        rows = by_class[cls]
        assert [r.label for r in rows] == ["original", "UNA", "UPD", "NNA", "RRNA", "RRPD", "RAR", "UIM", "RIM"]
        # operators that change only points (all but RAR) leave the labels, so the counted objects, alone
        assert {r.objects for r in rows if r.label != "RAR"} == {rows[0].objects}
    # the changes agree with the engine's own ΔAP table (summarise's delta_ap, R40)
    summary = summarise(Store(tmp_path / "ws"), 1)
    assert summary.task.frames == 2
    engine = {(d.operator, d.metric, d.cls): d.delta for d in summary.delta_ap if d.difficulty == "moderate"}
    for cls, rows in by_class.items():
        for row in rows[1:]:
            for metric, delta in row.delta.items():
                assert delta == pytest.approx(engine[(row.operator, metric, cls)])
