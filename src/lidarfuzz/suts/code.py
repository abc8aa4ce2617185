"""What identifies the code behind a system's output, for its fingerprint.

A system that keeps its name and version but runs other code must not be served the old
code's cached outputs, so :meth:`~lidarfuzz.suts.base.SystemUnderTest.fingerprint` covers
the code as well as the configuration and weights. The rule:

* **Python**: every class in the MRO of the system's class, and every extra object it names
  (a ``module:callable`` adapter's callable, ONNX pre/post hooks), by the module defining it:

  - a lidarfuzz module: every ``.py`` file of the module's package, sub-packages included
    (the SUT contract in ``lidarfuzz.suts`` makes that all of ``lidarfuzz/suts/``: the
    classic pipeline, its bug zoo, the learned detector and the adapters' conversions);
  - a module installed from another distribution (in site-packages): that distribution's
    name and version (its files are not read);
  - the standard library: nothing;
  - any other module (the user's): its source file's bytes.

  Helpers a user module imports from *other* modules of its own are not covered: name them
  in :meth:`~lidarfuzz.suts.base.SystemUnderTest.code_objects` or bump the version.
* **Programs** (``subprocess:``/``worker:``): the executable's bytes (a command name resolved
  on ``PATH``) and every argument naming an existing file (``python3 detector.py``: the
  script; ``--weights=w.pth``: the weights). ``python3 -m package`` is not resolved.

Keys are module names and arguments as written, never absolute paths, so the same code at
another place has the same fingerprint. A file is hashed once per process (cached by path,
size, inode and modification times): the files as they are on disk, so a module edited but
not re-imported in a long-lived process reads as the new code.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import inspect
import os
import shutil
import site
import sys
import sysconfig
from collections.abc import Iterable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

_DIGESTS: dict[tuple[str, int, int, int, int], str] = {}


def file_digest(path: str | Path) -> str:
    """SHA-256 of a file's bytes, computed once per process for each (path, inode, size, times)."""
    status = os.stat(path)
    key = (os.fspath(path), status.st_ino, status.st_size, status.st_mtime_ns, status.st_ctime_ns)
    found = _DIGESTS.get(key)
    if found is None:
        digest = hashlib.sha256()
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
        found = _DIGESTS[key] = digest.hexdigest()
    return found


@functools.cache
def _installed_roots() -> tuple[Path, ...]:
    """Folders third-party distributions are installed into (site-packages of this interpreter)."""
    found = {sysconfig.get_paths()[k] for k in ("purelib", "platlib")}
    found.update(getattr(site, "getsitepackages", list)())
    found.add(site.getusersitepackages())
    return tuple(Path(p).resolve() for p in found)


@functools.cache
def _distributions() -> dict[str, list[str]]:
    return dict(importlib.metadata.packages_distributions())


def distribution_version(name: str) -> str | None:
    """The installed version of distribution ``name``, or None when it is not installed."""
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def _modules_of(obj: Any) -> list[ModuleType]:
    """The modules whose code ``obj`` runs: a class's and its bases', a function's, an instance's class's."""
    if isinstance(obj, ModuleType):
        return [obj]
    if inspect.ismethod(obj):
        return _modules_of(obj.__func__) + _modules_of(type(obj.__self__))
    if isinstance(obj, functools.partial):
        return _modules_of(obj.func)
    classes = obj.__mro__ if isinstance(obj, type) else None
    if classes is None and inspect.isroutine(obj):
        module = sys.modules.get(getattr(obj, "__module__", "") or "")
        return [module] if module is not None else []
    if classes is None:
        classes = type(obj).__mro__
    return [m for m in (sys.modules.get(c.__module__) for c in classes) if m is not None]


def _source_file(module: ModuleType) -> Path | None:
    try:
        name = inspect.getsourcefile(module)
    except TypeError:  # a built-in module
        name = None
    name = name or getattr(module, "__file__", None)
    return Path(name) if name else None


def _installed(path: Path) -> bool:
    resolved = path.resolve()
    return any(resolved.is_relative_to(root) for root in _installed_roots())


def _package_files(module: ModuleType, source: Path) -> dict[str, str]:
    """Every ``.py`` file of a lidarfuzz module's package, keyed by its path from ``lidarfuzz/``."""
    root = Path(inspect.getfile(sys.modules["lidarfuzz"])).parent
    folder = source.parent
    out = {}
    for path in sorted(folder.rglob("*.py")):
        relative = path.relative_to(folder)
        if any(part.startswith((".", "__pycache__")) for part in relative.parts[:-1]):
            continue
        out[f"lidarfuzz/{path.relative_to(root).as_posix()}"] = file_digest(path)
    return out


def _module_identity(module: ModuleType) -> dict[str, str]:
    name = module.__name__
    top = name.partition(".")[0]
    if top in sys.stdlib_module_names or top == "builtins":
        return {}
    source = _source_file(module)
    if source is None or not source.is_file():
        return {}
    if top == "lidarfuzz":
        return _package_files(module, source)
    if _installed(source):
        dists = _distributions().get(top, [])
        if dists:
            return {f"dist:{d}": distribution_version(d) or "?" for d in dists}
    return {name: file_digest(source)}


def python_code(objects: Iterable[Any]) -> dict[str, str]:
    """The code identity of Python ``objects`` (classes, functions, modules, instances) by the
    rule in the module docstring: ``{key: digest or version}``, sorted by key.

    Example:
        >>> from lidarfuzz.suts.classic import ClassicPipeline
        >>> "lidarfuzz/suts/classic/pipeline.py" in python_code([ClassicPipeline])
        True
    """
    out: dict[str, str] = {}
    seen: set[str] = set()
    for obj in objects:
        for module in _modules_of(obj):
            if module.__name__ not in seen:
                seen.add(module.__name__)
                out.update(_module_identity(module))
    return dict(sorted(out.items()))


def _resolve_command(command: str, cwd: str | None) -> Path | None:
    if os.sep in command or (os.altsep and os.altsep in command):
        path = Path(command) if os.path.isabs(command) else Path(cwd or ".") / command
        return path if path.is_file() else None
    found = shutil.which(command)
    return Path(found) if found else None


def program_code(argv: Sequence[str], cwd: str | None = None) -> dict[str, str]:
    """The code identity of a program run as ``argv`` from ``cwd``: the executable's digest
    (``"not found"`` when there is none) and the digest of every argument naming a file
    (placeholders such as ``{points}`` are skipped), keyed by the arguments as written."""
    executable = _resolve_command(argv[0], cwd)
    out = {f"program:{argv[0]}": file_digest(executable) if executable is not None else "not found"}
    for arg in argv[1:]:
        candidates = [arg]
        if arg.startswith("-") and "=" in arg:
            candidates.append(arg.partition("=")[2])
        for candidate in candidates:
            if not candidate or "{" in candidate:
                continue
            path = Path(candidate) if os.path.isabs(candidate) else Path(cwd or ".") / candidate
            if path.is_file():
                out[f"file:{candidate}"] = file_digest(path)
    return out


__all__ = ["distribution_version", "file_digest", "program_code", "python_code"]
