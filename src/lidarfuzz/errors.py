"""Errors a user can act on.

Every problem with user data is raised as a :class:`DataFormatError` that names the
file, and where known the line and field, and says what was expected. Nothing in
lidarfuzz lets a raw ``struct``/``numpy`` traceback reach the user for bad input.
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path
from typing import Any


class LidarfuzzError(Exception):
    """Base class of every error lidarfuzz raises on purpose.

    ``cli``: what to run about it from the command line, shown after the message in a terminal
    (``str(exc)``) and left out where there is no command line (the web app shows :attr:`plain`).

    Example:
        >>> exc = LidarfuzzError("no data set called 'x'", cli="lidarfuzz datasets list")
        >>> str(exc), exc.plain
        ("no data set called 'x' (lidarfuzz datasets list)", "no data set called 'x'")
    """

    def __init__(self, *args: Any, cli: str | None = None) -> None:
        self.cli = cli
        if cli and args:
            args = (f"{args[0]} ({cli})", *args[1:])
        super().__init__(*args)
        self._plain = str(args[0]).removesuffix(f" ({cli})") if args else ""

    @property
    def plain(self) -> str:
        """The message without the command-line advice."""
        return getattr(self, "_plain", None) or str(self)


class DataFormatError(LidarfuzzError, ValueError):
    """A data file is malformed or does not match what lidarfuzz expects.

    Args:
        path: The offending file (or directory).
        message: What is wrong and what was expected.
        line: 1-based line number for text formats.
        field: The field, key or column that is wrong.
        hint: What the user can do about it.

    Example:
        >>> str(DataFormatError("calib/000001.txt", "missing key 'P2'", line=None))
        "calib/000001.txt: missing key 'P2'"
    """

    def __init__(
        self,
        path: str | PathLike[str],
        message: str,
        *,
        line: int | None = None,
        field: str | None = None,
        hint: str | None = None,
    ) -> None:
        self.path = Path(path)
        self.message = message
        self.line = line
        self.field = field
        self.hint = hint
        super().__init__(self._render())

    def _render(self) -> str:
        where = str(self.path)
        if self.line is not None:
            where += f":{self.line}"
        text = f"{where}: "
        if self.field is not None:
            text += f"field '{self.field}': "
        text += self.message
        if self.hint:
            text += f" ({self.hint})"
        return text


class MissingDependencyError(LidarfuzzError, ImportError):
    """An optional dependency is needed; the message names the extra to install."""

    def __init__(self, package: str, extra: str, purpose: str) -> None:
        super().__init__(
            f"{purpose} needs the '{package}' package; install it with "
            f"\"pip install 'lidarfuzz[{extra}]'\""
        )


def validation_error(path: str | PathLike[str], exc: Any) -> DataFormatError:
    """The first error of a pydantic ``ValidationError`` as a DataFormatError naming the key path
    (``operators.1.severities.0``)."""
    first = exc.errors()[0]
    where = ".".join(str(part) for part in first["loc"]) or "<root>"
    more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
    return DataFormatError(path, f"{first['msg']}{more}", field=where)
