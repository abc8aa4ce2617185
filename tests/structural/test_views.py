"""The structural views: table numbers, annotated source, the control-flow graph's SVG, two runs compared."""

from __future__ import annotations

import re
import shutil
import xml.etree.ElementTree as ET

import pytest

from lidarfuzz.structural.python_coverage import RecorderConfig
from lidarfuzz.structural.requirements import Requirement, aggregated
from lidarfuzz.structural.views import (
    CoverageRow,
    cfg_svg,
    compare,
    comparison_html,
    coverage_table,
    format_table,
    gcov_source_html,
    source_html,
    table_html,
)
from tests.requirements import missing
from tests.structural import sample_code

M = "tests.structural.sample_code"
SVG = "{http://www.w3.org/2000/svg}"


@pytest.fixture(scope="module")
def recorder():
    return RecorderConfig((f"{M}:sign", f"{M}:Rectangle")).build()


def test_table_per_module_class_and_function(recorder):
    _, sign = recorder.record(sample_code.sign, 1)
    _, area = recorder.record(sample_code.Rectangle().area, 1, 2)
    rows = coverage_table(recorder.requirements(), sign | area)
    # by hand (graphs in sample_code.py): sign 4 nodes/6 edges, area 3/5, is_square 1/2.
    # sign(1) covers 22, 23, 26 and entry->22, 22->23, 23->26, 26->exit;
    # area(1, 2) covers 61, 63 and entry->61, 61->63, 63->exit.
    assert rows == [
        CoverageRow("module", M, (5, 8), (7, 13)),
        CoverageRow("class", f"{M}:Rectangle", (2, 4), (3, 7)),
        CoverageRow("function", f"{M}:Rectangle.area", (2, 3), (3, 5)),
        CoverageRow("function", f"{M}:Rectangle.is_square", (0, 1), (0, 2)),
        CoverageRow("function", f"{M}:sign", (3, 4), (4, 6)),
    ]
    assert rows[0].node_percent == 62.5 and rows[4].edge_percent == pytest.approx(200 / 3)
    text = format_table(rows)
    assert re.search(r"^  Rectangle\s+2/4\s+50\.0 %\s+3/7\s+42\.9 %$", text, re.M)
    assert re.search(r"^    Rectangle\.is_square\s+0/1\s+0\.0 %", text, re.M)
    page = table_html(rows)
    assert page.count("<tr") == 6 and '<td class="num">5/8</td><td class="num">62.5 %</td>' in page


def test_a_function_without_edges_shows_a_dash():
    total = {Requirement("f.c:main", "node", 3)}
    row = coverage_table(total, total)[-1]
    assert row.edges == (0, 0) and row.edge_percent is None
    assert "–" in table_html([row])


def test_source_marks_unexecuted_lines_and_untaken_branches(recorder):
    _, covered = recorder.record(sample_code.sign, 1)
    page = source_html(recorder.model.graph(f"{M}:sign"), covered)
    rows = re.findall(r'<tr( class="(\w+)")?><td class="no">(\d+)</td>.*?</tr>', page)
    marks = {int(number): mark for _, mark, number in rows}
    # def line and else: not statements; 22 ran but its edge to 25 was not taken; 25 never ran
    assert marks == {21: "", 22: "partial", 23: "run", 24: "", 25: "missed", 26: "run"}
    assert "not taken: → 25" in page


def test_gcov_source_marks_lines_and_branch_outcomes(tmp_path):
    source = tmp_path / "f.c"
    source.write_text("int f(int x) {\n  if (x) return 1;\n  return 0;\n}\n")
    fn = "f.c:f"
    total = {Requirement(fn, "node", 1), Requirement(fn, "node", 2), Requirement(fn, "node", 3),
             Requirement(fn, "edge", 2, 1), Requirement(fn, "edge", 2, 2)}
    covered = {Requirement(fn, "node", 1), Requirement(fn, "node", 2), Requirement(fn, "edge", 2, 1)}
    page = gcov_source_html(source, fn, total, covered)
    assert re.findall(r'<tr class="(\w+)"><td class="no">(\d)', page) == [("run", "1"), ("partial", "2"),
                                                                         ("missed", "3")]
    assert "branch 1 not taken" in page  # gcov's branch 1 is the edge with target 2


def _svg_parts(svg: str) -> tuple[dict[str, ET.Element], dict[str, ET.Element]]:
    root = ET.fromstring(svg)
    nodes, edges = {}, {}
    for group in root.iter(f"{SVG}g"):
        title = group.find(f"{SVG}title")
        if group.get("class") == "node":
            nodes[title.text] = group
        elif group.get("class") == "edge":
            edges[title.text.replace("->", ">")] = group
    return nodes, edges


def test_cfg_svg_distinguishes_executed_nodes_and_edges(recorder):
    if shutil.which("dot") is None:
        missing("Graphviz's dot not found", "the Debian package graphviz")
    _, covered = recorder.record(sample_code.sign, 1)
    nodes, edges = _svg_parts(cfg_svg(recorder.model.graph(f"{M}:sign"), covered))
    # 4 blocks + entry + exit; the 6 edges of the hand-counted graph
    assert set(nodes) == {"entry", "exit", "b22", "b23", "b25", "b26"}
    assert set(edges) == {"entry>b22", "b22>b23", "b22>b25", "b23>b26", "b25>b26", "b26>exit"}
    for name in ("b22", "b23", "b26"):
        box = nodes[name].find(f".//{SVG}polygon")
        assert box.get("stroke") == "#2e7d32" and box.get("stroke-dasharray") is None
    missed = nodes["b25"].find(f".//{SVG}polygon")
    assert missed.get("stroke") == "#c62828" and missed.get("stroke-dasharray")
    for name, group in edges.items():
        path = group.find(f"{SVG}path")
        taken = name not in ("b22>b25", "b25>b26")
        assert path.get("stroke") == ("#2e7d32" if taken else "#c62828"), name
        assert (path.get("stroke-dasharray") is None) == taken, name


def test_two_runs_side_by_side(recorder):
    _, a = recorder.record(sample_code.sign, 1)
    _, b = recorder.record(sample_code.sign, -1)
    total = {r for r in recorder.requirements() if r.function == f"{M}:sign"}
    rows = compare(total, a, b)
    # by hand: A covers 22, 23, 26; B 22, 25, 26: A∪B all 4, new in B: 25.
    # edges: A entry->22, 22->23, 23->26, 26->exit; B the same with 25: A∪B all 6, new in B 2
    by = {(r.name, r.kind): (r.total, r.a, r.b, r.both, r.new_in_b) for r in rows}
    assert by[(f"{M}:sign", "node")] == (4, 3, 3, 4, 1)
    assert by[(f"{M}:sign", "edge")] == (6, 4, 4, 6, 2)
    assert by[("total", "node")] == by[(f"{M}:sign", "node")]
    assert by[("total", "edge")][4] / 6 == aggregated(a, b, total, "edge")
    page = comparison_html(rows, ("field test", "generated"))
    assert "new in generated" in page and '<td class="num">1 (25.0 %)</td>' in page
