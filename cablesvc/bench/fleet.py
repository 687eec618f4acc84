"""``cablesvc bench fleet``: a fleet's recordings serially and on a Dask LocalCluster.

The digital twin writes ``--recordings`` trajectory recordings (``--seconds`` long at
``--rate`` Hz, one robot of the fleet each night, some with a concealed effect that
appears on a given night, each with its ``start_time``) into a temporary directory. Then
``cablesvc discover`` (or ``--command identify`` on hold-sine recordings) runs over them
twice: serially in this process (:func:`cablesvc.batch.run_serial`), then on a new
``LocalCluster`` of ``--workers`` processes (:func:`cablesvc.batch.run_fleet`).

Printed: ``recordings``, ``workers``, ``serial_seconds``, ``cluster_seconds`` (the whole
cluster run *including* the LocalCluster start and the workers' first imports: what a
user waits for), ``cluster_start_seconds`` (the start alone), ``speedup`` = serial /
cluster (``speedup_excluding_start``: the start left out), ``identical`` (every row of the cluster run equals the serial row, all numbers,
only the timing fields left out), ``cpus`` and the 1-minute load average before and after.
``serial_cpu_seconds`` / ``cluster_cpu_seconds`` sum the jobs' CPU time in their processes
and ``cluster_cores_used`` = cluster CPU / cluster wall time: on a machine whose cores
other work also uses, the workers get less than a core each while the serial run may get a
whole one, and these say so.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Optional

__all__ = ["add_parser", "cmd_fleet_bench", "make_fleet", "run_fleet_bench"]

#: effect per night (cycled): a fleet where a pulley effect appears and stays on cable 1
EFFECTS = ["", "", "pulley:0.02@1", "pulley:0.02@1", "", "pulley:0.02@1,4", "pulley:0.02@1", ""]
#: the first recording's start_time; one recording a night after it
FIRST_NIGHT = "2026-11-01T02:00:00+00:00"


def make_fleet(directory: str | os.PathLike, recordings: int, seconds: float, rate: float, *,
               command: str = "discover", robot: str = "ipanema3", seed: int = 0) -> list[str]:
    """Write ``recordings`` simulated recordings into ``directory``; their paths in order."""
    from datetime import datetime, timedelta

    from cablesvc.config import load_robot
    from cablesvc.recording import write_recording
    from cablesvc.simulate import TruthConfig, effect_from_spec, simulate_recording

    out = []
    d = Path(directory)
    m = load_robot(robot).n_cables
    first = datetime.fromisoformat(FIRST_NIGHT)
    for i in range(recordings):
        spec = EFFECTS[i % len(EFFECTS)]
        eff = [effect_from_spec(spec, m)] if spec else []
        if command == "identify":
            rec = simulate_recording(robot, "hold-sine", None, truth=TruthConfig(noise_std=0.1), rate=rate,
                                     frequency=1.0, settle=0.5, rest=0.5, seed=seed + i)
        else:
            rec = simulate_recording(robot, "trajectory", None, truth=TruthConfig(effects=eff, noise_std=0.1),
                                     duration=seconds, rate=rate, seed=seed + i)
        rec.metadata["start_time"] = (first + timedelta(days=i)).isoformat()
        p = d / f"{robot}-night{i:02d}.mcap"
        write_recording(p, rec)
        out.append(str(p))
    return out


def run_fleet_bench(recordings: int = 8, workers: int = 2, seconds: float = 60.0, rate: float = 100.0, *,
                    command: str = "discover",
                    progress: Optional[Callable[[str], None]] = None) -> dict[str, Any]:
    """Run the bench (module docstring); a JSON-able dict."""
    from cablesvc.batch import comparable, run_fleet, run_serial

    say = progress or (lambda s: None)
    with tempfile.TemporaryDirectory(prefix="cablesvc-bench-fleet-") as tmp:
        say(f"simulating {recordings} recordings")
        paths = make_fleet(tmp, recordings, seconds, rate, command=command)
        load_before = os.getloadavg()[0]
        say("serial run")
        t0 = time.perf_counter()
        serial = run_serial(command, paths, {}, progress=lambda i, n, r: say(f"serial {i}/{n}"))
        t_serial = time.perf_counter() - t0
        say(f"LocalCluster, {workers} workers")
        t0 = time.perf_counter()
        res = run_fleet(command, paths, {}, workers=workers, progress=lambda i, n, r: say(f"cluster {i}/{n}"))
        t_cluster = time.perf_counter() - t0
        load_after = os.getloadavg()[0]
    return {"command": command, "recordings": recordings, "workers": res.engine["workers"],
            "seconds_per_recording": seconds, "rate_hz": rate,
            "serial_seconds": round(t_serial, 3), "cluster_seconds": round(t_cluster, 3),
            "cluster_start_seconds": round(res.engine["start_seconds"], 3),
            "cluster_includes_start": True,
            "speedup": round(t_serial / t_cluster, 3),
            "speedup_excluding_start": round(t_serial / (t_cluster - res.engine["start_seconds"]), 3),
            "identical": comparable(serial) == comparable(res.rows),
            "serial_cpu_seconds": round(sum(r["cpu_seconds"] or 0.0 for r in serial), 3),
            "cluster_cpu_seconds": round(sum(r["cpu_seconds"] or 0.0 for r in res.rows), 3),
            "cluster_cores_used": round(sum(r["cpu_seconds"] or 0.0 for r in res.rows) / t_cluster, 2),
            "failed": sum(r["status"] != "ok" for r in res.rows),
            "cpus": os.cpu_count(), "load_1min_before": round(load_before, 2),
            "load_1min_after": round(load_after, 2), "summary": res.summary["lines"]}


def cmd_fleet_bench(args: argparse.Namespace) -> int:
    if args.recordings < 1 or args.workers < 1 or not (args.seconds > 0) or not (args.rate > 0):
        print("cablesvc bench fleet: --recordings, --workers, --seconds and --rate must be > 0", file=sys.stderr)
        return 2
    from rich.console import Console
    con = Console(stderr=True)
    with con.status("fleet bench") as st:
        res = run_fleet_bench(args.recordings, args.workers, args.seconds, args.rate, command=args.command,
                              progress=lambda s: st.update(f"fleet bench: {s}"))
    if args.json:
        print(json.dumps(res))
    else:
        for k, v in res.items():
            if k != "summary":
                print(f"{k:24s} {v}")
        for line in res["summary"]:
            print(f"  {line}")
    return 0 if res["identical"] and not res["failed"] else 1


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("fleet", help="a fleet's recordings: serial run vs a Dask LocalCluster",
                              description=__doc__.split("\n\n")[0].split("``: ", 1)[-1])
    p.add_argument("--recordings", type=int, default=8, help="simulated recordings (default 8)")
    p.add_argument("--workers", type=int, default=2, help="LocalCluster worker processes (default 2)")
    p.add_argument("--seconds", type=float, default=60.0, help="length of each trajectory recording (default 60)")
    p.add_argument("--rate", type=float, default=100.0, help="tick rate in Hz (default 100)")
    p.add_argument("--command", choices=["discover", "identify"], default="discover",
                   help="the fleet job (default discover; identify fits the amplitude model to hold-sine "
                        "recordings)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_fleet_bench)
    return p
