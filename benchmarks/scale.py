"""Campaign throughput on a local Ray against the local process pool, the per-unit overheads of a
cluster run, and the model of docs/scaling.md built from them.

Usage: ``python benchmarks/scale.py [--frames N] [--repeats R] [--workers 1,2] [--actors 1,2,N]
[--commits K] [--write-doc]``

Everything runs on data, a store and a Ray the script makes itself and removes at the end: ``--frames``
simulator frames (HDL-64E, about 120k points each) in a temporary folder, ONE throwaway PostgreSQL
server (``initdb``/``pg_ctl``, as the ``postgres`` user when run as root; default settings, so every
commit is fsynced), and one local Ray of ``os.cpu_count()`` CPUs (``ray.init(address="local")``:
never another session's cluster).

1. **Throughput.** The same campaign (the ``classic`` system; originals + 4 operators at one severity:
   a cheap one, a point-noise one, fog and rain) run with ``run_task`` — the engine ``lidarfuzz run``
   drives — on the local pool of each ``--workers`` size (the baseline) and on Ray with each
   ``--actors`` count (``N`` is the CPU count), each run in a fresh PostgreSQL database, the
   configurations interleaved within each of ``--repeats`` rounds. Units/s counts every unit
   (originals included); frames × operators/s counts the mutants only. ``rotate_z`` is the cheap one
   and the one whose relations (equivariance, gt_recall) are checked: its violations are the findings.
   Wall time includes starting the workers (pool processes or actors, each importing lidarfuzz and
   loading the system) and the AP evaluation at the end of each subtask, but not starting Ray itself
   (timed apart: a cluster is started once for many campaigns). The Ray stays up during the pool's
   runs too, so every configuration sees the same background. The driver's CPU per unit is its
   process's CPU time (all its threads) over the whole run, and in steady state (between its first
   and its last committed result, from the runner's progress events) divided by the units.
2. **Per-unit overheads**, each measured directly: (a) the round trip of a no-op actor method call;
   (b) one frame through the object store (``ray.put`` in the driver, then an actor method that takes
   the reference and reads the points), with its size; (c) the store's commit rate, single writer,
   by calling ``_Run.commit`` — the very method the runner calls for every result — on realistic
   results (the campaign's own, made unique by their trial number and input key), against PostgreSQL
   (default, and with the database's ``synchronous_commit = off``) and SQLite; (d) the driver's CPU
   per unit, from the Ray runs, with its parts: reading a frame and ``ray.put`` (per frame), the
   commit (per unit), the rest (dispatch, results, bookkeeping, AP); (e) how ``ray.wait`` — called
   once per result by the executor — grows with the units in flight (2 per actor), which decides
   the driver's cost per unit on a cluster of hundreds of actors.
3. **The model** (docs/scaling.md): throughput and cost of KITTI's val split (3,769 frames × 37
   operators × 5 severities) on 10 and 100 GPU nodes from these figures and the assumptions listed in
   :data:`ASSUMPTIONS`.

``--write-doc`` writes the figures and the model into docs/scaling.md between
``<!-- BEGIN scale-figures -->``/``<!-- END scale-figures -->`` and ``<!-- BEGIN scale-model -->``/
``<!-- END scale-model -->``; the rest of the page is left as it is.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core per worker: the pool or the actors are the parallelism

import argparse  # noqa: E402
import contextlib  # noqa: E402
import dataclasses  # noqa: E402
import functools  # noqa: E402
import hashlib  # noqa: E402
import itertools  # noqa: E402
import pickle  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import socket  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import uuid  # noqa: E402
from collections.abc import Callable, Iterator  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "scaling.md"

OPERATORS = ("rotate_z", "gaussian_noise_addition", "fog", "rain")  # cheap (with 2 relations), noise, weather
SEVERITY = 3

#: The model's assumptions: none of them is measured by this script (see docs/scaling.md).
ASSUMPTIONS: dict[str, Any] = {
    "kitti_frames": 3769,  # KITTI object val split
    "kitti_operators": 37,
    "kitti_severities": 5,
    "kitti_points": 120_000,  # points in a KITTI velodyne frame (about; the object store's bytes scale with it)
    "gpu_ms": 15.0,  # a PointPillars-class detector's GPU time per frame on one modern data-centre GPU
    "detector_cpu_ms": 5.0,  # its CPU side per frame in the actor (voxelisation, copies, NMS)
    "node_gpus": 1,
    "node_cpus": 8,  # one actor per CPU (RayExecutor's default), the GPU shared equally (1/8 each)
    "node_price": 1.20,  # USD per hour, one GPU node (about an on-demand 1-GPU, 8-vCPU cloud instance)
    "head_price": 0.40,  # USD per hour, the head node: driver and PostgreSQL (8 vCPU, no GPU)
    "driver_gbit": 10.0,  # the head node's network, Gbit/s
}


# -- small helpers -----------------------------------------------------------------------------
def median_spread(values: list[float]) -> tuple[float, float, float]:
    """(median, min, max)."""
    return statistics.median(values), min(values), max(values)


def fmt_spread(values: list[float], digits: int = 1) -> str:
    med, low, high = median_spread(values)
    return f"{med:.{digits}f} ({low:.{digits}f}–{high:.{digits}f})"


def load_average() -> str:
    return ", ".join(f"{x:.2f}" for x in os.getloadavg())


def table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table (right-aligned figures: every column but the first)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] + ["---:"] * (len(header) - 1)) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


# -- PostgreSQL --------------------------------------------------------------------------------
def _binary(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    import glob

    candidates = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return candidates[-1] if candidates else None


@contextlib.contextmanager
def postgres_server() -> Iterator[str]:
    """A throwaway PostgreSQL server in a temporary folder (default settings: fsync on), stopped and
    removed at the end; as the ``postgres`` user when this runs as root (PostgreSQL refuses root).

    Raises:
        SystemExit: ``initdb``/``pg_ctl`` (the Debian package postgresql) or ``runuser`` is missing.
    """
    initdb, pg_ctl = _binary("initdb"), _binary("pg_ctl")
    if initdb is None or pg_ctl is None:
        raise SystemExit("benchmarks/scale.py needs PostgreSQL's initdb and pg_ctl (apt-get install postgresql)")
    root = Path(tempfile.mkdtemp(prefix="lf-scale-pg-"))
    data, sockets = root / "data", root / "s"
    sockets.mkdir()
    prefix: list[str] = []
    if os.geteuid() == 0:
        runuser = shutil.which("runuser")
        if runuser is None:
            raise SystemExit("running as root without runuser: cannot start PostgreSQL as its own user")
        prefix = [runuser, "-u", "postgres", "--"]
        shutil.chown(root, "postgres")
        shutil.chown(sockets, "postgres")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    subprocess.run([*prefix, initdb, "-D", str(data), "-A", "trust", "-U", "postgres"],
                   check=True, capture_output=True)
    options = f"-p {port} -k {sockets} -c listen_addresses=''"
    subprocess.run([*prefix, pg_ctl, "-D", str(data), "-o", options, "-w", "start", "-l", str(root / "log")],
                   check=True, capture_output=True)
    try:
        yield f"postgresql+psycopg://postgres@/postgres?host={sockets}&port={port}"
    finally:
        subprocess.run([*prefix, pg_ctl, "-D", str(data), "-m", "fast", "stop"], capture_output=True)
        shutil.rmtree(root, ignore_errors=True)


def new_database(server: str, settings: str = "") -> str:
    """A new empty database on ``server`` (``settings``: e.g. ``synchronous_commit = off``)."""
    from sqlalchemy import create_engine, make_url, text

    name = f"scale_{uuid.uuid4().hex[:10]}"
    admin = create_engine(server, isolation_level="AUTOCOMMIT")
    try:
        with admin.connect() as connection:
            connection.execute(text(f"CREATE DATABASE {name}"))
            if settings:
                connection.execute(text(f"ALTER DATABASE {name} SET {settings}"))
    finally:
        admin.dispose()
    return make_url(server).set(database=name).render_as_string(hide_password=False)


# -- the campaign ------------------------------------------------------------------------------
def campaign_spec(data: Path, frames: int) -> Any:
    from lidarfuzz.campaign.spec import parse_campaign

    return parse_campaign({"dataset": str(data), "sut": "classic", "frames": frames,
                           "operators": [{"name": n, "severities": [SEVERITY]} for n in OPERATORS]})


@dataclass
class RunFigures:
    wall: float
    driver_cpu: float
    units: int
    mutants: int
    stages: dict[str, float] = field(default_factory=dict)  # summed seconds: the workers' stages, store, evaluate
    steady_cpu: float = 0.0  # the driver's CPU per unit between its first and its last committed result
    steady_rate: float = 0.0  # units/s between the first and the last committed result (no start-up)


def run_campaign(url: str, data: Path, frames: int, executor: Any) -> RunFigures:
    """One campaign in the fresh store at ``url`` on ``executor``; the store is planned before the clock starts."""
    from lidarfuzz.campaign.runner import run_task
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.store import Store

    store = Store(url)
    try:
        task_id = create_task(store, campaign_spec(data, frames))
        marks: list[tuple[float, float]] = []  # the driver's CPU time and the clock after each committed result
        cpu, start = time.process_time(), time.perf_counter()
        outcome = run_task(store, task_id, executor=executor,
                           progress=lambda _: marks.append((time.process_time(), time.perf_counter())))
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
        stats = outcome.stats
        if stats.failures or stats.cached or outcome.status.value != "done":
            raise RuntimeError(f"the benchmark campaign did not run cleanly: {outcome.status}, "
                               f"{stats.failures} failures, {stats.cached} cached")
        mutants = stats.units - frames
        stages = {**stats.stages, "store": stats.store, "evaluate": stats.evaluate}
        if len(marks) < 2:
            raise RuntimeError("the benchmark campaign needs 2 or more units (--frames)")
        (cpu0, wall0), (cpu1, wall1) = marks[0], marks[-1]
        return RunFigures(wall, cpu, stats.units, mutants, stages, (cpu1 - cpu0) / (len(marks) - 1),
                          (len(marks) - 1) / (wall1 - wall0))
    finally:
        store.close()


# -- Ray ---------------------------------------------------------------------------------------
class _Probe:
    """A Ray actor that does nothing but answer (the fixed cost of one unit's round trip) or read a frame."""

    def noop(self) -> None:
        return None

    def points(self, scene: Any) -> int:
        return int(scene.points.data.shape[0])

    def block(self, seconds: float) -> None:
        time.sleep(seconds)


def timed(call: Callable[[], object], repeats: int) -> list[float]:
    """Seconds of each of ``repeats`` calls."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return times


@dataclass
class Overheads:
    noop_us: float
    frame_bytes: int
    frame_points: int
    read_ms: float
    put_ms: float
    put_fetch_ms: float  # put + an actor taking the reference and reading the points, round trip
    wait_us: dict[int, float]  # units in flight -> µs per ray.wait(num_returns=1)


def ray_overheads(ray: Any, data: Path) -> Overheads:
    from lidarfuzz.io.kitti import open_kitti

    dataset = open_kitti(data)
    frame_id = next(iter(dataset.frame_ids()))
    read = timed(lambda: dataset.load(frame_id), 20)
    scene = dataset.load(frame_id)
    probe = ray.remote(num_cpus=0)(_Probe).remote()
    try:
        ray.get(probe.noop.remote())
        for _ in range(50):  # warm the connection
            ray.get(probe.noop.remote())
        noop = timed(lambda: ray.get(probe.noop.remote()), 500)
        put = timed(lambda: ray.put(scene), 30)
        ray.get(probe.points.remote(ray.put(scene)))
        fetch = timed(lambda: ray.get(probe.points.remote(ray.put(scene))), 30)
        size = len(pickle.dumps(scene, protocol=5))
        # ray.wait over K pending units plus one finished, as the executor calls it once per result
        waits: dict[int, float] = {}
        blocker = ray.remote(num_cpus=0)(_Probe).remote()
        ray.get(blocker.noop.remote())
        done = probe.noop.remote()
        ray.get(done)
        for pending in (2, 16, 160, 1600):
            refs = [blocker.block.remote(60.0) for _ in range(pending)]
            ray.wait([*refs, done], num_returns=1, timeout=5.0)
            samples = timed(functools.partial(ray.wait, [*refs, done], num_returns=1, timeout=5.0), 30)
            waits[pending] = 1e6 * statistics.median(samples)
            ray.kill(blocker, no_restart=True)
            blocker = ray.remote(num_cpus=0)(_Probe).remote()
            ray.get(blocker.noop.remote())
        ray.kill(blocker, no_restart=True)
    finally:
        ray.kill(probe, no_restart=True)
    return Overheads(1e6 * statistics.median(noop), size, int(scene.points.data.shape[0]),
                     1e3 * statistics.median(read), 1e3 * statistics.median(put),
                     1e3 * statistics.median(fetch), waits)


# -- the store's commit rate -------------------------------------------------------------------
def sample_results(url: str, data: Path, frames: int) -> list[Any]:
    """The campaign's own results (originals, then the mutants with their relations), made by a
    :class:`~lidarfuzz.campaign.work.Worker` in this process on the units the runner plans."""
    from lidarfuzz.campaign.executor import InlineExecutor
    from lidarfuzz.campaign.lifecycle import get_task
    from lidarfuzz.campaign.mutation import _Run
    from lidarfuzz.campaign.plan import ORIGINAL
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.campaign.work import WorkContext, Worker
    from lidarfuzz.store import Store

    store = Store(url)
    try:
        task = get_task(store, create_task(store, campaign_spec(data, frames)))
        run = _Run(store, task, InlineExecutor(), None, None)
        worker = Worker(WorkContext(task.dataset.path, task.model.spec, dict(task.model.options),
                                    task.model.fingerprint))
        try:
            subs = sorted(task.subtasks, key=lambda s: (s.name != ORIGINAL, s.id))
            originals = [worker.run(unit) for unit in run._units(subs[:1], set(), {}, run.frame_ids)]
            sources: dict[str, Any] = {r.unit.frame_id: (r.detections, r.failure is not None, "") for r in originals}
            mutants = [worker.run(unit) for unit in run._units(subs[1:], set(), sources, run.frame_ids)]
        finally:
            worker.close()
            run.close()
        return originals + mutants
    finally:
        store.close()


@dataclass
class CommitFigures:
    wall_ms: list[float]  # per unit, one value per batch
    cpu_ms: list[float]
    findings: float  # findings per unit committed
    evaluate_ms_per_row: float  # the AP evaluation of a subtask (the runner's finish), per stored result


def commit_rate(url: str, data: Path, frames: int, samples: list[Any], count: int, batches: int) -> CommitFigures:
    """``batches`` × ``count`` calls of ``_Run.commit`` (the runner's commit) in a fresh store at ``url``,
    cycling through ``samples`` with each unit made unique (trial) and a fresh input key (a new cache row)."""
    from sqlalchemy import func, select

    from lidarfuzz.campaign.executor import InlineExecutor
    from lidarfuzz.campaign.lifecycle import get_task
    from lidarfuzz.campaign.mutation import _Run
    from lidarfuzz.campaign.plan import subtask_label
    from lidarfuzz.campaign.tasks import create_task
    from lidarfuzz.store import Store
    from lidarfuzz.store.models import Finding

    store = Store(url)
    try:
        task = get_task(store, create_task(store, campaign_spec(data, frames)))
        run = _Run(store, task, InlineExecutor(), None, None)
        subtask_ids = {subtask_label(sub.name, sub.severity): sub.id for sub in task.subtasks}
        walls, cpus = [], []
        serial = 0
        try:
            for _ in range(batches):
                batch = []
                for _ in range(count):
                    template = samples[serial % len(samples)]
                    serial += 1
                    unit = dataclasses.replace(template.unit, trial=serial,
                                               subtask_id=subtask_ids[template.unit.subtask_name])
                    key = hashlib.sha256(f"{template.input_key}|{serial}".encode()).hexdigest()
                    batch.append(dataclasses.replace(template, unit=unit, input_key=key))
                cpu, start = time.process_time(), time.perf_counter()
                for result in batch:
                    if not run.commit(result):
                        raise RuntimeError("a unique unit was refused by the store")
                walls.append(1e3 * (time.perf_counter() - start) / count)
                cpus.append(1e3 * (time.process_time() - cpu) / count)
            # the AP evaluation the runner does as each subtask completes, over many rows (a real campaign's
            # subtask has one per frame): its cost per row, which the few-frame runs above cannot show
            start = time.perf_counter()
            for sub in task.subtasks:
                run.finish(sub)
            evaluate = 1e3 * (time.perf_counter() - start) / serial
        finally:
            run.close()
        with store.session() as s:
            findings = s.scalar(select(func.count()).select_from(Finding)) or 0
        return CommitFigures(walls, cpus, findings / serial, evaluate)
    finally:
        store.close()


# -- the model ---------------------------------------------------------------------------------
@dataclass
class Measured:
    """What the model takes from this run (milliseconds unless named otherwise)."""

    cpu_ms_per_unit: float  # a worker's CPU per unit outside the detector: load, mutate, cache, relations
    driver_unit_ms: float  # the driver's CPU per unit in steady state, its per-frame work and AP taken out
    evaluate_ms: float  # the AP evaluation per unit, on subtasks of many rows
    driver_frame_ms: float  # the driver's CPU per frame: read it and ray.put it
    commit_wall_ms: float  # the store's commit, wall, PostgreSQL default
    commit_cpu_ms: float  # the driver's CPU inside it
    commit_async_wall_ms: float  # the same with synchronous_commit = off
    bytes_per_point: float  # a frame in the object store
    wait_us: dict[int, float]  # ray.wait's cost by units in flight


def wait_cost_us(waits: dict[int, float], in_flight: int) -> float:
    """µs of one ray.wait over ``in_flight`` refs: linear between the measured points, and beyond the
    largest one by the slope of the last two."""
    points = sorted(waits.items())
    for (k0, v0), (k1, v1) in itertools.pairwise(points):
        if in_flight <= k1:
            return v0 + (v1 - v0) * max(0, in_flight - k0) / (k1 - k0)
    (k0, v0), (k1, v1) = points[-2], points[-1]
    return v1 + (v1 - v0) * (in_flight - k1) / (k1 - k0)


@dataclass
class Ceilings:
    """Units per second each part allows on a cluster of ``nodes`` GPU nodes run by ``drivers`` drivers."""

    nodes: int
    drivers: int
    busy: float  # the nodes, all busy
    blocks: float  # the nodes, with the runner's two waits per block of frames (see model())
    driver: float
    store: float
    network: float  # worst case: every node pulls every frame from the driver

    @property
    def rate(self) -> float:
        return min(self.blocks, self.driver, self.store)

    @property
    def limit(self) -> str:
        return min((self.blocks, "the GPU nodes"), (self.driver, "the driver"), (self.store, "the store"))[1]


def node_rate(m: Measured) -> tuple[float, float, float]:
    """(a GPU node's units/s, its GPUs' ceiling, its actors' ceiling)."""
    a = ASSUMPTIONS
    gpu = 1e3 * a["node_gpus"] / a["gpu_ms"]
    # each actor in turn: its CPU work (mutation, relations, the detector's CPU side), then its detection
    actors = 1e3 * a["node_cpus"] / (m.cpu_ms_per_unit + a["detector_cpu_ms"] + a["gpu_ms"])
    return min(gpu, actors), gpu, actors


def ceilings(m: Measured, nodes: int, drivers: int = 1) -> Ceilings:
    """See :func:`model`."""
    from lidarfuzz.campaign.mutation import BLOCK

    a = ASSUMPTIONS
    units_per_frame = 1 + a["kitti_operators"] * a["kitti_severities"]
    in_flight = 2 * nodes * a["node_cpus"] // drivers  # per_actor = 2, the actors shared by the drivers
    driver_ms = (m.driver_unit_ms + m.driver_frame_ms / units_per_frame + m.evaluate_ms
                 + (wait_cost_us(m.wait_us, in_flight) - wait_cost_us(m.wait_us, 2)) / 1e3
                 + (m.commit_wall_ms - m.commit_cpu_ms))  # the commit's wait for the server: the loop waits too
    busy = nodes * node_rate(m)[0]
    # The runner runs a block of frames' originals, waits for them all (their outputs are the mutants'
    # sources), then the block's mutants, and waits for them all: twice per block the cluster drains.
    # Per driver's share of the cluster: the originals take one unit's time, the mutants their share of
    # the work plus one unit's time for the last wave.
    unit_s = (m.cpu_ms_per_unit + a["detector_cpu_ms"] + a["gpu_ms"]) / 1e3
    last_wave_s = a["node_cpus"] / node_rate(m)[0]  # a unit's time on an actor of a busy node
    mutants = BLOCK * (units_per_frame - 1) / drivers
    block_s = unit_s + mutants / (busy / drivers) + last_wave_s
    blocks = drivers * (BLOCK / drivers + mutants) / block_s
    frame_bytes = m.bytes_per_point * a["kitti_points"]
    network = a["driver_gbit"] * 1e9 / 8 * units_per_frame / (nodes * frame_bytes)
    return Ceilings(nodes, drivers, busy, min(busy, blocks), drivers * 1e3 / driver_ms,
                    drivers * 1e3 / m.commit_wall_ms, network)


def model(m: Measured) -> str:
    """The model's table and its conclusions for 10 and 100 GPU nodes (docs/scaling.md states its terms)."""
    a = ASSUMPTIONS
    units = a["kitti_frames"] * (1 + a["kitti_operators"] * a["kitti_severities"])

    def enough_drivers(nodes: int) -> int:
        return next(k for k in range(1, a["kitti_operators"] + 1)
                    if ceilings(m, nodes, k).limit == "the GPU nodes" or k == a["kitti_operators"])

    cases = [(1, 1), (5, 1), (10, 1), (10, enough_drivers(10)), (100, 1), (100, enough_drivers(100))]
    rows = []
    for nodes, drivers in dict.fromkeys(cases):
        c = ceilings(m, nodes, drivers)
        # K tasks started together each detect the originals (none is in the output cache yet)
        hours = (units + (drivers - 1) * a["kitti_frames"]) / c.rate / 3600
        cost = hours * (nodes * a["node_price"] + a["head_price"])
        network = f"{c.network:,.0f}" + (" ⚠" if c.network < c.rate else "")
        rows.append([f"{nodes}", f"{drivers}", f"{c.busy:,.0f}", f"{c.blocks:,.0f}", f"{c.driver:,.0f}",
                     f"{c.store:,.0f}", f"**{c.rate:,.0f}** ({c.limit})",
                     f"{60 * hours:.0f} min" if hours < 2 else f"{hours:.1f} h", f"${cost:,.2f}",
                     network])
    text = table(["GPU nodes", "drivers", "nodes, all busy", "nodes, with block waits", "driver ceiling",
                  "store ceiling", "throughput (units/s)", f"time for {units:,} units", "cost",
                  "network, worst case"], rows)
    rate, gpu, actors = node_rate(m)
    one = ceilings(m, 1)
    driver_nodes = next(n for n in range(1, 100_000) if ceilings(m, n).limit != "the GPU nodes")
    store_nodes = next(n for n in range(1, 100_000) if ceilings(m, n).busy > ceilings(m, n).store)
    node_hours = units / rate / 3600
    notes = [
        f"One GPU node runs {rate:.0f} units/s (its GPU allows {gpu:.0f}/s, its {a['node_cpus']} actors in turn "
        f"{actors:.0f}/s: {'the GPU' if gpu <= actors else 'the actors’ CPU work (mutation, relations)'} is the "
        f"limit), so the campaign is {node_hours:.1f} GPU-node-hours (${node_hours * a['node_price']:.2f}) "
        "whatever the cluster's size, as long as its nodes are kept busy.",
        f"One driver dispatches and commits at most {one.driver:,.0f} units/s ({one.driver / rate:.1f} nodes' "
        f"worth); the store alone, single writer, {one.store:,.0f} units/s "
        f"({1e3 / m.commit_async_wall_ms:,.0f} with synchronous_commit = off).",
        f"With one driver the GPU nodes stop being the bottleneck at {driver_nodes} nodes (then: "
        f"{ceilings(m, driver_nodes).limit}); the store's single-writer rate would be reached at {store_nodes} "
        "nodes."]
    return text + "\n\n" + " ".join(notes)


# -- main --------------------------------------------------------------------------------------
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=16, help="16: one block of the runner")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", default="1,2", help="local pool sizes (the baseline)")
    parser.add_argument("--actors", default="1,2,N", help="Ray actor counts; N: the CPU count")
    parser.add_argument("--commits", type=int, default=200, help="commits per batch (5 batches per store)")
    parser.add_argument("--write-doc", action="store_true", help="write the figures into docs/scaling.md")
    args = parser.parse_args()
    cpus = os.cpu_count() or 1
    pools = [int(w) for w in args.workers.split(",")]
    actor_counts = list(dict.fromkeys(cpus if a.strip() == "N" else int(a) for a in args.actors.split(",")))
    command = "python benchmarks/scale.py " + " ".join(sys.argv[1:])
    load_before = load_average()
    print(f"# {platform.machine()}, {cpus} CPUs (N = {cpus}), load average before: {load_before}", flush=True)

    from lidarfuzz.campaign.cluster import RayExecutor, import_ray
    from lidarfuzz.campaign.executor import ProcessExecutor
    from lidarfuzz.sim.dataset import GenerationConfig, generate_dataset

    ray = import_ray()
    work = Path(tempfile.mkdtemp(prefix="lf-scale-"))
    os.environ["LIDARFUZZ_CACHE"] = str(work / "cache")  # the object library and such: not the user's cache
    try:
        data = work / "data"
        started = time.perf_counter()
        generate_dataset(data, GenerationConfig(frames=args.frames, seed=0), workers=min(2, cpus))
        print(f"generated {args.frames} HDL-64E frames in {time.perf_counter() - started:.1f} s", flush=True)
        with postgres_server() as server:
            started = time.perf_counter()
            ray.init(address="local", num_cpus=cpus, include_dashboard=False, log_to_driver=False,
                     configure_logging=False, object_store_memory=1 << 30)
            ray_start = time.perf_counter() - started
            try:
                figures = measure(args, ray, server, data, pools, actor_counts, RayExecutor, ProcessExecutor)
            finally:
                ray.shutdown()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    load_after = load_average()
    report(args, figures, cpus, pools, actor_counts, ray_start, load_before, load_after, command)


@dataclass
class Figures:
    runs: dict[str, list[RunFigures]]
    overheads: Overheads
    commits: dict[str, CommitFigures]


def measure(args: argparse.Namespace, ray: Any, server: str, data: Path, pools: list[int], actor_counts: list[int],
            ray_executor: Any, process_executor: Any) -> Figures:
    configs: list[tuple[str, Callable[[], Any]]] = []
    for workers in pools:
        configs.append((f"pool {workers}", functools.partial(process_executor, workers)))
    for actors in actor_counts:
        configs.append((f"ray {actors}", functools.partial(ray_executor, None, actors=actors)))
    runs: dict[str, list[RunFigures]] = {name: [] for name, _ in configs}
    for repeat in range(args.repeats):
        for name, make in configs:
            figures = run_campaign(new_database(server), data, args.frames, make())
            runs[name].append(figures)
            print(f"  round {repeat + 1}/{args.repeats} {name}: {figures.wall:.2f} s, "
                  f"{figures.units / figures.wall:.1f} units/s, driver CPU {figures.driver_cpu:.2f} s "
                  f"(load {os.getloadavg()[0]:.2f})", flush=True)
    overheads = ray_overheads(ray, data)
    samples = sample_results(new_database(server), data, args.frames)
    commits = {}
    for name, url in (("PostgreSQL", new_database(server)),
                      ("PostgreSQL, synchronous_commit = off", new_database(server, "synchronous_commit = off")),
                      ("SQLite (WAL, synchronous=NORMAL)", str(data.parent / "sqlite-store"))):
        commits[name] = commit_rate(url, data, args.frames, samples, args.commits, 5)
        print(f"  commits, {name}: {statistics.median(commits[name].wall_ms):.2f} ms/unit", flush=True)
    return Figures(runs, overheads, commits)


def report(args: argparse.Namespace, figures: Figures, cpus: int, pools: list[int], actor_counts: list[int],
           ray_start: float, load_before: str, load_after: str, command: str) -> None:
    runs, o, commits = figures.runs, figures.overheads, figures.commits
    units = runs[next(iter(runs))][0].units
    out: list[str] = []
    out.append(f"*Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} on {platform.machine()} "
               f"({cpus} CPUs, so N = {cpus}; load average {load_before} before, {load_after} after) by "
               f"`{command}`: {args.frames} simulator frames (HDL-64E, {o.frame_points:,} points in the first) × "
               f"(original + {len(OPERATORS)} operators at severity {SEVERITY}: {', '.join(OPERATORS)}) = "
               f"{units} units per run, the classic system, one local PostgreSQL server (fsync on), median of "
               f"{args.repeats} runs (min–max). Starting the local Ray took {ray_start:.1f} s, not counted.*\n")

    rows = []
    for name, values in runs.items():
        kind, size = name.split()
        baseline = runs.get(f"pool {size}")
        rate = [r.units / r.wall for r in values]
        steady_rate = [r.steady_rate for r in values]
        ratio = (f"{statistics.median(rate) / statistics.median([r.units / r.wall for r in baseline]):.2f}× / "
                 f"{statistics.median(steady_rate) / statistics.median([r.steady_rate for r in baseline]):.2f}×"
                 if baseline else "— (no pool of that size)")
        what = f"local pool, {size} process{'es' if size != '1' else ''}" if kind == "pool" else \
            f"Ray, {size} actor{'s' if size != '1' else ''}"
        rows.append([what, fmt_spread([r.wall for r in values], 2), fmt_spread(rate),
                     fmt_spread([r.mutants / r.wall for r in values]), fmt_spread(steady_rate),
                     fmt_spread([1e3 * r.driver_cpu / r.units for r in values], 2),
                     fmt_spread([1e3 * r.steady_cpu for r in values], 2), ratio])
    out.append("**Throughput.** Wall time and the whole run's rates include starting the workers and the AP "
               "evaluation; *steady* is between the first and the last committed result (no start-up), for the "
               "units/s and the driver's CPU per unit alike:\n")
    out.append(table(["executor", "wall (s)", "units/s", "frames × operators/s", "units/s, steady",
                      "driver CPU/unit (ms)", "driver CPU/unit, steady (ms)",
                      "units/s vs the pool of the same size (run / steady)"], rows))

    stage_rows = []
    for name, values in runs.items():
        per = {k: 1e3 * statistics.median([r.stages.get(k, 0.0) / r.units for r in values])
               for k in ("load", "mutate", "cache", "detect", "relations", "store", "evaluate")}
        stage_rows.append([name] + [f"{per[k]:.2f}" for k in per])
    out.append("\nWhere a unit's time goes (ms per unit, summed over workers; store and evaluate are the driver's):\n")
    out.append(table(["executor", "load", "mutate", "cache look-up", "detect", "relations", "store (commit)",
                      "evaluate (AP)"], stage_rows))

    ray_runs = [r for name, values in runs.items() if name.startswith("ray") for r in values]
    steady = statistics.median([1e3 * r.steady_cpu for r in ray_runs])
    units_per_frame = 1 + len(OPERATORS)
    frame_ms = o.read_ms + o.put_ms
    pg = commits["PostgreSQL"]
    commit_cpu = statistics.median(pg.cpu_ms)
    evaluate = statistics.median([1e3 * r.stages.get("evaluate", 0.0) / r.units for r in ray_runs])
    rest = steady - frame_ms / units_per_frame - commit_cpu - evaluate * len(OPERATORS) / (1 + len(OPERATORS))
    out.append("\n**Per-unit overheads**, measured directly:\n")
    overhead_rows = [
        ["(a) scheduling: a no-op actor method, round trip (median of 500)", f"{o.noop_us:,.0f} µs"],
        ["(b) one frame, pickled size", f"{o.frame_bytes / 1e6:.2f} MB ({o.frame_points:,} points)"],
        ["(b) `ray.put` of one frame (median of 30)", f"{o.put_ms:.2f} ms"],
        ["(b) `ray.put` + an actor takes the reference and reads the points, round trip", f"{o.put_fetch_ms:.2f} ms"],
        ["(d) reading one frame from disk in the driver", f"{o.read_ms:.2f} ms"],
    ]
    for pending, us in o.wait_us.items():
        overhead_rows.append([f"(e) `ray.wait(num_returns=1)` over {pending:,} units in flight + 1 done",
                              f"{us:,.0f} µs"])
    out.append(table(["what", "cost"], overhead_rows))
    commit_rows = []
    for name, c in commits.items():
        wall = statistics.median(c.wall_ms)
        commit_rows.append([name, f"{1e3 / wall:,.0f}", fmt_spread(c.wall_ms, 2), fmt_spread(c.cpu_ms, 2),
                            f"{c.findings:.2f}"])
    out.append(f"\n(c) The store's commit, single writer: `_Run.commit` (the runner's own method) on the campaign's "
               f"own results, {args.commits} commits × 5 batches per store (median of the batches):\n")
    out.append(table(["store", "units/s", "wall ms/unit", "driver CPU ms/unit", "findings per unit"], commit_rows))
    out.append(f"\n(d) The driver's CPU per unit in the Ray runs, steady state: **{steady:.2f} ms** (median over "
               f"all Ray runs) ≈ reading and putting the frame {frame_ms:.2f} ms / {units_per_frame} units per frame "
               f"({frame_ms / units_per_frame:.2f}) + the commit's CPU {commit_cpu:.2f} (c) + the AP evaluation of "
               f"the {len(OPERATORS)} subtasks that finish before the last result "
               f"({evaluate * len(OPERATORS) / (1 + len(OPERATORS)):.2f}: {args.frames} rows each; on subtasks of "
               f"{args.commits} rows, as in (c), it costs {pg.evaluate_ms_per_row:.2f} ms per row) + the rest "
               f"(submitting, waiting, taking the results, ordering, progress) {rest:.2f}.")
    figures_md = "\n".join(out)
    print("\n" + figures_md)

    cpu_stages = statistics.median([1e3 * sum(r.stages.get(k, 0.0) for k in ("load", "mutate", "cache", "relations"))
                                    / r.units for r in ray_runs])
    subtasks = 1 + len(OPERATORS)  # the last subtask's AP comes after the last committed result
    measured = Measured(cpu_ms_per_unit=cpu_stages,
                        driver_unit_ms=steady - frame_ms / units_per_frame - evaluate * (subtasks - 1) / subtasks,
                        evaluate_ms=pg.evaluate_ms_per_row,
                        driver_frame_ms=frame_ms, commit_wall_ms=statistics.median(pg.wall_ms),
                        commit_cpu_ms=commit_cpu,
                        commit_async_wall_ms=statistics.median(commits["PostgreSQL, synchronous_commit = off"].wall_ms),
                        bytes_per_point=o.frame_bytes / o.frame_points, wait_us=o.wait_us)
    inputs = (f"Measured inputs (above): a worker's CPU per unit outside the detector (load, mutate, cache look-up, "
              f"relations; {o.frame_points:,}-point frames, the 4 operators' mean) **{cpu_stages:.1f} ms**; the "
              f"driver's CPU per unit in steady state {measured.driver_unit_ms:.2f} ms (AP evaluation apart) plus "
              f"{frame_ms:.2f} ms per frame and {measured.evaluate_ms:.2f} ms per unit of AP evaluation; "
              f"the commit {measured.commit_wall_ms:.2f} ms wall, {commit_cpu:.2f} ms of it the driver's CPU; "
              f"`ray.wait` as in (e), 2 units in flight per actor; {measured.bytes_per_point:.0f} bytes per point in "
              "the object store. Assumptions (not measured here): "
              + ", ".join(f"{k} = {v}" for k, v in ASSUMPTIONS.items()) + ".")
    model_md = f"{inputs}\n\n{model(measured)}"
    print("\n" + model_md)
    if args.write_doc:
        if str(ROOT) not in sys.path:  # run as a script: this package importable
            sys.path.insert(0, str(ROOT))
        from benchmarks.reliability_doc import write_section

        write_section("scale-figures", figures_md, DOC, title="# Campaigns on a cluster")
        write_section("scale-model", model_md, DOC, title="# Campaigns on a cluster")
        print(f"\nwrote {DOC.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
