"""Worker pools limit each process to one BLAS thread (cablesvc.threads): k processes on k
cores that each start one OpenBLAS thread per core spin against each other."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from cablesvc.threads import THREAD_VARS, blas_threads


@pytest.fixture
def unlimited_children(monkeypatch):
    """The test's processes start without the one-thread variables the suite's own workers
    set (tests/conftest.py): a spawned child would inherit them and run one thread whatever
    the pool under test does."""
    for var in THREAD_VARS:
        monkeypatch.delenv(var, raising=False)


def _threads(_x=None) -> int:
    import numpy  # noqa: F401  (a spawned worker loads its BLAS here)
    return blas_threads()


def test_the_discovery_benchs_workers_run_one_blas_thread_each(unlimited_children):
    from cablesvc.bench.discover import worker_pool
    with worker_pool(2) as pool:
        got = [f.result() for f in [pool.submit(_threads) for _ in range(4)]]
    assert got == [1, 1, 1, 1]


def test_the_swarms_worker_processes_run_one_blas_thread_each(unlimited_children):
    from cablesvc.identify.pso import _Evaluator
    ev = _Evaluator(_threads, 2)
    try:
        got = [f.result() for f in [ev.pool.submit(_threads) for _ in range(4)]]
    finally:
        ev.close()
    assert got == [1, 1, 1, 1]


_PROBE = """
import json, os
import numpy as np
from cablesvc.threads import blas_threads, one_blas_thread
np.ones(3) @ np.ones(3)
before = blas_threads()
one_blas_thread()
print(json.dumps({"before": before, "after": blas_threads(),
                  "env": os.environ.get("OPENBLAS_NUM_THREADS")}))
"""


def test_one_blas_thread_limits_this_process_and_what_it_loads_later(unlimited_children):
    # in a fresh interpreter: this one's BLAS may already have been limited at its start
    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: OpenBLAS starts one thread anyway")
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["before"] > 1         # the default the limit is there for
    assert got["after"] == 1
    assert got["env"] == "1"
