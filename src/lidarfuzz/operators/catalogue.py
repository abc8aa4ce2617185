"""The operator catalogue: parameter values and severity tables as text, as ``lidarfuzz operators``,
the web app's operator pages and docs/operators.md show them.

(Not the store's inventory of data sets and models: :mod:`lidarfuzz.store.inventory`.)"""

from __future__ import annotations

from typing import Any

from lidarfuzz.operators.base import Operator


def format_value(value: object) -> str:
    """A config value for a table: ``(0.2, 0.2)`` → ``0.2``, ``(5, 15)`` → ``5 – 15``, a list of
    names (``("median:3", "gaussian:3")``) → ``median:3, gaussian:3``."""
    if isinstance(value, tuple | list) and value and all(isinstance(v, str) for v in value):
        return ", ".join(value)
    if isinstance(value, tuple | list) and len(value) == 2 and value[0] == value[1]:
        return format_value(value[0])
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple | list):
        return " – ".join(format_value(v) for v in value)
    return str(value)


def severity_rows(cls: type[Operator[Any, Any, Any]]) -> list[tuple[str, str, list[str]]]:
    """One row per config field: (name, description, values at severity 0, 1, … 5)."""
    configs = [cls.at_severity(s).config.model_dump() for s in (0, *cls.SEVERITIES)]
    return [(field, info.description or "", [format_value(c[field]) for c in configs])
            for field, info in cls.ConfigModel.model_fields.items()]
