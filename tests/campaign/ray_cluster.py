"""A Ray cluster on this machine for the cluster tests (``test_ray.py``): a head node with no CPU
(so that no system actor runs beside the driver's connection) and two worker nodes of one CPU
each, started and stopped by the tests themselves, with a way to kill one worker node mid-run
(its raylet and every process on it, as a lost machine would) and to add it back.

Every Ray process started here is stopped at the end by :meth:`LocalRayCluster.shutdown`, never
by ``ray stop``, which would stop every Ray of this machine (other people's too).

Use the fixtures ``ray_cluster`` (one per module) and ``ray_nodes`` (it, with both worker nodes up)
by importing them into a test module::

    from tests.campaign.ray_cluster import ray_cluster_fixture, ray_nodes_fixture  # noqa: F401
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.requirements import missing

ROOT = Path(__file__).resolve().parents[2]
#: Worker nodes of the cluster, and CPUs each (one system actor per CPU).
WORKERS = 2
CPUS_PER_WORKER = 1
#: Seconds to wait for the cluster's resources to show a node gone or back.
SETTLE_SECONDS = 60.0


def import_ray_or_skip() -> Any:
    """The ``ray`` module; skips (fails under CI) when it is not installed."""
    try:
        import ray
    except ImportError:
        missing("Ray is not installed", "the ray extra (pip install 'lidarfuzz[ray]')")
    return ray


class LocalRayCluster:
    """A head node (0 CPUs) and ``workers`` worker nodes of ``cpus`` CPUs each, on this machine.

    The worker processes Ray starts inherit this process's environment when the nodes start:
    ``PYTHONPATH`` then names the repository, so that actors import the test systems
    (``tests.campaign.systems:…``) as the driver does.
    """

    def __init__(self, workers: int = WORKERS, cpus: int = CPUS_PER_WORKER) -> None:
        self.workers = workers
        self.cpus = cpus
        self._cluster: Any = None

    @property
    def address(self) -> str:
        """The head's address, for ``RayExecutor(address)`` and ``--address``."""
        if self._cluster is None:
            raise RuntimeError("the cluster is not started")
        return str(self._cluster.address)

    @property
    def nodes(self) -> int:
        """Worker nodes running now."""
        return len(self._cluster.worker_nodes) if self._cluster is not None else 0

    def start(self) -> None:
        import_ray_or_skip()
        from ray.cluster_utils import Cluster

        with _environment(PYTHONPATH=_python_path()):
            self._cluster = Cluster(initialize_head=True,
                                    head_node_args={"num_cpus": 0, "include_dashboard": False})
            try:
                for _ in range(self.workers):
                    self._cluster.add_node(num_cpus=self.cpus)
                self._cluster.wait_for_nodes()
                self.restore()
            except BaseException:
                self.shutdown()
                raise

    def kill_worker(self) -> None:
        """Kill one worker node at once (SIGKILL to its raylet and its workers: its actors die)."""
        ray = import_ray_or_skip()

        connected = ray._private.worker.global_worker.node if ray.is_initialized() else None
        mine = connected._raylet_socket_name if connected is not None else None
        # never the node this process's driver talks to (Ray refuses that: it would break the driver)
        victims = sorted((node for node in self._cluster.worker_nodes if node._raylet_socket_name != mine),
                         key=lambda node: node._raylet_socket_name)
        if not victims:
            raise RuntimeError("no worker node left to kill")
        self._cluster.remove_node(victims[0], allow_graceful=False)

    def add_worker(self) -> None:
        """Start one more worker node."""
        with _environment(PYTHONPATH=_python_path()):
            self._cluster.add_node(num_cpus=self.cpus)  # waits for it to register (restore() for the rest)

    def restore(self) -> None:
        """Back to ``workers`` live worker nodes, as the head sees them: a killed node counted dead
        (the head notices a lost node by missed health checks, 10-30 s after it went) and the new
        ones counted alive, with their CPUs."""
        while self.nodes < self.workers:
            self.add_worker()
        expected = {self._cluster.head_node.node_id, *(node.node_id for node in self._cluster.worker_nodes)}
        with self._driver() as ray:
            deadline = time.monotonic() + SETTLE_SECONDS
            while ((alive := {n["NodeID"] for n in ray.nodes() if n["Alive"]}) != expected
                   or float(ray.cluster_resources().get("CPU", 0.0)) != self.workers * self.cpus):
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the local Ray cluster has nodes {sorted(alive)} after "
                                       f"{SETTLE_SECONDS:g} s, not {sorted(expected)}")
                time.sleep(0.2)

    @contextlib.contextmanager
    def _driver(self) -> Iterator[Any]:
        """``ray``, connected to this cluster for the block (the test's own connection if it has one)."""
        ray = import_ray_or_skip()
        connected = ray.is_initialized()
        if not connected:
            ray.init(address=self.address, include_dashboard=False, log_to_driver=False, configure_logging=False)
        try:
            yield ray
        finally:
            if not connected:
                ray.shutdown()

    def shutdown(self) -> None:
        """Stop every process of this cluster (its nodes only: other Rays of this machine run on)."""
        ray = import_ray_or_skip()
        if ray.is_initialized():  # a driver connection left by a test: it would outlive the cluster
            ray.shutdown()
        if self._cluster is not None:
            self._cluster.shutdown()
            self._cluster = None


def _python_path() -> str:
    """``PYTHONPATH`` with the repository first (the test systems importable in Ray's workers)."""
    return os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)


@contextlib.contextmanager
def _environment(**values: str) -> Iterator[None]:
    """``os.environ`` with ``values`` for the block (the nodes started in it inherit them)."""
    before = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@pytest.fixture(scope="module", name="ray_cluster")
def ray_cluster_fixture() -> Iterator[LocalRayCluster]:
    """A local Ray cluster shared by a module's tests; each test gets it with two live worker nodes
    (use :func:`ray_nodes`, which adds back a node a test killed)."""
    cluster = LocalRayCluster()
    cluster.start()
    try:
        yield cluster
    finally:
        cluster.shutdown()


@pytest.fixture(name="ray_nodes")
def ray_nodes_fixture(ray_cluster: LocalRayCluster) -> Iterator[LocalRayCluster]:
    """The module's cluster with its two worker nodes live (a node an earlier test killed is added
    back first: not after that test, where waiting for the head to count it dead would cost 10-30 s
    for nothing when no test follows); no driver connection of the test outlives it."""
    ray_cluster.restore()
    try:
        yield ray_cluster
    finally:
        ray = import_ray_or_skip()
        if ray.is_initialized():
            ray.shutdown()
