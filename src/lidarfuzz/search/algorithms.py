"""Coverage-guided test generation: DeepTest's greedy search and a DeepHunter-style fuzz loop.

Both are step machines over a :class:`~lidarfuzz.search.evaluate.SearchEvaluator`: each
:meth:`Search.step` generates and runs some tests and returns :class:`TestRecord` s for
the caller to store; all state lives in :meth:`Search.state_dict` (JSON-able), so a
campaign commits the records and the state in one transaction and an interrupted search
resumes exactly where it stopped. Every random choice is drawn from a generator seeded
by ``SeedSequence([seed, test index, purpose])``: a search is a function of its seed.

**Guided** (DeepTest, Algorithm 1): seed frames on a stack, popped depth first; for the
frame in hand, pick T1 from the queue of transformations that raised coverage on it (or
at random), a random T2 and random parameters for both, apply them; when the new test
raises coverage, enqueue T1 and T2, update coverage and push the test on the stack; else
count a failed try, and move on after ``max_failed_tries``.

**Fuzz** (DeepHunter): a queue of seeds and accepted tests, one picked per step with
probability proportional to ``decay ** times_picked``; a batch of mutants of it (one
more random operator each); a mutant joins the queue when it is *valid* (every object
keeps ``keep_share`` of its points) and raises coverage. The relations are the bug
oracle: each violation gets a signature (relation, operator families, class, range bin);
a new signature is minimised — operators dropped and severities lowered while the same
violation persists — and becomes a finding; a known one only counts.

**Scene-moving operators** (equivariant: rotate_z, height_shift, global_translate, global_flip,
global_scale) may join the pool when listed: they move points, boxes and map together, so a
test's objects keep their points (the validity constraint reads each object in its moved box)
and its label is the seed's carried by the chain's composed transform. A test with a moving
step is judged by equivariance (the seed's detections, moved by that transform, found in the
test's output and nothing invented there) instead of the relations that compare boxes in place;
a chain without one keeps them. A moving operator's severity is drawn only up to the highest it
is meant to be harmless at (its ``harmless_up_to``: 2 for global_translate, 1 for global_scale),
so every test stays one a correct system must pass. They stay out of :data:`DEFAULT_OPERATORS`
(opt-in), by measurement: a guided search of 200 tests on 12 frames of the built-in world with
pillars found no violation with the default pool (0 of 116 valid tests), and with rotate_z,
height_shift, global_translate and global_flip added, 4 of 86 valid moved tests broke equivariance
(6 findings), nearly all objects a rotation carried out of the camera's view, which pillars does
not read (``fov_only``); the equivariance config's ``max_truncation`` leaves such objects out.

**Code coverage** may guide either search instead of neurons, for any Python system: the criteria
``code_nodes`` and ``code_edges`` with ``targets`` naming the code to cover (``guide: code`` is
``code_edges`` with both criteria); see :mod:`lidarfuzz.search.code`.
"""

from __future__ import annotations

import base64
import itertools
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from lidarfuzz.operators.base import Relation
from lidarfuzz.operators.registry import available, get
from lidarfuzz.search.evaluate import ChainStep, Evaluation, SearchEvaluator
from lidarfuzz.store.contracts import ViolationRecord

#: Operators of the default pool, one or more per family; none moves the frame (moving ones are
#: opt-in, see the module docstring). Degrading ones are kept honest by the validity constraint
#: (every object keeps ``keep_share`` of its points), so an object found before a valid test must be
#: found after it (the relations' premise).
DEFAULT_OPERATORS = (
    "gaussian_noise_addition", "uniform_noise_addition", "uniform_point_deletion", "random_region_point_deletion",
    "intensity_scaling", "region_intensity_scaling", "outside_roi_scatter", "gaussian_jitter", "beam_missing",
    "fog", "rain", "snow", "intensity_quantisation", "crosstalk",
)

#: Range bins (metres) of finding signatures.
RANGE_BINS = (0.0, 20.0, 40.0)


class SearchConfig(BaseModel):
    """How a coverage-guided search runs (stored with the task)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["guided", "fuzz"] = "guided"
    operators: tuple[str, ...] = DEFAULT_OPERATORS
    max_severity: int = Field(5, ge=1, le=5, description="severities are drawn from 1..max_severity")
    budget: int = Field(200, ge=1, description="tests to generate (seed frames not counted)")
    criteria: tuple[str, ...] = ("nc:0.2", "kmnc:10", "nbc", "snac", "tknc:2", "tknp:2")
    guide: str = Field("nc", description="the criterion whose increase accepts a test")
    targets: tuple[str, ...] = Field((), description="code criteria: the code to cover (pkg.module, "
                                     "pkg.module:Class, pkg.module:function)")
    max_failed_tries: int = Field(5, ge=0, description="guided: failed tries before the next frame")
    max_chain: int = Field(6, ge=1, description="most operators in one test's chain")
    batch: int = Field(4, ge=1, description="fuzz: mutants per picked seed (one forward pass)")
    decay: float = Field(0.8, gt=0.0, le=1.0, description="fuzz: selection weight is decay ** times picked")
    keep_share: float = Field(0.5, ge=0.0, le=1.0, description="validity: share of its points every object keeps")
    minimise: bool = True
    minimise_budget: int = Field(12, ge=0, description="fuzz: SUT runs spent minimising one new finding")

    @model_validator(mode="before")
    @classmethod
    def _code_guide(cls, data: Any) -> Any:
        """``guide: code`` means code_edges; a code guide without criteria tracks both code criteria;
        targets may be one comma-separated string (``--search targets=pkg.a,pkg.b``)."""
        if not isinstance(data, dict):
            return data
        data = dict(data)
        if data.get("guide") == "code":
            data["guide"] = "code_edges"
        if str(data.get("guide", "")).startswith("code_") and "criteria" not in data:
            data["criteria"] = ("code_nodes", "code_edges")
        if isinstance(data.get("targets"), str):
            data["targets"] = tuple(t.strip() for t in data["targets"].split(",") if t.strip())
        return data

    @field_validator("criteria")
    @classmethod
    def _known_criteria(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        from lidarfuzz.coverage.criteria import parse_spec
        from lidarfuzz.search.code import is_code_criterion, make_code_criteria

        code = [spec for spec in value if is_code_criterion(spec)]
        make_code_criteria(code)  # a value after a code criterion is an error
        # CoverageError is a ValueError: pydantic names the field
        names = [spec.split(":")[0].strip().lower() if spec in code else parse_spec(spec)[0] for spec in value]
        if len(set(names)) != len(names):
            raise ValueError(f"a criterion is listed twice in {list(value)}")
        if code and len(code) != len(value):
            raise ValueError(f"code criteria {code} and neuron criteria cannot be mixed in one search")
        return value

    @model_validator(mode="after")
    def _guide_is_tracked(self) -> SearchConfig:
        names = [c.split(":")[0].strip().lower() for c in self.criteria]
        if self.guide not in names:
            raise ValueError(f"guide {self.guide!r} must be one of the criteria {names}")
        if self.code and not self.targets:
            raise ValueError("targets: code criteria need the code to cover, e.g. targets=lidarfuzz.suts.classic "
                             "(--target on the command line)")
        if self.targets and not self.code:
            raise ValueError(f"targets: only code criteria (code_nodes, code_edges) read targets, not {names}")
        return self

    @property
    def code(self) -> bool:
        """Whether the search is guided by code coverage (its criteria are code criteria)."""
        return any(c.split(":")[0].strip().lower().startswith("code_") for c in self.criteria)

    @field_validator("operators")
    @classmethod
    def _known(cls, names: tuple[str, ...]) -> tuple[str, ...]:
        known = available()
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ValueError(f"unknown operator(s) {unknown}; see `lidarfuzz operators`")
        if not names:
            raise ValueError("the search needs at least one operator")
        unjudged = [n for n in names if known[n].relation == Relation.EQUIVARIANT and known[n].harmless_up_to < 1]
        if unjudged:
            raise ValueError(f"operator(s) {unjudged} move the frame and are meant to be harmless at no severity, "
                             "so no test of theirs could be judged by equivariance; leave them out")
        return names


@dataclass
class TestRecord:
    """One test to store: what ran, what it did to coverage, what the oracle said."""

    index: int  # the test's number in the search (its trial); -1 for a seed frame
    evaluation: Evaluation
    parent: str | None
    role: str = "test"  # "seed", "test" or "minimised"
    accepted: bool = False
    gains: dict[str, int] = field(default_factory=dict)
    coverage: dict[str, float] = field(default_factory=dict)
    severities: list[int] = field(default_factory=list)
    findings: list[dict[str, Any]] = field(default_factory=list)
    variant: int = 0  # a test minimised for several signatures gives several minimised tests

    def params(self) -> dict[str, Any]:
        """The frame result's params: the chain (a ``sequence`` spec and its exact params) and the search's notes."""
        e = self.evaluation
        return {"operator": e.spec, "params": e.params, "severities": self.severities, "parent": self.parent,
                "role": self.role, "accepted": self.accepted, "valid": e.valid, "validity": e.validity,
                "gains": self.gains, "coverage": self.coverage}


def pack(value: Any) -> Any:
    """JSON-able form of nested dicts/lists holding numpy arrays."""
    if isinstance(value, np.ndarray):
        data = base64.b64encode(np.ascontiguousarray(value).tobytes()).decode()
        return {"__ndarray__": data, "dtype": str(value.dtype), "shape": list(value.shape)}
    if isinstance(value, dict):
        return {str(k): pack(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [pack(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def unpack(value: Any) -> Any:
    if isinstance(value, dict):
        if "__ndarray__" in value:
            array = np.frombuffer(base64.b64decode(value["__ndarray__"]), dtype=value["dtype"])
            return array.reshape(value["shape"]).copy()
        return {k: unpack(v) for k, v in value.items()}
    if isinstance(value, list):
        return [unpack(v) for v in value]
    return value


def range_bin(distance: float) -> str:
    if not np.isfinite(distance):
        return "?"
    edges = [*RANGE_BINS, float("inf")]
    for low, high in itertools.pairwise(edges):
        if low <= distance < high:
            return f"{low:.0f}-{high:.0f}m" if np.isfinite(high) else f">{low:.0f}m"
    return "?"


def families(chain: Sequence[ChainStep]) -> tuple[str, ...]:
    return tuple(sorted({get(step.name).family for step in chain}))


def signatures(evaluation: Evaluation) -> dict[tuple[str, ...], list[ViolationRecord]]:
    """The violations of a test grouped by signature (relation, operator families, class, range bin)."""
    out: dict[tuple[str, ...], list[ViolationRecord]] = {}
    fams = "+".join(families(evaluation.chain))
    for outcome in evaluation.violated:
        for violation in outcome.violations:
            key = (outcome.relation, fams, violation.cls, range_bin(violation.range_m))
            out.setdefault(key, []).append(violation)
    return out


def _rng(seed: int, index: int, purpose: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, index, purpose]))


class Search:
    """Shared state and bookkeeping of both searches (see the module docstring)."""

    def __init__(self, config: SearchConfig, seeds: Sequence[str], criteria: Sequence[Any], seed: int) -> None:
        self.config, self.seeds, self.criteria, self.seed = config, list(seeds), list(criteria), seed
        names = [c.name for c in self.criteria]
        if config.guide not in names:
            raise ValueError(f"guide criterion {config.guide!r} is not among the criteria {names}")
        self.next_index = 0
        self.seeded = False
        self.known: dict[str, dict[str, Any]] = {}  # signature → {"count", "test", "finding"}
        self.stats = {"tests": 0, "accepted": 0, "invalid": 0, "violating": 0, "findings": 0, "minimise_runs": 0}

    # -- coverage ---------------------------------------------------------------------
    def guide(self) -> Any:
        return next(c for c in self.criteria if c.name == self.config.guide)

    def cover(self, evaluation: Evaluation) -> dict[str, int]:
        """Update every criterion with one test; the new items each gained."""
        if not evaluation.values:
            return {c.name: 0 for c in self.criteria}
        batch = {name: row[None] for name, row in evaluation.values.items()}
        gains = {}
        for criterion in self.criteria:
            gains[criterion.name] = int(criterion.gain(batch)[0])
            criterion.update(batch)
        return gains

    def would_gain(self, evaluation: Evaluation) -> int:
        if not evaluation.values:
            return 0
        return int(self.guide().gain({name: row[None] for name, row in evaluation.values.items()})[0])

    def coverage(self) -> dict[str, float]:
        return {c.name: float(c.coverage()) for c in self.criteria}

    @property
    def finished(self) -> bool:
        return self.next_index >= self.config.budget

    # -- seeds ------------------------------------------------------------------------
    def run_seeds(self, evaluator: SearchEvaluator) -> list[TestRecord]:
        """The seed frames' own outputs and coverage (DeepTest's baseline); once."""
        records = []
        for frame_id in self.seeds:
            evaluation = evaluator.original(frame_id)
            gains = self.cover(evaluation)
            records.append(TestRecord(-1, evaluation, None, role="seed", accepted=True, gains=gains,
                                      coverage=self.coverage()))
        self.seeded = True
        return records

    # -- chains -----------------------------------------------------------------------
    def random_step(self, rng: np.random.Generator, name: str | None = None) -> tuple[ChainStep, int]:
        """A random operator of the pool (or ``name``) at a random severity; a scene-moving one no
        stronger than it is meant to be harmless at (its test is judged by equivariance)."""
        name = name or str(rng.choice(list(self.config.operators)))
        cls = get(name)
        top = self.config.max_severity
        if cls.relation == Relation.EQUIVARIANT:
            top = min(top, cls.harmless_up_to)
        severity = int(rng.integers(1, top + 1))
        return ChainStep(cls.at_severity(severity).spec()), severity

    def findings_of(self, evaluator: SearchEvaluator, record: TestRecord, minimise: bool) -> list[TestRecord]:
        """Findings of a valid test (new signatures), minimised when asked; extra records of minimised tests."""
        evaluation = record.evaluation
        if not evaluation.valid or not evaluation.violated:
            return []
        self.stats["violating"] += 1
        extra: list[TestRecord] = []
        for key, violations in signatures(evaluation).items():
            text = json.dumps(list(key))
            if text in self.known:
                self.known[text]["count"] += 1
                continue
            target = record
            if minimise and self.config.minimise and len(evaluation.chain) > 0:
                target = self.minimise(evaluator, record, key)
                if target is not record:
                    target.variant = len(extra)
                    extra.append(target)
            self.known[text] = {"count": 1, "test": record.index}
            self.stats["findings"] += 1
            first = violations[0]
            more = f" (and {len(violations) - 1} more)" if len(violations) > 1 else ""
            target.findings.append({
                "kind": key[0], "cls": key[2], "magnitude": float(len(violations)),
                "message": f"{first.message or key[0]}{more} [{' · '.join(key[1:])}]",
                "detail": {"signature": list(key), "violations": [v.dump() for v in violations], "test": record.index,
                           "minimised_from": record.index if target is not record else None,
                           "chain_length": len(target.evaluation.chain),
                           "original_chain_length": len(evaluation.chain)},
            })
        return extra

    def minimise(self, evaluator: SearchEvaluator, record: TestRecord, key: tuple[str, ...]) -> TestRecord:
        """Drop operators, then lower severities, while a violation with signature ``key`` persists."""
        frame_id = record.evaluation.frame_id
        chain, severities = list(record.evaluation.chain), list(record.severities)
        best: Evaluation | None = None
        runs = 0

        def persists(evaluation: Evaluation) -> bool:
            sigs = signatures(evaluation)
            # families shrink when operators are dropped: the relation, class and range must persist
            return evaluation.valid and any(k[0] == key[0] and k[2:] == key[2:] for k in sigs)

        i = 0
        while i < len(chain) and len(chain) > 1 and runs < self.config.minimise_budget:
            trial = chain[:i] + chain[i + 1:]
            runs += 1
            evaluation = evaluator.mutants(frame_id, [trial], [None])[0]
            if persists(evaluation):
                chain, severities, best = evaluation.chain, severities[:i] + severities[i + 1:], evaluation
            else:
                i += 1
        for i in range(len(chain)):
            while severities[i] > 1 and runs < self.config.minimise_budget:
                lower = severities[i] - 1
                step = ChainStep(get(chain[i].name).at_severity(lower).spec())
                trial = [*chain[:i], step, *chain[i + 1:]]
                runs += 1
                evaluation = evaluator.mutants(frame_id, [trial], [_rng(self.seed, record.index, 1000 + runs)])[0]
                if not persists(evaluation):
                    break
                chain, best = evaluation.chain, evaluation
                severities = [*severities[:i], lower, *severities[i + 1:]]
        self.stats["minimise_runs"] += runs
        if best is None:
            return record
        return TestRecord(record.index, best, parent=f"t:{record.index}", role="minimised",
                          severities=severities, coverage=self.coverage())

    # -- persistence --------------------------------------------------------------------
    def base_state(self) -> dict[str, Any]:
        return {"next_index": self.next_index, "seeded": self.seeded, "known": self.known, "stats": self.stats,
                "criteria": {c.name: pack(c.state_dict()) for c in self.criteria}}

    def load_base_state(self, state: dict[str, Any]) -> None:
        self.next_index, self.seeded = int(state["next_index"]), bool(state["seeded"])
        self.known, self.stats = dict(state["known"]), dict(state["stats"])
        for criterion in self.criteria:
            criterion.load_state_dict(unpack(state["criteria"][criterion.name]))

    def step(self, evaluator: SearchEvaluator) -> list[TestRecord]:  # pragma: no cover - abstract
        raise NotImplementedError

    def state_dict(self) -> dict[str, Any]:  # pragma: no cover - abstract
        raise NotImplementedError

    def load_state_dict(self, state: dict[str, Any]) -> None:  # pragma: no cover - abstract
        raise NotImplementedError


class GuidedSearch(Search):
    """DeepTest's Algorithm 1 (see the module docstring)."""

    def __init__(self, config: SearchConfig, seeds: Sequence[str], criteria: Sequence[Any], seed: int) -> None:
        super().__init__(config, seeds, criteria, seed)
        self.stack: list[dict[str, Any]] = [{"id": f"s:{f}", "frame": f, "chain": [], "severities": []}
                                            for f in reversed(self.seeds)]
        self.current: dict[str, Any] | None = None
        self.tqueue: list[str] = []
        self.failed = 0

    @property
    def finished(self) -> bool:
        return super().finished or (self.current is None and not self.stack and self.seeded)

    def step(self, evaluator: SearchEvaluator) -> list[TestRecord]:
        if not self.seeded:
            return self.run_seeds(evaluator)
        while self.current is None:
            if not self.stack:
                return []
            self.current, self.tqueue, self.failed = self.stack.pop(), [], 0
        node = self.current
        index = self.next_index
        rng = _rng(self.seed, index, 0)
        first = self.tqueue.pop(0) if self.tqueue else None
        step1, sev1 = self.random_step(rng, first)
        step2, sev2 = self.random_step(rng)
        chain = [ChainStep(s["spec"], s["params"]) for s in node["chain"]] + [step1, step2]
        evaluation = evaluator.mutants(node["frame"], [chain], [rng])[0]
        self.next_index += 1
        self.stats["tests"] += 1
        self.stats["invalid"] += int(not evaluation.valid)
        gained = self.would_gain(evaluation) > 0
        record = TestRecord(index, evaluation, node["id"], severities=[*node["severities"], sev1, sev2])
        record.gains = self.cover(evaluation)
        record.coverage = self.coverage()
        if gained:
            record.accepted = True
            self.stats["accepted"] += 1
            self.tqueue += [step1.name, step2.name]
            if len(evaluation.chain) + 2 <= self.config.max_chain:
                self.stack.append({"id": f"t:{index}", "frame": node["frame"],
                                   "chain": [{"spec": s.spec, "params": s.params} for s in evaluation.chain],
                                   "severities": record.severities})
        else:
            self.failed += 1
            if self.failed > self.config.max_failed_tries:
                self.current = None
        return [record, *self.findings_of(evaluator, record, minimise=False)]

    def state_dict(self) -> dict[str, Any]:
        return {**self.base_state(), "stack": self.stack, "current": self.current, "tqueue": self.tqueue,
                "failed": self.failed}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.load_base_state(state)
        self.stack, self.current = list(state["stack"]), state["current"]
        self.tqueue, self.failed = list(state["tqueue"]), int(state["failed"])


class FuzzSearch(Search):
    """A DeepHunter-style fuzz loop (see the module docstring)."""

    def __init__(self, config: SearchConfig, seeds: Sequence[str], criteria: Sequence[Any], seed: int) -> None:
        super().__init__(config, seeds, criteria, seed)
        self.queue: list[dict[str, Any]] = [{"id": f"s:{f}", "frame": f, "chain": [], "severities": [], "picked": 0}
                                            for f in self.seeds]
        self.rounds = 0

    def step(self, evaluator: SearchEvaluator) -> list[TestRecord]:
        if not self.seeded:
            return self.run_seeds(evaluator)
        rng = _rng(self.seed, self.rounds, 1)
        weights = np.array([self.config.decay ** entry["picked"] for entry in self.queue])
        entry = self.queue[int(rng.choice(len(self.queue), p=weights / weights.sum()))]
        entry["picked"] += 1
        self.rounds += 1
        size = min(self.config.batch, self.config.budget - self.next_index)
        chains, rngs, severities, indices = [], [], [], []
        base = [ChainStep(s["spec"], s["params"]) for s in entry["chain"]]
        for _ in range(size):
            index = self.next_index
            self.next_index += 1
            mutant_rng = _rng(self.seed, index, 0)
            step, severity = self.random_step(mutant_rng)
            keep = base if len(base) < self.config.max_chain else base[:-1]
            sev = entry["severities"] if len(base) < self.config.max_chain else entry["severities"][:-1]
            chains.append([*keep, step])
            rngs.append(mutant_rng)
            severities.append([*sev, severity])
            indices.append(index)
        evaluations = evaluator.mutants(entry["frame"], chains, rngs)
        records: list[TestRecord] = []
        for index, evaluation, sev in zip(indices, evaluations, severities, strict=True):
            self.stats["tests"] += 1
            self.stats["invalid"] += int(not evaluation.valid)
            record = TestRecord(index, evaluation, entry["id"], severities=sev)
            gained = evaluation.valid and self.would_gain(evaluation) > 0
            if evaluation.valid:
                record.gains = self.cover(evaluation)
            record.coverage = self.coverage()
            if gained:
                record.accepted = True
                self.stats["accepted"] += 1
                self.queue.append({"id": f"t:{index}", "frame": entry["frame"], "severities": sev, "picked": 0,
                                   "chain": [{"spec": s.spec, "params": s.params} for s in evaluation.chain]})
            records.append(record)
            records += self.findings_of(evaluator, record, minimise=True)
        return records

    def state_dict(self) -> dict[str, Any]:
        return {**self.base_state(), "queue": self.queue, "rounds": self.rounds}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.load_base_state(state)
        self.queue, self.rounds = list(state["queue"]), int(state["rounds"])


def make_search(config: SearchConfig, seeds: Sequence[str], criteria: Sequence[Any], seed: int) -> Search:
    cls = GuidedSearch if config.kind == "guided" else FuzzSearch
    return cls(config, seeds, criteria, seed)
