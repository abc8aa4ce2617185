"""Root of the ``lidarfuzz`` command line: global options and command registration."""

from __future__ import annotations

import sys
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from lidarfuzz import __version__
from lidarfuzz.errors import LidarfuzzError

app = typer.Typer(
    name="lidarfuzz",
    help="Test LiDAR perception software: mutate point clouds, run the system under test, report where it breaks.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)
console = Console()
err_console = Console(stderr=True)


def _version(value: bool) -> None:
    if value:
        console.print(f"lidarfuzz {__version__}")
        raise typer.Exit()


@app.callback()
def root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Show the version and exit.")
    ] = False,
) -> None:
    """Test LiDAR perception software: mutate point clouds, run the system under test, report where it breaks."""


def _register() -> None:
    from lidarfuzz.cli import (
        campaign,
        catalog,
        convert,
        coverage,
        demo,
        evaluate,
        gen,
        info,
        operators,
        relations,
        serve,
        suts,
        train,
    )

    for module in (demo, gen, info, convert, operators, relations, suts, evaluate, catalog, campaign, coverage,
                   serve, train):
        module.register(app)


_register()


def main() -> None:
    """Entry point: user-facing errors become one clear line and exit code 2, not a traceback."""
    try:
        app()
    except LidarfuzzError as exc:
        err_console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False, soft_wrap=True)
        sys.exit(2)
    except OSError as exc:  # permission denied, disk full, ...: the OS message names the file
        err_console.print(f"[bold red]error:[/] {escape(str(exc))}", highlight=False, soft_wrap=True)
        sys.exit(2)
