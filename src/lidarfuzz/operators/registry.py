"""Finding operators by name: built-ins and plugins, both through the ``lidarfuzz.operators`` entry points.

A package adds an operator by declaring, in its ``pyproject.toml``::

    [project.entry-points."lidarfuzz.operators"]
    my_operator = "my_package.module:MyOperator"

Names and aliases are matched case-insensitively, with ``-`` and ``_`` equivalent.
"""

from __future__ import annotations

from typing import Any

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.operators.base import Operator
from lidarfuzz.operators.compose import COMPOSITES
from lidarfuzz.plugins import UnknownPluginError, find, load_group

GROUP = "lidarfuzz.operators"
#: Raised for names no operator has (kept under its historical name).
UnknownOperatorError = UnknownPluginError


def available() -> dict[str, type[Operator[Any, Any, Any]]]:
    """Every registered operator class by its name, built-ins first (loaded once per process)."""
    return load_group(GROUP, Operator)


def get(name: str) -> type[Operator[Any, Any, Any]]:
    """The operator class called ``name`` (or one of its aliases)."""
    return find(GROUP, Operator, name, "operator", "see lidarfuzz operators")


def from_spec(spec: dict[str, Any]) -> Operator[Any, Any, Any]:
    """Rebuild an operator from :meth:`Operator.spec` output (composites included, children first)."""
    name = spec.get("name")
    if not isinstance(name, str):
        raise LidarfuzzError(f"an operator spec needs a name, got {spec!r}")
    if name in COMPOSITES:
        children = [from_spec(child) for child in spec.get("operators", [])]
        return COMPOSITES[name].from_children(children, spec)
    cls = get(name)
    return cls(**spec.get("config", {}))
