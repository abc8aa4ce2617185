"""The camera task kind end to end, against values worked out by hand.

Four uniform grey images with values r = 40, 100, 160, 220 and labels −0.35, −0.10, 0.10, 0.40; the
system ``MeanRed`` answers θ = r / 255 − 0.5. Brightness with β fixed adds β to every pixel
(saturating at 255), so every figure of DeepTest's Eq. 2 and Eq. 3 follows from arithmetic on these
numbers, done below in plain Python (:func:`expected`), not by the code under test.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from lidarfuzz.campaign.runner import run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.store import Store
from lidarfuzz.store.models import Finding, FrameResult

VALUES = (40, 100, 160, 220)
LABELS = (-0.35, -0.10, 0.10, 0.40)
SYSTEM = "tests.campaign.camera_systems:MeanRed"


@pytest.fixture
def images(tmp_path: Path) -> Path:
    folder = tmp_path / "drive"
    folder.mkdir()
    with (folder / "labels.csv").open("w", newline="") as handle:
        out = csv.writer(handle)
        out.writerow(["image", "steering"])
        for k, (value, label) in enumerate(zip(VALUES, LABELS, strict=True)):
            cv2.imwrite(str(folder / f"f{k}.png"), np.full((24, 32, 3), value, np.uint8))
            out.writerow([f"f{k}.png", repr(label)])
    return folder / "labels.csv"


def expected(beta: float) -> tuple[float, list[float], float]:
    """MSE_orig, the squared errors (label − θ_t)² under brightness β, and MSE_t — by hand."""
    original = [v / 255 - 0.5 for v in VALUES]
    mse_orig = sum((label - o) ** 2 for label, o in zip(LABELS, original, strict=True)) / len(VALUES)
    transformed = [min(v + beta, 255) / 255 - 0.5 for v in VALUES]
    errors = [(label - t) ** 2 for label, t in zip(LABELS, transformed, strict=True)]
    return mse_orig, errors, sum(errors) / len(errors)


def run(tmp_path: Path, dataset: Path, epsilon: float, budget: int = 0, sut: str = SYSTEM) -> tuple[Store, int]:
    store = Store(tmp_path / "ws")
    spec = parse_campaign({
        "kind": "camera", "dataset": str(dataset), "sut": sut, "seed": 3,
        "operators": [{"name": "image_brightness", "config": {"bias_range": [50, 50]}},
                      {"name": "image_brightness", "config": {"bias_range": [5, 5]}}],
        "relations": [{"name": "deeptest_steering", "config": {"lambda": 5, "epsilon": epsilon}}],
        "search": {"budget": budget}})
    task_id = create_task(store, spec)
    run_task(store, task_id)
    return store, task_id


def test_mse_orig_eq2_and_eq3_as_worked_out_by_hand(tmp_path: Path, images: Path) -> None:
    store, task_id = run(tmp_path, images, epsilon=0.03)
    mse_orig, errors50, mse50 = expected(50)
    _, errors5, mse5 = expected(5)
    task = get_task(store, task_id)
    original = next(s for s in task.subtasks if s.name == "original")
    assert original.state["mse_orig"] == pytest.approx(mse_orig)  # ≈ 0.000563
    by_config = {s.operator["config"]["bias_range"][0]: s for s in task.subtasks if s.name == "image_brightness"}
    strong, mild = by_config[50.0].results.deeptest, by_config[5.0].results.deeptest
    assert strong.mse == pytest.approx(mse50) and mild.mse == pytest.approx(mse5)
    limit = 5 * mse_orig
    assert strong.violated == sum(e > limit for e in errors50) == 4
    assert mild.violated == sum(e > limit for e in errors5) == 0
    assert not strong.kept  # |0.0341 − 0.00056| = 0.0336 > ε = 0.03
    assert mild.kept
    with store.session() as s:
        # the violations' transformation was dropped by Eq. 3: no finding
        assert s.query(Finding).filter(Finding.task_id == task_id).count() == 0
        stored = sorted(s.query(FrameResult.relations).filter(FrameResult.subtask_id == by_config[50.0].id).all(),
                        key=lambda row: row[0][0].stats["label"])
        assert [row[0][0].stats["squared_errors"][0] for row in stored] == pytest.approx(
            [e for _, e in sorted(zip(LABELS, errors50, strict=True))])


def test_a_kept_transformation_s_violations_are_findings(tmp_path: Path, images: Path) -> None:
    store, task_id = run(tmp_path, images, epsilon=0.05)  # 0.0336 ≤ 0.05: kept
    _, errors50, _ = expected(50)
    with store.session() as s:
        findings = s.query(Finding).filter(Finding.task_id == task_id).all()
        assert len(findings) == 4
        assert sorted(f.magnitude for f in findings) == pytest.approx(sorted(errors50))
        assert {f.kind for f in findings} == {"deeptest_steering"}
        assert all(f.replay.operator["name"] == "image_brightness" for f in findings)


def test_a_frame_without_a_label_is_not_judged_and_mse_orig_skips_it(tmp_path: Path) -> None:
    root = tmp_path / "kitti"  # KITTI's layout: image_2/ and a steering.csv without frame 000003's row
    (root / "image_2").mkdir(parents=True)
    lines = ["frame_id,steering,speed"]
    for k, (value, label) in enumerate(zip(VALUES, LABELS, strict=True)):
        cv2.imwrite(str(root / "image_2" / f"{k:06d}.png"), np.full((24, 32, 3), value, np.uint8))
        if k < 3:
            lines.append(f"{k:06d},{label!r},5.0")
    (root / "steering.csv").write_text("\n".join(lines) + "\n")
    store, task_id = run(tmp_path, root, epsilon=0.03)
    task = get_task(store, task_id)
    original = next(s for s in task.subtasks if s.name == "original")
    labelled = [(label, v / 255 - 0.5) for label, v in zip(LABELS[:3], VALUES[:3], strict=True)]
    assert original.state["labelled"] == 3
    assert original.state["mse_orig"] == pytest.approx(sum((a - b) ** 2 for a, b in labelled) / 3)
    with store.session() as s:
        unjudged = [r for (r,) in s.query(FrameResult.relations).filter(FrameResult.frame_id == "000003").all() if r]
        assert unjudged and all(not outcome.applicable for outcomes in unjudged for outcome in outcomes)


@pytest.mark.torch
def test_the_guided_search_is_deterministic_for_a_seed(tmp_path: Path, images: Path) -> None:
    pytest.importorskip("torch")
    runs = []
    for k in range(2):
        store, _ = run(tmp_path / str(k), images, epsilon=0.03, budget=8,
                             sut="tests.campaign.camera_systems:TinyNet")
        with store.session() as s:
            rows = s.query(FrameResult.frame_id, FrameResult.trial, FrameResult.params, FrameResult.output).all()
        runs.append(sorted((f, t, str(p), math.floor(o["steering"] * 1e9) if o else None) for f, t, p, o in rows))
    assert runs[0] == runs[1]
    assert sum(1 for _, trial, params, _ in runs[0] if "sequence" in params) == 8  # the budget's tests, as chains


def test_a_finding_replays_from_its_stored_params(tmp_path: Path, images: Path) -> None:
    from lidarfuzz.campaign.camera import replay_camera

    store, task_id = run(tmp_path, images, epsilon=0.05)
    _, errors50, _ = expected(50)
    with store.session() as s:
        finding = s.query(Finding).filter(Finding.task_id == task_id).order_by(Finding.id).first()
        assert finding is not None
        finding_id = finding.id
    result = replay_camera(store, finding_id)
    assert result.reproduced and result.deterministic and result.same_system
    k = LABELS.index(result.label)  # which of the four images (labels read back exactly from the CSV)
    assert result.now[1] == pytest.approx(min(VALUES[k] + 50, 255) / 255 - 0.5)
    assert result.outcomes_now[0].stats["squared_errors"][0] == pytest.approx(errors50[k])


def test_the_report_shows_deeptest_s_figures_and_pictures_not_ap(tmp_path: Path, images: Path) -> None:
    from lidarfuzz.report import write_report

    store, task_id = run(tmp_path, images, epsilon=0.05)
    files = write_report(store, task_id, tmp_path / "report", images=2)
    html = files.html.read_text()
    assert 'id="deeptest"' in html and 'id="ap"' not in html and 'id="robustness"' not in html
    assert html.count('<img src="data:image/png;base64,') == 2  # two findings drawn as image pairs
    assert "3 of 4 findings" in " ".join(html.split())  # at most three per kind and transformation
    mse_orig, _, _ = expected(50)
    assert f"MSE_orig) is {mse_orig:.4g}" in html
