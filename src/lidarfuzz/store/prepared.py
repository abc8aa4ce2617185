"""Statements for a campaign's hot path: compiled by SQLAlchemy once, run on the driver's cursor.

A campaign commits every result in its own transaction (results are committed as produced). On
the classic pipeline a result's insert and its two counter updates cost ~0.1 ms in SQLite and
~0.4 ms in SQLAlchemy's per-execution work around them — the statement's cache key, the
parameters' construction, an execution context and a result object, run with caches the system
under test has just evicted. :class:`Prepared` keeps what SQLAlchemy does once (the SQL in the
dialect's own syntax and paramstyle, each parameter's bind processor: JSON, enums, timestamps as
the column types write them) and leaves out what it does on every call. It runs inside the
:class:`~sqlalchemy.engine.Connection`'s transaction (the same DBAPI connection), so a result, its
findings and its counters still commit or roll back together, and driver errors are raised as
SQLAlchemy's exceptions (an :class:`~sqlalchemy.exc.IntegrityError` is still one).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from sqlalchemy import Connection
from sqlalchemy.engine import Dialect
from sqlalchemy.exc import DBAPIError
from sqlalchemy.sql.dml import UpdateBase

from lidarfuzz.store.errors import StoreError


class Prepared:
    """One INSERT, UPDATE or DELETE compiled once for ``dialect``.

    ``keys`` are the parameters each execution passes (for an INSERT, the columns it writes).
    Columns whose values SQLAlchemy would compute in Python at execution (a Python-side
    ``default`` or ``onupdate`` not given in ``keys``) are refused here rather than written
    as NULL: pass them explicitly.
    """

    def __init__(self, statement: UpdateBase, dialect: Dialect, keys: Sequence[str]) -> None:
        compiled = statement.compile(dialect=dialect, column_keys=list(keys))
        prefetch = [c.key for c in (*compiled.insert_prefetch, *compiled.update_prefetch)]
        if prefetch:
            raise StoreError(f"a prepared statement needs explicit values for {', '.join(prefetch)} "
                             "(SQLAlchemy would compute them in Python)")
        self.sql = compiled.string
        self.returning = bool(compiled.effective_returning)
        self._names = list(compiled.positiontup or ()) if compiled.positional else None
        self._fixed: dict[str, Any] = {}  # the statement's own values (a literal status, say)
        self._processors: dict[str, Callable[[Any], Any]] = {}
        for bind, name in compiled.bind_names.items():
            if not bind.required:
                self._fixed[name] = bind.effective_value
            processor = bind.type.dialect_impl(dialect).bind_processor(dialect)
            if processor is not None:
                self._processors[name] = processor
        self._error = dialect.loaded_dbapi.Error

    def _parameters(self, values: Mapping[str, Any]) -> Any:
        merged = {**self._fixed, **values}
        for name, processor in self._processors.items():
            merged[name] = processor(merged[name])
        if self._names is not None:
            return tuple(merged[name] for name in self._names)
        return merged

    def execute(self, connection: Connection, values: Mapping[str, Any]) -> Any:
        """Run with ``values`` in ``connection``'s transaction; the first column of the first row
        for a statement with RETURNING, else None."""
        parameters = self._parameters(values)
        cursor = connection.connection.cursor()
        try:
            cursor.execute(self.sql, parameters)
            if not self.returning:
                return None
            first = cursor.fetchone()
            return None if first is None else first[0]
        except self._error as exc:
            raise DBAPIError.instance(self.sql, parameters, exc, self._error) from exc
        finally:
            cursor.close()

    def execute_many(self, connection: Connection, rows: Sequence[Mapping[str, Any]]) -> None:
        """Run once per row of ``rows`` (no RETURNING) in ``connection``'s transaction."""
        if not rows:
            return
        parameters = [self._parameters(row) for row in rows]
        cursor = connection.connection.cursor()
        try:
            cursor.executemany(self.sql, parameters)
        except self._error as exc:
            raise DBAPIError.instance(self.sql, parameters, exc, self._error) from exc
        finally:
            cursor.close()
