"""The fleet side of ``cablesvc discover`` and ``cablesvc identify``.

Both commands take one recording as before; given several paths, a directory or a glob
(or ``--scheduler`` / ``--workers`` / ``--serial``) they run :func:`cablesvc.batch.run_fleet`
instead: a rich progress bar on stderr while the recordings finish, then one line per
recording and the fleet summary (``--json``: the fleet JSON on stdout; ``--report DIR``:
``fleet.json`` and ``index.html``). Exit code 0 when every recording succeeded, 1 when
one failed (it is still reported, and the others finish) or the job could not start.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

__all__ = ["add_fleet_arguments", "fleet_requested", "cmd_fleet"]


def add_fleet_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("many recordings (a fleet's logs: several paths, a directory or a glob; "
                             "docs/cluster.md)")
    g.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run on this Dask scheduler, e.g. tcp://host:8786 (default: a LocalCluster on this machine)")
    g.add_argument("--workers", type=int, default=None, metavar="N",
                   help="LocalCluster worker processes, one thread each (default 2)")
    g.add_argument("--serial", action="store_true",
                   help="run the recordings one after the other in this process, without Dask")


def fleet_requested(args: argparse.Namespace, specs: Sequence[str]) -> bool:
    """True when the command should run as a fleet job (module docstring)."""
    from cablesvc.batch.inputs import is_pattern
    return (len(specs) > 1 or any(is_pattern(s) and not Path(s).exists() or Path(s).is_dir() for s in specs)
            or bool(args.scheduler) or args.workers is not None or bool(args.serial))


def _brief(row: dict[str, Any], command: str) -> str:
    if row["status"] != "ok":
        return f"FAILED: {row['error']}"
    if command == "discover":
        finds = "; ".join(f"{f['term']} on {','.join(map(str, f['cables']))}" for f in row["findings"])
        rc = f"recalibrated {','.join(map(str, row['recalibrated']))}" if row["recalibrated"] else ""
        return " | ".join(x for x in (finds, rc) if x) or "nothing significant"
    return "RMSE [N] " + ", ".join(f"{v:.3g}" for v in row["rmse"])


def cmd_fleet(command: str, args: argparse.Namespace, specs: Sequence[str], opts: dict[str, Any]) -> int:
    """Run ``command`` over the recordings ``specs`` name with job options ``opts``. A fleet
    that cannot run raises :class:`~cablesvc.errors.BatchError` (recordings that cannot be
    found, a bad ``--workers``, an engine that does not start); the CLI prints it as one line."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from cablesvc.batch.inputs import expand_recordings
    from cablesvc.batch.run import DEFAULT_WORKERS, run_fleet
    from cablesvc.errors import BatchError

    paths = expand_recordings(specs)
    workers = DEFAULT_WORKERS if args.workers is None else args.workers
    if workers < 1:
        raise BatchError(f"--workers: expected at least 1, got {workers}")
    err = Console(stderr=True)
    quiet = bool(getattr(args, "quiet", False))
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err, transient=True, disable=quiet) as prog:
        where = "serial" if args.serial else (args.scheduler or f"LocalCluster, {workers} workers")
        task = prog.add_task(f"{command} ({where})", total=len(paths))
        failed = [0]

        def cb(done: int, total: int, row: dict[str, Any]) -> None:
            failed[0] += row["status"] != "ok"
            prog.update(task, completed=done,
                        description=f"{command}: {Path(row['recording']).name}"
                                    + (f" [red]({failed[0]} failed)[/]" if failed[0] else ""))

        res = run_fleet(command, paths, opts, scheduler=args.scheduler, workers=workers, serial=args.serial,
                        progress=cb)
    files: dict[str, str] = {}
    if args.report:
        from cablesvc.batch.report import write_fleet_report
        files = write_fleet_report(res, args.report)
    if args.json:
        doc = res.to_json()
        doc["files"] = files
        print(json.dumps(doc, indent=1))
    else:
        from rich.table import Table
        con = Console()
        tb = Table(title=f"cablesvc {command}: {len(res.rows)} recordings, {len(res.failed)} failed, "
                         f"{res.engine.get('engine')} ({res.engine.get('workers')} workers), {res.seconds:.1f} s")
        for c in ("recording", "robot", "start (UTC)", "result", "s"):
            tb.add_column(c)
        for r in res.rows:
            tb.add_row(str(r["recording"]), str(r.get("robot") or ""), str(r.get("start_time") or ""),
                       _brief(r, command), "" if r.get("seconds") is None else f"{r['seconds']:.1f}")
        con.print(tb)
        for line in res.summary["lines"]:
            print(line)
        for k, v in files.items():
            print(f"wrote {k}: {v}")
    for r in res.failed:
        print(f"cablesvc {command}: {r['recording']}: {r['error']}", file=sys.stderr)
    return 1 if res.failed else 0
