"""DeepTest's erroneous behaviours as the paper counts them: Eq. 2 per mutant, Eq. 3 per transformation, Table 7.

Tian et al. (ICSE 2018) relax the metamorphic relation to Eq. 2, ``(ŷ_t − y)² ≤ λ · MSE_orig``
with ``MSE_orig`` the system's mean squared error on the *original data set*, and count a
violation as an erroneous behaviour only for transformations that pass Eq. 3,
``|MSE_(trans, param) − MSE_orig| ≤ ε`` (a transformation whose error moves far from the
originals' may change what the right answer is). Their Table 7 counts erroneous behaviours for
λ = 1 … 10 and ε = 0.01 … 0.05.

Here a transformation is one operator at one severity (or explicit config), i.e. one subtask;
its ``MSE_(trans, param)`` is the mean squared centre error over every object its mutants'
detections matched; a mutant (one frame, one trial) is one erroneous behaviour at λ when any of
its objects' squared error exceeds λ · MSE_orig. The inputs are the ``stats`` that
:class:`~lidarfuzz.oracles.relations.detection.DeepTestTolerance` stores with each outcome.

The grid: λ = 1 … 10 as in Table 7; ε = the paper's 0.01 … 0.05 and 0.1, 0.2, 0.5, 1, 2 (errors
here are in m², so a system's MSE_orig may sit on another scale than a steering angle's), plus an
unfiltered column (no ε filter, as the paper reports composite transformations).

Example:
    >>> a = transformation_errors([({"mse_orig": 0.5, "mse_orig_from": "data set", "lambda": 2.0,
    ...                              "epsilon": 0.25, "squared_errors": [0.25, 1.5]}, False)], lambdas=(1.0, 2.0))
    >>> a.mse, a.erroneous  # (0.25 + 1.5) / 2; 1.5 > 1 × 0.5 and 1.5 > 2 × 0.5
    (0.875, (1, 1))
    >>> table = erroneous_table([a], epsilons=(0.25, 0.5))
    >>> table.counts  # |0.875 − 0.5| = 0.375: kept by ε = 0.5 only
    ((0, 1), (0, 1))
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

#: λ rows of the table (DeepTest's Table 7).
LAMBDAS: tuple[float, ...] = tuple(float(k) for k in range(1, 11))
#: ε columns of the table: the paper's five, then wider ones for errors in m².
EPSILONS: tuple[float, ...] = (0.01, 0.02, 0.03, 0.04, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)


def _number(value: Any) -> float:
    """A stored figure as a float: JSON keeps an undefined one (NaN) as null."""
    return math.nan if value is None else float(value)


def keeps(mse_transformation: float, mse_orig: float, epsilon: float) -> bool:
    """DeepTest's Eq. 3: ``|MSE_(trans, param) − MSE_orig| <= ε`` (False when either is undefined)."""
    return abs(mse_transformation - mse_orig) <= epsilon  # NaN compares False


@dataclass(frozen=True)
class TransformationErrors:
    """``deeptest_tolerance`` over one transformation's mutants.

    Attributes:
        mse_orig: MSE_orig the outcomes were judged against (NaN when they disagree or none has one).
        mse_orig_from: ``data set`` (the campaign's MSE_orig) or ``frame`` (each frame's own error
            stood in: a task run before MSE_orig was passed, or a search; no ε filter then).
        mse: ``MSE_(trans, param)``: mean squared error over every matched object of the mutants.
        objects: How many objects that mean is over.
        mutants: Mutants checked.
        violated: Mutants violating Eq. 2 at the configured λ (the findings).
        lambdas: The λ grid.
        erroneous: Per λ of the grid, mutants with an object above λ · MSE_orig.
        configured_lambda: The relation's λ.
        configured_epsilon: The relation's ε.
        filtered: Whether Eq. 3 applies at all: the paper does not filter composite transformations
            (rain, fog, a search's chains), whose violations count at every ε.
    """

    mse_orig: float
    mse_orig_from: str
    mse: float
    objects: int
    mutants: int
    violated: int
    lambdas: tuple[float, ...]
    erroneous: tuple[int, ...]
    configured_lambda: float
    configured_epsilon: float
    filtered: bool = True

    def kept_at(self, epsilon: float) -> bool:
        """Whether Eq. 3 keeps this transformation at ``epsilon`` (never with a per-frame MSE_orig;
        always when it is not filtered)."""
        if self.mse_orig_from != "data set":
            return False
        return not self.filtered or keeps(self.mse, self.mse_orig, epsilon)

    @property
    def kept(self) -> bool:
        """Whether Eq. 3 keeps this transformation at the configured ε."""
        return self.kept_at(self.configured_epsilon)

    def to_dict(self) -> dict[str, Any]:
        return {"mse_orig": self.mse_orig, "mse_orig_from": self.mse_orig_from, "mse": self.mse,
                "objects": self.objects, "mutants": self.mutants, "violated": self.violated,
                "lambdas": list(self.lambdas), "erroneous": list(self.erroneous),
                "configured_lambda": self.configured_lambda, "configured_epsilon": self.configured_epsilon,
                "filtered": self.filtered, "kept": self.kept}


def transformation_errors(outcomes: Iterable[tuple[Mapping[str, Any], bool]], *,
                          lambdas: Sequence[float] = LAMBDAS) -> TransformationErrors | None:
    """One transformation's figures from its ``deeptest_tolerance`` outcomes, each given as
    (``stats``, ``holds``); None when none carries per-object errors (a task stored before they were)."""
    mse_origs: set[float] = set()
    origins: set[str] = set()
    total = 0.0
    objects = mutants = violated = 0
    erroneous = [0] * len(lambdas)
    configured = (math.nan, math.nan)
    filtered = True
    for stats, holds in outcomes:
        if "squared_errors" not in stats:
            continue
        errors = [float(e) for e in stats["squared_errors"]]
        mse_orig = _number(stats.get("mse_orig"))
        mutants += 1
        violated += int(not holds)
        total += sum(errors)
        objects += len(errors)
        mse_origs.add(mse_orig)
        origins.add(str(stats.get("mse_orig_from", "frame")))
        configured = (_number(stats.get("lambda")), _number(stats.get("epsilon")))
        filtered = filtered and bool(stats.get("filtered", True))
        worst = max(errors, default=-math.inf)
        for i, lam in enumerate(lambdas):
            erroneous[i] += int(worst > lam * mse_orig)  # NaN limit: never erroneous, as the relation
    if mutants == 0:
        return None
    origin = "data set" if origins == {"data set"} else "frame"
    one = next(iter(mse_origs)) if len(mse_origs) == 1 and origin == "data set" else math.nan
    return TransformationErrors(one, origin, total / objects if objects else math.nan, objects, mutants, violated,
                                tuple(float(x) for x in lambdas), tuple(erroneous), *configured, filtered=filtered)


@dataclass(frozen=True)
class ErroneousTable:
    """DeepTest's Table 7 for one task: erroneous behaviours per λ (rows) and ε (columns).

    Attributes:
        mse_orig: The data set's MSE_orig (NaN when the transformations disagree on it).
        lambdas: Row values.
        epsilons: Column values.
        counts: ``counts[i][j]``: mutants erroneous at ``lambdas[i]`` over the transformations
            Eq. 3 keeps at ``epsilons[j]`` (empty when no transformation was judged against a
            data-set MSE_orig).
        unfiltered: Per λ, over every such transformation (no ε filter).
        kept: Per transformation (in the order given), per ε, whether Eq. 3 keeps it (never one
            judged against a per-frame MSE_orig).
        notes: What the reader must know (transformations left out, and why).
    """

    mse_orig: float
    lambdas: tuple[float, ...]
    epsilons: tuple[float, ...]
    counts: tuple[tuple[int, ...], ...]
    unfiltered: tuple[int, ...]
    kept: tuple[tuple[bool, ...], ...]
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        return {"mse_orig": self.mse_orig, "lambdas": list(self.lambdas), "epsilons": list(self.epsilons),
                "counts": [list(row) for row in self.counts], "unfiltered": list(self.unfiltered),
                "notes": list(self.notes)}


def erroneous_table(transformations: Sequence[TransformationErrors], *,
                    epsilons: Sequence[float] = EPSILONS) -> ErroneousTable:
    """Table 7 over ``transformations`` (all on the same λ grid): a cell sums, over the
    transformations Eq. 3 keeps at its ε, their mutants erroneous at its λ. Transformations
    judged against a per-frame MSE_orig are left out (and named in ``notes``)."""
    notes: list[str] = []
    usable = [t for t in transformations if t.mse_orig_from == "data set"]
    if len(usable) < len(transformations):
        notes.append(f"{len(transformations) - len(usable)} transformation(s) were judged against each frame's own "
                     "error (no data-set MSE_orig was passed to the relation) and are left out")
    values = {t.mse_orig for t in usable if not math.isnan(t.mse_orig)}
    mse_orig = next(iter(values)) if len(values) == 1 else math.nan
    if len(values) > 1:
        notes.append("the transformations were judged against different MSE_orig values; each is filtered by its own")
    lambdas = usable[0].lambdas if usable else tuple(LAMBDAS)
    if any(t.lambdas != lambdas for t in usable):
        raise ValueError("erroneous_table: every transformation needs the same λ grid")
    kept = tuple(tuple(t.kept_at(eps) for eps in epsilons) for t in transformations)
    rows = range(len(lambdas)) if usable else range(0)  # no transformation to count: no table, only the notes
    counts = tuple(tuple(sum(t.erroneous[i] for t, k in zip(transformations, kept, strict=True) if k[j])
                         for j in range(len(epsilons))) for i in rows)
    unfiltered = tuple(sum(t.erroneous[i] for t in usable) for i in rows)
    undefined = sum(1 for t in usable if math.isnan(t.mse) and t.filtered)
    if undefined:
        notes.append(f"{undefined} transformation(s) had no matched object in any mutant (no MSE): never kept")
    return ErroneousTable(mse_orig, tuple(float(x) for x in lambdas), tuple(float(x) for x in epsilons), counts,
                          unfiltered, kept, tuple(notes))


__all__ = ["EPSILONS", "LAMBDAS", "ErroneousTable", "TransformationErrors", "erroneous_table", "keeps",
           "transformation_errors"]
