"""``lidarfuzz logs partition | generate``: Neves et al.'s logs, segments and generated logs."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from lidarfuzz.cli.common import (
    WORKSPACE,
    Column,
    JsonOption,
    LayoutOption,
    PlainOption,
    WorkspaceOption,
    console,
    open_store,
    print_listing,
)

if TYPE_CHECKING:
    from lidarfuzz.structural.logs import OrderedLog
    from lidarfuzz.structural.segments import Segment

LogArgument = Annotated[Path, typer.Argument(help="The log: a bag or MCAP file, or a KITTI-layout folder with "
                                                  "timestamps.txt (lidarfuzz gen --sequence writes one).")]
SizeOption = Annotated[int, typer.Option("--size", min=1, help="Frames per segment (the last may be shorter).")]
TopicOption = Annotated[str | None, typer.Option(help="PointCloud2 topic of a bag or MCAP file.")]
RecordOption = Annotated[str | None, typer.Option("--record", help="Record the log (and its segments) in the "
                                                                   "workspace's store under this name.")]


def _open(log: Path, layout: str | None, topic: str | None) -> OrderedLog:
    from lidarfuzz.io.options import options_from_flags
    from lidarfuzz.structural.logs import open_log

    return open_log(log, options=options_from_flags(layout), topic=topic)


def parse_segments(text: str, segments: list[Segment]) -> list[Segment]:
    """``0,3,s000007``: segment indices or ids, comma-separated; ``all`` for every segment.

    Raises:
        typer.BadParameter: A token that is no segment of the log (naming it and the range).
    """
    if text.strip().lower() == "all":
        return segments
    chosen: dict[int, Segment] = {}
    for token in (t.strip() for t in text.split(",")):
        if not token:
            continue
        digits = token[1:] if token[:1].lower() == "s" else token
        if not digits.isdigit() or int(digits) >= len(segments):
            raise typer.BadParameter(f"{token!r} is not a segment of this log (0..{len(segments) - 1}, or "
                                     f"s000000..{segments[-1].id})", param_hint="--segments")
        chosen[int(digits)] = segments[int(digits)]
    if not chosen:
        raise typer.BadParameter("no segment given", param_hint="--segments")
    return [chosen[i] for i in sorted(chosen)]


def _span(log: OrderedLog, segment: Segment) -> tuple[float | None, float | None]:
    if log.timestamps is None:
        return None, None
    return float(log.timestamps[segment.first]), float(log.timestamps[segment.last])


def partition_command(
    log: LogArgument,
    size: SizeOption = 5,
    topic: TopicOption = None,
    layout: LayoutOption = None,
    record: RecordOption = None,
    workspace: WorkspaceOption = WORKSPACE,
    as_json: JsonOption = False,
    plain: PlainOption = False,
) -> None:
    """Cut a log into segments of --size frames (Neves et al.: five point clouds, a small part of the route)."""
    from lidarfuzz.structural.segments import partition

    opened = _open(log, layout, topic)
    segments = partition(opened.frame_ids, size)
    rows: list[list[str]] = []
    records: list[dict[str, Any]] = []
    for s in segments:
        start, end = _span(opened, s)
        times = "" if start is None or end is None else f"{start:.3f}–{end:.3f}"
        rows.append([s.id, str(s.index), f"{s.first}–{s.last}", str(len(s)), f"{s.frame_ids[0]}–{s.frame_ids[-1]}",
                     times])
        records.append({"id": s.id, "index": s.index, "first": s.first, "last": s.last, "frames": len(s),
                        "first_frame_id": s.frame_ids[0], "last_frame_id": s.frame_ids[-1], "start_s": start,
                        "end_s": end})
    if record is not None:
        from lidarfuzz.store.errors import NotFoundError
        from lidarfuzz.structural.stored import get_log, record_log, record_segments

        with open_store(workspace).session() as session:
            try:
                row = get_log(session, record)
            except NotFoundError:
                row = record_log(session, opened, record)
            record_segments(session, row, segments)
    columns = [Column("segment", name=True), Column("index", justify="right"), Column("positions"),
               Column("frames", justify="right"), Column("frame ids", name=True), Column("time (s)")]
    footer = (f"{len(opened)} frame(s) of {opened.path} ({opened.format}, ordered by {opened.order}) in "
              f"{len(segments)} segment(s) of {size}" + (f"; recorded as log {record!r}" if record else ""))
    print_listing(columns, rows, records, as_json=as_json, plain=plain, footer=footer)


def generate_command(
    log: LogArgument,
    strategy: Annotated[str, typer.Option("--strategy", help="HGT (z + --height after each frame, 2k frames a "
                                          "segment), AVG (the average of consecutive frames between them, 2k - 1), "
                                          "any operator's name (at --severity, after each frame), or none (the "
                                          "selected segments unchanged: the base log).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="New folder for the generated log (KITTI layout with "
                                      "timestamps.txt and generated_log.json).")],
    segments: Annotated[str, typer.Option(help="Segments to generate from: indices or ids, comma-separated "
                                          "(0,3,s000007), or all.")] = "all",
    size: SizeOption = 5,
    heuristic: Annotated[str | None, typer.Option(help="The heuristic that chose --segments (recorded with the "
                                                  "log; default: none, chosen by hand).")] = None,
    seed: Annotated[int, typer.Option(help="Seeds every mutant (per source frame, as campaigns do).")] = 0,
    height: Annotated[float, typer.Option(help="HGT's constant c in metres (the paper's 10).")] = 10.0,
    severity: Annotated[int, typer.Option(min=1, max=5, help="Severity of an operator strategy.")] = 3,
    radius: Annotated[float, typer.Option(min=0.0, help="AVG without rings: the farthest apart (m) two points "
                                          "may be to pair.")] = 0.5,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --out folder (once the new one is "
                                            "complete).")] = False,
    topic: TopicOption = None,
    layout: LayoutOption = None,
    record: RecordOption = None,
    parent: Annotated[str | None, typer.Option(help="With --record: the parent log's name in the store (recorded "
                                               "now when it is not; default: the log's file or folder name).")]
    = None,
    workspace: WorkspaceOption = WORKSPACE,
) -> None:
    """Generate a new log from a log's segments (Neves et al., Section IV); written atomically."""
    from lidarfuzz.structural.generate import strategy as make_strategy
    from lidarfuzz.structural.generate import write_generated_log
    from lidarfuzz.structural.segments import partition

    chosen = make_strategy(strategy, height=height, severity=severity, radius=radius)
    opened = _open(log, layout, topic)
    every = partition(opened.frame_ids, size)
    selected = parse_segments(segments, every)
    made = write_generated_log(opened, selected, chosen, out, seed=seed, heuristic=heuristic, segment_size=size,
                               overwrite=overwrite)
    if record is not None:
        from lidarfuzz.store.errors import NotFoundError
        from lidarfuzz.structural.stored import get_log, record_generated, record_log, record_segments

        with open_store(workspace).session() as session:
            name = parent or opened.path.name
            try:
                parent_row = get_log(session, name)
            except NotFoundError:
                parent_row = record_log(session, opened, name)
            record_segments(session, parent_row, every)
            record_generated(session, made, record, parent_row)
    console.print(f"wrote {len(made.frames)} frame(s) from {len(selected)} segment(s) of {opened.path} "
                  f"(strategy {made.strategy}) to {out}" + (f"; recorded as log {record!r}" if record else ""))


__all__ = ["generate_command", "parse_segments", "partition_command"]
