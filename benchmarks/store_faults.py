"""Failing disks, concurrent runs and read-only workspaces, repeated: the figures of the ``store``
section of docs/reliability.md.

Scenarios (each ``--repeat`` times, seeded):

* disk full during ``run``: the SQLite store capped at a random page count between its size
  before the run and after it (:mod:`tests.cli.faults`), and, where ``unshare -rm`` may mount one,
  the workspace on a real tmpfs of a random size (the kernel's own ENOSPC); then ``resume`` with
  room again. Counted: one-line errors, exit codes 1, tracebacks, stores whose counters agree
  with their results, resumed results identical to an uninterrupted run's.
* disk full during ``report``: a random byte budget for the files written (``OSError(ENOSPC)``);
  counted: one-line errors, files left partial at a final name (a file that is not byte-identical
  to the complete report's), reports complete once there is room.
* concurrent creation: 4 processes opening and creating a campaign on one brand-new workspace at
  once; counted: campaigns stored of those created. The same migrating as before (no lock, SQLite's
  DDL outside a transaction), as the baseline that shows the race.
* double resume: two runners of one task at once (the second refusing, or waiting, in turn);
  counted: units run in all (the task's total means none twice), refusals naming the runner,
  identical results.
* read-only workspace: list, status, report --out -, and the writing commands; counted: commands
  that behave as documented.

Usage::

    python benchmarks/store_faults.py [--repeat 10] [--seed 0] [--write-doc]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing
import os
import random
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from sqlalchemy import func, select, text  # noqa: E402
from tests.cli.faults import run_commands  # noqa: E402

from lidarfuzz.campaign.executor import InlineExecutor  # noqa: E402
from lidarfuzz.campaign.runner import run_task  # noqa: E402
from lidarfuzz.campaign.spec import parse_campaign  # noqa: E402
from lidarfuzz.campaign.tasks import create_task, get_task  # noqa: E402
from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset  # noqa: E402
from lidarfuzz.store import FrameResult, Status, Store, Subtask  # noqa: E402
from lidarfuzz.store.claims import holder  # noqa: E402
from lidarfuzz.store.errors import TaskClaimedError  # noqa: E402

OPS = [{"name": "rotate_z", "severities": [3]}, {"name": "gaussian_noise_addition", "severities": [2]}]
CLI_OPS = ["--op", "rotate_z@3", "--op", "gaussian_noise_addition@2"]


def outputs(store: Store, task_id: int) -> dict[tuple[str, int, str, int], bytes | None]:
    with store.session() as s:
        rows = s.execute(select(Subtask.name, Subtask.severity, FrameResult.frame_id, FrameResult.trial,
                                FrameResult.boxes).join(Subtask).where(Subtask.task_id == task_id))
        return {(a, b, c, d): e for a, b, c, d, e in rows}


def pages(store: Store) -> int:
    with store.engine.connect() as connection:
        return int(connection.execute(text("PRAGMA page_count")).scalar_one())


def one_line(result: dict[str, Any]) -> bool:
    err = result["err"]
    return bool(err.startswith("error: ") and err.count("\n") == 1)


def consistent(workspace: Path) -> bool:
    """The task's counters agree with the results stored."""
    store = Store(workspace, migrate=False)
    task = get_task(store, 1)
    with store.session() as s:
        stored = s.scalar(select(func.count()).select_from(FrameResult))
    store.close()
    return bool(task.done == stored == sum(sub.done for sub in task.subtasks))


class Bench:
    def __init__(self, work: Path, repeat: int, seed: int) -> None:
        self.work, self.repeat, self.random = work, repeat, random.Random(seed)
        self.world = work / "world"
        generate_dataset(self.world, GenerationConfig(frames=2, seed=0), workers=1, overwrite=True)
        store = Store(work / "reference")
        task = create_task(store, parse_campaign({"dataset": str(self.world), "sut": "classic", "operators": OPS}))
        self.before = pages(store)
        run_task(store, task, executor=InlineExecutor())
        self.after = pages(store)
        self.reference = outputs(store, task)
        self.units = get_task(store, task).total
        store.close()

    def run_args(self, workspace: Path) -> list[str]:
        return ["run", "--dataset", str(self.world), "--sut", "classic", *CLI_OPS, "--inline", "--workspace",
                str(workspace)]

    # -- disk full during run -------------------------------------------------------------
    def run_full(self) -> dict[str, Any]:
        counts: Counter[str] = Counter()
        caps = []
        for i in range(self.repeat):
            ws = self.work / f"full-run-{i}"
            cap = self.random.randint(self.before, self.after - 1)
            caps.append(cap)
            failed, = run_commands([({"store_pages": cap}, self.run_args(ws))])
            self._count_run(counts, ws, failed)
        return {"counts": counts, "caps": (min(caps), max(caps)), "trials": self.repeat}

    def _count_run(self, counts: Counter[str], ws: Path, failed: dict[str, Any]) -> None:
        """Count a failed run (its line, and the store it left: counters agreeing with the results,
        or, when the disk filled before the task was created, no half-made schema), then go on with
        room again: ``resume 1``, or ``run`` again."""
        existed, sound = False, False
        with contextlib.suppress(Exception):
            store = Store(ws, migrate=False)
            revision = store.revision()  # never tables without their revision
            sound = revision == store.head() or (revision is None and not store.tables())
            with contextlib.suppress(Exception):
                existed = get_task(store, 1) is not None
            store.close()
            sound = sound and (consistent(ws) if existed else True)
        counts["trials"] += 1
        counts["before the task existed"] += not existed
        counts["exit 1"] += failed["code"] == 1
        counts["one line"] += one_line(failed)
        counts["traceback"] += "Traceback" in failed["err"]
        counts["names the file"] += str(ws.resolve()) in failed["err"] or str(ws) in failed["err"]
        counts["says resume"] += existed and "lidarfuzz resume 1" in failed["err"]
        counts["consistent"] += sound
        then = ["resume", "1", "--inline", "--workspace", str(ws)] if existed else self.run_args(ws)
        resumed, = run_commands([({}, then)])
        counts["resumed"] += resumed["code"] == 0
        with contextlib.suppress(Exception):
            store = Store(ws, migrate=False)
            counts["identical"] += outputs(store, 1) == self.reference
            store.close()

    def run_full_tmpfs(self) -> dict[str, Any] | None:
        """The workspace on a real tmpfs of a random size, mounted in a private namespace."""
        if shutil.which("unshare") is None:
            return None
        probe = subprocess.run(["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o size=64k none {self.work}"],
                               capture_output=True)
        if probe.returncode != 0:
            return None
        counts: Counter[str] = Counter()
        sizes = []
        reference_bytes = (self.work / "reference" / "lidarfuzz.db").stat().st_size
        for i in range(self.repeat):
            mount, kept = self.work / f"tmpfs-{i}", self.work / f"tmpfs-kept-{i}"
            mount.mkdir()
            size_kib = self.random.randint(96, max(97, 2 * reference_bytes // 1024))
            sizes.append(size_kib)
            script = (f'mount -t tmpfs -o size={size_kib}k none {mount} && "$@" > {self.work}/tmpfs-{i}.json; '
                      f"cp -a {mount}/ws {kept}")
            child = [sys.executable, "-c", _CHILD_ONE, json.dumps(self.run_args(mount / "ws"))]
            subprocess.run(["unshare", "-rm", "sh", "-c", script, "sh", *child], capture_output=True, timeout=600,
                           env={**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "200"})
            failed = json.loads((self.work / f"tmpfs-{i}.json").read_text())
            if failed["code"] == 0:  # the disk was large enough: not a trial of a full disk
                counts["fitted"] += 1
                continue
            failed["err"] = failed["err"].replace(str(mount), str(kept))
            self._count_run(counts, kept, failed)
        return {"counts": counts, "sizes": (min(sizes), max(sizes)), "trials": self.repeat}

    # -- disk full during report ----------------------------------------------------------
    def report_full(self) -> dict[str, Any]:
        ws = self.work / "report-ws"
        shutil.copytree(self.work / "reference", ws)
        complete = self.work / "complete"
        base = ["--workspace", str(ws), "--quiet"]
        first, = run_commands([({}, ["report", "1", "--out", str(complete), *base])])
        assert first["code"] == 0, first
        whole = {p.name: p.read_bytes() for p in complete.iterdir()}
        total = sum(len(data) for data in whole.values())
        budgets = [self.random.randint(1, total - 1) for _ in range(self.repeat)]
        commands: list[tuple[dict[str, Any], list[str]]] = []
        for i, budget in enumerate(budgets):
            commands.append(({"write_bytes": budget}, ["report", "1", "--out", str(self.work / f"rep-{i}"), *base]))
            commands.append(({}, ["report", "1", "--out", str(self.work / f"rep-{i}-again"), *base]))
        counts: Counter[str] = Counter()
        for i, (failed, again) in enumerate(zip(*[iter(run_commands(commands))] * 2, strict=True)):
            counts["trials"] += 1
            counts["exit 1"] += failed["code"] == 1
            counts["one line"] += one_line(failed)
            counts["traceback"] += "Traceback" in failed["err"]
            folder = self.work / f"rep-{i}"
            left = [p for p in folder.iterdir()] if folder.exists() else []
            counts["partial files"] += sum(1 for p in left if p.name not in whole or p.name.startswith("."))
            counts["complete after"] += again["code"] == 0 and sorted(
                p.name for p in (self.work / f"rep-{i}-again").iterdir()) == sorted(whole)
        return {"counts": counts, "budgets": (min(budgets), max(budgets)), "bytes": total, "trials": self.repeat}

    # -- concurrent creation ----------------------------------------------------------------
    def concurrent_create(self, *, lock: bool) -> dict[str, Any]:
        context = multiprocessing.get_context("fork")
        counts: Counter[str] = Counter()
        for i in range(self.repeat):
            ws = self.work / f"create-{'lock' if lock else 'nolock'}-{i}"
            loaded, go, failures = context.Semaphore(0), context.Event(), context.Queue()
            names = [f"c{j}" for j in range(4)]
            procs = [context.Process(target=_create, args=(str(ws), str(self.world), name, lock, loaded, go,
                                                           failures)) for name in names]
            for proc in procs:
                proc.start()
            for _ in procs:
                loaded.acquire(timeout=60)
            go.set()
            for proc in procs:
                proc.join(120)
            stored: list[str] = []
            with contextlib.suppress(Exception):
                store = Store(ws)
                from lidarfuzz.store.models import Task

                with store.session() as s:
                    stored = list(s.scalars(select(Task.name)))
                store.close()
            counts["rounds"] += 1
            counts["created"] += len(names)
            counts["stored"] += len(stored)
            counts["rounds losing one"] += len(stored) < len(names)
        return {"counts": counts}

    # -- double resume ----------------------------------------------------------------------
    def double_resume(self) -> dict[str, Any]:
        counts: Counter[str] = Counter()
        context = multiprocessing.get_context("fork")
        for i in range(self.repeat):
            wait = i % 2 == 1
            ws = self.work / f"resume-{i}"
            store = Store(ws)
            task_id = create_task(store, parse_campaign({"dataset": str(self.world), "operators": OPS,
                                                         "sut": "tests.campaign.systems:SlowClassic"}),
                                  sut_options={"delay": 0.2})
            store.engine.dispose()
            loaded, go, results = context.Event(), context.Event(), context.Queue()
            second = context.Process(target=_second, args=(str(ws), task_id, wait, loaded, go, results))
            second.start()
            loaded.wait(60)
            first: dict[str, Any] = {}
            runner = threading.Thread(target=_first, args=(store, task_id, first))
            runner.start()
            while holder(store, task_id) is None and runner.is_alive():
                time.sleep(0.01)
            go.set()
            runner.join()
            second.join(120)
            kind, value = results.get(timeout=30)
            units = first["outcome"].stats.units + (value if kind == "ran" else 0)
            counts["trials"] += 1
            counts["waited" if wait else "refused"] += (kind == "ran") if wait else (kind == "refused"
                                                                                     and value == os.getpid())
            counts["units run"] += units
            counts["units planned"] += self.units
            task = get_task(store, task_id)
            counts["done"] += task.status == Status.DONE and task.done == task.total
            counts["identical"] += outputs(store, task_id) == self.reference
            store.close()
        return {"counts": counts}

    # -- read-only ----------------------------------------------------------------------------
    def read_only(self) -> dict[str, Any] | None:
        from tests.store.test_readonly import COMMANDS, _can_bind_read_only

        ws = self.work / "ro"
        shutil.copytree(self.work / "reference", ws)
        if os.geteuid() == 0 and not _can_bind_read_only(ws):
            return None
        w = ["--workspace", str(ws)]
        expected = [(["list", "--plain", *w], 0, ""), (["status", "1", *w], 0, ""),
                    (["report", "1", "--out", "-", *w], 0, ""),
                    (["resume", "1", *w], 1, "is read-only: lidarfuzz resume 1 writes to it"),
                    (["cancel", "1", *w], 1, "is read-only: lidarfuzz cancel writes to it"),
                    (["delete", "1", *w], 1, "is read-only: lidarfuzz delete writes to it"),
                    (["run", "--dataset", str(self.world), "--sut", "classic", "--op", "fog@1", *w], 1,
                     "is read-only: lidarfuzz run writes to it"),
                    (["report", "1", "--quiet", *w], 1, "cannot write")]
        env = {**os.environ, "COLUMNS": "200", "PYTHONPATH": str(ROOT)}
        script = [sys.executable, "-c", COMMANDS, json.dumps([args for args, _, _ in expected])]
        if os.geteuid() == 0:
            mount = f"mount --bind {ws} {ws} && mount -o remount,ro,bind {ws} && exec \"$@\""
            script = ["unshare", "-rm", "sh", "-c", mount, "sh", *script]
        else:
            subprocess.run(["chmod", "-R", "a-w", str(ws)], check=True)
        done = subprocess.run(script, capture_output=True, text=True, env=env, timeout=600)
        if os.geteuid() != 0:
            subprocess.run(["chmod", "-R", "u+w", str(ws)], check=True)
        results = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
        good = sum(1 for (args, code, words), got in zip(expected, results, strict=True)
                   if got["code"] == code and words in got["err"] and (code == 0 or one_line(got)))
        return {"commands": len(expected), "as documented": good,
                "failures": [got["args"][0] for (a, c, w_), got in zip(expected, results, strict=True)
                             if not (got["code"] == c and w_ in got["err"])]}


_CHILD_ONE = r"""
import contextlib, io, json, sys
from lidarfuzz.cli.app import main
out, err = io.StringIO(), io.StringIO()
code = 0
with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
    sys.argv = ["lidarfuzz", *json.loads(sys.argv[1])]
    try:
        main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:
        import traceback
        err.write(traceback.format_exc())
        code = 99
print(json.dumps({"code": code, "out": out.getvalue(), "err": err.getvalue()}))
"""


def _unlocked_migrate(self: Store, revision: str = "head") -> None:
    """Store.migrate as it was before issue 23: no lock, and SQLite's DDL outside a transaction."""
    from alembic import command

    with self.engine.begin() as connection:
        command.upgrade(self._alembic(connection), revision)


def _create(ws: str, world: str, name: str, lock: bool, loaded: Any, go: Any, failures: Any) -> None:
    if not lock:
        Store.migrate = _unlocked_migrate  # type: ignore[method-assign]
    loaded.release()
    go.wait(60)
    try:
        create_task(Store(ws), parse_campaign({"name": name, "dataset": world, "sut": "classic", "operators": OPS}))
    except Exception as exc:  # the baseline's lost campaign
        failures.put(str(exc)[:200])


def _first(store: Store, task_id: int, first: dict[str, Any]) -> None:
    first["outcome"] = run_task(store, task_id, executor=InlineExecutor())


def _second(ws: str, task_id: int, wait: bool, loaded: Any, go: Any, results: Any) -> None:
    store = Store(ws)
    loaded.set()
    go.wait(60)
    try:
        outcome = run_task(store, task_id, executor=InlineExecutor(), wait=wait)
        results.put(("ran", outcome.stats.units))
    except TaskClaimedError as exc:
        results.put(("refused", exc.pid))


def markdown(figures: dict[str, Any], command: str) -> str:
    from reliability_doc import provenance

    run, tmpfs, report = figures["run"]["counts"], figures["tmpfs"], figures["report"]["counts"]
    create, baseline = figures["create"]["counts"], figures["create_baseline"]["counts"]
    resume, ro = figures["resume"]["counts"], figures["readonly"]
    lines = [provenance(command), "",
             "| scenario | trials | held |", "|---|---|---|",
             f"| disk full during `run` (store capped at {figures['run']['caps'][0]}–{figures['run']['caps'][1]} "
             f"pages, SQLite's \"database or disk is full\"), then `resume` | {run['trials']} | "
             f"{run['one line']} one-line errors, {run['exit 1']} exit 1, {run['traceback']} tracebacks, "
             f"{run['names the file']} naming the database, {run['says resume']} saying `lidarfuzz resume 1`; "
             f"{run['consistent']} stores consistent; {run['resumed']} resumed, {run['identical']} with results "
             f"identical to an uninterrupted run |"]
    tmpfs_note = ("then `resume` (or `run` again where the disk filled before the task was created: "
                  "{before} trials)")
    if tmpfs is not None:
        t = tmpfs["counts"]
        lines.append(f"| disk full during `run` on a real tmpfs of {tmpfs['sizes'][0]}–{tmpfs['sizes'][1]} KiB "
                     f"(the kernel's ENOSPC), {tmpfs_note.format(before=t['before the task existed'])} | "
                     f"{tmpfs['trials']} ({t['fitted']} fitted the disk) | "
                     f"{t['one line']} one-line errors, {t['exit 1']} exit 1, {t['traceback']} tracebacks; "
                     f"{t['consistent']} stores consistent; {t['resumed']} finished, {t['identical']} with results "
                     f"identical to an uninterrupted run |")
    else:
        lines.append("| disk full on a real tmpfs | — | not run: `unshare -rm` may not mount here |")
    lines.append(f"| disk full during `report` (a budget of {figures['report']['budgets'][0]}–"
                 f"{figures['report']['budgets'][1]} of its {figures['report']['bytes']} bytes, ENOSPC from "
                 f"`write`), then `report` again | {report['trials']} | {report['one line']} one-line errors, "
                 f"{report['exit 1']} exit 1, {report['traceback']} tracebacks, {report['partial files']} partial "
                 f"files at a final name; {report['complete after']} complete reports after |")
    lines.append(f"| 4 processes creating a campaign on one new workspace at once | {create['rounds']} rounds | "
                 f"{create['stored']} of {create['created']} campaigns stored ({create['rounds losing one']} rounds "
                 f"lost one); migrating as before (no lock, DDL outside a transaction): {baseline['stored']} of "
                 f"{baseline['created']} ({baseline['rounds losing one']} rounds lost one) |")
    lines.append(f"| two runners of one task at once (second refusing / waiting in turn) | {resume['trials']} | "
                 f"{resume['refused']} refused naming the runner, {resume['waited']} waited; {resume['units run']} "
                 f"units run for {resume['units planned']} planned (none twice); {resume['done']} done, "
                 f"{resume['identical']} identical to one run |")
    if ro is not None:
        lines.append(f"| read-only workspace: list, status, report --out -, and run/resume/cancel/delete/report "
                     f"refusing in one line | {ro['commands']} commands | {ro['as documented']} as documented |")
    else:
        lines.append("| read-only workspace | — | not run: root, and `unshare -rm` may not bind-mount here |")
    lines += ["", "How: `tests/cli/faults.py` caps SQLite with `max_page_count` (SQLite then fails as on a "
                  "full disk) or gives the files a byte budget (`OSError(ENOSPC)` from `write`); the tmpfs rows "
                  "mount a real one in a private mount namespace. The read-only workspace is a read-only bind "
                  "mount (as root) or `chmod a-w`. SQLite only here; the PostgreSQL variants of the races run "
                  "in `tests/store/test_races.py`."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--write-doc", action="store_true", help="rewrite the store section of docs/reliability.md")
    args = parser.parse_args()
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="store-faults-") as folder:
        bench = Bench(Path(folder), args.repeat, args.seed)
        figures: dict[str, Any] = {}
        for name, step in [("run", bench.run_full), ("tmpfs", bench.run_full_tmpfs), ("report", bench.report_full),
                           ("create", lambda: bench.concurrent_create(lock=True)),
                           ("create_baseline", lambda: bench.concurrent_create(lock=False)),
                           ("resume", bench.double_resume), ("readonly", bench.read_only)]:
            moment = time.perf_counter()
            figures[name] = step()
            print(f"{name}: {json.dumps(figures[name], default=dict)} ({time.perf_counter() - moment:.0f} s)",
                  flush=True)
    command = f"python benchmarks/store_faults.py --repeat {args.repeat} --seed {args.seed}"
    text_ = markdown(figures, command)
    print(text_)
    print(f"({time.perf_counter() - started:.0f} s)")
    if args.write_doc:
        from reliability_doc import write_section

        write_section("store", text_)


if __name__ == "__main__":
    main()
