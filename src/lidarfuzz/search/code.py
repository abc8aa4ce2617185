"""Code coverage as the guide of a search: all-nodes and all-edges of any Python system's code.

Neuron coverage needs a ``torch.nn.Module``; code coverage needs only the system's source. A
guided or fuzz search with the criteria ``code_nodes`` and ``code_edges`` measures, around each
call of the system's ``detect``, which nodes (basic blocks) and edges of the target code ran
(:class:`~lidarfuzz.structural.python_coverage.CoverageRecorder`, coverage.py's arcs; the targets
are ``pkg.module``, ``pkg.module:Class`` or ``pkg.module:function``, as in ``lidarfuzz logs``), so
a per-frame system such as the classic pipeline can be searched: a test is accepted when it runs
code no test before it ran, and a bug behind a rarely taken branch is found by reaching the branch.

The two criteria are :class:`~lidarfuzz.coverage.criteria.Criterion` s like the neuron ones, so
the search algorithms, their state, resume and reports stay as they are: each test's coverage is
a 0/1 row over the targets' requirements in a fixed order (sorted), one "layer" per criterion
(``nodes`` and ``edges``). Each test runs on its own under the recorder (no batching), so a test
whose ``detect`` raises is a ``crash`` of that test alone, and the code it reached before raising
still counts (reaching the branch is what the search is after).

The recorder is built from a :class:`~lidarfuzz.structural.python_coverage.RecorderConfig` (a
small picklable value) in whichever process runs the search: ``lidarfuzz run`` in its own, the
web app's workers in theirs.

Example:
    >>> from lidarfuzz.structural.requirements import Requirement
    >>> every = frozenset({Requirement("m:f", "node", 2), Requirement("m:f", "node", 4),
    ...                    Requirement("m:f", "edge", -1, 2)})
    >>> layout = CodeLayout(every)
    >>> values = layout.values(frozenset({Requirement("m:f", "node", 4)}))
    >>> values["nodes"].tolist(), values["edges"].tolist()
    ([[0.0, 1.0]], [[0.0]])
    >>> nodes = CodeNodes()
    >>> nodes.update(values).tolist(), nodes.coverage()
    ([True], 0.5)
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.coverage.criteria import Criterion
from lidarfuzz.search.evaluate import SearchEvaluator
from lidarfuzz.store.contracts import FailureRecord
from lidarfuzz.structural.python_coverage import RecorderConfig
from lidarfuzz.structural.requirements import Covered, Requirement, of_kind


class CodeCriterion(Criterion):
    """A code-coverage criterion: the share of the targets' requirements of one kind any test ran.

    Its one layer (``nodes`` or ``edges``) holds one 0/1 value per requirement (:class:`CodeLayout`).
    """

    layer: ClassVar[str] = ""

    def __init__(self) -> None:
        super().__init__()
        self.layers = [self.layer]

    def hits(self, arrays: Sequence[NDArray[np.float64]]) -> NDArray[np.bool_]:
        return np.asarray(arrays[0] > 0.5)

    def reset(self) -> None:
        super().reset()
        self.layers = [self.layer]


class CodeNodes(CodeCriterion):
    """All-nodes: basic blocks of the target code run by some test."""

    name = "code_nodes"
    layer = "nodes"


class CodeEdges(CodeCriterion):
    """All-edges: edges between basic blocks of the target code taken by some test."""

    name = "code_edges"
    layer = "edges"


#: The code-coverage criteria by name.
CODE_CRITERIA: dict[str, type[CodeCriterion]] = {c.name: c for c in (CodeNodes, CodeEdges)}


def is_code_criterion(spec: str) -> bool:
    """Whether a criterion spec names a code-coverage criterion (``code_nodes``, ``code_edges``)."""
    return spec.split(":")[0].strip().lower() in CODE_CRITERIA


def make_code_criteria(specs: Sequence[str]) -> list[CodeCriterion]:
    """The code criteria of ``specs`` (which take no value).

    Raises:
        ValueError: An unknown name, or a value after the name.
    """
    out = []
    for spec in specs:
        name, _, value = spec.strip().lower().partition(":")
        if name not in CODE_CRITERIA:
            raise ValueError(f"criteria: {spec!r} is no code criterion ({', '.join(CODE_CRITERIA)})")
        if value.strip():
            raise ValueError(f"criteria: {spec!r}: code criteria take no value")
        out.append(CODE_CRITERIA[name]())
    return out


class CodeLayout:
    """The fixed order of the targets' requirements: a covered set ↔ 0/1 rows per kind.

    Args:
        requirements: Every node and edge of the targets (the recorder's ``requirements()``).
    """

    def __init__(self, requirements: Covered) -> None:
        self.nodes = sorted(of_kind(requirements, "node"))
        self.edges = sorted(of_kind(requirements, "edge"))
        self._position = {r: i for i, r in enumerate(self.nodes)} | {r: i for i, r in enumerate(self.edges)}

    def values(self, covered: Covered) -> dict[str, NDArray[np.float32]]:
        """``{"nodes": (1, nT), "edges": (1, eT)}``: 1 where ``covered`` holds the requirement."""
        rows = {"nodes": np.zeros((1, len(self.nodes)), np.float32), "edges": np.zeros((1, len(self.edges)),
                                                                                         np.float32)}
        for requirement in covered:
            position = self._position.get(requirement)
            if position is not None:
                rows["nodes" if requirement.kind == "node" else "edges"][0, position] = 1.0
        return rows

    def covered(self, values: dict[str, NDArray[Any]]) -> Covered:
        """The requirements a row (or a criterion's bit set, as ``{layer: bits}``) marks."""
        out: set[Requirement] = set()
        for layer, every in (("nodes", self.nodes), ("edges", self.edges)):
            if layer in values:
                bits = np.asarray(values[layer]).reshape(-1)
                out.update(every[i] for i in np.flatnonzero(bits > 0.5))
        return frozenset(out)


class CodeSearchEvaluator(SearchEvaluator):
    """A :class:`~lidarfuzz.search.evaluate.SearchEvaluator` whose coverage values are the code
    each test ran (see the module docstring); mutation, validity and relations are the base's.

    Args:
        dataset: Anything with ``load(frame_id)``.
        sut: A loaded system under test (any: its ``detect`` is called once per test).
        relations: Relation objects checked between a seed frame's output and a test's.
        code: What to cover (built into a recorder here).
        keep_share: Validity: every object keeps at least this share of its points.
    """

    def __init__(self, dataset: Any, sut: Any, relations: Sequence[Any], code: RecorderConfig, *,
                 keep_share: float = 0.5, min_points: int = 10, cache: int = 64) -> None:
        super().__init__(dataset, sut, relations, None, keep_share=keep_share, min_points=min_points, cache=cache)
        self.code = code.build()
        self.layout = CodeLayout(self.code.requirements())

    def _forward(self, scenes: list[Any]) -> tuple[list[Any], list[dict[str, NDArray[np.float32]]], float,
                                                    list[FailureRecord | None]]:
        start = time.perf_counter()
        outputs: list[Any] = []
        rows: list[dict[str, NDArray[np.float32]]] = []
        failures: list[FailureRecord | None] = []
        for scene in scenes:
            try:
                output, covered = self.code.record(self.sut.detect, scene)
                failure = None
            except Exception as exc:  # the SUT's crash is this test's result; the code it reached counts
                output, covered = None, self.code.last
                failure = FailureRecord(kind="crash", message=f"{type(exc).__name__}: {exc}".splitlines()[0])
            outputs.append(output)
            rows.append({layer: row[0] for layer, row in self.layout.values(covered).items()})
            failures.append(failure)
        return outputs, rows, time.perf_counter() - start, failures


__all__ = ["CODE_CRITERIA", "CodeCriterion", "CodeEdges", "CodeLayout", "CodeNodes", "CodeSearchEvaluator",
           "is_code_criterion", "make_code_criteria"]
