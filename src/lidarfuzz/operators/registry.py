"""Finding operators by name: built-ins and plugins, both through the ``lidarfuzz.operators`` entry points.

A package adds an operator by declaring, in its ``pyproject.toml``::

    [project.entry-points."lidarfuzz.operators"]
    my_operator = "my_package.module:MyOperator"

Names and aliases are matched case-insensitively, with ``-`` and ``_`` equivalent.
"""

from __future__ import annotations

from functools import cache
from importlib.metadata import entry_points
from typing import Any

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.operators.base import Operator

GROUP = "lidarfuzz.operators"


class UnknownOperatorError(LidarfuzzError, KeyError):
    def __init__(self, name: str, known: list[str]) -> None:
        self.name = name
        super().__init__(f"unknown operator {name!r}; known: {', '.join(known)} (see lidarfuzz operators)")

    def __str__(self) -> str:
        return str(self.args[0])


def _key(name: str) -> str:
    return name.strip().lower().replace("-", "_")


@cache
def available() -> dict[str, type[Operator[Any, Any, Any]]]:
    """Every registered operator class by its name, built-ins first (loaded once per process)."""
    found: dict[str, type[Operator[Any, Any, Any]]] = {}
    for entry in sorted(entry_points(group=GROUP), key=lambda e: (not e.value.startswith("lidarfuzz."), e.name)):
        cls = entry.load()
        if not (isinstance(cls, type) and issubclass(cls, Operator)):
            raise LidarfuzzError(f"entry point {entry.name} = {entry.value} in group {GROUP} is not an Operator class")
        found.setdefault(cls.name, cls)
    return found


def _index() -> dict[str, type[Operator[Any, Any, Any]]]:
    index: dict[str, type[Operator[Any, Any, Any]]] = {}
    for name, cls in available().items():
        for alias in (name, *cls.aliases):
            index.setdefault(_key(alias), cls)
    return index


def get(name: str) -> type[Operator[Any, Any, Any]]:
    """The operator class called ``name`` (or one of its aliases)."""
    try:
        return _index()[_key(name)]
    except KeyError:
        raise UnknownOperatorError(name, sorted(available())) from None


def from_spec(spec: dict[str, Any]) -> Operator[Any, Any, Any]:
    """Rebuild an operator from :meth:`Operator.spec` output (composites included)."""
    from lidarfuzz.operators.compose import COMPOSITES

    name = spec.get("name")
    if not isinstance(name, str):
        raise LidarfuzzError(f"an operator spec needs a name, got {spec!r}")
    if name in COMPOSITES:
        return COMPOSITES[name].from_spec(spec)
    cls = get(name)
    return cls(**spec.get("config", {}))
