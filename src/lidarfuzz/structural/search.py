"""Search-based log generation towards uncovered code (Neves et al.'s future work).

Neves et al. generate logs with one strategy per segment and measure what they reach; here a
loop searches for them. It starts from a log (the field test, or a base log) replayed in order
under the coverage recorder, and spends a budget of *candidates* on a *working log* W, a list of
*units*: at first the log's segments (``s000003``), later also mutated copies (``c12``: the unit
candidate 12 made).

1. **Pick a unit** with probability proportional to ``decay ** times picked × (1 + near)``, where
   *near* counts the requirements not yet covered in the functions the unit's own replay ran (its
   frames reach that code; what they miss is a branch away). A new unit has been picked zero times
   (a new seed, as DeepHunter's queue treats an accepted test).
2. **Mutate it**: two operators of the pool at severities drawn from 1 to ``max_severity``,
   composed in order (a ``sequence``), as DeepTest's guided search does: the first is the next of
   the operators of kept candidates (when there are any), the second is random. Every frame of
   the unit is mutated with the same draw of the generator (``SeedSequence([seed, candidate,
   1])``): params that depend only on the draw (a height, a fog density) are the unit's, a stretch
   of road seen under one condition; params that depend on a frame's content (which object) are
   drawn from that frame.
3. **Insert** the mutated copy right after its unit — as Neves et al.'s generated logs insert a
   mutant after its source — so the unit keeps what it covered (a frame lifted 0.4 m still covers
   its branch when a copy lifted once more covers the next), and **replay** the candidate log from
   its start, because the system keeps state: the units up to the insertion point are stepped
   *without* recording (their coverage is W's, known; untraced steps run at the system's own
   speed), the new unit and every unit after it under the recorder (a changed state can change
   what later, unchanged frames run). One candidate costs one replay of W plus k frames, of which
   the part from the insertion point on is recorded. Copying the system's state at the insertion
   point instead would save the prefix, but the sequence contract offers no copy
   (``reset``/``step`` only; a ``worker:`` program's state cannot be copied at all). The system
   must be deterministic: the prefix is not measured again.
4. **Keep** the candidate when its log covers a requirement (node or edge) that W did not, and
   loses none W covered (a changed state may lose some after the insertion point); W becomes the
   candidate log. So the written log, replayed, covers everything the summary lists, and at least
   what the starting log covers (its frames are all there, in order).

Candidates whose operators fail on a frame count against the budget without a replay. The
``random`` strategy is the baseline with the same budget and the same acceptance: a segment of
the starting log uniformly, both operators at random, applied to the starting log's own frames
(nothing builds on a kept candidate).

Every draw comes from ``SeedSequence([seed, candidate, purpose])``: the search is a function of
its arguments. The state — the kept candidates with their exact per-frame params, times each unit
was picked, the queue of productive operators, counters, and which candidate found each
requirement — is written after every candidate to a JSON checkpoint beside the output
(``OUT.search.json``, replaced atomically). A rerun with the same arguments continues from it (a
larger budget goes on; W is rebuilt from the exact params and its coverage restored by one replay,
not counted in the budget) and ends with the same log as an uninterrupted run. At the end W is
written as a generated log (KITTI layout, :func:`~lidarfuzz.structural.generate.write_log`,
heuristic and strategy ``search``): every frame's source and the flattened chain of every kept
operator applied to it, with its exact params; an inserted unit's frames are timed evenly between
its segment's last frame and the next segment's first (after the log's end: by its last gap).
"""

from __future__ import annotations

import contextlib
import json
import os
from collections import defaultdict
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, Literal

import numpy as np

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.operators.registry import available, from_spec, get
from lidarfuzz.scene.scene import Scene
from lidarfuzz.structural.generate import GeneratedLog, Provenance, write_log
from lidarfuzz.structural.logs import OrderedLog
from lidarfuzz.structural.python_coverage import CoverageRecorder
from lidarfuzz.structural.requirements import Covered, Requirement, of_kind, union
from lidarfuzz.structural.segments import Segment, partition

#: The default pool: operators that move or reshape what a controller sees (heights, positions,
#: objects, free space, clutter, weather).
DEFAULT_OPERATORS = (
    "height_shift", "rotate_z", "global_translate", "object_insertion", "object_placement", "object_removal",
    "random_region_point_deletion", "uniform_point_deletion", "gaussian_noise_addition", "outside_roi_scatter",
    "beam_missing", "fog", "rain", "snow",
)
#: Bytes of the starting log's points kept in memory between replays.
CACHE_BYTES = 1 << 30
#: The checkpoint's suffix, beside the output folder.
CHECKPOINT_SUFFIX = ".search.json"
_FORMAT = 1


class LogSearchError(LidarfuzzError):
    """A search that cannot start or continue (bad settings, a checkpoint of other arguments)."""


@dataclass(frozen=True)
class SearchSettings:
    """How a log search runs (all but ``budget`` must match a checkpoint to continue it).

    Attributes:
        operators: The pool (registered operator names).
        budget: Candidates to try (each one replay, unless its operators fail on a frame).
        seed: Seeds every draw.
        size: Frames per segment.
        max_severity: Severities are drawn from 1 to this.
        decay: Segment selection weight is ``decay ** times picked`` (× closeness to uncovered code).
        strategy: ``search`` (guided, cumulative) or ``random`` (the baseline).
    """

    operators: tuple[str, ...] = DEFAULT_OPERATORS
    budget: int = 50
    seed: int = 0
    size: int = 5
    max_severity: int = 5
    decay: float = 0.8
    strategy: Literal["search", "random"] = "search"

    def __post_init__(self) -> None:
        known = available()
        unknown = [name for name in self.operators if name not in known]
        if unknown:
            raise LogSearchError(f"--operators: unknown operator(s) {unknown}; see `lidarfuzz operators`")
        other = [name for name in self.operators if known[name].modality != "lidar"]
        if other:
            raise LogSearchError(f"--operators: {other[0]} is a {known[other[0]].modality} operator; logs are "
                                 "searched with lidar operators (lidarfuzz operators --modality lidar)")
        if not self.operators:
            raise LogSearchError("--operators: the search needs at least one operator")
        for name, value, low in (("--budget", self.budget, 0), ("--size", self.size, 1),
                                 ("--max-severity", self.max_severity, 1)):
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise LogSearchError(f"{name}: expected a whole number >= {low}, got {value!r}")
        if self.max_severity > 5:
            raise LogSearchError(f"--max-severity: severities go up to 5, got {self.max_severity}")
        if not 0.0 < self.decay <= 1.0:
            raise LogSearchError(f"decay: expected a number in (0, 1], got {self.decay}")
        if self.strategy not in ("search", "random"):
            raise LogSearchError(f"strategy: expected search or random, got {self.strategy!r}")

    def identity(self) -> dict[str, Any]:
        """What a checkpoint must agree on (everything but the budget)."""
        values = asdict(self)
        values.pop("budget")
        values["operators"] = list(self.operators)
        return values


@dataclass
class Mutation:
    """One kept candidate: the segment of the working log it mutated, the operators, each frame's
    exact params, and what it covered first.

    Attributes:
        candidate: The candidate's number.
        source: The unit of the working log it mutated (``s000003`` for the starting log's segment 3,
            ``c12`` for the unit candidate 12 inserted).
        segment: The starting log's segment the frames come from.
        spec: The chain's operator spec (a ``sequence`` of the two operators at their severities).
        params: Per frame of the segment, the chain's concrete params (``{"steps": [...]}``).
        severities: The two severities drawn.
        new: The requirements it covered first (labels).
    """

    candidate: int
    source: str
    segment: int
    spec: dict[str, Any]
    params: list[dict[str, Any]]
    severities: list[int]
    new: list[str] = field(default_factory=list)

    @property
    def unit(self) -> str:
        """The id of the unit it inserted."""
        return f"c{self.candidate}"

    @property
    def operators(self) -> list[str]:
        return [str(child["name"]) for child in self.spec["operators"]]


@dataclass
class Unit:
    """A run of frames of the working log: one of the starting log's segments, or a mutated copy
    of another unit inserted right after it.

    Attributes:
        id: ``s000003`` or ``c12``.
        segment: The starting log's segment its frames come from.
        chain: The kept mutations applied, in order, to the segment's frames (empty for a segment of
            the starting log).
        picked: Times a candidate mutated it.
    """

    id: str
    segment: Segment
    chain: list[Mutation] = field(default_factory=list)
    picked: int = 0


@dataclass(frozen=True)
class Candidate:
    """What one candidate did (for progress and tests)."""

    index: int
    source: str
    segment: int
    operators: tuple[str, ...]
    severities: tuple[int, ...]
    kept: bool
    new: Covered
    lost: Covered
    error: str | None = None


@dataclass(frozen=True)
class SearchResult:
    """The end of a search.

    Attributes:
        log: The generated log written (``None`` when no output was asked for).
        total: Every requirement of the targets.
        start: What the starting log covers.
        covered: What the written log covers (a superset of ``start``'s: its frames are all there).
        found: Each newly covered requirement → the kept :class:`Mutation` that covered it first.
        kept: The kept mutations, in order.
        stats: ``candidates``, ``replays``, ``kept``, ``operator_errors``, ``restore_replays``.
        frames: Frames of the written log.
    """

    log: GeneratedLog | None
    total: Covered
    start: Covered
    covered: Covered
    found: dict[Requirement, Mutation]
    kept: list[Mutation]
    stats: dict[str, int]
    frames: int

    @property
    def new(self) -> Covered:
        return frozenset(self.found)

    def per_function(self) -> dict[str, dict[str, list[str]]]:
        """Newly covered requirements grouped by function: ``{function: {"node": [...], "edge": [...]}}``."""
        out: dict[str, dict[str, list[str]]] = defaultdict(lambda: {"node": [], "edge": []})
        for requirement in sorted(self.found):
            out[requirement.function][requirement.kind].append(requirement.label().rpartition(":")[2])
        return dict(out)

    def to_json(self) -> dict[str, Any]:
        counts = {kind: {"total": len(of_kind(self.total, kind)), "start": len(of_kind(self.start & self.total, kind)),
                         "covered": len(of_kind(self.covered & self.total, kind))} for kind in ("node", "edge")}
        return {"log": None if self.log is None else self.log.path, "frames": self.frames, "coverage": counts,
                "stats": self.stats, "new": self.per_function(),
                "found_by": [{"requirement": r.label(), "candidate": m.candidate, "source": m.source,
                              "segment": m.segment, "operators": m.operators, "severities": m.severities}
                             for r, m in sorted(self.found.items())]}


def _key(requirement: Requirement) -> list[Any]:
    return [requirement.function, requirement.kind, requirement.source, requirement.target]


def _requirement(key: Sequence[Any]) -> Requirement:
    return Requirement(str(key[0]), key[1], int(key[2]), int(key[3]))


def checkpoint_path(out: str | PathLike[str]) -> Path:
    """Where the checkpoint of a search writing to ``out`` lives: ``OUT.search.json`` beside it."""
    out = Path(out)
    return out.with_name(out.name + CHECKPOINT_SUFFIX)


def _write_atomically(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, path)


class LogSearch:
    """The search's state and loop (see the module docstring).

    Args:
        log: The starting log.
        system: A sequence system (``reset()``, ``step(frame)``), deterministic.
        targets: The code to cover (``pkg.module``, ``pkg.module:Class``, ``pkg.module:function``).
        settings: How to search.
        system_spec: The system's name for the checkpoint (e.g. ``controller``).
    """

    def __init__(self, log: OrderedLog, system: Any, targets: Sequence[str], settings: SearchSettings, *,
                 system_spec: str | None = None) -> None:
        self.log, self.system, self.settings = log, system, settings
        self.targets = tuple(targets)
        self.system_spec = system_spec or type(system).__name__
        self.recorder = CoverageRecorder(self.targets)
        self.total = self.recorder.requirements()
        self.segments = partition(log.frame_ids, settings.size)
        self.units = [Unit(s.id, s) for s in self.segments]
        self.next_index = 0
        self.queue: list[str] = []
        self.kept: list[Mutation] = []
        self.found: dict[Requirement, Mutation] = {}
        self.stats = {"candidates": 0, "replays": 0, "kept": 0, "operator_errors": 0, "restore_replays": 0}
        self._frames: dict[str, list[Scene]] = {}  # the frames of inserted units
        self._originals: dict[int, Scene] = {}
        self._cached = 0
        self.covered_per_unit = self._replay_all()
        self.start = union(*(c for unit in self.covered_per_unit for c in unit))

    # -- the working log ---------------------------------------------------------------
    def frames_of(self, unit: Unit) -> list[Scene]:
        """A unit's frames (the starting log's, or those its mutations made)."""
        if not unit.chain:
            return [self._original(position) for position in unit.segment.positions]
        return self._frames[unit.id]

    def _original(self, position: int) -> Scene:
        """A frame of the starting log, kept in memory while they fit in :data:`CACHE_BYTES` (every
        replay reads them all, in order)."""
        scene = self._originals.get(position)
        if scene is None:
            scene = self.log.frame(position)
            if self._cached + scene.points.data.nbytes <= CACHE_BYTES:
                self._originals[position] = scene
                self._cached += scene.points.data.nbytes
        return scene

    def _replay_all(self) -> list[list[Covered]]:
        self.system.reset()
        return [[self._step(scene, record=True) for scene in self.frames_of(unit)] for unit in self.units]

    def _step(self, scene: Scene, *, record: bool) -> Covered:
        """One step (a failure of the system is its own result: the log goes on, as replay does)."""
        if not record:
            with contextlib.suppress(Exception):  # a failure here is known from the working log's own replay
                self.system.step(scene)
            return frozenset()
        try:
            return self.recorder.record(self.system.step, scene)[1]
        except Exception:  # a crash reached that code: it counts
            return self.recorder.last

    @property
    def covered(self) -> Covered:
        """What the working log covers (the starting log's frames are all in it)."""
        return self.start | union(*(c for unit in self.covered_per_unit for c in unit))

    # -- one candidate -------------------------------------------------------------------
    def _rng(self, index: int, *purpose: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence([self.settings.seed, index, *purpose]))

    def near(self) -> list[int]:
        """Per unit, the requirements not yet covered in the functions its replay ran."""
        missing: dict[str, int] = defaultdict(int)
        for requirement in self.total - self.covered:
            missing[requirement.function] += 1
        out = []
        for covered in self.covered_per_unit:
            functions = {r.function for frame in covered for r in frame}
            out.append(sum(missing.get(function, 0) for function in functions))
        return out

    def _pick(self, rng: np.random.Generator) -> int:
        """The position in :attr:`units` of the unit to mutate."""
        if self.settings.strategy == "random":  # a segment of the starting log, as it is
            chosen = self.segments[int(rng.integers(len(self.segments)))].id
            return next(i for i, unit in enumerate(self.units) if unit.id == chosen)
        weights = np.array([self.settings.decay ** unit.picked * (1 + near)
                            for unit, near in zip(self.units, self.near(), strict=True)], dtype=np.float64)
        return int(rng.choice(len(self.units), p=weights / weights.sum()))

    def _chain(self, rng: np.random.Generator) -> tuple[dict[str, Any], list[int]]:
        pool = list(self.settings.operators)
        first = self.queue.pop(0) if self.queue and self.settings.strategy == "search" else str(rng.choice(pool))
        names = [first, str(rng.choice(pool))]
        severities = [int(rng.integers(1, self.settings.max_severity + 1)) for _ in names]
        specs = [get(name).at_severity(severity).spec() for name, severity in zip(names, severities, strict=True)]
        return {"name": "sequence", "operators": specs}, severities

    def _mutate(self, index: int, frames: list[Scene], spec: dict[str, Any],
                ) -> tuple[list[Scene], list[dict[str, Any]]]:
        """The chain on each frame, every frame with the same draw of the generator: params that
        depend only on the draw (a height, a fog density) are the segment's, those that depend on a
        frame's content (which object) are drawn from it."""
        chain = from_spec(spec)
        mutants, params = [], []
        for frame in frames:
            mutant, drawn = chain(frame, self._rng(index, 1))
            mutants.append(mutant)
            params.append(drawn.model_dump(mode="json"))
        return mutants, params

    def _replay_candidate(self, after: int, frames: list[Scene]) -> list[list[Covered]]:
        """Coverage per unit and frame of the working log with ``frames`` inserted after unit ``after``
        (the units up to it stepped untraced: their coverage is the working log's)."""
        self.system.reset()
        out: list[list[Covered]] = []
        for position, unit in enumerate(self.units):
            if position <= after:
                for scene in self.frames_of(unit):
                    self._step(scene, record=False)
                out.append(self.covered_per_unit[position])
            else:
                out.append([self._step(scene, record=True) for scene in self.frames_of(unit)])
            if position == after:
                out.append([self._step(scene, record=True) for scene in frames])
        return out

    def step(self) -> Candidate:
        """Try the next candidate."""
        index = self.next_index
        rng = self._rng(index, 0)
        position = self._pick(rng)
        unit = self.units[position]
        spec, severities = self._chain(rng)
        names = tuple(str(child["name"]) for child in spec["operators"])
        unit.picked += 1
        self.next_index += 1
        self.stats["candidates"] += 1
        note = (index, unit.id, unit.segment.index, names, tuple(severities))
        try:
            frames, params = self._mutate(index, self.frames_of(unit), spec)
        except Exception as exc:  # an operator that cannot work on these frames: no replay
            self.stats["operator_errors"] += 1
            return Candidate(*note, False, frozenset(), frozenset(), f"{type(exc).__name__}: {exc}".splitlines()[0])
        per_unit = self._replay_candidate(position, frames)
        self.stats["replays"] += 1
        covered = union(*(c for frames_covered in per_unit for c in frames_covered))
        before = self.covered
        new = (covered - before) & self.total
        lost = (before - covered) & self.total
        kept = bool(new) and not lost
        if kept:
            mutation = Mutation(index, unit.id, unit.segment.index, spec, params, severities,
                                sorted(r.label() for r in new))
            self._insert(position, mutation, frames)
            self.covered_per_unit = per_unit
            self.found.update({r: mutation for r in new})
            self.stats["kept"] += 1
            if self.settings.strategy == "search":
                self.queue += mutation.operators
        return Candidate(*note, kept, frozenset(new), frozenset(lost))

    def _insert(self, position: int, mutation: Mutation, frames: list[Scene]) -> None:
        source = self.units[position]
        self.units.insert(position + 1, Unit(mutation.unit, source.segment, [*source.chain, mutation]))
        self._frames[mutation.unit] = frames
        self.kept.append(mutation)

    # -- state ----------------------------------------------------------------------------
    def identity(self) -> dict[str, Any]:
        return {"log": str(Path(self.log.path).resolve()), "frames": len(self.log), "system": self.system_spec,
                "targets": list(self.targets), **self.settings.identity()}

    def state(self) -> dict[str, Any]:
        return {"format": _FORMAT, "identity": self.identity(), "next_index": self.next_index,
                "units": [[unit.id, unit.picked] for unit in self.units], "queue": self.queue, "stats": self.stats,
                "kept": [asdict(m) for m in self.kept],
                "found": [[_key(r), m.candidate] for r, m in sorted(self.found.items())]}

    def load(self, state: dict[str, Any], where: str) -> None:
        """Continue from a checkpoint of the same arguments: the working log rebuilt from the kept
        mutations' exact params, its coverage restored by one replay."""
        if state.get("format") != _FORMAT:
            raise LogSearchError(f"{where}: not a checkpoint of this version of lidarfuzz logs search")
        mine = self.identity()
        for name, value in state["identity"].items():
            if mine.get(name) != value:
                raise LogSearchError(f"{where}: the checkpoint was made with {name} {value!r}, this run has "
                                     f"{mine.get(name)!r}; rerun with the same arguments, or another --out")
        self.next_index, self.queue = int(state["next_index"]), list(state["queue"])
        self.stats = dict(state["stats"])
        for data in state["kept"]:
            mutation = Mutation(**data)
            position = next(i for i, unit in enumerate(self.units) if unit.id == mutation.source)
            frames = [self._apply(scene, mutation, offset)
                      for offset, scene in enumerate(self.frames_of(self.units[position]))]
            self._insert(position, mutation, frames)
        picked = {unit_id: count for unit_id, count in state["units"]}
        for unit in self.units:
            unit.picked = int(picked[unit.id])
        by_candidate = {m.candidate: m for m in self.kept}
        self.found = {_requirement(key): by_candidate[candidate] for key, candidate in state["found"]}
        self.covered_per_unit = self._replay_all()
        self.stats["restore_replays"] = self.stats.get("restore_replays", 0) + 1

    @staticmethod
    def _apply(scene: Scene, mutation: Mutation, offset: int) -> Scene:
        operator = from_spec(mutation.spec)
        return operator.apply(scene, operator.parse_params(mutation.params[offset]))

    # -- output ---------------------------------------------------------------------------
    def timestamps(self) -> list[float | None]:
        """The working log's clock: the starting log's frames keep their times; an inserted unit's
        frames lie evenly between the unit before it and the next original frame (after the log's
        end: spaced by its last gap, or 0.1 s)."""
        stamps = self.log.timestamps
        if stamps is None:
            return [None] * sum(len(unit.segment) for unit in self.units)
        gap = float(stamps[-1] - stamps[-2]) if len(stamps) > 1 else 0.1
        inserted: dict[int, int] = defaultdict(int)  # frames inserted after each segment of the starting log
        for unit in self.units:
            if unit.chain:
                inserted[unit.segment.index] += len(unit.segment)
        out: list[float | None] = []
        for segment in self.segments:
            out += [float(stamps[p]) for p in segment.positions]
            count = inserted[segment.index]
            if count:
                begin = float(stamps[segment.last])
                end = float(stamps[segment.last + 1]) if segment.last + 1 < len(stamps) else begin + gap
                out += [begin + (end - begin) * (i + 1) / (count + 1) for i in range(count)]
        return out

    def provenance(self) -> Iterator[tuple[Scene, Provenance]]:
        """The working log's frames in order, each with its source and the flattened chain applied to it."""
        stamps = self.timestamps()
        position = 0
        for unit in self.units:
            operators = [child for m in unit.chain for child in m.spec["operators"]]
            for offset, scene in enumerate(self.frames_of(unit)):
                frame_id = f"{position:06d}"
                source = (self.log.frame_ids[unit.segment.first + offset],)
                scene = scene.replace(frame_id=frame_id, timestamp=stamps[position])
                if not unit.chain:
                    yield scene, Provenance(position, frame_id, unit.segment.index, source)
                else:
                    steps = [step for m in unit.chain for step in m.params[offset]["steps"]]
                    yield scene, Provenance(position, frame_id, unit.segment.index, source,
                                            {"name": "sequence", "operators": operators}, {"steps": steps})
                position += 1

    def result(self, written: GeneratedLog | None) -> SearchResult:
        frames = sum(len(unit.segment) for unit in self.units)
        return SearchResult(written, self.total, self.start, self.covered, dict(self.found), list(self.kept),
                            dict(self.stats), frames)


def search_log(log: OrderedLog, system: Any, targets: Sequence[str], settings: SearchSettings,
               out: str | PathLike[str] | None = None, *, system_spec: str | None = None, overwrite: bool = False,
               on_candidate: Callable[[Candidate], None] | None = None) -> SearchResult:
    """Search for a log that covers code ``log`` does not (see the module docstring).

    Args:
        log: The starting log (a field test, or a base log).
        system: The sequence system (``reset()``, ``step(frame)``); deterministic.
        targets: The code to cover.
        settings: How to search.
        out: The generated log's new folder; its checkpoint is ``OUT.search.json``, and a rerun with
            the same arguments continues from it. ``None``: no output and no checkpoint.
        system_spec: The system's name, recorded in the checkpoint.
        overwrite: Replace an existing ``out`` that no checkpoint of this search accounts for.
        on_candidate: Called after every candidate (an exception it raises stops the search, with
            the checkpoint of the candidates before it).

    Raises:
        LogSearchError: Bad settings, an ``out`` that exists, or a checkpoint of other arguments.
    """
    where = checkpoint_path(out) if out is not None else None
    if out is not None and Path(out).exists() and not overwrite and not (where and where.exists()):
        raise LogSearchError(f"--out {out}: exists and is no output of this search; choose a new folder or "
                             "--overwrite")
    search = LogSearch(log, system, targets, settings, system_spec=system_spec)
    if where is not None and where.exists():
        try:
            state = json.loads(where.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise LogSearchError(f"{where}: unreadable checkpoint ({exc}); delete it to start over") from None
        search.load(state, str(where))
    while search.next_index < settings.budget:
        candidate = search.step()
        if where is not None:
            _write_atomically(where, search.state())
        if on_candidate is not None:
            on_candidate(candidate)
    written = None
    if out is not None:
        written = write_log(log, search.provenance(), out, strategy=settings.strategy, seed=settings.seed,
                            heuristic="search", segment_size=settings.size,
                            segments=tuple(sorted({m.segment for m in search.kept})), overwrite=True)
    result = search.result(written)
    if where is not None:
        _write_atomically(where, {**search.state(), "summary": result.to_json()})
    return result


__all__ = ["CHECKPOINT_SUFFIX", "DEFAULT_OPERATORS", "Candidate", "LogSearch", "LogSearchError", "Mutation",
           "SearchResult", "SearchSettings", "Unit", "checkpoint_path", "search_log"]
