"""What the commands share: the consoles, the common options, opening the store, and listings.

Kept cheap to import (Typer and Rich's console only): every command module imports it, and
``lidarfuzz --help`` imports every command module. Heavy libraries are imported inside the
command functions that use them.

Listings (``operators``, ``relations``, ``suts``, ``list``, ``datasets list``, ``models list``)
go through :func:`print_listing`: a table whose name columns are never cut, as wide as it needs
when the output is not a terminal (``lidarfuzz operators | grep …`` sees whole names), one
tab-separated row a line with ``--plain``, or JSON with ``--json``.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from importlib.util import find_spec
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console

from lidarfuzz.errors import LidarfuzzError
from lidarfuzz.settings import settings

if TYPE_CHECKING:
    from rich.table import Table

    from lidarfuzz.store import Store

console = Console()
err_console = Console(stderr=True)

WORKSPACE = settings().workspace
# A str, not a Path: a Path would fold the "//" of a database URL.
WorkspaceOption = Annotated[str, typer.Option(help="Workspace folder (its SQLite store) or a database URL "
                                                    "(postgresql+psycopg://…); $LIDARFUZZ_WORKSPACE.")]
LayoutOption = Annotated[str | None, typer.Option(
    help="Point layout of headerless scans: kitti, kitti360, nuscenes, semantickitti, argoverse2, waymo, or the "
         "columns, e.g. x,y,z,intensity,ring:f4 (default: what the data's structure says, else kitti).")]
AllowUnlabelledOption = Annotated[bool, typer.Option(
    help="Frames without a label file in a labelled data set are allowed: campaigns run them through the "
         "system and relations and score AP on the labelled frames only.")]
JsonOption = Annotated[bool, typer.Option("--json", help="Print the listing as JSON (for scripts).")]
PlainOption = Annotated[bool, typer.Option("--plain", help="Print one tab-separated row a line, no header "
                                                           "(for grep, cut and awk).")]

#: PostgreSQL drivers SQLAlchemy may be told to use, by the module they need.
_POSTGRES_DRIVERS = {"psycopg": "psycopg", "psycopg2": "psycopg2", "asyncpg": "asyncpg", "pg8000": "pg8000"}


def check_store_driver(workspace: str | Path) -> None:
    """Raise a clear error when a PostgreSQL store URL names a driver that is not installed.

    The driver (psycopg) comes with the ``postgres`` extra; a workspace folder (SQLite) needs none.
    """
    text = str(workspace)
    if "://" not in text:
        return
    scheme = text.partition("://")[0].lower()
    dialect, _, driver = scheme.partition("+")
    if dialect not in ("postgresql", "postgres"):
        return
    module = _POSTGRES_DRIVERS.get(driver or "psycopg2", driver)
    if find_spec(module) is not None:
        return
    if driver == "psycopg" or find_spec("psycopg") is None:
        raise LidarfuzzError(f"{scheme}:// store: the PostgreSQL driver ({module}) is not installed: "
                             f"pip install 'lidarfuzz[postgres]'")
    raise LidarfuzzError(f"{scheme}:// store: the driver {module} is not installed; the one lidarfuzz installs "
                         f"is psycopg: postgresql+psycopg://… (pip install 'lidarfuzz[postgres]')")


def open_store(workspace: str | Path, *, writes: str | None = None) -> Store:
    """The store of a workspace folder or database URL (after :func:`check_store_driver`).

    A workspace this process cannot write opens read-only (``list``, ``status`` and ``report``
    work); a command that writes says so in ``writes`` (``"lidarfuzz run"``) and is refused there
    with one line, before it does anything.
    """
    check_store_driver(workspace)
    from lidarfuzz.store import Store

    store = Store(str(workspace))
    if writes is not None:
        store.require_writable(writes)
    return store


@contextlib.contextmanager
def disk_failures(then: str, where: str | Path | None = None) -> Iterator[None]:
    """Inside the block, a failing disk (full, over quota, read-only, I/O error; under the store or
    an output) becomes one :class:`~lidarfuzz.store.errors.StorageError` line that ends with
    ``then``: what the user does once the disk is fixed (``lidarfuzz resume 3 finishes the task``);
    ``where`` names what was written when the error does not (a database's file)."""
    try:
        yield
    except Exception as exc:
        from lidarfuzz.store.errors import StorageError, storage_error

        failure = storage_error(exc, where)
        if failure is None:
            raise
        raise StorageError(failure.path, failure.reason, f"{failure.plain}; {then}") from None


@dataclass(frozen=True)
class Column:
    """A listing's column: its header, and whether it holds names (never cut, never wrapped)."""

    header: str
    name: bool = False
    justify: str = "left"


def print_table(table: Table) -> None:
    """Print a table; on anything but a terminal (a pipe, a file) as wide as its content needs,
    so that no cell is cut to the 80 columns a pipe is given."""
    if console.is_terminal:
        console.print(table)
        return
    from rich.measure import Measurement

    table.width = Measurement.get(console, console.options.update_width(1 << 16), table).maximum
    console.print(table, crop=False)


def print_listing(columns: Sequence[Column], rows: Sequence[Sequence[str]],
                  records: Sequence[dict[str, Any]] | dict[str, Any], *,
                  as_json: bool = False, plain: bool = False, title: str | None = None,
                  footer: str | None = None) -> None:
    """A listing as a table (default), tab-separated lines (``plain``) or JSON (``as_json``).

    Args:
        columns: The table's columns.
        rows: One list of cell texts per row, in the columns' order (Rich markup is not read).
        records: The same rows for JSON, with structured values (lists, numbers, null); or one
            object, for a listing of one thing's parts.
        as_json: Print ``records`` as a JSON array.
        plain: Print each row's cells joined by tabs, without header, title or footer.
        title: Above the table.
        footer: A line after the table (Rich markup), e.g. where the details are.
    """
    if as_json and plain:
        raise typer.BadParameter("choose one of --json and --plain", param_hint="--plain")
    if as_json:
        typer.echo(json.dumps(records if isinstance(records, dict) else list(records), indent=2, default=str))
        return
    from lidarfuzz.store.inventory import printable

    # names, notes and paths come from users and uploads: a control character is shown escaped,
    # never sent to the terminal (an escape sequence could rewrite the screen)
    rows = [[printable(str(cell)) for cell in row] for row in rows]
    if plain:
        for row in rows:
            typer.echo("\t".join(" ".join(cell.split()) for cell in row))
        return
    from rich.table import Table
    from rich.text import Text

    table = Table(title=title)
    for column in columns:
        if column.name:
            table.add_column(column.header, no_wrap=True, overflow="fold", justify=column.justify)  # type: ignore[arg-type]
        else:
            table.add_column(column.header, justify=column.justify)  # type: ignore[arg-type]
    for row in rows:
        table.add_row(*(Text(str(cell)) for cell in row))
    print_table(table)
    if footer:
        console.print(footer)


__all__ = ["WORKSPACE", "AllowUnlabelledOption", "Column", "JsonOption", "LayoutOption", "PlainOption",
           "WorkspaceOption", "check_store_driver", "console", "disk_failures", "err_console", "open_store",
           "print_listing",
           "print_table"]
