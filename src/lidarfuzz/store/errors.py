"""What can go wrong with the store, by type: callers (the web app's HTTP answers, the CLI) act on
the class of an error, never on the words of its message.

* :class:`StoreError`: the store cannot be opened or migrated, or a request does not fit its state.
* :class:`NotFoundError`: no such task, finding, data set or model (HTTP 404).
* :class:`ConflictError`: the request contradicts what is stored — a name taken, a task still
  running, a data set registered with other options (HTTP 409).
* :class:`TaskClaimedError`: another process runs the task now (a :class:`ConflictError`).
* :class:`StorageError`: the disk failed under the store or an output — full, over quota,
  read-only, an I/O error (:func:`storage_error` makes one from an ``OSError`` or a database's
  error); the command line prints its one line and exits 1.
"""

from __future__ import annotations

import errno
from datetime import datetime
from pathlib import Path
from typing import Any

from lidarfuzz.errors import LidarfuzzError


class StoreError(LidarfuzzError):
    """The store cannot be opened or is not at a schema this version understands (and the base
    of the store's other errors)."""


class NotFoundError(StoreError):
    """A row the request names does not exist (its message says how to list what does)."""


class ConflictError(StoreError):
    """The request contradicts what is stored (its message says what to do instead)."""


class TaskClaimedError(ConflictError):
    """Another process runs the task now (its claim is live): who, where and since when."""

    def __init__(self, task_id: int, host: str, pid: int, since: datetime, *, cli: str | None = None) -> None:
        self.task_id, self.host, self.pid, self.since = task_id, host, pid, since
        super().__init__(f"task {task_id} is being run by process {pid} on {host} since "
                         f"{since:%Y-%m-%d %H:%M:%S} UTC", cli=cli)


class StorageError(StoreError):
    """The disk under the store or an output failed: full, over quota, read-only, an I/O error.

    Attributes:
        path: The file or folder being written (or the store's database).
        reason: ``errno``'s code name (``ENOSPC``, ``EDQUOT``, ``EROFS``, ``EIO``, ...).
    """

    def __init__(self, path: str | Path, reason: str, message: str, *, cli: str | None = None) -> None:
        self.path, self.reason = str(path), reason
        super().__init__(message, cli=cli)


#: What a failing disk says, and what to do about it.
_ADVICE = {
    errno.ENOSPC: ("the disk is full", "free space on that disk (or write elsewhere), then run the command again"),
    errno.EDQUOT: ("the disk quota is exceeded", "free space within your quota (or write elsewhere), then run "
                                                 "the command again"),
    errno.EFBIG: ("the file is larger than that disk or the process's limit allows",
                  "write elsewhere or raise the limit (ulimit -f), then run the command again"),
    errno.EROFS: ("the file system is read-only", "write elsewhere (a workspace or --out folder you can write)"),
    errno.EIO: ("the disk reported an I/O error", "check that disk (dmesg, its health); then run the command again "
                                                  "on a sound one"),
    errno.EACCES: ("permission denied", "write elsewhere (a workspace or --out folder you can write)"),
    errno.EPERM: ("permission denied", "write elsewhere (a workspace or --out folder you can write)"),
}
#: The errors that mean the disk (or its permissions), not lidarfuzz's input or code.
DISK_ERRNOS = frozenset(_ADVICE)
#: SQLite's result texts for the same failures (its errors carry no errno).
_SQLITE_TEXTS = {"database or disk is full": errno.ENOSPC, "disk i/o error": errno.EIO,
                 "attempt to write a readonly database": errno.EROFS}
#: PostgreSQL's SQLSTATEs for them: disk_full, io_error, read_only_sql_transaction.
_PG_STATES = {"53100": errno.ENOSPC, "58030": errno.EIO, "25006": errno.EROFS}


def _code_of(exc: BaseException) -> int | None:
    """The errno a failure stands for: an OSError's own, SQLite's message, PostgreSQL's SQLSTATE."""
    if isinstance(exc, OSError):
        return exc.errno if exc.errno in DISK_ERRNOS else None
    original: Any = getattr(exc, "orig", None)  # SQLAlchemy's DBAPIError wraps the driver's error
    if original is None:
        return None
    state = getattr(original, "sqlstate", None) or getattr(original, "pgcode", None)
    if state in _PG_STATES:
        return _PG_STATES[state]
    text = str(original).lower()
    return next((code for words, code in _SQLITE_TEXTS.items() if words in text), None)


def storage_error(exc: BaseException, path: str | Path | None = None, *,
                  then: str | None = None) -> StorageError | None:
    """``exc`` as a :class:`StorageError` when it is a failing disk (None when it is something else).

    Args:
        exc: An ``OSError`` (ENOSPC, EDQUOT, EFBIG, EROFS, EIO, EACCES, EPERM) or a database error
            (SQLite's "database or disk is full", "disk I/O error", "attempt to write a readonly
            database"; PostgreSQL's disk_full, io_error, read_only_sql_transaction).
        path: What was being written, when ``exc`` does not say (a database's file or URL).
        then: What else to do after the advice, e.g. ``lidarfuzz resume 3 finishes the task``.

    Example:
        >>> import errno
        >>> failure = storage_error(OSError(errno.ENOSPC, "No space left on device", "out/report.html"))
        >>> failure.reason, str(failure).split(";")[0]
        ('ENOSPC', 'cannot write out/report.html: the disk is full')
    """
    if isinstance(exc, StorageError):
        return exc
    code = _code_of(exc)
    if code is None:
        return None
    where = getattr(exc, "filename", None) if isinstance(exc, OSError) else None
    where = where if where is not None else path if path is not None else "the store"
    what, advice = _ADVICE[code]
    verb = "cannot use" if code == errno.EIO else "cannot write"  # EIO fails reads too
    message = f"{verb} {where}: {what}; {advice}" + (f"; {then}" if then else "")
    return StorageError(where, errno.errorcode.get(code, str(code)), message)


__all__ = ["DISK_ERRNOS", "ConflictError", "NotFoundError", "StorageError", "StoreError", "TaskClaimedError",
           "storage_error"]
