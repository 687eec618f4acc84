"""Run a fleet job: serially in this process, or on Dask distributed.

:func:`run_fleet` runs one job per recording (:mod:`cablesvc.batch.jobs`) and returns a
:class:`FleetResult`: the rows in the order of the recordings, the fleet summary
(:mod:`cablesvc.batch.summary`) and what ran it.

On Dask (the default) the work goes to a ``LocalCluster`` started here (``workers``
worker processes of one thread each, bound to 127.0.0.1, no dashboard) or, with
``scheduler="tcp://host:8786"``, to an existing cluster's workers. Each task carries a
recording's absolute path and the options dict in, and one row (a few kB) out: every
worker reads its recording itself (from a filesystem that all workers share on a real
cluster, docs/cluster.md), so nothing large goes through the scheduler. A task whose
worker dies (out of memory, killed) is retried by Dask and then reported as a failed row
like any other failure. Before submitting, every worker's cablesvc version is checked
against this one: a mixed cluster would not give the serial run's numbers.

Rows are the same numbers whichever way they ran (serial, any number of workers): the
jobs are deterministic functions of the file and the options; only ``seconds`` and
``cpu_seconds`` differ (:func:`comparable` leaves them out).
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

from cablesvc.batch.jobs import JOBS, blas_threads, import_job_modules, worker_version
from cablesvc.errors import BatchError

__all__ = ["FleetEngineError", "FleetResult", "comparable", "run_fleet", "run_on_dask", "run_serial",
           "DEFAULT_WORKERS"]

#: LocalCluster worker processes when --workers is not given
DEFAULT_WORKERS = 2
#: seconds to wait for an existing cluster's first worker
WAIT_FOR_WORKERS_S = 60.0

Progress = Optional[Callable[[int, int, dict], None]]
#: fields that differ between two runs of the same job (left out of comparisons)
TIMING_FIELDS = ("seconds", "cpu_seconds")


class FleetEngineError(BatchError, RuntimeError):
    """The cluster cannot run the job: scheduler unreachable, no worker, version mismatch."""


@dataclass
class FleetResult:
    """What :func:`run_fleet` returns; :meth:`to_json` is the fleet JSON (docs/cluster.md)."""

    command: str
    rows: list[dict[str, Any]]
    summary: dict[str, Any]
    engine: dict[str, Any]
    seconds: float
    options: dict[str, Any] = field(default_factory=dict)

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["status"] != "ok"]

    def to_json(self) -> dict[str, Any]:
        return {"command": self.command, "recordings": len(self.rows), "ok": len(self.rows) - len(self.failed),
                "failed": len(self.failed), "engine": self.engine, "seconds": self.seconds,
                "options": self.options, "summary": self.summary, "rows": self.rows}


def comparable(rows: Sequence[dict[str, Any]]) -> str:
    """Canonical JSON of ``rows`` without the timing fields: equal strings = same numbers."""
    return json.dumps([{k: v for k, v in r.items() if k not in TIMING_FIELDS} for r in rows], sort_keys=True)


def _label(row: dict[str, Any], given: str) -> dict[str, Any]:
    row = dict(row)
    row["recording"] = given
    return row


def run_serial(command: str, paths: Sequence[str], opts: dict[str, Any], progress: Progress = None) -> list[dict]:
    """The rows of ``command`` over ``paths``, one after the other in this process."""
    job = JOBS[command]
    rows = []
    for i, p in enumerate(paths):
        rows.append(_label(job(os.path.abspath(p), opts), p))
        if progress:
            progress(i + 1, len(paths), rows[-1])
    return rows


def _client(scheduler: Optional[str], workers: int, memory_limit: Any, command: str):
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as e:
            raise FleetEngineError(f"--scheduler {scheduler}: cannot connect: {e}") from None
        return client, None
    if workers < 1:
        raise FleetEngineError(f"--workers: expected at least 1, got {workers}")
    import dask
    # Dask's nanny gives its workers MALLOC_TRIM_THRESHOLD_=65536: glibc then hands freed
    # memory back at once and page-faults it in again, which made one discovery take 1.6 x
    # the CPU time of the serial run here; the workers keep glibc's defaults instead (the
    # BLAS thread variables stay: one thread per worker)
    env = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
           if k != "MALLOC_TRIM_THRESHOLD_"}
    # Dask's statistical profiler samples every worker thread's stack every 10 ms for its
    # dashboard (which this cluster does not serve); the jobs are long pure-Python/numpy
    # loops, and measured here it cost the workers about a tenth more CPU per discovery.
    # Worker saturation 1.0: the scheduler hands a one-thread worker its next recording only
    # when the last is done. With Dask's default 1.1 (ceil: two per worker) a worker could
    # hold a second recording at the end of the run while the other worker had nothing left
    # to do, and one job of several seconds then ran alone.
    # On Linux the nannies fork their workers from this process (Dask's default is spawn),
    # after the job's modules are imported here: a spawned worker imports numpy, scipy and
    # cablesvc again before its first recording, about 1.2 s of CPU each and 0.7 s more
    # cluster start, measured on the 2-core bench machine. fork is not safe on macOS, so
    # elsewhere Dask's setting stays.
    cfg = {"distributed.nanny.pre-spawn-environ": env, "distributed.worker.profile.enabled": False,
           "distributed.scheduler.worker-saturation": 1.0}
    forked = sys.platform.startswith("linux")
    if forked:
        import_job_modules(command)
        cfg["distributed.worker.multiprocessing-method"] = "fork"
    with dask.config.set(cfg):
        # no dashboard; the scheduler's small HTTP server (health, metrics) on a free loopback port
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None, silence_logs=logging.ERROR, memory_limit=memory_limit,
                               scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
    client = Client(cluster)
    if forked:
        # a plugin, not a one-off client.run: a worker that the nanny restarts gets it too
        from cablesvc.batch.worker_setup import OneBlasThread
        client.register_plugin(OneBlasThread())
    return client, cluster


def run_on_dask(command: str, paths: Sequence[str], opts: dict[str, Any], *, scheduler: Optional[str] = None,
                workers: int = DEFAULT_WORKERS, progress: Progress = None,
                memory_limit: Any = "auto") -> tuple[list[dict], dict[str, Any]]:
    """The rows of ``command`` over ``paths`` on Dask (module docstring) and the engine
    description (``scheduler``, ``workers``, ``threads``, ``blas_threads_per_worker``, ``dask``,
    ``start_seconds``)."""
    import dask
    from dask.distributed import as_completed

    t0 = time.perf_counter()
    client, cluster = _client(scheduler, workers, memory_limit, command)
    try:
        try:
            client.wait_for_workers(1, timeout=WAIT_FOR_WORKERS_S)
        except TimeoutError:
            raise FleetEngineError(f"no worker joined the scheduler {client.scheduler.address} within "
                                   f"{WAIT_FOR_WORKERS_S:g} s (start them with: dask worker ADDRESS)") from None
        mine = worker_version()
        try:
            versions = client.run(worker_version)
        except Exception as e:            # cablesvc not importable on a worker
            raise FleetEngineError(f"cannot run cablesvc on the workers ({type(e).__name__}: {e}); install the "
                                   f"same cablesvc ({mine}) on every worker") from None
        other = {w: v for w, v in versions.items() if v != mine}
        if other:
            raise FleetEngineError("workers run another cablesvc version than this one (" + mine + "): "
                                   + ", ".join(f"{w}: {v}" for w, v in sorted(other.items())))
        nthreads = client.nthreads()
        engine = {"engine": "dask.distributed", "dask": dask.__version__,
                  "scheduler": scheduler or "LocalCluster", "address": client.scheduler.address,
                  "workers": len(nthreads), "threads": int(sum(nthreads.values())),
                  "blas_threads_per_worker": max(client.run(blas_threads).values()),
                  "start_seconds": time.perf_counter() - t0}
        job = JOBS[command]
        futs = [client.submit(job, os.path.abspath(p), opts, pure=False) for p in paths]
        index = {f.key: i for i, f in enumerate(futs)}
        rows: list[Optional[dict]] = [None] * len(paths)
        done = 0
        for fut in as_completed(futs):
            i = index[fut.key]
            if fut.status == "finished":
                rows[i] = _label(fut.result(), paths[i])
            else:                          # the task itself failed: its worker died, or it was cancelled
                exc = fut.exception() if fut.status == "error" else None
                rows[i] = {"recording": paths[i], "status": "failed",
                           "error": f"{type(exc).__name__}: {exc}" if exc is not None else f"task {fut.status}",
                           "robot": None, "start_time": None, "start_source": None, "ticks": None,
                           "duration_s": None, "seconds": None, "cpu_seconds": None}
            fut.release()
            done += 1
            if progress:
                progress(done, len(paths), rows[i])
        return [r for r in rows if r is not None], engine
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_fleet(command: str, paths: Sequence[str], opts: dict[str, Any], *, scheduler: Optional[str] = None,
              workers: int = DEFAULT_WORKERS, serial: bool = False, progress: Progress = None,
              memory_limit: Any = "auto") -> FleetResult:
    """Run ``command`` (``"discover"`` or ``"identify"``) on every recording in ``paths``
    with ``opts`` (see :mod:`cablesvc.batch.jobs`); ``serial``: in this process without
    Dask. Raises :class:`FleetEngineError` when the cluster cannot run it."""
    from cablesvc.batch.summary import fleet_summary

    if command not in JOBS:
        raise ValueError(f"unknown fleet command {command!r}")
    t0 = time.perf_counter()
    if serial:
        rows = run_serial(command, paths, opts, progress)
        engine = {"engine": "serial", "workers": 1, "threads": 1}
    else:
        rows, engine = run_on_dask(command, paths, opts, scheduler=scheduler, workers=workers, progress=progress,
                                   memory_limit=memory_limit)
    return FleetResult(command=command, rows=rows, summary=fleet_summary(command, rows), engine=engine,
                       seconds=time.perf_counter() - t0, options=dict(opts))
