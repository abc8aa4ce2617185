"""What a tester looks at: coverage tables, annotated source, control-flow graphs, two runs compared.

Every view reads requirement sets (:class:`~lidarfuzz.structural.requirements.Requirement`) and,
for the source and graph of a Python function, its :class:`FunctionGraph`; each returns a value
or an HTML/SVG fragment the report and the web app embed (classes ``lf-cov-*``, styled by
:data:`STYLE`). Neves et al.'s tool shows the same four: coverage of classes and methods, the
source with lines not executed, the control-flow graph with nodes and edges not executed, and
two logs compared with their aggregated coverage.

Example:
    >>> from lidarfuzz.structural.requirements import Requirement
    >>> total = {Requirement("m:f", "node", 2), Requirement("m:f", "node", 4), Requirement("m:f", "edge", 2, 4)}
    >>> [(r.level, r.name, r.nodes) for r in coverage_table(total, {Requirement("m:f", "node", 2)})]
    [('module', 'm', (1, 2)), ('function', 'm:f', (1, 2))]
"""

from __future__ import annotations

import html
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import graphviz

from lidarfuzz.structural.python_coverage import FunctionGraph
from lidarfuzz.structural.requirements import Requirement, of_kind

Level = Literal["module", "class", "function"]

COVERED, MISSED = "#2e7d32", "#c62828"
COVERED_FILL, MISSED_FILL = "#e8f5e9", "#ffebee"

STYLE = f"""
.lf-cov-table td.num {{ text-align: right; font-variant-numeric: tabular-nums; }}
.lf-cov-table tr.module td {{ font-weight: bold; }}
.lf-cov-source {{ font-family: monospace; white-space: pre; border-collapse: collapse; }}
.lf-cov-source td.no {{ color: #888; text-align: right; padding-right: .8em; }}
.lf-cov-source tr.run {{ background: {COVERED_FILL}; }}
.lf-cov-source tr.missed {{ background: {MISSED_FILL}; }}
.lf-cov-source tr.partial {{ background: #fff8e1; }}
.lf-cov-source td.note {{ color: {MISSED}; font-style: italic; padding-left: 1em; }}
"""


def _module_and_name(function: str) -> tuple[str, str]:
    module, _, qualname = function.rpartition(":")
    return module, qualname


def _count(covered: frozenset[Requirement], total: frozenset[Requirement], kind: Literal["node", "edge"],
           functions: set[str]) -> tuple[int, int]:
    every = {r for r in of_kind(total, kind) if r.function in functions}
    return len(every & covered), len(every)


@dataclass(frozen=True)
class CoverageRow:
    """One line of a coverage table: ``(covered, total)`` nodes and edges of a module, class or function."""

    level: Level
    name: str
    nodes: tuple[int, int]
    edges: tuple[int, int]

    @property
    def label(self) -> str:
        """The module's name, or the class's or function's qualified name in its module."""
        return self.name if self.level == "module" else _module_and_name(self.name)[1]

    @property
    def depth(self) -> int:
        """Indentation: 0 for a module, 1 + the dots of a class or function's qualified name."""
        return 0 if self.level == "module" else 1 + self.label.count(".")

    @staticmethod
    def _percent(pair: tuple[int, int]) -> float | None:
        return 100.0 * pair[0] / pair[1] if pair[1] else None

    @property
    def node_percent(self) -> float | None:
        """COV_Nodes in %, ``None`` without nodes."""
        return self._percent(self.nodes)

    @property
    def edge_percent(self) -> float | None:
        """COV_Edges in %, ``None`` without edges (a compiled function without branches)."""
        return self._percent(self.edges)


def coverage_table(total: Iterable[Requirement], covered: Iterable[Requirement]) -> list[CoverageRow]:
    """Per module, then per class and function in it (by name): nodes and edges covered of total.

    A class is a dotted prefix of a qualified name that is not itself a function (``A`` of
    ``A.m``); its row sums its methods. A nested function has its own row and is not in its
    outer function's. Covered requirements outside ``total`` do not count.
    """
    every, hit = frozenset(total), frozenset(covered)
    by_module: dict[str, set[str]] = {}
    for function in {r.function for r in every}:
        by_module.setdefault(_module_and_name(function)[0], set()).add(function)
    rows = []
    for module in sorted(by_module):
        functions = by_module[module]
        rows.append(CoverageRow("module", module, _count(hit, every, "node", functions),
                                _count(hit, every, "edge", functions)))
        names = {_module_and_name(f)[1] for f in functions}
        seen_classes: set[str] = set()
        for function in sorted(functions, key=lambda f: _module_and_name(f)[1]):
            parts = _module_and_name(function)[1].split(".")
            for end in range(1, len(parts)):
                prefix = ".".join(parts[:end])
                if prefix in names or prefix in seen_classes:
                    continue
                seen_classes.add(prefix)
                members = {f for f in functions if _module_and_name(f)[1].startswith(prefix + ".")}
                rows.append(CoverageRow("class", f"{module}:{prefix}", _count(hit, every, "node", members),
                                        _count(hit, every, "edge", members)))
            rows.append(CoverageRow("function", function, _count(hit, every, "node", {function}),
                                    _count(hit, every, "edge", {function})))
    return rows


def _cell(pair: tuple[int, int], percent: float | None) -> str:
    shown = "–" if percent is None else f"{percent:.1f} %"
    return f'<td class="num">{pair[0]}/{pair[1]}</td><td class="num">{shown}</td>'


def table_html(rows: list[CoverageRow]) -> str:
    """The coverage table as an HTML ``<table>``."""
    head = ("<tr><th>module / class / function</th><th>nodes</th><th>all-nodes</th>"
            "<th>edges</th><th>all-edges</th></tr>")
    body = "".join(
        f'<tr class="{row.level}"><td title="{html.escape(row.name)}" style="padding-left: {row.depth}em">'
        f"{html.escape(row.label)}</td>{_cell(row.nodes, row.node_percent)}"
        f"{_cell(row.edges, row.edge_percent)}</tr>"
        for row in rows
    )
    return f'<table class="lf-cov-table"><thead>{head}</thead><tbody>{body}</tbody></table>'


def format_table(rows: list[CoverageRow]) -> str:
    """The coverage table as text (the CLI's)."""
    def cell(pair: tuple[int, int], percent: float | None) -> str:
        return f"{pair[0]:>5}/{pair[1]:<5} {'–' if percent is None else f'{percent:5.1f} %':>7}"

    names = ["  " * r.depth + r.label for r in rows]
    width = max([len(n) for n in names] + [8])
    lines = [f"{'code':<{width}}  {'nodes':^19} {'edges':^19}"]
    lines += [f"{n:<{width}}  {cell(r.nodes, r.node_percent)} {cell(r.edges, r.edge_percent)}"
              for n, r in zip(names, rows, strict=True)]
    return "\n".join(lines)


def _where(line: int) -> str:
    return str(line) if line > 0 else "exit"


def source_html(graph: FunctionGraph, covered: Iterable[Requirement]) -> str:
    """The source of a Python function, each statement line marked.

    ``run``: its block was covered; ``missed``: it was not; ``partial``: it ends a covered block
    some of whose outgoing edges were not taken (the untaken targets are named in a note).
    """
    hit = frozenset(covered)
    source = Path(graph.filename).read_text(encoding="utf-8").splitlines()
    marks: dict[int, tuple[str, str]] = {}
    out_edges: dict[int, list[int]] = {}
    for a, b in graph.edges:
        out_edges.setdefault(a, []).append(b)
    for block in graph.blocks:
        run = Requirement(graph.function, "node", block.leader) in hit
        for line in block.lines:
            marks[line] = ("run" if run else "missed", "")
        untaken = [b for b in out_edges.get(block.leader, [])
                   if Requirement(graph.function, "edge", block.leader, b) not in hit]
        if run and untaken:
            marks[block.last] = ("partial", "not taken: → " + ", ".join(_where(b) for b in untaken))
    return _annotated(source, graph.first, graph.last_line or max(marks, default=graph.first), marks)


def gcov_source_html(source_file: str | Path, function: str, total: Iterable[Requirement],
                     covered: Iterable[Requirement]) -> str:
    """The source of a compiled function (gcov requirements), lines marked as in :func:`source_html`;
    a partial line names its untaken branch outcomes."""
    every, hit = frozenset(r for r in total if r.function == function), frozenset(covered)
    lines = sorted(r.source for r in every if r.kind == "node")
    marks: dict[int, tuple[str, str]] = {}
    for line in lines:
        run = Requirement(function, "node", line) in hit
        untaken = sorted(r.target - 1 for r in every if r.kind == "edge" and r.source == line and r not in hit)
        if run and untaken:
            marks[line] = ("partial", "branch " + ", ".join(map(str, untaken)) + " not taken")
        else:
            marks[line] = ("run" if run else "missed", "")
    source = Path(source_file).read_text(encoding="utf-8", errors="replace").splitlines()
    return _annotated(source, min(lines, default=1), max(lines, default=0), marks)


def _annotated(source: list[str], first: int, last: int, marks: dict[int, tuple[str, str]]) -> str:
    rows = []
    for number in range(first, min(last, len(source)) + 1):
        mark, note = marks.get(number, ("", ""))
        klass = f' class="{mark}"' if mark else ""
        note_cell = f'<td class="note">{html.escape(note)}</td>' if note else "<td></td>"
        rows.append(f'<tr{klass}><td class="no">{number}</td><td>{html.escape(source[number - 1])}</td>'
                    f"{note_cell}</tr>")
    return f'<table class="lf-cov-source">{"".join(rows)}</table>'


def _node_id(line: int) -> str:
    return f"b{line}" if line > 0 else ("entry" if line < 0 else "exit")


def cfg_graph(graph: FunctionGraph, covered: Iterable[Requirement]) -> graphviz.Digraph:
    """The control-flow graph as a Graphviz digraph.

    Blocks are boxes labelled with their lines; the entry and exit are small ovals. Covered
    blocks and edges are green and solid, the rest red and dashed.
    """
    hit = frozenset(covered)
    dot = graphviz.Digraph(name=graph.function, graph_attr={"rankdir": "TB", "fontsize": "10"},
                           node_attr={"fontname": "Helvetica", "fontsize": "10"})
    dot.node("entry", "entry", shape="oval", style="filled", fillcolor="#eeeeee")
    dot.node("exit", "exit", shape="oval", style="filled", fillcolor="#eeeeee")
    for block in graph.blocks:
        run = Requirement(graph.function, "node", block.leader) in hit
        label = str(block.leader) if len(block.lines) == 1 else f"{block.leader}–{block.last}"
        dot.node(_node_id(block.leader), label, shape="box", style="filled" if run else "filled,dashed",
                 color=COVERED if run else MISSED, fillcolor=COVERED_FILL if run else MISSED_FILL,
                 tooltip=f"lines {', '.join(map(str, block.lines))}: {'executed' if run else 'not executed'}")
    for a, b in graph.edges:
        run = Requirement(graph.function, "edge", a, b) in hit
        target = "exit" if b < 0 else _node_id(b)
        dot.edge(_node_id(a), target, color=COVERED if run else MISSED, style="solid" if run else "dashed")
    return dot


def cfg_svg(graph: FunctionGraph, covered: Iterable[Requirement]) -> str:
    """:func:`cfg_graph` rendered by Graphviz's ``dot`` to an SVG fragment (no XML prolog)."""
    svg = cfg_graph(graph, covered).pipe(format="svg", encoding="utf-8")
    return svg[svg.index("<svg"):]


@dataclass(frozen=True)
class ComparedRow:
    """Two coverage sets side by side for one function (or ``total``): counts of one kind of requirement.

    Attributes:
        name: The function, or ``total``.
        kind: ``node`` or ``edge``.
        total: How many requirements (``nT`` or ``eT``).
        a, b, both, new_in_b: How many A, B, A∪B cover, and B covers that A does not.
    """

    name: str
    kind: Literal["node", "edge"]
    total: int
    a: int
    b: int
    both: int
    new_in_b: int

    def percent(self, count: int) -> float | None:
        return 100.0 * count / self.total if self.total else None


def compare(total: Iterable[Requirement], a: Iterable[Requirement], b: Iterable[Requirement]) -> list[ComparedRow]:
    """A, B, A∪B and new in B per function and kind, then the totals.

    ``new_in_b / total`` is Neves et al.'s aggregated coverage COV_Ag of a base log A and a
    generated log B.
    """
    every, left, right = frozenset(total), frozenset(a), frozenset(b)
    functions = sorted({r.function for r in every})
    rows = []
    for name, members in [*((f, {f}) for f in functions), ("total", set(functions))]:
        for kind in ("node", "edge"):
            req = {r for r in of_kind(every, kind) if r.function in members}
            rows.append(ComparedRow(name, kind, len(req), len(req & left), len(req & right),
                                    len(req & (left | right)), len(req & (right - left))))
    return rows


def comparison_html(rows: list[ComparedRow], names: tuple[str, str] = ("A", "B")) -> str:
    """The comparison as an HTML ``<table>`` (counts and % of total)."""
    first, second = (html.escape(n) for n in names)
    head = (f"<tr><th>function</th><th>criterion</th><th>total</th><th>{first}</th><th>{second}</th>"
            f"<th>{first} ∪ {second}</th><th>new in {second}</th></tr>")

    def cell(row: ComparedRow, count: int) -> str:
        percent = row.percent(count)
        return f'<td class="num">{count} ({"–" if percent is None else f"{percent:.1f} %"})</td>'

    body = "".join(
        f'<tr class="{"module" if row.name == "total" else "function"}"><td>{html.escape(row.name)}</td>'
        f'<td>all-{row.kind}s</td><td class="num">{row.total}</td>{cell(row, row.a)}{cell(row, row.b)}'
        f"{cell(row, row.both)}{cell(row, row.new_in_b)}</tr>"
        for row in rows
    )
    return f'<table class="lf-cov-table lf-cov-compare"><thead>{head}</thead><tbody>{body}</tbody></table>'


__all__ = ["STYLE", "ComparedRow", "CoverageRow", "cfg_graph", "cfg_svg", "compare", "comparison_html",
           "coverage_table", "format_table", "gcov_source_html", "source_html", "table_html"]
