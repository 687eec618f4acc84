"""``cablesvc run``: the live daemon (embedded simulated controller by default)."""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
import time
from typing import Any

from cablesvc.cli.failures import UsageError, zenoh_failure
from cablesvc.cli.run_fleet import run_fleet, run_overrides
from cablesvc.cli.run_session import (
    StartupInterrupted,
    hup_during_startup,
    interrupt_startup,
    print_last_frame,
    reload_on_sighup,
    view,
    wait_until_stopped,
)
from cablesvc.errors import ConfigError

DESCRIPTION = """\
Run the live cable-force predictor beside a robot controller.

With no arguments it runs the embedded default: a simulated IPAnema 3 controller sends
cable lengths, pose and measured forces on an in-process virtual CAN FD bus; the daemon
decodes them with robots/ipanema3-fd.dbc, runs the fixed-time kernel every tick, tracks
drift alarms, and publishes over Zenoh as a peer listening on tcp/127.0.0.1:7447
(multicast scouting off), with a live terminal view. `cablesvc listen` in another
terminal prints what it publishes.

Real use picks a source:
  --source can     --interface socketcan --channel can0 [--dbc robots/R.dbc]
  --source modbus  --host 10.0.0.5 --port 502 [--register-map robots/R.modbus.toml]
  --source replay  --replay rec.mcap [--speed 1 | 0 for as fast as possible] [--loop]
and --zenoh-config FILE for a router, TLS or access control (deploy/zenoh-router.json5).

Key expressions: cablesvc/<robot>/forces, cablesvc/<robot>/alarms, cablesvc/<robot>/status
(queryable), cablesvc/<robot>/alive (liveliness). SIGHUP re-reads the --params file, and a
put of a parameter file's TOML text on cablesvc/<robot>/params switches to it: between two
ticks, keeping the hysteresis state within a model family; a bad file is refused with the
reason and the old parameters stay (status: model, params_reload). SIGINT/SIGTERM shut down cleanly; the
hysteresis state is snapshotted every few seconds and at shutdown and restored at start
when it belongs to the same input and the first tick agrees with it (live sources only by
default: a replay or the embedded simulator uses a state file only when given --snapshot).

Several robots in one daemon (a fleet): a --config file with [[robots]] tables, one per
robot, each with its own robot, params, [robots.source], record, snapshot, [robots.alarms];
the Zenoh keys (zenoh_config, listen, connect, encoding) sit at the top and are shared: one
Zenoh session, each robot under its own cablesvc/<robot>/... keys, one loop thread per
robot (a fault in one robot's input never stops the others). Robot names must be unique.
Per-robot flags (--robot, --source, --replay, --record, --snapshot, ...) do not apply to a
fleet config; the shared ones (--listen, --connect, --zenoh-config, --encoding,
--no-snapshot, --snapshot-interval, --wait-subscriber, --seconds, --no-view) do.
Example: deploy/fleet.example.toml.
"""

EPILOG = """\
examples:
  cablesvc run                                          embedded demo (simulated controller, virtual CAN)
  cablesvc run --robot ipanema3 --source can --interface socketcan --channel can0 --params p.toml
  cablesvc run --source modbus --host 192.168.1.20 --port 502 --no-view
  cablesvc run --source replay --replay rec.mcap --speed 0 --record out.mcap --no-view
  cablesvc run --config daemon.toml                     all of the above from a TOML file
  cablesvc run --config fleet.toml --no-view            several robots, one [[robots]] table each
"""


def add_parser(sub) -> argparse.ArgumentParser:
    r = sub.add_parser("run", help="run the live daemon (embedded simulated controller by default)",
                       description=DESCRIPTION, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("--config", help="daemon TOML file: keys robot, params, zenoh_config, listen, record, snapshot, "
                                    "and tables [source], [alarms]; command-line flags override it. "
                                    "A fleet config (several robots in one daemon) has shared zenoh_config, listen, "
                                    "connect, encoding and one [[robots]] table per robot "
                                    "(deploy/fleet.example.toml)")
    r.add_argument("--robot", help="robot name or .toml path (default: ipanema3)")
    r.add_argument("--params", help="cable-model parameter file from `cablesvc identify` "
                                    "(default: nominal amplitude model from the robot's EA)")
    g = r.add_argument_group("source")
    g.add_argument("--source", choices=["sim", "can", "modbus", "replay"],
                   help="input: sim = embedded simulated controller on a virtual CAN bus (default)")
    g.add_argument("--interface", help="python-can interface (socketcan, virtual, udp_multicast, ...)")
    g.add_argument("--channel", help="python-can channel (can0, ...)")
    g.add_argument("--bitrate", type=int)
    g.add_argument("--fd", action="store_true", default=None,
                   help="CAN FD frames (default DBC robots/<robot>-fd.dbc): a tick in 2 frames, needed for 1 kHz "
                        "(the embedded sim uses FD unless the config file says fd = false)")
    g.add_argument("--dbc", help="DBC file (default robots/<robot>.dbc)")
    g.add_argument("--deadline", type=float, help="CAN: seconds a tick may wait for its frames (default 0.005)")
    g.add_argument("--host", help="Modbus TCP host (default 127.0.0.1)")
    g.add_argument("--port", type=int, help="Modbus TCP port (default 5020)")
    g.add_argument("--unit", type=int, help="Modbus unit id")
    g.add_argument("--register-map", help="Modbus register map TOML (default robots/<robot>.modbus.toml)")
    g.add_argument("--poll-rate", type=float, help="Modbus polls per second (default 100)")
    g.add_argument("--replay", metavar="FILE", help="recording (.mcap or .csv) to replay")
    g.add_argument("--speed", type=float, help="replay speed factor (1 = real time, 0 = as fast as possible)")
    g.add_argument("--loop", action="store_true", help="replay: start again at the end")
    g.add_argument("--scenario", default=None, help="sim: twin scenario (default trajectory)")
    g.add_argument("--rate", type=float, default=None, help="sim: controller tick rate in Hz (default 1000)")
    g.add_argument("--seed", type=int, default=None, help="sim: seed of the simulated controller (default 0)")
    o = r.add_argument_group("outputs")
    o.add_argument("--zenoh-config", help="Zenoh JSON5 config (router, TLS, access control); default: loopback peer")
    o.add_argument("--listen", action="append", help="Zenoh listen endpoint (default tcp/127.0.0.1:7447)")
    o.add_argument("--connect", action="append", help="Zenoh endpoint to connect to (repeatable)")
    o.add_argument("--encoding", choices=["json", "compact"], help="forces payload encoding (default json)")
    o.add_argument("--record", metavar="OUT.mcap", help="record the run: OUT.mcap holds inputs, forces and alarms "
                                                        "(opens in Foxglove), OUT.csv the inputs only; an existing "
                                                        "file is kept unless --overwrite is given")
    o.add_argument("--overwrite", action="store_true", help="let --record replace an existing file")
    o.add_argument("--record-encoding", choices=["protobuf", "json"], default="protobuf",
                   help="input encoding of an .mcap --record: protobuf (binary blocks of ticks, format 2, "
                        "default; fast to read) or json (one JSON message per tick, format 1)")
    o.add_argument("--snapshot", help="hysteresis state file (default for --source can / modbus: "
                                      "~/.local/state/cablesvc/<robot>.state.npz; replays and the simulator: none)")
    o.add_argument("--no-snapshot", action="store_true", help="neither restore nor write the hysteresis state")
    o.add_argument("--snapshot-interval", type=float, default=None, help="seconds between snapshots (default 5)")
    o.add_argument("--wait-subscriber", type=float, default=0.0, metavar="S",
                   help="wait up to S seconds for a forces subscriber before reading the source "
                        "(replays into a tool that must see the first tick)")
    o.add_argument("--no-view", action="store_true", help="no terminal view (daemon / systemd use)")
    o.add_argument("--seconds", type=float, help="stop after this many seconds (default: run until signalled)")
    o.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR")
    r.set_defaults(func=cmd_run)
    return r


def check_flags(args) -> str | None:
    """The command-line values that no config can fix: a one-line message for the first bad
    one (exit status 2), or None."""
    from cablesvc.config.daemon import is_endpoint, seconds_ok

    for flag, v, zero in (("--snapshot-interval", args.snapshot_interval, False), ("--seconds", args.seconds, False),
                          ("--rate", args.rate, False), ("--wait-subscriber", args.wait_subscriber, True)):
        if v is not None and not seconds_ok(v, zero=zero):
            what = "a tick rate in Hz > 0" if flag == "--rate" else f"seconds {'>=' if zero else '>'} 0"
            return f"{flag}: expected {what} (a finite number), got {v!r}"
    for flag, vals in (("--listen", args.listen), ("--connect", args.connect)):
        for v in vals or ():
            if not is_endpoint(v):
                return f"{flag}: a Zenoh endpoint looks like tcp/127.0.0.1:7447, got {v!r}"
    return None


def source_config(args, cfg_source: dict[str, Any] | None) -> dict[str, Any]:
    """Merge the [source] table of the config file (None: none) with the command-line flags."""
    src = dict(cfg_source or {})
    kind = args.source or src.get("kind") or "sim"
    src["kind"] = kind
    flags = {"interface": args.interface, "channel": args.channel, "bitrate": args.bitrate, "dbc": args.dbc,
             "deadline_s": args.deadline, "host": args.host, "port": args.port, "unit": args.unit,
             "register_map": args.register_map, "rate_hz": args.poll_rate, "path": args.replay,
             "speed": args.speed, "fd": args.fd}
    if args.loop:
        flags["loop"] = True
    allowed = {"can": {"interface", "channel", "bitrate", "dbc", "deadline_s", "fd"},
               "sim": {"interface", "channel", "dbc", "deadline_s", "fd"},
               "modbus": {"host", "port", "unit", "register_map", "rate_hz"},
               "replay": {"path", "speed", "loop"}}[kind]
    for k, v in flags.items():
        if v is None:
            continue
        if k not in allowed:
            flag = {"deadline_s": "deadline", "rate_hz": "poll-rate", "path": "replay"}.get(k, k).replace("_", "-")
            raise ConfigError(f"--{flag} does not apply to --source {kind}")
        src[k] = v
    if kind == "replay" and not src.get("path"):
        raise ConfigError("--source replay needs --replay FILE")
    return src


def cmd_run(args) -> int:
    """Start-up (loading files, precomputing the simulated controller, opening the bus and
    Zenoh) takes a few seconds; SIGINT or SIGTERM during it ends the process cleanly with
    status 130 instead of a traceback. SIGHUP during it is kept and served once the daemon
    runs (its default action would kill the process)."""
    signal.signal(signal.SIGINT, interrupt_startup)
    signal.signal(signal.SIGTERM, interrupt_startup)
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, hup_during_startup)
    try:
        return _cmd_run(args)
    except StartupInterrupted as e:
        print(f"cablesvc run: {e} during start-up; nothing was running yet", file=sys.stderr)
        return 130


def _cmd_run(args) -> int:
    import zenoh

    from cablesvc.config.daemon import RobotOverrides, daemon_config, is_fleet_config, load_config, zenoh_where
    from cablesvc.service.daemon import Daemon
    from cablesvc.service.plan import plan_daemon

    logging.basicConfig(level=getattr(logging, str(args.log_level).upper(), logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    bad = check_flags(args)
    if bad:
        raise UsageError(bad)
    raw = load_config(args.config)
    if is_fleet_config(raw):
        return run_fleet(args, raw, str(args.config))
    cfg = daemon_config(raw, str(args.config))
    src = source_config(args, raw.get("source"))
    if src["kind"] != "sim" and (args.scenario is not None or args.rate is not None or args.seed is not None):
        raise UsageError("--scenario, --rate and --seed apply to --source sim only")
    one = RobotOverrides(robot=args.robot, params=args.params, record=args.record, snapshot=args.snapshot,
                         scenario=args.scenario, rate=args.rate, seed=args.seed)
    shared, plan = plan_daemon(cfg, src, run_overrides(args), one)
    opts, controller = plan.options, plan.controller
    robot, params, src = opts.robot, opts.params, opts.source
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    try:
        daemon = Daemon(opts)
    except zenoh.ZError as e:                        # start-up failures get one clear line, not a traceback
        raise zenoh_failure("open the Zenoh session", zenoh_where(shared), e) from None
    signal.signal(signal.SIGINT, on_signal)          # from here on: a clean shutdown
    signal.signal(signal.SIGTERM, on_signal)
    if hasattr(signal, "SIGHUP"):
        reload_on_sighup([daemon])
    log = logging.getLogger("cablesvc.run")
    log.info("cablesvc %s: robot %s, source %s, model %s, zenoh %s", robot.name, robot.name,
             json.dumps(src, default=str), params.model,
             opts.zenoh_config_file or f"peer on {', '.join(opts.listen or ('tcp/127.0.0.1:7447',))}")
    if daemon.restored_from:
        log.info("hysteresis state restored from %s", daemon.restored_from)
    errors: list[str] = []

    def loop():
        # an exception ends the loop: logged, and the exit status says so (as for a fleet)
        try:
            daemon.run(stop)
        except BaseException as e:  # noqa: BLE001
            errors.append(f"{type(e).__name__}: {e}")
            log.exception("the loop stopped: %s", e)

    worker = threading.Thread(target=loop, name="cablesvc-loop", daemon=True)
    if controller is not None:
        controller.start()
    worker.start()
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    last_frame: list = []
    try:
        if args.no_view:
            wait_until_stopped(worker.is_alive, stop, deadline)
        else:
            view([(daemon, robot, daemon.geom)], stop, worker.is_alive, deadline, last_frame)
    finally:
        stop.set()
        t0 = time.monotonic()
        if controller is not None:
            controller.stop()
        worker.join(1.0)
        daemon.close()
        print_last_frame(last_frame)
        st = daemon.status()
        log.info("stopped in %.2f s after %d ticks; input %s; latency %s", time.monotonic() - t0, st["ticks"],
                 json.dumps(st["input"]), json.dumps(st["latency_us"]))
        if "recording" in st:
            r = st["recording"]
            log.info("recording %s: %d ticks written, %d missing", r["path"], r["written"], r["missing"])
        bad_lines = getattr(daemon.source, "bad_lines", 0)
        if bad_lines:
            log.warning("replay %s: %d line(s) rejected as unreadable (each named above); the other ticks "
                        "were played", src.get("path"), bad_lines)
    if errors:
        log.error("robot %s: its loop ended with an error: %s", robot.name, errors[0])
        return 1
    failed = daemon.exit_problems()
    for line in failed:
        print(f"cablesvc run: {line}", file=sys.stderr)
    return 1 if failed else 0
