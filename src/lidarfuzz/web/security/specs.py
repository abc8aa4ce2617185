"""Which systems under test the API may register: built-in and plugin names, ``module:callable``
from an installed ``lidarfuzz.suts`` plugin's module, and ``onnx:`` / ``open3d:`` files among the
uploads. ``subprocess:`` and ``worker:`` specs, other imports and files outside the uploads are
for the CLI and campaign files only."""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from fastapi import HTTPException, status

from lidarfuzz.plugins import declared
from lidarfuzz.web.security.paths import within

CLI_ONLY_SCHEMES = ("subprocess", "worker")
FILE_SCHEMES = ("onnx", "open3d")
IMPORT_SPEC = re.compile(r"^\s*[A-Za-z_][\w.]*\s*:\s*[A-Za-z_][\w.]*\s*$")


def _entry_point_modules() -> set[str]:
    return {entry.value.partition(":")[0].strip() for entry in declared("lidarfuzz.suts")}


def _forbidden(detail: str) -> HTTPException:
    return HTTPException(status.HTTP_403_FORBIDDEN, detail)


def check_options(options: dict[str, Any], uploads: Path, field: str = "options") -> None:
    """Options given through the API may not name code to import or files outside the uploads."""
    for key, value in options.items():
        for item in (value if isinstance(value, list | tuple) else [value]):
            if not isinstance(item, str):
                continue
            if IMPORT_SPEC.match(item) and not re.match(r"^[A-Za-z]:[\\/]", item):
                raise _forbidden(f"{field}.{key}: {item!r} names code to import; options like this can only be "
                                 "given from the CLI or a campaign file")
            if ("/" in item or "\\" in item) and not within(Path(item), uploads):
                raise _forbidden(f"{field}.{key}: {item!r} is a file outside the uploads; upload it first")


def check_model_spec(spec: str, uploads: Path, options: Iterable[tuple[str, Any]] = (), field: str = "spec") -> None:
    """Refuse (403) a SUT spec the API may not register.

    Allowed: built-in and plugin names (``classic``, ``pillars?threads=2``), ``module:callable``
    in a module that an installed ``lidarfuzz.suts`` entry point comes from, and ``onnx:`` /
    ``open3d:`` specs of uploaded files. Refused: ``subprocess:`` and ``worker:`` (they run a
    command line: CLI or campaign file only), any other import, files outside the uploads.
    """
    from lidarfuzz.suts.registry import split_spec

    text = spec.strip()
    scheme, sep, rest = text.partition(":")
    if sep and scheme in CLI_ONLY_SCHEMES:
        raise _forbidden(f"{field}: {scheme}: systems run a command line; they can only be registered from the CLI "
                         f"(lidarfuzz models add) or a campaign file, not through the web API")
    base, query = split_spec(rest if sep and scheme in FILE_SCHEMES else text)
    if sep and scheme in FILE_SCHEMES:
        if not within(Path(base), uploads):
            raise _forbidden(f"{field}: {base!r} is not an uploaded file; upload it with POST /api/models/upload")
        if scheme == "open3d":
            config = dict(query).get("config", dict(options).get("config", ""))
            if isinstance(config, str) and config.endswith((".yml", ".yaml")):
                raise _forbidden(f"{field}: an Open3D-ML configuration file can only be given from the CLI; "
                                 f"use a bundled name such as pointpillars_kitti")
    elif ":" in base:
        module = base.partition(":")[0].strip()
        if module not in _entry_point_modules():
            raise _forbidden(f"{field}: {base!r} imports code from {module!r}, which no installed lidarfuzz.suts "
                             f"plugin provides; register it from the CLI (lidarfuzz models add)")
    check_options({**query, **dict(options)}, uploads)


__all__ = ["CLI_ONLY_SCHEMES", "FILE_SCHEMES", "check_model_spec", "check_options"]
