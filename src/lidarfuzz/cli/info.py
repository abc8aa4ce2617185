"""``lidarfuzz info PATH``: what a frame file, data set folder or log holds, and what is wrong with it."""

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from lidarfuzz.cli.common import AllowUnlabelledOption, LayoutOption, console, print_table

if TYPE_CHECKING:
    from lidarfuzz.io.inspect import DatasetReport


def render(report: "DatasetReport") -> None:
    """Print an inspection report: the summary lines, the channel, label and topic tables, the problems."""
    from rich.table import Table

    status = []
    if report.unreadable:
        status.append(f"{report.unreadable} unreadable")
    if report.inspected + report.unreadable < report.frames:
        status.append(f"{report.inspected + report.unreadable} inspected")
    console.print(f"[bold]{report.path}[/]  {report.kind} ({report.format}), {report.frames} frame(s)"
                  + (f" ({', '.join(status)})" if status else ""), soft_wrap=True)
    if report.time_span:
        start, end = report.time_span
        console.print(f"log: {end - start:.3f} s from t={start:.3f}; poses: {'yes' if report.has_poses else 'no'}")
    if report.images is not None:
        _render_images(report)
    if report.inspected and report.images is None:
        console.print(f"points per frame: min {report.points_min:,}, max {report.points_max:,}, "
                      f"mean {report.points_total / report.inspected:,.0f}")
    if report.channels:
        table = Table("channel", "min", "max", title="channels")
        for name, stats in report.channels.items():
            table.add_row(name, f"{stats.minimum:.4g}", f"{stats.maximum:.4g}")
        print_table(table)
    if report.classes:
        table = Table("class", "objects", title=f"labels ({report.labelled_frames} labelled frame(s))")
        for name, count in sorted(report.classes.items()):
            table.add_row(name, str(count))
        print_table(table)
    if report.unlabelled_frames:
        console.print(f"[yellow]unlabelled frames (no label file): {report.unlabelled_frames}[/] — info, detect, "
                      "mutate and convert use them; run scores AP without them only with --allow-unlabelled")
    if report.images is None:
        console.print(f"calibrated frames: {report.calibrated_frames}; "
                      f"frames with a drivable-area map: {report.roi_frames}")
    if report.log:
        table = Table("topic", "type", "messages", title=f"log topics ({report.log.get('format')})")
        for topic in report.log.get("topics", []):
            table.add_row(topic.get("name", ""), topic.get("type", ""), str(topic.get("count", "")))
        print_table(table)
    if report.problems:
        console.print(f"[bold]{len(report.problems)} problem(s):[/]")
        for problem in report.problems[:50]:
            colour = "red" if problem.severity == "error" else "yellow"
            console.print(f"  [{colour}]{problem}[/]", highlight=False, soft_wrap=True)
        if len(report.problems) > 50:
            console.print(f"  ... and {len(report.problems) - 50} more (use --json for all)")
    else:
        console.print("[green]no problems found[/]")


def _render_images(report: "DatasetReport") -> None:
    """The camera modality's lines: image sizes, steering range, depth and camera matrices."""
    stats = report.images
    assert stats is not None
    if not report.inspected:
        return
    sizes = ", ".join(f"{w}×{h} ({n})" for (h, w), n in stats.sizes.most_common())
    console.print(f"images: {sizes}")
    if stats.labelled:
        console.print(f"steering: {stats.labelled} labelled, from {stats.steering.minimum:.4g} to "
                      f"{stats.steering.maximum:.4g} (the data set's units)")
    else:
        console.print("steering: no labels")
    console.print(f"with depth: {stats.with_depth}; with a camera matrix: {stats.with_intrinsics}")


def info(
    path: Annotated[Path, typer.Argument(help="A frame file, a data set folder (KITTI layout or frame files), "
                                         "a ROS1/ROS2 bag or an MCAP file; for the camera, a Udacity folder, "
                                         "a folder of images with a CSV, or a KITTI folder with image_2/.")],
    topic: Annotated[str | None, typer.Option(help="PointCloud2 (or image) topic of a log (default: the only "
                                              "one).")] = None,
    limit: Annotated[int | None, typer.Option(min=1, help="Inspect only the first N frames.")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Also write the report as JSON to this file "
                                                  "('-' for standard output).")] = None,
    layout: LayoutOption = None,
    allow_unlabelled: AllowUnlabelledOption = False,
    modality: Annotated[str | None, typer.Option(help="lidar (point clouds) or camera (images: a KITTI "
                                                 "folder's image_2/); default: what the data holds.")] = None,
    camera: Annotated[str | None, typer.Option(help="Camera of a multi-camera image data set: center, left, "
                                               "right (Udacity) or image_2, image_3 (KITTI).")] = None,
    image_column: Annotated[str | None, typer.Option(help="Image column of a CSV of images (default: image, "
                                                     "filename, path, ...).")] = None,
    steering_column: Annotated[str | None, typer.Option(help="Steering column of a CSV of images (default: "
                                                        "steering, angle, ...).")] = None,
    steering_topic: Annotated[str | None, typer.Option(help="Topic of a log whose messages carry the steering "
                                                       "angle of its images (e.g. /vehicle/steering_report).")] = None,
) -> None:
    """Summarise a frame, data set or log: counts, channels and ranges, classes, problems found.

    A camera data set (or --modality camera) is described by its images: sizes, steering range,
    depth maps and camera matrices.

    Exits with code 1 when an error-level problem is found, so scripts can gate on it. Frames
    without a label file in a labelled data set are a warning (only AP needs labels); with
    --allow-unlabelled they are counted without one.
    """
    from lidarfuzz.io.inspect import inspect_source
    from lidarfuzz.io.options import options_from_flags

    if modality not in (None, "lidar", "camera"):
        raise typer.BadParameter(f"expected lidar or camera, got {modality!r}", param_hint="--modality")
    options = options_from_flags(layout, allow_unlabelled)
    given = {key: value for key, value in (("camera", camera), ("image_column", image_column),
                                           ("steering_column", steering_column),
                                           ("steering_topic", steering_topic)) if value is not None}
    if given and modality == "lidar":
        raise typer.BadParameter(f"--{next(iter(given)).replace('_', '-')} applies to the camera modality",
                                 param_hint="--modality")
    report = inspect_source(path, topic=topic, limit=limit, options=options, modality=modality, **given)
    if allow_unlabelled:
        report.problems = [p for p in report.problems if not p.message.endswith(": unlabelled")]
    if json_out is not None and str(json_out) == "-":
        console.print_json(json.dumps(report.as_dict()))
    else:
        render(report)
        if json_out is not None:
            json_out.write_text(json.dumps(report.as_dict(), indent=2), encoding="utf-8")
    if report.errors:
        raise typer.Exit(1)
