"""``lidarfuzz eval GT_DIR DT_DIR``: KITTI AP of detection files against ground-truth labels."""

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal, NoReturn, cast

import typer
from rich.markup import escape

from lidarfuzz.cli.common import console, err_console

if TYPE_CHECKING:
    from rich.table import Table

    from lidarfuzz.oracles.kitti_eval import KittiEvalResult

OVERLAP_PRESETS = ("official", "loose")


def _refuse(option: str, message: str) -> NoReturn:
    """A bad option value: one line naming the option and what it takes, exit code 2 (no usage box)."""
    err_console.print(f"[bold red]error:[/] {option}: {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(2)


def _classes(text: str) -> tuple[str, ...]:
    """The classes named in ``--classes``, in KITTI's spelling whatever their case (as the devkit matches them)."""
    from lidarfuzz.oracles.kitti_eval import OFFICIAL_OVERLAPS

    known = {name.lower(): name for name in OFFICIAL_OVERLAPS["bbox"]}
    given = [c.strip() for c in text.split(",") if c.strip()]
    unknown = [c for c in given if c.lower() not in known]
    if unknown or not given:
        verb = "is not a class" if len(unknown) == 1 else "are not classes"
        what = f"{', '.join(repr(c) for c in unknown)} {verb}" if unknown else "no class given"
        _refuse("--classes", f"{what}; choose among {', '.join(known.values())} (comma-separated, any case)")
    return tuple(dict.fromkeys(known[c.lower()] for c in given))


def summary_table(result: "KittiEvalResult", classes: tuple[str, ...]) -> "Table":
    """Moderate AP|R40 per class (columns) and metric (rows), with the mAP over classes."""
    from rich.table import Table

    from lidarfuzz.oracles.kitti_eval import METRICS

    table = Table("metric", *classes, "mAP", title="AP|R40, moderate")
    for metric in METRICS:
        cells = [f"{result.get(metric, cls, 'moderate', 'R40'):.2f}" for cls in classes]
        table.add_row(metric, *cells, f"[bold]{result.mean_ap(metric, 'moderate', 'R40'):.2f}[/]")
    return table


def eval_command(
    gt_dir: Annotated[
        Path,
        typer.Argument(
            help="Ground truth: a KITTI label_2 folder, or a KITTI root holding label_2/ or training/label_2/."
        ),
    ],
    dt_dir: Annotated[
        Path,
        typer.Argument(
            help="Detections: KITTI label files with a score column, named like the ground-truth files."
        ),
    ],
    classes: Annotated[
        str, typer.Option(help="Classes to evaluate, comma-separated (any case).")
    ] = "Car,Pedestrian,Cyclist",
    overlaps: Annotated[
        str, typer.Option(help="IoU thresholds: official (0.7/0.5/0.5) or loose (BEV and 3D at 0.5/0.25/0.25).")
    ] = "official",
    calib_dir: Annotated[
        Path | None,
        typer.Option(help="Calibration folder (default: calib/ next to label_2, else an idealised KITTI rig)."),
    ] = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Also write every AP and the mAP as JSON to this file.")
    ] = None,
    allow_unlabelled: Annotated[
        bool, typer.Option(help="Leave out detection files of frames without a label file (unlabelled).")
    ] = False,
) -> None:
    """Evaluate detections as the KITTI 3D object devkit does: bbox, BEV, 3D AP and AOS at R11 and R40.

    A ground-truth frame without a detection file counts as a frame with no detections.
    """
    from lidarfuzz.oracles.kitti_eval import METRICS, evaluate_kitti
    from lidarfuzz.oracles.kitti_files import load_kitti_eval_frames

    names = _classes(classes)
    if overlaps not in OVERLAP_PRESETS:
        _refuse("--overlaps", f"{overlaps!r} is not one of {', '.join(OVERLAP_PRESETS)}")
    loaded = load_kitti_eval_frames(gt_dir, dt_dir, calib_dir, allow_unlabelled=allow_unlabelled)
    for note in loaded.notes:
        err_console.print(f"[yellow]note:[/] {note}", highlight=False, soft_wrap=True)
    if loaded.missing_detections:
        missing = loaded.missing_detections
        err_console.print(
            f"[yellow]warning:[/] {len(missing)} of {len(loaded.frames)} ground-truth frame(s) have no "
            f"detection file in {loaded.detection_dir} (evaluated as no detections), e.g. {missing[0]}",
            highlight=False,
            soft_wrap=True,
        )
    result = evaluate_kitti(loaded.frames, classes=names, overlaps=cast(Literal["official", "loose"], overlaps))
    console.print(result.format_table(), markup=False, highlight=False, end="")
    console.print(summary_table(result, names))
    for note in result.sample_warnings():
        err_console.print(f"[yellow]warning:[/] {note}", highlight=False, soft_wrap=True, markup=True)
    if json_out is not None:
        payload = result.to_dict()
        payload["map_moderate_R40"] = {m: result.mean_ap(m, "moderate", "R40") for m in METRICS}
        payload["inputs"] = {
            "label_dir": str(loaded.label_dir),
            "detection_dir": str(loaded.detection_dir),
            "calib_dir": None if loaded.calib_dir is None else str(loaded.calib_dir),
            "frames": len(loaded.frames),
            "missing_detections": loaded.missing_detections,
        }
        from lidarfuzz.io.atomic import write_text

        write_text(json_out, json.dumps(payload, indent=2, sort_keys=True), overwrite=True)
        console.print(f"wrote {json_out}", highlight=False)
