"""Every environment variable lidarfuzz reads, in one place.

========================  ===================================================  ==========================
variable                  meaning                                              default
========================  ===================================================  ==========================
``LIDARFUZZ_WORKSPACE``   workspace of the CLI: a folder (its SQLite store,    ``lidarfuzz-workspace``
                          data sets and reports) or a database URL
``LIDARFUZZ_CACHE``       cache folder: training profiles of watched neurons   ``~/.cache/lidarfuzz``
                          (``profiles/``) and the object library insertion
                          operators cut from simulator frames
``LIDARFUZZ_TOKEN``       token ``lidarfuzz serve`` requires on every API      none
                          call (``--token`` overrides it)
``LIDARFUZZ_LOG_LEVEL``   log level of the web server: critical, error,        ``warning``
                          warning, info, debug or trace
========================  ===================================================  ==========================

A variable set to an empty string counts as unset. Values are read from the environment
when asked for (``settings().cache``), so a test or a caller that changes the environment
is seen at once, and checked when read: a value that cannot be what the variable needs
raises :class:`SettingsError`, one line naming the variable — only for code that uses it.

Example:
    >>> Settings({"LIDARFUZZ_LOG_LEVEL": "INFO"}).log_level
    'info'
    >>> Settings({}).workspace
    'lidarfuzz-workspace'
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from lidarfuzz.errors import LidarfuzzError

LOG_LEVELS = ("critical", "error", "warning", "info", "debug", "trace")


class SettingsError(LidarfuzzError, ValueError):
    """An environment variable whose value cannot be used (the message names it)."""


@dataclass(frozen=True)
class Variable:
    """One environment variable: its name, what it means and its default (as text)."""

    name: str
    meaning: str
    default: str | None


#: Every variable lidarfuzz reads, by name (the module docstring's table).
VARIABLES: dict[str, Variable] = {v.name: v for v in (
    Variable("LIDARFUZZ_WORKSPACE", "workspace of the CLI: a folder or a database URL", "lidarfuzz-workspace"),
    Variable("LIDARFUZZ_CACHE", "cache folder (neuron profiles, the insertion operators' object library)",
             "~/.cache/lidarfuzz"),
    Variable("LIDARFUZZ_TOKEN", "token lidarfuzz serve requires on every API call", None),
    Variable("LIDARFUZZ_LOG_LEVEL", f"log level of the web server: {', '.join(LOG_LEVELS)}", "warning"),
)}


@dataclass(frozen=True)
class Settings:
    """The ``LIDARFUZZ_*`` variables of an environment (``os.environ`` by default), each parsed when read.

    Args:
        environ: The variables to read; a snapshot of them is kept.
    """

    environ: Mapping[str, str] = field(default_factory=lambda: dict(os.environ))

    def __post_init__(self) -> None:
        snapshot = {k: v for k, v in self.environ.items() if k.startswith("LIDARFUZZ_")}
        object.__setattr__(self, "environ", snapshot)

    def _text(self, name: str) -> str | None:
        value = self.environ.get(name, "").strip()
        return value or VARIABLES[name].default

    @property
    def workspace(self) -> str:
        """``$LIDARFUZZ_WORKSPACE``: a folder or a database URL (text: a path would fold a URL's ``//``)."""
        return self._text("LIDARFUZZ_WORKSPACE") or ""

    @property
    def cache(self) -> Path:
        """``$LIDARFUZZ_CACHE``, by default ``~/.cache/lidarfuzz``."""
        value = self.environ.get("LIDARFUZZ_CACHE", "").strip()
        return Path(value) if value else Path.home() / ".cache" / "lidarfuzz"

    @property
    def token(self) -> str | None:
        """``$LIDARFUZZ_TOKEN``, or ``None``."""
        return self._text("LIDARFUZZ_TOKEN")

    @property
    def log_level(self) -> str:
        """``$LIDARFUZZ_LOG_LEVEL`` in lower case, one of :data:`LOG_LEVELS`.

        Raises:
            SettingsError: Another value.
        """
        value = (self._text("LIDARFUZZ_LOG_LEVEL") or "").lower()
        if value not in LOG_LEVELS:
            raise SettingsError(f"LIDARFUZZ_LOG_LEVEL={self.environ['LIDARFUZZ_LOG_LEVEL']!r} is not a log level; "
                                f"expected one of {', '.join(LOG_LEVELS)}")
        return value


def settings() -> Settings:
    """The settings of the current environment (read now)."""
    return Settings()
