"""``cablesvc bench read``: how long reading a long recording takes, per input encoding.

A synthetic ``--minutes`` long recording at ``--rate`` Hz of an ``--cables``-cable robot
(every part present: pose, motor lengths, forces, temperature; smooth motion plus sensor
noise, all values finite so both encodings keep them exactly) is written into a temporary
directory once per encoding (``--encodings``, default ``protobuf,json``) with
:class:`cablesvc.recording.McapRecordingWriter` (``write_inputs``, one minute of ticks per
call, generated before the clock starts). Each file is then read back with
``cablesvc.recording.read_recording`` (the whole recording into a ``Recording``, as
``cablesvc discover`` / ``identify`` read it) in a fresh Python process, so that its peak
resident memory is the reader's own (``VmHWM`` of ``/proc/self/status``; ``ru_maxrss``
where there is no /proc: on Linux ``ru_maxrss`` keeps the parent's peak across the exec).

Printed per encoding: ``minutes``, ``ticks``, ``file_mb`` (MiB on disk), ``write_seconds``
(writer calls and close), ``read_seconds`` (``read_recording`` alone, imports excluded),
``peak_rss_mb`` (the reading process's peak RSS, MiB, imports included),
``rss_before_read_mb`` (that process's peak after its imports, before reading), and ``identical``
(the SHA-256 of every column read back equals that of the columns written). The target of
issue 17 is ``read_seconds <= 20`` for one hour at 1 kHz with 8 cables.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

import numpy as np

__all__ = ["add_parser", "cmd_read_bench", "run_read_bench", "synthetic_chunks"]

COLUMNS = ("seq", "t", "motor_length", "position", "orientation", "force", "temperature")
TARGET_READ_S = 20.0


def synthetic_chunks(minutes: float, rate: float, cables: int, chunk_ticks: int,
                     seed: int = 0) -> Iterator[dict[str, np.ndarray]]:
    """The synthetic recording, ``chunk_ticks`` ticks at a time (deterministic)."""
    n = int(round(minutes * 60.0 * rate))
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, cables)
    for i0 in range(0, n, chunk_ticks):
        i1 = min(i0 + chunk_ticks, n)
        k = np.arange(i0, i1)
        t = k / rate
        w = 2 * np.pi * 0.1 * t
        position = np.stack([0.3 * np.sin(w), 0.2 * np.cos(0.7 * w), 1.0 + 0.1 * np.sin(0.3 * w)], axis=1)
        half = 0.05 * np.sin(0.2 * w)
        orientation = np.stack([np.zeros_like(half), np.zeros_like(half), np.sin(half), np.cos(half)], axis=1)
        ml = 2.0 + 0.25 * np.sin(w[:, None] + phase[None, :]) + 1e-6 * rng.standard_normal((i1 - i0, cables))
        force = 150.0 + 40.0 * np.cos(w[:, None] + phase[None, :]) + 0.1 * rng.standard_normal((i1 - i0, cables))
        temperature = 21.5 + 0.5 * t / 3600.0 + 0.01 * rng.standard_normal(i1 - i0)
        yield {"seq": k.astype(np.int64), "t": t, "motor_length": ml, "position": position,
               "orientation": orientation, "force": force, "temperature": temperature}


def _write(path: Path, encoding: str, minutes: float, rate: float, cables: int) -> tuple[float, int, dict]:
    """Write the recording; (seconds in the writer, ticks, sha256 per column)."""
    from cablesvc.recording import McapRecordingWriter

    hashes = {c: hashlib.sha256() for c in COLUMNS}
    spent = 0.0
    ticks = 0
    t0 = time.perf_counter()
    w = McapRecordingWriter(path, "synthetic", {"source": "cablesvc bench read"}, encoding=encoding)
    spent += time.perf_counter() - t0
    try:
        for c in synthetic_chunks(minutes, rate, cables, chunk_ticks=int(60 * rate)):
            for name in COLUMNS:
                hashes[name].update(np.ascontiguousarray(c[name]).tobytes())
            t0 = time.perf_counter()
            w.write_inputs(c["seq"], c["t"], c["motor_length"], c["force"], c["position"], c["orientation"],
                           c["temperature"])
            spent += time.perf_counter() - t0
            ticks += c["t"].shape[0]
    finally:
        t0 = time.perf_counter()
        w.close()
        spent += time.perf_counter() - t0
    return spent, ticks, {k: h.hexdigest() for k, h in hashes.items()}


_CHILD = r"""
import hashlib, json, sys, time
import numpy as np
from cablesvc.bench.memory import own_peak_kb as peak_kb    # not the writer's memory
from cablesvc.recording import read_recording

before = peak_kb()
t0 = time.perf_counter()
rec = read_recording(sys.argv[1])
dt = time.perf_counter() - t0
peak = peak_kb()
cols = {c: getattr(rec, c) for c in %r}
print(json.dumps({"read_seconds": dt, "ticks": rec.n_ticks, "peak_rss_kb": peak, "before_kb": before,
                  "sha256": {c: None if a is None else hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()
                             for c, a in cols.items()}}))
""" % (COLUMNS,)


def _read(path: Path) -> dict[str, Any]:
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"reading {path} failed: {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run_read_bench(minutes: float = 60.0, *, rate: float = 1000.0, cables: int = 8,
                   encodings: tuple[str, ...] = ("protobuf", "json"), directory: Optional[str] = None,
                   progress: Optional[Callable[[str, float], None]] = None) -> dict[str, Any]:
    """Write and read the recording once per encoding (see the module docstring)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="cablesvc-bench-read-", dir=directory) as tmp:
        for i, enc in enumerate(encodings):
            path = Path(tmp) / f"synthetic-{enc}.mcap"
            if progress:
                progress(f"{enc}: writing", i / len(encodings))
            write_s, ticks, want = _write(path, enc, minutes, rate, cables)
            size = path.stat().st_size
            if progress:
                progress(f"{enc}: reading", (i + 0.5) / len(encodings))
            got = _read(path)
            path.unlink()
            rows.append({
                "encoding": enc, "minutes": minutes, "ticks": ticks, "file_mb": round(size / 2**20, 1),
                "write_seconds": round(write_s, 2), "read_seconds": round(got["read_seconds"], 2),
                "peak_rss_mb": round(got["peak_rss_kb"] / 1024, 1),
                "rss_before_read_mb": round(got["before_kb"] / 1024, 1),
                "ticks_read": got["ticks"], "identical": got["sha256"] == want and got["ticks"] == ticks,
            })
    if progress:
        progress("done", 1.0)
    return {"rate_hz": rate, "cables": cables, "target_read_seconds": TARGET_READ_S, "cpus": os.cpu_count(),
            "rows": rows}


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("read", help="write and read a long synthetic recording per input encoding",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--minutes", type=float, default=60.0, help="recording length (default 60)")
    p.add_argument("--rate", type=float, default=1000.0, help="tick rate in Hz (default 1000)")
    p.add_argument("--cables", type=int, default=8, help="cables (default 8)")
    p.add_argument("--encodings", default="protobuf,json",
                   help="comma-separated input encodings to measure (default protobuf,json)")
    p.add_argument("--dir", help="directory for the temporary files (default: the system's temp directory)")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.set_defaults(func=cmd_read_bench)
    return p


def cmd_read_bench(args) -> int:
    from cablesvc.recording import ENCODINGS

    encodings = tuple(e.strip() for e in args.encodings.split(",") if e.strip())
    bad = [e for e in encodings if e not in ENCODINGS]
    if bad or not encodings:
        print(f"cablesvc bench read: --encodings takes {', '.join(ENCODINGS)}; got {args.encodings!r}",
              file=sys.stderr)
        return 2
    if not (0 < args.minutes <= 24 * 60 and 0 < args.rate <= 100_000 and 1 <= args.cables <= 64):
        print("cablesvc bench read: need 0 < --minutes <= 1440, 0 < --rate <= 100000, 1 <= --cables <= 64",
              file=sys.stderr)
        return 2
    if args.dir and not Path(args.dir).is_dir():
        print(f"cablesvc bench read: --dir {args.dir} is not a directory", file=sys.stderr)
        return 2
    kw = dict(rate=args.rate, cables=args.cables, encodings=encodings, directory=args.dir)
    if args.json:
        res = run_read_bench(args.minutes, **kw)
        print(json.dumps(res))
        return 0 if all(r["identical"] for r in res["rows"]) else 1
    from rich.console import Console
    from rich.table import Table

    from cablesvc.bench.e2e import run_with_progress
    con = Console()
    res = run_with_progress(con, "read", lambda progress: run_read_bench(args.minutes, progress=progress, **kw))
    tb = Table(title=f"read a recording: {args.minutes:g} min at {args.rate:g} Hz, {args.cables} cables "
                     f"({res['cpus']} CPUs)")
    for c in ("encoding", "ticks", "file MiB", "write s", "read s", "peak RSS MiB", "identical"):
        tb.add_column(c, justify="right")
    for r in res["rows"]:
        tb.add_row(r["encoding"], f"{r['ticks']:,}", f"{r['file_mb']:.1f}", f"{r['write_seconds']:.2f}",
                   f"{r['read_seconds']:.2f}", f"{r['peak_rss_mb']:.0f}", "yes" if r["identical"] else "NO")
    con.print(tb)
    return 0 if all(r["identical"] for r in res["rows"]) else 1
