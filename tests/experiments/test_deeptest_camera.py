"""experiments/deeptest_camera.py: the statistics behind Tables 5, 6, 9 and Figure 5 against hand-worked
values, the page's sections, and one command end to end on a tiny rendered world (slow)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def load_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("deeptest_camera", ROOT / "experiments" / "deeptest_camera.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["deeptest_camera"] = module
    spec.loader.exec_module(module)
    return module


def test_cohens_d_of_two_tiny_samples() -> None:
    script = load_script()
    # means 2 and 4, sample variances 1 and 1: pooled 1, d = (2 - 4) / 1
    assert script.cohens_d([1.0, 2, 3], [3.0, 4, 5]) == -2.0
    # a: mean 1, variance ((0-1)² + (2-1)²) / 1 = 2; b: mean 2, variance (1 + 1 + 4) / 2 = 3;
    # pooled (1·2 + 2·3) / (2 + 3 - 2) = 8/3; d = (1 - 2) / sqrt(8/3) = -0.61237
    assert script.cohens_d([0.0, 2], [1.0, 1, 4]) == pytest.approx(-1 / math.sqrt(8 / 3))
    assert math.isnan(script.cohens_d([1.0, 1], [1.0, 1]))  # no spread: undefined
    assert math.isnan(script.cohens_d([1.0], [2.0]))  # two values: no variance to pool


def test_effect_size_words_follow_cohen() -> None:
    script = load_script()
    words = [script.effect_words(d) for d in (0.0, 0.19, -0.2, 0.49, 0.5, -0.79, 0.8, 3.0)]
    assert words == ["negligible", "negligible", "small", "small", "medium", "medium", "large", "large"]
    assert script.effect_words(float("nan")) == "n/a"


def test_coverage_increase_is_the_union_over_the_seed() -> None:
    script = load_script()
    seed = np.array([True, False, False, False])
    # the seed activates neuron 0 (N_O = 1); with both images neurons 0, 1, 2 (N_T = 3): (3 - 1) / 1 = 2
    assert script.coverage_increase(seed, [np.array([False, True, False, False]),
                                           np.array([False, True, True, False])]) == 2.0
    assert script.coverage_increase(seed, [seed.copy()]) == 0.0
    assert script.coverage_increase(np.array([True, True, False, False]), [np.array([False, False, True, True])]) == 1.0
    assert math.isnan(script.coverage_increase(np.zeros(4, bool), [seed]))


def test_improvement_and_p_values() -> None:
    script = load_script()
    assert script.improvement(0.2, 0.15) == pytest.approx(0.25)  # (0.2 - 0.15) / 0.2
    assert script.improvement(0.1, 0.2) == pytest.approx(-1.0)
    assert script.p_text(0.0005) == "0.0005 ***"
    assert script.p_text(0.004) == "0.004 **"
    assert script.p_text(0.03) == "0.03 *"
    assert script.p_text(0.2) == "0.2"
    assert script.p_text(float("nan")) == "—"
    assert script.p_text(0.0) == "< 1e-300 ***"


def test_rq1_on_four_images() -> None:
    script = load_script()
    angles = np.array([0.1, 0.2, -0.1, -0.2])
    nc = np.array([0.5, 0.6, 0.3, 0.4])
    r = script.rq1_rows(angles, nc)
    # ranks of θ 3, 4, 2, 1 and of NC 3, 4, 1, 2: Σd² = 2, ρ = 1 - 6·2 / (4·15) = 0.8
    assert r["rho"] == pytest.approx(0.8)
    # left NC 0.5, 0.6 (mean 0.55), right 0.3, 0.4 (0.35); variances 0.005: d = 0.2 / sqrt(0.005) = 2.828
    assert (r["left"], r["right"]) == (2, 2)
    assert r["d"] == pytest.approx(0.2 / math.sqrt(0.005))
    # every left value above every right one: U = 4 of 4, exact two-sided p = 2 · 1/C(4, 2) = 1/3
    assert r["p_w"] == pytest.approx(1 / 3)


def test_sections_are_replaced_in_place_and_notes_kept(tmp_path: Path) -> None:
    script = load_script()
    page = tmp_path / "page.md"
    script.write_section("fig5", "F5", "first", "cmd", 1.0, page=page)
    script.write_section("table5", "T5", "one", "cmd", 1.0, page=page)
    page.write_text(page.read_text() + "\n## Notes by hand\n\nlooked at it.\n")
    script.write_section("fig5", "F5", "second", "cmd", 2.0, page=page)
    text = page.read_text()
    assert "first" not in text and "second" in text and "one" in text
    assert text.index("## T5") < text.index("## F5")  # the commands' order, whatever the order of writing
    assert text.count("<!-- fig5 -->") == 1 and text.endswith("looked at it.\n")


def test_review_sample_spreads_over_models_and_transformations() -> None:
    script = load_script()
    pool = [("epoch", "image_blur", 1, i) for i in range(10)] + [("dave2", "image_fog", 1, 0),
                                                                  ("epoch", "image_rain", 3, 4)]
    chosen = script.review_sample(pool, 3, seed=0)
    assert {(c[0], c[1]) for c in chosen} == {("epoch", "image_blur"), ("dave2", "image_fog"),
                                              ("epoch", "image_rain")}
    assert script.review_sample(pool, 3, seed=0) == chosen  # seeded
    assert len(script.review_sample(pool, 50, seed=1)) == len(pool)


@pytest.mark.slow
@pytest.mark.torch
def test_table5_and_table6_end_to_end_on_a_tiny_world(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("torch")
    script = load_script()
    monkeypatch.setattr(script, "DATA", tmp_path / "data")
    monkeypatch.setattr(script, "PAGE", tmp_path / "page.md")
    monkeypatch.setattr(script, "IMAGES", tmp_path / "images")
    # a 6-frame world at 64×48 (rendered in a few seconds) and the smallest network, epoch
    common = ["--frames", "6", "--seed", "5", "--image-size", "64x48", "--models", "epoch", "--seeds", "2"]
    assert script.main(["table5", *common]) == 0
    assert script.main(["table6", *common, "--budget", "10"]) == 0
    text = (tmp_path / "page.md").read_text()
    assert "<!-- table5 -->" in text and "<!-- table6 -->" in text
    row = next(line for line in text.splitlines() if line.startswith("| epoch | 6 |"))  # Table 5: 6 images
    assert len(row.split("|")) == 9  # model, images, ρ, left / right, NC, Wilcoxon, d
    table6 = next(line for line in text.splitlines() if line.startswith("| epoch | 160 |"))  # epoch: 160 neurons
    base, cumulative = (int(cell.split("(")[0].replace(",", "")) for cell in table6.split("|")[3:5])
    assert 0 < base <= cumulative <= 160
    # the guided search is deterministic for a seed: the same table again
    assert script.main(["table6", *common, "--budget", "10"]) == 0
    assert table6 in (tmp_path / "page.md").read_text().splitlines()
