"""What every reader of a user's file uses so that a hostile file is refused, never obeyed.

A file's header is a claim: a count of points, of records, of bytes. Before anything is
allocated from a claim it is checked against what the file can hold (:func:`require_bytes`),
and whatever a library raises on malformed input — numpy's ``MemoryError``, a tokenizer's
``SyntaxError``, ``RecursionError``, ``zipfile.BadZipFile``, ``OverflowError`` — leaves
through :func:`reading` as a :class:`~lidarfuzz.errors.DataFormatError` naming the file.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from os import PathLike
from pathlib import Path

from lidarfuzz.errors import DataFormatError, LidarfuzzError

#: Library modules whose exception names say little alone (a bare ``KeyError('x')``).
_TERSE = ("builtins", "struct", "_struct", "zlib", "zipfile", "numpy", "numpy.linalg", "_io", "io")


def describe(err: BaseException) -> str:
    """An exception as one line: its message, prefixed by its type where the message alone says little."""
    detail = str(err).splitlines()[0] if str(err).strip() else type(err).__name__
    terse = type(err).__module__ in _TERSE or isinstance(err, (KeyError, IndexError, TypeError, ValueError))
    if terse and not detail.startswith(type(err).__name__):
        detail = f"{type(err).__name__}: {detail}"
    return detail[:300]


@contextlib.contextmanager
def reading(path: str | PathLike[str], what: str, *, hint: str | None = None) -> Iterator[None]:
    """Turn any error a library raises on malformed input into a DataFormatError naming the file.

    Args:
        path: The file being read.
        what: What was being done, completing "cannot …" (``"read the PCD header"``).
        hint: What the user can do, appended to the message.

    Example:
        >>> try:
        ...     with reading("scan.npy", "read the array"):
        ...         raise MemoryError
        ... except DataFormatError as exc:
        ...     print(exc)
        scan.npy: cannot read the array: its header claims more memory than this machine has
    """
    try:
        yield
    except LidarfuzzError:
        raise
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except IsADirectoryError:
        raise DataFormatError(path, "is a folder, not a file") from None
    except MemoryError:
        raise DataFormatError(path, f"cannot {what}: its header claims more memory than this machine has",
                              hint=hint) from None
    except RecursionError:
        raise DataFormatError(path, f"cannot {what}: it is nested too deeply", hint=hint) from None
    except Exception as err:
        raise DataFormatError(path, f"cannot {what}: {describe(err)}", hint=hint) from err


def file_size(path: str | PathLike[str]) -> int:
    """The size of a file in bytes (a DataFormatError naming it when it cannot be examined)."""
    try:
        return os.stat(path).st_size
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except OSError as err:
        raise DataFormatError(path, f"cannot examine the file: {err.strerror or err}") from None


def require_bytes(path: str | PathLike[str], needed: int, available: int, *, field: str | None = None,
                  what: str = "the data") -> None:
    """Refuse a header's claim before allocating for it: ``needed`` bytes of ``what`` must fit in the
    ``available`` bytes the file really has after its header.

    Raises:
        DataFormatError: naming the file and ``field`` (the header field that claims too much).
    """
    if needed < 0 or needed > available:
        raise DataFormatError(
            Path(path), f"the header claims {needed:,} bytes of {what} but the file holds {max(available, 0):,}",
            field=field, hint="the file is truncated or its header is damaged")
