"""Opening the store: SQLite in WAL mode in a workspace by default, PostgreSQL by URL; schema by Alembic."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event, inspect
from sqlalchemy.orm import Session, sessionmaker

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.store.errors import ConflictError, NotFoundError, StoreError

MIGRATIONS = Path(__file__).with_name("migrations")
DATABASE_FILE = "lidarfuzz.db"


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")  # readers (the web app) never block the campaign's writer
    cursor.execute("PRAGMA synchronous=NORMAL")  # durable at checkpoints; WAL keeps committed work on a crash
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA busy_timeout=30000")
    cursor.close()


def store_url(target: str | PathLike[str]) -> str:
    """A database URL for ``target``: URLs pass through; a folder means its SQLite database."""
    text = str(target)
    if "://" in text:
        return text
    folder = Path(target)
    folder.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{(folder / DATABASE_FILE).resolve()}"


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
        try:
            self.engine: Engine = create_engine(self.url, future=True, pool_pre_ping=True)
        except ImportError as exc:  # the database's driver is an extra
            hint = " (pip install 'lidarfuzz[postgres]')" if self.url.startswith("postgresql") else ""
            raise StoreError(f"cannot open the store at {self.url}: {exc}{hint}") from None
        except Exception as exc:  # bad URL
            raise StoreError(f"cannot open the store at {self.url}: {exc}") from None
        if self.engine.dialect.name == "sqlite":
            event.listen(self.engine, "connect", _sqlite_pragmas)
        self._sessions = sessionmaker(self.engine, expire_on_commit=False)
        if migrate:
            self.migrate()

    def _alembic(self, connection: Any) -> Any:
        from alembic.config import Config

        config = Config()
        config.set_main_option("script_location", str(MIGRATIONS))
        config.attributes["connection"] = connection
        return config

    def migrate(self, revision: str = "head") -> None:
        """Upgrade the schema (idempotent)."""
        from alembic import command

        try:
            with self.engine.begin() as connection:
                command.upgrade(self._alembic(connection), revision)
        except Exception as exc:
            if isinstance(exc, LidarfuzzError):
                raise
            raise StoreError(f"cannot migrate the store at {self.url}: {exc}") from exc

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
        except BaseException:
            session.rollback()
            raise
        finally:
            session.close()

    def close(self) -> None:
        self.engine.dispose()


__all__ = ["DATABASE_FILE", "MIGRATIONS", "ConflictError", "NotFoundError", "Store", "StoreError", "store_url"]
