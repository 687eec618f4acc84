"""Worker pools limit each process to one BLAS thread (cablesvc.threads): k processes on k
cores that each start one OpenBLAS thread per core spin against each other."""

from __future__ import annotations

import os

import numpy as np

from cablesvc.threads import blas_threads, one_blas_thread


def _threads(_x=None) -> int:
    import numpy  # noqa: F401  (a spawned worker loads its BLAS here)
    return blas_threads()


def test_the_discovery_benchs_workers_run_one_blas_thread_each():
    from cablesvc.bench.discover import worker_pool
    with worker_pool(2) as pool:
        got = [f.result() for f in [pool.submit(_threads) for _ in range(4)]]
    assert got == [1, 1, 1, 1]


def test_the_swarms_worker_processes_run_one_blas_thread_each():
    from cablesvc.identify.pso import _Evaluator
    ev = _Evaluator(_threads, 2)
    try:
        got = [f.result() for f in [ev.pool.submit(_threads) for _ in range(4)]]
    finally:
        ev.close()
    assert got == [1, 1, 1, 1]


def test_one_blas_thread_limits_this_process_and_what_it_loads_later(monkeypatch):
    from threadpoolctl import threadpool_limits
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(var, raising=False)
    np.ones(3) @ np.ones(3)
    with threadpool_limits(limits=None):
        one_blas_thread()
        assert blas_threads() == 1
        assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
