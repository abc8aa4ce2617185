"""The thesis's first experiment: people judge original/mutant pairs as same, similar or different.

Thesis, section 6.3.5 (experiment one) and Table 6-7: 100 point clouds drawn at random from KITTI
form the control set D; each operator mutates all 100, giving one experiment set per operator (RAR,
UIM and RIM left out: their mutants look no different). Ten raters, told what LiDAR data looks like
but not what the operators do, compare each mutant with its original (and the camera image) and
answer *same* (every object as clearly recognisable), *similar* (every object recognisable, some
blurred) or *different* (some object no longer recognisable). Table 6-7 sums the answers of all
raters per operator (1,000 per row); the operators are judged valid when same + similar exceeds 95%.

Here a *draw* reproduces that protocol on a finished (or running) LiDAR task:

* the frames: ``per_operator`` frames (the thesis's 100, or every frame when there are fewer)
  drawn without replacement by a generator seeded with ``seed`` (the task's seed by default),
  among the frames whose original and every chosen mutant (trial 0) exist; the same frames for
  every operator, as the thesis mutates the same control set with each;
* the strata: each operator × severity of the task (a subtask; the thesis has one setting per
  operator), without RAR, UIM and RIM unless they are asked for by name;
* the order: shuffled per rater (a generator seeded with the draw's seed and the rater's name),
  so the operators cannot be told from the sequence and no operator is always rated first or tired;
  the same rater always gets the same order, so a rater who leaves comes back to where they were.

The same seed, size and operators always give the same pairs. A pair is identified by the
mutant's frame result. Each rater rates a pair once; rating it again replaces the verdict (the
time of the first and of the latest verdict are both kept).

Where the thesis says nothing, this module adds what a careful experimenter would: Fleiss' kappa
(agreement among raters beyond chance, per operator and overall), which the thesis does not report.

Example:
    >>> draw = draw_pairs(store, 1, per_operator=20, seed=7)  # doctest: +SKIP
    >>> record_rating(store, 1, draw.pairs[0].id, "ana", "similar")  # doctest: +SKIP
    >>> tally(store, 1).rows[0].same_or_similar_share  # doctest: +SKIP
"""

from __future__ import annotations

import hashlib
from collections import Counter, defaultdict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import select

from lidarfuzz.campaign.lifecycle import get_task
from lidarfuzz.campaign.plan import ORIGINAL, SEARCHES, subtask_label
from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store.errors import NotFoundError
from lidarfuzz.store.models import FrameResult, Rating, Subtask
from lidarfuzz.store.store import Store

#: The answers, in the questionnaire's (and Table 6-7's) order.
VERDICTS: tuple[str, ...] = ("same", "similar", "different")
#: The thesis's pairs per operator (100 control frames, each mutated by every operator).
PER_OPERATOR = 100
#: The thesis left these out: their mutants show no visual difference (section 6.3.5).
THESIS_EXCLUDED: tuple[str, ...] = ("RAR", "UIM", "RIM")
#: The longest rater name kept.
RATER_LENGTH = 100
_STREAM = 67  # the draw's own seed stream (Table 6-7), apart from the campaign's operators'


@dataclass(frozen=True)
class RatingPair:
    """One original/mutant pair: the mutant's frame result and what made it (never shown to raters)."""

    id: int
    frame_id: str
    subtask_id: int
    operator: str
    severity: int
    label: str


@dataclass(frozen=True)
class Draw:
    """The pairs of one draw, in stratum order (operator by operator, frames sorted).

    Attributes:
        task_id: The task.
        seed: The draw's seed.
        per_operator: The frames asked for per operator.
        frames: The frames drawn (fewer than ``per_operator`` when the task has fewer).
        strata: The subtasks' labels rated (``uniform_noise@3``), in the task's order.
        excluded: The labels left out (the thesis's RAR, UIM, RIM, or not asked for).
        pairs: Every (stratum, frame) pair.
    """

    task_id: int
    seed: int
    per_operator: int
    frames: tuple[str, ...]
    strata: tuple[str, ...]
    excluded: tuple[str, ...]
    pairs: tuple[RatingPair, ...]

    def for_rater(self, rater: str) -> list[RatingPair]:
        """The pairs in ``rater``'s order: a permutation fixed by the draw's seed and the name."""
        name = check_rater(rater)
        # the name as its verdicts are kept (trimmed, case kept): the same rater, the same order
        digest = int.from_bytes(hashlib.sha256(name.encode("utf-8")).digest()[:8], "big")
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, _STREAM, digest]))
        return [self.pairs[i] for i in rng.permutation(len(self.pairs))]


def check_rater(rater: str) -> str:
    """The rater's name, trimmed; a one-line error naming the field when empty or too long."""
    name = (rater or "").strip()
    if not name:
        raise LidarfuzzError("rater: a name is needed (each rater's verdicts are kept apart)")
    if len(name) > RATER_LENGTH:
        raise LidarfuzzError(f"rater: at most {RATER_LENGTH} characters, got {len(name)}")
    return name


def check_verdict(verdict: str) -> str:
    """``verdict`` when it is one of :data:`VERDICTS`, else a one-line error naming the field."""
    value = (verdict or "").strip().lower()
    if value not in VERDICTS:
        raise LidarfuzzError(f"verdict: expected one of {', '.join(VERDICTS)}, got {verdict!r}")
    return value


def operator_aliases(name: str) -> tuple[str, ...]:
    """The registered operator's aliases (the thesis's abbreviations: ``UNA``), () when unknown."""
    from lidarfuzz.operators.registry import get

    try:
        return tuple(str(a) for a in getattr(get(name), "aliases", ()) or ())
    except Exception:  # a plugin operator no longer installed: no alias to show
        return ()


def _modality(kind: str) -> str:
    from lidarfuzz.campaign.kinds import find_kind

    found = find_kind(kind)
    return found.modality if found is not None else "lidar"


def _mutation_subtasks(subtasks: Iterable[Subtask]) -> list[Subtask]:
    """The subtasks that hold one operator's mutants (not the originals, not a search's tests)."""
    return [s for s in subtasks if s.name != ORIGINAL and s.name not in SEARCHES and s.operator]


def _chosen(subtasks: Sequence[Subtask], operators: Sequence[str] | None) -> tuple[list[Subtask], list[Subtask]]:
    """The strata to rate and those left out: by name or alias when ``operators`` is given, else
    every operator but the thesis's excluded ones."""
    if operators is None:
        excluded = {a.upper() for a in THESIS_EXCLUDED}
        keep = [s for s in subtasks if not excluded & {a.upper() for a in operator_aliases(s.name)}]
    else:
        wanted = {o.strip().lower().replace("-", "_") for o in operators if o.strip()}
        known: set[str] = set()
        keep = []
        for sub in subtasks:
            names = {sub.name.lower(), *(a.lower().replace("-", "_") for a in operator_aliases(sub.name))}
            known |= names
            if names & wanted:
                keep.append(sub)
        unknown = sorted(wanted - known)
        if unknown:
            offered = ", ".join(sorted({s.name for s in subtasks})) or "none"
            raise LidarfuzzError(f"operators: the task has no operator {unknown[0]!r} (it has: {offered})")
    left = [s for s in subtasks if s not in keep]
    return keep, left


def _usable_frames(store: Store, subtask_ids: Sequence[int]) -> tuple[list[str], dict[tuple[int, str], int]]:
    """The frames every one of ``subtask_ids`` has a trial-0 mutant of (the operator did not fail
    there), and each (subtask, frame)'s result id."""
    with store.session() as s:
        rows = s.execute(select(FrameResult.id, FrameResult.subtask_id, FrameResult.frame_id, FrameResult.failure)
                         .where(FrameResult.subtask_id.in_(subtask_ids), FrameResult.trial == 0)).all()
    ids: dict[tuple[int, str], int] = {}
    for result_id, subtask_id, frame_id, failure in rows:
        if failure is not None and failure.kind == "operator_error":  # no mutant to show
            continue
        ids[(subtask_id, frame_id)] = result_id
    frames = [f for f in sorted({f for _, f in ids}) if all((sid, f) in ids for sid in subtask_ids)]
    return frames, ids


def _original_frames(store: Store, task_id: int) -> set[str]:
    with store.session() as s:
        return set(s.scalars(select(FrameResult.frame_id).join(Subtask).where(
            Subtask.task_id == task_id, Subtask.name == ORIGINAL, FrameResult.trial == 0)))


def draw_pairs(store: Store, task_id: int, *, per_operator: int | None = None, seed: int | None = None,
               operators: Sequence[str] | None = None) -> Draw:
    """The pairs to rate for task ``task_id`` (see the module's docstring for the protocol).

    Args:
        store: The campaign store.
        task_id: A LiDAR mutation task.
        per_operator: Frames per operator (default :data:`PER_OPERATOR`, the thesis's 100).
        seed: The draw's seed (default: the task's seed).
        operators: Operator names or aliases to rate (default: all but the thesis's RAR, UIM, RIM).

    Raises:
        NotFoundError: No such task.
        LidarfuzzError: A camera task, a task without mutants, a size below 1 or an unknown operator.
    """
    task = get_task(store, task_id)
    if _modality(task.options.kind) != "lidar":
        raise LidarfuzzError(f"task {task_id} is a camera task: rating pairs are for LiDAR point clouds")
    size = PER_OPERATOR if per_operator is None else int(per_operator)
    if size < 1:
        raise LidarfuzzError(f"per_operator: at least 1 frame per operator, got {size}")
    seed = task.seed if seed is None else int(seed)
    subtasks = _mutation_subtasks(task.subtasks)
    if not subtasks:
        raise LidarfuzzError(f"task {task_id} has no operator's mutants to rate")
    keep, left = _chosen(subtasks, operators)
    if not keep:
        raise LidarfuzzError("operators: every operator of the task is one the thesis leaves out "
                             f"({', '.join(THESIS_EXCLUDED)}: no visual difference); name one to rate it anyway")
    frames, ids = _usable_frames(store, [s.id for s in keep])
    originals = _original_frames(store, task_id)
    frames = [f for f in frames if f in originals]
    rng = np.random.default_rng(np.random.SeedSequence([seed, _STREAM]))
    chosen = sorted(frames[i] for i in rng.choice(len(frames), size=min(size, len(frames)), replace=False))
    pairs = tuple(RatingPair(ids[(sub.id, f)], f, sub.id, sub.name, sub.severity, subtask_label(sub.name, sub.severity))
                  for sub in keep for f in chosen)
    return Draw(task_id, seed, size, tuple(chosen), tuple(subtask_label(s.name, s.severity) for s in keep),
                tuple(subtask_label(s.name, s.severity) for s in left), pairs)


def pair_of(store: Store, task_id: int, pair_id: int) -> RatingPair:
    """The pair ``pair_id`` of task ``task_id`` (a mutant's frame result), or NotFoundError."""
    with store.session() as s:
        row = s.execute(select(FrameResult.id, FrameResult.frame_id, Subtask).join(Subtask).where(
            FrameResult.id == pair_id, Subtask.task_id == task_id)).first()
    if row is None or row[2].name == ORIGINAL or row[2].name in SEARCHES:
        raise NotFoundError(f"task {task_id} has no pair {pair_id}")
    sub = row[2]
    return RatingPair(row[0], row[1], sub.id, sub.name, sub.severity, subtask_label(sub.name, sub.severity))


@dataclass(frozen=True)
class Verdict:
    """One rater's verdict on one pair."""

    pair_id: int
    rater: str
    verdict: str
    first_rated_at: datetime
    rated_at: datetime


def _utc(moment: datetime) -> datetime:
    """``moment`` with its zone: SQLite gives back the UTC times it was given without one."""
    return moment.replace(tzinfo=UTC) if moment.tzinfo is None else moment


def _verdict(row: Rating) -> Verdict:
    return Verdict(row.frame_result_id, row.rater, row.verdict, _utc(row.first_rated_at), _utc(row.rated_at))


def record_rating(store: Store, task_id: int, pair_id: int, rater: str, verdict: str) -> Verdict:
    """Keep ``rater``'s ``verdict`` on pair ``pair_id``, replacing an earlier one (whose first time is kept).

    Raises:
        NotFoundError: The task has no such pair.
        LidarfuzzError: An empty or overlong rater name, or a verdict not in :data:`VERDICTS`.
    """
    name, value = check_rater(rater), check_verdict(verdict)
    pair_of(store, task_id, pair_id)
    at = datetime.now(UTC)
    with store.session() as s:
        row = s.scalar(select(Rating).where(Rating.frame_result_id == pair_id, Rating.rater == name))
        if row is None:
            row = Rating(task_id=task_id, frame_result_id=pair_id, rater=name, verdict=value, first_rated_at=at,
                         rated_at=at)
            s.add(row)
        else:
            row.verdict, row.rated_at = value, at
        s.commit()
        return _verdict(row)


def ratings_of(store: Store, task_id: int, rater: str | None = None) -> list[Verdict]:
    """The task's verdicts (one rater's, or everyone's), in the order they were first given."""
    query = select(Rating).where(Rating.task_id == task_id)
    if rater is not None:
        query = query.where(Rating.rater == check_rater(rater))
    with store.session() as s:
        return [_verdict(r) for r in s.scalars(query.order_by(Rating.first_rated_at, Rating.id))]


# -- Table 6-7 --------------------------------------------------------------------------------
def fleiss_kappa(counts: Sequence[Sequence[int]]) -> float | None:
    """Fleiss' kappa of ``counts`` (one row per item, one column per category: how many raters put
    the item there); items with fewer than two raters are left out.

    With the same number of raters for every item this is Fleiss (1971); with differing numbers,
    each item's agreement P_i = (Σ_j n_ij² − n_i) / (n_i (n_i − 1)) is averaged over the items and
    the categories' shares p_j are taken over all their ratings (the usual generalisation).
    None when undefined: no item with two raters, or every rating in one category (P̄e = 1).

    Example (Wikipedia's, 10 items × 14 raters × 5 categories): κ ≈ 0.210.
        >>> round(fleiss_kappa([[1, 1], [2, 0]]), 3)  # P̄ = (0 + 1)/2, p = (3/4, 1/4), P̄e = 5/8
        -0.333
    """
    table = np.asarray([row for row in counts if sum(row) >= 2], dtype=np.float64)
    if table.size == 0:
        return None
    n = table.sum(axis=1)
    agreement = ((table ** 2).sum(axis=1) - n) / (n * (n - 1))
    shares = table.sum(axis=0) / n.sum()
    expected = float((shares ** 2).sum())
    if expected >= 1.0 - 1e-12:
        return None
    return (float(agreement.mean()) - expected) / (1.0 - expected)


@dataclass(frozen=True)
class TallyRow:
    """One row of Table 6-7: an operator at a severity (or ``all``), its verdicts summed over raters.

    Attributes:
        label: ``uniform_noise@3`` (``all`` for the total row).
        operator: The operator's name.
        alias: The thesis's abbreviation (``UNA``), "" when it has none.
        severity: The severity (0 for a config or the total row).
        same, similar, different: Verdicts, summed over raters and pairs.
        pairs: Pairs with at least one verdict.
        raters: Raters with at least one verdict in the row.
        kappa: Fleiss' kappa over the row's pairs (None: undefined, see :func:`fleiss_kappa`).
    """

    label: str
    operator: str
    alias: str
    severity: int
    same: int
    similar: int
    different: int
    pairs: int
    raters: int
    kappa: float | None

    @property
    def total(self) -> int:
        return self.same + self.similar + self.different

    def share(self, verdict: str) -> float | None:
        """The share of ``verdict`` among the row's verdicts (None without any)."""
        return getattr(self, verdict) / self.total if self.total else None

    @property
    def same_or_similar_share(self) -> float | None:
        """The thesis's criterion: (same + similar) / all; above 0.95 for every operator there."""
        return (self.same + self.similar) / self.total if self.total else None


@dataclass(frozen=True)
class RatingTally:
    """Table 6-7 of a task: one row per rated operator × severity and the total row."""

    task_id: int
    rows: tuple[TallyRow, ...]
    total: TallyRow
    raters: tuple[str, ...]

    @property
    def empty(self) -> bool:
        return self.total.total == 0


def _row(label: str, operator: str, alias: str, severity: int, verdicts: Sequence[Verdict]) -> TallyRow:
    counts = Counter(v.verdict for v in verdicts)
    per_pair: dict[int, Counter[str]] = defaultdict(Counter)
    for v in verdicts:
        per_pair[v.pair_id][v.verdict] += 1
    kappa = fleiss_kappa([[c[x] for x in VERDICTS] for c in per_pair.values()])
    return TallyRow(label, operator, alias, severity, counts["same"], counts["similar"], counts["different"],
                    len(per_pair), len({v.rater for v in verdicts}), kappa)


def tally(store: Store, task_id: int) -> RatingTally:
    """Table 6-7 of task ``task_id`` from every verdict given on it (every draw, every rater)."""
    get_task(store, task_id)
    verdicts = ratings_of(store, task_id)
    with store.session() as s:
        subs = {sid: (name, severity) for sid, name, severity in s.execute(
            select(Subtask.id, Subtask.name, Subtask.severity).where(Subtask.task_id == task_id)).all()}
        pair_subtask = dict(s.execute(select(FrameResult.id, FrameResult.subtask_id).join(
            Rating, Rating.frame_result_id == FrameResult.id).where(Rating.task_id == task_id)).all())
    grouped: dict[int, list[Verdict]] = defaultdict(list)
    for v in verdicts:
        grouped[pair_subtask[v.pair_id]].append(v)
    rows = []
    for sid in sorted(grouped):  # subtask ids follow the task's operator order
        name, severity = subs[sid]
        alias = next(iter(operator_aliases(name)), "")
        rows.append(_row(subtask_label(name, severity), name, alias, severity, grouped[sid]))
    total = _row("all", "", "", 0, verdicts)
    return RatingTally(task_id, tuple(rows), total, tuple(sorted({v.rater for v in verdicts}, key=str.casefold)))


def tally_dict(result: RatingTally) -> dict[str, Any]:
    """The tally as JSON: ``{"task_id", "raters", "rows": [...], "total": {...}}``; each row with its
    counts, shares (None without verdicts) and kappa."""
    def row(r: TallyRow) -> Mapping[str, Any]:
        return {"label": r.label, "operator": r.operator, "alias": r.alias, "severity": r.severity,
                "same": r.same, "similar": r.similar, "different": r.different, "total": r.total,
                "shares": {v: r.share(v) for v in VERDICTS}, "same_or_similar": r.same_or_similar_share,
                "pairs": r.pairs, "raters": r.raters, "kappa": r.kappa}

    return {"task_id": result.task_id, "raters": list(result.raters), "rows": [row(r) for r in result.rows],
            "total": row(result.total)}


__all__ = ["PER_OPERATOR", "THESIS_EXCLUDED", "VERDICTS", "Draw", "RatingPair", "RatingTally", "TallyRow", "Verdict",
           "check_rater", "check_verdict", "draw_pairs", "fleiss_kappa", "operator_aliases", "pair_of", "ratings_of",
           "record_rating", "tally", "tally_dict"]
