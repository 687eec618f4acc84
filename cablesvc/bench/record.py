"""``cablesvc bench record``: replay + record round trips, as a user runs them.

The README's line ``cablesvc run --source replay --replay traj.mcap --speed 0 --record
out.mcap --no-view``, repeated: the digital twin writes one ``--seconds`` long recording at
``--rate`` Hz (``cablesvc simulate``), then each of ``--repeat`` runs starts the real daemon
as a separate process (``python -m cablesvc run``, Zenoh on loopback, no snapshot), lets it
replay the file at ``--speed`` and exit by itself, and compares:

* ``accepted``: ticks the daemon's input accepted (its exit log line ``input {...}``);
* ``in_file``: input ticks in the ``--record`` file, read back with ``read_recording``;
* ``forces_in_file``: forces messages in it (MCAP only: CSV holds the inputs);
* the exit status and the run's wall time.

A run passes when it exits 0 and ``accepted == in_file`` (== ``forces_in_file`` for MCAP) ==
the recording's tick count. The command exits 0 only when every run passes.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Optional

__all__ = ["add_parser", "cmd_record", "run_record_bench"]

_INPUT = re.compile(r"after (\d+) ticks; input (\{.*?\}); latency")


def _free_port() -> int:
    from cablesvc.netutil import free_tcp_port
    return free_tcp_port()


def run_record_bench(seconds: float, rate: float, repeat: int, *, speed: float = 0.0, robot: str = "ipanema3",
                     fmt: str = "mcap", progress: Optional[Callable[[str, float], None]] = None) -> dict[str, Any]:
    """Run the round trips (see the module docstring); a JSON-able result."""
    from cablesvc.recording import read_recording, write_recording
    from cablesvc.simulate import simulate_recording

    with tempfile.TemporaryDirectory(prefix="cablesvc-bench-record-") as tmp:
        d = Path(tmp)
        rec = simulate_recording(robot, "trajectory", None, duration=seconds, rate=rate, seed=0)
        src = d / "traj.mcap"
        write_recording(src, rec)
        runs = []
        for i in range(repeat):
            if progress:
                progress(f"run {i + 1}/{repeat}", i / repeat)
            out = d / f"out-{i}.{fmt}"
            t0 = time.monotonic()
            proc = subprocess.run([sys.executable, "-m", "cablesvc", "run", "--robot", robot, "--source", "replay",
                                   "--replay", str(src), "--speed", f"{speed:g}", "--record", str(out), "--no-view",
                                   "--no-snapshot", "--listen", f"tcp/127.0.0.1:{_free_port()}"],
                                  capture_output=True, text=True)
            wall = time.monotonic() - t0
            m = _INPUT.search(proc.stderr)
            accepted = json.loads(m.group(2)).get("accepted") if m else None
            in_file = forces = None
            error = None
            try:
                back = read_recording(out, keep_topics=["/cablesvc/forces"] if fmt == "mcap" else ())
                in_file = back.n_ticks
                forces = len(back.extra.get("/cablesvc/forces", ())) if fmt == "mcap" else None
            except Exception as e:  # noqa: BLE001 - a broken file is a failed run, reported
                error = str(e)
            ok = (proc.returncode == 0 and accepted == in_file == rec.n_ticks
                  and (fmt != "mcap" or forces == in_file))
            lines = [ln for ln in proc.stderr.splitlines() if "ERROR" in ln or ln.startswith("cablesvc run:")]
            runs.append({"run": i + 1, "exit": proc.returncode, "accepted": accepted, "in_file": in_file,
                         "forces_in_file": forces, "missing": None if accepted is None or in_file is None
                         else accepted - in_file, "wall_s": round(wall, 2), "ok": ok,
                         "error": error or (lines[0] if lines else None)})
            out.unlink(missing_ok=True)
        if progress:
            progress("done", 1.0)
    return {"robot": robot, "seconds": seconds, "rate_hz": rate, "speed": speed, "format": fmt,
            "ticks_in_replay": rec.n_ticks, "repeat": repeat, "runs": runs,
            "passed": sum(r["ok"] for r in runs)}


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("record", help="replay + record round trips: every accepted tick in the recording",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seconds", type=float, default=60.0, help="length of the replayed recording (default 60)")
    p.add_argument("--rate", type=float, default=1000.0, help="its tick rate in Hz (default 1000)")
    p.add_argument("--repeat", type=int, default=10, help="round trips (default 10)")
    p.add_argument("--speed", type=float, default=0.0, help="replay speed (default 0: as fast as possible)")
    p.add_argument("--robot", default="ipanema3")
    p.add_argument("--format", choices=["mcap", "csv"], default="mcap", help="--record file format (default mcap)")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.set_defaults(func=cmd_record)
    return p


def cmd_record(args) -> int:
    if not (0 < args.seconds <= 3600 and 0 < args.rate <= 10_000 and 1 <= args.repeat <= 1000 and args.speed >= 0):
        print("cablesvc bench record: need 0 < --seconds <= 3600, 0 < --rate <= 10000, 1 <= --repeat <= 1000, "
              "--speed >= 0", file=sys.stderr)
        return 2
    kw = dict(speed=args.speed, robot=args.robot, fmt=args.format)
    if args.json:
        res = run_record_bench(args.seconds, args.rate, args.repeat, **kw)
        print(json.dumps(res))
        return 0 if res["passed"] == res["repeat"] else 1
    from rich.console import Console
    from rich.table import Table

    from cablesvc.bench.e2e import run_with_progress
    con = Console()
    res = run_with_progress(con, "record", lambda progress: run_record_bench(args.seconds, args.rate, args.repeat,
                                                                             progress=progress, **kw))
    tb = Table(title=f"replay + record, {res['robot']}, {res['seconds']:g} s at {res['rate_hz']:g} Hz "
                     f"({res['ticks_in_replay']} ticks), --speed {res['speed']:g}, {res['format']}")
    for c in ("run", "exit", "accepted", "in file", "forces in file", "missing", "wall s", "ok"):
        tb.add_column(c, justify="right")
    for r in res["runs"]:
        tb.add_row(str(r["run"]), str(r["exit"]), str(r["accepted"]), str(r["in_file"]),
                   "-" if r["forces_in_file"] is None else str(r["forces_in_file"]), str(r["missing"]),
                   f"{r['wall_s']:.1f}", "yes" if r["ok"] else "NO")
    con.print(tb)
    for r in res["runs"]:
        if r["error"]:
            con.print(f"run {r['run']}: {r['error']}")
    con.print(f"accepted == written in {res['passed']}/{res['repeat']} runs")
    return 0 if res["passed"] == res["repeat"] else 1
