"""``lidarfuzz convert SRC DST``: any supported format to any other."""

from pathlib import Path
from typing import Annotated

import typer

from lidarfuzz.cli.common import LayoutOption, console

#: The targets of :mod:`lidarfuzz.io.convert` (FOLDER_TARGETS, LOG_TARGETS), for the help text without
#: importing the readers and writers (tests/cli checks that the two agree).
TARGETS: tuple[str, ...] = ("kitti", "bin", "pcd", "ply", "las", "laz", "npy", "npz", "feather", "ros1", "ros2",
                            "mcap")


def convert_command(
    src: Annotated[Path, typer.Argument(help="Frame file, data set folder, bag or MCAP file to read.")],
    dst: Annotated[Path, typer.Argument(help="Where to write: a frame file (format from its suffix), a .bag or "
                                        ".mcap log, or a new folder (KITTI layout unless --to says otherwise).")],
    to: Annotated[str | None, typer.Option(help=f"Target format: {', '.join(TARGETS)}.")]
    = None,
    topic: Annotated[str | None, typer.Option(help="PointCloud2 topic to read from a log.")] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing destination.")] = False,
    reject_nonfinite: Annotated[bool, typer.Option(help="Fail on NaN/Inf coordinates instead of dropping "
                                                   "them with a warning.")] = False,
    layout: LayoutOption = None,
) -> None:
    """Convert between formats; the source is never modified and the destination is written atomically."""
    from rich.progress import Progress

    from lidarfuzz.io.convert import FOLDER_TARGETS, LOG_TARGETS, convert
    from lidarfuzz.io.options import options_from_flags

    if to is not None and to.lower() not in (*FOLDER_TARGETS, *LOG_TARGETS):
        raise typer.BadParameter(f"{to!r} is not one of {', '.join((*FOLDER_TARGETS, *LOG_TARGETS))}",
                                 param_hint="--to")
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task("converting", total=None)

        def on_frame(done: int, total: int) -> None:
            progress.update(task, completed=done, total=total)

        result = convert(src, dst, to=to, topic=topic, overwrite=overwrite,
                         nonfinite="reject" if reject_nonfinite else "drop", on_frame=on_frame,
                         options=options_from_flags(layout))
    console.print(f"wrote {result.frames} frame(s) to {result.destination} ({result.target})")
