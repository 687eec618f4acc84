"""Threads of the BLAS/OpenMP libraries in worker processes.

numpy's OpenBLAS starts one thread per core in every process that loads it. A pool of k
worker processes on k cores then runs k x k BLAS threads, and OpenBLAS threads that wait
for work spin. On this project's 2-core machine (2026-11-28, numpy 2.4.6 with OpenBLAS
0.3.31) the realistic discovery bench, two workers, seed 301511, Bouc-Wen truth, had not
finished after 18 minutes alone; with one thread per worker it took 504 s. One process alone
gains nothing from a second thread there (one case's discovery: 7.4 s with two, 7.0 s
with one). Every pool of
processes that each do numpy work therefore limits each worker to one BLAS thread, at its
start (:func:`one_blas_thread` as the pool's initializer, or on a Dask worker by
:mod:`cablesvc.batch.worker_setup`).
"""

from __future__ import annotations

__all__ = ["THREAD_VARS", "blas_threads", "one_blas_thread"]

#: the environment variables the BLAS/OpenMP libraries read for their thread count when they load
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """Limit the BLAS/OpenMP libraries loaded in this process to one thread each, and those
    it loads later (the environment variables they read when they load). A worker forked
    from a process that already loaded numpy inherits its library with one thread per core
    (an ``OMP_NUM_THREADS=1`` set afterwards is not read), a spawned worker loads it anew:
    run once on every worker, either way."""
    import os
    for var in THREAD_VARS:
        os.environ[var] = "1"
    from threadpoolctl import threadpool_limits
    threadpool_limits(limits=1)


def blas_threads() -> int:
    """The most threads any BLAS/OpenMP library loaded in this process would use (0: none
    loaded); the fleet runner reports it per worker."""
    from threadpoolctl import threadpool_info
    return max((int(i.get("num_threads", 0)) for i in threadpool_info()), default=0)
