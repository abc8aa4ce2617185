"""Background workers of the web app: threads that run queued tasks through the campaign engine.

Each thread takes a task id from the queue and calls
:func:`lidarfuzz.campaign.runner.run_task` — the function ``lidarfuzz run`` and ``lidarfuzz
resume`` call — with a stop event. Stopping a task is what ``lidarfuzz cancel`` does (the
task's status in the store) plus setting that event, so a task stops within a second whether
this server or a CLI process runs it.

On start, unfinished tasks are queued again: pending ones, and running ones whose process is
gone (:func:`lidarfuzz.campaign.tasks.looks_alive`, the rule ``lidarfuzz resume`` applies).
A task interrupted because the server shuts down goes back to pending (it is resumed on the
next start); one a user stopped stays cancelled.

A server started while the previous one is still shutting down (a restart soon after Ctrl-C)
finds the task still running in a live process; that process then puts it back to pending, or
dies with it marked running. So the workers keep looking (every :data:`SWEEP_EVERY` seconds) for
such orphans — pending with :data:`~lidarfuzz.campaign.lifecycle.STOPPED_NOTE` or
:data:`~lidarfuzz.campaign.lifecycle.INTERRUPTED_NOTE`, or running in a process that is gone —
and queue them: a task running when the server stopped is always picked up.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
from dataclasses import dataclass, field

from sqlalchemy import select
from sqlalchemy.orm import load_only

from lidarfuzz.campaign.lifecycle import INTERRUPTED_NOTE, STOPPED_NOTE, ProgressEvent, StopSignal
from lidarfuzz.campaign.tasks import cancel_task, get_task, list_tasks, looks_alive
from lidarfuzz.store.errors import NotFoundError, TaskClaimedError
from lidarfuzz.store.models import Status, Task
from lidarfuzz.store.store import Store, StoreError

log = logging.getLogger("lidarfuzz.web")
SHUTDOWN_NOTE = STOPPED_NOTE  # the name earlier versions exported
SWEEP_EVERY = 2.0  # seconds between looks for orphaned tasks (see the module's docstring)
ORPHAN_NOTES = (STOPPED_NOTE, INTERRUPTED_NOTE)


@dataclass
class _Running:
    stop: StopSignal = field(default_factory=StopSignal)
    by_user: bool = False
    units: int = 0  # units this run committed (0: the system under test is still loading)


class TaskWorkers:
    """Threads running tasks of one store.

    Args:
        store: The campaign store.
        threads: Tasks run at once (0: none run; tasks only queue, e.g. for tests).
        processes: Worker processes of each task's pool (None: the CPU count), as ``lidarfuzz run
            --workers``.
        executor: Where units run, as ``lidarfuzz run --executor``: ``pool`` (a process pool per
            task), ``inline`` (the worker thread itself; tests, debugging) or ``ray`` (the Ray
            cluster at ``address``, connected to once when the threads start, so that tasks running
            at once share the connection).
    """

    def __init__(self, store: Store, *, threads: int = 1, processes: int | None = None, executor: str = "pool",
                 address: str | None = None, sweep_every: float = SWEEP_EVERY) -> None:
        self.store, self.threads, self.processes = store, max(0, threads), processes
        self.executor, self.address = executor, address
        self.sweep_every = sweep_every
        self._queue: queue.Queue[int | None] = queue.Queue()
        self._queued: set[int] = set()
        self._running: dict[int, _Running] = {}
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self._closing = threading.Event()

    # -- life cycle ----------------------------------------------------------------------
    def start(self) -> list[int]:
        """Start the threads and queue every unfinished task; returns the ids queued."""
        if self.threads and not self._threads and self.executor == "ray":
            self._connect_ray()
        if self.threads and not self._threads:
            for number in range(self.threads):
                thread = threading.Thread(target=self._loop, name=f"lidarfuzz-task-worker-{number}", daemon=True)
                thread.start()
                self._threads.append(thread)
            sweeper = threading.Thread(target=self._sweep_loop, name="lidarfuzz-task-sweeper", daemon=True)
            sweeper.start()
            self._threads.append(sweeper)
        resumed = []
        for task in reversed(list_tasks(self.store)):  # oldest first
            if task.status == Status.PENDING or (task.status == Status.RUNNING and not looks_alive(task)):
                self.submit(task.id)
                resumed.append(task.id)
        if resumed:
            log.info("queued unfinished task(s) %s", ", ".join(map(str, resumed)))
        return resumed

    def close(self, timeout: float = 30.0) -> None:
        """Stop running tasks (they go back to pending) and the threads."""
        self._closing.set()
        with self._lock:
            for running in self._running.values():
                running.stop.interrupt()  # the run ends as pending (STOPPED_NOTE), resumed on the next start
        for _ in range(self.threads):
            self._queue.put(None)
        for thread in self._threads:
            thread.join(timeout)
        self._threads.clear()

    # -- tasks ---------------------------------------------------------------------------
    def submit(self, task_id: int) -> None:
        """Queue a task (once; a task already queued or running is left alone)."""
        with self._lock:
            if task_id in self._queued or task_id in self._running:
                return
            self._queued.add(task_id)
        self._queue.put(task_id)

    def resumable(self, task: Task) -> bool:
        """Whether :meth:`resume` would queue ``task``: not done, not run by a live process, not queued here
        (cancelled, failed, or interrupted: pending or running with its process gone)."""
        if task.status == Status.DONE or looks_alive(task):
            return False
        with self._lock:
            running = self._running.get(task.id)
            queued = task.id in self._queued
        # a run told to stop a moment ago still finishes its unit: resume waits for it
        return not queued and (running is None or running.stop.is_set())

    def resume(self, task_id: int) -> Status:
        """Queue a cancelled, failed or interrupted task again (only units without a result run, as
        with ``lidarfuzz resume``); a done task, or one another process runs, is left alone."""
        with self._lock:
            stopping = task_id in self._running
        if stopping:  # stopped a moment ago: let its thread finish first
            self.wait_stopped(task_id)
        with self.store.session() as s:
            task = s.get(Task, task_id)
            if task is None:
                raise NotFoundError(f"no task {task_id}")
            if not self.resumable(task):
                return task.status
            task.status, task.error = Status.PENDING, ""
        self.submit(task_id)
        return Status.PENDING

    def sweep(self) -> list[int]:
        """Queue the orphans (see the module's docstring): tasks put back to pending by a process
        that stopped, and running tasks whose process is gone; returns the ids queued."""
        found = []
        with self.store.session() as s:  # only what the rule reads: this runs every few seconds
            tasks = list(s.scalars(select(Task).options(load_only(
                Task.id, Task.status, Task.error, Task.worker, Task.heartbeat_at)).where(
                Task.status.in_((Status.PENDING, Status.RUNNING))).order_by(Task.id)))
        for task in tasks:  # oldest first
            if self.is_active(task.id):
                continue
            orphan = (task.status == Status.PENDING and task.error in ORPHAN_NOTES) or (
                task.status == Status.RUNNING and not looks_alive(task))
            if orphan:
                self.submit(task.id)
                found.append(task.id)
        if found:
            log.info("picked up interrupted task(s) %s", ", ".join(map(str, found)))
        return found

    def loading(self, task_id: int) -> bool:
        """Whether this server runs ``task_id`` and no unit of this run has finished yet (the
        system under test loading)."""
        with self._lock:
            running = self._running.get(task_id)
            return running is not None and running.units == 0

    def is_active(self, task_id: int) -> bool:
        """Whether this server has the task queued or running."""
        with self._lock:
            return task_id in self._queued or task_id in self._running

    def stop(self, task_id: int) -> Status:
        """Cancel a task as ``lidarfuzz cancel`` does, and stop it at once if this server runs it."""
        status = cancel_task(self.store, task_id)
        with self._lock:
            self._queued.discard(task_id)
            running = self._running.get(task_id)
            if running is not None:
                running.by_user = True
                running.stop.set()
        return status

    def wait_stopped(self, task_id: int, timeout: float = 10.0) -> bool:
        """Wait until this server no longer runs ``task_id``; False on a timeout."""
        deadline = threading.Event()
        for _ in range(int(timeout / 0.05)):
            with self._lock:
                if task_id not in self._running:
                    return True
            deadline.wait(0.05)
        return False

    # -- the threads ---------------------------------------------------------------------
    def _claim(self, task_id: int) -> _Running | None:
        with self._lock:
            if task_id not in self._queued:  # stopped while queued
                return None
            self._queued.discard(task_id)
            running = self._running[task_id] = _Running()
            return running

    def _runnable(self, task_id: int) -> bool:
        try:
            task = get_task(self.store, task_id)
        except StoreError:
            return False  # deleted while queued
        return task.status == Status.PENDING or (task.status == Status.RUNNING and not looks_alive(task))

    def _sweep_loop(self) -> None:
        while not self._closing.wait(self.sweep_every):
            try:
                self.sweep()
            except Exception:  # a busy or closing store: the next sweep looks again
                log.debug("sweep failed", exc_info=True)

    def _loop(self) -> None:
        while True:
            task_id = self._queue.get()
            if task_id is None or self._closing.is_set():
                return
            running = self._claim(task_id)
            if running is None:
                continue
            try:
                if self._runnable(task_id):
                    self._run(task_id, running)
            except KeyboardInterrupt:  # Ctrl-C reached the run's worker processes: pending again (INTERRUPTED_NOTE)
                log.info("task %s interrupted; it resumes when the server starts again", task_id)
            except TaskClaimedError as exc:  # another process (a CLI resume) runs it: not a failure
                log.info("task %s is run by another process: %s", task_id, exc)
            except Exception:  # the task records its own failure; the worker keeps serving
                log.exception("task %s failed", task_id)
            finally:
                with self._lock:
                    self._running.pop(task_id, None)

    def _connect_ray(self) -> None:
        """Join the Ray cluster once for every task this server runs (each task's executor then
        finds Ray started and leaves it running).

        Raises:
            ClusterError: The store is SQLite, or the cluster cannot be reached.
            MissingDependencyError: Ray is not installed.
        """
        from lidarfuzz.campaign.cluster import ClusterError, import_ray, require_shared_store

        require_shared_store(self.store.url)
        ray = import_ray()
        if not ray.is_initialized():
            address = self.address or os.environ.get("RAY_ADDRESS") or "local"  # as RayExecutor: never a stray one
            try:
                ray.init(address=address, include_dashboard=False, log_to_driver=False, configure_logging=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                where = "a new local Ray" if address == "local" else address
                raise ClusterError(f"cannot reach the Ray cluster at {where}: "
                                   f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None

    def _run(self, task_id: int, running: _Running) -> None:
        from lidarfuzz.campaign.runner import make_executor, run_task

        def progress(_event: ProgressEvent) -> None:
            running.units += 1

        executor = make_executor(self.executor, workers=self.processes, address=self.address)
        outcome = run_task(self.store, task_id, executor=executor, stop=running.stop, progress=progress)
        log.info("task %s: %s", task_id, outcome.status.value)


__all__ = ["TaskWorkers"]
