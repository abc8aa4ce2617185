"""Running one generated test: operator chain → mutant → the SUT's output and activations → oracle.

A test is a seed frame and a chain of operators applied in order. Steps whose params are
known (the part of the chain a test inherits from its parent) are applied exactly; new
steps draw theirs from the generator the search hands in. The chain is stored as a
``sequence`` operator spec and its concrete params, so every test replays exactly through
the ordinary operator machinery (``lidarfuzz replay``).

A chain may hold steps that move the whole scene (equivariant operators: rotate_z, height_shift,
global_translate, global_flip, global_scale move points, boxes and map together). Such a test's
label is the seed's carried by the chain's composed transform (the ``sequence`` operator's
:meth:`~lidarfuzz.operators.compose.Compose.transform`, which a replay computes the same way), so
its oracle is equivariance; a chain that moves nothing keeps the relations for invariant operators.

One forward pass gives both the detections and the neuron values: the activation
recorder's hooks are on while the SUT runs ``detect_batch``, so coverage costs no second
pass. Nothing here assumes LiDAR except the validity check, which asks a
:class:`~lidarfuzz.scene.scene.Scene`'s objects to keep their points.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lidarfuzz.operators.base import Operator, Relation
from lidarfuzz.operators.compose import Compose, CompositeParams, Step
from lidarfuzz.operators.registry import from_spec
from lidarfuzz.store.contracts import FailureRecord, OutcomeRecord


@dataclass(frozen=True)
class ChainStep:
    """One operator of a test's chain: its spec and, once drawn, its concrete params."""

    spec: dict[str, Any]
    params: dict[str, Any] | None = None

    @property
    def name(self) -> str:
        return str(self.spec["name"])


@dataclass
class Evaluation:
    """What one test produced."""

    frame_id: str
    chain: list[ChainStep]
    scene: Any = None
    output: Any = None
    values: dict[str, NDArray[np.float32]] = field(default_factory=dict)  # one row per layer
    failure: FailureRecord | None = None
    relations: list[OutcomeRecord] = field(default_factory=list)
    valid: bool = True
    validity: str = ""
    seconds: float = 0.0
    #: invariant, or equivariant when a step moved the scene (``transform`` then maps seed → test)
    operator_relation: Relation = Relation.INVARIANT
    transform: NDArray[np.float64] | None = None

    @property
    def spec(self) -> dict[str, Any]:
        return {"name": Compose.name, "operators": [step.spec for step in self.chain]}

    @property
    def params(self) -> dict[str, Any]:
        steps = [Step(operator=s.name, params=s.params) for s in self.chain]
        return CompositeParams(steps=steps).model_dump(mode="json")

    @property
    def violated(self) -> list[OutcomeRecord]:
        return [r for r in self.relations if r.applicable and not r.holds]


def points_kept(source: Any, follow: Any, min_points: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Points inside each labelled object of ``source`` before and after a mutation (objects
    with fewer than ``min_points`` at first are left out). The follow-up's boxes are the same
    objects after the mutation: a step that moves the scene moves them with their points."""
    from lidarfuzz.scene.geometry import points_in_boxes

    boxes = source.boxes
    if len(boxes) == 0 or len(follow.boxes) != len(boxes):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    keep = boxes.has_geometry
    before = points_in_boxes(source.points.xyz, boxes.as_array()[keep]).sum(axis=0)
    after = points_in_boxes(follow.points.xyz, follow.boxes.as_array()[keep]).sum(axis=0)
    seen = before >= min_points
    return before[seen].astype(np.int64), after[seen].astype(np.int64)


class SearchEvaluator:
    """Runs tests of one data set through one SUT with coverage hooks and the relations.

    Args:
        dataset: Anything with ``load(frame_id)`` (a :mod:`lidarfuzz.io` data set).
        sut: A loaded system under test exposing its ``torch.nn.Module`` as ``module``.
        relations: Relation objects checked between a seed frame's output and a test's.
        recorder: An :class:`~lidarfuzz.coverage.ActivationRecorder` on ``sut.module``.
        keep_share: Validity: every object keeps at least this share of its points.
        min_points: Objects with fewer points in the seed frame are not checked for validity.
    """

    def __init__(self, dataset: Any, sut: Any, relations: Sequence[Any], recorder: Any, *,
                 keep_share: float = 0.5, min_points: int = 10, cache: int = 64) -> None:
        self.dataset, self.sut, self.relations, self.recorder = dataset, sut, list(relations), recorder
        self.keep_share, self.min_points = keep_share, min_points
        self._originals: OrderedDict[str, Evaluation] = OrderedDict()
        self._scenes: OrderedDict[str, Any] = OrderedDict()  # exact chains → mutated scene
        self._operators: dict[str, Operator[Any, Any, Any]] = {}
        self._cache = cache
        #: data-set figures the relations read (:attr:`~lidarfuzz.oracles.relations.base.Pair.reference`)
        self.reference: dict[str, float] = {}

    def motion(self, evaluation: Evaluation) -> None:
        """Mark a test whose chain moves the scene as equivariant, with the chain's composed
        transform (seed frame → test frame); such a test is invalid when a moving step exposes no
        transform (nothing could judge it)."""
        moving = [s.name for s in evaluation.chain if self.operator(s.spec).relation == Relation.EQUIVARIANT]
        if not moving:
            return
        chain = self.operator(evaluation.spec)
        evaluation.operator_relation = Relation.EQUIVARIANT
        evaluation.transform = chain.transform(chain.parse_params(evaluation.params))
        if evaluation.transform is None:
            evaluation.valid = False
            evaluation.validity = f"{sorted(set(moving))} moved the scene and exposed no transform to judge it by"

    def operator(self, spec: dict[str, Any]) -> Operator[Any, Any, Any]:
        import json

        key = json.dumps(spec, sort_keys=True)
        if key not in self._operators:
            self._operators[key] = from_spec(spec)
        return self._operators[key]

    def _forward(self, scenes: list[Any]) -> tuple[list[Any], list[dict[str, NDArray[np.float32]]], float,
                                                    list[FailureRecord | None]]:
        """Outputs, per-input coverage values and per-input failures of one pass: here one batched
        forward with the neuron hooks on (a failure fails the batch); a subclass may measure
        otherwise (:class:`lidarfuzz.search.code.CodeSearchEvaluator`: code coverage per input)."""
        start = time.perf_counter()
        self.recorder.clear()
        try:
            with self.recorder:
                outputs = self.sut.detect_batch(scenes)
        except Exception as exc:  # the SUT's crash is a result
            failure = FailureRecord(kind="crash", message=f"{type(exc).__name__}: {exc}")
            return [None] * len(scenes), [{} for _ in scenes], time.perf_counter() - start, [failure] * len(scenes)
        values = self.recorder.values()
        rows = [{name: array[i] for name, array in values.items()} for i in range(len(scenes))]
        return list(outputs), rows, time.perf_counter() - start, [None] * len(scenes)

    def check_validity(self, source: Evaluation, evaluation: Evaluation) -> None:
        """Mark a test invalid when an object of the seed frame kept less than ``keep_share`` of its
        points (a subclass for other samples judges validity its own way)."""
        before, after = points_kept(source.scene, evaluation.scene, self.min_points)
        lost = after < self.keep_share * before
        if lost.any() and evaluation.valid:
            evaluation.valid = False
            evaluation.validity = f"{int(lost.sum())} object(s) kept less than {self.keep_share:.0%} of their points"

    def original(self, frame_id: str) -> Evaluation:
        """The seed frame itself (cached)."""
        found = self._originals.get(frame_id)
        if found is not None:
            return found
        scene = self.dataset.load(frame_id)
        outputs, rows, seconds, failures = self._forward([scene])
        evaluation = Evaluation(frame_id, [], scene, outputs[0], rows[0], failures[0], seconds=seconds)
        self._originals[frame_id] = evaluation
        if len(self._originals) > self._cache:
            self._originals.popitem(last=False)
        return evaluation

    def _apply(self, frame_id: str, chain: Sequence[ChainStep],
               rng: np.random.Generator | None) -> tuple[Any, list[ChainStep]]:
        """The mutant of a chain; steps without params draw them from ``rng``, in order."""
        import json

        scene = self.original(frame_id).scene
        done: list[ChainStep] = []
        exact = 0
        while exact < len(chain) and chain[exact].params is not None:
            exact += 1
        for length in range(exact, 0, -1):  # the longest exactly known prefix seen before
            key = json.dumps([frame_id, [[s.spec, s.params] for s in chain[:length]]], sort_keys=True)
            if key in self._scenes:
                scene, done = self._scenes[key], list(chain[:length])
                break
        for step in chain[len(done):]:
            op = self.operator(step.spec)
            if step.params is not None:
                params = op.parse_params(step.params)
            else:
                if rng is None:
                    raise ValueError(f"step {step.name} has no params and no generator to draw them")
                params = op.sample(rng, scene)
            scene = op.apply(scene, params)
            done.append(ChainStep(step.spec, params.model_dump(mode="json")))
        key = json.dumps([frame_id, [[s.spec, s.params] for s in done]], sort_keys=True)
        self._scenes[key] = scene
        if len(self._scenes) > self._cache:
            self._scenes.popitem(last=False)
        return scene, done

    def mutants(self, frame_id: str, chains: Sequence[Sequence[ChainStep]],
                rngs: Sequence[np.random.Generator | None]) -> list[Evaluation]:
        """Tests of one seed frame, run through the SUT in one batch."""
        from lidarfuzz.oracles.relations.base import Pair

        source = self.original(frame_id)
        evaluations = []
        for chain, rng in zip(chains, rngs, strict=True):
            try:
                scene, done = self._apply(frame_id, chain, rng)
                evaluation = Evaluation(frame_id, done, scene)
                self.motion(evaluation)
            except Exception as exc:  # an operator failing on this frame is a finding, not a crash
                evaluation = Evaluation(frame_id, list(chain), None, valid=False, validity="operator error",
                                        failure=FailureRecord(kind="operator_error",
                                                              message=f"{type(exc).__name__}: {exc}"))
            evaluations.append(evaluation)
        runnable = [e for e in evaluations if e.scene is not None]
        if runnable:
            outputs, rows, seconds, failures = self._forward([e.scene for e in runnable])
            for evaluation, output, row, failure in zip(runnable, outputs, rows, failures, strict=True):
                evaluation.output, evaluation.values = output, row
                evaluation.seconds = seconds / len(runnable)
                evaluation.failure = failure
        for evaluation in runnable:
            self.check_validity(source, evaluation)
            if evaluation.output is None or source.output is None or not evaluation.valid:
                continue
            # a valid test kept every object's points: its label is the seed's (the search's premise,
            # as DeepHunter's validity constraint), moved by the chain's transform when a step moved
            # the scene; so the relations for invariant operators are its oracle, or equivariance's
            pair = Pair(source.scene, evaluation.scene, source.output, evaluation.output,
                        operator_relation=evaluation.operator_relation, transform=evaluation.transform,
                        reference=self.reference)
            for relation in self.relations:
                if pair.operator_relation in relation.applies_to:
                    evaluation.relations.append(OutcomeRecord.of(relation(pair)))
        return evaluations
