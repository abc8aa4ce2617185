"""The table of task kinds: every kind of task the engine runs, one row each.

A row names the kind (what a campaign's ``kind:`` and ``lidarfuzz run --kind`` take), says in a
line what it does, and names the module that implements it — the hooks of
:class:`lidarfuzz.campaign.lifecycle.KindImplementation`: ``check_spec``, ``plan``, ``start``,
``describe`` and ``counted_below``. The lifecycle every kind shares (status, progress, heartbeat,
cancel, resume, errors) is :mod:`lidarfuzz.campaign.lifecycle`; creating a task
(:func:`lidarfuzz.campaign.tasks.create_task`) and running one
(:func:`lidarfuzz.campaign.runner.run_task`) look the kind up here and nowhere else.

A new kind is its module plus a row below. The module is imported when a task of its kind is
planned or run, not when this table is read: listing kinds (``lidarfuzz run --help``, a
campaign's validation) stays cheap, and the table depends on no kind.

Example:
    >>> [kind.name for kind in TASK_KINDS]
    ['mutation', 'guided', 'fuzz', 'structural', 'camera']
    >>> task_kind("guided").module
    'lidarfuzz.campaign.coverage_search'
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from lidarfuzz.errors import LidarfuzzError

DEFAULT_KIND = "mutation"


@dataclass(frozen=True)
class TaskKind:
    """One row of the table.

    Attributes:
        name: The kind's name.
        help: What a task of this kind does, in a line.
        module: The module implementing the kind's hooks.
        requires_operators: Its campaigns must list operators (a search's are an optional pool).
        consumes_logs: Its system is a sequence system replaying logs in order
            (:func:`lidarfuzz.suts.registry.create_sequence` builds it), not a per-frame one.
        modality: The sensor its data sets hold: ``lidar`` (point clouds) or ``camera`` (images,
            opened by :mod:`lidarfuzz.io.images`, tested on a steering system built by
            :func:`lidarfuzz.suts.registry.create_camera`).
        uses_executor: Its units run on the run's executor (a process pool, a Ray cluster); the
            others run in the driver's process, whatever ``--executor`` says.
    """

    name: str
    help: str
    module: str
    requires_operators: bool = False
    consumes_logs: bool = False
    modality: str = "lidar"
    uses_executor: bool = False

    def implementation(self) -> Any:
        """The implementing module (a :class:`~lidarfuzz.campaign.lifecycle.KindImplementation`)."""
        return importlib.import_module(self.module)


TASK_KINDS: tuple[TaskKind, ...] = (
    TaskKind("mutation", "operators × severities on every frame, detections compared by AP and relations",
             "lidarfuzz.campaign.mutation", requires_operators=True, uses_executor=True),
    TaskKind("guided", "DeepTest's greedy coverage-guided search on a learned SUT (neuron coverage) or any "
             "Python system (code coverage: --guide code --target CODE)", "lidarfuzz.campaign.coverage_search"),
    TaskKind("fuzz", "DeepHunter-style coverage-guided fuzzing loop on a learned SUT (neuron coverage) or any "
             "Python system (code coverage)", "lidarfuzz.campaign.coverage_search"),
    TaskKind("structural", "Neves et al.'s structural testing: field-test logs replayed in order through a sequence "
             "system under code coverage, discriminatory segments, generated logs (HGT, AVG, ...)",
             "lidarfuzz.campaign.structural", consumes_logs=True),
    TaskKind("camera", "DeepTest on a steering system: image transformations judged by Eq. 2 against MSE_orig, "
             "Eq. 3's filter, Table 7, and Algorithm 1's coverage-guided search (search: {budget: N})",
             "lidarfuzz.campaign.camera", modality="camera"),
)


class UnknownKindError(LidarfuzzError, ValueError):
    """A task kind that is not in the table."""


def kind_names() -> tuple[str, ...]:
    return tuple(kind.name for kind in TASK_KINDS)


def find_kind(name: str) -> TaskKind | None:
    """The row called ``name``, or None."""
    return next((kind for kind in TASK_KINDS if kind.name == name), None)


def task_kind(name: str) -> TaskKind:
    """The row called ``name``.

    Raises:
        UnknownKindError: No kind has that name (the message lists those that do).
    """
    kind = find_kind(name)
    if kind is None:
        raise UnknownKindError(f"unknown task kind {name!r}; choose one of {', '.join(kind_names())}")
    return kind


def kind_of(task: Any) -> TaskKind:
    """The row of a stored task."""
    return task_kind(task.options.kind)


__all__ = ["DEFAULT_KIND", "TASK_KINDS", "TaskKind", "UnknownKindError", "find_kind", "kind_names", "kind_of",
           "task_kind"]
