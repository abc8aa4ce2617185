"""Pool workers run one BLAS thread (issue 25).

A spawned worker imports numpy before its initializer runs, and OpenBLAS sizes its thread pool
when it loads: limits set in the initializer came too late, so each worker ran a BLAS thread per
core on top of the pool's own parallelism. The executor now starts its workers with the limits
in the environment they inherit; here a real worker is asked what its OpenBLAS runs.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from lidarfuzz.campaign.executor import THREAD_LIMIT_VARIABLES, ProcessExecutor
from lidarfuzz.campaign.work import WorkContext


def openblas_threads() -> int:
    """The thread count of the OpenBLAS numpy is linked to, asked through its own C API
    (``openblas_get_num_threads``; numpy's wheels bundle it as ``scipy_openblas``, with the
    64-bit-integer interface's suffix)."""
    np.ones((4, 4)) @ np.ones((4, 4))  # make sure the library is loaded and initialised
    libraries = Path(np.__file__).resolve().parent.parent / "numpy.libs"
    candidates = sorted(libraries.glob("libscipy_openblas*.so*")) if libraries.is_dir() else []
    for path in candidates:
        library = ctypes.CDLL(str(path))
        for symbol in ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
                       "openblas_get_num_threads64_", "openblas_get_num_threads"):
            function = getattr(library, symbol, None)
            if function is not None:
                function.restype = ctypes.c_int
                return int(function())
    from threadpoolctl import threadpool_info  # a numpy built against a system BLAS

    pools = [pool for pool in threadpool_info() if pool["user_api"] == "blas"]
    assert pools, "numpy's BLAS library was not found"
    return int(pools[0]["num_threads"])


def worker_report() -> tuple[int, dict[str, str | None]]:
    """Run in a pool worker: its BLAS thread count and its thread-limit variables."""
    return openblas_threads(), {variable: os.environ.get(variable) for variable in THREAD_LIMIT_VARIABLES}


@pytest.fixture
def without_thread_limits(monkeypatch: pytest.MonkeyPatch) -> None:
    """The parent as a user's shell starts it: no thread limits (the CI may have set some)."""
    for variable in THREAD_LIMIT_VARIABLES:
        monkeypatch.delenv(variable, raising=False)


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="OpenBLAS runs one thread on one core anyway")
def test_pool_workers_run_one_blas_thread(tmp_path: Path, without_thread_limits: None) -> None:
    before = dict(os.environ)
    executor = ProcessExecutor(2)
    # the data set need not exist: a worker that cannot open it stays up (and answers data faults)
    executor.open(WorkContext(str(tmp_path / "no-data"), "classic", {}, ""))
    try:
        assert executor._pool is not None
        reports = [executor._pool.submit(worker_report).result(timeout=120) for _ in range(4)]
    finally:
        executor.close()
    for threads, environment in reports:
        assert threads == 1
        assert environment == dict.fromkeys(THREAD_LIMIT_VARIABLES, "1")
    assert dict(os.environ) == before, "the parent's environment changed"


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="OpenBLAS runs one thread on one core anyway")
def test_a_process_spawned_without_the_limits_runs_more(without_thread_limits: None) -> None:
    """The check above can fail: a spawned process that inherits no limits (what every pool
    worker was before the fix) runs OpenBLAS with a thread per core."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=context) as pool:
        threads, _ = pool.submit(worker_report).result(timeout=120)
    assert threads > 1
