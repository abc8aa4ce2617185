"""kill -9 at random moments of ``lidarfuzz run``, then ``lidarfuzz resume``; and a data set file
deleted mid-run, restored, then ``resume``: the results must be those of an undisturbed run.

For each backend (SQLite; PostgreSQL when ``initdb``/``pg_ctl`` can start a throwaway server here):

1. an undisturbed ``lidarfuzz run`` of a small campaign (the reference, and how long a run takes);
2. ``--kills`` times: a fresh workspace, ``lidarfuzz run`` started, and once its task exists the
   whole process group (the CLI and its worker pool) killed with SIGKILL after a random delay
   drawn uniformly over the reference run's length; right after the kill the store must hold whole
   results only (rows = the task's counter = the sum of its subtasks' counters); then
   ``lidarfuzz resume`` to the end, and the task must have every unit exactly once (0 lost, 0
   duplicated) and the reference's results, findings and exports (:func:`snapshot`) bit for bit.
   On PostgreSQL a transaction killed mid-way may have drawn ids from a sequence (sequences are not
   transactional): the ids then skip numbers, so findings.csv is also compared with ids renumbered
   in order, and the kills where only the ids differ are counted apart.

The data-fault scenario (SQLite): ``--faults`` times, a frame file of the campaign's data set is
moved away at a random moment of ``lidarfuzz run``, then moved back, then ``lidarfuzz resume``: no
system failure may be recorded for it, and the resumed task must match the reference.

The harness runs on a copy of the code made when it starts (``src/``, the test systems, this
folder), so that edits to the working tree while it runs (another change being made) cannot change the
system's fingerprint or behaviour between the reference and the kills.

The system under test is :class:`tests.campaign.kill_systems.SlowRaises` (the classic pipeline slowed
down, raising on frame 000001: crash findings to number). ``--write-doc`` rewrites the ``kills``
section of docs/reliability.md.

Usage: python benchmarks/kills.py [--kills 20] [--faults 5] [--backends sqlite,postgresql] [--write-doc]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import random
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script: the test systems and this package importable
    sys.path.insert(0, str(ROOT))

CLI = "from lidarfuzz.cli.app import main; main()"
SYSTEM = "tests.campaign.kill_systems:SlowRaises"
DELAY = 0.1  # seconds per detection on top of the classic pipeline's own
OPERATORS = ("gaussian_noise_addition@2,5", "rotate_z@3")
FRAMES = 3
#: The data-fault runs: more frames than a block (16, which workers keep loaded), so that a frame of the
#: second block is still unread during the run's first half; only rotate_z, to keep them short.
FAULT_FRAMES = 20
FAULT_OPERATORS = ("rotate_z@3",)
BLOCK = 16
WORKERS = 2
SYSTEM_FAILURES = ("crash", "timeout", "invalid_output")


# -- running the CLI ---------------------------------------------------------------------------
def cli(cwd: Path, *args: str) -> subprocess.Popen[str]:
    """``lidarfuzz ARGS`` in ``cwd``, in its own process group (so SIGKILL reaches its worker pool)."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return subprocess.Popen([sys.executable, "-c", CLI, *args], cwd=cwd, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, start_new_session=True,
                            env={**os.environ, "COLUMNS": "120", "PYTHONPATH": path})


def run_args(dataset: Path, workspace: str, operators: tuple[str, ...] = OPERATORS) -> list[str]:
    ops = [arg for op in operators for arg in ("--op", op)]
    return ["run", "--dataset", str(dataset), "--sut", SYSTEM, "--option", f"delay={DELAY}", *ops,
            "--workers", str(WORKERS), "--workspace", workspace]


def finish(process: subprocess.Popen[str], timeout: float = 600) -> str:
    out = process.communicate(timeout=timeout)[0]
    return out


def task_exists(workspace: str) -> bool:
    from sqlalchemy import func, select

    from lidarfuzz.store import Store, Task

    try:
        store = Store(workspace, migrate=False)
        try:
            with store.session() as s:
                return bool(s.scalar(select(func.count()).select_from(Task)))
        finally:
            store.close()
    except Exception:  # no schema yet
        return False


def wait_for_task(process: subprocess.Popen[str], workspace: str, limit: float = 120) -> float:
    """Seconds until the run's task exists in the store (polled every 20 ms)."""
    start = time.monotonic()
    while time.monotonic() - start < limit and process.poll() is None:
        if task_exists(workspace):
            return time.monotonic() - start
        time.sleep(0.02)
    return time.monotonic() - start


# -- what a finished task holds ------------------------------------------------------------------
@dataclass
class Snapshot:
    """A task's results (per unit: boxes, ground truth, failure, params, relations), findings (in
    unit order, ids apart) and exports (CSV files byte for byte, the JSON summary less the run's
    record)."""

    results: dict[tuple[str, int, str, int], tuple[Any, ...]]
    findings: list[tuple[Any, ...]]
    exports: dict[str, bytes]
    finding_ids: list[int] = field(default_factory=list)

    def renumbered(self) -> dict[str, bytes]:
        """The exports with findings.csv's ids (and replay commands) numbered 1, 2, … in order."""
        out = dict(self.exports)
        rows = list(csv.reader(out["findings.csv"].decode().splitlines()))
        number = {row[0]: str(i) for i, row in enumerate(rows[1:], start=1)}
        buffer = _Text()  # (benchmarks/io.py shadows the standard io module for mypy)
        writer = csv.writer(buffer)
        writer.writerow(rows[0])
        for row in rows[1:]:
            writer.writerow([number[row[0]], *row[1:-1], row[-1].replace(row[0], number[row[0]])])
        out["findings.csv"] = "".join(buffer).encode()
        return out


class _Text(list[str]):
    """A file-like list of the text written to it."""

    def write(self, text: str) -> int:
        self.append(text)
        return len(text)


def snapshot(store: Any, task_id: int) -> Snapshot:
    from sqlalchemy import select

    from lidarfuzz.campaign.results import summarise
    from lidarfuzz.report.exports import finding_rows, without_run_record, write_csvs, write_json
    from lidarfuzz.store import Finding, FrameResult, Subtask

    with store.session() as s:
        rows = s.execute(select(Subtask.name, Subtask.severity, FrameResult.frame_id, FrameResult.trial,
                                FrameResult.boxes, FrameResult.labels, FrameResult.gt_boxes, FrameResult.gt_labels,
                                FrameResult.failure, FrameResult.params, FrameResult.relations)
                         .join(Subtask).where(Subtask.task_id == task_id)).all()
        results = {(r[0], r[1], r[2], r[3]): (r[4], r[5], r[6], r[7], r[8] and r[8].dump(), r[9],
                                              [o.dump() for o in r[10] or []]) for r in rows}
        found = s.execute(select(Finding.id, Subtask.name, Subtask.severity, FrameResult.frame_id, FrameResult.trial,
                                 Finding.kind, Finding.cls, Finding.magnitude, Finding.message, Finding.detail)
                          .join(FrameResult, Finding.frame_result_id == FrameResult.id).join(Subtask)
                          .where(Finding.task_id == task_id)
                          .order_by(Subtask.id, FrameResult.frame_id, FrameResult.trial, Finding.id)).all()
    with tempfile.TemporaryDirectory() as folder:
        summary = summarise(store, task_id)
        write_csvs(summary, folder, finding_rows(store, task_id))
        write_json(summary, Path(folder) / "report.json")
        exports = {p.name: p.read_bytes() for p in sorted(Path(folder).iterdir())}
    exports["report.json"] = json.dumps(without_run_record(json.loads(exports["report.json"])),
                                        sort_keys=True).encode()
    return Snapshot(results, [tuple(f[1:]) for f in found], exports, [f[0] for f in found])


@dataclass(frozen=True)
class Whole:
    """What the store holds of a task: rows, the task's counter, the sum of its subtasks' counters,
    the units of its plan, distinct unit keys, and its status."""

    rows: int
    task_done: int
    subtasks_done: int
    total: int
    keys: int
    status: str

    @property
    def consistent(self) -> bool:
        return self.rows == self.task_done == self.subtasks_done == self.keys

    @property
    def complete(self) -> bool:
        return self.consistent and self.rows == self.total


def whole(store: Any, task_id: int) -> Whole:
    from sqlalchemy import select

    from lidarfuzz.campaign.tasks import get_task
    from lidarfuzz.store import FrameResult, Subtask

    task = get_task(store, task_id)
    with store.session() as s:
        units = s.execute(select(FrameResult.subtask_id, FrameResult.frame_id, FrameResult.trial).join(Subtask)
                          .where(Subtask.task_id == task_id)).all()
    rows, keys = len(units), len({tuple(unit) for unit in units})
    return Whole(rows, task.done, sum(sub.done for sub in task.subtasks), task.total, keys, task.status.value)


# -- backends --------------------------------------------------------------------------------------
@contextlib.contextmanager
def postgres_server() -> Iterator[str | None]:
    """A throwaway PostgreSQL server's URL (None when it cannot be started here)."""
    initdb, pg_ctl = shutil.which("initdb"), shutil.which("pg_ctl")
    if initdb is None or pg_ctl is None:
        yield None
        return
    root = Path(tempfile.mkdtemp(prefix="lfpg-kills-"))
    data, sockets = root / "data", root / "s"
    sockets.mkdir()
    prefix: list[str] = []
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        runuser = shutil.which("runuser")
        if runuser is None:
            yield None
            return
        prefix = [runuser, "-u", "postgres", "--"]
        shutil.chown(root, "postgres")
        shutil.chown(sockets, "postgres")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    try:
        subprocess.run([*prefix, initdb, "-D", str(data), "-A", "trust", "-U", "postgres", "--no-sync"],
                       check=True, capture_output=True)
        options = f"-p {port} -k {sockets} -c listen_addresses=''"
        subprocess.run([*prefix, pg_ctl, "-D", str(data), "-o", options, "-w", "start", "-l", str(root / "log")],
                       check=True, capture_output=True)
    except (OSError, subprocess.CalledProcessError):
        shutil.rmtree(root, ignore_errors=True)
        yield None
        return
    try:
        yield f"postgresql+psycopg://postgres@/postgres?host={sockets}&port={port}"
    finally:
        subprocess.run([*prefix, pg_ctl, "-D", str(data), "-m", "immediate", "stop"], capture_output=True)
        shutil.rmtree(root, ignore_errors=True)


class Workspaces:
    """Fresh workspaces of one backend: SQLite folders, or new databases on a PostgreSQL server."""

    def __init__(self, backend: str, root: Path, server: str | None = None) -> None:
        self.backend, self.root, self.server = backend, root, server
        self.made: list[str] = []

    def new(self, name: str) -> str:
        if self.backend == "sqlite":
            return str(self.root / name)
        from sqlalchemy import create_engine, make_url, text

        assert self.server is not None
        database = f"k_{uuid.uuid4().hex[:12]}"
        admin = create_engine(self.server, isolation_level="AUTOCOMMIT")
        with admin.connect() as connection:
            connection.execute(text(f"CREATE DATABASE {database}"))
        admin.dispose()
        self.made.append(database)
        return make_url(self.server).set(database=database).render_as_string(hide_password=False)


def open_store(workspace: str) -> Any:
    from lidarfuzz.store import Store

    return Store(workspace, migrate=False)


# -- the trials --------------------------------------------------------------------------------------
@dataclass
class KillTrial:
    delay: float  # seconds after the task existed
    at_kill: Whole
    after: Whole
    results_same: bool
    findings_same: bool
    exports_same: bool
    same_but_ids: bool  # exports equal once findings are renumbered in order
    resume_seconds: float
    note: str = ""

    @property
    def identical(self) -> bool:
        return self.results_same and self.findings_same and self.exports_same

    @property
    def lost(self) -> int:
        return max(0, self.after.total - self.after.keys)

    @property
    def duplicated(self) -> int:
        return self.after.rows - self.after.keys


@dataclass
class Reference:
    snapshot: Snapshot
    run_seconds: float  # from the task existing to the run's end
    total: int


def reference_run(dataset: Path, workspaces: Workspaces, cwd: Path,
                  operators: tuple[str, ...] = OPERATORS) -> Reference:
    workspace = workspaces.new(f"reference-{uuid.uuid4().hex[:8]}")
    process = cli(cwd, *run_args(dataset, workspace, operators))
    wait_for_task(process, workspace)
    start = time.monotonic()
    out = finish(process)
    run_seconds = time.monotonic() - start
    store = open_store(workspace)
    try:
        state = whole(store, 1)  # the exit status says the gates failed: the system's crashes, on purpose
        if not state.complete or state.status != "done":
            raise RuntimeError(f"the reference run did not finish ({state}):\n{out}")
        return Reference(snapshot(store, 1), run_seconds, state.total)
    finally:
        store.close()


def differences(mine: Snapshot, reference: Snapshot) -> str:
    """What differs, in a few words (for the departures' notes)."""
    parts = []
    if mine.results != reference.results:
        keys = sorted(k for k in mine.results.keys() | reference.results.keys()
                      if mine.results.get(k) != reference.results.get(k))
        parts.append(f"results of {len(keys)} units (first {keys[0]})")
    if mine.findings != reference.findings:
        parts.append(f"findings ({len(mine.findings)} vs {len(reference.findings)})")
    parts += [f"{name}" for name in sorted(reference.exports) if mine.exports.get(name) != reference.exports[name]]
    return ", ".join(parts)


def compare(mine: Snapshot, reference: Snapshot) -> tuple[bool, bool, bool, bool]:
    exports_same = mine.exports == reference.exports
    return (mine.results == reference.results, mine.findings == reference.findings, exports_same,
            exports_same or mine.renumbered() == reference.renumbered())


def kill_trial(dataset: Path, workspaces: Workspaces, cwd: Path, reference: Reference, rng: random.Random,
               attempts: int = 5) -> KillTrial:
    """One kill at a random moment of a run, then resume (see the module docstring)."""
    for _ in range(attempts):
        workspace = workspaces.new(f"kill-{uuid.uuid4().hex[:8]}")
        process = cli(cwd, *run_args(dataset, workspace))
        wait_for_task(process, workspace)
        delay = rng.uniform(0.0, reference.run_seconds)
        deadline = time.monotonic() + delay
        while time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.005)
        if process.poll() is not None:  # it finished before the kill: draw again
            finish(process)
            continue
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
        store = open_store(workspace)
        try:
            at_kill = whole(store, 1)
            start = time.monotonic()
            resumed = cli(cwd, "resume", "1", "--workers", str(WORKERS), "--workspace", workspace)
            out = finish(resumed)
            seconds = time.monotonic() - start
            after = whole(store, 1)
            mine = snapshot(store, 1)
        finally:
            store.close()
        same = compare(mine, reference.snapshot)
        note = "" if after.status == "done" else f"resume ended {after.status}: {out.strip()[-300:]}"
        if not all(same[:2]) or not same[3]:
            note = (note + "; " if note else "") + "differs: " + differences(mine, reference.snapshot)
        return KillTrial(delay, at_kill, after, *same, seconds, note)
    raise RuntimeError(f"the run finished before every one of {attempts} random kills")


@dataclass
class FaultTrial:
    victim: str
    delay: float
    status: str  # the run's task after the file went
    faults: int  # units recorded with a data fault
    blamed: int  # system failures recorded that the reference does not have
    identical: bool  # after restoring and resuming: results, findings, exports (findings renumbered)
    ids_same: bool  # findings.csv's ids too (a unit run again numbers its findings anew)
    error: str = ""


def system_failures(store: Any, task_id: int) -> set[tuple[Any, ...]]:
    from sqlalchemy import select

    from lidarfuzz.store import Finding, FrameResult, Subtask

    with store.session() as s:
        rows = s.execute(select(Subtask.name, Subtask.severity, FrameResult.frame_id, FrameResult.trial, Finding.kind)
                         .join(FrameResult, Finding.frame_result_id == FrameResult.id).join(Subtask)
                         .where(Finding.task_id == task_id, Finding.kind.in_(SYSTEM_FAILURES))).all()
    return {tuple(r) for r in rows}


def data_faults(store: Any, task_id: int) -> int:
    from lidarfuzz.campaign.lifecycle import data_faults as messages

    return len(messages(store, task_id))


def fault_trial(dataset: Path, workspaces: Workspaces, cwd: Path, reference: Reference, expected: set[Any],
                rng: random.Random) -> FaultTrial:
    """A frame file moved away at a random moment of a run, then back, then resume."""
    frames = sorted((dataset / "velodyne").glob("*.bin"))
    victim = rng.choice(frames[BLOCK:])  # the second block: unread during the run's first half
    away = victim.with_name(victim.name + ".away")
    workspace = workspaces.new(f"fault-{uuid.uuid4().hex[:8]}")
    process = cli(cwd, *run_args(dataset, workspace, FAULT_OPERATORS))
    wait_for_task(process, workspace)
    delay = rng.uniform(0.0, reference.run_seconds / 2)  # the first half: frames still to be read
    time.sleep(delay)
    victim.rename(away)
    try:
        finish(process)
    finally:
        away.rename(victim)
    store = open_store(workspace)
    try:
        from lidarfuzz.campaign.tasks import get_task

        task = get_task(store, 1)
        status, error = task.status.value, task.error
        faults = data_faults(store, 1)
        blamed = len(system_failures(store, 1) - expected)
        resumed = cli(cwd, "resume", "1", "--workers", str(WORKERS), "--workspace", workspace)
        finish(resumed)
        results_same, findings_same, exports_same, same_but_ids = compare(snapshot(store, 1), reference.snapshot)
        identical = whole(store, 1).complete and results_same and findings_same and same_but_ids
    finally:
        store.close()
    return FaultTrial(victim.name, delay, status, faults, blamed, identical, exports_same, error[:160])


# -- the report ---------------------------------------------------------------------------------------
def kills_table(backend: str, reference: Reference, trials: list[KillTrial]) -> list[str]:
    done = [t.at_kill.rows for t in trials]
    consistent = sum(t.at_kill.consistent for t in trials)
    identical = sum(t.identical for t in trials)
    ids_only = sum((not t.exports_same) and t.same_but_ids and t.results_same and t.findings_same for t in trials)
    lines = [
        f"| {backend} | {len(trials)} | {min(done)}–{max(done)} of {reference.total} (median "
        f"{statistics.median(done):g}) | {consistent}/{len(trials)} | {sum(t.lost for t in trials)} | "
        f"{sum(t.duplicated for t in trials)} | {identical}/{len(trials)} | {ids_only} | "
        f"{statistics.median(t.resume_seconds for t in trials):.1f} s |"]
    return lines


def markdown(command: str, kill_results: dict[str, tuple[Reference, list[KillTrial]]],
             fault_results: list[FaultTrial], skipped: dict[str, str], kept: str = "") -> str:
    """The section: the kills' part (or ``kept``, the current section's, when this run made no kill) and
    the data faults' part."""
    from benchmarks.reliability_doc import provenance

    out = [kept.strip()] if kept.strip() and not kill_results and not skipped else kills_markdown(
        command, kill_results, skipped)
    if fault_results:
        faults = sum(t.faults for t in fault_results)
        blamed = sum(t.blamed for t in fault_results)
        identical = sum(t.identical for t in fault_results)
        touched = sum(t.faults > 0 or t.status == "failed" for t in fault_results)
        out += ["", "### Data faults", "", provenance(command), "",
                f"{len(fault_results)} runs on SQLite of {FAULT_FRAMES} simulated frames × (original + "
                f"{', '.join(FAULT_OPERATORS)}), the same system, with one frame file of the second block of "
                f"{BLOCK} frames (`velodyne/*.bin`, drawn at random) moved away at a random moment of the run's "
                "first half, moved back after the run ended, then `lidarfuzz resume`:", "",
                "| runs | runs the missing file reached | units with a data fault | system failures blamed on it | "
                "identical to the undisturbed run after resume | findings' ids too |",
                "|---:|---:|---:|---:|---:|---:|",
                f"| {len(fault_results)} | {touched} | {faults} | {blamed} | {identical}/{len(fault_results)} | "
                f"{sum(t.ids_same for t in fault_results)}/{len(fault_results)} |", "",
                "*Identical*: results, findings and exports, findings.csv compared with ids renumbered in order: a "
                "unit run again after a data fault numbers its findings after the others'."]
    return "\n".join(out)


def kills_markdown(command: str, kill_results: dict[str, tuple[Reference, list[KillTrial]]],
                   skipped: dict[str, str]) -> list[str]:
    from benchmarks.reliability_doc import provenance

    ops = ", ".join(OPERATORS)
    out = [provenance(command), "",
           f"Campaign: {FRAMES} simulated frames × (original + {ops}) = the units below, system "
           f"`{SYSTEM}` (the classic pipeline + {DELAY} s per frame, raising on frame 000001: crash findings), "
           f"`lidarfuzz run --workers {WORKERS}`. Each kill: a fresh workspace, the whole process group killed "
           "with SIGKILL at a random moment (uniform over an undisturbed run's length, once the task exists), "
           "then `lidarfuzz resume`, compared with an undisturbed run: results per unit (boxes, ground truth, "
           "failure, params, relations), findings, and exports (ap.csv, delta_ap.csv, violations.csv and "
           "findings.csv byte for byte; the JSON summary less the run's own record).", "",
           "| backend | kills | units stored at the kill | store whole at the kill | lost | duplicated | "
           "identical after resume | ids skipped only | resume (median) |",
           "|---|---:|---|---:|---:|---:|---:|---:|---:|"]
    for backend, (reference, trials) in kill_results.items():
        out += kills_table(backend, reference, trials)
    for backend, why in skipped.items():
        out.append(f"| {backend} | not run: {why} | | | | | | | |")
    notes = [f"- {backend}, kill at +{t.delay:.2f} s: {t.note or 'differs'}"
             for backend, (_, trials) in kill_results.items() for t in trials if not t.identical or t.note]
    if notes:
        out += ["", "Departures:", *notes]
    out += ["", "*Store whole at the kill*: stored rows = the task's counter = the sum of its subtasks' counters "
            "= distinct units. *Ids skipped only*: on PostgreSQL a transaction killed mid-way has drawn ids from "
            "a sequence (not transactional), so later findings' ids skip numbers; everything else is identical."]
    return out


def current_kills_part(doc: Path) -> str:
    """The kills part of the page's current section (what a run with ``--kills 0`` keeps)."""
    text = doc.read_text(encoding="utf-8") if doc.exists() else ""
    begin, end = "<!-- BEGIN kills -->", "<!-- END kills -->"
    if begin not in text or end not in text:
        return ""
    section = text.split(begin, 1)[1].split(end, 1)[0]
    return section.split("### Data faults", 1)[0] if "Measured" in section else ""


def freeze(argv: list[str]) -> None:
    """Run this harness again on a copy of the code (see the module docstring); returns only in that copy."""
    if os.environ.get("LIDARFUZZ_KILLS_REPO"):
        return
    code = Path(tempfile.mkdtemp(prefix="lidarfuzz-kills-code-"))
    skip = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(ROOT / "src", code / "src", ignore=skip)
    shutil.copytree(ROOT / "benchmarks", code / "benchmarks", ignore=skip)
    (code / "tests" / "campaign").mkdir(parents=True)
    for name in ("tests/__init__.py", "tests/campaign/__init__.py", "tests/campaign/systems.py",
                 "tests/campaign/kill_systems.py"):
        shutil.copy2(ROOT / name, code / name)
    path = os.pathsep.join(p for p in (str(code / "src"), str(code), os.environ.get("PYTHONPATH", "")) if p)
    env = {**os.environ, "PYTHONPATH": path, "LIDARFUZZ_KILLS_REPO": str(ROOT)}
    os.execve(sys.executable, [sys.executable, str(code / "benchmarks" / "kills.py"), *argv], env)


def main(argv: list[str] | None = None) -> int:
    freeze(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=20, help="kills per backend")
    parser.add_argument("--faults", type=int, default=5, help="data-fault runs (SQLite)")
    parser.add_argument("--backends", default="sqlite,postgresql")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--write-doc", action="store_true", help="rewrite the kills section of docs/reliability.md")
    parser.add_argument("--keep", action="store_true", help="keep the workspaces (their folder is printed)")
    args = parser.parse_args(argv)
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset

    rng = random.Random(args.seed)
    root = Path(tempfile.mkdtemp(prefix="lidarfuzz-kills-"))
    try:
        dataset = root / "sim"
        generate_dataset(dataset, GenerationConfig(frames=FRAMES, seed=0), workers=1, overwrite=True)
        kill_results: dict[str, tuple[Reference, list[KillTrial]]] = {}
        skipped: dict[str, str] = {}
        fault_results: list[FaultTrial] = []
        command = "python benchmarks/kills.py " + " ".join(argv if argv is not None else sys.argv[1:])

        doc = Path(os.environ["LIDARFUZZ_KILLS_REPO"]) / "docs" / "reliability.md"
        kept = current_kills_part(doc) if args.kills == 0 else ""

        def publish() -> str:
            """The section as measured so far (written after each phase, so a long run's figures are kept)."""
            text = markdown(command.strip(), kill_results, fault_results, skipped, kept)
            if args.write_doc:
                from benchmarks.reliability_doc import write_section

                write_section("kills", text, doc)
            return text

        for backend in [b.strip() for b in args.backends.split(",") if b.strip()] if args.kills else []:
            with contextlib.ExitStack() as stack:
                server = stack.enter_context(postgres_server()) if backend == "postgresql" else None
                if backend == "postgresql" and server is None:
                    skipped[backend] = "no PostgreSQL server could be started here (initdb, pg_ctl)"
                    continue
                workspaces = Workspaces(backend, root / backend, server)
                reference = reference_run(dataset, workspaces, root)
                print(f"{backend}: reference run {reference.run_seconds:.1f} s, {reference.total} units, "
                      f"{len(reference.snapshot.findings)} findings", flush=True)
                trials = []
                for number in range(1, args.kills + 1):
                    trial = kill_trial(dataset, workspaces, root, reference, rng)
                    trials.append(trial)
                    print(f"  kill {number}: +{trial.delay:.2f} s, {trial.at_kill.rows}/{trial.at_kill.total} stored, "
                          f"whole {trial.at_kill.consistent}, lost {trial.lost}, duplicated {trial.duplicated}, "
                          f"identical {trial.identical} (ids only {trial.same_but_ids}) {trial.note}", flush=True)
                kill_results[backend] = (reference, trials)
                publish()
        if args.faults:
            faulty = root / "faults"
            generate_dataset(faulty, GenerationConfig(frames=FAULT_FRAMES, seed=0), workers=1, overwrite=True)
            workspaces = Workspaces("sqlite", root / "faults-ws")
            reference = reference_run(faulty, workspaces, root, FAULT_OPERATORS)
            print(f"data faults: reference run {reference.run_seconds:.1f} s, {reference.total} units", flush=True)
            expected = {tuple(f[:5]) for f in reference.snapshot.findings if f[4] in SYSTEM_FAILURES}
            for number in range(1, args.faults + 1):
                fault = fault_trial(faulty, workspaces, root, reference, expected, rng)
                fault_results.append(fault)
                print(f"  data fault {number}: {fault.victim} at +{fault.delay:.2f} s → {fault.status}, "
                      f"{fault.faults} faults, {fault.blamed} blamed, identical after resume "
                      f"{fault.identical} {fault.error}", flush=True)
            publish()
        print(publish())
        bad = [t for _, trials in kill_results.values() for t in trials
               if t.lost or t.duplicated or not t.at_kill.consistent or not (t.identical or t.same_but_ids)]
        bad_faults = [t for t in fault_results if t.blamed or not t.identical]
        return 1 if bad or bad_faults else 0
    finally:
        if args.keep:
            print(f"workspaces kept in {root}")
        else:
            shutil.rmtree(root, ignore_errors=True)
        if ROOT.name.startswith("lidarfuzz-kills-code-"):  # the copy freeze() made: this process's own
            shutil.rmtree(ROOT, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(main())
