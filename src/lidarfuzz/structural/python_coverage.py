"""All-nodes and all-edges of Python code: control-flow graphs from coverage.py, measured per call.

**The graph of a function.** coverage.py's parser gives the *arcs* of a file: pairs of
executable lines ``(a, b)`` such that b can run right after a, with a function's exit written
as the negative of its code object's first line (the first decorator's line, else the ``def``
line), ``(last, -first)``. For one function, its lines are its statements (nested functions'
bodies are theirs, not its) and its arcs are those between them plus its exits; the entry
arc ``(-first, first statement)``, which coverage.py measures but does not list, is added.

A **node** is a basic block: a maximal chain of lines in which each line has exactly one
successor and that successor exactly one predecessor. A line starts a block (is a *leader*)
when it is the function's first statement, when it has no or several predecessors, when its
one predecessor has several successors, or when it starts an ``except`` clause. A node is
named by its first line.

An **edge** is an arc from a block's last line to another block's first line (or to the exit),
named by the two blocks' first lines; the entry edge goes from ``-first`` to the first block.
coverage.py lists no arc into an ``except`` clause except from a ``raise`` (an exception can
leave any line of the ``try`` body, or a function it calls), so each clause also gets one
*exception edge* from the block of its ``try`` statement — the Java-CFG convention of an edge
from a try to each of its handlers — found with :mod:`ast`, the one thing coverage.py lacks.

**Measurement.** A call runs under coverage.py with ``branch=True`` (its C tracer). A node is
covered when its first line executed; an edge when the arc from the last line of its source
block to the first line of its target executed; an exception edge when any line entered its
``except`` clause. Executed arcs that are not requirements (comprehensions, lambdas, an
exception leaving a block half-way) count for nothing.

**Per call.** One :class:`coverage.Coverage` per recorder, started and stopped around each
call, and a dynamic context per call (``switch_context``) whose arcs are then queried. This is
the cheaper of the two ways coverage.py offers (``benchmarks/structural.py`` measures both):
starting and stopping around a call costs little, but clearing the data between calls
(``erase``) costs about 10 ms, so the data is kept and cleared only every few hundred calls.

Example:
    >>> recorder = RecorderConfig(("lidarfuzz.structural.requirements:union",)).build()
    >>> result, covered = recorder.record(union, [1], [2])
    >>> sorted(result), len(covered) > 0, covered <= recorder.requirements()
    ([1, 2], True, True)
"""

from __future__ import annotations

import ast
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from functools import cache, cached_property, partial
from typing import Any, TypeVar

from coverage.control import Coverage

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.structural.requirements import Covered, Requirement, union
from lidarfuzz.structural.targets import SourceFunction, file_reporter, resolve

T = TypeVar("T")
Arc = tuple[int, int]


@dataclass(frozen=True)
class Block:
    """A basic block: its lines in execution order; named by the first (the leader)."""

    lines: tuple[int, ...]

    @property
    def leader(self) -> int:
        return self.lines[0]

    @property
    def last(self) -> int:
        return self.lines[-1]


@dataclass(frozen=True)
class FunctionGraph:
    """The control-flow graph of one function.

    Attributes:
        function: ``module:qualname``.
        filename: Its source file.
        first: Its code object's first line; ``-first`` is the entry (as an edge's source) and
            the exit (as an edge's target).
        blocks: Its basic blocks in source order.
        edges: ``(source leader or -first, target leader or -first)``, sorted.
        handlers: ``{except clause's first line: leader of its try statement's block}``.
        last_line: The definition's last line (with ``first``, the span of its source).
    """

    function: str
    filename: str
    first: int
    blocks: tuple[Block, ...]
    edges: tuple[Arc, ...]
    handlers: dict[int, int] = field(default_factory=dict, compare=False, hash=False)
    last_line: int = 0

    @property
    def block_of(self) -> dict[int, Block]:
        """Each line's block."""
        return {line: block for block in self.blocks for line in block.lines}

    def nodes(self) -> Covered:
        return frozenset(Requirement(self.function, "node", b.leader) for b in self.blocks)

    def edge_requirements(self) -> Covered:
        return frozenset(Requirement(self.function, "edge", a, b) for a, b in self.edges)

    def requirements(self) -> Covered:
        """Every node and edge: what all-nodes and all-edges ask for."""
        return self.nodes() | self.edge_requirements()

    @cached_property
    def index(self) -> ArcIndex:
        """Which executed line or arc covers which requirement (built once; measurement only looks up)."""
        index = ArcIndex()
        requirement = partial(Requirement, self.function)
        index.nodes.update({b.leader: requirement("node", b.leader) for b in self.blocks})
        last_of = {b.leader: b.last for b in self.blocks}
        for a, b in self.edges:
            # the entry edge is the arc (-first, first line); any other edge the arc from its source's last line
            index.edges[(last_of.get(a, a), b)] = requirement("edge", a, b)
        index.handlers.update({h: requirement("edge", source, h) for h, source in self.handlers.items()})
        return index

    def covered(self, arcs: Iterable[Arc]) -> Covered:
        """The requirements that executed ``arcs`` (coverage.py's, translated to first lines) cover."""
        return self.index.covered(arcs)


@dataclass
class ArcIndex:
    """Executed lines and arcs → requirements, for one function or every function of a file.

    Attributes:
        nodes: A block's first line → its node.
        edges: The arc from a block's last line (or ``-first``, the entry) → its edge.
        handlers: An except clause's first line → its exception edge (entered from any line).
    """

    nodes: dict[int, Requirement] = field(default_factory=dict)
    edges: dict[Arc, Requirement] = field(default_factory=dict)
    handlers: dict[int, Requirement] = field(default_factory=dict)

    def merge(self, other: ArcIndex) -> None:
        self.nodes.update(other.nodes)
        self.edges.update(other.edges)
        self.handlers.update(other.handlers)

    def covered(self, arcs: Iterable[Arc]) -> Covered:
        """The requirements ``arcs`` cover (the rule in the module docstring)."""
        nodes, edges, handlers = self.nodes, self.edges, self.handlers
        out: set[Requirement] = set()
        for arc in arcs:
            a, b = arc
            if a in nodes:
                out.add(nodes[a])
            if b in nodes:
                out.add(nodes[b])
            edge = edges.get(arc) or handlers.get(b)
            if edge is not None:
                out.add(edge)
        return frozenset(out)


@cache
def _file_arcs(filename: str) -> frozenset[Arc]:
    return frozenset(file_reporter(filename).arcs())


@cache
def _file_tree(filename: str) -> ast.Module:
    return ast.parse(file_reporter(filename).source(), filename)


def _definition(filename: str, start: int) -> ast.FunctionDef | ast.AsyncFunctionDef:
    for node in ast.walk(_file_tree(filename)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.lineno == start:
            return node
    raise LidarfuzzError(f"{filename}:{start}: no function definition on this line")


def _own_nodes(node: ast.AST) -> Iterator[ast.AST]:
    """The nodes of a function's body, without descending into nested functions, lambdas or classes."""
    for child in ast.iter_child_nodes(node):
        if not isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda | ast.ClassDef):
            yield child
            yield from _own_nodes(child)


def _try_clauses(definition: ast.FunctionDef | ast.AsyncFunctionDef) -> list[tuple[int, int, int]]:
    """``(try statement's line, its body's first line, except clause's line)`` of every try in the function."""
    out = []
    for node in _own_nodes(definition):
        if isinstance(node, ast.Try | ast.TryStar):
            out += [(node.lineno, node.body[0].lineno, handler.lineno) for handler in node.handlers]
    return out


def function_graph(function: SourceFunction) -> FunctionGraph:
    """The control-flow graph of one function (the rule is in the module docstring)."""
    definition = _definition(function.filename, function.start)
    first = min([definition.lineno, *(d.lineno for d in definition.decorator_list)])
    end = definition.end_lineno or definition.lineno
    lines = function.statements
    if not lines:
        return FunctionGraph(function.name, function.filename, first, (), (), last_line=end)
    parser = file_reporter(function.filename).parser
    entry = min(lines)
    arcs = {(a, b) for a, b in _file_arcs(function.filename) if a in lines and (b in lines or b == -first)}
    arcs.add((-first, entry))
    successors: dict[int, set[int]] = defaultdict(set)
    predecessors: dict[int, set[int]] = defaultdict(set)
    for a, b in arcs:
        successors[a].add(b)
        predecessors[b].add(a)
    clauses = []
    for try_line, body_line, handler_line in _try_clauses(definition):
        # the try's own line where it is a statement (Python 3.11), else its body's first line
        anchor, handler = parser.first_line(try_line), parser.first_line(handler_line)
        anchor = anchor if anchor in lines else parser.first_line(body_line)
        if anchor in lines and handler in lines:
            clauses.append((anchor, handler))
    leaders = {entry} | {h for _, h in clauses}
    for line in lines:
        before = predecessors[line]
        if len(before) != 1 or len(successors[next(iter(before))]) != 1:
            leaders.add(line)
    blocks = []
    for leader in sorted(leaders):
        chain = [leader]
        while len(successors[chain[-1]]) == 1:
            after = next(iter(successors[chain[-1]]))
            if after < 0 or after in leaders:
                break
            chain.append(after)
        blocks.append(Block(tuple(chain)))
    block_of = {line: block for block in blocks for line in block.lines}
    edges = {(-first, entry)} | {(b.leader, after) for b in blocks for after in successors[b.last]}
    handlers = {h: block_of[t].leader for t, h in clauses}
    edges |= {(source, h) for h, source in handlers.items()}
    return FunctionGraph(function.name, function.filename, first, tuple(blocks), tuple(sorted(edges)), handlers,
                         end)


@dataclass(frozen=True)
class CodeModel:
    """The graphs of every function of some targets, and the mapping of measured arcs onto them."""

    graphs: tuple[FunctionGraph, ...]

    @classmethod
    def of(cls, targets: Iterable[str]) -> CodeModel:
        """The model of targets such as ``pkg.module`` or ``pkg.module:Class.method``."""
        return cls(tuple(function_graph(f) for f in resolve(tuple(targets))))

    @property
    def files(self) -> tuple[str, ...]:
        return tuple(sorted({g.filename for g in self.graphs}))

    def graph(self, function: str) -> FunctionGraph:
        """The graph of ``module:qualname``."""
        for graph in self.graphs:
            if graph.function == function:
                return graph
        raise LidarfuzzError(f"function '{function}' is not among the covered targets")

    def requirements(self) -> Covered:
        """All nodes and edges of the targets (``nT`` and ``eT``)."""
        return union(*(g.requirements() for g in self.graphs))

    @cached_property
    def _indexes(self) -> dict[str, ArcIndex]:
        out: dict[str, ArcIndex] = {}
        for graph in self.graphs:
            out.setdefault(graph.filename, ArcIndex()).merge(graph.index)
        return out

    def covered(self, arcs_by_file: dict[str, set[Arc]]) -> Covered:
        """What executed arcs per file (translated to first lines) cover."""
        return union(*(index.covered(arcs_by_file.get(f, ())) for f, index in self._indexes.items()))


def requirements_of(targets: Iterable[str]) -> Covered:
    """The static requirements of targets: every node and edge of every function in them."""
    return CodeModel.of(targets).requirements()


class CoverageRecorder:
    """Runs callables under coverage.py and returns the requirements each call covered.

    Args:
        targets: What to cover (``pkg.module``, ``pkg.module:Class``, ...).
        erase_every: Calls between clearing coverage.py's data (bounds its memory).
    """

    def __init__(self, targets: Iterable[str], *, erase_every: int = 256) -> None:
        self.model = CodeModel.of(targets)
        self.erase_every = erase_every
        self._reporters = {f: file_reporter(f) for f in self.model.files}
        self._coverage = Coverage(branch=True, data_file=None, config_file=False, include=list(self.model.files))
        self._coverage.set_option("run:disable_warnings", ["no-data-collected", "module-not-measured"])
        self._calls = 0
        self._context = ""
        self.last: Covered = frozenset()

    def requirements(self) -> Covered:
        """Every node and edge of the targets."""
        return self.model.requirements()

    def record(self, function: Callable[..., T], *args: Any, **kwargs: Any) -> tuple[T, Covered]:
        """``function(*args, **kwargs)`` under coverage: its result and the requirements it covered.

        When it raises, the exception propagates and :attr:`last` holds what it covered.
        """
        self.begin()
        try:
            result = function(*args, **kwargs)
        finally:
            self.end()
        return result, self.last

    def begin(self) -> None:
        """Start measuring a unit of work (one call, one request of a worker); :meth:`end` closes it."""
        if self._calls and self._calls % self.erase_every == 0:
            self._coverage.erase()
        self._context = f"call-{self._calls}"
        self._calls += 1
        self._coverage.start()
        self._coverage.switch_context(self._context)

    def end(self) -> Covered:
        """Stop measuring the unit :meth:`begin` opened: what it covered (also in :attr:`last`)."""
        self._coverage.stop()
        self.last = self._collect(self._context)
        return self.last

    def _collect(self, context: str) -> Covered:
        data = self._coverage.get_data()
        data.set_query_context(context)
        arcs = {f: reporter.translate_arcs(data.arcs(f) or ()) for f, reporter in self._reporters.items()}
        return self.model.covered(arcs)


@dataclass(frozen=True)
class RecorderConfig:
    """What a worker process needs to build its own :class:`CoverageRecorder` (picklable).

    Attributes:
        targets: What to cover, as target strings.
        erase_every: See :class:`CoverageRecorder`.
    """

    targets: tuple[str, ...]
    erase_every: int = 256

    def build(self) -> CoverageRecorder:
        """A recorder in this process (targets resolved here)."""
        return CoverageRecorder(self.targets, erase_every=self.erase_every)


__all__ = ["Block", "CodeModel", "CoverageRecorder", "FunctionGraph", "RecorderConfig", "function_graph",
           "requirements_of"]
