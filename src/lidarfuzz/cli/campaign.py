"""Campaign task commands: ``run``, ``resume``, ``cancel``, ``delete``, ``list`` and ``status``.

They drive the engine in :mod:`lidarfuzz.campaign` (the web app drives the same one);
``report`` and the tables are in :mod:`lidarfuzz.cli.reporting`, ``replay`` in
:mod:`lidarfuzz.cli.replay`.
"""

import os
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape

from lidarfuzz.campaign.kinds import DEFAULT_KIND, TASK_KINDS, kind_of
from lidarfuzz.cli.common import (
    WORKSPACE,
    Column,
    JsonOption,
    PlainOption,
    WorkspaceOption,
    console,
    disk_failures,
    err_console,
    open_store,
    print_listing,
    print_table,
)
from lidarfuzz.cli.compare import print_comparisons
from lidarfuzz.cli.reporting import print_tables, reports_dir, write_report
from lidarfuzz.errors import LidarfuzzError

#: ``--kind``'s help, from the table of task kinds (a new row shows here without a change).
KIND_HELP = "; ".join(f"{kind.name}: {kind.help}" for kind in TASK_KINDS) + (
    ". With a search, --op names the operator pool (default pool if none).")

WorkersOption = Annotated[int | None, typer.Option(min=1, help="Worker processes, or system actors with --executor "
                                                              "ray (default: the CPU count, the cluster's CPUs).")]
InlineOption = Annotated[bool, typer.Option(help="Run every unit in this process (no pool; for debugging); the "
                                                 "same as --executor inline.")]


class ExecutorKind(StrEnum):
    """Where a campaign's units run (``--executor``)."""

    pool = "pool"
    inline = "inline"
    ray = "ray"


ExecutorOption = Annotated[ExecutorKind, typer.Option(
    "--executor", help="Where units run: pool (local worker processes), inline (this process) or ray (a Ray "
                       "cluster: the ray extra, and a PostgreSQL --workspace every node reaches).")]
ActorCpusOption = Annotated[float, typer.Option(min=0.0, help="With --executor ray: CPUs each system actor reserves.")]
ActorGpusOption = Annotated[float | None, typer.Option(
    min=0.0, help="With --executor ray: GPUs each system actor reserves, e.g. 0.25 for four per GPU (default: "
                  "the cluster's GPUs shared equally among the actors, at most 1; 0 without GPUs).")]
AddressOption = Annotated[str | None, typer.Option(
    help="With --executor ray: the cluster, auto (the one ray start runs here) or ray://HOST:PORT (default: "
         "RAY_ADDRESS, else a local Ray started for this run).")]


@dataclass(frozen=True)
class Placement:
    """Where a run's units go: ``--executor``, ``--workers``, ``--address`` (``--inline``)."""

    executor: str = "pool"
    workers: int | None = None
    address: str | None = None
    actor_cpus: float = 1.0
    actor_gpus: float | None = None

    @classmethod
    def of(cls, executor: ExecutorKind, workers: int | None, address: str | None, inline: bool,
           actor_cpus: float = 1.0, actor_gpus: float | None = None) -> "Placement":
        if inline and executor not in (ExecutorKind.pool, ExecutorKind.inline):
            raise typer.BadParameter(f"--inline and --executor {executor.value} disagree; give one",
                                     param_hint="'--inline'")
        kind = ExecutorKind.inline if inline else executor
        for given, name in ((address is not None, "--address"), (actor_cpus != 1.0, "--actor-cpus"),
                            (actor_gpus is not None, "--actor-gpus")):
            if given and kind != ExecutorKind.ray:
                what = "the address of a Ray cluster" if name == "--address" else "a system actor's share"
                raise typer.BadParameter(f"{what} goes with --executor ray", param_hint=f"'{name}'")
        return cls(kind.value, workers, address, actor_cpus, actor_gpus)

    def check(self, store: Any) -> None:
        """Refuse, before anything runs, a Ray run on a store the cluster cannot share.

        Raises:
            MissingDependencyError: ``--executor ray`` without Ray installed.
            ClusterError: An SQLite store with ``--executor ray``.
        """
        if self.executor == ExecutorKind.ray.value:
            from lidarfuzz.campaign.cluster import import_ray, require_shared_store

            import_ray()  # without the ray extra: one line naming it, before a task is created
            require_shared_store(store.url)


def _shown(text: str) -> str:
    """A user's name or note for the terminal: control characters escaped, then Rich markup."""
    from lidarfuzz.store.inventory import printable

    return escape(printable(text, newlines=True))


def parse_op(text: str) -> dict[str, Any]:
    """``fog`` or ``fog@1,3,5`` → an operator choice of a campaign."""
    name, _, severities = text.partition("@")
    choice: dict[str, Any] = {"name": name.strip()}
    if severities.strip():
        try:
            choice["severities"] = [int(v) for v in severities.split(",") if v.strip()]
        except ValueError:
            if "@" in severities:  # several operators in one --op: say how to write them
                groups: list[str] = []
                for part in (p.strip() for p in text.split(",")):
                    if "@" in part or not groups:
                        groups.append(part)
                    elif part:
                        groups[-1] += f",{part}"
                raise LidarfuzzError(f"--op {text!r}: one operator per --op, e.g. "
                                     f"{' '.join(f'--op {g}' for g in groups)}") from None
            raise LidarfuzzError(f"--op {text!r}: severities are integers, e.g. fog@1,3,5") from None
    return choice


def _age(moment: datetime | None) -> float | None:
    if moment is None:
        return None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return (datetime.now(UTC) - moment).total_seconds()


def execute(workspace: str, task_id: int, *, placement: Placement, show_progress: bool = True,
            report: bool = True, gates: list[str] | None = None, wait: bool = False, take_over: bool = False) -> int:
    """Run a task with progress bars, print its tables and write its report; returns an exit code.

    The run holds the task's claim (one runner per task): another process running it refuses
    this one with a line naming it, unless ``wait`` (wait for it to end) or ``take_over``. A
    failing disk stops it with one line; what is stored stays, and the line says how to go on.
    """
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from lidarfuzz.campaign.runner import ProgressEvent, describe_plan, make_executor, run_task
    from lidarfuzz.campaign.tasks import get_task
    from lidarfuzz.store.models import Status

    store = open_store(workspace, writes=f"running task {task_id}")
    placement.check(store)
    task = get_task(store, task_id)
    if placement.executor == "ray" and not kind_of(task).uses_executor:
        console.print(f"note: a {kind_of(task).name} task runs in this process; --executor ray runs operator campaigns "
                      "(kind mutation) on the cluster")
    elif placement.executor == "ray":
        where = placement.address or os.environ.get("RAY_ADDRESS") or "a local Ray started for this run"
        actors = f"{placement.workers} system actors" if placement.workers else "a system actor per CPU"
        console.print(f"units run on the Ray cluster at {escape(where)}: {actors}")
    plan = describe_plan(task)
    console.print(f"task [bold]{task_id}[/]: {_shown(task.model.name)} on {_shown(task.dataset.name)}, "
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

        def on_wait(claim: Any) -> None:
            console.print(f"task {task_id} is being run by process {claim.pid} on {escape(claim.host)} since "
                          f"{claim.claimed_at:%Y-%m-%d %H:%M:%S} UTC: waiting for it")

        try:
            with disk_failures(f"what is stored is kept: lidarfuzz resume {task_id} finishes the task",
                               store.file or store.where):
                executor = make_executor(placement.executor, workers=placement.workers, address=placement.address,
                                         actor_cpus=placement.actor_cpus, actor_gpus=placement.actor_gpus)
                outcome = run_task(store, task_id, executor=executor, progress=on_progress,
                                   wait=wait, take_over=take_over, on_wait=on_wait)
        except KeyboardInterrupt:
            console.print(f"\ninterrupted; what is done is stored. Finish with: lidarfuzz resume {task_id}")
            return 130
    if outcome.status == Status.CANCELLED:
        console.print(f"task {task_id} cancelled; what is done is stored (lidarfuzz resume {task_id} finishes it)")
        return 1
    print_tables(store, task_id)
    if report:
        print_comparisons(store, task_id)
    code = 0
    if report:
        with disk_failures(f"the task is done and stored: lidarfuzz report {task_id} writes its report"):
            code = write_report(store, task_id, reports_dir(workspace, task_id), gates or [])
    if outcome.status == Status.FAILED:  # e.g. data faults: what ran is shown and reported, the run did not finish
        error = get_task(store, task_id).error or "the task failed"
        err_console.print(f"[bold red]error:[/] task {task_id}: {_shown(error)}", highlight=False, soft_wrap=True)
        code = code or 1
    return code


def _pilot(store: Any, workspace: str, spec: Any, sut_options: dict[str, Any], dataset_options: Any, *,
           placement: Placement) -> tuple[Any, Any]:
    """Run ``spec``'s pilot as a task of its own; the trimmed spec and what changed."""
    from lidarfuzz.campaign.pilot import floors, pilot_campaign, trim
    from lidarfuzz.campaign.tasks import campaign_frames, create_task

    if spec.kind != DEFAULT_KIND:
        raise LidarfuzzError(f"pilot: only a {DEFAULT_KIND} campaign has operator settings to trim, not {spec.kind}")
    pilot_spec = pilot_campaign(spec)
    pilot_id = create_task(store, pilot_spec, sut_options=sut_options, dataset_options=dataset_options)
    console.print(f"pilot: task {pilot_id}, {pilot_spec.sut} on {spec.pilot} frames, every severity")
    code = execute(workspace, pilot_id, placement=placement, report=False, show_progress=False)
    if code:
        console.print(f"the pilot (task {pilot_id}) did not finish: the campaign was not created")
        raise typer.Exit(code)
    trimmed, note = trim(spec, floors(store, pilot_id), campaign_frames(store, spec, dataset_options),
                         pilot_task=pilot_id, system=pilot_spec.sut)
    for line in [*note.lowered, *note.dropped] or ["every operator setting has room"]:
        console.print(f"pilot: {line}")
    if not trimmed.operators:
        raise LidarfuzzError("pilot: no operator setting has room at this frame count; give more frames "
                             "(--frames) or other operators")
    return trimmed, note


def run(
    campaign: Annotated[Path | None, typer.Argument(help="A campaign file (YAML/JSON); or use the flags.")] = None,
    dataset: Annotated[str | None, typer.Option(help="Registered data set name, or a path.")] = None,
    sut: Annotated[str | None, typer.Option(help="Registered model name, or a SUT spec (lidarfuzz suts).")] = None,
    op: Annotated[list[str] | None, typer.Option(help="Operator, optionally with severities: fog@1,3,5 "
                                                      "(repeatable; default severities 1,3,5), or auto: the "
                                                      "default operator set.")] = None,
    relations: Annotated[str, typer.Option(help="auto, or comma-separated relation names.")] = "auto",
    seed: Annotated[int, typer.Option(help="Campaign seed (every mutant derives from it).")] = 0,
    trials: Annotated[int, typer.Option(min=1, help="Mutants per frame and severity.")] = 1,
    frames: Annotated[int | None, typer.Option(min=1, help="Only N frames: the first N, or with --random-frames "
                                                           "N drawn at random with the seed.")] = None,
    random_frames: Annotated[bool, typer.Option(help="Draw the --frames at random (seeded) instead of taking "
                                                     "the first N.")] = False,
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
    executor: ExecutorOption = ExecutorKind.pool,
    address: AddressOption = None,
    actor_cpus: ActorCpusOption = 1.0,
    actor_gpus: ActorGpusOption = None,
    detach: Annotated[bool, typer.Option(help="Only create the task; run it with lidarfuzz resume.")] = False,
    kind: Annotated[str, typer.Option(help=KIND_HELP)] = DEFAULT_KIND,
    budget: Annotated[int | None, typer.Option(min=1, help="guided/fuzz: tests to generate (default 200).")] = None,
    criteria: Annotated[str | None, typer.Option(
        help="guided/fuzz: coverage criteria, e.g. nc:0.2,kmnc:10,nbc,snac,tknc:2,tknp:2 (the default).")] = None,
    guide: Annotated[str | None, typer.Option(help="guided/fuzz: criterion whose increase accepts a test "
                                                   "(default nc; code: code_edges, with --target).")] = None,
    target: Annotated[list[str] | None, typer.Option(
        "--target", help="guided/fuzz with code criteria (code_nodes, code_edges): the code to cover, "
                         "pkg.module, pkg.module:Class or pkg.module:function (repeatable).")] = None,
    heuristic: Annotated[list[str] | None, typer.Option(
        "--heuristic", help="structural: a segment-selection heuristic (repeatable; default greedy_edges, "
                            "greedy_nodes, budget, decision_change, random).")] = None,
    strategy: Annotated[list[str] | None, typer.Option(
        "--strategy", help="structural: a log-generation strategy, HGT, AVG or an operator (repeatable; default "
                           "HGT and AVG).")] = None,
    segments: Annotated[int | None, typer.Option(min=1, help="structural: frames per segment (default 5).")] = None,
    gcov: Annotated[Path | None, typer.Option(
        help="structural: a compiled worker: program's build folder (built with --coverage, dumping its counts "
             "on a request with \"gcov_dump\": true); --target then names source files or file:function.")] = None,
    source_root: Annotated[Path | None, typer.Option(
        help="structural, with --gcov: the sources' root (default: the build folder).")] = None,
    log: Annotated[list[str] | None, typer.Option(
        "--log", help="structural: a further field-test log after --dataset (repeatable).")] = None,
    search_option: Annotated[list[str] | None, typer.Option(
        "--search", help="guided/fuzz: any search setting k=v, e.g. max_failed_tries=5, batch=4, keep_share=0.5 "
                         "(repeatable).")] = None,
    layout: Annotated[str | None, typer.Option(help="Point layout of a data set given by path: kitti, nuscenes, "
                                                    "… or columns such as x,y,z,intensity,ring:f4.")] = None,
    allow_unlabelled: Annotated[bool, typer.Option(help="Run a labelled data set whose frames are not all "
                                                         "labelled: every frame through the SUT and relations, AP "
                                                         "from the labelled ones.")] = False,
    reference: Annotated[list[str] | None, typer.Option(
        help="Differential testing: a reference system (registered model or SUT spec) run on the same mutants; "
             "the report compares the two (repeatable).")] = None,
    pilot: Annotated[int | None, typer.Option(
        min=1, help="First a pilot on N frames (on the reference, if any): operator severities whose false-alarm "
                    "floor leaves no room at the campaign's frame count are lowered or dropped.")] = None,
    workspace: WorkspaceOption = WORKSPACE,
) -> None:
    """Create a campaign task and run it: originals and mutants through the SUT, AP, relations, report.

    With a reference system (--reference, or reference: in the campaign file) each reference runs
    as a task of its own on the same mutants first; the report then sets the system's violation
    rates beside the reference's and flags those significantly above (lidarfuzz compare A B).

    With --kind guided or fuzz the task is a coverage-guided search on a learned SUT (e.g. pillars):
    generated tests, neuron coverage and deduplicated, minimised findings; with --guide code and
    --target CODE, guided by the code coverage of any Python system (e.g. classic).

    With --kind structural the dataset is a field-test log (more with --log) replayed in order through a
    sequence system (--sut controller) under code coverage of --target: segments, heuristics' base logs,
    generated logs (--strategy), coverage tables and decision-relation findings.
    """
    from lidarfuzz.campaign.kinds import find_kind
    from lidarfuzz.campaign.spec import load_campaign, parse_campaign
    from lidarfuzz.campaign.tasks import create_task, get_task
    from lidarfuzz.io.options import options_from_flags
    from lidarfuzz.operators.mutate import parse_assignments

    if campaign is not None:
        if dataset or sut or op:
            raise LidarfuzzError("give a campaign file or --dataset/--sut/--op, not both")
        spec = load_campaign(campaign)
        if reference:
            spec = spec.model_copy(update={"reference": [*spec.reference, *reference]})
    else:
        takes_ops = (row := find_kind(kind)) is not None and row.requires_operators
        needed = (("--dataset", dataset), ("--sut", sut)) + ((("--op", op),) if takes_ops else ())
        missing = [flag for flag, value in needed if not value]
        if missing:
            raise LidarfuzzError(f"missing {', '.join(missing)} (or give a campaign file); see lidarfuzz run -h")
        if random_frames and frames is None:
            raise LidarfuzzError("--random-frames draws --frames N of the data set's frames: give --frames too")
        chosen: Any = "auto" if relations == "auto" else [r.strip() for r in relations.split(",") if r.strip()]
        search: dict[str, Any] = dict(parse_assignments(search_option or []))
        if budget is not None:
            search["budget"] = budget
        if criteria is not None:
            search["criteria"] = [c.strip() for c in criteria.split(",") if c.strip()]
        if guide is not None:
            search["guide"] = guide
        if target and kind != "structural":
            search["targets"] = target
        structural: dict[str, Any] = {}
        if kind == "structural":
            coverage: dict[str, Any] = {"targets": target or []}
            if gcov is not None:
                coverage.update(gcov=str(gcov), source_root=str(source_root) if source_root else None)
            structural = {"coverage": coverage, "heuristics": heuristic or [],
                          "strategies": strategy or [], "segments": segments, "logs": log or []}
            if not target:
                raise LidarfuzzError("--target: a structural campaign needs the code to cover, e.g. --target "
                                     "lidarfuzz.suts.controller.avoidance:ObstacleAvoidance.process")
        elif heuristic or strategy or segments or log or gcov:
            raise LidarfuzzError("--heuristic, --strategy, --segments, --log and --gcov are for --kind structural")
        spec = parse_campaign({"name": name, "dataset": dataset, "sut": sut, "kind": kind, **structural,
                               "operators": "auto" if op == ["auto"] else [parse_op(o) for o in op or []],
                               "search": search,
                               "relations": chosen, "seed": seed, "trials": trials, "frames": frames,
                               "frame_order": "random" if random_frames else "first",
                               "reference": reference or []},
                              "command line")
    if pilot is not None:
        spec = spec.model_copy(update={"pilot": pilot})
    store = open_store(workspace, writes="lidarfuzz run")
    placement = Placement.of(executor, workers, address, inline, actor_cpus, actor_gpus)
    placement.check(store)  # before a task is created
    sut_options = parse_assignments(option or [])
    dataset_options = options_from_flags(layout, allow_unlabelled)
    note = None
    if spec.pilot is not None:
        spec, note = _pilot(store, workspace, spec, sut_options if not spec.reference else {}, dataset_options,
                            placement=placement)
    task_id = create_task(store, spec, sut_options=sut_options, isolate=isolate,
                          timeout=timeout, save_mutants=str(save_mutants.resolve()) if save_mutants else None,
                          dataset_options=dataset_options, pilot=note)
    references = get_task(store, task_id).options.references
    if detach:
        console.print(f"created task {task_id}; run it with: lidarfuzz resume {task_id}"
                      + "".join(f"; its reference: lidarfuzz resume {ref}" for ref in references))
        return
    for ref in references:  # first, so that the task's report compares with them
        code = execute(workspace, ref, placement=placement, report=False)
        if code:
            console.print(f"the reference task {ref} did not finish: task {task_id} was not run "
                          f"(lidarfuzz resume {ref}, then lidarfuzz resume {task_id})")
            raise typer.Exit(code)
    raise typer.Exit(execute(workspace, task_id, placement=placement, gates=gate))

def resume(
    task: Annotated[int, typer.Argument(help="Task id (lidarfuzz list).")],
    workers: WorkersOption = None,
    inline: InlineOption = False,
    executor: ExecutorOption = ExecutorKind.pool,
    address: AddressOption = None,
    actor_cpus: ActorCpusOption = 1.0,
    actor_gpus: ActorGpusOption = None,
    force: Annotated[bool, typer.Option(help="Resume even if another process seems to be running it (its "
                                             "claim on the task is taken over).")] = False,
    wait: Annotated[bool, typer.Option(help="When another process runs the task, wait for it to end (or die), "
                                            "then finish what is left, instead of refusing.")] = False,
    workspace: WorkspaceOption = WORKSPACE,
) -> None:
    """Finish an interrupted, cancelled or failed task: only units without a result run.

    One process runs a task at a time: while another runs it (``lidarfuzz status`` names it),
    resume refuses with a line naming that process, or with --wait waits for it. A process that
    died leaves a claim that is taken over (at once on the same host, else 30 s after its last
    heartbeat).
    """
    from lidarfuzz.campaign.tasks import get_task
    from lidarfuzz.store.models import Status

    placement = Placement.of(executor, workers, address, inline, actor_cpus, actor_gpus)
    row = get_task(open_store(workspace, writes=f"lidarfuzz resume {task}"), task)
    if row.status == Status.DONE:
        console.print(f"task {task} is done already (lidarfuzz report {task})")
        return
    raise typer.Exit(execute(workspace, task, placement=placement, wait=wait, take_over=force))

def cancel(task: int, workspace: WorkspaceOption = WORKSPACE) -> None:
    """Stop a task cleanly (a running one stops within a second; what is done stays)."""
    from lidarfuzz.campaign.tasks import cancel_task

    status = cancel_task(open_store(workspace, writes="lidarfuzz cancel"), task)
    console.print(f"task {task}: {status.value}")

def delete(task: int, workspace: WorkspaceOption = WORKSPACE) -> None:
    """Delete a task and its results (the data set and model stay)."""
    from lidarfuzz.campaign.tasks import delete_task

    delete_task(open_store(workspace, writes="lidarfuzz delete"), task)
    console.print(f"deleted task {task}")

def list_tasks_command(limit: Annotated[int, typer.Option(help="Newest N tasks.")] = 50,
                       workspace: WorkspaceOption = WORKSPACE, as_json: JsonOption = False,
                       plain: PlainOption = False) -> None:
    """The tasks in the store, newest first."""
    from lidarfuzz.campaign.tasks import list_tasks

    rows: list[list[str]] = []
    records: list[dict[str, Any]] = []
    for t in list_tasks(open_store(workspace), limit):
        share = f"{t.done}/{t.total} ({100 * t.done / t.total:.0f}%)" if t.total else "0/0"
        rows.append([str(t.id), t.name, t.status.value, t.dataset.name, t.model.name, str(len(t.operators)), share,
                     f"{t.started_at:%Y-%m-%d %H:%M}" if t.started_at else "",
                     f"{t.finished_at:%Y-%m-%d %H:%M}" if t.finished_at else "", ", ".join(t.tags or [])])
        records.append({"id": t.id, "name": t.name, "status": t.status.value, "dataset": t.dataset.name,
                        "model": t.model.name, "subtasks": len(t.operators), "done": t.done, "total": t.total,
                        "started": t.started_at.isoformat() if t.started_at else None,
                        "finished": t.finished_at.isoformat() if t.finished_at else None,
                        "tags": list(t.tags or [])})
    columns = [Column("id", justify="right"), Column("name", name=True), Column("status"),
               Column("data set", name=True), Column("SUT", name=True), Column("subtasks"), Column("progress"),
               Column("started"), Column("finished"), Column("tags")]
    print_listing(columns, rows, records, as_json=as_json, plain=plain)


def status(task: int, workspace: WorkspaceOption = WORKSPACE) -> None:
    """One task: state, progress per subtask, findings."""
    from rich.table import Table
    from sqlalchemy import func, select

    from lidarfuzz.campaign.tasks import get_task, subtask_label
    from lidarfuzz.store.claims import holder, is_dead
    from lidarfuzz.store.models import Finding, Status

    store = open_store(workspace)
    row = get_task(store, task)
    age = _age(row.heartbeat_at)
    alive = f", {row.worker}, last heartbeat {age:.0f} s ago" if row.status.value == "running" and age else ""
    claim = holder(store, task)
    if claim is not None:  # who runs it now (a dead claim is taken over by the next resume)
        gone = " (gone: the next resume takes it over)" if is_dead(claim) else ""
        alive += (f"; claimed by process {claim.pid} on {escape(claim.host)} since "
                  f"{claim.claimed_at:%Y-%m-%d %H:%M:%S} UTC{gone}")
    console.print(f"task {row.id} {_shown(row.name)}: [bold]{row.status.value}[/]{alive}; "
                  f"{row.done}/{row.total} units; {_shown(row.model.name)} on {_shown(row.dataset.name)}; "
                  f"seed {row.seed}")
    if row.error:
        console.print(f"[red]{_shown(row.error)}[/]")
    table = Table("subtask", "status", "done", "total", "failures")
    table.columns[0].no_wrap, table.columns[0].overflow = True, "fold"
    for sub in row.subtasks:  # a subtask's figures exist once it is done
        table.add_row(subtask_label(sub.name, sub.severity), sub.status.value, str(sub.done), str(sub.total),
                      str(sub.results.failures) if sub.status == Status.DONE else "")
    print_table(table)
    with store.session() as s:
        kinds = dict(s.execute(select(Finding.kind, func.count()).where(Finding.task_id == task).group_by(
            Finding.kind)).all())
    console.print("findings: " + (", ".join(f"{k} {v}" for k, v in sorted(kinds.items())) or "none"))
