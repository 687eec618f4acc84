"""One recording's job: what a Dask worker (or the serial loop) runs for each recording.

A job gets a recording's *path* and a small dict of options, reads the recording itself,
runs :func:`cablesvc.discover.discover` or :func:`cablesvc.identify.cable.identify_cable`
on it and returns one *row*: a plain JSON-able dict (a few kB). Nothing large travels: the
scheduler carries the path in and the row out, never the recording's arrays.

A job never raises: whatever goes wrong (an unreadable or corrupt file, a recording of
another robot, too short for a held-out split, a fit that fails) becomes a row with
``status = "failed"`` and ``error`` naming the exception and its message, so the fleet's
other recordings finish.

Every row has ``recording`` (the path), ``status`` (``"ok"`` / ``"failed"``), ``error``,
``robot``, ``start_time`` (ISO 8601, UTC) with ``start_source`` (how it was known, see
:func:`recording_start`), ``ticks``, ``duration_s``, ``seconds`` and ``cpu_seconds`` (the job's wall and CPU time
in its process: the only fields that differ between two runs of the same job). A discover row adds
``verdict``, ``findings`` (term, label, cables, p_value), ``recalibrated`` (the cables whose
baseline was recalibrated: the cable no longer matches its parameter file),
``unexplained``, ``detection`` (per term not named: its least floor and limit over the
cables, :mod:`cablesvc.discover.detectability`; identified mode), ``rmse_test_before`` /
``rmse_test_after`` and ``discovery`` (the whole JSON of ``cablesvc discover --json``). An identify row adds ``model``, ``method``,
``cables``, ``names``, ``parameters`` (per fitted cable the values and standard errors),
``rmse``, ``notes`` and ``params_toml`` (the parameter file ``--out`` would write).
"""

from __future__ import annotations

import json
import math
import os
import time
from datetime import datetime, timezone
from typing import Any, Callable

from cablesvc.threads import blas_threads, one_blas_thread

__all__ = ["JOBS", "JOB_MODULES", "START_TIME_KEY", "blas_threads", "discover_job", "identify_job", "import_job_modules",
           "one_blas_thread", "recording_start", "worker_version"]

#: recording metadata key holding the wall-clock time of the first tick (ISO 8601 or Unix seconds)
START_TIME_KEY = "start_time"


def worker_version() -> str:
    """The cablesvc version where this runs (the fleet runner compares every worker's)."""
    from cablesvc import __version__
    return __version__


def _iso(ts: float) -> str:
    return datetime.fromtimestamp(ts, timezone.utc).isoformat(timespec="seconds")


def recording_start(path: str, rec: Any) -> tuple[str, str]:
    """``(start_time, start_source)`` of a recording: the wall-clock time of its first tick
    as ISO 8601 in UTC. From the metadata key ``start_time`` (ISO 8601, or Unix seconds)
    when the recording has one (``start_source = "metadata"``); otherwise the file's
    modification time less the recording's duration (``"file mtime - duration"``: a log
    file is last written at its last tick). The controller clock ``t`` is not a wall clock
    (it may start at 0 every run), so it is not used."""
    raw = (getattr(rec, "metadata", None) or {}).get(START_TIME_KEY)
    note = ""
    if raw is not None:
        try:
            ts = float(raw)
        except ValueError:
            try:
                dt = datetime.fromisoformat(str(raw).strip())
                if dt.tzinfo is None:
                    dt = dt.replace(tzinfo=timezone.utc)
                ts = dt.timestamp()
            except ValueError:
                ts = float("nan")
        if math.isfinite(ts):
            return _iso(ts), "metadata"
        note = f" (metadata {START_TIME_KEY} {raw!r} is not a time)"
    dur = float(rec.t[-1] - rec.t[0]) if len(rec.t) else 0.0
    return _iso(os.path.getmtime(path) - dur), "file mtime - duration" + note


def _plain(doc: Any) -> Any:
    """A JSON round trip: numpy scalars and arrays become plain floats and lists."""
    return json.loads(json.dumps(doc, default=_default))


def _default(o: Any) -> Any:
    import numpy as np
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.integer,)):
        return int(o)
    return float(o)


def _start_row(path: str) -> dict[str, Any]:
    return {"recording": path, "status": "failed", "error": None, "robot": None, "start_time": None,
            "start_source": None, "ticks": None, "duration_s": None}


def _read(path: str, row: dict[str, Any], robot_opt: str | None):
    from cablesvc.config.robot import load_robot
    from cablesvc.recording import read_recording

    rec = read_recording(path)
    row["ticks"] = int(len(rec.t))
    row["duration_s"] = float(rec.t[-1] - rec.t[0]) if len(rec.t) else 0.0
    row["start_time"], row["start_source"] = recording_start(path, rec)
    name = robot_opt or rec.robot
    if not name:
        raise ValueError("the recording names no robot; give --robot")
    row["robot"] = name
    rob = load_robot(name)
    row["robot"] = rob.name
    return rec, rob


_MALLOC_TUNED = False


def _tune_malloc() -> None:
    """On a worker that Dask's nanny started with ``MALLOC_TRIM_THRESHOLD_=65536`` (an
    existing cluster's ``dask worker``): raise glibc's trim threshold to 256 MiB and serve
    blocks below 32 MiB from the heap, so the large numpy temporaries of a discovery are
    not returned to the system and page-faulted in again on every call (measured: one
    60 s discovery took 4.5 s of CPU with Dask's setting, 3.0 s with these, 2.7 s with
    glibc's defaults, which the LocalCluster's workers keep). Only glibc; elsewhere nothing."""
    global _MALLOC_TUNED
    if _MALLOC_TUNED or os.environ.get("MALLOC_TRIM_THRESHOLD_") != "65536":
        return
    _MALLOC_TUNED = True
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-1, 256 * 1024 * 1024)          # M_TRIM_THRESHOLD
        libc.mallopt(-3, 32 * 1024 * 1024)           # M_MMAP_THRESHOLD
    except (OSError, AttributeError):
        pass


def _run(path: str, fn: Callable[[str, dict[str, Any]], None]) -> dict[str, Any]:
    _tune_malloc()
    t0, c0 = time.perf_counter(), time.process_time()
    row = _start_row(path)
    try:
        fn(path, row)
        row["status"] = "ok"
    except Exception as e:                    # reported in the row; the other recordings go on
        row["status"] = "failed"
        row["error"] = f"{type(e).__name__}: {e}"
    row["seconds"] = time.perf_counter() - t0
    row["cpu_seconds"] = time.process_time() - c0
    return row


def discover_job(path: str, opts: dict[str, Any]) -> dict[str, Any]:
    """Discovery on the recording at ``path`` (read here); ``opts``: ``robot`` (None: the
    recording's), ``params`` (a parameter file path or None), ``terms`` (list of names or
    None), ``block``, ``min_gain``, ``exact_baseline``. Returns the row (module docstring)."""

    def work(p: str, row: dict[str, Any]) -> None:
        from cablesvc.discover import ForwardSelector, SelectOptions, discover, library

        rec, rob = _read(p, row, opts.get("robot"))
        terms = library(list(opts["terms"])) if opts.get("terms") else None
        sel = ForwardSelector(SelectOptions(min_gain=float(opts.get("min_gain", 0.05))))
        d = discover(rec, rob, opts.get("params"), terms=terms, selector=sel, block=float(opts.get("block", 2.5)),
                     exact_baseline=bool(opts.get("exact_baseline", False)))
        doc = _plain(d.to_json())
        row["verdict"] = doc["verdict"]
        row["findings"] = [{"term": f["term"], "label": f["label"], "cables": f["cables"], "p_value": f["p_value"]}
                           for f in doc["findings"]]
        row["recalibrated"] = list(doc.get("recalibration", {}).get("cables", []))
        row["unexplained"] = [{"cables": u["cables"], "variable": u["variable"]} for u in doc.get("unexplained", [])]
        row["detection"] = [{"term": x["term"], "min_floor_rms_N": x["min_floor_rms_N"],
                             "min_limit_rms_N": x["min_limit_rms_N"]} for x in doc.get("detection_limits", [])]
        row["rmse_test_before"] = doc["rmse_test_before"]
        row["rmse_test_after"] = doc["rmse_test_after"]
        row["discovery"] = doc

    return _run(path, work)


def identify_job(path: str, opts: dict[str, Any]) -> dict[str, Any]:
    """Identification on the recording at ``path`` (read here); ``opts``: ``robot``,
    ``model``, ``method``, ``cables`` (list or None), ``shared``, ``seed``, ``particles``,
    ``iterations``. Returns the row (module docstring)."""

    def work(p: str, row: dict[str, Any]) -> None:
        from cablesvc.identify.cable import identify_cable

        rec, rob = _read(p, row, opts.get("robot"))
        fit = identify_cable(rec, rob, opts.get("model", "amplitude"), cables=opts.get("cables"),
                             shared=bool(opts.get("shared", False)), method=opts.get("method", "pso+lm"),
                             seed=opts.get("seed", 0), particles=int(opts.get("particles", 10)),
                             iterations=int(opts.get("iterations", 75)))
        names = list(fit.names)
        per = []
        for j, r in enumerate(fit.results):
            se = r.get("stderr")
            se = [float("nan")] * len(names) if se is None else list(se)
            per.append({"cable": "shared" if fit.shared else int(fit.cables[j]),
                        "value": dict(zip(names, (float(v) for v in r["x"]))),
                        "stderr": dict(zip(names, (float(v) for v in se)))})
        row.update(_plain({"model": fit.model, "method": fit.method, "cables": list(fit.cables), "names": names,
                           "parameters": per, "rmse": [float(v) for v in fit.rmse], "notes": list(fit.notes),
                           "params_toml": fit.params.to_toml()}))

    return _run(path, work)


def import_job_modules(command: str) -> None:
    """Import what the job of ``command`` runs (:data:`JOB_MODULES`), here and now. The
    LocalCluster forks its workers from this process on Linux (:mod:`cablesvc.batch.run`):
    a worker then starts with these modules loaded instead of importing them again on its
    first recording (about 1.2 s of CPU each, measured)."""
    import importlib
    for name in JOB_MODULES[command]:
        importlib.import_module(name)


#: the job of each command
JOBS: dict[str, Callable[[str, dict[str, Any]], dict[str, Any]]] = {"discover": discover_job,
                                                                     "identify": identify_job}
#: the modules each job imports when it runs (what :func:`_read` and its ``work`` import)
JOB_MODULES: dict[str, tuple[str, ...]] = {
    "discover": ("cablesvc.config.robot", "cablesvc.recording", "cablesvc.discover"),
    "identify": ("cablesvc.config.robot", "cablesvc.recording", "cablesvc.identify.cable"),
}
