"""``lidarfuzz gen``: render a labelled KITTI-layout data set with the built-in simulator."""

from pathlib import Path
from typing import Annotated

import typer

from lidarfuzz.cli.common import console, print_table

#: The simulator's sensor presets (lidarfuzz.sim.sensor.preset_names()), for the help text without
#: importing the simulator (tests/cli checks that the two agree).
SENSOR_PRESETS: tuple[str, ...] = ("HDL-64E", "HDL-32E", "VLP-16", "OS1-64")


def gen_command(
    out: Annotated[Path, typer.Option("--out", "-o", help="New folder for the data set (KITTI layout).")],
    frames: Annotated[int, typer.Option(min=1, max=1_000_000, help="Number of frames.")] = 100,
    seed: Annotated[int, typer.Option(help="Seed: the same seed gives the same bytes.")] = 0,
    scene: Annotated[Path | None, typer.Option(help="Scene description (YAML/JSON) to render instead of "
                                               "generated scenes; its frames form a sequence.")] = None,
    sensor: Annotated[str | None, typer.Option(help=f"Sensor preset ({', '.join(SENSOR_PRESETS)}) or a "
                                               "YAML/JSON beam table; default: the scene's, else HDL-64E.")]
    = None,
    sequence: Annotated[bool, typer.Option(help="One generated scene driven through at 10 Hz, written as a "
                                           "log with timestamps and poses (default: independent scenes).")]
    = False,
    drive: Annotated[bool, typer.Option(help="A drive log (implies --sequence): the generated ego vehicle "
                                        "stops at a junction (for a crossing pedestrian or behind a car), turns "
                                        "left or right and drives on; ego.txt holds its speed and steering.")]
    = False,
    kind: Annotated[str | None, typer.Option(help="Scene kind: urban or suburban (default: a mix).")] = None,
    workers: Annotated[int | None, typer.Option(min=1, help="Worker processes (default: CPU cores).")] = None,
    val_fraction: Annotated[float, typer.Option(min=0.0, max=1.0, help="Share of frames in ImageSets/val.txt "
                                                "(the last ones).")] = 0.5,
    camera: Annotated[bool, typer.Option(help="Also render camera 2: image_2/ (RGB PNG), depth_2/ (16-bit "
                                         "z-depth PNG, metres x 256) and steering.csv (front-wheel angle, rad, "
                                         "left positive; speed, m/s); calib/ then describes the image.")] = False,
    image_size: Annotated[str | None, typer.Option(help="Camera image size WIDTHxHEIGHT: 640x480 (default) or "
                                                   "1242x375 (KITTI's); needs --camera.")] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing data set in OUT.")] = False,
    resume: Annotated[bool, typer.Option(help="Finish an interrupted run into OUT (same options), keeping the "
                                         "frames already written.")] = False,
) -> None:
    """Generate a labelled data set: procedural scenes (or your scene file) ray-cast with a spinning LiDAR.

    Writes velodyne/, velodyne_extra/ (ring, time, semantic label, instance), label_2/ (with
    truncation, occlusion and DontCare), label_2_extra/ (track ids, points per object), calib/,
    roi/ (drivable area), ImageSets/ (train/val), scenes/ (each frame's scene description) and,
    for a sequence, timestamps.txt, poses.txt and ego.txt (the ego vehicle's speed, yaw rate,
    curvature and steering angle per frame). With --camera also image_2/, depth_2/ and steering.csv.
    """
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.table import Table

    from lidarfuzz.errors import LidarfuzzError
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset
    from lidarfuzz.sim.spec import load_scene

    if kind is not None and kind not in ("urban", "suburban"):
        raise typer.BadParameter(f"{kind!r} is not one of urban, suburban", param_hint="--kind")
    if overwrite and resume:
        raise typer.BadParameter("choose one of --overwrite and --resume", param_hint="--resume")
    if drive and scene is not None:
        raise typer.BadParameter("a drive log is generated; leave out --scene (or --drive)", param_hint="--drive")
    if image_size is not None and not camera:
        raise LidarfuzzError(f"--image-size {image_size}: a camera image size needs --camera")
    size = parse_image_size(image_size) if camera else None
    spec = load_scene(scene) if scene is not None else None
    config = GenerationConfig(frames=frames, seed=seed, scene=spec, sensor=sensor, sequence=sequence, kind=kind,
                              val_fraction=val_fraction, drive=drive, camera=size)
    columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("frames"),
               TimeElapsedColumn(), TimeRemainingColumn())
    try:
        with Progress(*columns, console=console, transient=True) as progress:
            task = progress.add_task("rendering", total=frames)
            summary = generate_dataset(out, config, workers=workers, overwrite=overwrite, resume=resume,
                                       on_frame=lambda _result: progress.advance(task))
    except KeyboardInterrupt:
        console.print(f"interrupted: the frames written so far are kept; finish with the same command "
                      f"and [bold]--resume[/] (out: {out})")
        raise typer.Exit(130) from None
    table = Table("class", "objects", title=f"labels in {summary.frames} frame(s)")
    for name, count in sorted(summary.label_counts.items(), key=lambda kv: -kv[1]):
        table.add_row(name, str(count))
    print_table(table)
    kept = f", {summary.resumed} kept from the interrupted run" if summary.resumed else ""
    rate = summary.generated / summary.seconds if summary.seconds > 0 else 0.0
    images = f", {summary.images} camera image(s) with steering.csv" if config.camera is not None else ""
    console.print(f"wrote {summary.frames} frame(s) to [bold]{summary.root}[/] in {summary.seconds:.1f} s "
                  f"({rate:.1f} frames/s{kept}); {summary.points_per_frame:,.0f} points per frame{images}")


def parse_image_size(text: str | None) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` (640x480 when None) as (width, height); a one-line error naming --image-size."""
    from lidarfuzz.errors import LidarfuzzError

    if text is None:
        return (640, 480)
    width, sep, height = text.strip().lower().partition("x")
    if not sep or not width.isdigit() or not height.isdigit():
        raise LidarfuzzError(f"--image-size {text!r}: expected WIDTHxHEIGHT, e.g. 640x480 or 1242x375")
    size = (int(width), int(height))
    if not all(8 <= v <= 8192 for v in size):
        raise LidarfuzzError(f"--image-size {text!r}: width and height must each lie in 8 … 8192 pixels")
    return size
