"""Campaigns on a Ray cluster (``--executor ray``): a local cluster of a head and two worker nodes
of one CPU each (:mod:`tests.campaign.ray_cluster`), a PostgreSQL store per run.

What a cluster must not change: the results stored (the same bit for bit as inline and on a local
pool), whatever happens to it mid-run — a worker node lost, a system that segfaults its actor,
the driver killed and resumed, two drivers on one task. Each run is compared with an undisturbed
inline run of the same campaign by :mod:`benchmarks.kills`' snapshot (per unit: boxes, labels,
ground truth, failure, params, relations; findings in unit order; the CSV exports byte for byte and
the JSON summary but for the run's own record).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pytest
from benchmarks.kills import Snapshot, Workspaces, compare, differences, snapshot, whole
from sqlalchemy import func, select

from lidarfuzz.campaign.cluster import CLOSE_SECONDS, ClusterError, RayExecutor, import_ray, require_shared_store
from lidarfuzz.campaign.executor import Executor, InlineExecutor, ProcessExecutor
from lidarfuzz.campaign.runner import ProgressEvent, run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.campaign.work import UnitResult, WorkUnit
from lidarfuzz.errors import MissingDependencyError
from lidarfuzz.store import Finding, FrameResult, Status, Store, Subtask, Task
from tests.campaign.ray_cluster import LocalRayCluster, ray_cluster_fixture, ray_nodes_fixture  # noqa: F401

pytestmark = pytest.mark.ray

ROOT = Path(__file__).resolve().parents[2]
CLI = "from lidarfuzz.cli.app import main; main()"
#: The classic pipeline slowed down (so that a run can be disturbed mid-way) and raising on frame
#: 000001 (a crash finding on each of its units, so that the findings' numbering is put to the test).
SYSTEM = "tests.campaign.kill_systems:SlowRaises"
DELAY = 0.25
OPS = ["--op", "gaussian_noise_addition@2,5", "--op", "rotate_z@3"]
OPERATORS = [{"name": "gaussian_noise_addition", "severities": [2, 5]}, {"name": "rotate_z", "severities": [3]}]
#: 3 frames × (the originals + 3 operator settings)
UNITS = 12
#: The frame SlowRaises raises on (and SegfaultsOnFrame segfaults on).
BAD_FRAME = "000001"
RAY_CRASH = "the system under test killed its Ray actor's process twice (e.g. a segmentation fault)"


# -- helpers -------------------------------------------------------------------------------------------------
def campaign(world: Path, sut: str = SYSTEM, operators: list[dict[str, Any]] | None = None) -> Any:
    return parse_campaign({"dataset": str(world), "sut": sut, "operators": operators or OPERATORS})


def new_task(workspace: str, world: Path) -> tuple[Store, int]:
    store = Store(workspace)
    return store, create_task(store, campaign(world), sut_options={"delay": DELAY})


def cli(cwd: Path, *args: str, **kwargs: Any) -> subprocess.Popen[str]:
    """``lidarfuzz ARGS`` in ``cwd`` (reports of a database-URL workspace go to ./lidarfuzz-reports),
    with the test systems importable."""
    path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
    return subprocess.Popen([sys.executable, "-c", CLI, *args], cwd=cwd, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, env={**os.environ, "COLUMNS": "120", "PYTHONPATH": path},
                            **kwargs)


def assert_same(mine: Snapshot, reference: Snapshot, exports_ids_may_skip: bool = False) -> None:
    """Results and findings bit for bit; exports byte for byte (with ``exports_ids_may_skip``, a
    PostgreSQL transaction killed mid-way may have drawn finding ids from the sequence, which is not
    transactional: then only findings.csv's ids may skip numbers)."""
    results_same, findings_same, exports_same, same_but_ids = compare(mine, reference)
    note = differences(mine, reference)
    assert results_same and findings_same, note
    assert exports_same or (exports_ids_may_skip and same_but_ids), note


def stored(workspace: str) -> int:
    """Results stored so far (0 while the schema does not exist yet)."""
    store = Store(workspace, migrate=False)
    try:
        with store.session() as s:
            return s.scalar(select(func.count()).select_from(FrameResult)) or 0
    except Exception:  # no schema yet
        return 0
    finally:
        store.close()


class CountingRay(RayExecutor):
    """A RayExecutor that counts the results it hands back (a unit run by two drivers is counted by
    each, and stored once)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.results = 0

    def run(self, units: Iterable[WorkUnit]) -> Iterator[UnitResult]:
        for result in super().run(units):
            self.results += 1
            yield result


@pytest.fixture(scope="module")
def databases(postgres_url: str, tmp_path_factory: pytest.TempPathFactory) -> Workspaces:
    """Fresh databases on the throwaway PostgreSQL server (dropped with it)."""
    return Workspaces("postgresql", tmp_path_factory.mktemp("ray-ws"), postgres_url)


@pytest.fixture(scope="module")
def reference(databases: Workspaces, world: Path) -> Snapshot:
    """The campaign run undisturbed, inline, into a fresh PostgreSQL database."""
    store, task_id = new_task(databases.new("inline"), world)
    try:
        assert run_task(store, task_id, executor=InlineExecutor()).status == Status.DONE
        state = whole(store, task_id)
        assert state.complete and state.total == UNITS, state
        found = snapshot(store, task_id)
    finally:
        store.close()
    # frame 000001 under the originals and each of the 3 operator settings: a crash each
    assert [(f[2], f[4]) for f in found.findings if f[4] == "crash"] == [(BAD_FRAME, "crash")] * 4
    return found


# -- the same results on every executor ----------------------------------------------------------------------
@pytest.mark.parametrize("executor", ["pool", "ray"])
def test_every_executor_stores_the_same_results_bit_for_bit(executor: str, request: pytest.FixtureRequest,
                                                           databases: Workspaces, world: Path,
                                                           reference: Snapshot) -> None:
    """Inline (the reference), a local pool of 2 processes and the Ray cluster's 2 actors, each into
    its own fresh PostgreSQL database: the same rows, findings with their numbering, AP figures."""
    chosen: Executor
    if executor == "ray":
        cluster: LocalRayCluster = request.getfixturevalue("ray_nodes")
        chosen = RayExecutor(cluster.address)
    else:
        chosen = ProcessExecutor(2)
    store, task_id = new_task(databases.new(executor), world)
    try:
        assert run_task(store, task_id, executor=chosen).status == Status.DONE
        state = whole(store, task_id)
        assert state.complete and state.total == UNITS, state
        assert_same(snapshot(store, task_id), reference)
    finally:
        store.close()


# -- a system that segfaults its actor -----------------------------------------------------------------------
def test_a_segfault_in_an_actor_is_the_system_s_crash_on_that_frame_only(ray_nodes: LocalRayCluster,
                                                                         databases: Workspaces, world: Path,
                                                                         reference: Snapshot) -> None:
    store = Store(databases.new("segfault"))
    operators = [{"name": "rotate_z", "severities": [3]}]
    task_id = create_task(store, campaign(world, "tests.campaign.ray_systems:SegfaultsOnFrame", operators),
                          sut_options={"frame": BAD_FRAME})
    try:
        executor = RayExecutor(ray_nodes.address)
        assert run_task(store, task_id, executor=executor).status == Status.DONE
        # each unit of the frame killed one actor in company and one alone
        assert executor.restarts >= 4
        state = whole(store, task_id)
        assert state.complete and state.total == 6, state  # 3 frames × (the originals + rotate_z@3)
        mine = snapshot(store, task_id)
        crashed = {key: value[4] for key, value in mine.results.items() if value[4] is not None}
        expected = {("original", 0, BAD_FRAME, 0), ("rotate_z", 3, BAD_FRAME, 0)}
        assert set(crashed) == expected
        assert all(failure["kind"] == "crash" and failure["message"] == RAY_CRASH
                   for failure in crashed.values()), crashed
        for key in expected:
            assert mine.results[key][0] is None  # no detections stored for a crash
        with store.session() as s:
            findings = s.execute(select(Subtask.name, FrameResult.frame_id, Finding.kind, Finding.message)
                                 .join(FrameResult, Finding.frame_result_id == FrameResult.id).join(Subtask)
                                 .where(Finding.task_id == task_id).order_by(Finding.id)).all()
        crash_findings = [tuple(f) for f in findings if f[2] == "crash"]
        assert crash_findings == [("original", BAD_FRAME, "crash", RAY_CRASH),
                                  ("rotate_z", BAD_FRAME, "crash", RAY_CRASH)]
        # every other unit: the classic pipeline's answer, as in the inline reference (same frames,
        # same seeded mutants; SlowRaises differs from this system only on the bad frame)
        others = {key: value for key, value in mine.results.items() if key not in expected}
        assert len(others) == 4
        assert others == {key: reference.results[key] for key in others}
    finally:
        store.close()


# -- the driver killed, then resumed -------------------------------------------------------------------------
def test_the_driver_killed_then_resumed_on_the_cluster(ray_nodes: LocalRayCluster, fresh_postgres_url: str,
                                                      world: Path, tmp_path: Path, reference: Snapshot) -> None:
    workspace = fresh_postgres_url
    ray_args = ["--executor", "ray", "--address", ray_nodes.address, "--workspace", workspace]
    run = cli(tmp_path, "run", "--dataset", str(world), "--sut", SYSTEM, "--option", f"delay={DELAY}", *OPS,
              *ray_args, start_new_session=True)
    kill_after = 4
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and run.poll() is None and stored(workspace) < kill_after:
        time.sleep(0.02)
    assert run.poll() is None, f"the run ended before it could be killed:\n{run.communicate()[0]}"
    os.killpg(run.pid, signal.SIGKILL)
    run.wait()

    store = Store(workspace)
    try:
        at_kill = whole(store, 1)
        assert at_kill.status == "running" and kill_after <= at_kill.rows < UNITS, at_kill  # died mid-way
        assert at_kill.consistent, at_kill  # whole results: rows = counters = distinct units
        # the dead driver's claim (a process gone on this host) is taken over at once: no --force
        resumed = cli(tmp_path, "resume", "1", *ray_args)
        log = resumed.communicate(timeout=300)[0]
        after = whole(store, 1)
        assert after.status == "done" and after.complete and after.total == UNITS, log  # 0 lost, 0 twice
        assert_same(snapshot(store, 1), reference, exports_ids_may_skip=True)
    finally:
        store.close()


# -- refusals ------------------------------------------------------------------------------------------------
def test_ray_refuses_an_sqlite_store_and_an_address_alone(world: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str],
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    from lidarfuzz.cli.app import main

    def lidarfuzz(*args: str) -> tuple[int, str]:
        monkeypatch.setattr(sys, "argv", ["lidarfuzz", *args])
        with pytest.raises(SystemExit) as exit_:
            main()
        code = exit_.value.code
        return (code if isinstance(code, int) else 1), capsys.readouterr().err

    workspace = tmp_path / "ws"
    args = ["run", "--dataset", str(world), "--sut", "classic", "--op", "rotate_z@3"]
    code, err = lidarfuzz(*args, "--executor", "ray", "--workspace", str(workspace))
    lines = err.strip().splitlines()
    assert code != 0 and len(lines) == 1, err
    assert "PostgreSQL" in lines[0] and "SQLite" in lines[0] and "every node" in lines[0], err
    if workspace.exists():  # refused before a task was created
        store = Store(workspace, migrate=False)
        try:
            with store.session() as s:
                assert not s.scalar(select(func.count()).select_from(Task))
        finally:
            store.close()

    code, err = lidarfuzz(*args, "--address", "127.0.0.1:6379", "--workspace", str(workspace))
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err  # a usage error: one line naming the option
    assert "--address" in lines[0] and "--executor ray" in lines[0], err

    sqlite = Store(tmp_path / "another")
    try:
        with pytest.raises(ClusterError, match="PostgreSQL"):  # what RayExecutor.open() checks first
            require_shared_store(sqlite.url)
    finally:
        sqlite.close()


def test_without_ray_the_executor_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    with pytest.raises(MissingDependencyError) as error:
        import_ray()
    assert "lidarfuzz[ray]" in str(error.value) and "--executor ray" in str(error.value)


# -- two drivers on one task ---------------------------------------------------------------------------------
def test_two_drivers_on_one_task_store_each_unit_once(ray_nodes: LocalRayCluster, databases: Workspaces,
                                                      world: Path, reference: Snapshot) -> None:
    """A second driver takes the task over (``resume --force``) while the first still runs it, one
    actor each: both run the units left when the second started, and each unit is stored once."""
    ray = import_ray()
    workspace = databases.new("two-drivers")
    first_store, task_id = new_task(workspace, world)
    second_store = Store(workspace)
    # one connection for both drivers' executors (each would otherwise shut Ray down at its end)
    ray.init(address=ray_nodes.address, include_dashboard=False, log_to_driver=False, configure_logging=False)
    first, second = CountingRay(actors=1), CountingRay(actors=1)
    outcomes: dict[str, Any] = {}
    errors: list[BaseException] = []

    def drive(name: str, store: Store, executor: RayExecutor, take_over: bool, progress: Any = None) -> None:
        try:
            outcomes[name] = run_task(store, task_id, executor=executor, take_over=take_over, progress=progress)
        except BaseException as exc:  # seen by the test below
            errors.append(exc)

    started = threading.Event()

    def start_second(event: ProgressEvent) -> None:
        if event.task_done >= 1 and not started.is_set():
            started.set()
            threading.Thread(target=drive, args=("second", second_store, second, True)).start()

    try:
        drive_first = threading.Thread(target=drive, args=("first", first_store, first, False, start_second))
        drive_first.start()
        drive_first.join(180)
        deadline = time.monotonic() + 180
        while started.is_set() and "second" not in outcomes and not errors and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not errors, errors
        assert started.is_set() and set(outcomes) == {"first", "second"}
        state = whole(first_store, task_id)
        assert state.complete and state.total == UNITS and state.status == "done", state
        # each stored its own share (commits of a unit the other stored first are refused)
        assert outcomes["first"].stats.units + outcomes["second"].stats.units == UNITS
        assert first.results + second.results > UNITS  # some unit ran on both drivers
        assert get_task(first_store, task_id).done == UNITS
        mine = snapshot(first_store, task_id)
        results_same, findings_same, _, same_but_ids = compare(mine, reference)
        assert results_same and findings_same and same_but_ids, differences(mine, reference)
    finally:
        first_store.close()
        second_store.close()
        ray.shutdown()


# -- the end of a run ------------------------------------------------------------------------------------------
#: Seconds without a unit stored (or, after the last, without the run ending) that make a stall: an
#: actor starts in 2-5 s here, a unit takes under a second, the end of a run (AP figures, closing
#: the actors) under 2 s.
STALL_SECONDS = 15.0


class CpuHolder:
    """Another job's actor holding one of the cluster's CPUs (a shared cluster)."""

    def ready(self) -> int:
        return os.getpid()


def run_in_thread(store: Store, task_id: int, executor: Executor,
                  on_progress: Any = None) -> tuple[threading.Thread, list[Any], list[BaseException], list[float]]:
    """``run_task`` in a thread of its own: the thread, its outcome, its error, when each unit was stored."""
    outcomes: list[Any] = []
    errors: list[BaseException] = []
    stored_at: list[float] = []

    def progress(event: ProgressEvent) -> None:
        stored_at.append(time.monotonic())
        if on_progress is not None:
            on_progress(event)

    def drive() -> None:
        try:
            outcomes.append(run_task(store, task_id, executor=executor, progress=progress))
        except BaseException as exc:  # seen by the test
            errors.append(exc)

    runner = threading.Thread(target=drive)
    runner.start()
    return runner, outcomes, errors, stored_at


def stalls(runner: threading.Thread, stored_at: list[float], *, units: int | None = None,
           closing: float = 0.0) -> bool:
    """Wait for the run in ``runner`` to end; True as soon as it stalls (nothing stored, or no end
    after its last unit, for :data:`STALL_SECONDS`; ``closing`` seconds more once all ``units``
    are stored, where the executor may wait that long to close an actor)."""
    since = time.monotonic()
    while runner.is_alive():
        allowed = STALL_SECONDS + (closing if units is not None and len(stored_at) >= units else 0.0)
        if time.monotonic() - max(since, stored_at[-1] if stored_at else since) > allowed:
            return True
        runner.join(0.05)
    return False


def test_a_run_ends_with_its_last_unit_while_an_actor_still_waits_for_a_cpu(ray_nodes: LocalRayCluster,
                                                                             databases: Workspaces,
                                                                             world: Path) -> None:
    """Another job holds one of the cluster's 2 CPUs: of the run's 2 actors one starts, one waits
    for a CPU; the run's 6 units (the 3 originals, then their 3 mutants) go to the first without a
    pause, and the run ends with them (the other actor is given up). Before, each call of
    ``RayExecutor.run`` (a block of units) waited for the other actor to start, up to 300 s."""
    ray = import_ray()  # typed Any: Ray's stubs do not follow ray.remote(...)(cls).remote()
    ray.init(address=ray_nodes.address, include_dashboard=False, log_to_driver=False, configure_logging=False)
    holder = ray.remote(num_cpus=1)(CpuHolder).remote()
    ray.get(holder.ready.remote(), timeout=120)
    store = Store(databases.new("cpu-held"))
    task_id = create_task(store, campaign(world, "classic", [{"name": "rotate_z", "severities": [3]}]))
    runner, outcomes, errors, stored_at = run_in_thread(store, task_id, RayExecutor(ray_nodes.address))
    try:
        stalled = stalls(runner, stored_at)
        if stalled:  # the CPU back, so that the run can end: the waiting actor starts
            ray.kill(holder)
            runner.join(120)
        assert not stalled, f"the run stored nothing for {STALL_SECONDS:g} s after {len(stored_at)} units"
        assert not runner.is_alive() and not errors, errors
        assert outcomes[0].status == Status.DONE
        state = whole(store, task_id)
        assert state.complete and state.total == 6, state
    finally:
        runner.join(300)
        store.close()


# -- the web app's task workers on the cluster (lidarfuzz serve --executor ray) ---------------------------------
def test_the_web_app_runs_its_tasks_on_the_cluster(ray_nodes: LocalRayCluster, databases: Workspaces, world: Path,
                                                     reference: Snapshot) -> None:
    """``serve --executor ray``: the server's task worker joins the cluster once and runs a queued
    task there, to the same results as the inline run."""
    from lidarfuzz.web.workers import TaskWorkers

    store, task_id = new_task(databases.new("web"), world)
    workers = TaskWorkers(store, threads=1, executor="ray", address=ray_nodes.address)
    try:
        workers.start()
        deadline = time.monotonic() + 180
        while get_task(store, task_id).status not in (Status.DONE, Status.FAILED) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert get_task(store, task_id).status == Status.DONE
        assert_same(snapshot(store, task_id), reference)
    finally:
        workers.close()
        store.close()


# -- a worker node lost mid-run (last: the head counts a lost node dead 10-30 s later) -----------------------
def test_a_worker_node_killed_mid_campaign_loses_and_repeats_nothing(ray_nodes: LocalRayCluster,
                                                                      databases: Workspaces, world: Path,
                                                                      reference: Snapshot) -> None:
    """One of the two worker nodes killed (every process on it) while both actors hold units: the run
    goes on with the other node's actor, runs the lost units again, and ends with what an
    undisturbed run stores."""
    store, task_id = new_task(databases.new("node-lost"), world)
    third = threading.Event()

    def on_progress(event: ProgressEvent) -> None:
        if event.task_done >= 3:
            third.set()

    executor = RayExecutor(ray_nodes.address)
    runner, outcomes, errors, stored_at = run_in_thread(store, task_id, executor, on_progress)
    try:
        # killed from here while the driver waits on both actors' units (2 in flight each)
        assert third.wait(120), errors
        time.sleep(0.1)
        killed_at = len(stored_at)
        ray_nodes.kill_worker()
        # the lost actor's replacement waits for room (on the lost node until the head counts it
        # dead, 10-30 s): the run goes on without it. When the lost actor had no unit left when its
        # node died (the others ran them), nothing tells the driver it is gone before the head does:
        # closing waits for its answer up to CLOSE_SECONDS (as a user's run would)
        stalled = stalls(runner, stored_at, units=UNITS, closing=CLOSE_SECONDS)
        if stalled:  # a node back gives it room, so that the run can end
            ray_nodes.add_worker()
            runner.join(120)
        assert not stalled, f"the run stored nothing for {STALL_SECONDS:g} s after {len(stored_at)} units"
        assert not runner.is_alive() and not errors, errors
        assert killed_at < UNITS, killed_at  # mid-run
        assert executor.restarts >= 1  # the actor of the lost node was replaced: its units ran again
        assert outcomes[0].status == Status.DONE
        state = whole(store, task_id)
        # nothing lost, nothing counted twice: rows = task counter = subtasks' counters = distinct units
        assert state.complete and state.total == UNITS and state.status == "done", state
        assert_same(snapshot(store, task_id), reference)  # and no crash finding for the node's loss
    finally:
        third.set()
        runner.join(300)
        store.close()
