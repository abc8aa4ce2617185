"""Code-coverage criteria and the search settings that choose them (lidarfuzz.search.code)."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from lidarfuzz.search.algorithms import SearchConfig, pack, unpack
from lidarfuzz.search.code import CodeEdges, CodeLayout, CodeNodes, make_code_criteria
from lidarfuzz.structural.python_coverage import RecorderConfig
from lidarfuzz.structural.requirements import Requirement

F = "m:f"
NODES = [Requirement(F, "node", line) for line in (2, 3, 5)]
EDGES = [Requirement(F, "edge", -1, 2), Requirement(F, "edge", 2, 3), Requirement(F, "edge", 2, 5)]


def test_layout_orders_requirements_and_maps_both_ways() -> None:
    layout = CodeLayout(frozenset(NODES + EDGES))
    # sorted: nodes 2, 3, 5; edges (-1, 2), (2, 3), (2, 5)
    values = layout.values(frozenset({NODES[0], NODES[2], EDGES[2], Requirement("other:g", "node", 9)}))
    assert values["nodes"].tolist() == [[1.0, 0.0, 1.0]]
    assert values["edges"].tolist() == [[0.0, 0.0, 1.0]]
    assert layout.covered(values) == {NODES[0], NODES[2], EDGES[2]}  # the requirement outside the targets is gone


def test_code_criteria_count_new_requirements_and_round_trip() -> None:
    layout = CodeLayout(frozenset(NODES + EDGES))
    nodes, edges = CodeNodes(), CodeEdges()
    first = layout.values(frozenset({NODES[0], NODES[1], EDGES[0], EDGES[1]}))  # the `then` path
    second = layout.values(frozenset({NODES[0], NODES[2], EDGES[0], EDGES[2]}))  # the `else` path
    assert nodes.update(first).tolist() == [True] and edges.update(first).tolist() == [True]
    # the else path adds node 5 and edge 2->5 to what the then path covered
    assert nodes.gain(second).tolist() == [1] and edges.gain(second).tolist() == [1]
    assert (nodes.coverage(), edges.coverage()) == (2 / 3, 2 / 3)
    twin = CodeEdges()
    twin.load_state_dict(unpack(pack(edges.state_dict())))
    assert twin.gain(first).tolist() == [0] and twin.gain(second).tolist() == [1]
    assert twin.covered() == 2 and twin.layers == ["edges"]


def test_make_code_criteria_refuses_values_and_unknown_names() -> None:
    assert [c.name for c in make_code_criteria(["code_nodes", "CODE_EDGES"])] == ["code_nodes", "code_edges"]
    with pytest.raises(ValueError, match="code criteria take no value"):
        make_code_criteria(["code_edges:2"])
    with pytest.raises(ValueError, match="no code criterion"):
        make_code_criteria(["code_lines"])


def test_search_config_code_guide() -> None:
    config = SearchConfig.model_validate({"guide": "code", "targets": "lidarfuzz.suts.classic, pkg.mod:f"})
    assert (config.guide, config.criteria, config.code) == ("code_edges", ("code_nodes", "code_edges"), True)
    assert config.targets == ("lidarfuzz.suts.classic", "pkg.mod:f")
    assert not SearchConfig().code  # the neuron criteria stay the default
    for values, message in (({"guide": "code"}, "targets: code criteria need"),
                            ({"criteria": ["code_nodes", "nc"], "guide": "nc", "targets": ["m"]}, "cannot be mixed"),
                            ({"targets": ["m"]}, "targets: only code criteria"),
                            ({"criteria": ["code_nodes"], "guide": "code_edges", "targets": ["m"]}, "guide")):
        with pytest.raises(ValidationError, match=message):
            SearchConfig.model_validate(values)


def test_recorder_config_builds_the_layout_of_real_code() -> None:
    from lidarfuzz.structural.requirements import union

    recorder = RecorderConfig(("lidarfuzz.structural.requirements:union",)).build()
    layout = CodeLayout(recorder.requirements())
    _, covered = recorder.record(union, [1], [2])
    row = layout.values(covered)
    # union by hand: blocks `out = set()`, `for part in covered`, `out.update(part)`, `return`; edges
    # entry->out, out->for, for->update, update->for, for->return, return->exit: two parts take them all
    assert row["nodes"].shape == (1, 4) and row["edges"].shape == (1, 6)
    assert row["nodes"].all() and row["edges"].all()
    _, none = recorder.record(union)
    assert layout.values(none)["edges"].sum() == 4  # no part: for->update and update->for are not taken
