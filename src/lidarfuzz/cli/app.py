"""Root of the ``lidarfuzz`` command line: global options, and the commands assembled.

Each command is a plain function in its own module (:mod:`lidarfuzz.cli.info`,
:mod:`lidarfuzz.cli.campaign`, ...); this module only names and orders them. The command
modules import the shared pieces from :mod:`lidarfuzz.cli.common`, never this module, and
import heavy libraries (numpy, the engine, SQLAlchemy, FastAPI) inside the command bodies, so
``lidarfuzz --help`` loads Typer, Rich and the command signatures only.
"""

from __future__ import annotations

import sys
import warnings
from typing import Annotated, Any, TextIO

import typer
from rich.markup import escape

from lidarfuzz.cli import (
    campaign,
    catalog,
    compare,
    convert,
    coverage,
    demo,
    evaluate,
    gen,
    info,
    logs,
    operators,
    relations,
    replay,
    reporting,
    serve,
    suts,
    train,
)
from lidarfuzz.cli.common import console, err_console
from lidarfuzz.errors import LidarfuzzError

app = typer.Typer(
    name="lidarfuzz",
    help="Test LiDAR perception software: mutate point clouds, run the system under test, report where it breaks.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if value:
        from lidarfuzz import __version__

        console.print(f"lidarfuzz {__version__}")
        raise typer.Exit()


@app.callback()
def root(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Show the version and exit.")
    ] = False,
) -> None:
    """Test LiDAR perception software: mutate point clouds, run the system under test, report where it breaks."""


# In the order `lidarfuzz --help` lists them.
app.command("demo")(demo.demo)
app.command("gen")(gen.gen_command)
app.command("info")(info.info)
app.command("convert")(convert.convert_command)
app.command("operators")(operators.operators_command)
app.command("mutate")(operators.mutate_command)
app.command("relations")(relations.relations_command)
app.command("suts")(suts.suts_command)
app.command("detect")(suts.detect_command)
app.command("eval")(evaluate.eval_command)
app.command("run")(campaign.run)
app.command("resume")(campaign.resume)
app.command("cancel")(campaign.cancel)
app.command("delete")(campaign.delete)
app.command("list")(campaign.list_tasks_command)
app.command("status")(campaign.status)
app.command("report")(reporting.report)
app.command("replay")(replay.replay)
app.command("compare")(compare.compare)
app.command("profile")(coverage.profile)
app.command("serve")(serve.serve)
app.command("train")(train.train_command)

datasets = typer.Typer(help="Data sets campaigns run on: add, list, remove.", no_args_is_help=True)
datasets.command("add")(catalog.datasets_add)
datasets.command("list")(catalog.datasets_list)
datasets.command("remove")(catalog.datasets_remove)
app.add_typer(datasets, name="datasets")

models = typer.Typer(help="Systems under test campaigns run against: add, list, remove.", no_args_is_help=True)
models.command("add")(catalog.models_add)
models.command("list")(catalog.models_list)
models.command("remove")(catalog.models_remove)
app.add_typer(models, name="models")

log_commands = typer.Typer(help="Structural testing with logs (Neves et al.): partition a log into segments, "
                                "select discriminatory ones, generate new logs, compare coverage, search for logs "
                                "that reach uncovered code.",
                           no_args_is_help=True)
log_commands.command("partition")(logs.partition_command)
log_commands.command("select")(logs.select_command)
log_commands.command("generate")(logs.generate_command)
log_commands.command("compare")(logs.compare_command)
log_commands.command("search")(logs.search_command)
app.add_typer(log_commands, name="logs")


_python_show_warning = warnings.showwarning


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                  file: TextIO | None = None, line: str | None = None) -> None:
    """A plugin left out is the user's to act on, not a line of lidarfuzz's code: show it as
    ``lidarfuzz: warning: <message>``, one line on stderr. Other warnings as Python shows them."""
    from lidarfuzz.plugins import PluginWarning  # here, not at start-up (``--help`` needs no plugins)

    if issubclass(category, PluginWarning):
        print(f"lidarfuzz: warning: {message}", file=file or sys.stderr)
    else:
        _python_show_warning(message, category, filename, lineno, file, line)


def _fail(message: str, code: int) -> None:
    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    sys.exit(code)


def _click_errors() -> tuple[type[Any], type[Any], type[Any]]:
    """Click's UsageError, ClickException and NoArgsIsHelpError, from whichever click Typer uses
    (recent Typer carries its own copy; older ones use the click package)."""
    bases = {cls.__name__: cls for cls in typer.BadParameter.__mro__}
    usage, click_error = bases["UsageError"], bases["ClickException"]
    no_args = getattr(sys.modules[usage.__module__], "NoArgsIsHelpError", None)
    return usage, click_error, no_args or type("_Never", (Exception,), {})


def main() -> None:
    """Entry point: user-facing errors become one clear line, not a traceback: exit code 2 for what
    the user gave, 1 for a failing disk (full, over quota, read-only, I/O error: what is stored is
    kept, and the line says what to do)."""
    usage_error, click_error, no_args = _click_errors()
    previous, warnings.showwarning = warnings.showwarning, _show_warning
    try:
        # click's exits come back as codes, its errors as exceptions
        code = app(standalone_mode=False, prog_name="lidarfuzz")
    except no_args as exc:  # `lidarfuzz` alone: the help, as click shows it
        exc.show()
        sys.exit(exc.exit_code)
    except usage_error as exc:  # a bad option or value: one line naming it, not a usage box
        where = exc.ctx.command_path if exc.ctx is not None else "lidarfuzz"
        _fail(f"{where}: {exc.format_message()} ({where} --help)", exc.exit_code)
    except click_error as exc:
        _fail(exc.format_message(), exc.exit_code)
    except typer.Abort:  # Ctrl-C or end of input at a prompt
        err_console.print("Aborted.", highlight=False)
        sys.exit(130)
    except LidarfuzzError as exc:
        from lidarfuzz.store.errors import StorageError

        _fail(str(exc), 1 if isinstance(exc, StorageError) else 2)
    except OSError as exc:  # permission denied, disk full, ...: the OS message names the file
        from lidarfuzz.store.errors import storage_error

        failure = storage_error(exc)
        _fail(str(failure or exc), 1 if failure else 2)
    except Exception as exc:  # a database's own error for a failing disk ("database or disk is full")
        from lidarfuzz.store.errors import storage_error

        if (failure := storage_error(exc)) is None:
            raise
        _fail(str(failure), 1)
    else:  # as click's standalone mode ends: always through SystemExit (0 when a command returned nothing)
        sys.exit(code if isinstance(code, int) else 0)
    finally:
        warnings.showwarning = previous
