"""``lidarfuzz datasets`` and ``lidarfuzz models``: what campaigns can be run on and against."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

WORKSPACE = os.environ.get("LIDARFUZZ_WORKSPACE", "lidarfuzz-workspace")
# A str, not a Path: a Path would fold the "//" of a database URL.
WorkspaceOption = Annotated[str, typer.Option(help="Workspace folder (its SQLite store) or a database URL "
                                                    "(postgresql+psycopg://…); $LIDARFUZZ_WORKSPACE.")]
LayoutOption = Annotated[str | None, typer.Option(
    help="Point layout of headerless scans: kitti, kitti360, nuscenes, semantickitti, argoverse2, waymo, or the "
         "columns, e.g. x,y,z,intensity,ring:f4 (default: what the data's structure says, else kitti).")]
AllowUnlabelledOption = Annotated[bool, typer.Option(
    help="Frames without a label file in a labelled data set are allowed: campaigns run them through the "
         "system and relations and score AP on the labelled frames only.")]


def _store(workspace: Path | str):
    from lidarfuzz.store import Store

    return Store(str(workspace))


def register(app: typer.Typer) -> None:
    datasets = typer.Typer(help="Data sets campaigns run on: add, list, remove.", no_args_is_help=True)
    models = typer.Typer(help="Systems under test campaigns run against: add, list, remove.", no_args_is_help=True)
    app.add_typer(datasets, name="datasets")
    app.add_typer(models, name="models")

    @datasets.command("add")
    def datasets_add(
        name: Annotated[str, typer.Argument(help="A name for it.")],
        path: Annotated[Path, typer.Argument(help="KITTI folder, folder of frames, frame file, bag or MCAP.")],
        notes: Annotated[str, typer.Option(help="Free text.")] = "",
        layout: LayoutOption = None,
        allow_unlabelled: AllowUnlabelledOption = False,
        roi_map: Annotated[Path | None, typer.Option(help="GeoJSON drivable-area map for every frame without its "
                                                          "own roi/ map (LiDAR frame; \"frame\": \"world\" for a "
                                                          "log with poses), or 'estimate': the drivable region "
                                                          "estimated from each frame's points, which the system "
                                                          "and every mutant then see (Zhou & Sun's MR1 on data "
                                                          "without a map).")] = None,
        intensity_scale: Annotated[float | None, typer.Option(help="Intensity of the strongest return (1 or 255), "
                                                                   "when the layout's is wrong.")] = None,
        workspace: WorkspaceOption = WORKSPACE,
    ) -> None:
        """Validate a data set (never modified) and record it with how to read it."""
        from lidarfuzz.cli.app import console
        from lidarfuzz.io.options import options_from_flags
        from lidarfuzz.store.inventory import add_dataset

        options = options_from_flags(layout, allow_unlabelled, intensity_scale, roi_map)
        row = add_dataset(_store(workspace), name, path, notes, options=options)
        shown = ", ".join(f"{k} {v}" for k, v in row.options.items())
        console.print(f"added data set {row.name}: {row.frame_count} frame(s), {row.format}, {row.path}"
                      + (f" ({shown})" if shown else ""))

    @datasets.command("list")
    def datasets_list(workspace: WorkspaceOption = WORKSPACE) -> None:
        """The recorded data sets."""
        from lidarfuzz.cli.app import console
        from lidarfuzz.store.inventory import list_datasets

        table = Table("name", "frames", "format", "path", "options", "added", "notes")
        for row in list_datasets(_store(workspace)):
            options = ", ".join(f"{k}={v}" for k, v in (row.options or {}).items())
            table.add_row(row.name, str(row.frame_count), row.format, row.path, options,
                          f"{row.added_at:%Y-%m-%d %H:%M}", row.notes)
        console.print(table)

    @datasets.command("remove")
    def datasets_remove(name: str, workspace: WorkspaceOption = WORKSPACE) -> None:
        """Forget a data set (its files stay where they are)."""
        from lidarfuzz.cli.app import console
        from lidarfuzz.store.inventory import remove_dataset

        remove_dataset(_store(workspace), name)
        console.print(f"removed data set {name}")

    @models.command("add")
    def models_add(
        name: Annotated[str, typer.Argument(help="A name for it.")],
        spec: Annotated[str, typer.Argument(help="The system's spec (see lidarfuzz suts).")],
        option: Annotated[list[str] | None, typer.Option(help="key=value passed to the system (JSON values); "
                                                         "repeatable.")] = None,
        notes: Annotated[str, typer.Option(help="Free text.")] = "",
        workspace: WorkspaceOption = WORKSPACE,
    ) -> None:
        """Check that a spec builds a system, and record it with its fingerprint."""
        from lidarfuzz.cli.app import console
        from lidarfuzz.store.inventory import add_model

        options = {}
        for item in option or []:
            key, sep, value = item.partition("=")
            if not sep:
                raise typer.BadParameter(f"expected key=value, got {item!r}", param_hint="--option")
            try:
                options[key] = json.loads(value)
            except json.JSONDecodeError:
                options[key] = value
        row = add_model(_store(workspace), name, spec, options, notes)
        console.print(f"added model {row.name}: {row.spec} (fingerprint {row.fingerprint})")

    @models.command("list")
    def models_list(workspace: WorkspaceOption = WORKSPACE) -> None:
        """The recorded systems under test."""
        from lidarfuzz.cli.app import console
        from lidarfuzz.store.inventory import list_models

        table = Table("name", "spec", "fingerprint", "added", "notes")
        for row in list_models(_store(workspace)):
            table.add_row(row.name, row.spec, row.fingerprint, f"{row.added_at:%Y-%m-%d %H:%M}", row.notes)
        console.print(table)

    @models.command("remove")
    def models_remove(name: str, workspace: WorkspaceOption = WORKSPACE) -> None:
        """Forget a system under test."""
        from lidarfuzz.cli.app import console
        from lidarfuzz.store.inventory import remove_model

        remove_model(_store(workspace), name)
        console.print(f"removed model {name}")
