"""Opening the store: SQLite in WAL mode in a workspace by default, PostgreSQL by URL; schema by Alembic.

Several processes may open one new workspace at once (two ``lidarfuzz run``, a server and a
command): creating and migrating the schema is serialised — by an exclusive lock on
``lidarfuzz.db.lock`` beside an SQLite database, by an advisory lock on PostgreSQL — and a store
already at the newest revision is opened without taking either. A workspace the user cannot write
(a read-only folder, file or file system) is opened read-only: reading commands work, a write is
refused with one line saying so (:class:`~lidarfuzz.store.errors.StorageError`), and a store that
would need a migration says which.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import Any
from urllib.parse import quote

from sqlalchemy import Engine, create_engine, event, inspect, text
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store.errors import ConflictError, NotFoundError, StorageError, StoreError, storage_error

MIGRATIONS = Path(__file__).with_name("migrations")
DATABASE_FILE = "lidarfuzz.db"
#: PostgreSQL's advisory lock key that serialises migrations ("lfzz" in ASCII).
MIGRATION_LOCK_KEY = 0x6C667A7A


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA busy_timeout=30000")  # first: switching a new database to WAL waits for another opener
    cursor.execute("PRAGMA journal_mode=WAL")  # readers (the web app) never block the campaign's writer
    cursor.execute("PRAGMA synchronous=NORMAL")  # durable at checkpoints; WAL keeps committed work on a crash
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.close()


def _sqlite_read_only_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA busy_timeout=30000")
    cursor.execute("PRAGMA query_only=ON")
    cursor.close()


def store_url(target: str | PathLike[str]) -> str:
    """A database URL for ``target``: URLs pass through; a folder means its SQLite database."""
    text = str(target)
    if "://" in text:
        return text
    folder = Path(target)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        failure = storage_error(exc)
        if failure is None:
            raise
        raise failure from None
    return f"sqlite:///{(folder / DATABASE_FILE).resolve()}"


def sqlite_file(url: str) -> Path | None:
    """The database file of an SQLite URL (None: another database, or SQLite in memory)."""
    parsed = make_url(url)
    database = parsed.database or ""
    if parsed.get_backend_name() != "sqlite" or database in ("", ":memory:") or database.startswith("file:"):
        return None
    return Path(database)


def _read_only(database: Path) -> bool:
    """Whether this process cannot write ``database`` (its folder holds SQLite's -wal, -shm and lock
    files, so a folder it cannot write counts too; EROFS reads as no access)."""
    folder = database.parent
    if database.exists():
        return not (os.access(database, os.W_OK) and os.access(folder, os.W_OK))
    return folder.exists() and not os.access(folder, os.W_OK)


def _read_only_url(database: Path) -> str:
    """An SQLite URL opening ``database`` read-only. Where SQLite could not create the WAL's shared
    memory file (a folder it cannot write, no -shm left), ``immutable``: nobody can write it either."""
    shared = database.with_name(database.name + "-shm")
    writable_folder = os.access(database.parent, os.W_OK)
    mode = "mode=ro" if writable_folder or shared.exists() else "mode=ro&immutable=1"
    return f"sqlite:///file:{quote(str(database.resolve()))}?{mode}&uri=true"


class Store:
    """The campaign store.

    Args:
        target: A workspace folder (SQLite at ``<folder>/lidarfuzz.db``) or a database URL
            (``postgresql+psycopg://user@host/db``, ``sqlite:///path``).
        migrate: Bring the schema to the newest revision on opening.

    Example:
        >>> store = Store("sqlite://")  # in memory
        >>> store.revision() is not None
        True
    """

    def __init__(self, target: str | PathLike[str], *, migrate: bool = True) -> None:
        self.url = store_url(target)
        #: the SQLite database's file (None: PostgreSQL, or SQLite in memory)
        self.file = sqlite_file(self.url)
        #: what messages name: the workspace folder, or the URL without its password
        self.where = str(self.file.parent) if self.file is not None else \
            make_url(self.url).render_as_string(hide_password=True)
        self.read_only = self.file is not None and _read_only(self.file)
        if self.read_only and self.file is not None and not self.file.exists():
            raise StorageError(self.where, "EROFS", f"the workspace at {self.where} is read-only and holds no "
                                                    f"store yet; give a workspace you can write (--workspace)")
        url = _read_only_url(self.file) if self.read_only and self.file is not None else self.url
        try:
            self.engine: Engine = create_engine(url, future=True, pool_pre_ping=True)
        except ImportError as exc:  # the database's driver is an extra
            hint = " (pip install 'lidarfuzz[postgres]')" if self.url.startswith("postgresql") else ""
            raise StoreError(f"cannot open the store at {self.url}: {exc}{hint}") from None
        except Exception as exc:  # bad URL
            raise StoreError(f"cannot open the store at {self.url}: {exc}") from None
        if self.engine.dialect.name == "sqlite":
            event.listen(self.engine, "connect", _sqlite_read_only_pragmas if self.read_only else _sqlite_pragmas)
        self._sessions = sessionmaker(self.engine, expire_on_commit=False)
        if migrate:
            self.migrate()

    def _alembic(self, connection: Any) -> Any:
        from alembic.config import Config

        config = Config()
        config.set_main_option("script_location", str(MIGRATIONS))
        config.attributes["connection"] = connection
        return config

    def head(self) -> str:
        """The newest schema revision this version of lidarfuzz knows."""
        from alembic.script import ScriptDirectory

        return str(ScriptDirectory(str(MIGRATIONS)).get_current_head())

    def pending(self) -> list[str]:
        """The migrations the database lacks, oldest first."""
        from alembic.script import ScriptDirectory

        current = self.revision()
        if current == self.head():
            return []
        scripts = ScriptDirectory(str(MIGRATIONS))
        return [script.revision for script in reversed(list(scripts.iterate_revisions("head", current or "base")))]

    @contextlib.contextmanager
    def _migration_lock(self) -> Iterator[None]:
        """Held while migrating an SQLite database: one process creates and upgrades the schema, the
        others wait and then find it done (PostgreSQL's advisory lock is taken in :meth:`migrate`)."""
        if self.file is None:
            yield
            return
        import fcntl

        lock = self.file.with_name(self.file.name + ".lock")
        with open(lock, "a+b") as handle:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(handle.fileno(), fcntl.LOCK_UN)

    def migrate(self, revision: str = "head") -> None:
        """Upgrade the schema (idempotent, and safe when other processes do it at the same time)."""
        from alembic import command

        try:
            if revision == "head" and not self.pending():  # the common case: no lock, nothing written
                return
        except Exception as exc:  # a database that cannot be read: reported below, under the lock
            if self.read_only:
                raise StoreError(f"cannot read the store at {self.where}: {exc}") from None
        if self.read_only:
            pending = self.pending()
            raise StorageError(self.where, "EROFS", f"the workspace at {self.where} is read-only and needs "
                                                    f"migration{'s' if len(pending) > 1 else ''} {', '.join(pending)}; "
                                                    f"run a command with write access once")
        try:
            with self._migration_lock(), self.engine.begin() as connection:
                if self.engine.dialect.name == "postgresql":  # released when this transaction ends
                    connection.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK_KEY})
                elif self.engine.dialect.name == "sqlite":
                    # the driver begins no transaction before DDL: without this, a disk that fills
                    # mid-migration leaves tables without their revision, and the store cannot be opened
                    connection.exec_driver_sql("BEGIN IMMEDIATE")
                command.upgrade(self._alembic(connection), revision)
        except Exception as exc:
            if isinstance(exc, LidarfuzzError):
                raise
            raise self.failure(exc) or StoreError(f"cannot migrate the store at {self.url}: {exc}") from exc

    def failure(self, exc: BaseException, *, then: str | None = None) -> StorageError | None:
        """``exc`` as a :class:`StorageError` when the disk under the store failed (None otherwise);
        a write refused by a read-only workspace says so."""
        if self.read_only and isinstance(exc, Exception) and (failed := storage_error(exc)) is not None \
                and failed.reason == "EROFS":
            return StorageError(self.where, "EROFS", f"the workspace at {self.where} is read-only: this command "
                                                     f"writes to it; run it where you can write (or on a copy)",
                                cli=None)
        return storage_error(exc, self.file if self.file is not None else self.where, then=then)

    def require_writable(self, what: str) -> None:
        """Refuse, before anything is done, a command that writes to a read-only workspace.

        Raises:
            StorageError: The workspace is read-only.
        """
        if self.read_only:
            raise StorageError(self.where, "EROFS", f"the workspace at {self.where} is read-only: {what} writes to "
                                                    f"it; run it where you can write (or on a copy)")

    def revision(self) -> str | None:
        """The schema revision the database is at (None before the first migration)."""
        from alembic.runtime.migration import MigrationContext

        with self.engine.connect() as connection:
            return MigrationContext.configure(connection).get_current_revision()

    def tables(self) -> list[str]:
        return sorted(inspect(self.engine).get_table_names())

    @contextlib.contextmanager
    def session(self) -> Iterator[Session]:
        """A unit of work: committed on success, rolled back on error."""
        session = self._sessions()
        try:
            yield session
            session.commit()
        except BaseException as exc:
            with contextlib.suppress(Exception):  # a disk that failed the commit may fail this too
                session.rollback()
            failed = self.failure(exc)
            if failed is not None and failed is not exc:
                raise failed from exc
            raise
        finally:
            session.close()

    def close(self) -> None:
        self.engine.dispose()


__all__ = ["DATABASE_FILE", "MIGRATIONS", "MIGRATION_LOCK_KEY", "ConflictError", "NotFoundError", "StorageError",
           "Store", "StoreError", "sqlite_file", "store_url"]
