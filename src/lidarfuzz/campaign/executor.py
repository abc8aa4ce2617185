"""Where work units run: an executor takes units and yields their results as they finish.

* :class:`InlineExecutor` runs them one by one in this process (tests, debugging, replays).
* :class:`ProcessExecutor` runs them on a local pool of processes, each holding one
  :class:`~lidarfuzz.campaign.work.Worker` (the system under test loaded once per process).
  A system that kills its process (a segfault, an abort) breaks the pool: the pool is
  rebuilt, the units that were in flight are re-run one at a time, and the one that kills
  its process again is recorded as a crash of the system under test.

A worker process that cannot open the data set (a file deleted mid-run, seen when the pool is
rebuilt) stays up and answers each unit with a data fault (:func:`~lidarfuzz.campaign.work.data_fault`):
its pool never breaks over it, so it is never taken for a crash of the system under test.
:func:`in_unit_order` gives any executor's results in the order the units were given, so results are
stored (and numbered) in the same order whatever finishes first.

The runner commits every result as it arrives, so an executor keeps nothing worth keeping:
closing one (on cancel, Ctrl-C or kill) loses only units in flight, which a resume re-runs.
The Ray cluster's executor (:mod:`lidarfuzz.campaign.cluster`) implements the same three methods.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import threading
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from lidarfuzz.campaign.work import UnitResult, WorkContext, Worker, WorkUnit, data_fault
from lidarfuzz.store.contracts import FailureRecord


class Executor(ABC):
    """Runs the work units of one task."""

    @abstractmethod
    def open(self, context: WorkContext) -> None:
        """Prepare workers for a task."""

    @abstractmethod
    def run(self, units: Iterable[WorkUnit]) -> Iterator[UnitResult]:
        """Results of ``units`` in the order they finish (units are pulled lazily)."""

    @abstractmethod
    def close(self) -> None:
        """Stop the workers; units in flight are dropped."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class InlineExecutor(Executor):
    """Every unit in this process, in order."""

    def __init__(self) -> None:
        self._worker: Worker | None = None

    def open(self, context: WorkContext) -> None:
        self.close()
        self._worker = Worker(context)

    def run(self, units: Iterable[WorkUnit]) -> Iterator[UnitResult]:
        if self._worker is None:
            raise RuntimeError("open() the executor first")
        for unit in units:
            yield self._worker.run(unit)

    def close(self) -> None:
        if self._worker is not None:
            self._worker.close()
            self._worker = None


_WORKER: Worker | None = None
_WORKER_ERROR: BaseException | None = None  # why this process has no worker (the data set did not open)


#: Thread counts that OpenMP runtimes, OpenBLAS and MKL read once, when the library loads.
THREAD_LIMIT_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
_ENVIRONMENT_LOCK = threading.Lock()


@contextlib.contextmanager
def _one_thread_environment() -> Iterator[None]:
    """This process's environment with one BLAS/OpenMP thread (unless the user chose a count),
    restored on exit.

    Worker processes must start with the limits already in their environment: a spawned
    worker imports numpy (the module holding :func:`_start` needs it) before its initializer
    runs, and OpenBLAS sizes its thread pool when it loads — setting the variables in
    :func:`_start` comes too late for it. Children inherit the environment at the moment they
    are spawned, so the pool's processes are started inside this block. The parent's own
    environment is put back as it was (a variable it did not have is removed again).
    """
    with _ENVIRONMENT_LOCK:  # pools started from several threads (the web app's task workers)
        saved = {variable: os.environ.get(variable) for variable in THREAD_LIMIT_VARIABLES}
        for variable in THREAD_LIMIT_VARIABLES:
            os.environ.setdefault(variable, "1")  # one core per worker: the pool is the parallelism
        try:
            yield
        finally:
            for variable, value in saved.items():
                if value is None:
                    os.environ.pop(variable, None)
                else:
                    os.environ[variable] = value


def _start(context: WorkContext) -> None:
    global _WORKER, _WORKER_ERROR
    # Inherited from the parent (_one_thread_environment), so numpy's BLAS already runs one
    # thread; set here too for a pool started some other way and for the libraries a system under
    # test loads later (torch's OpenMP reads OMP_NUM_THREADS when it loads).
    for var in THREAD_LIMIT_VARIABLES:
        os.environ.setdefault(var, "1")
    try:
        _WORKER = Worker(context)
    except Exception as exc:  # an initializer that raises breaks the pool: that would read as a crash
        _WORKER_ERROR = exc


def _run(unit: WorkUnit) -> UnitResult:
    if _WORKER is None:
        assert _WORKER_ERROR is not None, "worker not started"
        return data_fault(unit, _WORKER_ERROR)
    return _WORKER.run(unit)


def _crash(unit: WorkUnit) -> UnitResult:
    message = "the system under test killed its worker process (e.g. a segmentation fault)"
    return UnitResult(unit, failure=FailureRecord(kind="crash", message=message))


class ProcessExecutor(Executor):
    """A local pool of ``workers`` processes (default: the CPU count)."""

    def __init__(self, workers: int | None = None, window: int | None = None) -> None:
        self.workers = max(1, workers or os.cpu_count() or 1)
        self.window = window or 2 * self.workers
        self._pool: ProcessPoolExecutor | None = None
        self._context: WorkContext | None = None

    def _new_pool(self) -> ProcessPoolExecutor:
        """A pool whose processes are all started now, with one BLAS/OpenMP thread each.

        A spawn pool starts its processes on demand, one per ``submit`` while none is idle; one
        no-op per worker, submitted inside :func:`_one_thread_environment`, starts all of them
        while the thread limits are in the environment they inherit (a process started later,
        outside the block, would load numpy's BLAS with a thread per core).
        """
        assert self._context is not None
        with _one_thread_environment():
            pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                       initializer=_start, initargs=(self._context,))
            for _ in range(self.workers):
                pool.submit(os.getpid)
        return pool

    def open(self, context: WorkContext) -> None:
        self.close()
        self._context = context
        self._pool = self._new_pool()

    def _restart(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        self._pool = self._new_pool()

    def run(self, units: Iterable[WorkUnit]) -> Iterator[UnitResult]:
        if self._pool is None:
            raise RuntimeError("open() the executor first")
        source = iter(units)
        suspects: deque[WorkUnit] = deque()  # units in flight when the pool broke: re-run one at a time
        held: deque[WorkUnit] = deque()  # units the pool refused because it broke meanwhile: they never ran
        in_flight: dict[Future[UnitResult], WorkUnit] = {}
        exhausted = False
        while True:
            limit = 1 if suspects else self.window
            while len(in_flight) < limit:
                suspect = bool(suspects)
                if suspects:
                    unit: WorkUnit | None = suspects.popleft()
                elif held:
                    unit = held.popleft()
                elif not exhausted:
                    unit = next(source, None)
                    exhausted = unit is None
                else:
                    unit = None
                if unit is None:
                    break
                try:
                    in_flight[self._pool.submit(_run, unit)] = unit
                except BrokenProcessPool:
                    # a worker died after the last wait: the futures in flight say which units were
                    # with it; this one is submitted again once the pool is new
                    (suspects if suspect else held).appendleft(unit)
                    if in_flight:
                        break
                    self._restart()
            if not in_flight:
                return
            done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
            broken: list[WorkUnit] = []
            for future in done:
                unit = in_flight.pop(future)
                try:
                    yield future.result()
                except BrokenProcessPool:
                    broken.append(unit)
            if broken:
                lost = broken + list(in_flight.values())
                in_flight.clear()
                self._restart()
                if len(lost) == 1 and limit == 1:
                    yield _crash(lost[0])  # alone in the pool and killed it again: the culprit
                else:
                    suspects.extend(lost)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def in_unit_order(executor: Executor, units: Iterable[WorkUnit]) -> Iterator[UnitResult]:
    """``executor``'s results of ``units`` in the order of ``units`` (each unit, keyed by subtask,
    frame and trial, gives exactly one result): a result that finishes early waits for those
    before it, so the store numbers results and findings the same way on every run."""
    issued: deque[tuple[int, str, int]] = deque()

    def tap() -> Iterator[WorkUnit]:
        for unit in units:
            issued.append((unit.subtask_id, unit.frame_id, unit.trial))
            yield unit

    waiting: dict[tuple[int, str, int], UnitResult] = {}
    for result in executor.run(tap()):
        waiting[result.key] = result
        while issued and issued[0] in waiting:
            yield waiting.pop(issued.popleft())
    if waiting:  # an executor that answered a unit it was not given: a bug, never hidden
        raise RuntimeError(f"results of units never issued: {sorted(waiting)[:3]}")
