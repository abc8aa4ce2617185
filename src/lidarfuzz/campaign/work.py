"""One work unit: (subtask, frame, trial) → mutant, the system's output on it, the relations checked.

A :class:`Worker` holds what every unit of a task needs — the data set, the system under test
(loaded once), the relations — and turns a :class:`WorkUnit` into a :class:`UnitResult`. It
never writes to the store: the runner, a single writer, commits results as they arrive, so
any executor (inline, a process pool, later a cluster) can run workers.

A frame that cannot be read (a file deleted, unreadable or malformed mid-run: any error while loading
the source frame, or while a worker opens the data set) is a *data fault* (:data:`DATA_FAULT`): recorded
on its unit, never a failure of the system under test, never a finding, left out of AP, and run
again by ``lidarfuzz resume`` — as are the mutants of an original that had one (their relations need
its output).

The SUT's outputs are cached by the system's fingerprint and an *input key*: the digest of
the source frame's content (points, calibration, ROI, frame id, timestamp) for an original,
and that digest with the operator's spec and concrete params for a mutant (params make a
mutant exactly), so a unit whose input was seen before is not run again. A worker whose system
no longer has the task's recorded fingerprint (its code, weights or configuration changed since
the task was created, then resumed) neither reads nor feeds the cache under that fingerprint.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xxhash

from lidarfuzz.scene.scene import Scene
from lidarfuzz.store.boxes import StoredBoxes
from lidarfuzz.store.contracts import TOOL_ERRORS, FailureRecord, OutcomeRecord
from lidarfuzz.store.types import json_safe

#: The failure kind of a unit whose frame could not be read (see the module docstring).
DATA_FAULT = "data_error"
#: Failure kinds that are never the system under test's: lidarfuzz's own errors and data faults.
NOT_THE_SYSTEM: tuple[str, ...] = (*TOOL_ERRORS, DATA_FAULT)


@dataclass(frozen=True)
class WorkContext:
    """What every worker of a task needs (picklable)."""

    dataset: str
    sut_spec: str
    sut_options: dict[str, Any]
    fingerprint: str
    store_url: str | None = None  # for cache look-ups; None: no cache
    isolate: bool = False
    timeout: float = 60.0
    save_mutants: str | None = None  # a folder: each subtask's mutants as a KITTI data set
    dataset_options: dict[str, Any] = field(default_factory=dict)  # DatasetOptions as the store keeps them


@dataclass(frozen=True)
class WorkUnit:
    """One test: the originals when ``operator`` is None, else one mutant."""

    subtask_id: int
    frame_id: str
    trial: int = 0
    operator: dict[str, Any] | None = None
    op_index: int = 0
    seed: int = 0
    subtask_name: str = "original"
    relations: tuple[dict[str, Any], ...] = ()
    source: StoredBoxes | None = None  # the system's output on the original, for the relations
    source_failed: bool = False
    params: dict[str, Any] | None = None  # exact params (a replay) instead of drawing them
    operator_relation: str | None = None  # overrides the operator's own (a search's valid tests: invariant)
    source_fault: str = ""  # the original of this frame had a data fault (its message): so has this unit


@dataclass
class UnitResult:
    unit: WorkUnit
    params: dict[str, Any] = field(default_factory=dict)
    detections: StoredBoxes | None = None  # None: no output (the operator or the system failed)
    ground_truth: StoredBoxes | None = None  # the mutant's (None: the operator failed)
    failure: FailureRecord | None = None
    relations: list[OutcomeRecord] = field(default_factory=list)
    seconds: float = 0.0  # the system's own time (0 when cached)
    timings: dict[str, float] = field(default_factory=dict)  # load, mutate, detect, relations, save
    cached: bool = False
    input_key: str = ""  # the input's cache key ("": not cached)
    input_source: str = ""  # the content digest of the frame the input was made from

    def box_columns(self) -> dict[str, Any]:
        """The detections and ground truth as the frame-results table's four columns."""
        return {**(self.detections or StoredBoxes(None)).columns(),
                **(self.ground_truth or StoredBoxes(None)).columns("gt_boxes", "gt_labels")}

    @property
    def key(self) -> tuple[int, str, int]:
        return self.unit.subtask_id, self.unit.frame_id, self.unit.trial


def data_fault(unit: WorkUnit, exc: BaseException | str) -> UnitResult:
    """The result of ``unit`` when its frame cannot be read (``exc``: the error, or a message)."""
    message = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
    return UnitResult(unit, failure=FailureRecord(kind=DATA_FAULT, message=f"frame {unit.frame_id}: {message}"))


#: Marks a content digest's algorithm: outputs cached under SHA-256 digests by earlier versions
#: are simply never found again (a cache miss runs the system), never confused with these.
DIGEST_PREFIX = "x3:"


def content_digest(scene: Scene) -> str:
    """A digest of everything a system may read from a frame: XXH3-128 (xxhash) of the point
    array's own buffer, then the channels, calibration, ROI, frame id and timestamp.

    A cache key, not a signature: nobody forges a frame against their own cache, and with 128
    bits an accidental collision stays negligible at any cache size (the birthday bound is
    2⁻⁶⁵ at 2³² cached inputs). XXH3 hashes ~30 GB/s where SHA-256 does ~2 GB/s here: 0.1 ms
    instead of ~1.8 ms per 120k-point frame, paid for every frame of every run.
    """
    h = xxhash.xxh3_128()
    data = np.ascontiguousarray(scene.points.data)
    h.update(data.data.cast("B"))  # the array's own buffer: no copy
    h.update(json.dumps(list(scene.points.channels)).encode())
    if scene.calib is not None:
        h.update(scene.calib.to_text().encode())
    if scene.roi is not None:
        h.update(json.dumps(scene.roi.to_geojson(), sort_keys=True).encode())
    h.update(f"{scene.frame_id}|{scene.timestamp!r}".encode())
    return f"{DIGEST_PREFIX}{h.hexdigest()}"


def mutant_key(source_digest: str, operator: dict[str, Any], params: dict[str, Any]) -> str:
    text = json.dumps({"source": source_digest, "operator": operator, "params": params}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


#: Source frames a worker keeps (a runner's frame block; about 3 MB per 120k-point frame).
SCENE_CACHE = 16


def _basis(operator: Any) -> str:
    """Why a harmlessness relation checks this operator's mutants (a chain of a search: its validity)."""
    from lidarfuzz.campaign.plan import harmless_basis

    if hasattr(operator, "harmless") and hasattr(operator, "harmless_because"):
        return harmless_basis(operator)
    return ""


def open_worker_dataset(context: WorkContext) -> Any:
    """The task's data set, opened with its stored options.

    Raises:
        LidarfuzzError: It cannot be opened (a data fault of every unit that needs it).
    """
    from lidarfuzz.io.open import open_dataset
    from lidarfuzz.io.options import DatasetOptions

    return open_dataset(context.dataset, options=DatasetOptions.from_stored(context.dataset_options))


class Worker:
    """Runs units of one task (see the module docstring)."""

    def __init__(self, context: WorkContext, *, open_data: bool = True) -> None:
        """``open_data=False``: every unit comes with its frame (:meth:`run`'s ``scene``), as on a
        cluster whose driver sends frames through Ray's object store; the data set is opened
        only should a unit come without one."""
        self.context = context
        self._dataset: Any = None
        if open_data:
            self._dataset = open_worker_dataset(context)
        self._digests: OrderedDict[str, str] = OrderedDict()
        self._known: OrderedDict[str, dict[str, StoredBoxes]] = OrderedDict()  # cached outputs by frame digest
        self._scenes: OrderedDict[str, Scene] = OrderedDict()  # the runner sends units frame block by block
        self._operators: dict[str, Any] = {}
        self._relations: dict[str, Any] = {}
        self._sut: Any = None
        self._cache: Any = None
        self._lookup: Any = None
        self._connection: Any = None
        self._empty: bool | None = None  # the cache had no output of this system (see _cache_empty)
        self._changed: bool | None = None
        if context.store_url is not None:
            from lidarfuzz.store.store import Store

            self._cache = Store(context.store_url, migrate=False)

    # -- lazily built parts -------------------------------------------------------------
    @property
    def dataset(self) -> Any:
        if self._dataset is None:
            self._dataset = open_worker_dataset(self.context)
        return self._dataset

    @property
    def sut(self) -> Any:
        if self._sut is None:
            if self.context.isolate:
                from lidarfuzz.suts.guard import IsolatedSut

                sut: Any = IsolatedSut(self.context.sut_spec, timeout=self.context.timeout,
                                       options=self.context.sut_options)
            else:
                from lidarfuzz.suts.registry import create

                sut = create(self.context.sut_spec, **self.context.sut_options)
            sut.load()
            self._sut = sut
        return self._sut

    @property
    def system_changed(self) -> bool:
        """Whether the system built from the task's spec now has another fingerprint than the
        task recorded (computed once, without loading the system)."""
        if self._changed is None:
            from lidarfuzz.suts.registry import create

            now = create(self.context.sut_spec, **self.context.sut_options).fingerprint()
            self._changed = now != self.context.fingerprint
        return self._changed

    def operator(self, spec: dict[str, Any]) -> Any:
        key = json.dumps(spec, sort_keys=True)
        if key not in self._operators:
            from lidarfuzz.operators.registry import from_spec

            self._operators[key] = from_spec(spec)
        return self._operators[key]

    def relation(self, spec: dict[str, Any]) -> Any:
        key = json.dumps(spec, sort_keys=True)
        if key not in self._relations:
            from lidarfuzz.oracles.relations.registry import from_spec

            self._relations[key] = from_spec(spec)
        return self._relations[key]

    def load(self, frame_id: str) -> Scene:
        """A source frame, from a small cache (scenes are immutable; loading one costs milliseconds)."""
        scene = self._scenes.get(frame_id)
        if scene is None:
            scene = self.dataset.load(frame_id)
            self._scenes[frame_id] = scene
            if len(self._scenes) > SCENE_CACHE:
                self._scenes.popitem(last=False)
        else:
            self._scenes.move_to_end(frame_id)
        return scene

    def digest(self, scene: Scene) -> str:
        found = self._digests.get(scene.frame_id)
        if found is None:
            found = content_digest(scene)
            self._digests[scene.frame_id] = found
            if len(self._digests) > 4096:
                self._digests.popitem(last=False)
        return found

    def _cached(self, source: str, key: str) -> StoredBoxes | None:
        """The system's cached output for input ``key`` made from the frame with digest ``source``.

        The first look-up for a frame reads all of that frame's cached outputs in one query, and
        later ones are dictionary look-ups: one query per frame instead of one per unit. Outputs
        cached after that read (by this run, or another one) are not seen until the frame is
        read again; such an input is run again — the cache only ever saves work.
        """
        if self._cache is None or self._cache_empty():
            return None
        known = self._known.get(source)
        if known is None:
            known = self._read_cached(source)
            self._known[source] = known
            if len(self._known) > 4 * SCENE_CACHE:
                self._known.popitem(last=False)
        return known.get(key)

    def _cache_empty(self) -> bool:
        """Whether the cache held no output of this system when this worker first looked (asked
        once): then no frame is read from it. A run's own outputs are never looked for by that run
        (each frame's outputs are read once, at its first unit, before the run caches any), so a
        system's first run skips a query per frame and finds exactly what it would have found."""
        if self._empty is None:
            from sqlalchemy import select

            from lidarfuzz.store.models import SutOutput

            any_output = select(SutOutput.digest).where(SutOutput.fingerprint == self.context.fingerprint).limit(1)
            self._empty = not self._execute(any_output)
        return self._empty

    def _execute(self, statement: Any, parameters: dict[str, Any] | None = None) -> Any:
        """``statement``'s rows from the cache, read in a transaction ended at once (never hold a
        snapshot open)."""
        if self._connection is None:
            self._connection = self._cache.engine.connect()
        rows = self._connection.execute(statement, parameters).all()
        self._connection.rollback()
        return rows

    def _read_cached(self, source: str) -> dict[str, StoredBoxes]:
        from sqlalchemy import bindparam, select

        from lidarfuzz.store.models import SutOutput

        if self._lookup is None:
            self._lookup = select(SutOutput.digest, SutOutput.boxes, SutOutput.labels).where(
                SutOutput.fingerprint == self.context.fingerprint, SutOutput.source == bindparam("source"))
        rows = self._execute(self._lookup, {"source": source})
        return {digest: StoredBoxes(boxes, labels) for digest, boxes, labels in rows}

    # -- one unit ---------------------------------------------------------------------
    def run(self, unit: WorkUnit, scene: Scene | None = None) -> UnitResult:
        """Load the source frame (or take ``scene``, the frame as the caller read it), mutate it,
        detect (or find the output cached), check the relations and save the mutant — each step
        timed in ``result.timings``."""
        if unit.source_fault:
            return data_fault(unit, f"its original had a data fault — {unit.source_fault}")
        result = UnitResult(unit)
        timings = result.timings
        t0 = time.perf_counter()
        try:
            source = scene if scene is not None else self.load(unit.frame_id)
        except Exception as exc:  # the data, not the system: a data fault, run again on resume
            return data_fault(unit, exc)
        timings["load"] = time.perf_counter() - t0
        mutated = self._mutate(unit, source, result)
        if mutated is None:
            return result  # the operator failed on this frame: recorded as its failure
        follow, operator, params = mutated
        result.ground_truth = StoredBoxes.of(follow.boxes)
        output = self._detect(unit, source, follow, result)
        if operator is not None and output is not None and unit.relations and not unit.source_failed:
            self._check_relations(unit, source, follow, output, operator, params, result)
        if self.context.save_mutants and operator is not None:
            t0 = time.perf_counter()
            self._save(unit, follow)
            timings["save"] = time.perf_counter() - t0
        return result

    def _mutate(self, unit: WorkUnit, source: Scene, result: UnitResult) -> tuple[Scene, Any, Any] | None:
        """The frame the system sees, its operator and params (the source itself, None, None for an
        original); None when the operator fails on this frame (``result.failure`` says how)."""
        if unit.operator is None:
            return source, None, None
        from lidarfuzz.operators.base import generator

        t0 = time.perf_counter()
        try:
            operator = self.operator(unit.operator)
            if unit.params is not None:
                params = operator.parse_params(unit.params)
                follow = operator.apply(source, params)
            else:
                follow, params = operator(source, generator(unit.seed, unit.frame_id, unit.op_index, unit.trial))
        except Exception as exc:  # an operator that fails on this frame is a finding, not a crash
            result.failure = FailureRecord(kind="operator_error", message=f"{type(exc).__name__}: {exc}")
            return None
        result.params = json_safe(params.model_dump(mode="json"))
        result.timings["mutate"] = time.perf_counter() - t0
        return follow, operator, params

    def _detect(self, unit: WorkUnit, source: Scene, follow: Scene, result: UnitResult) -> Any:
        """The system's output on ``follow``: from the cache when this input was seen before, else
        run guarded (a crash, timeout or invalid output is ``result.failure``, and None returned)."""
        from lidarfuzz.suts.guard import run_guarded

        t0 = time.perf_counter()
        digest = self.digest(source)
        key = digest if unit.operator is None else mutant_key(digest, unit.operator, result.params)
        fresh = self.system_changed  # the recorded fingerprint's outputs are another system's
        result.input_key = "" if fresh else key  # "": the runner caches nothing under it
        result.input_source = "" if fresh else digest
        hit = None if fresh else self._cached(digest, key)
        result.timings["cache"] = time.perf_counter() - t0
        if hit is not None:
            result.detections = hit
            result.cached = True
            return hit.boxes()
        t0 = time.perf_counter()
        outcome = run_guarded(self.sut, follow)
        result.timings["detect"] = time.perf_counter() - t0
        result.seconds = outcome.seconds
        if outcome.failure is not None:
            result.failure = FailureRecord.model_validate(outcome.failure.to_dict())
            return None
        output = outcome.output
        assert output is not None  # run_guarded gives an output or a failure
        result.detections = StoredBoxes.of(output)
        return output

    def _check_relations(self, unit: WorkUnit, source: Scene, follow: Scene, output: Any, operator: Any,
                         params: Any, result: UnitResult) -> None:
        """Every relation of the unit on (source, its output; mutant, its output), into
        ``result.relations``; a relation that raises is an ``oracle_error`` failure."""
        from lidarfuzz.operators.base import Relation
        from lidarfuzz.oracles.relations.base import Pair

        t0 = time.perf_counter()
        kind = Relation(unit.operator_relation) if unit.operator_relation else operator.relation
        pair = Pair(source, follow, (unit.source or StoredBoxes(None)).boxes(), output,
                    operator_relation=kind, transform=operator.transform(params), basis=_basis(operator))
        for spec in unit.relations:
            try:
                result.relations.append(OutcomeRecord.of(self.relation(spec)(pair)))
            except Exception as exc:  # a broken oracle is reported, and the campaign goes on
                result.failure = FailureRecord(kind="oracle_error", detail=str(spec.get("name", "")),
                                               message=f"relation {spec.get('name')}: {type(exc).__name__}: {exc}")
        result.timings["relations"] = time.perf_counter() - t0

    def _save(self, unit: WorkUnit, mutant: Scene) -> None:
        from lidarfuzz.io.kitti import write_kitti_frame

        root = Path(self.context.save_mutants or ".") / unit.subtask_name
        frame_id = unit.frame_id if unit.trial == 0 else f"{unit.frame_id}_t{unit.trial}"
        write_kitti_frame(root, mutant, frame_id, overwrite=True, durable=False, labelled_set=True)

    def close(self) -> None:
        if self._sut is not None:
            self._sut.close()
            self._sut = None
        if self._connection is not None:
            self._connection.close()
            self._connection = None
        if self._cache is not None:
            self._cache.close()
