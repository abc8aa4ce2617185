"""What code to cover: modules, packages, classes and functions of a Python system under test.

A :class:`CodeTarget` is written ``pkg.module`` (every function of a module, or of every module
of a package), ``pkg.module:Class`` (its methods), ``pkg.module:Class.method`` or
``pkg.module:function``. A function target includes the functions nested in it. Code run at
import time (module and class bodies) is not a target: it does not run per frame.

The functions of a file and their executable lines come from coverage.py's own analysis
(:meth:`FileReporter.code_regions` and :meth:`FileReporter.lines`), so what is measured and what
is counted agree line for line, ``# pragma: no cover`` exclusions included.

Example:
    >>> target = CodeTarget.parse("lidarfuzz.structural.requirements:union")
    >>> [f.name for f in target.functions()]
    ['lidarfuzz.structural.requirements:union']
"""

from __future__ import annotations

import importlib.util
import re
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from coverage.control import Coverage
from coverage.python import PythonFileReporter

from lidarfuzz.errors import LidarfuzzError

_DOTTED = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*\Z")


@dataclass(frozen=True)
class SourceFunction:
    """One function or method of a target, as coverage.py sees it.

    Attributes:
        module: Dotted module name.
        qualname: ``Class.method``, ``function`` or ``outer.inner``.
        filename: Absolute path of its source file.
        start: The ``def`` line.
        statements: Its executable lines (first lines of multi-line statements), nested
            functions' bodies excluded.
    """

    module: str
    qualname: str
    filename: str
    start: int
    statements: frozenset[int]

    @property
    def name(self) -> str:
        """``module:qualname``, the :attr:`Requirement.function` of its requirements."""
        return f"{self.module}:{self.qualname}"


@cache
def _settings() -> Coverage:
    # config_file=False: a user's .coveragerc must not change what counts as a statement here
    return Coverage(branch=True, data_file=None, config_file=False)


def file_reporter(filename: str) -> PythonFileReporter:
    """coverage.py's reporter of one Python file (its parser: statements, arcs, regions)."""
    return PythonFileReporter(filename, _settings())


def _module_files(module: str, text: str) -> list[tuple[str, Path]]:
    """``(module name, source file)`` of a module, or of every module of a package."""
    try:
        spec = importlib.util.find_spec(module)
    except ModuleNotFoundError:
        spec = None
    except (ImportError, ValueError) as exc:
        raise LidarfuzzError(f"code target '{text}': cannot import module '{module}' ({exc})") from None
    if spec is None:
        raise LidarfuzzError(f"code target '{text}': no module named '{module}'")
    if spec.submodule_search_locations:
        found = []
        for folder in spec.submodule_search_locations:
            for path in sorted(Path(folder).rglob("*.py")):
                parts = list(path.relative_to(folder).with_suffix("").parts)
                if parts[-1] == "__init__":
                    parts.pop()
                if all(p.isidentifier() for p in parts):
                    found.append((".".join([module, *parts]), path.resolve()))
        return found
    if spec.origin is None or not spec.origin.endswith(".py"):
        raise LidarfuzzError(f"code target '{text}': module '{module}' has no Python source ({spec.origin})")
    return [(module, Path(spec.origin).resolve())]


def functions_of_file(module: str, filename: str) -> list[SourceFunction]:
    """Every function and method of one file, in source order."""
    reporter = file_reporter(filename)
    statements = reporter.lines()
    out = [
        SourceFunction(module, region.name, reporter.filename, region.start, frozenset(region.lines & statements))
        for region in reporter.code_regions() if region.kind == "function"
    ]
    return sorted(out, key=lambda f: f.start)


@dataclass(frozen=True)
class CodeTarget:
    """A module, package, class or function to cover.

    Attributes:
        module: Dotted module or package name.
        qualname: A class, ``Class.method`` or function inside it; ``None`` for the whole module.
    """

    module: str
    qualname: str | None = None

    @classmethod
    def parse(cls, text: str) -> CodeTarget:
        """``pkg.module``, ``pkg.module:Class``, ``pkg.module:Class.method`` or ``pkg.module:function``."""
        module, colon, qualname = text.strip().partition(":")
        if not _DOTTED.match(module) or (colon and not _DOTTED.match(qualname)):
            raise LidarfuzzError(f"code target '{text}': expected 'pkg.module' or 'pkg.module:Name[.name]'")
        return cls(module, qualname if colon else None)

    def __str__(self) -> str:
        return self.module if self.qualname is None else f"{self.module}:{self.qualname}"

    def functions(self) -> list[SourceFunction]:
        """The functions this target covers; one-line error when the module or name does not exist."""
        files = _module_files(self.module, str(self))
        found = [f for module, path in files for f in functions_of_file(module, str(path))]
        if self.qualname is None:
            return found
        prefix = self.qualname + "."
        chosen = [f for f in found if f.qualname == self.qualname or f.qualname.startswith(prefix)]
        if not chosen:
            classes = {
                region.name for _, path in files for region in file_reporter(str(path)).code_regions()
                if region.kind == "class"
            }
            if self.qualname in classes:
                raise LidarfuzzError(f"code target '{self}': class '{self.qualname}' has no method to cover")
            raise LidarfuzzError(f"code target '{self}': module '{self.module}' has no function or class "
                                 f"'{self.qualname}'")
        return chosen


def resolve(targets: list[str] | tuple[str, ...]) -> list[SourceFunction]:
    """The functions of several targets (each once, by file and line)."""
    seen: dict[tuple[str, int], SourceFunction] = {}
    for text in targets:
        for function in CodeTarget.parse(text).functions():
            seen.setdefault((function.filename, function.start), function)
    return sorted(seen.values(), key=lambda f: (f.filename, f.start))


__all__ = ["CodeTarget", "SourceFunction", "file_reporter", "functions_of_file", "resolve"]
