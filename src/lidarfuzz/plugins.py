"""Classes found through entry points: the one mechanism for built-ins and third-party plugins.

A package adds, say, a metamorphic relation by declaring in its ``pyproject.toml``::

    [project.entry-points."lidarfuzz.relations"]
    my_relation = "my_package.module:MyRelation"

Names and aliases are matched case-insensitively, with ``-`` and ``_`` equivalent;
built-ins (entry points of ``lidarfuzz`` itself) win over plugins of the same name.

A broken third-party entry point — its module does not import, its object is not the
group's kind of class — is left out with a :class:`PluginWarning` naming it (entry point
name and value, the error in one line); the rest of the group loads. A broken built-in is a
bug in lidarfuzz and raises.
"""

from __future__ import annotations

import warnings
from functools import cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from lidarfuzz.errors import LidarfuzzError


class PluginWarning(UserWarning):
    """A third-party entry point that could not be loaded and was left out."""


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


def is_builtin(entry: EntryPoint) -> bool:
    """Whether an entry point is one of lidarfuzz's own."""
    return entry.value.startswith("lidarfuzz.")


def declared(group: str) -> list[EntryPoint]:
    """The entry points of ``group``, built-ins first, without loading any of them."""
    return sorted(entry_points(group=group), key=lambda e: (not is_builtin(e), e.name))


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _load(entry: EntryPoint, group: str, base: type) -> type[Any]:
    cls = entry.load()
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise LidarfuzzError(f"entry point {entry.name} = {entry.value} in group {group} is not a {base.__name__}")
    if not isinstance(getattr(cls, "name", None), str):
        raise LidarfuzzError(f"entry point {entry.name} = {entry.value} in group {group}: {cls.__name__} has no name")
    return cls


@cache
def load_group(group: str, base: type) -> dict[str, type[Any]]:
    """Every class registered under ``group`` by its ``name`` attribute, built-ins first (loaded once).

    A third-party entry point that fails to load or is not a ``base`` subclass is skipped with
    a :class:`PluginWarning`; a built-in one raises.
    """
    found: dict[str, type[Any]] = {}
    for entry in declared(group):
        try:
            cls = _load(entry, group, base)
        except Exception as exc:
            if is_builtin(entry):
                raise
            warnings.warn(f"plugin {entry.name} = {entry.value} (group {group}) left out: {_one_line(exc)}",
                          PluginWarning, stacklevel=2)
            continue
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
