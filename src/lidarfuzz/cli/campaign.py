"""Campaign commands: ``run``, ``status``, ``resume``, ``cancel``, ``list``, ``delete``, ``report``, ``replay``.

They drive the engine in :mod:`lidarfuzz.campaign` (the web app drives the same one).
"""

from __future__ import annotations

import math
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

from lidarfuzz.cli.catalog import WORKSPACE, WorkspaceOption, _store
from lidarfuzz.errors import LidarfuzzError

WorkersOption = Annotated[int | None, typer.Option(min=1, help="Worker processes (default: the CPU count).")]
InlineOption = Annotated[bool, typer.Option(help="Run every unit in this process (no pool; for debugging).")]


def parse_op(text: str) -> dict[str, Any]:
    """``fog`` or ``fog@1,3,5`` → an operator choice of a campaign."""
    name, _, severities = text.partition("@")
    choice: dict[str, Any] = {"name": name.strip()}
    if severities.strip():
        try:
            choice["severities"] = [int(v) for v in severities.split(",") if v.strip()]
        except ValueError:
            raise LidarfuzzError(f"--op {text!r}: severities are integers, e.g. fog@1,3,5") from None
    return choice


def fmt(value: float | None, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.{digits}f}"


def _age(moment: datetime | None) -> float | None:
    if moment is None:
        return None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return (datetime.now(UTC) - moment).total_seconds()


def reports_dir(workspace: str, task_id: int) -> Path:
    """Where a task's report goes: under the workspace folder, or ./lidarfuzz-reports for a database URL."""
    base = Path("lidarfuzz-reports") if "://" in workspace else Path(workspace) / "reports"
    return base / f"task-{task_id}"


def execute(workspace: str, task_id: int, *, workers: int | None, inline: bool, show_progress: bool = True,
            report: bool = True, gates: list[str] | None = None) -> int:
    """Run a task with progress bars, print its tables and write its report; returns an exit code."""
    from lidarfuzz.campaign.executor import make_executor
    from lidarfuzz.campaign.runner import ProgressEvent, run_task
    from lidarfuzz.campaign.tasks import get_task
    from lidarfuzz.cli.app import console
    from lidarfuzz.store.models import Status

    store = _store(workspace)
    task = get_task(store, task_id)
    kind = task.options.get("kind", "mutation")
    plan = (f"{len(task.subtasks) - 1} operator × severity subtasks" if kind == "mutation" else
            f"{kind} search of {task.options['search']['budget']} tests from "
            f"{len(task.options['frame_ids'])} seed frames")
    console.print(f"task [bold]{task_id}[/]: {escape(task.model.name)} on {escape(task.dataset.name)}, "
                  f"{plan}, {task.total} units ({task.done} done before)")
    columns = (TextColumn("{task.description:<28}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TimeRemainingColumn())
    with Progress(*columns, console=console, disable=not show_progress, transient=False) as bars:
        overall = bars.add_task("all units", total=task.total, completed=task.done)
        current = bars.add_task("", total=1, completed=0)
        shown: list[int] = [-1]

        def on_progress(event: ProgressEvent) -> None:
            if event.subtask_id != shown[0]:
                shown[0] = event.subtask_id
                bars.update(current, description=event.label, total=event.subtask_total)
            bars.update(current, completed=event.subtask_done)
            bars.update(overall, completed=event.task_done)

        try:
            outcome = run_task(store, task_id, executor=make_executor(workers, inline), progress=on_progress)
        except KeyboardInterrupt:
            console.print(f"\ninterrupted; what is done is stored. Finish with: lidarfuzz resume {task_id}")
            return 130
    if outcome.status == Status.CANCELLED:
        console.print(f"task {task_id} cancelled; what is done is stored (lidarfuzz resume {task_id} finishes it)")
        return 1
    print_summary(store, task_id)
    code = 0
    if report:
        code = write_report(store, task_id, reports_dir(workspace, task_id), gates or [])
    return code


def write_report(store: Any, task_id: int, out: Path, gates: list[str], baseline: int | None = None) -> int:
    from lidarfuzz.cli.app import console

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


def print_summary(store: Any, task_id: int, difficulty: str = "moderate") -> None:
    """The thesis's AP table (3D, BEV and bbox AP|R40) and the violation summary."""
    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.cli.app import console

    data = summarise(store, task_id)
    classes = data["classes"]
    table = Table(title=f"KITTI AP|R40, {difficulty} (task {task_id})", show_lines=False)
    table.add_column("subtask")
    table.add_column("metric")
    for cls in [*classes, "mAP"]:
        table.add_column(cls, justify="right")
    table.add_column("Δ3D mAP", justify="right")
    clean = data["subtasks"][0].get("ap")
    for entry in data["subtasks"]:
        ap = entry.get("ap")
        if ap is None:
            continue
        for i, metric in enumerate(("bbox", "bev", "3d")):
            row = [fmt(ap["ap"][metric][c][difficulty]["R40"]) for c in classes]
            row.append(fmt(ap["map"][metric][difficulty]["R40"]))
            delta = ""
            if metric == "3d" and clean is not None and entry is not data["subtasks"][0]:
                d = ap["map"]["3d"][difficulty]["R40"] - clean["map"]["3d"][difficulty]["R40"]
                delta = f"[red]{d:+.1f}[/]" if d < -0.05 else f"{d:+.1f}"
            table.add_row(entry["label"] if i == 0 else "", metric.upper() if metric != "bbox" else "bbox", *row,
                          delta, end_section=metric == "3d")
    if clean is None:
        console.print("[yellow]the data set has no labels: no AP (relations still apply)[/]")
    else:
        console.print(table)
    excluded = data["subtasks"][0].get("ap_excluded")
    if data["task"].get("unlabelled_frames") and excluded:
        console.print(f"[yellow]AP from the labelled frames only: {excluded['frames']} frame(s) without a label "
                      f"file left out ({', '.join(excluded['examples'])}"
                      f"{', …' if excluded['frames'] > len(excluded['examples']) else ''}); every frame ran "
                      "through the system and the relations[/]")
    for note in data.get("ap_warnings", []):
        console.print(f"[yellow]AP warning:[/] {escape(note)}", highlight=False, soft_wrap=True)
    rates = Table(title="metamorphic relations: frames violated / checked (rate)")
    rates.add_column("operator")
    relations = [r["relation"] for r in data["violations"]["relation"]]
    for relation in relations:
        rates.add_column(relation, justify="right")
    by = {(r["relation"], r["operator"]): r for r in data["violations"]["relation_operator"]}

    def cell(r: dict[str, Any] | None) -> str:
        if r is None:
            return ""
        text = f"{r['violated']}/{r['checked']} ({fmt(None if r['rate'] is None else 100 * r['rate'], 0)}%)"
        return f"[red]{text}[/]" if r["violated"] else text

    for op in sorted({r["operator"] for r in data["violations"]["relation_operator"]}):
        rates.add_row(op, *[cell(by.get((relation, op))) for relation in relations])
    rates.add_row("all", *[cell(r) for r in data["violations"]["relation"]], style="bold")
    console.print(rates)
    kinds = data["findings"]["by_kind"]
    failures = {k: v for k, v in kinds.items() if k in ("crash", "timeout", "invalid_output", "operator_error")}
    console.print(f"findings: {data['findings']['total']} "
                  f"({', '.join(f'{k} {v}' for k, v in sorted(kinds.items())) or 'none'})"
                  + (f"; [red]system failures: {failures}[/]" if failures else ""))
    print_search(store, task_id)


def print_search(store: Any, task_id: int) -> None:
    """A guided / fuzz task's coverage and search statistics."""
    from lidarfuzz.campaign.tasks import get_task
    from lidarfuzz.cli.app import console

    task = get_task(store, task_id)
    kind = task.options.get("kind", "mutation")
    sub = next((s for s in task.subtasks if s.name == kind), None)
    if sub is None or "search" not in sub.results:
        return
    info = sub.results["search"]
    seeds = next((s for s in task.subtasks if s.name != kind), None)
    table = Table(title=f"{kind} search: neuron coverage (task {task_id})")
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
    for name, value in info["coverage"].items():
        show = (lambda v: f"{v:.0f} patterns") if name == "tknp" else (lambda v: f"{100 * v:.1f}%")
        before = seed_cov.get(name)
        table.add_row(name.upper(), "" if before is None else show(before), show(value))
    console.print(table)
    st = info["stats"]
    console.print(f"tests {st['tests']}: accepted (new coverage) {st['accepted']}, invalid {st['invalid']}, "
                  f"violating {st['violating']}; unique findings {st['findings']}"
                  + (f" (minimising took {st['minimise_runs']} extra runs)" if st.get("minimise_runs") else ""))


def register(app: typer.Typer) -> None:
    @app.command()
    def run(
        campaign: Annotated[Path | None, typer.Argument(help="A campaign file (YAML/JSON); or use the flags.")] = None,
        dataset: Annotated[str | None, typer.Option(help="Registered data set name, or a path.")] = None,
        sut: Annotated[str | None, typer.Option(help="Registered model name, or a SUT spec (lidarfuzz suts).")] = None,
        op: Annotated[list[str] | None, typer.Option(help="Operator, optionally with severities: fog@1,3,5 "
                                                          "(repeatable; default severities 1,3,5).")] = None,
        relations: Annotated[str, typer.Option(help="auto, or comma-separated relation names.")] = "auto",
        seed: Annotated[int, typer.Option(help="Campaign seed (every mutant derives from it).")] = 0,
        trials: Annotated[int, typer.Option(min=1, help="Mutants per frame and severity.")] = 1,
        frames: Annotated[int | None, typer.Option(min=1, help="Only the first N frames.")] = None,
        name: Annotated[str, typer.Option(help="A name for the task.")] = "",
        option: Annotated[list[str] | None, typer.Option(help="SUT option k=v (repeatable).")] = None,
        isolate: Annotated[bool, typer.Option(help="Run the SUT in its own process with --timeout.")] = False,
        timeout: Annotated[float, typer.Option(help="Seconds per frame with --isolate.")] = 60.0,
        save_mutants: Annotated[Path | None, typer.Option(help="Also write each subtask's mutants as a KITTI "
                                                               "data set under this folder.")] = None,
        gate: Annotated[list[str] | None, typer.Option(help="JUnit gate, e.g. ap_drop:3d:Car:fog@3>10 "
                                                            "(repeatable; exit code 1 when one fails).")] = None,
        workers: WorkersOption = None,
        inline: InlineOption = False,
        detach: Annotated[bool, typer.Option(help="Only create the task; run it with lidarfuzz resume.")] = False,
        kind: Annotated[str, typer.Option(help="mutation (operators × severities), or a coverage-guided search: "
                                                "guided (DeepTest's greedy search) or fuzz (DeepHunter-style loop); "
                                                "with a search, --op names the operator pool (default pool if none).")
                        ] = "mutation",
        budget: Annotated[int | None, typer.Option(min=1, help="guided/fuzz: tests to generate (default 200).")] = None,
        criteria: Annotated[str | None, typer.Option(
            help="guided/fuzz: coverage criteria, e.g. nc:0.2,kmnc:10,nbc,snac,tknc:2,tknp:2 (the default).")] = None,
        guide: Annotated[str | None, typer.Option(help="guided/fuzz: criterion whose increase accepts a test "
                                                       "(default nc).")] = None,
        search_option: Annotated[list[str] | None, typer.Option(
            "--search", help="guided/fuzz: any search setting k=v, e.g. max_failed_tries=5, batch=4, keep_share=0.5 "
                             "(repeatable).")] = None,
        layout: Annotated[str | None, typer.Option(help="Point layout of a data set given by path: kitti, nuscenes, "
                                                        "… or columns such as x,y,z,intensity,ring:f4.")] = None,
        allow_unlabelled: Annotated[bool, typer.Option(help="Run a labelled data set whose frames are not all "
                                                             "labelled: every frame through the SUT and relations, AP "
                                                             "from the labelled ones.")] = False,
        workspace: WorkspaceOption = WORKSPACE,
    ) -> None:
        """Create a campaign task and run it: originals and mutants through the SUT, AP, relations, report.

        With --kind guided or fuzz the task is a coverage-guided search on a learned SUT (e.g. pillars):
        generated tests, neuron coverage and deduplicated, minimised findings.
        """
        from lidarfuzz.campaign.spec import load_campaign, parse_campaign
        from lidarfuzz.campaign.tasks import create_task
        from lidarfuzz.cli.app import console
        from lidarfuzz.io.options import options_from_flags
        from lidarfuzz.operators.mutate import parse_assignments

        if campaign is not None:
            if dataset or sut or op:
                raise LidarfuzzError("give a campaign file or --dataset/--sut/--op, not both")
            spec = load_campaign(campaign)
        else:
            needed = (("--dataset", dataset), ("--sut", sut)) + ((("--op", op),) if kind == "mutation" else ())
            missing = [flag for flag, value in needed if not value]
            if missing:
                raise LidarfuzzError(f"missing {', '.join(missing)} (or give a campaign file); see lidarfuzz run -h")
            chosen: Any = "auto" if relations == "auto" else [r.strip() for r in relations.split(",") if r.strip()]
            search: dict[str, Any] = dict(parse_assignments(search_option or []))
            if budget is not None:
                search["budget"] = budget
            if criteria is not None:
                search["criteria"] = [c.strip() for c in criteria.split(",") if c.strip()]
            if guide is not None:
                search["guide"] = guide
            spec = parse_campaign({"name": name, "dataset": dataset, "sut": sut, "kind": kind,
                                   "operators": [parse_op(o) for o in op or []], "search": search,
                                   "relations": chosen, "seed": seed, "trials": trials, "frames": frames},
                                  "command line")
        store = _store(workspace)
        task_id = create_task(store, spec, sut_options=parse_assignments(option or []), isolate=isolate,
                              timeout=timeout, save_mutants=str(save_mutants.resolve()) if save_mutants else None,
                              dataset_options=options_from_flags(layout, allow_unlabelled))
        if detach:
            console.print(f"created task {task_id}; run it with: lidarfuzz resume {task_id}")
            return
        raise typer.Exit(execute(workspace, task_id, workers=workers, inline=inline, gates=gate))

    @app.command()
    def resume(
        task: Annotated[int, typer.Argument(help="Task id (lidarfuzz list).")],
        workers: WorkersOption = None,
        inline: InlineOption = False,
        force: Annotated[bool, typer.Option(help="Resume even if another process seems to be running it.")] = False,
        workspace: WorkspaceOption = WORKSPACE,
    ) -> None:
        """Finish an interrupted, cancelled or failed task: only units without a result run."""
        from lidarfuzz.campaign.tasks import get_task, heartbeat_age, looks_alive
        from lidarfuzz.cli.app import console
        from lidarfuzz.store.models import Status

        row = get_task(_store(workspace), task)
        if row.status == Status.DONE:
            console.print(f"task {task} is done already (lidarfuzz report {task})")
            return
        age = heartbeat_age(row) or 0.0
        if looks_alive(row) and not force:
            raise LidarfuzzError(f"task {task} looks alive: {row.worker} reported {age:.0f} s ago "
                                 f"(--force to resume anyway)")
        raise typer.Exit(execute(workspace, task, workers=workers, inline=inline))

    @app.command()
    def cancel(task: int, workspace: WorkspaceOption = WORKSPACE) -> None:
        """Stop a task cleanly (a running one stops within a second; what is done stays)."""
        from lidarfuzz.campaign.tasks import cancel_task
        from lidarfuzz.cli.app import console

        status = cancel_task(_store(workspace), task)
        console.print(f"task {task}: {status.value}")

    @app.command()
    def delete(task: int, workspace: WorkspaceOption = WORKSPACE) -> None:
        """Delete a task and its results (the data set and model stay)."""
        from lidarfuzz.campaign.tasks import delete_task
        from lidarfuzz.cli.app import console

        delete_task(_store(workspace), task)
        console.print(f"deleted task {task}")

    @app.command("list")
    def list_(limit: Annotated[int, typer.Option(help="Newest N tasks.")] = 50,
              workspace: WorkspaceOption = WORKSPACE) -> None:
        """The tasks in the store, newest first."""
        from lidarfuzz.campaign.tasks import list_tasks
        from lidarfuzz.cli.app import console

        table = Table("id", "name", "status", "data set", "SUT", "subtasks", "progress", "started", "finished")
        for t in list_tasks(_store(workspace), limit):
            share = f"{t.done}/{t.total} ({100 * t.done / t.total:.0f}%)" if t.total else "0/0"
            table.add_row(str(t.id), escape(t.name), t.status.value, escape(t.dataset.name), escape(t.model.name),
                          str(len(t.operators)), share,
                          f"{t.started_at:%Y-%m-%d %H:%M}" if t.started_at else "",
                          f"{t.finished_at:%Y-%m-%d %H:%M}" if t.finished_at else "")
        console.print(table)

    @app.command()
    def status(task: int, workspace: WorkspaceOption = WORKSPACE) -> None:
        """One task: state, progress per subtask, findings."""
        from sqlalchemy import func, select

        from lidarfuzz.campaign.tasks import get_task, subtask_label
        from lidarfuzz.cli.app import console
        from lidarfuzz.store.models import Finding

        store = _store(workspace)
        row = get_task(store, task)
        age = _age(row.heartbeat_at)
        alive = f", {row.worker}, last heartbeat {age:.0f} s ago" if row.status.value == "running" and age else ""
        console.print(f"task {row.id} {escape(row.name)}: [bold]{row.status.value}[/]{alive}; "
                      f"{row.done}/{row.total} units; {escape(row.model.name)} on {escape(row.dataset.name)}; "
                      f"seed {row.seed}")
        if row.error:
            console.print(f"[red]{escape(row.error)}[/]")
        table = Table("subtask", "status", "done", "total", "failures")
        for sub in row.subtasks:
            table.add_row(subtask_label(sub.name, sub.severity), sub.status.value, str(sub.done), str(sub.total),
                          str(sub.results.get("failures", "")) if sub.results else "")
        console.print(table)
        with store.session() as s:
            kinds = dict(s.execute(select(Finding.kind, func.count()).where(Finding.task_id == task).group_by(
                Finding.kind)).all())
        console.print("findings: " + (", ".join(f"{k} {v}" for k, v in sorted(kinds.items())) or "none"))

    @app.command()
    def report(
        task: int,
        out: Annotated[Path | None, typer.Option(help="Folder for report.html, JSON, CSV and JUnit XML "
                                                      "(default: <workspace>/reports/task-ID).")] = None,
        baseline: Annotated[int | None, typer.Option(help="A task of a baseline system on the same campaign "
                                                          "(for Robo3D's corruption error, CE/mCE).")] = None,
        gate: Annotated[list[str] | None, typer.Option(help="JUnit gate, e.g. ap_drop:3d:Car:fog@3>10 or "
                                                            "violations:preservation>0 (repeatable).")] = None,
        quiet: Annotated[bool, typer.Option(help="Do not print the tables.")] = False,
        workspace: WorkspaceOption = WORKSPACE,
    ) -> None:
        """Write a task's report (self-contained HTML, JSON, CSV, JUnit XML) and print its tables."""
        store = _store(workspace)
        if not quiet:
            print_summary(store, task)
        target = out or reports_dir(workspace, task)
        raise typer.Exit(write_report(store, task, target, gate or [], baseline))

    @app.command()
    def replay(finding: int, workspace: WorkspaceOption = WORKSPACE) -> None:
        """Re-run one finding (same frame, operator params and system) and show what differs."""
        from lidarfuzz.campaign.replay import replay_finding
        from lidarfuzz.cli.app import console

        start = time.perf_counter()
        result = replay_finding(_store(workspace), finding)
        f = result.finding
        console.print(f"finding {f['id']} of task {f['task_id']}: [bold]{f['kind']}[/] {f['class']} on frame "
                      f"{f['frame_id']} under {f['subtask']}@{f['severity']}\n  recorded: {escape(f['message'])}")
        if not result.same_system:
            console.print(f"[yellow]the system changed since: fingerprint {result.fingerprint_now[:12]} "
                          f"(recorded {result.fingerprint_recorded[:12]})[/]")
        table = Table("output", "recorded", "now", "same")
        for what, recorded, now in (("source (original)", result.source_recorded, result.source_now),
                                    ("follow-up (mutant)", result.follow_recorded, result.follow_now)):
            same = now is not None and len(now) == len(recorded) and (len(now) == 0 or now.allclose(recorded, 1e-3))
            table.add_row(what, _describe(recorded), _describe(now), "yes" if same else "[yellow]no[/]")
        console.print(table)
        if result.failure_now:
            console.print(f"system failure now: {result.failure_now['kind']}: {escape(result.failure_now['message'])}")
        for outcome in result.outcomes_now:
            state = "holds" if outcome["holds"] else f"violated ({len(outcome['violations'])})"
            console.print(f"  {outcome['relation']}: {state}")
            for v in outcome["violations"][:10]:
                console.print(f"    - {escape(v['message'])}")
        verdict = "[red]reproduced[/]" if result.reproduced else "[green]not reproduced[/]"
        console.print(f"{verdict} in {time.perf_counter() - start:.1f} s")


def _describe(boxes: Any) -> str:
    if boxes is None:
        return "(failed)"
    if len(boxes) == 0:
        return "no boxes"
    labels, counts = np.unique(boxes.labels, return_counts=True)
    return ", ".join(f"{n} {label}" for label, n in zip(labels, counts, strict=True))
