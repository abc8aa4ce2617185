"""``lidarfuzz logs partition | select | generate | compare | search``: Neves et al.'s logs, segments and
generated logs, and a search for logs that reach uncovered code."""

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




SutOption = Annotated[str, typer.Option("--sut", help="The system that consumes the log in order: a registered "
                                        "sequence system (controller, …), module:callable (its code measured in "
                                        "this process) or worker:COMMAND running a Python program (measured in "
                                        "its process).")]
TargetOption = Annotated[list[str], typer.Option("--target", help="Code to cover: pkg.module, pkg.module:Class or "
                                                 "pkg.module:function; repeatable.")]
GcovOption = Annotated[Path | None, typer.Option(
    "--gcov", help="A compiled worker: program's build folder (built with --coverage; the program dumps its counts "
                   "before answering a request with \"gcov_dump\": true). --target then names source files or "
                   "file:function, relative to --source-root.")]
SourceRootOption = Annotated[Path | None, typer.Option("--source-root", help="With --gcov: the sources' root "
                                                       "(default: the build folder).")]


def _replay(log: OrderedLog, sut: str, targets: list[str], gcov: Path | None = None,
            source_root: Path | None = None) -> tuple[Any, Any, str]:
    """(the log's frame coverage, the recorder, the system's fingerprint) for ``sut`` on ``log``."""
    from lidarfuzz.structural.log_coverage import frame_coverage, measured_system

    system, recorder, _ = measured_system(sut, targets, gcov=gcov, source_root=source_root)
    with system:
        replay = frame_coverage(log, system.step, recorder, reset=system.reset)
        fingerprint = system.fingerprint()
    if replay.failures:
        first = min(replay.failures)
        console.print(f"[yellow]{len(replay.failures)} frame(s) failed[/] (first: position {first}, "
                      f"{replay.failures[first]}); what they covered before failing counts")
    return replay, recorder, fingerprint


def _record_coverage(workspace: str, name: str, log: OrderedLog, segments: list[Segment], per_segment: list[Any],
                     fingerprint: str, target: str, total: Any) -> None:
    """The log (recorded when new), its partition, and its and every segment's coverage per criterion."""
    from lidarfuzz.store.errors import NotFoundError
    from lidarfuzz.store.log_contracts import Criterion
    from lidarfuzz.structural.requirements import union
    from lidarfuzz.structural.stored import get_log, record_coverage, record_log, record_segments

    with open_store(workspace).session() as session:
        try:
            row = get_log(session, name)
        except NotFoundError:
            row = record_log(session, log, name)
        rows = record_segments(session, row, segments)
        whole = union(*per_segment)
        criteria: tuple[Criterion, ...] = ("node", "edge")
        for criterion in criteria:
            record_coverage(session, log=row, fingerprint=fingerprint, criterion=criterion, target=target,
                            covered=whole, total=total)
            for segment_row, covered in zip(rows, per_segment, strict=True):
                record_coverage(session, segment=segment_row, fingerprint=fingerprint, criterion=criterion,
                                target=target, covered=covered, total=total)


def _percent(value: float) -> str:
    return f"{100 * value:.1f} %"


def select_command(
    log: LogArgument,
    sut: SutOption,
    target: TargetOption,
    heuristic: Annotated[str, typer.Option(help="greedy_edges, greedy_nodes, budget, decision_change or random.")]
    = "greedy_edges",
    size: SizeOption = 5,
    frames: Annotated[int | None, typer.Option("--frames", min=1, help="budget's frame budget.")] = None,
    seed: Annotated[int, typer.Option(help="random's seed.")] = 0,
    reference: Annotated[str, typer.Option(help="The heuristic whose selection size random matches.")]
    = "greedy_edges",
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Also write the reduced base log (the selected "
                                             "segments, in the log's order) to this new folder.")] = None,
    topic: TopicOption = None,
    gcov: GcovOption = None,
    source_root: SourceRootOption = None,
    layout: LayoutOption = None,
    record: Annotated[str | None, typer.Option("--record", help="Record the log, its segments and the coverage "
                                               "of the log and of every segment (per criterion, with the "
                                               "system's fingerprint) in the store under this name.")] = None,
    workspace: WorkspaceOption = WORKSPACE,
    as_json: JsonOption = False,
) -> None:
    """Replay a log through a system under coverage and select its discriminatory segments."""
    from lidarfuzz.structural.generate import strategy, write_generated_log
    from lidarfuzz.structural.heuristics import closeness, select
    from lidarfuzz.structural.log_coverage import decision_signature
    from lidarfuzz.structural.requirements import coverage_ratio, of_kind, union
    from lidarfuzz.structural.segments import partition, segment_coverage

    if heuristic == "budget" and frames is None:
        raise typer.BadParameter("the budget heuristic needs a frame budget", param_hint="--frames")
    opened = _open(log, layout, topic)
    replay, recorder, fingerprint = _replay(opened, sut, target, gcov, source_root)
    segments = partition(opened.frame_ids, size)
    per_segment = segment_coverage(segments, replay.covered)
    if record is not None:
        _record_coverage(workspace, record, opened, segments, per_segment, fingerprint, ",".join(target),
                         recorder.requirements())
    try:
        chosen = select(heuristic, segments, per_segment, frames=frames,
                        signatures=[decision_signature(o) for o in replay.outputs], seed=seed, reference=reference)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--heuristic") from None
    total = recorder.requirements()
    near = closeness(chosen, per_segment, segments, total)
    alone = None
    if out is not None:
        write_generated_log(opened, [segments[i] for i in chosen.segments], strategy("none"), out,
                            heuristic=heuristic, segment_size=size)
        # replayed on its own the system's state differs from inside the full log: say what it covers then
        base, _, _ = _replay(_open(out, layout, None), sut, target, gcov, source_root)
        alone = union(*base.covered)
    rows = [[segments[s.segment].id, str(len(segments[s.segment])), str(len(of_kind(s.added, "node"))),
             str(len(of_kind(s.added, "edge"))), str(s.score)] for s in chosen.steps]
    summary = {"heuristic": heuristic, "segments": near.segments, "frames": near.frames,
               "log_segments": near.log_segments, "log_frames": near.log_frames, "nodes": near.nodes,
               "edges": near.edges, "log_nodes": near.log_nodes, "log_edges": near.log_edges,
               "steps": [{"segment": segments[s.segment].id, "index": s.segment, "frames": s.frames,
                          "added_nodes": len(of_kind(s.added, "node")), "added_edges": len(of_kind(s.added, "edge")),
                          "score": s.score} for s in chosen.steps]}
    if alone is not None:  # the base log replayed on its own
        summary.update(base_nodes=coverage_ratio(alone, total, "node"), base_edges=coverage_ratio(alone, total, "edge"))
    footer = (f"{heuristic}: {near.segments} of {near.log_segments} segments, {near.frames} of {near.log_frames} "
              f"frames: nodes {_percent(near.nodes)}, edges {_percent(near.edges)} (the full log: nodes "
              f"{_percent(near.log_nodes)}, edges {_percent(near.log_edges)})"
              + (f"; base log written to {out}" if out is not None else "")
              + (f"; replayed on its own it covers nodes {_percent(coverage_ratio(alone, total, 'node'))}, edges "
                 f"{_percent(coverage_ratio(alone, total, 'edge'))} (the system's state differs from inside the "
                 "full log)" if alone is not None else ""))
    columns = [Column("segment", name=True), Column("frames", justify="right"), Column("+nodes", justify="right"),
               Column("+edges", justify="right"), Column("score", justify="right")]
    print_listing(columns, rows, summary, as_json=as_json, footer=footer)


def compare_command(
    base: Annotated[Path, typer.Argument(help="The base log L'.")],
    generated: Annotated[Path, typer.Argument(help="The generated log L''.")],
    sut: SutOption,
    target: TargetOption,
    gcov: GcovOption = None,
    source_root: SourceRootOption = None,
    layout: LayoutOption = None,
    as_json: JsonOption = False,
) -> None:
    """Coverage of two logs side by side, and the aggregated coverage: what L'' reached that L' did not."""
    from lidarfuzz.structural.log_coverage import compare_logs

    first, first_recorder, _ = _replay(_open(base, layout, None), sut, target, gcov, source_root)
    second, _, _ = _replay(_open(generated, layout, None), sut, target, gcov, source_root)
    rows, records = [], []
    comparisons = compare_logs(first.covered, second.covered, first_recorder.requirements())
    for c in comparisons:
        name = "all-nodes" if c.kind == "node" else "all-edges"
        rows.append([name, str(c.total), _percent(c.base), _percent(c.generated), _percent(c.together),
                     _percent(c.aggregated), str(len(c.new))])
        records.append({"criterion": name, "total": c.total, "base": c.base, "generated": c.generated,
                        "together": c.together, "aggregated": c.aggregated, "new": sorted(r.label() for r in c.new)})
    columns = [Column("criterion", name=True), Column("total", justify="right"), Column("L'", justify="right"),
               Column("L''", justify="right"), Column("together", justify="right"),
               Column("aggregated", justify="right"), Column("new", justify="right")]
    new = sorted({r for c in comparisons for r in c.new})
    shown = ", ".join(r.label().split(":", 1)[-1] for r in new[:12])  # without the module: Class.method:line
    more = f", and {len(new) - 12} more (--json lists all)" if len(new) > 12 else ""
    footer = f"new in L'': {shown}{more}" if new else "L'' reached nothing L' did not"
    print_listing(columns, rows, records, as_json=as_json, footer=footer)


def search_command(
    log: LogArgument,
    sut: SutOption,
    target: TargetOption,
    out: Annotated[Path, typer.Option("--out", "-o", help="New folder for the generated log (KITTI layout, "
                                      "generated_log.json); its checkpoint is OUT.search.json, and a rerun with the "
                                      "same arguments continues from it.")],
    budget: Annotated[int, typer.Option(min=0, help="Candidates to try: one replay of the log each.")] = 50,
    seed: Annotated[int, typer.Option(help="Seeds every draw.")] = 0,
    operators: Annotated[str | None, typer.Option(help="The operator pool, comma-separated (default: heights, "
                                                  "positions, objects, deletions, clutter, weather).")] = None,
    size: SizeOption = 5,
    max_severity: Annotated[int, typer.Option(min=1, max=5, help="Severities are drawn from 1 to this.")] = 5,
    random: Annotated[bool, typer.Option("--random", help="The baseline: segments and operators at random on the "
                                         "log's own frames, nothing built on a kept candidate.")] = False,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing --out folder that is no output of this "
                                            "search.")] = False,
    topic: TopicOption = None,
    layout: LayoutOption = None,
    record: Annotated[str | None, typer.Option("--record", help="Record the generated log in the store under this "
                                               "name (heuristic search; its parent recorded too).")] = None,
    workspace: WorkspaceOption = WORKSPACE,
    as_json: JsonOption = False,
) -> None:
    """Search for a log that covers code the log does not: mutate segments, keep what reaches new code."""
    from lidarfuzz.structural.search import DEFAULT_OPERATORS, SearchSettings, search_log
    from lidarfuzz.suts.registry import create_sequence

    pool = DEFAULT_OPERATORS if operators is None else tuple(o.strip() for o in operators.split(",") if o.strip())
    settings = SearchSettings(operators=pool, budget=budget, seed=seed, size=size, max_severity=max_severity,
                              strategy="random" if random else "search")
    opened = _open(log, layout, topic)

    def report(candidate: Any) -> None:
        if candidate.kept and not as_json:
            console.print(f"candidate {candidate.index}: {candidate.source} + {'+'.join(candidate.operators)} "
                          f"covers {len(candidate.new)} new requirement(s)")

    with create_sequence(sut) as system:
        result = search_log(opened, system, target, settings, out, system_spec=sut, overwrite=overwrite,
                            on_candidate=report)
    if record is not None and result.log is not None:
        from lidarfuzz.store.errors import NotFoundError
        from lidarfuzz.structural.segments import partition
        from lidarfuzz.structural.stored import get_log, record_generated, record_log, record_segments

        with open_store(workspace).session() as session:
            try:
                parent_row = get_log(session, opened.path.name)
            except NotFoundError:
                parent_row = record_log(session, opened, opened.path.name)
            record_segments(session, parent_row, partition(opened.frame_ids, size))
            record_generated(session, result.log, record, parent_row)
    summary = result.to_json()
    rows = []
    for function, kinds in result.per_function().items():
        by = sorted({(m.candidate, m.source, "+".join(m.operators)) for r, m in result.found.items()
                     if r.function == function})
        rows.append([function, str(len(kinds["node"])), str(len(kinds["edge"])),
                     ", ".join(f"c{c} ({source}: {ops})" for c, source, ops in by)])
    counts = summary["coverage"]
    st = result.stats

    def share(kind: str, which: str) -> str:
        return f"{counts[kind][which]}/{counts[kind]['total']}"

    footer = (f"{st['candidates']} candidate(s), {st['replays']} replay(s), {st['kept']} kept; nodes "
              f"{share('node', 'start')} -> {share('node', 'covered')}, edges {share('edge', 'start')} -> "
              f"{share('edge', 'covered')}; {result.frames} frame(s) written to {out}"
              + (f"; recorded as log {record!r}" if record else ""))
    columns = [Column("function", name=True), Column("+nodes", justify="right"), Column("+edges", justify="right"),
               Column("found by")]
    print_listing(columns, rows, summary, as_json=as_json, footer=footer)


__all__ = ["compare_command", "generate_command", "parse_segments", "partition_command", "search_command",
           "select_command"]
