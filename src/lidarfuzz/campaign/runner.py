"""Running a task: the one entry point ``lidarfuzz run`` / ``resume`` and the web app's workers
call, whatever the task's kind.

The task's kind is looked up in the table (:mod:`lidarfuzz.campaign.kinds`), and its
implementation run through the lifecycle every kind shares (:mod:`lidarfuzz.campaign.lifecycle`):
claimed, run with progress, heartbeat and cooperative cancel (``lidarfuzz cancel`` or the web
app sets the task's status in the store; the run looks at it twice a second and stops, keeping
what is done), and ended as done, cancelled, failed or pending again.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from lidarfuzz.campaign.executor import Executor
from lidarfuzz.campaign.kinds import kind_of
from lidarfuzz.campaign.lifecycle import (
    CancelledError,
    KindImplementation,
    ProgressEvent,
    RunOptions,
    RunOutcome,
    RunStats,
    drive,
    get_task,
    mark_running,
    recount,
)
from lidarfuzz.store.claims import claim_task
from lidarfuzz.store.models import Task, TaskClaim
from lidarfuzz.store.store import Store

#: What ``--executor`` accepts.
EXECUTORS = ("pool", "inline", "ray")


def make_executor(kind: str = "pool", *, workers: int | None = None, address: str | None = None,
                  actor_cpus: float = 1.0, actor_gpus: float | None = None) -> Executor:
    """The executor ``--executor`` names: ``pool`` (a local pool of ``workers`` processes),
    ``inline`` (this process) or ``ray`` (a Ray cluster at ``address`` with ``workers`` system
    actors of ``actor_cpus`` CPUs and ``actor_gpus`` GPUs each,
    :class:`~lidarfuzz.campaign.cluster.RayExecutor`).

    Raises:
        ValueError: ``kind`` is none of :data:`EXECUTORS`.
    """
    from lidarfuzz.campaign.executor import InlineExecutor, ProcessExecutor

    if kind == "inline":
        return InlineExecutor()
    if kind == "pool":
        return ProcessExecutor(workers)
    if kind == "ray":
        from lidarfuzz.campaign.cluster import RayExecutor

        return RayExecutor(address, actors=workers, cpus_per_actor=actor_cpus, gpus_per_actor=actor_gpus)
    raise ValueError(f"--executor: expected one of {', '.join(EXECUTORS)}, got {kind!r}")


def implementation(task: Task) -> KindImplementation:
    """The implementation of ``task``'s kind (see :mod:`lidarfuzz.campaign.kinds`)."""
    found: KindImplementation = kind_of(task).implementation()
    return found


def describe_plan(task: Task) -> str:
    """One line on what ``task`` runs, e.g. ``12 operator × severity subtasks``."""
    return implementation(task).describe(task)


def run_task(store: Store, task_id: int, *, executor: Executor | None = None, workers: int | None = None,
             progress: Callable[[ProgressEvent], None] | None = None,
             stop: threading.Event | None = None, wait: bool = False, take_over: bool = False,
             on_wait: Callable[[TaskClaim], object] | None = None) -> RunOutcome:
    """Run (or resume) task ``task_id`` to its end, committing every result as it is produced.

    Args:
        store: The campaign store.
        executor: Where units run (default: a :class:`~lidarfuzz.campaign.executor.ProcessExecutor`
            of ``workers`` processes; a kind that runs in this process ignores it).
        progress: Called after every committed result.
        stop: Set it to stop the run cleanly (as ``lidarfuzz cancel`` does from outside).
        wait, take_over, on_wait: When another process runs the task: wait for it, take its claim
            anyway, say whom it waits for (:func:`lidarfuzz.store.claims.claim_task`; by default
            :class:`~lidarfuzz.store.errors.TaskClaimedError` names it).
    """
    kind = implementation(get_task(store, task_id))
    with claim_task(store, task_id, wait=wait, take_over=take_over, on_wait=on_wait):  # one runner per task
        return drive(store, task_id, kind, RunOptions(executor, workers, progress, stop))


__all__ = ["EXECUTORS", "CancelledError", "ProgressEvent", "RunOutcome", "RunStats", "describe_plan",
           "implementation", "make_executor", "mark_running", "recount", "run_task"]
