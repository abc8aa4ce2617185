"""The life of a task, the same for every kind: claimed, running (progress, heartbeat, cancel),
then done, cancelled, failed or back to pending — and what a kind implements to take part.

A task kind (:mod:`lidarfuzz.campaign.kinds` lists them) plans its subtasks and runs its units;
everything around that is here, once:

* status transitions: :func:`mark_running` claims a task (and :func:`recount` re-derives its
  counters from the stored results, so a resumed task goes on where the last one stopped);
  :func:`drive` ends it as done (with its summary), cancelled, failed (with the error) or, on
  Ctrl-C, pending again;
* liveness: a running task's worker writes a heartbeat (:class:`Watch`); :func:`looks_alive`
  tells a live task from one whose process died (``lidarfuzz resume`` and the web app's
  workers resume only the latter);
* data faults: a run that ends with units whose frames could not be read
  (:data:`~lidarfuzz.campaign.work.DATA_FAULT`) ends as failed, with its summary (the faults counted
  apart) and an error saying how many and what to do: restore the files and resume, which runs only
  those units again;
* cancelling is cooperative: :func:`cancel_task` sets the status in the store (from any
  process), and the running task's :class:`Watch` sees it within :data:`CHECK_EVERY` seconds
  and stops, keeping what is done.
"""

from __future__ import annotations

import os
import socket
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, Protocol

from sqlalchemy import func, select, update

from lidarfuzz.store.contracts import RunTimings, TaskSummary
from lidarfuzz.store.errors import NotFoundError, StoreError
from lidarfuzz.store.models import FrameResult, Model, Status, Subtask, Task
from lidarfuzz.store.store import Store

if TYPE_CHECKING:
    from lidarfuzz.campaign.executor import Executor
    from lidarfuzz.campaign.plan import KindPlan
    from lidarfuzz.campaign.spec import CampaignSpec

CHECK_EVERY = 0.5  # seconds between looks at the task's status (cancel) and heartbeats
STALE_AFTER = 30.0  # seconds without a heartbeat before a "running" task is taken as dead
HEARTBEAT_EVERY = 5.0  # seconds between heartbeats of a run's own thread (while a model loads too)
#: The error of a task that went back to pending because its run was stopped from inside its
#: process (the web app's server shutting down) or interrupted (Ctrl-C): it is resumed, not failed.
STOPPED_NOTE = "interrupted: the server stopped while it ran; it resumes when the server starts again"
INTERRUPTED_NOTE = "interrupted before it finished; resuming it runs only what is left"
#: How many data-fault messages :func:`data_fault_note` quotes.
QUOTED_FAULTS = 2


@dataclass(frozen=True)
class ProgressEvent:
    task_done: int
    task_total: int
    subtask_id: int
    label: str
    subtask_done: int
    subtask_total: int


@dataclass
class RunStats:
    """Where the time of one run went (seconds, summed over units; wall is elapsed)."""

    units: int = 0
    cached: int = 0
    failures: int = 0
    wall: float = 0.0
    sut: float = 0.0
    stages: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    store: float = 0.0  # committing results
    evaluate: float = 0.0  # AP and summaries at the end of subtasks

    def timings(self) -> RunTimings:
        return RunTimings(units=self.units, cached=self.cached, failures=self.failures, wall=self.wall,
                          sut=self.sut, stages=dict(self.stages), store=self.store, evaluate=self.evaluate)


@dataclass(frozen=True)
class RunOutcome:
    task_id: int
    status: Status
    stats: RunStats


class CancelledError(Exception):
    """The task was cancelled while running."""


class StopSignal(threading.Event):
    """A run's ``stop`` event that can also say "interrupted, not cancelled": after
    :meth:`interrupt` the run ends as pending with :data:`STOPPED_NOTE`, to be resumed (the web
    app's workers interrupt their runs when the server shuts down); after ``set()`` it is cancelled."""

    interrupted = False

    def interrupt(self) -> None:
        self.interrupted = True
        self.set()


def now() -> datetime:
    return datetime.now(UTC)


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


# -- finding tasks ----------------------------------------------------------------------
def task_row(session: Any, task_id: int) -> Task:
    """Task ``task_id`` in ``session``.

    Raises:
        NotFoundError: There is no such task.
    """
    task = session.get(Task, task_id)
    if task is None:
        raise NotFoundError(f"no task {task_id}")
    return task


def get_task(store: Store, task_id: int) -> Task:
    """A task with its data set, model and subtasks loaded."""
    with store.session() as s:
        task = task_row(s, task_id)
        task.dataset, task.model, list(task.subtasks)  # loaded before the session closes
        return task


def task_status(store: Store, task_id: int) -> Status:
    """A task's status alone (one column: loading the task with its subtasks costs milliseconds).

    Raises:
        NotFoundError: There is no such task.
    """
    with store.session() as s:
        status = s.scalar(select(Task.status).where(Task.id == task_id))
    if status is None:
        raise NotFoundError(f"no task {task_id}")
    return status


# -- liveness and cancelling ------------------------------------------------------------
def heartbeat_age(task: Task) -> float | None:
    """Seconds since the process running ``task`` last reported (None: it never did)."""
    moment = task.heartbeat_at
    if moment is None:
        return None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return (datetime.now(UTC) - moment).total_seconds()


def _process_gone(worker: str) -> bool:
    """True when ``worker`` (``host:pid``) names a process of this host that no longer exists."""
    host, _, pid = worker.rpartition(":")
    if host != socket.gethostname() or not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except OSError:  # exists, owned by someone else
        return False
    return False


def looks_alive(task: Task, stale_after: float = STALE_AFTER) -> bool:
    """Whether a process seems to be running ``task`` now: it is marked running, its worker
    reported within ``stale_after`` seconds, and (on this host) that process still exists.
    ``lidarfuzz resume`` and the web app's workers resume only tasks that do not look alive."""
    if task.status != Status.RUNNING:
        return False
    age = heartbeat_age(task)
    if age is None or age >= stale_after:
        return False
    return not _process_gone(task.worker)


def cancel_task(store: Store, task_id: int) -> Status:
    """Ask a task to stop: a running one stops at its next unit (what is done stays done)."""
    with store.session() as s:
        task = task_row(s, task_id)
        if task.status in (Status.DONE, Status.FAILED, Status.CANCELLED):
            return task.status
        task.status = Status.CANCELLED
        for sub in task.subtasks:  # at once, not when the run notices: a page reading it now sees no "running"
            if sub.status == Status.RUNNING and sub.done < sub.total:
                sub.status = Status.PENDING
        return task.status


class Watch:
    """A running task's look-out: raises :class:`CancelledError` once the task is cancelled (in
    the store, or by ``stop`` in this process). Cheap to call after every unit: it reads the
    task's status at most every :data:`CHECK_EVERY` seconds, one query on a connection of its
    own. The heartbeat is :class:`Heartbeat`'s (every run has one): writing it here too, twenty
    times more often than a stale run is judged, cost a transaction per look."""

    def __init__(self, store: Store, task_id: int, stop: threading.Event | None) -> None:
        self.store, self.task_id, self.stop = store, task_id, stop
        self._last = time.monotonic()
        self._status = select(Task.status).where(Task.id == task_id)
        self._connection: Any = None

    def check(self) -> None:
        if self.stop is not None and self.stop.is_set():
            raise CancelledError
        moment = time.monotonic()
        if moment - self._last < CHECK_EVERY:
            return
        self._last = moment
        if self._connection is None:
            self._connection = self.store.engine.connect()
        try:
            status = self._connection.execute(self._status).scalar()
            self._connection.rollback()  # end the read transaction: never hold a snapshot open
        except Exception as exc:
            failed = self.store.failure(exc)
            if failed is not None and failed is not exc:
                raise failed from exc
            raise
        if status == Status.CANCELLED:
            raise CancelledError

    def close(self) -> None:
        if self._connection is not None:
            self._connection.close()
            self._connection = None


class Heartbeat:
    """A thread writing a running task's heartbeat every :data:`HEARTBEAT_EVERY` seconds, so a run
    whose first unit is slow (a model loading) still looks alive to ``lidarfuzz resume`` and to
    another server's workers, which take over only tasks that do not."""

    def __init__(self, store: Store, task_id: int, every: float = HEARTBEAT_EVERY) -> None:
        self.store, self.task_id, self.every = store, task_id, every
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._beat, name=f"lidarfuzz-heartbeat-{task_id}", daemon=True)

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._done.set()
        self._thread.join()

    def _beat(self) -> None:
        while not self._done.wait(self.every):
            try:
                with self.store.session() as s:
                    s.execute(update(Task).where(Task.id == self.task_id, Task.status == Status.RUNNING)
                              .values(heartbeat_at=now()))
            except Exception:  # a busy store ("database is locked"): the next beat tries again
                continue


# -- status transitions -----------------------------------------------------------------
def mark_running(store: Store, task_id: int, *, below_trial: int | None = None) -> None:
    """Claim a task for this process (status, worker, heartbeat, start time), then recount it."""
    with store.session() as s:
        row = task_row(s, task_id)
        row.status, row.error, row.worker, row.heartbeat_at = Status.RUNNING, "", worker_name(), now()
        row.started_at = row.started_at or now()
        row.finished_at = None
    recount(store, task_id, below_trial=below_trial)


def recount(store: Store, task_id: int, *, below_trial: int | None = None) -> None:
    """Counters and subtask states from the results actually stored (only trials below
    ``below_trial`` count, when given: a search's minimised copies are extra rows)."""
    with store.session() as s:
        task = task_row(s, task_id)
        query = select(FrameResult.subtask_id, func.count()).join(Subtask).where(Subtask.task_id == task_id)
        if below_trial is not None:
            query = query.where(FrameResult.trial < below_trial)
        counts = dict(s.execute(query.group_by(FrameResult.subtask_id)).all())
        for sub in task.subtasks:
            sub.done = int(counts.get(sub.id, 0))
            if sub.done >= sub.total and sub.status != Status.DONE:
                sub.status = Status.RUNNING  # complete but not evaluated: finished below
            elif sub.done < sub.total:
                sub.status = Status.RUNNING if sub.done else Status.PENDING
        task.done = sum(sub.done for sub in task.subtasks)


def set_status(store: Store, task_id: int, status: Status, error: str) -> None:
    """End a run that did not finish: the task's status and error; its unfinished subtasks back to
    pending (left as they are when it failed, to show where)."""
    with store.session() as s:
        row = s.get(Task, task_id)
        if row is None:
            raise StoreError(f"task {task_id} vanished while running")
        row.status, row.error = status, error
        for sub in row.subtasks:
            if sub.status == Status.RUNNING and sub.done < sub.total:
                sub.status = Status.PENDING if status != Status.FAILED else sub.status


def data_faults(store: Store, task_id: int) -> list[str]:
    """The messages of task ``task_id``'s units that have a data fault, in unit order."""
    from lidarfuzz.campaign.work import DATA_FAULT

    with store.session() as s:
        rows = s.execute(select(FrameResult.failure).join(Subtask).where(
            Subtask.task_id == task_id, FrameResult.failure.is_not(None)).order_by(
            Subtask.id, FrameResult.frame_id, FrameResult.trial))
        return [failure.message for (failure,) in rows if failure is not None and failure.kind == DATA_FAULT]


def data_fault_note(faults: list[str]) -> str:
    """The error of a task whose run ended with data faults (their messages)."""
    quoted = "; ".join(faults[:QUOTED_FAULTS]) + ("; …" if len(faults) > QUOTED_FAULTS else "")
    units = "1 unit" if len(faults) == 1 else f"{len(faults)} units"
    return (f"data faults: {units} could not read their frames ({quoted}); not the system's failures, and "
            f"left out of the figures. Restore the data set's files and resume the task: only those units run again")


def finish(store: Store, task_id: int, summary: TaskSummary, faults: list[str] | None = None) -> Status:
    """A run that finished: the task done, with its summary (and its headline figures) — or failed
    when ``faults`` (data faults' messages) remain, with its summary and :func:`data_fault_note`."""
    from lidarfuzz.campaign.headline import headline

    status = Status.FAILED if faults else Status.DONE
    with store.session() as s:
        row = task_row(s, task_id)
        row.status, row.finished_at = status, now()
        row.error = data_fault_note(faults) if faults else ""
        # the summary was drawn up while the task ran: it describes the task as it ends
        info = summary.task.model_copy(update={"status": status.value, "finished_at": row.finished_at.isoformat(),
                                               "done": row.done})
        row.summary = summary.model_copy(update={"task": info})
        row.headline = headline(row.summary)  # the task list's sortable figures
    return status


def _stopped(store: Store, task_id: int, interrupted: bool) -> Status:
    """End a run its :class:`Watch` stopped: cancelled when the task is cancelled in the store (a
    user's stop) or its ``stop`` was set; back to pending with :data:`STOPPED_NOTE` when it was
    interrupted (:class:`StopSignal`: a server shutting down) — in one transaction, so a process
    that dies right after leaves nothing a restart would take for a user's cancel."""
    with store.session() as s:
        cancelled = s.scalar(select(Task.status).where(Task.id == task_id)) == Status.CANCELLED
    status = Status.CANCELLED if cancelled or not interrupted else Status.PENDING
    set_status(store, task_id, status, "" if cancelled else STOPPED_NOTE)
    return status


# -- what a task kind implements --------------------------------------------------------
@dataclass(frozen=True)
class RunOptions:
    """How to run a task (what ``lidarfuzz run`` / ``resume`` and the web app's workers choose).

    Attributes:
        executor: Where units run (a kind that runs units in this process ignores it).
        workers: Processes of the default executor.
        progress: Called after every committed result (or step).
        stop: Set it to stop the run cleanly (as ``lidarfuzz cancel`` does from outside).
    """

    executor: Executor | None = None
    workers: int | None = None
    progress: Callable[[ProgressEvent], None] | None = None
    stop: threading.Event | None = None


class KindRun(Protocol):
    """One run of a task, as a kind's ``start`` returns it."""

    stats: RunStats

    def execute(self) -> None:
        """Run every unit that has no result, committing each; raise :class:`CancelledError` when
        the :class:`Watch` says so."""

    def summary(self) -> TaskSummary:
        """After :meth:`execute`: evaluate what is left and return the task's summary."""

    def close(self) -> None:
        """Release what the run holds (connections, workers, the system under test)."""


class KindImplementation(Protocol):
    """What a task kind's module provides (the row in :data:`lidarfuzz.campaign.kinds.TASK_KINDS`
    names the module).

    Attributes:
        counted_below: Only results with a trial below this count towards progress (None: all).
    """

    counted_below: int | None

    def check_spec(self, spec: CampaignSpec) -> None:
        """Refuse a campaign this kind cannot run (ValueError, named by pydantic)."""

    def plan(self, spec: CampaignSpec, model: Model, frame_ids: list[str]) -> KindPlan:
        """The subtasks after the originals, and the kind's own task options."""

    def start(self, store: Store, task: Task, options: RunOptions) -> KindRun:
        """Set up a run of ``task`` (already marked running)."""

    def describe(self, task: Task) -> str:
        """One line on what the task runs (``lidarfuzz run`` prints it first)."""


def drive(store: Store, task_id: int, kind: KindImplementation, options: RunOptions) -> RunOutcome:
    """Run (or resume) task ``task_id`` with its kind's implementation, through the lifecycle
    above: a done task is left alone; else claimed, run, and ended in one of the four states."""
    if task_status(store, task_id) == Status.DONE:
        return RunOutcome(task_id, Status.DONE, RunStats())
    mark_running(store, task_id, below_trial=kind.counted_below)
    task = get_task(store, task_id)
    started = time.perf_counter()
    status = Status.DONE
    run: KindRun | None = None
    try:
        with Heartbeat(store, task_id):
            run = kind.start(store, task, options)
            run.execute()
            summary = run.summary()
        run.stats.wall = time.perf_counter() - started
        summary.run = run.stats.timings()
        status = finish(store, task_id, summary, data_faults(store, task_id))
    except CancelledError:
        status = _stopped(store, task_id, isinstance(options.stop, StopSignal) and options.stop.interrupted)
    except KeyboardInterrupt:
        set_status(store, task_id, Status.PENDING, INTERRUPTED_NOTE)
        raise
    except BaseException as exc:
        set_status(store, task_id, Status.FAILED, f"{type(exc).__name__}: {exc}")
        raise
    finally:
        if run is not None:
            run.close()
    stats = run.stats if run is not None else RunStats()
    stats.wall = time.perf_counter() - started
    return RunOutcome(task_id, status, stats)


__all__ = ["CHECK_EVERY", "HEARTBEAT_EVERY", "INTERRUPTED_NOTE", "STALE_AFTER", "STOPPED_NOTE", "CancelledError",
           "Heartbeat", "KindImplementation", "KindRun", "ProgressEvent", "RunOptions", "RunOutcome", "RunStats",
           "StopSignal", "Watch", "cancel_task", "data_fault_note", "data_faults", "drive", "finish", "get_task",
           "heartbeat_age", "looks_alive", "mark_running", "now", "recount", "set_status", "task_row", "task_status",
           "worker_name"]
