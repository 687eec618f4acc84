"""``cablesvc listen``: show what a running cablesvc daemon publishes on Zenoh.

By default a live table of the latest forces of each robot and the recent alarms; with
``--json`` one JSON object per line and message::

    {"kind": "forces", "key": "cablesvc/ipanema3/forces", "receive_ns": ..., "payload": {...}}
    {"kind": "alarm",  "key": "cablesvc/ipanema3/alarms", "receive_ns": ..., "payload": {...}}

``--status`` prints the daemon's status answer (JSON) and exits, ``--alive`` the robots
whose daemon is up. The listener is a Zenoh peer that listens nowhere and connects to
``--connect`` (default the daemon's loopback endpoint), or uses ``--zenoh-config``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from collections import deque
from typing import Any

from cablesvc.cli.failures import UsageError, zenoh_failure

EPILOG = """\
examples:
  cablesvc listen                                   live table of every robot on tcp/127.0.0.1:7447
  cablesvc listen --robot ipanema3 --json --count 100 > forces.jsonl
  cablesvc listen --status --robot ipanema3         the daemon's status (JSON)
  cablesvc listen --zenoh-config deploy/zenoh-peer.json5 --connect tls/cdpr-ctl:7447
"""


def _config(args):
    from cablesvc.service.zenoh_io import DEFAULT_LISTEN, make_config

    connect = args.connect if args.connect else None
    if args.zenoh_config:
        kw = {"connect": connect} if connect else {}
        return make_config(args.zenoh_config, **kw)
    return make_config(mode="peer", listen=(), connect=connect or [DEFAULT_LISTEN])


def _check_args(args) -> None:
    """Bad values of the command line: a :class:`UsageError` (exit status 2) naming the flag."""
    from cablesvc.service.zenoh_io import keys

    if args.robot is not None:
        try:
            keys(args.robot)
        except ValueError as e:
            raise UsageError(f"--robot: {e}") from None
    for flag, v in (("--wait", args.wait), ("--timeout", args.timeout)):
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise UsageError(f"{flag}: expected seconds >= 0 (a finite number), got {v!r}")
    if args.count is not None and args.count < 1:
        raise UsageError(f"--count: expected a number of messages >= 1, got {args.count!r}")
    for v in args.connect or ():
        proto, _, addr = v.partition("/")
        if not proto or not addr or v != v.strip():
            raise UsageError(f"--connect: a Zenoh endpoint looks like tcp/127.0.0.1:7447, got {v!r}")


def _listener(args, **kw):
    """The Listener of ``args``; a Zenoh configuration or session that cannot be had is a
    :class:`~cablesvc.errors.ServiceError` (exit status 1) naming the file or the endpoints."""
    import zenoh

    from cablesvc.service.zenoh_io import DEFAULT_LISTEN, Listener

    where = args.zenoh_config or f"connect {', '.join(args.connect or (DEFAULT_LISTEN,))}"
    try:
        config = _config(args)
    except (zenoh.ZError, ValueError, OSError) as e:    # a missing or invalid JSON5 file, a bad endpoint
        raise zenoh_failure("use the Zenoh configuration", where, e) from None
    try:
        return Listener(args.robot, config, **kw)
    except zenoh.ZError as e:
        raise zenoh_failure("open the Zenoh session", where, e) from None


def cmd_listen(args) -> int:
    """Handler of ``cablesvc listen``. Exit status 0; 1 when --status/--alive got no answer
    or --timeout passed without a message, or the Zenoh session cannot be opened; 2 for a
    bad argument (cablesvc.cli.main prints the error)."""
    _check_args(args)
    out = sys.stdout
    if args.status or args.alive:
        lis = _listener(args)
        try:
            if args.alive:
                deadline = time.monotonic() + args.wait
                robots = lis.alive()
                while not robots and time.monotonic() < deadline:      # the connection may still be coming up
                    time.sleep(0.1)
                    robots = lis.alive()
                print(json.dumps(robots) if args.json else "\n".join(robots), file=out)
                return 0 if robots else 1
            deadline = time.monotonic() + args.wait
            st = lis.statuses(timeout=args.wait)
            while not st and time.monotonic() < deadline:
                time.sleep(0.1)
                st = lis.statuses(timeout=max(0.1, deadline - time.monotonic()))
            if not st:
                print(f"cablesvc listen: no daemon answered on {lis.keys.status} within {args.wait:g} s",
                      file=sys.stderr)
                return 1
            for s in st:
                print(json.dumps(s, indent=None if args.json else 2), file=out)
            return 0
        finally:
            lis.close()
    if args.json:
        return _listen_json(args, out)
    return _listen_table(args)


def _listen_json(args, out) -> int:
    lis = _listener(args)
    n_forces = 0
    last = time.monotonic()
    try:
        while True:
            got = False
            a = lis.alarms(timeout=0)
            while a is not None:
                got = True
                out.write(json.dumps({"kind": "alarm", "key": a.key, "receive_ns": a.receive_ns,
                                      "payload": a.payload}) + "\n")
                a = lis.alarms(timeout=0)
            f = lis.forces(timeout=0.05)
            if f is not None:
                got = True
                out.write(json.dumps({"kind": "forces", "key": f.key, "receive_ns": f.receive_ns,
                                      "payload": f.payload}) + "\n")
                n_forces += 1
            if got:
                out.flush()
                last = time.monotonic()
                if args.count is not None and n_forces >= args.count:
                    return 0
            elif args.timeout is not None and time.monotonic() - last > args.timeout:
                print(f"cablesvc listen: nothing received for {args.timeout:g} s", file=sys.stderr)
                return 1
    except KeyboardInterrupt:
        return 0
    finally:
        lis.close()


def _fmt(v: Any, fmt: str) -> str:
    return "-" if v is None else fmt.format(v)


def _listen_table(args) -> int:
    from rich.console import Console, Group
    from rich.live import Live
    from rich.table import Table

    latest: dict[str, tuple[dict, int]] = {}
    counts: dict[str, int] = {}
    alarms: deque = deque(maxlen=12)
    lock = threading.Lock()
    total = {"forces": 0}
    done = threading.Event()

    def on_forces(p, ns):
        with lock:
            r = p.get("robot", "?")
            latest[r] = (p, ns)
            counts[r] = counts.get(r, 0) + 1
            total["forces"] += 1
            if args.count is not None and total["forces"] >= args.count:
                done.set()

    def on_alarm(p, ns):
        with lock:
            alarms.append(p)

    def render():
        with lock:
            items = sorted(latest.items())
            al = list(alarms)
            cnt = dict(counts)
        parts = []
        for robot, (p, _) in items:
            names = p.get("cables") or [str(i) for i in range(len(p["force"]))]
            tb = Table(title=f"{robot}   seq {p['seq']}   t = {p['t']:.3f} s   {cnt.get(robot, 0)} messages"
                             f"{'   pose from FK' if p.get('pose_from_fk') else ''}")
            for c in ("cable", "predicted N", "measured N", "residual N", "elongation mm", "wrap deg", "slack"):
                tb.add_column(c, justify="right")
            meas = p.get("measured") or [None] * len(names)
            res = p.get("residual") or [None] * len(names)
            for i, name in enumerate(names):
                tb.add_row(name, _fmt(p["force"][i], "{:.2f}"), _fmt(meas[i], "{:.2f}"), _fmt(res[i], "{:+.2f}"),
                           _fmt(None if p["elongation"][i] is None else p["elongation"][i] * 1e3, "{:.3f}"),
                           _fmt(None if p["wrap_angle"][i] is None else p["wrap_angle"][i] * 57.29577951308232,
                                "{:.1f}"),
                           "yes" if p["slack"][i] else "")
            parts.append(tb)
        at = Table(title="alarms (latest last)")
        for c in ("t s", "robot", "action", "severity", "code", "cable", "message"):
            at.add_column(c)
        for a in al:
            colour = {"error": "red", "warning": "yellow"}.get(a.get("severity"), "")
            at.add_row(f"{a['t']:.3f}", str(a.get("robot", "")), a["action"],
                       f"[{colour}]{a['severity']}[/]" if colour else a["severity"], a["code"],
                       "" if a.get("cable") is None else str(a["cable"]), a["message"])
        if not items:
            parts.append(f"waiting for cablesvc/{args.robot or '*'}/forces ...")
        parts.append(at)
        return Group(*parts)

    con = Console()
    lis = _listener(args, on_forces=on_forces, on_alarm=on_alarm)
    try:
        with Live(render(), console=con, refresh_per_second=8) as live:
            last_n = -1
            last_change = time.monotonic()
            while not done.wait(0.125):
                live.update(render())
                n = total["forces"]
                if n != last_n:
                    last_n, last_change = n, time.monotonic()
                elif args.timeout is not None and time.monotonic() - last_change > args.timeout:
                    return 1
            live.update(render())
    except KeyboardInterrupt:
        pass
    finally:
        lis.close()
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``listen`` on the top-level ``cablesvc`` subparsers; returns the parser."""
    p = subparsers.add_parser(
        "listen", help="show what a running daemon publishes (forces, alarms, status)",
        description=__doc__, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--robot", help="only this robot (default: every robot)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint of the daemon or router (default tcp/127.0.0.1:7447; repeatable)")
    p.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration (router, TLS, ...)")
    p.add_argument("--json", action="store_true", help="one JSON object per line and message")
    p.add_argument("--count", type=int, metavar="N", help="stop after N forces messages")
    p.add_argument("--timeout", type=float, metavar="S", help="exit with status 1 after S seconds without messages")
    p.add_argument("--status", action="store_true", help="print the daemon's status and exit")
    p.add_argument("--alive", action="store_true", help="print the robots whose daemon is up and exit")
    p.add_argument("--wait", type=float, default=3.0, metavar="S",
                   help="how long --status / --alive wait for an answer (default 3)")
    p.set_defaults(func=cmd_listen)
    return p


def main(argv: list[str] | None = None) -> int:
    """``python -m cablesvc.cli.listen_cmd listen ...``: the listen command on its own (its
    errors are one line, as from ``cablesvc listen``)."""
    from cablesvc.cli.failures import run_command

    parser = argparse.ArgumentParser(prog="cablesvc")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    return run_command(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
