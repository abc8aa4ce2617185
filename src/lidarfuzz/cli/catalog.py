"""``lidarfuzz datasets`` and ``lidarfuzz models``: what campaigns can be run on and against."""

import json
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from lidarfuzz.cli.common import (
    WORKSPACE,
    AllowUnlabelledOption,
    Column,
    JsonOption,
    LayoutOption,
    PlainOption,
    WorkspaceOption,
    console,
    open_store,
    print_listing,
)

Modality = Literal["lidar", "camera"]


def _shown(text: object) -> str:
    """A stored name, path or note as a terminal may show it: control characters escaped
    (:func:`~lidarfuzz.store.inventory.printable`; names stored before they were refused)."""
    from lidarfuzz.store.inventory import printable

    return printable(str(text), newlines=True)

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
    modality: Annotated[Modality, typer.Option(help="lidar (point clouds) or camera (the images: a KITTI folder's "
                                                    "image_2/, a Udacity folder, a CSV of images, image topics; "
                                                    "for camera tasks).")] = "lidar",
    camera: Annotated[str | None, typer.Option(help="With --modality camera: which camera of the source "
                                                    "(image_3; Udacity's left or right).")] = None,
    workspace: WorkspaceOption = WORKSPACE,
) -> None:
    """Validate a data set (never modified) and record it with how to read it."""
    from lidarfuzz.errors import LidarfuzzError
    from lidarfuzz.io.options import options_from_flags
    from lidarfuzz.store.inventory import add_dataset

    if camera is not None and modality != "camera":
        raise LidarfuzzError("--camera chooses a camera of an image data set: give --modality camera too")
    options = options_from_flags(layout, allow_unlabelled, intensity_scale, roi_map)
    if modality == "camera":
        options = options.model_copy(update={"modality": "camera", "camera": camera})
    row = add_dataset(open_store(workspace), name, path, notes, options=options)
    shown = ", ".join(f"{k} {v}" for k, v in row.options.items())
    console.print(f"added data set {_shown(row.name)}: {row.frame_count} frame(s), {row.format}, {_shown(row.path)}"
                  + (f" ({_shown(shown)})" if shown else ""), markup=False)


def datasets_list(workspace: WorkspaceOption = WORKSPACE, as_json: JsonOption = False,
                  plain: PlainOption = False) -> None:
    """The recorded data sets."""
    from lidarfuzz.store.inventory import list_datasets

    rows: list[list[str]] = []
    records: list[dict[str, Any]] = []
    for row in list_datasets(open_store(workspace)):
        options = ", ".join(f"{k}={v}" for k, v in (row.options or {}).items())
        rows.append([_shown(row.name), str(row.frame_count), row.format, _shown(row.path), _shown(options),
                     f"{row.added_at:%Y-%m-%d %H:%M}", _shown(row.notes)])
        records.append({"name": row.name, "frames": row.frame_count, "format": row.format, "path": row.path,
                        "options": row.options or {}, "added": row.added_at.isoformat(), "notes": row.notes})
    columns = [Column("name", name=True), Column("frames"), Column("format"), Column("path", name=True),
               Column("options"), Column("added"), Column("notes")]
    print_listing(columns, rows, records, as_json=as_json, plain=plain)


def datasets_remove(name: str, workspace: WorkspaceOption = WORKSPACE) -> None:
    """Forget a data set (its files stay where they are)."""
    from lidarfuzz.store.inventory import remove_dataset

    remove_dataset(open_store(workspace), name)
    console.print(f"removed data set {_shown(name)}", markup=False)


def models_add(
    name: Annotated[str, typer.Argument(help="A name for it.")],
    spec: Annotated[str, typer.Argument(help="The system's spec (see lidarfuzz suts).")],
    option: Annotated[list[str] | None, typer.Option(help="key=value passed to the system (JSON values); "
                                                     "repeatable.")] = None,
    notes: Annotated[str, typer.Option(help="Free text.")] = "",
    modality: Annotated[Modality, typer.Option(help="lidar (a detector or controller) or camera (a steering "
                                                    "system: dave2, onnx:…, a torch module; for camera tasks).")
                        ] = "lidar",
    workspace: WorkspaceOption = WORKSPACE,
) -> None:
    """Check that a spec builds a system, and record it with its fingerprint."""
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
    row = add_model(open_store(workspace), name, spec, options, notes, modality=modality)
    console.print(f"added model {_shown(row.name)}: {_shown(row.spec)} (fingerprint {row.fingerprint})", markup=False)


def models_list(workspace: WorkspaceOption = WORKSPACE, as_json: JsonOption = False,
                plain: PlainOption = False) -> None:
    """The recorded systems under test."""
    from lidarfuzz.store.inventory import list_models

    rows: list[list[str]] = []
    records: list[dict[str, Any]] = []
    for row in list_models(open_store(workspace)):
        rows.append([_shown(row.name), _shown(row.spec), row.fingerprint, f"{row.added_at:%Y-%m-%d %H:%M}",
                     _shown(row.notes)])
        records.append({"name": row.name, "spec": row.spec, "options": row.options or {},
                        "fingerprint": row.fingerprint, "added": row.added_at.isoformat(), "notes": row.notes})
    columns = [Column("name", name=True), Column("spec", name=True), Column("fingerprint", name=True),
               Column("added"), Column("notes")]
    print_listing(columns, rows, records, as_json=as_json, plain=plain)


def models_remove(name: str, workspace: WorkspaceOption = WORKSPACE) -> None:
    """Forget a system under test."""
    from lidarfuzz.store.inventory import remove_model

    remove_model(open_store(workspace), name)
    console.print(f"removed model {_shown(name)}", markup=False)
