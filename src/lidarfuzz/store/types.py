"""Column types of the store: JSON that cannot hold what JSON has no word for.

:class:`SafeJSON` stores NaN and ±Inf as ``null`` (JSON has no such numbers; SQLite would store
a bare ``NaN`` no other reader accepts and PostgreSQL refuses it) and numpy scalars as Python
numbers. :class:`ContractJSON` does the same for a column holding one of
:mod:`lidarfuzz.store.contracts`' models: a value is validated when it is written (a dict or the
model) and comes back as the model, so every reader gets attributes and a wrong shape fails where
it is written, not where it is read.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np
from pydantic import BaseModel, TypeAdapter, ValidationError
from sqlalchemy import JSON
from sqlalchemy.engine import Dialect
from sqlalchemy.types import TypeDecorator, TypeEngine

logger = logging.getLogger(__name__)


_AS_IS = frozenset({str, int, bool, type(None)})


def json_safe(value: Any) -> Any:
    """``value`` with NaN and ±Inf as None, numpy scalars as Python numbers, tuples as lists."""
    kind = type(value)
    if kind in _AS_IS:  # the leaves of nearly every stored value: decided by the exact type
        return value
    if kind is float:
        return value if math.isfinite(value) else None
    if kind is dict:
        return {k: json_safe(v) for k, v in value.items()}
    if kind is list or kind is tuple:
        return [json_safe(v) for v in value]
    if isinstance(value, float):
        return None if math.isnan(value) or math.isinf(value) else value
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return json_safe(value.item())
    if isinstance(value, BaseModel):
        return json_safe(value.model_dump(mode="json", by_alias=True))
    return value


class SafeJSON(TypeDecorator[Any]):
    """A JSON column that stores NaN and ±Inf as null.

    Args:
        none_as_null: Python None is SQL NULL (else JSON ``null``).
    """

    impl = JSON
    cache_ok = True

    def __init__(self, none_as_null: bool = False) -> None:
        super().__init__(none_as_null=none_as_null)
        self.none_as_null = none_as_null
        self.should_evaluate_none = not none_as_null  # None reaches the processors: JSON null

    def process_bind_param(self, value: Any, dialect: Dialect) -> Any:
        return value if value is JSON.NULL else json_safe(value)

    def process_result_value(self, value: Any, dialect: Dialect) -> Any:
        return value

    def compare_against_backend(self, dialect: Dialect, conn_type: TypeEngine[Any]) -> bool | None:
        return isinstance(conn_type, JSON) or None


class ContractJSON(SafeJSON):
    """A JSON column holding a contract (a pydantic model, or a list of them).

    Args:
        contract: The model (or e.g. ``list[Model]``) the column holds.
        none_as_null: Python None is SQL NULL (else JSON ``null``); either comes back as None.
        derived: The column holds what can be computed again from other rows (a task's summary):
            a value an older version stored in another shape reads as None, with a warning, so the
            task stays readable and its summary is computed afresh (any other column's wrong shape
            is an error).
    """

    cache_ok = True

    def __init__(self, contract: Any, none_as_null: bool = False, derived: bool = False) -> None:
        super().__init__(none_as_null=none_as_null)
        self.contract, self.derived = contract, derived
        self._adapter: TypeAdapter[Any] = TypeAdapter(contract)

    def process_bind_param(self, value: Any, dialect: Dialect) -> Any:
        if value is None or value is JSON.NULL:
            return None if self.none_as_null else JSON.NULL
        checked = value if isinstance(value, BaseModel) else self._adapter.validate_python(value)
        return json_safe(self._adapter.dump_python(checked, mode="json", by_alias=True))

    def process_result_value(self, value: Any, dialect: Dialect) -> Any:
        if value is None:
            return None
        if not self.derived:
            return self._adapter.validate_python(value)
        try:
            return self._adapter.validate_python(value)
        except ValidationError as exc:
            name = getattr(self.contract, "__name__", str(self.contract))
            logger.warning("a stored %s in an older shape is ignored (it is computed again): %s", name,
                           str(exc).splitlines()[0])
            return None

    def copy(self, **kw: Any) -> ContractJSON:
        return ContractJSON(self.contract, self.none_as_null, self.derived)


__all__ = ["ContractJSON", "SafeJSON", "json_safe"]
