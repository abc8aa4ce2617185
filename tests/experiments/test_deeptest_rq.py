"""experiments/deeptest_rq.py: the pure helpers behind Figures 5 and 6 (the experiments themselves run
the learned detector for minutes and are not tests)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def load_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("deeptest_rq", ROOT / "experiments" / "deeptest_rq.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["deeptest_rq"] = module
    spec.loader.exec_module(module)
    return module


def test_coverage_gain_is_the_union_over_the_seed() -> None:
    script = load_script()
    seed = np.array([True, False, False, False])
    mutants = [np.array([False, True, False, False]), np.array([False, True, True, False])]
    # the seed activates neuron 0 (N_O = 1); with both mutants neurons 0, 1, 2 (N_T = 3): (3 - 1) / 1 = 2
    assert script.coverage_gain(seed, mutants) == (1, 3, 2.0)
    # a mutant that activates only what the seed did adds nothing; no mutant at all neither
    assert script.coverage_gain(seed, [seed.copy()]) == (1, 1, 0.0)
    assert script.coverage_gain(seed, []) == (1, 1, 0.0)
    n_o, n_t, increase = script.coverage_gain(np.zeros(4, bool), mutants)  # mutants: neurons 1, 2; N_O = 0
    assert (n_o, n_t) == (0, 2) and math.isnan(increase)


def test_matched_pairs_rank_biserial() -> None:
    script = load_script()
    # differences x - y = 1, 3, -3: |d| ranks 1, 2.5, 2.5 (the tie shares ranks 2 and 3);
    # R+ = 1 + 2.5 = 3.5, R- = 2.5, r = (3.5 - 2.5) / 6 = 1/6
    assert script.matched_pairs_rank_biserial(np.array([1.0, 4, 0]), np.array([0.0, 1, 3])) == 1 / 6
    # a zero difference is dropped as the Wilcoxon test drops it: 2 and 1 left, both positive, r = +1
    assert script.matched_pairs_rank_biserial(np.array([5.0, 2, 3]), np.array([5.0, 0, 2])) == 1.0
    assert script.matched_pairs_rank_biserial(np.array([0.0, 1]), np.array([2.0, 3])) == -1.0
    assert math.isnan(script.matched_pairs_rank_biserial(np.array([1.0]), np.array([1.0])))


def test_image_mse_is_the_mean_of_the_objects_squared_errors() -> None:
    script = load_script()
    stats = {"squared_errors": [0.25, 1.0, 4.0], "source_squared_errors": []}
    assert script.image_mse(stats, "squared_errors") == 1.75  # (0.25 + 1 + 4) / 3
    assert math.isnan(script.image_mse(stats, "source_squared_errors"))  # the original found no object
