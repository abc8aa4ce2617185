"""One runner per task at a time: the claim a run holds while it runs.

:func:`claim_task` takes task N's row in ``task_claims`` for this process — an insert when
nobody holds it, else a compare-and-set on the holder's ``token`` when that claim is dead — and
renews it from a thread every :data:`RENEW_EVERY` seconds until the run ends, when it is deleted.
Both steps are single statements that SQLite (one writer at a time) and PostgreSQL (row locks)
apply atomically, so of two processes claiming at once exactly one wins; the other is refused
with :class:`~lidarfuzz.store.errors.TaskClaimedError`, naming the runner (process, host, since
when), or waits for it (``wait``).

A claim dies with its process: one whose process no longer exists (same host) is taken over at
once, one not renewed for :data:`STALE_AFTER` seconds (a process on another host that died, or
lost its connection) after that.

Example:
    >>> from lidarfuzz.store import Store
    >>> with claim_task(Store("workspace"), 3):  # doctest: +SKIP
    ...     ...  # run task 3; a second claim_task(…, 3) elsewhere raises TaskClaimedError
"""

from __future__ import annotations

import contextlib
import os
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import delete, insert, select, update
from sqlalchemy.exc import IntegrityError

from lidarfuzz.store.errors import NotFoundError, StoreError, TaskClaimedError
from lidarfuzz.store.models import Task, TaskClaim
from lidarfuzz.store.store import Store

RENEW_EVERY = 5.0  # seconds between a claim's heartbeats
STALE_AFTER = 30.0  # seconds without a heartbeat before a claim is taken as dead
WAIT_POLL = 1.0  # seconds between tries while waiting for another runner


def _now() -> datetime:
    return datetime.now(UTC)


def _age(moment: datetime) -> float:
    if moment.tzinfo is None:  # SQLite keeps no zone: stored as UTC
        moment = moment.replace(tzinfo=UTC)
    return (_now() - moment).total_seconds()


def _process_gone(host: str, pid: int) -> bool:
    """True when ``pid`` names a process of this host that no longer exists."""
    if host != socket.gethostname():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # exists, another user's
        return False
    return False


def is_dead(claim: TaskClaim, stale_after: float = STALE_AFTER) -> bool:
    """Whether ``claim``'s runner is gone: its process no longer exists, or it stopped renewing."""
    return _process_gone(claim.host, claim.pid) or _age(claim.renewed_at) >= stale_after


def holder(store: Store, task_id: int) -> TaskClaim | None:
    """Task ``task_id``'s claim, live or dead (None: nobody claimed it)."""
    with store.session() as s:
        return s.get(TaskClaim, task_id)


def _try_claim(store: Store, task_id: int, token: str, *, take_over: bool, stale_after: float) -> TaskClaim | None:
    """Claim ``task_id`` with ``token``; None when done, else the live claim in the way."""
    moment = _now()
    mine = {"token": token, "host": socket.gethostname(), "pid": os.getpid(), "claimed_at": moment,
            "renewed_at": moment}
    try:
        with store.session() as s:
            s.execute(insert(TaskClaim).values(task_id=task_id, **mine))
        return None
    except IntegrityError:  # claimed already (or no such task: the caller looked it up first)
        pass
    current = holder(store, task_id)
    if current is None:  # released between the two statements, or no such task
        with store.session() as s:
            if s.get(Task, task_id) is None:
                raise NotFoundError(f"no task {task_id}", cli="lidarfuzz list")
        return _try_claim(store, task_id, token, take_over=take_over, stale_after=stale_after)
    if not take_over and not is_dead(current, stale_after):
        return current
    # a statement of its own (not in the read's transaction): SQLite applies it to the newest state
    with store.session() as s:
        taken = s.execute(update(TaskClaim).where(TaskClaim.task_id == task_id, TaskClaim.token == current.token)
                          .values(**mine)).rowcount  # type: ignore[attr-defined]
    if taken == 1:
        return None
    return _try_claim(store, task_id, token, take_over=take_over, stale_after=stale_after)  # another took it first


class _Renewal(threading.Thread):
    """Renews a claim every ``every`` seconds until stopped (a busy store: the next beat tries again)."""

    def __init__(self, store: Store, task_id: int, token: str, every: float) -> None:
        super().__init__(name=f"lidarfuzz-claim-{task_id}", daemon=True)
        self.store, self.task_id, self.token, self.every = store, task_id, token, every
        self.done = threading.Event()
        self.lost = False

    def run(self) -> None:
        while not self.done.wait(self.every):
            try:
                with self.store.session() as s:
                    renewed = s.execute(update(TaskClaim).where(TaskClaim.task_id == self.task_id,
                                                                TaskClaim.token == self.token)
                                        .values(renewed_at=_now())).rowcount  # type: ignore[attr-defined]
                self.lost = self.lost or renewed == 0
            except Exception:  # "database is locked", a full disk: the run itself reports those
                continue


@contextlib.contextmanager
def claim_task(store: Store, task_id: int, *, wait: bool = False, take_over: bool = False,
               on_wait: Callable[[TaskClaim], Any] | None = None, renew_every: float = RENEW_EVERY,
               stale_after: float = STALE_AFTER) -> Iterator[str]:
    """Hold task ``task_id``'s claim for the block (yields the claim's token).

    Args:
        store: The campaign store.
        task_id: The task (it must exist).
        wait: When another runner holds it, wait for it to end (or die) instead of refusing.
        take_over: Take the claim even from a runner that looks alive (``resume --force``).
        on_wait: Called once with the live claim when waiting starts (to say whom it waits for).
        renew_every: Seconds between heartbeats.
        stale_after: Seconds without a heartbeat before a claim is dead.

    Raises:
        TaskClaimedError: Another runner holds a live claim and ``wait`` is false.
        StorageError: The workspace is read-only (or its disk failed).
    """
    store.require_writable(f"running task {task_id}")
    token = uuid.uuid4().hex
    told = False
    while (current := _try_claim(store, task_id, token, take_over=take_over, stale_after=stale_after)) is not None:
        if not wait:
            raise TaskClaimedError(task_id, current.host, current.pid, current.claimed_at,
                                   cli=f"lidarfuzz resume {task_id} --wait waits for it; lidarfuzz status {task_id}")
        if not told and on_wait is not None:
            on_wait(current)
            told = True
        time.sleep(WAIT_POLL)
    renewal = _Renewal(store, task_id, token, renew_every)
    renewal.start()
    try:
        yield token
    finally:
        renewal.done.set()
        renewal.join()
        with contextlib.suppress(Exception), store.session() as s:  # a failed disk: it dies with this process
            s.execute(delete(TaskClaim).where(TaskClaim.task_id == task_id, TaskClaim.token == token))


def release_claim(store: Store, task_id: int) -> bool:
    """Remove task ``task_id``'s claim whoever holds it (True when there was one)."""
    with store.session() as s:
        return bool(s.execute(delete(TaskClaim).where(TaskClaim.task_id == task_id)).rowcount)  # type: ignore[attr-defined]


def claims(store: Store) -> list[TaskClaim]:
    """Every claim in the store, live or dead (for ``lidarfuzz status`` and tests)."""
    with store.session() as s:
        return list(s.scalars(select(TaskClaim).order_by(TaskClaim.task_id)))


__all__ = ["RENEW_EVERY", "STALE_AFTER", "StoreError", "TaskClaimedError", "claim_task", "claims", "holder",
           "is_dead", "release_claim"]
