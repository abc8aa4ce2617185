"""Campaigns on a Ray cluster: the executor behind ``lidarfuzz run --executor ray``.

The driver (the process running ``lidarfuzz run``) keeps everything that is written: it reads
each frame once, puts it in Ray's object store, and sends units to **system actors** — one
process each, holding one loaded system under test (a :class:`~lidarfuzz.campaign.work.Worker`
that opens no data set: every unit comes with its frame's object reference, which Ray resolves
on the actor's node, once per node). Mutation and relation work is stateless and seeded by the
unit, so a result does not depend on which actor or node ran it; results stream back and the
runner commits each as it arrives, in the units' order (:func:`~lidarfuzz.campaign.executor.in_unit_order`).

**Backpressure.** At most ``per_actor`` units are in flight per actor (one running, one queued to
hide the round trip), units are pulled from the plan only as results come back, and only the
frames of units in flight (plus :data:`FRAMES_KEPT`) stay referenced in the object store: a data
set of any size runs in bounded memory.

**Faults.** An actor whose process dies (its node was lost, its worker killed, or the system under
test segfaulted) loses the units it held; they are run again one at a time on a fresh actor, and
a unit that kills its actor again while alone on it is the system's ``crash`` (the rule of the
local process pool). Units already committed are never run again, and the store's unit key
(subtask, frame, trial) is unique, so a restarted driver, or a second one, stores nothing twice.
When the cluster has fewer CPUs than before (a node gone), the executor goes on with fewer actors.

**Placement.** ``actors`` system actors (default: one per CPU in the cluster), each reserving
``cpus_per_actor`` CPUs and, where the cluster has GPUs, an equal share of them
(``num_gpus = GPUs / actors``, at most 1), so several actors share one GPU.

A cluster needs a store every node and driver can reach: PostgreSQL, never an SQLite file
(:func:`require_shared_store`).
"""

from __future__ import annotations

import contextlib
import os
import time
from collections import OrderedDict, deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from lidarfuzz.campaign.executor import Executor
from lidarfuzz.campaign.work import UnitResult, WorkContext, Worker, WorkUnit, data_fault, open_worker_dataset
from lidarfuzz.errors import LidarfuzzError, MissingDependencyError
from lidarfuzz.store.contracts import FailureRecord

#: Seconds a new actor may take to start (its process and lidarfuzz's import) before it is given up.
ACTOR_START_SECONDS = 300.0
#: Actors in a row that die before answering ready() before the run stops (a node without lidarfuzz).
MAX_FAILED_STARTS = 3
#: Seconds the actors are given, all together, to close their systems at the end of a run.
CLOSE_SECONDS = 10.0
#: Frames kept in the object store beyond those of units in flight: two of the runner's blocks of 16
#: (units come block by block, each block's frames once per subtask).
FRAMES_KEPT = 32


class ClusterError(LidarfuzzError):
    """A cluster run cannot start or go on (no Ray, an SQLite store, no CPU left)."""


def import_ray() -> Any:
    """The ``ray`` module.

    Raises:
        MissingDependencyError: Ray is not installed; the message names the ``ray`` extra.
    """
    try:
        import ray
    except ImportError:
        raise MissingDependencyError("ray", "ray", "--executor ray (a campaign on a Ray cluster)") from None
    return ray


def require_shared_store(store_url: str | None) -> None:
    """Refuse a cluster run on a store that is not shared.

    Raises:
        ClusterError: ``store_url`` is an SQLite database (or none), with why and what to use.
    """
    if store_url is None or store_url.startswith("sqlite"):
        raise ClusterError(
            "--executor ray needs a store that every node and driver reaches: an SQLite store is a file on "
            "this machine, written by one process at a time; use PostgreSQL, e.g. --workspace "
            "postgresql+psycopg://user@host/lidarfuzz (pip install 'lidarfuzz[ray]' installs its driver)")


class _SystemActor:
    """One process of the cluster holding one system under test (a Ray actor)."""

    def __init__(self, context: WorkContext) -> None:
        self.worker = Worker(context, open_data=False)

    def ready(self) -> tuple[str, int]:
        """Where it runs: (node address, process id)."""
        import ray

        return ray.util.get_node_ip_address(), os.getpid()

    def run(self, unit: WorkUnit, scene: Any) -> UnitResult:
        return self.worker.run(unit, scene)

    def close(self) -> None:
        self.worker.close()


@dataclass
class _Actor:
    handle: Any
    ready: Any = None  # the ready() reference while it starts; None once it answered
    started: float = field(default_factory=time.monotonic)
    units: dict[Any, WorkUnit] = field(default_factory=dict)  # result reference -> unit
    suspect: bool = False  # running a suspect unit, alone


def _crash(unit: WorkUnit) -> UnitResult:
    message = "the system under test killed its Ray actor's process twice (e.g. a segmentation fault)"
    return UnitResult(unit, failure=FailureRecord(kind="crash", message=message))


class RayExecutor(Executor):
    """Units on a Ray cluster's system actors (see the module docstring).

    Args:
        address: The cluster: ``auto`` (the one ``ray start`` runs on this machine),
            ``ray://HOST:PORT`` (Ray Client), ``HOST:PORT``, or None (``RAY_ADDRESS``, else a
            local Ray started for this run and stopped after it).
        actors: System actors (default: the cluster's CPUs / ``cpus_per_actor``).
        cpus_per_actor: CPUs each actor reserves.
        gpus_per_actor: GPUs each actor reserves (default: the cluster's GPUs shared equally, 0
            without GPUs).
        per_actor: Units in flight per actor.
        init: Extra arguments of ``ray.init`` (e.g. ``num_cpus`` of a local Ray).
    """

    def __init__(self, address: str | None = None, *, actors: int | None = None, cpus_per_actor: float = 1.0,
                 gpus_per_actor: float | None = None, per_actor: int = 2,
                 init: dict[str, Any] | None = None) -> None:
        if actors is not None and actors < 1:
            raise ClusterError(f"--actors: expected 1 or more, got {actors}")
        self.address = address
        self.actors = actors
        self.cpus_per_actor = cpus_per_actor
        self.gpus_per_actor = gpus_per_actor
        self.per_actor = max(1, per_actor)
        self.init = dict(init or {})
        self.restarts = 0  # actors replaced after their process died
        self._failed_starts = 0
        self._ray: Any = None
        self._started_ray = False
        self._context: WorkContext | None = None
        self._remote: Any = None
        self._options: dict[str, Any] = {}
        self._pool: list[_Actor] = []
        self._dataset: Any = None
        self._dataset_error: BaseException | None = None
        self._frames: OrderedDict[str, Any] = OrderedDict()  # frame id -> its scene's object reference

    # -- the cluster --------------------------------------------------------------------
    def open(self, context: WorkContext) -> None:
        self.close()
        require_shared_store(context.store_url)
        ray = self._ray = import_ray()
        if not ray.is_initialized():
            # no address: RAY_ADDRESS, else a Ray of our own ("local"; never a cluster that happens to
            # run on this machine, which ray.init() would join)
            address = self.address or os.environ.get("RAY_ADDRESS") or "local"
            try:
                ray.init(address=address, include_dashboard=False, log_to_driver=False,
                         configure_logging=False, **self.init)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                where = "a new local Ray" if address == "local" else address
                raise ClusterError(f"cannot reach the Ray cluster at {where}: "
                                   f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
            self._started_ray = True
        self._context = context
        try:
            self._dataset = open_worker_dataset(context)
        except Exception as exc:  # every unit is then a data fault, as in the local pool
            self._dataset, self._dataset_error = None, exc
        count = self._wanted()
        gpus = self.gpus_per_actor
        if gpus is None:
            total = float(ray.cluster_resources().get("GPU", 0.0))
            gpus = min(1.0, total / count) if total > 0 else 0.0
        self._remote = ray.remote(_SystemActor)
        # a system given as module:Class is imported by the actors as by the driver: from the driver's
        # folder and PYTHONPATH (on other nodes, where that folder is not, install its package there)
        paths = [os.getcwd(), *os.environ.get("PYTHONPATH", "").split(os.pathsep)]
        self._options = {"num_cpus": self.cpus_per_actor, "num_gpus": gpus, "max_restarts": 0,
                         "max_task_retries": 0,
                         "runtime_env": {"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in paths if p)}}}
        self._pool = [self._start_actor() for _ in range(count)]

    def _cpus(self) -> float:
        return float(self._ray.cluster_resources().get("CPU", 0.0))

    def _wanted(self) -> int:
        """How many actors the cluster has room for now (``actors`` at most), counting CPUs and,
        for actors that reserve a GPU share, GPUs."""
        room = int(self._cpus() // self.cpus_per_actor) if self.cpus_per_actor > 0 else self.actors or 1
        if room < 1:
            raise ClusterError(f"the Ray cluster has {self._cpus():g} CPUs: no room for a system actor "
                               f"of {self.cpus_per_actor:g} CPU")
        if self.gpus_per_actor:
            gpus = float(self._ray.cluster_resources().get("GPU", 0.0))
            room = min(room, int(gpus // self.gpus_per_actor + 1e-9))
            if room < 1:
                raise ClusterError(f"--actor-gpus {self.gpus_per_actor:g}: the Ray cluster has {gpus:g} GPUs, no "
                                   "room for a system actor")
        return min(room, self.actors) if self.actors else room

    def _start_actor(self) -> _Actor:
        handle = self._remote.options(**self._options).remote(self._context)
        return _Actor(handle, ready=handle.ready.remote())

    # -- frames -------------------------------------------------------------------------
    def _frame(self, unit: WorkUnit, window: int) -> tuple[Any, UnitResult | None]:
        """The object reference of ``unit``'s frame (read and put once), or its data fault."""
        if unit.source_fault:
            return None, None  # the actor answers it without the frame
        if self._dataset is None:
            assert self._dataset_error is not None
            return None, data_fault(unit, self._dataset_error)
        ref = self._frames.get(unit.frame_id)
        if ref is None:
            try:
                scene = self._dataset.load(unit.frame_id)
            except Exception as exc:  # the data, not the system: a data fault, run again on resume
                return None, data_fault(unit, exc)
            ref = self._frames[unit.frame_id] = self._ray.put(scene)
        self._frames.move_to_end(unit.frame_id)
        busy = {u.frame_id for actor in self._pool for u in actor.units.values()}
        while len(self._frames) > window:  # forget frames no unit in flight needs (Ray frees them)
            oldest = next((f for f in self._frames if f not in busy and f != unit.frame_id), None)
            if oldest is None:
                break
            del self._frames[oldest]
        return ref, None

    # -- the units ------------------------------------------------------------------------
    def run(self, units: Iterable[WorkUnit]) -> Iterator[UnitResult]:
        if self._ray is None or self._context is None:
            raise RuntimeError("open() the executor first")
        ray = self._ray
        from ray.exceptions import RayActorError, RayTaskError, WorkerCrashedError

        lost_errors = (RayActorError, WorkerCrashedError)
        source = iter(units)
        suspects: deque[WorkUnit] = deque()  # units whose actor died under them: run again, alone
        exhausted = False
        window = FRAMES_KEPT
        while True:
            # hand out units: suspects first, each alone on a ready actor; then the plan's
            for actor in sorted(self._pool, key=lambda a: len(a.units)):
                if actor.ready is not None or actor.suspect:
                    continue
                while len(actor.units) < self.per_actor and (suspects or not exhausted):
                    if suspects:
                        if actor.units:
                            break
                        unit, suspect = suspects.popleft(), True
                    else:
                        next_unit = next(source, None)
                        if next_unit is None:
                            exhausted = True
                            break
                        unit, suspect = next_unit, False
                    ref, fault = self._frame(unit, window)
                    if fault is not None:
                        yield fault
                        continue
                    actor.units[actor.handle.run.remote(unit, ref)] = unit
                    if suspect:
                        actor.suspect = True
                        break
            waiting = {ref: actor for actor in self._pool for ref in actor.units}
            starting = {actor.ready: actor for actor in self._pool if actor.ready is not None}
            if not waiting and exhausted and not suspects:
                return  # every unit answered: an actor still waiting for room is not waited for
            if not waiting and not starting:
                raise ClusterError("no system actor is left on the Ray cluster to run the remaining units")
            pending = [*waiting, *starting]
            done, rest = ray.wait(pending, num_returns=1, timeout=5.0)
            if done and rest:  # every other result already back, in one call (not one wait per result)
                done += ray.wait(rest, num_returns=len(rest), timeout=0)[0]
            for ref in done:
                if ref in starting:
                    actor = starting[ref]
                    try:
                        ray.get(ref)
                    except lost_errors as exc:  # it could not start: give up after a few in a row
                        self._failed_starts += 1
                        if self._failed_starts >= MAX_FAILED_STARTS:
                            lines = [line for line in str(exc).splitlines() if line.strip()]
                            raise ClusterError(f"{self._failed_starts} system actors in a row could not start on the "
                                               "Ray cluster (is lidarfuzz installed on every node?): "
                                               f"{lines[0] if lines else type(exc).__name__}") from None
                        self._replace(actor, suspects)
                    else:
                        actor.ready, self._failed_starts = None, 0
                    continue
                actor = waiting[ref]
                if ref not in actor.units:  # its actor died earlier in this batch, and this unit was dealt with
                    continue
                unit = actor.units.pop(ref)
                try:
                    result: UnitResult = ray.get(ref)
                except RayTaskError as exc:  # lidarfuzz's own error inside the actor: never hidden
                    raise exc.as_instanceof_cause() from None
                except lost_errors:
                    alone = actor.suspect and not actor.units
                    # what the actor finished before it died is kept: those units never run twice
                    yield from self._salvage(actor, lost_errors, RayTaskError)
                    if alone:
                        yield _crash(unit)  # alone on its actor and killed it again: the culprit
                    else:
                        suspects.append(unit)
                    self._replace(actor, suspects)
                    continue
                actor.suspect = False
                yield result
            self._give_up_slow_starts()

    def _salvage(self, actor: _Actor, lost: tuple[type[Exception], ...],
                 own: type[Exception]) -> Iterator[UnitResult]:
        """Results ``actor`` finished before its process died (its other units stay in ``units``,
        to be run again)."""
        for ref in list(actor.units):
            if not self._ray.wait([ref], timeout=0)[0]:
                continue
            try:
                result = self._ray.get(ref)
            except own as exc:
                raise exc.as_instanceof_cause() from None  # type: ignore[attr-defined]
            except lost:
                continue
            del actor.units[ref]
            yield result

    def _replace(self, actor: _Actor, suspects: deque[WorkUnit]) -> None:
        """``actor``'s process is gone: its units become suspects; a new actor takes its place when
        the cluster still has room for it."""
        if actor not in self._pool:
            return
        suspects.extend(actor.units.values())
        actor.units.clear()
        self._pool.remove(actor)
        self._kill(actor)
        self.restarts += 1
        if len(self._pool) < self._room():
            self._pool.append(self._start_actor())

    def _room(self) -> int:
        try:
            return self._wanted()
        except ClusterError:
            return 0

    def _give_up_slow_starts(self) -> None:
        """Drop actors that could not start (no room on any node) when others are running."""
        now = time.monotonic()
        for actor in list(self._pool):
            if actor.ready is not None and now - actor.started > ACTOR_START_SECONDS:
                self._pool.remove(actor)
                self._kill(actor)
        if not self._pool:
            raise ClusterError(f"no system actor started on the Ray cluster within {ACTOR_START_SECONDS:g} s "
                               f"({self._cpus():g} CPUs in the cluster)")

    def _kill(self, actor: _Actor) -> None:
        with contextlib.suppress(Exception):  # already gone with its node
            self._ray.kill(actor.handle, no_restart=True)

    def close(self) -> None:
        ray = self._ray
        if ray is None:
            return
        # every actor closes its system at once (a worker system's program group is killed there); one on a
        # node that died unnoticed never answers, so the wait is bounded for all together
        closing = []
        for actor in self._pool:
            if actor.ready is None:
                with contextlib.suppress(Exception):
                    closing.append(actor.handle.close.remote())
        if closing:
            with contextlib.suppress(Exception):  # gone, or its system does not close: killed below
                ray.wait(closing, num_returns=len(closing), timeout=CLOSE_SECONDS)
        for actor in self._pool:
            self._kill(actor)
        self._pool.clear()
        self._frames.clear()
        if self._dataset is not None and hasattr(self._dataset, "close"):
            self._dataset.close()
        self._dataset = None
        if self._started_ray:
            ray.shutdown()
            self._started_ray = False
        self._ray = None

