"""Test requirements of structural testing and the coverage formulas of Neves et al.

A *requirement* is one thing a criterion asks the tests to execute: a node (basic block) of a
function's control-flow graph for all-nodes, an edge between two of them for all-edges. Every
producer of code coverage (coverage.py for Python, gcov for compiled programs) reports what it
measured as sets of :class:`Requirement`; everything downstream — segments, heuristics,
generated logs, reports — works on those sets alone and never on a tool's own data.

The formulas (Neves, Delamaro & Masiero, Section IV), with ``nT``/``eT`` the nodes and edges
of the code under test and ``NC'``/``NC''`` the requirements logs L' (the base) and L'' (the
generated log) cover::

    COV_Nodes = nC / nT            COV_Edges = eC / eT
    COV_AgNodes = |NC'' − NC'| / nT    (what L'' covers that L' did not)

The paper prints the aggregated form as ``|NC − NC''|``; its text defines it as the
requirements the generated log covers that the base did not, which is what is computed here.

Example:
    >>> a, b = Requirement("m:f", "node", 1), Requirement("m:f", "node", 4)
    >>> e = Requirement("m:f", "edge", 1, 4)
    >>> total = frozenset({a, b, e})
    >>> coverage_ratio(frozenset({a}), total, "node"), coverage_ratio(frozenset({a, e}), total, "edge")
    (0.5, 1.0)
    >>> aggregated(frozenset({a}), frozenset({a, b}), total, "node")
    0.5
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

Kind = Literal["node", "edge"]


@dataclass(frozen=True, order=True)
class Requirement:
    """One node or edge of one function's control-flow graph.

    Attributes:
        function: ``module:Qualified.name`` for Python code, ``file:function`` for compiled code.
        kind: ``node`` (a basic block) or ``edge`` (control passing from one block to another).
        source: A node's first line; an edge's source block's first line (negative: the
            function's entry, as coverage.py writes arcs).
        target: An edge's target block's first line (negative: the function's exit); 0 for a node.
    """

    function: str
    kind: Kind
    source: int
    target: int = 0

    def label(self) -> str:
        """``f:12`` for a node, ``f:12->15`` for an edge (``entry``/``exit`` for negative lines)."""
        def line(n: int, end: str) -> str:
            return str(n) if n > 0 else end

        if self.kind == "node":
            return f"{self.function}:{self.source}"
        return f"{self.function}:{line(self.source, 'entry')}->{line(self.target, 'exit')}"


Covered = frozenset[Requirement]


def of_kind(requirements: Iterable[Requirement], kind: Kind, function: str | None = None) -> Covered:
    """The requirements of one kind (and one function, when given)."""
    return frozenset(r for r in requirements if r.kind == kind and (function is None or r.function == function))


def coverage_ratio(covered: Iterable[Requirement], total: Iterable[Requirement], kind: Kind,
                   function: str | None = None) -> float:
    """COV_Nodes or COV_Edges: covered ÷ total requirements of ``kind`` (of ``function``); 0 with none.

    Requirements covered but not in ``total`` (code outside the chosen targets) do not count.
    """
    every = of_kind(total, kind, function)
    return len(of_kind(covered, kind, function) & every) / len(every) if every else 0.0


def aggregated(base: Iterable[Requirement], generated: Iterable[Requirement], total: Iterable[Requirement],
               kind: Kind, function: str | None = None) -> float:
    """COV_AgNodes or COV_AgEdges: requirements ``generated`` covers that ``base`` did not, ÷ total."""
    every = of_kind(total, kind, function)
    new = (of_kind(generated, kind, function) - of_kind(base, kind, function)) & every
    return len(new) / len(every) if every else 0.0


def union(*covered: Iterable[Requirement]) -> Covered:
    """The requirements any of the runs covered (a log's coverage from its frames' or segments')."""
    out: set[Requirement] = set()
    for part in covered:
        out.update(part)
    return frozenset(out)


__all__ = ["Covered", "Kind", "Requirement", "aggregated", "coverage_ratio", "of_kind", "union"]
