"""Reading a user's text files — label lines, calibration, campaign, scene and sensor descriptions,
GeoJSON maps — so that a hostile file is refused in one line naming it, never obeyed.

:func:`read_text` refuses bytes that are not UTF-8 (naming the offset) and files too large for
what they are. :func:`load_structured` reads YAML (and so JSON) after a first pass over the
parser's events that refuses what would make the parser, or whatever walks its result, recurse
or expand without bound: nesting deeper than :data:`MAX_DEPTH` levels, aliases that expand to more
than :data:`MAX_VALUES` values, integers longer than Python converts (4,300 digits). The event pass
does not recurse, so a file of 100,000 ``[`` is refused with its line, not a ``RecursionError``.
:func:`check_json_depth` does the same for text given to :func:`json.loads`.
"""

from __future__ import annotations

import re
from os import PathLike
from pathlib import Path
from typing import Any

import yaml

from lidarfuzz.errors import DataFormatError
from lidarfuzz.io.guards import file_size, reading

#: Deepest nesting of lists and mappings a description may have (the deepest lidarfuzz writes is ~6).
MAX_DEPTH = 100
#: Most values a YAML file may expand to through its aliases (``&a`` … ``*a``).
MAX_VALUES = 1_000_000
#: Longest integer literal accepted (Python refuses to convert longer ones).
MAX_DIGITS = 4_000
#: Largest text file read whole (a label, calib, campaign or scene file is a few kilobytes).
MAX_TEXT_BYTES = 256 << 20
#: Largest YAML/JSON description (a 2,500-frame drive's scene file is 56 KB).
MAX_STRUCTURED_BYTES = 2 << 20
#: The safe loader, on libyaml's parser when PyYAML was built with it (same resolver and constructor).
_LOADER: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

_INTEGER = re.compile(r"[-+]?[0-9][0-9_]*")
_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_BRACKET = re.compile(r"[\[\]{}\n]")


def read_text(path: str | PathLike[str], what: str, *, limit: int = MAX_TEXT_BYTES) -> str:
    """A file's text as UTF-8; a DataFormatError naming the file when it is not text or too large.

    Args:
        path: The file.
        what: What the file should be, for the message (``"a KITTI label file"``).
        limit: Largest size in bytes.

    Example:
        >>> import tempfile, pathlib
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "label.txt"
        >>> _ = path.write_bytes(b"Car \\xff")
        >>> try:
        ...     read_text(path, "a KITTI label file")
        ... except DataFormatError as exc:
        ...     print(exc.message)
        not UTF-8 text (byte 0xff at offset 4): expected a KITTI label file
    """
    path = Path(path)
    size = file_size(path)
    if size > limit:
        raise DataFormatError(path, f"{size:,} bytes is too large for {what} (at most {limit:,})")
    with reading(path, f"read {what}"):
        data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataFormatError(path, f"not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}): "
                              f"expected {what}") from None


def _line_of(text: str, offset: int) -> int:
    return text.count("\n", 0, offset) + 1


def check_json_depth(text: str, path: str | PathLike[str], *, limit: int = MAX_DEPTH) -> None:
    """Refuse JSON nested deeper than ``limit`` levels (before :func:`json.loads` recurses into it),
    naming the line where it gets too deep."""
    depth = 0
    line = 1
    for match in _BRACKET.finditer(_JSON_STRING.sub('""', text)):
        char = match.group()
        if char == "\n":
            line += 1
        elif char in "[{":
            depth += 1
            if depth > limit:
                raise DataFormatError(path, f"nested deeper than {limit} levels", line=line)
        else:
            depth -= 1


def _too_deep(path: str | PathLike[str], event: Any, limit: int) -> DataFormatError:
    return DataFormatError(path, f"nested deeper than {limit} levels", line=event.start_mark.line + 1)


def check_yaml(text: str, path: str | PathLike[str], *, depth_limit: int = MAX_DEPTH,
               value_limit: int = MAX_VALUES, scalar_limit: int | None = None) -> None:
    """One pass over the YAML parser's events (libyaml's when installed, ~80 times faster; neither
    recurses) refusing deep nesting, alias expansion beyond ``value_limit`` values, over-long integers
    and, given ``scalar_limit``, longer values, naming the line."""
    sizes: dict[str, int] = {}
    stack: list[list[Any]] = [[None, 0]]  # [anchor, values below] per open collection
    total = 0
    try:
        for event in yaml.parse(text, Loader=_LOADER):
            if isinstance(event, yaml.CollectionStartEvent):
                stack.append([event.anchor, 1])
                if len(stack) - 1 > depth_limit:
                    raise _too_deep(path, event, depth_limit)
            elif isinstance(event, yaml.CollectionEndEvent):
                anchor, count = stack.pop()
                if anchor is not None:
                    sizes[anchor] = count
                stack[-1][1] += count
            elif isinstance(event, (yaml.ScalarEvent, yaml.AliasEvent)):
                count = 1
                if isinstance(event, yaml.AliasEvent):
                    count = sizes.get(str(event.anchor), 1)
                else:
                    if scalar_limit is not None and len(event.value) > scalar_limit:
                        raise DataFormatError(path, f"a value of {len(event.value):,} characters (at most "
                                              f"{scalar_limit:,})", line=event.start_mark.line + 1)
                    if not event.style and len(event.value) > MAX_DIGITS and _INTEGER.fullmatch(event.value):
                        raise DataFormatError(path, f"a number of {len(event.value):,} digits (at most {MAX_DIGITS:,})",
                                              line=event.start_mark.line + 1)
                    if event.anchor is not None:
                        sizes[event.anchor] = 1
                stack[-1][1] += count
                total = stack[0][1] + sum(level[1] for level in stack[1:])
                if total > value_limit:
                    raise DataFormatError(path, f"expands to more than {value_limit:,} values through its aliases "
                                          "(&anchor … *anchor)", line=event.start_mark.line + 1)
    except yaml.MarkedYAMLError as exc:  # libyaml >= 0.2.6 stops at 1,000 levels, scanning ahead of the events
        if exc.problem_mark is None or "nesting depth" not in (exc.problem or ""):
            raise
        raise DataFormatError(path, f"nested deeper than {depth_limit} levels",
                              line=exc.problem_mark.line + 1) from None


def load_structured(path: str | PathLike[str], what: str) -> Any:
    """Read a YAML or JSON file (YAML is a superset of JSON) safely: only plain data, checked by
    :func:`check_yaml` first; every error a DataFormatError naming the file and, where known, the line.

    Args:
        path: The file.
        what: What the file should be, for messages (``"a campaign file"``).
    """
    path = Path(path)
    text = read_text(path, what, limit=MAX_STRUCTURED_BYTES)
    with reading(path, f"read {what}"):  # what still escapes: an int(), a float() of the constructor
        try:
            check_yaml(text, path)
            data = yaml.load(text, Loader=_LOADER)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            line = mark.line + 1 if mark is not None else None
            if isinstance(exc, yaml.reader.ReaderError):  # a character YAML does not allow: its offset
                line = _line_of(text, exc.position)
            problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
            raise DataFormatError(path, f"not valid YAML/JSON: {problem}", line=line) from None
    return data


__all__ = ["MAX_DEPTH", "MAX_VALUES", "check_json_depth", "check_yaml", "load_structured", "read_text"]
