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

from lidarfuzz.campaign.cluster import ClusterError, RayExecutor, import_ray, require_shared_store
from lidarfuzz.campaign.executor import Executor, InlineExecutor, ProcessExecutor
from lidarfuzz.campaign.runner import ProgressEvent, run_task
from lidarfuzz.campaign.spec import parse_campaign
from lidarfuzz.campaign.tasks import create_task, get_task
from lidarfuzz.campaign.work import UnitResult, WorkUnit
from lidarfuzz.errors import MissingDependencyError
from lidarfuzz.store import Finding, FrameResult, Status, Store, Subtask
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


# -- helpers -------------------------------------------------------------------------------------
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


# -- 1. the same results on every executor -------------------------------------------------------
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


# -- 2. a worker node lost mid-run ------------------------------------------------------------------
def test_a_worker_node_killed_mid_campaign_loses_and_repeats_nothing(ray_nodes: LocalRayCluster,
                                                                      databases: Workspaces, world: Path,
                                                                      reference: Snapshot) -> None:
    store, task_id = new_task(databases.new("node-lost"), world)
    killed_at: list[int] = []

    t0 = time.monotonic()

    def kill_a_node(event: ProgressEvent) -> None:
        print(f"DBG {time.monotonic()-t0:.2f} done {event.task_done} pool {[(a.ready is None, len(a.units), a.suspect) for a in executor._pool]} cpus {executor._cpus()}", flush=True)
        if event.task_done >= 3 and not killed_at:  # units are in flight on both actors (2 each)
            ray_nodes.kill_worker()
            killed_at.append(event.task_done)
            print(f"DBG killed {time.monotonic()-t0:.2f}", flush=True)

    class Dbg(RayExecutor):
        def run(self, units):
            yield from super().run(units)
            print(f"DBG run over {time.monotonic()-t0:.2f} failed starts {self._failed_starts} pool {[(a.ready is None, len(a.units)) for a in self._pool]}", flush=True)
        def close(self):
            super().close()
            print(f"DBG closed {time.monotonic()-t0:.2f}", flush=True)
    executor = Dbg(ray_nodes.address)
    try:
        outcome = run_task(store, task_id, executor=executor, progress=kill_a_node)
        print(f"DBG end {time.monotonic()-t0:.2f} restarts {executor.restarts}", flush=True)
        assert killed_at and killed_at[0] < UNITS and ray_nodes.nodes == 1
        assert executor.restarts >= 1  # the actor of the lost node was replaced: its units ran again
        assert outcome.status == Status.DONE
        state = whole(store, task_id)
        # nothing lost, nothing counted twice: rows = task counter = subtasks' counters = distinct units
        assert state.complete and state.total == UNITS and state.status == "done", state
        assert_same(snapshot(store, task_id), reference)  # no crash finding for the node's loss
    finally:
        store.close()


# -- 3. a system that segfaults its actor -------------------------------------------------------------
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


# -- 4. the driver killed, then resumed ------------------------------------------------------------------
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


# -- 5. refusals -------------------------------------------------------------------------------------------
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
    store = Store(workspace, migrate=False) if workspace.exists() else None
    if store is not None:  # refused before a task was created
        with store.session() as s:
            assert not s.scalar(select(func.count()).select_from(FrameResult))
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


# -- 6. two drivers on one task -------------------------------------------------------------------------------
def test_two_drivers_on_one_task_store_each_unit_once(ray_nodes: LocalRayCluster, databases: Workspaces,
                                                      world: Path, reference: Snapshot) -> None:
    """A second driver takes the task over (``resume --force``) while the first still runs it, one
    actor each: both run the units left when the second started, and each unit is stored once."""
    import ray

    workspace = databases.new("two-drivers")
    first_store, task_id = new_task(workspace, world)
    second_store = Store(workspace)
    # one connection for both drivers' executors (each would otherwise shut Ray down at its end)
    ray.init(address=ray_nodes.address, include_dashboard=False, log_to_driver=False, configure_logging=False)
    first, second = CountingRay(actors=1), CountingRay(actors=1)
    outcomes: dict[str, Any] = {}
    errors: list[BaseException] = []

    def drive(name: str, store: Store, executor: RayExecutor, take_over: bool) -> None:
        try:
            outcomes[name] = run_task(store, task_id, executor=executor, take_over=take_over)
        except BaseException as exc:  # seen by the test below
            errors.append(exc)

    started = threading.Event()

    def start_second(event: ProgressEvent) -> None:
        if event.task_done >= 2 and not started.is_set():
            started.set()
            threading.Thread(target=drive, args=("second", second_store, second, True)).start()

    try:
        drive_first = threading.Thread(target=lambda: outcomes.update(
            first=run_task(first_store, task_id, executor=first, progress=start_second)))
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
        assert outcomes["second"].stats.units >= 1
        assert first.results + second.results > UNITS  # some unit ran on both drivers
        assert get_task(first_store, task_id).done == UNITS
        mine = snapshot(first_store, task_id)
        results_same, findings_same, _, same_but_ids = compare(mine, reference)
        assert results_same and findings_same and same_but_ids, differences(mine, reference)
    finally:
        first_store.close()
        second_store.close()
        ray.shutdown()
