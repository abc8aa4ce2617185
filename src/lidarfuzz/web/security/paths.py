"""Names and paths that come from clients: plain names for data sets and models, frame ids that
are never paths, upload file names reduced to safe characters, and containment checks that keep
every file operation inside its folder."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

from fastapi import HTTPException, status

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")
FRAME_ID = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]{0,199}$")


def check_name(value: str, field: str) -> str:
    """A name a user gives a data set or model: letters, digits, ``. _ -``; no path."""
    if not NAME.match(value or "") or ".." in value:
        raise HTTPException(status.HTTP_400_BAD_REQUEST,
                            f"{field}: {value!r} is not a plain name (letters, digits, '.', '_', '-'; "
                            f"at most 100; no '/' or '..')")
    return value


def check_frame_id(value: str) -> str:
    """A frame id from a URL: never a path (no separators, no ``..``)."""
    if not FRAME_ID.match(value or "") or ".." in value:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"frame_id: {value!r} is not a frame id")
    return value


def safe_component(name: str) -> str:
    """One path component of an uploaded file, reduced to safe characters (never empty or dotted)."""
    cleaned = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".")
    return cleaned[:150] or "file"


def within(path: Path, root: Path) -> bool:
    """Whether ``path`` (resolved) lies inside ``root`` (resolved)."""
    try:
        path.resolve().relative_to(root.resolve())
    except ValueError:
        return False
    return True


def remove_tree(path: Path, root: Path) -> None:
    """Delete an upload folder — only ever one inside ``root``."""
    if within(path, root) and path.resolve() != root.resolve():
        shutil.rmtree(path, ignore_errors=True)


__all__ = ["FRAME_ID", "NAME", "check_frame_id", "check_name", "remove_tree", "safe_component", "within"]
