"""Classes found through entry points: the one mechanism for built-ins and third-party plugins.

A package adds, say, a metamorphic relation by declaring in its ``pyproject.toml``::

    [project.entry-points."lidarfuzz.relations"]
    my_relation = "my_package.module:MyRelation"

Names and aliases are matched case-insensitively, with ``-`` and ``_`` equivalent;
built-ins (entry points of ``lidarfuzz`` itself) win over plugins of the same name.
"""

from __future__ import annotations

from functools import cache
from importlib.metadata import entry_points
from typing import Any

from lidarfuzz.errors import LidarfuzzError


class UnknownPluginError(LidarfuzzError, KeyError):
    """A name that no entry point of the group provides."""

    def __init__(self, kind: str, name: str, known: list[str], hint: str = "") -> None:
        self.name = name
        text = f"unknown {kind} {name!r}; known: {', '.join(known)}"
        super().__init__(f"{text} ({hint})" if hint else text)

    def __str__(self) -> str:
        return str(self.args[0])


def plugin_key(name: str) -> str:
    return name.strip().lower().replace("-", "_")


@cache
def load_group(group: str, base: type) -> dict[str, type[Any]]:
    """Every class registered under ``group`` by its ``name`` attribute, built-ins first (loaded once)."""
    found: dict[str, type[Any]] = {}
    for entry in sorted(entry_points(group=group), key=lambda e: (not e.value.startswith("lidarfuzz."), e.name)):
        cls = entry.load()
        if not (isinstance(cls, type) and issubclass(cls, base)):
            raise LidarfuzzError(f"entry point {entry.name} = {entry.value} in group {group} is not a {base.__name__}")
        found.setdefault(cls.name, cls)
    return found


def find(group: str, base: type, name: str, kind: str, hint: str = "") -> type[Any]:
    """The class of ``group`` called ``name`` or one of its ``aliases``."""
    index: dict[str, type[Any]] = {}
    classes = load_group(group, base)
    for cls_name, cls in classes.items():
        for alias in (cls_name, *getattr(cls, "aliases", ())):
            index.setdefault(plugin_key(alias), cls)
    try:
        return index[plugin_key(name)]
    except KeyError:
        raise UnknownPluginError(kind, name, sorted(classes), hint) from None
