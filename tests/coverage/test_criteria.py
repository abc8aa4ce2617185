"""Neuron-coverage criteria on hand-written neuron values (numpy only; every expectation is worked out by hand)."""

from __future__ import annotations

import json
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from lidarfuzz.coverage import (
    CRITERIA,
    CoverageError,
    KMultisectionCoverage,
    NeuronBoundaryCoverage,
    NeuronCoverage,
    StrongActivationCoverage,
    TopKCoverage,
    TopKPatterns,
    make_criteria,
    make_criterion,
)


def values(**layers: list[list[float]]) -> dict[str, np.ndarray]:
    return {name: np.asarray(rows, dtype=np.float64) for name, rows in layers.items()}


def fake_profile(**layers: tuple[list[float], list[float], list[float]]) -> SimpleNamespace:
    """Anything with ``.layers = {name: {"min", "max", "std"}}`` will do for the profiled criteria."""
    def arr(x: list[float]) -> np.ndarray:
        return np.asarray(x, dtype=np.float64)

    return SimpleNamespace(layers={name: {"min": arr(lo), "max": arr(hi), "std": arr(sd)}
                                   for name, (lo, hi, sd) in layers.items()})


# -- NC -----------------------------------------------------------------------------------------


def test_nc_threshold_is_strict() -> None:
    nc = NeuronCoverage(threshold=0.25)
    new = nc.update(values(a=[[0, 1, 2, 3, 4]]))
    # min 0, max 4 → scaled [0, .25, .5, .75, 1]; strictly above .25: neurons 2, 3, 4 → 3 / 5 = 0.6
    assert new.tolist() == [True]
    assert nc.covered_items.tolist() == [False, False, True, True, True]
    assert (nc.covered(), nc.total) == (3, 5)
    assert nc.coverage() == pytest.approx(0.6)


def test_nc_default_threshold_is_0_2() -> None:
    nc = NeuronCoverage()
    nc.update(values(a=[[0, 1, 2, 3, 4]]))
    # scaled [0, .25, .5, .75, 1]; .25 > .2 too → neurons 1..4 → 4 / 5 = 0.8
    assert nc.threshold == 0.2
    assert nc.coverage() == pytest.approx(0.8)


def test_nc_constant_layer_activates_nothing() -> None:
    nc = NeuronCoverage(threshold=0.0)
    new = nc.update(values(a=[[5, 5, 5]]))
    # max − min = 0 → every neuron scales to 0, and 0 > 0 is false, even with t = 0 → 0 / 3
    assert new.tolist() == [False]
    assert (nc.covered(), nc.total) == (0, 3)
    assert nc.coverage() == 0.0


def test_nc_scales_each_layer_on_its_own() -> None:
    nc = NeuronCoverage(threshold=0.4)
    nc.update(values(a=[[0, 10]], b=[[100, 101, 102]]))
    # a: range 0..10 → [0, 1] → [F, T];  b: range 100..102 → [0, .5, 1] → [F, T, T]  → 3 / 5
    # (one range 0..102 over both layers would give a: [0, .098] → F, F; b: all ≈ .98 → T, T, T)
    assert nc.covered_items.tolist() == [False, True, False, True, True]
    assert nc.coverage() == pytest.approx(3 / 5)


def test_nc_scales_each_input_on_its_own() -> None:
    nc = NeuronCoverage(threshold=0.4)
    new = nc.update(values(a=[[0, 1, 2], [20, 0, 10]]))
    # input 0: range 0..2 → [0, .5, 1] → {1, 2};  input 1: range 0..20 → [1, 0, .5] → {0, 2}
    # union {0, 1, 2} → 3 / 3; input 1 adds neuron 0 → new for both
    # (one range 0..20 over the batch would leave input 0 at [0, .05, .1] → nothing, and 2 / 3 in all)
    assert new.tolist() == [True, True]
    assert nc.coverage() == 1.0


def test_nc_fixes_its_layers_at_the_first_update() -> None:
    nc = NeuronCoverage(threshold=0.5)
    nc.update(values(a=[[0, 1]]))
    # a later batch may carry more layers (ignored: still 2 neurons) but not fewer
    nc.update(values(a=[[1, 0]], b=[[0, 1, 2]]))
    assert nc.layers == ["a"]
    assert (nc.covered(), nc.total) == (2, 2)
    with pytest.raises(CoverageError, match="lack"):
        nc.update(values(b=[[0, 1, 2]]))


# -- update vs gain -----------------------------------------------------------------------------


def test_update_commits_in_order() -> None:
    nc = NeuronCoverage(threshold=0.25)
    new = nc.update(values(a=[[0, 1, 2, 3, 4], [4, 3, 2, 1, 0], [0, 1, 2, 3, 4]]))
    # input 0 → {2, 3, 4} new; input 1 scales to [1, .75, .5, .25, 0] → {0, 1, 2}: 0 and 1 new;
    # input 2 repeats input 0 → nothing new.  Covered {0, 1, 2, 3, 4} = 5 / 5
    assert new.tolist() == [True, True, False]
    assert nc.coverage() == 1.0
    # the same input again, in a later batch → not new
    assert nc.update(values(a=[[0, 1, 2, 3, 4]])).tolist() == [False]


def test_second_identical_input_in_a_batch_is_not_new() -> None:
    nc = NeuronCoverage(threshold=0.25)
    assert nc.update(values(a=[[0, 1, 2, 3, 4], [0, 1, 2, 3, 4]])).tolist() == [True, False]


def test_gain_judges_each_input_alone_and_keeps_state() -> None:
    nc = NeuronCoverage(threshold=0.25)
    batch = values(a=[[0, 1, 2, 3, 4], [0, 1, 2, 3, 4]])
    # each alone would add {2, 3, 4} = 3 (the second is not discounted by the first)
    assert nc.gain(batch).tolist() == [3, 3]
    assert nc.covered() == 0
    assert nc.gain(batch).tolist() == [3, 3]  # still nothing committed
    nc.update(values(a=[[0, 1, 2, 3, 4]]))  # covered {2, 3, 4}
    # [0..4] adds nothing; [4, 3, 2, 1, 0] → {0, 1, 2}, of which 0 and 1 are new → 2
    assert nc.gain(values(a=[[0, 1, 2, 3, 4], [4, 3, 2, 1, 0]])).tolist() == [0, 2]
    assert nc.covered_items.tolist() == [False, False, True, True, True]


# -- KMNC ---------------------------------------------------------------------------------------

# neuron 0 and 1: [0, 8] in k = 4 sections of width 2; neuron 2: low = high = 5
KMNC_PROFILE = fake_profile(a=([0, 0, 5], [8, 8, 5], [1, 1, 0]))


def test_kmnc_sections() -> None:
    kmnc = KMultisectionCoverage(KMNC_PROFILE, k=4)
    kmnc.update(values(a=[[3, 8, 5]]))
    # neuron 0: floor(3 / 8 · 4) = floor(1.5) = 1;  neuron 1: v = high → floor(4) = 4 → last section 3;
    # neuron 2 (low = high): v = low → section 0.   Items are neuron · k + section: 0·4+1, 1·4+3, 2·4+0
    assert np.flatnonzero(kmnc.covered_items).tolist() == [1, 7, 8]
    # denominator k · neurons = 4 · 3 = 12 → 3 / 12
    assert (kmnc.covered(), kmnc.total) == (3, 12)
    assert kmnc.coverage() == pytest.approx(0.25)


def test_kmnc_section_edges() -> None:
    kmnc = KMultisectionCoverage(KMNC_PROFILE, k=4)
    kmnc.update(values(a=[[0, 2, 5], [6, 7.999, 5]]))
    # input 0: neuron 0 v = low → section 0 (index 0); neuron 1 v = 2 → floor(1.0) = 1 (index 5); neuron 2 → 8
    # input 1: neuron 0 v = 6 → floor(3.0) = 3 (index 3); neuron 1 v = 7.999 → floor(3.9995) = 3 (index 7)
    assert np.flatnonzero(kmnc.covered_items).tolist() == [0, 3, 5, 7, 8]
    assert kmnc.coverage() == pytest.approx(5 / 12)


def test_kmnc_values_outside_the_range_cover_nothing() -> None:
    kmnc = KMultisectionCoverage(KMNC_PROFILE, k=4)
    batch = values(a=[[-1, 9, 5.5], [-0.001, 8.001, 4.999]])
    # below low, above high, and off the single point 5 → no section
    assert kmnc.gain(batch).tolist() == [0, 0]
    assert kmnc.update(batch).tolist() == [False, False]
    assert (kmnc.covered(), kmnc.total) == (0, 12)


def test_kmnc_degenerate_neuron_counts_all_k_sections() -> None:
    kmnc = KMultisectionCoverage(fake_profile(a=([5], [5], [0])), k=4)
    kmnc.update(values(a=[[5], [4], [6], [5]]))
    # only v = 5 hits, in section 0; sections 1..3 are unreachable but counted → 1 / 4
    assert kmnc.covered_items.tolist() == [True, False, False, False]
    assert kmnc.coverage() == pytest.approx(0.25)


def test_kmnc_k_and_layers() -> None:
    profile = fake_profile(a=([0], [10], [1]), b=([-1, 0], [1, 1], [1, 1]))
    kmnc = KMultisectionCoverage(profile)
    kmnc.update(values(a=[[3.5]], b=[[0, 0.25]]))
    # default k = 10 → 10 · 3 = 30 items; a: floor(3.5 / 10 · 10) = 3;
    # b0: floor((0 + 1) / 2 · 10) = 5; b1: floor(.25 · 10) = 2 → indices 3, 10 + 5, 20 + 2
    assert kmnc.k == 10
    assert np.flatnonzero(kmnc.covered_items).tolist() == [3, 15, 22]
    assert kmnc.coverage() == pytest.approx(3 / 30)


def test_kmnc_errors() -> None:
    with pytest.raises(CoverageError, match="k >= 1"):
        KMultisectionCoverage(KMNC_PROFILE, k=0)
    with pytest.raises(CoverageError, match="profile"):
        KMultisectionCoverage(None)
    with pytest.raises(CoverageError, match="no layer 'zz'"):
        KMultisectionCoverage(KMNC_PROFILE, k=4).update(values(zz=[[1.0]]))


# -- NBC / SNAC ---------------------------------------------------------------------------------

# two neurons, both [0, 10] with std 2
CORNER_PROFILE = fake_profile(a=([0, 0], [10, 10], [2, 2]))


def test_nbc_without_sigma() -> None:
    nbc = NeuronBoundaryCoverage(CORNER_PROFILE)
    assert nbc.sigma == 0.0
    # v = high and v = low are inside (strict comparisons) → nothing
    assert nbc.update(values(a=[[10, 0]])).tolist() == [False]
    # 10.5 > 10: upper corner of neuron 0; -0.5 < 0: lower corner of neuron 1 → 2 of 2 · 2 = 0.5
    assert nbc.update(values(a=[[10.5, -0.5]])).tolist() == [True]
    assert (nbc.covered(), nbc.total) == (2, 4)
    assert nbc.coverage() == pytest.approx(0.5)
    # the other two corners: neuron 0 below, neuron 1 above → 4 / 4
    assert nbc.gain(values(a=[[-0.1, 10.1]])).tolist() == [2]
    nbc.update(values(a=[[-0.1, 10.1]]))
    assert nbc.coverage() == 1.0


def test_nbc_with_sigma() -> None:
    nbc = NeuronBoundaryCoverage(CORNER_PROFILE, sigma=1.5)
    # corners at 10 + 1.5 · 2 = 13 and 0 − 1.5 · 2 = −3
    # between high and high + σ·std (and between low − σ·std and low), or on the margin itself → nothing
    assert nbc.gain(values(a=[[12, -2], [13, -3], [10.5, -0.5]])).tolist() == [0, 0, 0]
    assert nbc.update(values(a=[[13.5, -3.5]])).tolist() == [True]
    # upper of neuron 0 and lower of neuron 1 → 2 / 4
    assert nbc.coverage() == pytest.approx(0.5)


def test_snac_without_and_with_sigma() -> None:
    snac = StrongActivationCoverage(CORNER_PROFILE)
    # 10.5 > 10 → upper corner of neuron 0; -50 is a lower corner, which SNAC ignores → 1 / 2
    assert snac.update(values(a=[[10.5, -50]])).tolist() == [True]
    assert snac.covered_items.tolist() == [True, False]
    assert (snac.covered(), snac.total) == (1, 2)

    snac = StrongActivationCoverage(CORNER_PROFILE, sigma=1.5)
    # upper corner at 13: 12 is between high and high + σ·std → not covered; 20 → covered → 1 / 2
    assert snac.update(values(a=[[12, 20]])).tolist() == [True]
    assert snac.covered_items.tolist() == [False, True]
    assert snac.coverage() == pytest.approx(0.5)


# -- TKNC / TKNP --------------------------------------------------------------------------------


def test_tknc_top_k() -> None:
    tknc = TopKCoverage()  # k = 2
    tknc.update(values(a=[[1, 3, 2, 0]]))
    # two largest: 3 (index 1) and 2 (index 2) → 2 / 4
    assert tknc.k == 2
    assert tknc.covered_items.tolist() == [False, True, True, False]
    assert tknc.coverage() == pytest.approx(0.5)


def test_tknc_ties_go_to_the_lower_index() -> None:
    tknc = TopKCoverage(k=2)
    tknc.update(values(a=[[1, 1, 1, 1]]))
    # all equal → indices 0 and 1
    assert tknc.covered_items.tolist() == [True, True, False, False]
    tknc.update(values(a=[[0, 5, 5, 5]]))
    # three tie at 5 → indices 1 and 2; covered {0, 1, 2} → 3 / 4
    assert tknc.covered_items.tolist() == [True, True, True, False]
    assert tknc.coverage() == pytest.approx(0.75)


def test_tknc_per_layer_and_k_above_units() -> None:
    tknc = TopKCoverage(k=1)
    tknc.update(values(a=[[1, 3, 2]], b=[[7, 9]]))
    # a → index 1; b → index 1 → items [F, T, F | F, T] → 2 / 5
    assert tknc.covered_items.tolist() == [False, True, False, False, True]
    tknc = TopKCoverage(k=5)
    tknc.update(values(a=[[1, 3, 2]]))
    # k = 5 > 3 units → all three → 3 / 3
    assert tknc.coverage() == 1.0


TKNP_BATCH = values(
    # top-1 per layer:   a  b
    a=[[3, 1, 2],      # 0, 1
       [5, 0, 0],      # 0, 1  (same pattern as input 0)
       [0, 9, 0],      # 1, 0
       [9, 0, 0]],     # 0, 0  (same top of a as input 0, another of b → another pattern)
    b=[[0, 1],
       [4, 9],
       [9, 0],
       [9, 0]],
)


def test_tknp_counts_distinct_patterns() -> None:
    tknp = TopKPatterns(k=1)
    assert tknp.is_count
    new = tknp.update(TKNP_BATCH)
    # patterns (0, 1), (0, 1), (1, 0), (0, 0) → new, repeat, new, new → 3 distinct
    assert new.tolist() == [True, False, True, True]
    assert tknp.coverage() == 3.0
    assert tknp.covered() == tknp.total == 3
    # the same batch again → nothing new, still 3
    assert tknp.update(TKNP_BATCH).tolist() == [False] * 4
    assert tknp.coverage() == 3.0


def test_tknp_top_k_sets_and_ties() -> None:
    tknp = TopKPatterns()  # k = 2
    new = tknp.update(values(a=[[1, 1, 1], [2, 2, 0], [0, 3, 3]]))
    # top-2 sets: ties to the lower index → {0, 1}; {0, 1} again; {1, 2} → 2 patterns
    assert new.tolist() == [True, False, True]
    assert tknp.coverage() == 2.0


def test_tknp_gain_keeps_state() -> None:
    tknp = TopKPatterns(k=1)
    # each input alone would be new, the repeat (input 1) included
    assert tknp.gain(TKNP_BATCH).tolist() == [1, 1, 1, 1]
    assert tknp.coverage() == 0.0
    tknp.update(TKNP_BATCH)
    assert tknp.gain(TKNP_BATCH).tolist() == [0, 0, 0, 0]
    # a fourth pattern: a → 2, b → 1
    assert tknp.gain(values(a=[[0, 0, 1]], b=[[0, 1]])).tolist() == [1]
    assert tknp.coverage() == 3.0


# -- state, copy, reset -------------------------------------------------------------------------


def test_state_dict_round_trip() -> None:
    nc = NeuronCoverage(threshold=0.25)
    nc.update(values(a=[[0, 1, 2, 3, 4]]))  # covered {2, 3, 4}
    state = nc.state_dict()
    assert state["layers"] == ["a"]

    again = NeuronCoverage(threshold=0.25)
    again.load_state_dict(state)
    assert (again.covered(), again.total) == (3, 5)
    assert again.covered_items.tolist() == [False, False, True, True, True]
    assert again.update(values(a=[[0, 1, 2, 3, 4]])).tolist() == [False]
    # the loaded state is a copy: changing the dict afterwards does not reach the criterion
    state["covered"][0] = True
    assert again.covered() == 3
    # lists (JSON) load as well
    plain = NeuronCoverage(threshold=0.25)
    plain.load_state_dict({"layers": ["a"], "covered": [True, False, False, False, False]})
    # [4, 3, 2, 1, 0] → {0, 1, 2}: 1 and 2 new → gain 2
    assert plain.gain(values(a=[[4, 3, 2, 1, 0]])).tolist() == [2]


def test_state_dict_of_a_fresh_criterion() -> None:
    kmnc = KMultisectionCoverage(KMNC_PROFILE, k=4)
    kmnc.load_state_dict(KMultisectionCoverage(KMNC_PROFILE, k=4).state_dict())
    assert (kmnc.layers, kmnc.covered_items, kmnc.total, kmnc.coverage()) == (None, None, 0, 0.0)


def test_tknp_state_dict_round_trip() -> None:
    tknp = TopKPatterns(k=1)
    tknp.update(TKNP_BATCH)
    state = json.loads(json.dumps(tknp.state_dict()))  # plain JSON
    assert state["layers"] == ["a", "b"]
    assert len(state["patterns"]) == 3

    again = TopKPatterns(k=1)
    again.load_state_dict(state)
    assert again.coverage() == 3.0
    assert again.layers == ["a", "b"]
    assert again.update(TKNP_BATCH).tolist() == [False] * 4
    assert again.update(values(a=[[0, 0, 1]], b=[[0, 1]])).tolist() == [True]
    assert again.coverage() == 4.0


def test_copy_and_reset() -> None:
    nc = NeuronCoverage(threshold=0.25)
    nc.update(values(a=[[0, 1, 2, 3, 4]]))
    twin = nc.copy()
    twin.update(values(a=[[4, 3, 2, 1, 0]]))
    # the copy reaches 5 / 5, the original stays at 3 / 5
    assert (twin.covered(), nc.covered()) == (5, 3)
    nc.reset()
    assert (nc.layers, nc.total, nc.coverage()) == (None, 0, 0.0)
    tknp = TopKPatterns(k=1)
    tknp.update(TKNP_BATCH)
    tknp.reset()
    assert (tknp.layers, tknp.coverage()) == (None, 0.0)


# -- make_criterion -----------------------------------------------------------------------------


def test_make_criterion_specs() -> None:
    nc = make_criterion("nc:0.3")
    assert isinstance(nc, NeuronCoverage) and nc.threshold == 0.3
    kmnc = make_criterion("kmnc:4", KMNC_PROFILE)
    assert isinstance(kmnc, KMultisectionCoverage) and kmnc.k == 4 and kmnc.profile is KMNC_PROFILE
    nbc = make_criterion("nbc:1.5", CORNER_PROFILE)
    assert isinstance(nbc, NeuronBoundaryCoverage) and nbc.sigma == 1.5
    snac = make_criterion("snac:0.5", CORNER_PROFILE)
    assert isinstance(snac, StrongActivationCoverage) and snac.sigma == 0.5
    tknc = make_criterion("tknc:3")
    assert isinstance(tknc, TopKCoverage) and tknc.k == 3
    tknp = make_criterion("tknp:3")
    assert isinstance(tknp, TopKPatterns) and tknp.k == 3


def test_make_criterion_defaults_and_case() -> None:
    assert make_criterion("nc").threshold == 0.2
    assert make_criterion("kmnc", KMNC_PROFILE).k == 10
    assert make_criterion("nbc", CORNER_PROFILE).sigma == 0.0
    assert make_criterion("snac", CORNER_PROFILE).sigma == 0.0
    assert make_criterion("tknc").k == 2
    assert make_criterion("tknp").k == 2
    upper = make_criterion("  NC:0.3 ")
    assert isinstance(upper, NeuronCoverage) and upper.threshold == 0.3
    assert [c.name for c in make_criteria(["nc", "tknc:1", "kmnc:2"], KMNC_PROFILE)] == ["nc", "tknc", "kmnc"]
    assert sorted(CRITERIA) == ["kmnc", "nbc", "nc", "snac", "tknc", "tknp"]


def test_make_criterion_errors() -> None:
    with pytest.raises(CoverageError, match="unknown coverage criterion 'foo'"):
        make_criterion("foo:1")
    with pytest.raises(CoverageError, match="not a number"):
        make_criterion("nc:abc")
    for spec in ("kmnc:4", "kmnc", "nbc:1.5", "snac"):
        with pytest.raises(CoverageError, match="profile"):
            make_criterion(spec)
    # a CoverageError is a ValueError too
    with pytest.raises(ValueError):
        make_criterion("kmnc:0", KMNC_PROFILE)


# -- vectorised update over several layers, validation, non-finite values ---------------------


def test_update_in_order_across_layers_and_criteria() -> None:
    tknc = TopKCoverage(k=1)
    batch = values(a=[[1, 0], [1, 0], [0, 1]], b=[[0, 0, 1], [1, 0, 0], [0, 0, 1]])
    # tops: input 0 → a0, b2 (both new); input 1 → a0 (seen), b0 (new); input 2 → a1 (new), b2 (seen)
    assert tknc.gain(batch).tolist() == [2, 2, 2]  # alone, against the empty state
    assert tknc.update(batch).tolist() == [True, True, True]
    # items a0 a1 | b0 b1 b2 → all but b1 → 4 / 5
    assert tknc.covered_items.tolist() == [True, True, True, False, True]
    assert tknc.update(values(a=[[0, 1]], b=[[0, 2, 1]])).tolist() == [True]  # b1 at last
    assert tknc.coverage() == 1.0


def test_layers_must_agree_on_inputs_and_keep_their_widths() -> None:
    with pytest.raises(CoverageError, match=r"layer 'b' has 1 rows but layer 'a' has 2.*reducer"):
        NeuronCoverage().update(values(a=[[0, 1], [1, 0]], b=[[0, 1]]))
    with pytest.raises(CoverageError, match=r"\(inputs, units\)"):
        NeuronCoverage().update({"a": np.zeros(3)})
    with pytest.raises(CoverageError, match="no neuron values"):
        NeuronCoverage().update({})
    nc = NeuronCoverage()
    nc.update(values(a=[[0, 1]]))
    with pytest.raises(CoverageError, match="layer 'a' had 2 neurons, now 3"):
        nc.gain(values(a=[[0, 1, 2]]))
    tknp = TopKPatterns(k=1)
    tknp.update(values(a=[[0, 1]]))
    with pytest.raises(CoverageError, match="widths changed"):
        tknp.update(values(a=[[0, 1, 2]]))


def test_profiled_criteria_check_the_profile_width() -> None:
    # KMNC_PROFILE's layer "a" has 3 neurons; 2 values per input do not fit it
    with pytest.raises(CoverageError, match="'a' has 2 neurons but its profile 3"):
        KMultisectionCoverage(KMNC_PROFILE, k=4).update(values(a=[[1, 2]]))
    with pytest.raises(CoverageError, match="not a NeuronProfile"):
        NeuronBoundaryCoverage(object())


def test_non_finite_values_cover_nothing() -> None:
    nc = NeuronCoverage(threshold=0.4)
    nc.update(values(a=[[0, np.nan, 10, np.inf]]))
    # NaN and inf left out of min and max: range 0..10 → [0, -, 1, -] → only neuron 2
    assert nc.covered_items.tolist() == [False, False, True, False]
    kmnc = KMultisectionCoverage(KMNC_PROFILE, k=4)
    assert kmnc.gain(values(a=[[np.nan, np.inf, 5]])).tolist() == [1]  # only neuron 2 (v = low = high)
    nbc = NeuronBoundaryCoverage(CORNER_PROFILE)
    assert nbc.gain(values(a=[[np.nan, np.nan]])).tolist() == [0]
    tknc = TopKCoverage(k=1)
    tknc.update(values(a=[[np.nan, -5, -7]]))  # NaN is never the top: -5 (index 1) is
    assert tknc.covered_items.tolist() == [False, True, False]


# -- parameters, states, copies -----------------------------------------------------------------


@pytest.mark.parametrize("spec", ["nc:1.0", "nc:-0.1", "kmnc:2.5", "tknc:0", "tknp:-1", "nbc:-1", "snac:nan"])
def test_bad_parameters_are_refused_naming_the_spec(spec: str) -> None:
    with pytest.raises(CoverageError, match=spec.replace(".", r"\.")):
        make_criterion(spec, CORNER_PROFILE)


def test_make_criteria_options_strings_and_duplicates() -> None:
    nc, kmnc, tknc = make_criteria(["nc", "kmnc", "tknc:3"], KMNC_PROFILE, nc=0.5, kmnc=4, tknc=1)
    # options fill in specs without a value; an explicit value wins
    assert (nc.threshold, kmnc.k, tknc.k) == (0.5, 4, 3)
    assert [c.name for c in make_criteria("nc:0.1, tknp")] == ["nc", "tknp"]
    with pytest.raises(CoverageError, match="unknown criterion option"):
        make_criteria(["nc"], threshold=0.5)
    with pytest.raises(CoverageError, match="'nc' is asked for twice"):
        make_criteria(["nc:0.1", "nc:0.5"])
    with pytest.raises(CoverageError, match=r"training-set profile.*build_profile"):
        make_criteria(["nc", "snac"])


def test_state_dict_names_its_criterion_and_parameters() -> None:
    nc = NeuronCoverage(threshold=0.25)
    nc.update(values(a=[[0, 1, 2, 3, 4]]))
    state = nc.state_dict()
    assert (state["name"], state["params"], state["sizes"]) == ("nc", {"threshold": 0.25}, [5])
    with pytest.raises(CoverageError, match=r"recorded with \{'threshold': 0.25\}"):
        NeuronCoverage(threshold=0.5).load_state_dict(state)
    with pytest.raises(CoverageError, match="'nc' into 'tknc'"):
        TopKCoverage().load_state_dict(state)
    # an old state without sizes learns them from the next batch, and refuses a batch that does not fit
    old = NeuronCoverage(threshold=0.25)
    old.load_state_dict({"layers": ["a"], "covered": [True, False, False]})
    with pytest.raises(CoverageError, match="3 items but these layers give 5"):
        old.update(values(a=[[0, 1, 2, 3, 4]]))


def test_kmnc_state_and_copy_share_the_profile() -> None:
    kmnc = KMultisectionCoverage(KMNC_PROFILE, k=4)
    kmnc.update(values(a=[[3, 8, 5]]))  # items 1, 7, 8 (see test_kmnc_sections)
    twin = kmnc.copy()
    assert twin.profile is kmnc.profile
    twin.update(values(a=[[0, 0, 5]]))  # adds items 0 and 4
    assert (twin.covered(), kmnc.covered()) == (5, 3)
    again = KMultisectionCoverage(KMNC_PROFILE, k=4)
    again.load_state_dict(json.loads(json.dumps({**kmnc.state_dict(), "covered": kmnc.covered_items.tolist()})))
    assert np.flatnonzero(again.covered_items).tolist() == [1, 7, 8]
    assert again.update(values(a=[[3, 8, 5]])).tolist() == [False]
    tknp = TopKPatterns(k=1)
    tknp.update(TKNP_BATCH)
    copy = tknp.copy()
    copy.update(values(a=[[0, 0, 1]], b=[[0, 1]]))
    assert (copy.coverage(), tknp.coverage()) == (4.0, 3.0)


def test_coverage_imports_without_torch() -> None:
    code = (
        "import sys; sys.modules['torch'] = None\n"
        "import numpy as np, lidarfuzz.coverage as cov\n"
        "assert cov.make_criterion('nc').update({'a': np.array([[0.0, 1.0]])}).tolist() == [True]\n"
        "try:\n"
        "    cov.neuron_values(object(), None)\n"
        "except ImportError as exc:\n"
        "    print(exc)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert "pip install 'lidarfuzz[learned]'" in done.stdout
