"""``lidarfuzz operators`` (what exists) and ``lidarfuzz mutate`` (apply one)."""

import inspect
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer
from rich.markup import escape

from lidarfuzz.cli.common import (
    Column,
    JsonOption,
    LayoutOption,
    PlainOption,
    console,
    err_console,
    print_listing,
    print_table,
)


def _refuse(option: str, message: str) -> NoReturn:
    """A bad option value: one line naming the option and what it takes, exit code 2 (no usage box)."""
    err_console.print(f"[bold red]error:[/] {option}: {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(2)


def operators_command(
    name: Annotated[str | None, typer.Argument(help="Show one operator in full (name or alias).")] = None,
    modality: Annotated[str | None, typer.Option(help="Only the operators for this data: lidar (point clouds) "
                                                 "or camera (images).")] = None,
    as_json: JsonOption = False,
    plain: PlainOption = False,
) -> None:
    """List the mutation operators: modality, family, relation, targets, parameters and severity table."""
    from lidarfuzz.operators import available, get
    from lidarfuzz.operators.catalogue import format_value, severity_rows

    known_modalities = sorted({cls.modality for cls in available().values()})
    if modality is not None and modality not in known_modalities:
        _refuse("--modality", f"expected one of {', '.join(known_modalities)}, got {modality!r}")

    if name is not None:
        cls = get(name)
        if as_json or plain:
            parameter_rows = [[field, description, *values] for field, description, values in severity_rows(cls)]
            parameters = [{"name": row[0], "description": row[1], "severities": row[2:]} for row in parameter_rows]
            record = {**_record(cls), "doc": inspect.getdoc(cls) or "", "parameters": parameters}
            print_listing([], parameter_rows, record, as_json=as_json, plain=plain)
            return
        from rich.table import Table

        console.print(f"[bold]{cls.name}[/] ({', '.join(cls.aliases) or 'no aliases'}) — {cls.modality}, "
                      f"{cls.family}, {cls.relation.value}; changes {', '.join(sorted(t.value for t in cls.targets))}")
        console.print(inspect.getdoc(cls) or "")
        table = Table("parameter", "description", *(f"severity {s}" for s in (0, *cls.SEVERITIES)))
        table.columns[0].no_wrap, table.columns[0].overflow = True, "fold"
        for field, description, values in severity_rows(cls):
            table.add_row(field, description, *values)
        print_table(table)
        return
    rows: list[list[str]] = []
    records: list[dict[str, Any]] = []
    listed = {n: cls for n, cls in available().items() if modality is None or cls.modality == modality}
    for op_name, cls in sorted(listed.items(), key=lambda kv: (kv[1].modality != "lidar", kv[1].family, kv[0])):
        low, high = cls.SEVERITIES.get(1, {}), cls.SEVERITIES.get(max(cls.SEVERITIES, default=1), {})
        span = "; ".join(f"{k} {format_value(low[k])} … {format_value(high.get(k))}" for k in low)
        rows.append([op_name, ", ".join(cls.aliases), cls.modality, cls.family, cls.relation.value,
                     ", ".join(sorted(t.value for t in cls.targets)), span])
        records.append({**_record(cls), "name": op_name})
    columns = [Column("name", name=True), Column("aliases"), Column("modality"), Column("family"), Column("relation"),
               Column("changes"), Column("severity 1 … 5")]
    print_listing(columns, rows, records, as_json=as_json, plain=plain,
                  footer="details: [cyan]lidarfuzz operators NAME[/]")


def _record(cls: Any) -> dict[str, Any]:
    """An operator class as JSON: names, modality, family, relation, targets and its parameters at each severity."""
    return {"name": cls.name, "aliases": list(cls.aliases), "modality": cls.modality, "family": cls.family,
            "relation": cls.relation.value,
            "targets": sorted(t.value for t in cls.targets),
            "severities": {str(level): params for level, params in sorted(cls.SEVERITIES.items())}}


def mutate_command(
    src: Annotated[Path, typer.Argument(help="Frame file, data set folder or log to mutate (never modified).")],
    dst: Annotated[Path, typer.Argument(help="Where to write the mutants (any destination `convert` takes).")],
    op: Annotated[str, typer.Option("--op", help="Operator name or alias (see lidarfuzz operators).")],
    severity: Annotated[int | None, typer.Option(min=0, max=5, help="Severity 0–5 (default 3).")] = None,
    param: Annotated[list[str] | None, typer.Option(help="Config field as key=value (repeatable), e.g. "
                                                    "ratio=0.2 or angle_range=[10,20]; instead of "
                                                    "--severity.")] = None,
    seed: Annotated[int, typer.Option(help="Seed: the same seed gives the same mutants.")] = 0,
    to: Annotated[str | None, typer.Option(help="Destination format, as for convert.")] = None,
    overwrite: Annotated[bool, typer.Option(help="Replace an existing destination.")] = False,
    interleave: Annotated[bool, typer.Option(help="For a log: write a new log with each mutant after its "
                                             "source frame (Neves et al.); with --op AVG, each average of "
                                             "two consecutive frames between them.")] = False,
    layout: LayoutOption = None,
) -> None:
    """Apply one operator to every frame; labels are updated with the points and each frame's
    concrete params are saved (mutations.jsonl) so every mutant replays exactly."""
    from rich.progress import Progress

    from lidarfuzz.io.options import options_from_flags
    from lidarfuzz.operators.lidar.log import FrameAverage
    from lidarfuzz.operators.mutate import build_operator, is_frame_average, mutate, mutate_log, parse_assignments

    options = options_from_flags(layout)
    if is_frame_average(op):
        if not interleave:
            _refuse("--op", "AVG combines consecutive frames of a log: add --interleave")
        written = mutate_log(src, dst, FrameAverage(), seed=seed, to=to, overwrite=overwrite, options=options)
        console.print(f"wrote a log of {written.frames} frame(s) to {written.destination} ({written.target})")
        return
    operator = build_operator(op, severity, parse_assignments(param or []))
    if operator.modality != "lidar":
        _refuse("--op", f"{operator.name} is a {operator.modality} operator; mutate writes lidar frames "
                "(lidarfuzz operators --modality lidar)")
    if interleave:
        written = mutate_log(src, dst, operator, seed=seed, to=to, overwrite=overwrite, options=options)
        console.print(f"wrote a log of {written.frames} frame(s) to {written.destination} ({written.target})")
        return
    with Progress(console=console, transient=True) as progress:
        task = progress.add_task(f"mutating ({operator.name})", total=None)
        result = mutate(src, dst, operator, seed=seed, to=to, overwrite=overwrite, options=options,
                        on_frame=lambda done, total: progress.update(task, completed=done, total=total))
    console.print(f"wrote {result.conversion.frames} mutant(s) of {src} to {result.conversion.destination} "
                  f"({result.conversion.target}); params: {result.record}")
