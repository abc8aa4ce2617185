"""Server-sent events of a task's progress.

The stream polls the store (every :data:`POLL` seconds) and sends a ``progress`` event whenever
the task's counters, status or running subtask change — so any number of browsers can watch
one task, and a task that a CLI process runs is watched the same way. When the task ends
(done, failed, cancelled, or deleted) an ``end`` event with the final state closes the
stream. A comment line every :data:`KEEPALIVE` seconds keeps proxies from closing it.

Event data (JSON)::

    {"id": 3, "status": "running", "done": 12, "total": 40, "error": "",
     "running": {"id": 9, "label": "fog@3", "done": 2, "total": 10} | null,
     "subtasks": [{"id": 8, "label": "original", "status": "done", "done": 10, "total": 10}, ...],
     "heartbeat_at": "...", "started_at": "...", "finished_at": null, "loading": false}

``loading`` is true while the task runs and no unit of the run has finished yet: the system under
test is loading (a model can take many seconds). The web app's workers know it of the runs they
drive (:meth:`lidarfuzz.web.workers.TaskWorkers.loading`); without them (a task a CLI process
runs) it is read from the store: running, and no unit done.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator, Callable
from datetime import UTC
from typing import Any

from sqlalchemy import select

from lidarfuzz.campaign.tasks import subtask_label
from lidarfuzz.store.models import FrameResult, Status, Subtask, Task
from lidarfuzz.store.store import Store

POLL = 0.5
KEEPALIVE = 15.0
FINAL = (Status.DONE, Status.FAILED, Status.CANCELLED)


def iso(value: Any) -> str | None:
    """A stored time as ISO 8601 with its zone (SQLite returns them naive; they are UTC)."""
    if value is None:
        return None
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    return str(value.isoformat())


def progress_snapshot(store: Store, task_id: int,
                      loading: Callable[[int], bool] | None = None) -> dict[str, Any] | None:
    """A task's counters and state (None: no such task), read in one short transaction.

    Args:
        store: The campaign store.
        task_id: The task.
        loading: Whether the server's own run of a task has finished no unit yet (its workers'
            :meth:`~lidarfuzz.web.workers.TaskWorkers.loading`); None: running with no unit done.
    """
    with store.session() as s:
        task = s.execute(select(Task.id, Task.status, Task.done, Task.total, Task.error, Task.started_at,
                                Task.finished_at, Task.heartbeat_at, Task.worker).where(Task.id == task_id)).first()
        if task is None:
            return None
        subs = s.execute(select(Subtask.id, Subtask.name, Subtask.severity, Subtask.status, Subtask.done,
                                Subtask.total).where(Subtask.task_id == task_id).order_by(Subtask.id)).all()
        running = None
        if task.status == Status.RUNNING:
            # the subtask of the newest result: the operator running now
            latest = s.scalar(select(FrameResult.subtask_id).join(Subtask).where(Subtask.task_id == task_id)
                              .order_by(FrameResult.id.desc()).limit(1))
            running = next((sub for sub in subs if sub.id == latest), None)
            if running is not None and running.done >= running.total:
                running = next((sub for sub in subs if sub.done < sub.total), running)
    subtasks = [{"id": sub.id, "label": subtask_label(sub.name, sub.severity), "name": sub.name,
                 "severity": sub.severity, "status": Status(sub.status).value, "done": sub.done, "total": sub.total}
                for sub in subs]
    return {"id": task.id, "status": Status(task.status).value, "done": task.done, "total": task.total,
            "error": task.error, "worker": task.worker,
            "running": None if running is None else {"id": running.id, "label": subtask_label(running.name,
                                                                                              running.severity),
                                                     "done": running.done, "total": running.total},
            "subtasks": subtasks, "started_at": iso(task.started_at), "finished_at": iso(task.finished_at),
            "heartbeat_at": iso(task.heartbeat_at), "loading": _loading(task, loading)}


def _loading(task: Any, loading: Callable[[int], bool] | None) -> bool:
    """Whether ``task`` runs and its system under test is still loading (see the module's docstring)."""
    if task.status != Status.RUNNING:
        return False
    if loading is not None and loading(task.id):
        return True
    return bool(task.done == 0)


def _event(name: str, data: dict[str, Any]) -> str:
    return f"event: {name}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n"


async def progress_events(store: Store, task_id: int, disconnected: Callable[[], Any], *,
                          poll: float = POLL, keepalive: float = KEEPALIVE,
                          loading: Callable[[int], bool] | None = None) -> AsyncIterator[str]:
    """The ``text/event-stream`` lines of task ``task_id`` until it ends or the client leaves
    (``loading``: as :func:`progress_snapshot` takes it)."""
    from starlette.concurrency import run_in_threadpool

    last: Any = None
    last_sent = time.monotonic()
    yield f"retry: {int(poll * 2000)}\n\n"
    while True:
        snapshot = await run_in_threadpool(progress_snapshot, store, task_id, loading)
        if snapshot is None:
            yield _event("end", {"id": task_id, "status": "deleted"})
            return
        key = (snapshot["status"], snapshot["done"], snapshot["running"], snapshot["error"], snapshot["loading"],
               [(s["status"], s["done"]) for s in snapshot["subtasks"]])
        if key != last:
            last, last_sent = key, time.monotonic()
            yield _event("progress", snapshot)
        elif time.monotonic() - last_sent > keepalive:
            last_sent = time.monotonic()
            yield ": keep-alive\n\n"
        if Status(snapshot["status"]) in FINAL:
            yield _event("end", snapshot)
            return
        if await disconnected():
            return
        await asyncio.sleep(poll)


__all__ = ["POLL", "iso", "progress_events", "progress_snapshot"]
