"""Heuristics that pick a log's *discriminatory segments* into a reduced base log.

Neves et al. observe that a few segments of a long log — those where the route's conditions
changed and the program left its regular flow — carry most of its coverage, and build seven
heuristics on that (two kept, H2 and H6, "the segments that better discriminated all-edges");
the paper does not define them. These are designed here, each documented with its rule:

``greedy_edges``
    Greedy set cover on edges: repeatedly take the segment that adds the most edges not yet
    covered (ties: the earliest segment); stop when no segment adds a new edge. The classic
    ln(n)-approximation: the result covers every edge the log covers, with few segments but not
    always the fewest (see below).
``greedy_nodes``
    The same on nodes.
``budget``
    Largest new coverage first under a frame budget: like the greedy rule (on edges unless told
    otherwise), but a segment is a candidate only while its frames fit in what is left of the
    budget (the last, shorter segment may still fit when a full one does not); stops when
    nothing that fits adds anything.
``decision_change``
    The paper's physical intuition without any coverage: the segments in which the system's
    decision changes. The caller gives one *decision signature* per frame (any hashable value,
    e.g. ``(speed_state, steering_sign)`` from the system's outputs); a change is a pair of
    consecutive frames with different signatures. A segment counts the changes between its own
    consecutive frames and the change (if any) between the frame before it and its first frame,
    so a change at a boundary counts for the later segment — the one whose replay starts in the
    new decision. Every segment with at least one change is selected, most changes first (ties:
    the earliest segment).
``random``
    A baseline: as many segments as a chosen heuristic's selection, drawn without replacement by
    a generator seeded with ``seed`` (the same seed draws the same segments).

Each heuristic returns a :class:`Selection`: its steps in the order they were taken, each with
the requirements (of every kind) it added to what the earlier steps covered — empty for a
``decision_change`` step when no coverage is given. The reduced base log replays the selected
segments in the log's order (:meth:`Selection.log_order`), as the paper executes generated
logs "in the same order of the original log".

Greedy is not optimal. With edges {1..6} and segments A = {1, 2, 3, 4}, B = {1, 2, 5},
C = {3, 4, 6}, greedy takes A (4 new) and then needs B and C (one new each): 3 segments,
where B and C alone cover everything.

Example:
    >>> from lidarfuzz.structural.requirements import Requirement
    >>> def edges(*ns):
    ...     return frozenset(Requirement("m:f", "edge", n, n + 1) for n in ns)
    >>> chosen = greedy_edges([edges(1, 2, 3, 4), edges(1, 2, 5), edges(3, 4, 6)])
    >>> chosen.segments, [len(s.added) for s in chosen.steps]
    ((0, 1, 2), [4, 1, 1])
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from lidarfuzz.structural.logs import OrderedLog
from lidarfuzz.structural.requirements import Covered, Kind, Requirement, coverage_ratio, of_kind, union
from lidarfuzz.structural.segments import DEFAULT_SIZE, Segment, partition, segment_coverage

HEURISTICS = ("greedy_edges", "greedy_nodes", "budget", "decision_change", "random")
#: Mixed into the random baseline's seed so it never shares a stream with another draw of the same seed.
RANDOM_STREAM = 0x52414E44


@dataclass(frozen=True)
class Step:
    """One segment a heuristic took.

    Attributes:
        segment: The segment's index in the log's partition.
        added: The requirements (nodes and edges) it covered that no earlier step had.
        score: What the heuristic ranked it by: new requirements of its kind (greedy, budget,
            random), decision changes (``decision_change``).
        frames: Its number of frames.
    """

    segment: int
    added: Covered
    score: int
    frames: int


@dataclass(frozen=True)
class Selection:
    """A heuristic's choice of segments, step by step."""

    heuristic: str
    steps: tuple[Step, ...]

    @property
    def segments(self) -> tuple[int, ...]:
        """Segment indices in the order they were taken."""
        return tuple(s.segment for s in self.steps)

    def log_order(self) -> tuple[int, ...]:
        """Segment indices in the log's order: how the reduced base log replays them."""
        return tuple(sorted(self.segments))

    @property
    def frames(self) -> int:
        return sum(s.frames for s in self.steps)

    @property
    def covered(self) -> Covered:
        """Everything the selected segments cover."""
        return union(*(s.added for s in self.steps))

    def __len__(self) -> int:
        return len(self.steps)


def _check_sizes(coverage: Sequence[Covered], sizes: Sequence[int] | None) -> list[int]:
    if sizes is None:
        return [1] * len(coverage)
    if len(sizes) != len(coverage):
        raise ValueError(f"sizes: expected one frame count per segment ({len(coverage)}), got {len(sizes)}")
    return list(sizes)


def _steps(heuristic: str, order: Iterable[tuple[int, int]], coverage: Sequence[Covered] | None,
           sizes: Sequence[int]) -> Selection:
    """A selection from (segment, score) pairs, with what each added to the ones before."""
    seen: set[Requirement] = set()
    steps = []
    for index, score in order:
        covered = coverage[index] if coverage is not None else frozenset()
        added = frozenset(covered - seen)
        seen |= added
        steps.append(Step(index, added, score, sizes[index]))
    return Selection(heuristic, tuple(steps))


def _greedy(coverage: Sequence[Covered], kind: Kind, sizes: Sequence[int], budget: int | None) -> list[tuple[int, int]]:
    """Lazy greedy set cover: a heap of (−gain, index) whose gains are upper bounds (a segment's
    gain only shrinks as others are taken), re-evaluated when popped. The popped key after
    re-evaluation is ≤ every other key's bound, hence ≤ every true key: the most new requirements,
    the earliest segment among ties — the same choice as a full scan, in far fewer set operations."""
    wanted = [of_kind(c, kind) for c in coverage]
    heap = [(-len(w), i) for i, w in enumerate(wanted) if w]
    heapq.heapify(heap)
    covered: set[Requirement] = set()
    left = budget
    order: list[tuple[int, int]] = []
    while heap:
        _, index = heapq.heappop(heap)
        if left is not None and sizes[index] > left:
            continue  # the budget only shrinks: it never fits again
        gain = len(wanted[index] - covered)
        if gain == 0:
            continue
        if heap and (-gain, index) > heap[0]:
            heapq.heappush(heap, (-gain, index))
            continue
        order.append((index, gain))
        covered |= wanted[index]
        if left is not None:
            left -= sizes[index]
    return order


def greedy(coverage: Sequence[Covered], kind: Kind, *, sizes: Sequence[int] | None = None,
           name: str | None = None) -> Selection:
    """Greedy set cover on ``kind`` (``node`` or ``edge``) over per-segment coverage."""
    frames = _check_sizes(coverage, sizes)
    return _steps(name or f"greedy_{kind}s", _greedy(coverage, kind, frames, None), coverage, frames)


def greedy_edges(coverage: Sequence[Covered], *, sizes: Sequence[int] | None = None) -> Selection:
    """Greedy set cover on edges (see the module docstring)."""
    return greedy(coverage, "edge", sizes=sizes)


def greedy_nodes(coverage: Sequence[Covered], *, sizes: Sequence[int] | None = None) -> Selection:
    """Greedy set cover on nodes (see the module docstring)."""
    return greedy(coverage, "node", sizes=sizes)


def budget(coverage: Sequence[Covered], sizes: Sequence[int], frames: int, *, kind: Kind = "edge") -> Selection:
    """Largest new coverage of ``kind`` first, within ``frames`` frames in all.

    Raises:
        ValueError: ``frames`` below 1, or ``sizes`` not one count per segment.
    """
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"budget: expected a whole number of frames >= 1, got {frames!r}")
    counts = _check_sizes(coverage, sizes)
    return _steps("budget", _greedy(coverage, kind, counts, frames), coverage, counts)


def decision_changes(segments: Sequence[Segment], signatures: Sequence[Hashable]) -> list[int]:
    """Per segment, the decision changes it holds (see ``decision_change`` in the module docstring)."""
    frames = segments[-1].last + 1 if segments else 0
    if len(signatures) != frames:
        raise ValueError(f"signatures: expected one decision signature per frame of the log ({frames}), "
                         f"got {len(signatures)}")
    changed = [False] + [signatures[i] != signatures[i - 1] for i in range(1, frames)]
    return [sum(changed[p] for p in s.positions) for s in segments]


def decision_change(segments: Sequence[Segment], signatures: Sequence[Hashable],
                    coverage: Sequence[Covered] | None = None) -> Selection:
    """The segments in which the decision changes, most changes first (ties: the earliest).

    Args:
        segments: The log's partition.
        signatures: One decision signature per frame, in replay order.
        coverage: Per-segment coverage, when known: each step then records what it added.
    """
    if coverage is not None and len(coverage) != len(segments):
        raise ValueError(f"coverage: expected one set per segment ({len(segments)}), got {len(coverage)}")
    counts = decision_changes(segments, signatures)
    order = sorted(((i, n) for i, n in enumerate(counts) if n), key=lambda item: (-item[1], item[0]))
    return _steps("decision_change", order, coverage, [len(s) for s in segments])


def random_segments(coverage: Sequence[Covered], count: int, seed: int, *, kind: Kind = "edge",
                    sizes: Sequence[int] | None = None) -> Selection:
    """``count`` segments drawn at random without replacement (seeded); each step's score is the
    new requirements of ``kind`` it added.

    Raises:
        ValueError: ``count`` below 0 or above the number of segments.
    """
    if isinstance(count, bool) or not isinstance(count, int) or not 0 <= count <= len(coverage):
        raise ValueError(f"count: expected 0 to {len(coverage)} segments, got {count!r}")
    frames = _check_sizes(coverage, sizes)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), RANDOM_STREAM]))
    drawn = [int(i) for i in rng.choice(len(coverage), size=count, replace=False)]
    seen: set[Requirement] = set()
    order = []
    for index in drawn:
        order.append((index, len(of_kind(coverage[index], kind) - seen)))
        seen |= coverage[index]
    return _steps("random", order, coverage, frames)


def select(heuristic: str, segments: Sequence[Segment], coverage: Sequence[Covered] | None = None, *,
           frames: int | None = None, signatures: Sequence[Hashable] | None = None, seed: int = 0,
           reference: str = "greedy_edges") -> Selection:
    """Run the heuristic named ``heuristic`` (one of :data:`HEURISTICS`) on a partitioned log.

    Args:
        heuristic: Its name.
        segments: The log's partition.
        coverage: Per-segment coverage (all but ``decision_change`` need it).
        frames: ``budget``'s frame budget.
        signatures: ``decision_change``'s per-frame decision signatures.
        seed: ``random``'s seed.
        reference: The heuristic whose selection size ``random`` matches.

    Raises:
        ValueError: An unknown heuristic, or an input it needs missing — naming it.
    """
    sizes = [len(s) for s in segments]
    if heuristic == "decision_change":
        if signatures is None:
            raise ValueError("decision_change needs signatures: one decision signature per frame")
        return decision_change(segments, signatures, coverage)
    if heuristic not in HEURISTICS:
        raise ValueError(f"heuristic {heuristic!r}: choose one of {', '.join(HEURISTICS)}")
    if coverage is None:
        raise ValueError(f"{heuristic} needs coverage: one set of covered requirements per segment")
    if len(coverage) != len(segments):
        raise ValueError(f"coverage: expected one set per segment ({len(segments)}), got {len(coverage)}")
    if heuristic == "greedy_edges":
        return greedy_edges(coverage, sizes=sizes)
    if heuristic == "greedy_nodes":
        return greedy_nodes(coverage, sizes=sizes)
    if heuristic == "budget":
        if frames is None:
            raise ValueError("budget needs frames: the most frames the reduced log may hold")
        return budget(coverage, sizes, frames)
    if reference == "random":
        raise ValueError("random's reference must be another heuristic")
    size = len(select(reference, segments, coverage, frames=frames, signatures=signatures, seed=seed))
    return random_segments(coverage, size, seed, sizes=sizes)


@dataclass(frozen=True)
class Closeness:
    """How close a reduced log comes to the full log (the paper: 13 segments, about 65 clouds,
    92 % of the nodes against 95 % for all 2,490 clouds).

    Ratios are COV_Nodes / COV_Edges over ``total`` (the requirements of the code under test),
    or over what the full log covers when no total is known (then the full log's are 1.0).
    """

    segments: int
    frames: int
    log_segments: int
    log_frames: int
    nodes: float
    edges: float
    log_nodes: float
    log_edges: float


def closeness(selection: Selection, coverage: Sequence[Covered], segments: Sequence[Segment],
              total: Iterable[Requirement] | None = None) -> Closeness:
    """The reduced log's size and coverage beside the full log's."""
    full = union(*coverage)
    every = frozenset(total) if total is not None else full
    reduced = union(*(coverage[i] for i in selection.segments))
    return Closeness(len(selection), selection.frames, len(segments), sum(len(s) for s in segments),
                     coverage_ratio(reduced, every, "node"), coverage_ratio(reduced, every, "edge"),
                     coverage_ratio(full, every, "node"), coverage_ratio(full, every, "edge"))


@dataclass(frozen=True)
class LogSelection:
    """A log's partition, its per-segment coverage and a heuristic's selection from it."""

    segments: list[Segment]
    coverage: list[Covered]
    selection: Selection


def select_from_log(log: OrderedLog, coverage_of: Callable[[OrderedLog], Sequence[Covered]], heuristic: str, *,
                    size: int = DEFAULT_SIZE, frames: int | None = None,
                    signatures: Sequence[Hashable] | None = None, seed: int = 0,
                    reference: str = "greedy_edges") -> LogSelection:
    """Partition ``log``, measure it and select: ``coverage_of(log)`` replays the log through the
    system under test (a coverage recorder's job) and returns one ``Covered`` per frame."""
    segments = partition(log.frame_ids, size)
    per_segment = segment_coverage(segments, coverage_of(log))
    chosen = select(heuristic, segments, per_segment, frames=frames, signatures=signatures, seed=seed,
                    reference=reference)
    return LogSelection(segments, per_segment, chosen)


__all__ = [
    "HEURISTICS", "Closeness", "LogSelection", "Selection", "Step", "budget", "closeness", "decision_change",
    "decision_changes", "greedy", "greedy_edges", "greedy_nodes", "random_segments", "select", "select_from_log",
]
