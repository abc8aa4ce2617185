"""How a task is laid out in the store, whatever its kind: the originals' subtask, the key and
label of every other subtask, the relations that apply to it, and the plan a task kind returns
when a task is created (:class:`KindPlan`, one :class:`SubtaskPlan` per subtask).
"""

from __future__ import annotations

import hashlib
import json
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

ORIGINAL = "original"
#: Subtasks holding a search's tests: named after the search, not an operator.
SEARCHES = ("guided", "fuzz")


def operator_key(spec: dict[str, Any] | None) -> str:
    """A stable key of an operator spec ("original" for none)."""
    if spec is None:
        return ORIGINAL
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:32]


def operator_stream(name: str, config: dict[str, Any] | None = None) -> int:
    """The seed stream of an operator's mutants (the ``operator_index`` of
    :func:`lidarfuzz.operators.base.seed_sequence`): keyed by the operator's name, and its explicit
    config when it has one, never by its place in the campaign, so adding or reordering operators
    leaves every other mutant unchanged and two tasks' mutants comparable. Severities of one operator
    share a stream (common random numbers: rotate_z@1 and @5 turn the same frames the same way
    round). 31 bits, so it fits every database's integer column.

        >>> operator_stream("fog") == operator_stream("fog") != operator_stream("rain")
        True
    """
    key = name if config is None else f"{name} {json.dumps(config, sort_keys=True)}"
    return zlib.crc32(key.encode("utf-8")) & 0x7FFFFFFF


def subtask_label(name: str, severity: int) -> str:
    """How reports name a subtask: ``fog@3``, ``fog (config)`` or ``original``; a structural task's
    logs by their own names (``base:greedy_edges``, ``greedy_edges+HGT``: no operator's name).

        >>> subtask_label("fog", 3), subtask_label("rotate_z", 0), subtask_label("greedy_edges+HGT", 0)
        ('fog@3', 'rotate_z (config)', 'greedy_edges+HGT')
        >>> subtask_label("guided", 0)
        'guided'
    """
    if name in (ORIGINAL, *SEARCHES) or not name.isidentifier():
        return name
    return f"{name}@{severity}" if severity else f"{name} (config)"


def select_frames(frame_ids: Sequence[str], count: int | None, order: str = "first", seed: int = 0) -> list[str]:
    """The frames a task tests: all of them, or ``count`` — the first ones, or (``order="random"``)
    drawn without replacement by a generator of ``seed``, kept in the data set's order (a worker
    then loads neighbouring frames together). The same seed draws the same frames.

    Example:
        >>> select_frames(["a", "b", "c", "d"], 2)
        ['a', 'b']
        >>> select_frames(["a", "b"], 5, "random")
        ['a', 'b']
    """
    ids = list(frame_ids)
    if count is None or count >= len(ids):
        return ids
    if order == "first":
        return ids[:count]
    if order != "random":
        raise ValueError(f"frame order {order!r}: choose first or random")
    chosen = np.random.default_rng(np.random.SeedSequence([int(seed), 0x46524D53])).choice(len(ids), count,
                                                                                           replace=False)
    return [ids[i] for i in sorted(int(i) for i in chosen)]


def relations_for_kind(relation: Any, choice: Any) -> list[dict[str, Any]]:
    """Relation specs to check on outputs whose operator relation kind (invariant, equivariant,
    degrading) is ``relation``: every applicable one for ``auto``, else the chosen ones (names or
    ``{name, config}``) that apply to that kind."""
    from lidarfuzz.oracles.relations.registry import for_operator, from_spec

    if choice == "auto":
        return [r.spec() for r in for_operator(relation)]
    chosen = [from_spec(item if isinstance(item, str) else item.model_dump()) for item in choice]
    return [r.spec() for r in chosen if relation in r.applies_to]


def relations_for(operator: Any, choice: Any) -> list[dict[str, Any]]:
    """Relation specs to check for ``operator`` (see :func:`relations_for_kind`), without those that
    assume a harmless mutation when the operator is not meant to be harmless at its setting
    (:func:`unchecked_relations` says which and why)."""
    from lidarfuzz.oracles.relations.registry import get

    specs = relations_for_kind(operator.relation, choice)
    if operator.harmless():
        return specs
    return [spec for spec in specs if not get(spec["name"]).assumes_harmless]


def unchecked_relations(operator: Any, choice: Any) -> dict[str, str]:
    """The relations :func:`relations_for` leaves out for ``operator``, each with the reason."""
    from lidarfuzz.oracles.relations.registry import get

    if operator.harmless():
        return {}
    if operator.harmless_up_to <= 0:
        why = f"{operator.name} is not meant to be harmless at any severity"
    else:
        why = (f"{operator.name} is meant to be harmless only up to severity {operator.harmless_up_to} "
               f"({operator.harmless_because})")
    return {spec["name"]: why for spec in relations_for_kind(operator.relation, choice)
            if get(spec["name"]).assumes_harmless}


def harmless_basis(operator: Any) -> str:
    """The "checked because …" of a harmlessness relation on ``operator``'s mutants."""
    return f"{operator.name} is meant to be harmless here: {operator.harmless_because}" if operator.harmless() \
        else ""


@dataclass(frozen=True)
class SubtaskPlan:
    """One subtask of a new task (the originals' subtask is planned for every kind).

    Attributes:
        name: The subtask's name (an operator's, or the kind's for a search).
        operator: The operator spec its units apply (what :func:`operator_key` hashes; None for
            the originals).
        units: How many frame results complete it.
        severity: 1–5, or 0 for an explicit config (or none).
        op_index: Its mutants' seed stream (:func:`operator_stream`; tasks planned before it was
            keyed by spec hold the operator's position in the campaign, and keep it).
        relations: Relation specs its results are checked against.
        unchecked: Relations that apply to its operator's kind but are not checked, with the reason
            (the operator is not meant to be harmless at this setting).
    """

    name: str
    operator: dict[str, Any] | None
    units: int
    severity: int = 0
    op_index: int = 0
    relations: list[dict[str, Any]] = field(default_factory=list)
    unchecked: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class KindPlan:
    """What a task kind adds to a new task: its subtasks after the originals, and options of its own
    (stored as :attr:`lidarfuzz.store.contracts.TaskOptions.kind_options`; the kind validates them).
    ``original_units``: how many results complete the originals' subtask (None: one per frame; a
    structural task's originals are its field-test logs, one result each)."""

    subtasks: list[SubtaskPlan]
    options: dict[str, Any] = field(default_factory=dict)
    original_units: int | None = None


__all__ = ["ORIGINAL", "KindPlan", "SubtaskPlan", "harmless_basis", "operator_key", "operator_stream",
           "relations_for", "relations_for_kind", "select_frames", "subtask_label", "unchecked_relations"]
