"""``lidarfuzz report``: a task's report files, and the tables ``run``, ``resume`` and ``report`` print."""

import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape

from lidarfuzz.cli.common import WORKSPACE, WorkspaceOption, console, disk_failures, open_store, print_table

if TYPE_CHECKING:
    from lidarfuzz.store.contracts import RateRow


def fmt(value: float | None, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.{digits}f}"


def reports_dir(workspace: str, task_id: int) -> Path:
    """Where a task's report goes: under the workspace folder, or ./lidarfuzz-reports for a database URL."""
    base = Path("lidarfuzz-reports") if "://" in workspace else Path(workspace) / "reports"
    return base / f"task-{task_id}"


def write_report(store: Any, task_id: int, out: Path, gates: list[str], baseline: int | None = None) -> int:
    """Write a task's report into ``out`` and say where; returns 1 when a gate failed, else 0."""
    try:
        from lidarfuzz.report import parse_gate
        from lidarfuzz.report import write_report as write
    except ImportError:  # pragma: no cover - the report package is part of lidarfuzz
        console.print("[yellow]the report package is not available[/]")
        return 0
    files = write(store, task_id, out, baseline=baseline, gates=[parse_gate(g) for g in gates])
    console.print(f"report: [bold]{escape(str(Path(files.html).resolve()))}[/]  "
                  f"(JSON, CSV and JUnit XML beside it)")
    if not files.passed:
        console.print("[red]gates failed[/] (see junit.xml)")
        return 1
    return 0


def print_tables(store: Any, task_id: int) -> None:
    """A task's tables as its kind has them: a structural task's coverage, a camera task's DeepTest
    figures, else AP and violations."""
    from lidarfuzz.campaign.tasks import get_task

    kind = get_task(store, task_id).options.kind
    if kind == "structural":  # no AP, no operators: its coverage tables instead
        from lidarfuzz.cli.structural import print_structural

        print_structural(store, task_id)
    elif kind == "camera":  # a steering system: MSE, Eq. 2 and 3, Table 7, the search
        from lidarfuzz.cli.camera import print_camera

        print_camera(store, task_id)
    else:
        print_summary(store, task_id)


def print_summary(store: Any, task_id: int, difficulty: str = "moderate") -> None:
    """The thesis's AP table (3D, BEV and bbox AP|R40) and the violation summary."""
    from rich.table import Table

    from lidarfuzz.campaign.results import summarise

    data = summarise(store, task_id)
    classes = data.classes
    table = Table(title=f"KITTI AP|R40, {difficulty} (task {task_id})", show_lines=False)
    table.add_column("subtask", no_wrap=True, overflow="fold")
    table.add_column("metric")
    for cls in [*classes, "mAP"]:
        table.add_column(cls, justify="right")
    table.add_column("Δ3D mAP", justify="right")
    first = data.subtasks[0]
    clean = first.ap
    for entry in data.subtasks:
        ap = entry.ap
        if ap is None:
            continue
        for i, metric in enumerate(("bbox", "bev", "3d")):
            row = [fmt(ap.ap[metric][c][difficulty]["R40"]) for c in classes]
            row.append(fmt(ap.map[metric][difficulty]["R40"]))
            delta = ""
            if metric == "3d" and clean is not None and entry is not first:
                d = ap.map["3d"][difficulty]["R40"] - clean.map["3d"][difficulty]["R40"]
                delta = f"[red]{d:+.1f}[/]" if d < -0.05 else f"{d:+.1f}"
            table.add_row(entry.label if i == 0 else "", metric.upper() if metric != "bbox" else "bbox", *row,
                          delta, end_section=metric == "3d")
    if clean is None:
        console.print("[yellow]the data set has no labels: no AP (relations still apply)[/]")
    else:
        print_table(table)
    excluded = first.ap_excluded
    if data.task.unlabelled_frames and excluded:
        console.print(f"[yellow]AP from the labelled frames only: {excluded.frames} frame(s) without a label "
                      f"file left out ({', '.join(excluded.examples)}"
                      f"{', …' if excluded.frames > len(excluded.examples) else ''}); every frame ran "
                      "through the system and the relations[/]")
    for note in data.ap_warnings:
        console.print(f"[yellow]AP warning:[/] {escape(note)}", highlight=False, soft_wrap=True)
    rates = Table(title="metamorphic relations: frames violated / checked (rate)")
    rates.add_column("operator", no_wrap=True, overflow="fold")
    relations = [r.relation or "" for r in data.violations.relation]  # grouped by relation: always set
    for relation in relations:
        rates.add_column(relation, justify="right")
    by = {(r.relation, r.operator): r for r in data.violations.relation_operator}

    def cell(r: "RateRow | None") -> str:
        if r is None:
            return ""
        text = f"{r.violated}/{r.checked} ({fmt(None if r.rate is None else 100 * r.rate, 0)}%)"
        return f"[red]{text}[/]" if r.violated else text

    for op in sorted({r.operator for r in data.violations.relation_operator if r.operator is not None}):
        rates.add_row(op, *[cell(by.get((relation, op))) for relation in relations])
    rates.add_row("all", *[cell(r) for r in data.violations.relation], style="bold")
    print_table(rates)
    print_deeptest(data)
    kinds = data.findings.by_kind
    failures = {k: v for k, v in kinds.items() if k in ("crash", "timeout", "invalid_output")}
    tool: dict[str, int] = {}
    for entry in data.subtasks:
        for kind, n in entry.tool_errors.items():
            tool[kind] = tool.get(kind, 0) + n
    console.print(f"findings: {data.findings.total} "
                  f"({', '.join(f'{k} {v}' for k, v in sorted(kinds.items())) or 'none'})"
                  + (f"; [red]system failures: {failures}[/]" if failures else ""))
    if tool:
        console.print(f"[yellow]lidarfuzz's own errors (not the system's): "
                      f"{', '.join(f'{k} {v}' for k, v in sorted(tool.items()))}[/]")
    print_search(store, task_id)


def print_deeptest(data: Any) -> None:
    """DeepTest's Table 7 of a task summary (nothing when no subtask checked ``deeptest_tolerance``)."""
    from lidarfuzz.report.deeptest import deeptest_lines

    for line in deeptest_lines(data.deeptest):
        console.print(escape(line), highlight=False, soft_wrap=True)


def print_search(store: Any, task_id: int) -> None:
    """A guided / fuzz task's coverage and search statistics (nothing for a task without a search)."""
    from rich.table import Table

    from lidarfuzz.campaign.plan import ORIGINAL
    from lidarfuzz.campaign.tasks import get_task

    task = get_task(store, task_id)
    # the search's subtask is the one that is not the originals and carries the search's progress;
    # the originals are its seeds
    sub = next((s for s in task.subtasks if s.name != ORIGINAL and s.results.search is not None), None)
    if sub is None or sub.results.search is None:
        return
    info = sub.results.search
    seeds = next((s for s in task.subtasks if s.name == ORIGINAL), None)
    what = "code coverage" if any(name.startswith("code_") for name in info.coverage) else "neuron coverage"
    table = Table(title=f"{task.options.kind} search: {what} (task {task_id})")
    table.add_column("criterion")
    table.add_column("seeds alone", justify="right")
    table.add_column("after the search", justify="right")
    seed_cov: dict[str, float] = {}
    if seeds is not None:
        from sqlalchemy import select

        from lidarfuzz.store.models import FrameResult

        with store.session() as s:
            last = s.scalars(select(FrameResult.params).where(FrameResult.subtask_id == seeds.id).order_by(
                FrameResult.id.desc()).limit(1)).first()
        seed_cov = (last or {}).get("coverage", {})
    for name, value in info.coverage.items():
        show = (lambda v: f"{v:.0f} patterns") if name == "tknp" else (lambda v: f"{100 * v:.1f}%")
        before = seed_cov.get(name)
        table.add_row(name.upper(), "" if before is None else show(before), show(value))
    print_table(table)
    st = info.stats
    console.print(f"tests {st['tests']}: accepted (new coverage) {st['accepted']}, invalid {st['invalid']}, "
                  f"violating {st['violating']}; unique findings {st['findings']}"
                  + (f" (minimising took {st['minimise_runs']} extra runs)" if st.get("minimise_runs") else ""))


def report(
    task: int,
    out: Annotated[Path | None, typer.Option(help="Folder for report.html, JSON, CSV and JUnit XML "
                                                  "(default: <workspace>/reports/task-ID); - prints "
                                                  "report.html on stdout and writes nothing.")] = None,
    baseline: Annotated[int | None, typer.Option(help="A task of a baseline system on the same campaign: "
                                                      "compared with (violation rates with a significance test, "
                                                      "disagreements, recall/AP by group; lidarfuzz compare) and "
                                                      "for Robo3D's corruption error, CE/mCE.")] = None,
    gate: Annotated[list[str] | None, typer.Option(help="JUnit gate, e.g. ap_drop:3d:Car:fog@3>10 or "
                                                        "violations:preservation>0 (repeatable).")] = None,
    quiet: Annotated[bool, typer.Option(help="Do not print the tables.")] = False,
    workspace: WorkspaceOption = WORKSPACE,
) -> None:
    """Write a task's report (self-contained HTML, JSON, CSV, JUnit XML) and print its tables."""
    store = open_store(workspace)
    if out == Path("-"):  # the page alone (a read-only workspace can be reported): no tables, no files
        from lidarfuzz.report import render_report

        sys.stdout.write(render_report(store, task, baseline=baseline))
        return
    if not quiet:
        print_tables(store, task)
        from lidarfuzz.cli.compare import print_comparisons

        print_comparisons(store, task, baseline)
    target = out or reports_dir(workspace, task)
    with disk_failures(f"nothing half-written is left; lidarfuzz report {task} writes it again (--out - prints "
                       f"report.html)"):
        code = write_report(store, task, target, gate or [], baseline)
    raise typer.Exit(code)
