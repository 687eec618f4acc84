"""``cablesvc run``: the live daemon (embedded simulated controller by default)."""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time
import tomllib
from pathlib import Path
from typing import Any

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
(queryable), cablesvc/<robot>/alive (liveliness). SIGINT/SIGTERM shut down cleanly; the
hysteresis state is snapshotted every few seconds and at shutdown and restored at start.
"""

EPILOG = """\
examples:
  cablesvc run                                          embedded demo (simulated controller, virtual CAN)
  cablesvc run --robot ipanema3 --source can --interface socketcan --channel can0 --params p.toml
  cablesvc run --source modbus --host 192.168.1.20 --port 502 --no-view
  cablesvc run --source replay --replay rec.mcap --speed 0 --record out.mcap --no-view
  cablesvc run --config daemon.toml                     all of the above from a TOML file
"""


def add_parser(sub) -> argparse.ArgumentParser:
    r = sub.add_parser("run", help="run the live daemon (embedded simulated controller by default)",
                       description=DESCRIPTION, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    r.add_argument("--config", help="daemon TOML file: keys robot, params, zenoh_config, listen, record, snapshot, "
                                    "and tables [source], [alarms]; command-line flags override it")
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
    g.add_argument("--seed", type=int, default=0, help="sim: seed of the simulated controller")
    o = r.add_argument_group("outputs")
    o.add_argument("--zenoh-config", help="Zenoh JSON5 config (router, TLS, access control); default: loopback peer")
    o.add_argument("--listen", action="append", help="Zenoh listen endpoint (default tcp/127.0.0.1:7447)")
    o.add_argument("--connect", action="append", help="Zenoh endpoint to connect to (repeatable)")
    o.add_argument("--encoding", choices=["json", "compact"], help="forces payload encoding (default json)")
    o.add_argument("--record", metavar="OUT.mcap", help="write inputs, forces and alarms to MCAP (opens in Foxglove)")
    o.add_argument("--snapshot", help="hysteresis state file (default ~/.local/state/cablesvc/<robot>.state.npz)")
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


def _load_config(path: str | None) -> dict[str, Any]:
    if not path:
        return {}
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise SystemExit(f"cablesvc run: config file {path} not found")
    except tomllib.TOMLDecodeError as e:
        raise SystemExit(f"cablesvc run: {path}: not valid TOML: {e}")


def nominal_params(geom):
    """The default model when no parameter file is given: nominal amplitude model (EA / L)."""
    import numpy as np

    from cablesvc.config.params import default_params
    from cablesvc.kinematics import inverse_kinematics

    L = inverse_kinematics(geom, np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]])).length[0]
    return default_params(geom.ea, L, "amplitude")


def source_config(args, cfg: dict[str, Any], robot_name: str) -> dict[str, Any]:
    """Merge the [source] table of the config file with the command-line flags."""
    src = dict(cfg.get("source", {}))
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
            raise SystemExit(f"cablesvc run: --{flag} does not apply to --source {kind}")
        src[k] = v
    if kind == "replay" and not src.get("path"):
        raise SystemExit("cablesvc run: --source replay needs --replay FILE")
    return src


class _StartupInterrupted(Exception):
    pass


def _interrupt_startup(signum, frame):
    raise _StartupInterrupted(signal.Signals(signum).name)


def cmd_run(args) -> int:
    """Start-up (loading files, precomputing the simulated controller, opening the bus and
    Zenoh) takes a few seconds; SIGINT or SIGTERM during it ends the process cleanly with
    status 130 instead of a traceback."""
    signal.signal(signal.SIGINT, _interrupt_startup)
    signal.signal(signal.SIGTERM, _interrupt_startup)
    try:
        return _cmd_run(args)
    except _StartupInterrupted as e:
        print(f"cablesvc run: {e} during start-up; nothing was running yet", file=sys.stderr)
        return 130


def _cmd_run(args) -> int:
    from cablesvc.config import load_robot
    from cablesvc.config.params import load_params
    from cablesvc.service.daemon import Daemon, DaemonOptions, default_snapshot_path

    logging.basicConfig(level=getattr(logging, str(args.log_level).upper(), logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    cfg = _load_config(args.config)
    robot = load_robot(args.robot or cfg.get("robot") or "ipanema3")
    geom = robot.geometry()
    params_file = args.params or cfg.get("params")
    params = load_params(params_file) if params_file else nominal_params(geom)
    if params.robot and params.robot != robot.name:
        print(f"cablesvc run: {params.source} was identified for robot {params.robot!r}, not {robot.name!r}",
              file=sys.stderr)
        return 1
    src = source_config(args, cfg, robot.name)
    controller = None
    if src["kind"] == "sim":
        # the embedded default: the simulated controller and the daemon share a virtual CAN bus
        from cablesvc.sources.controller import CanController
        channel = src.get("channel") or f"cablesvc-sim-{os.getpid()}"
        bus = {"interface": src.get("interface") or "virtual", "channel": channel}
        # 10 s of twin motion, played forwards and backwards without end
        fd = src.get("fd", True) is not False          # 1 kHz needs the FD layout (docs/sources.md)
        src["fd"] = fd
        controller = CanController(robot, bus, dbc=src.get("dbc"), scenario=args.scenario or "trajectory",
                                   rate=args.rate or 1000.0, seed=args.seed, duration=10.0, fd=fd)
        # the controller thread shares the interpreter: allow it to be held off by the GIL mid-tick
        src = {"kind": "can", "interface": bus["interface"], "channel": channel, "deadline_s": 0.05,
               **{k: v for k, v in src.items() if k in ("dbc", "deadline_s", "fd")}}
    elif args.scenario or args.rate:
        print("cablesvc run: --scenario and --rate apply to --source sim only", file=sys.stderr)
        return 2
    snapshot = None
    if not args.no_snapshot:
        snapshot = Path(args.snapshot or cfg.get("snapshot") or default_snapshot_path(robot.name))
    alarm_cfg = None
    if "alarms" in cfg:
        from cablesvc.alarms import AlarmConfig
        alarm_cfg = AlarmConfig.model_validate(cfg["alarms"])
    opts = DaemonOptions(
        robot=robot, params=params, source=src,
        zenoh_config_file=args.zenoh_config or cfg.get("zenoh_config"),
        listen=tuple(args.listen or cfg.get("listen")) if (args.listen or cfg.get("listen")) else None,
        connect=tuple(args.connect or cfg.get("connect")) if (args.connect or cfg.get("connect")) else None,
        encoding=args.encoding or cfg.get("encoding", "json"),
        record=Path(args.record or cfg["record"]) if (args.record or cfg.get("record")) else None,
        snapshot=snapshot,
        snapshot_interval_s=args.snapshot_interval or cfg.get("snapshot_interval", 5.0),
        alarm_config=alarm_cfg,
        wait_subscriber_s=args.wait_subscriber,
    )
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    try:
        daemon = Daemon(opts)
    except Exception as e:  # noqa: BLE001 - start-up failures get one clear line, not a traceback
        from cablesvc.sources import SourceConfigError
        if isinstance(e, SourceConfigError):
            print(f"cablesvc run: {e}", file=sys.stderr)
            return 1
        if type(e).__module__.startswith("zenoh") or type(e).__name__ == "ZError":
            where = opts.zenoh_config_file or f"listen {', '.join(opts.listen or ('tcp/127.0.0.1:7447',))}"
            print(f"cablesvc run: cannot open the Zenoh session ({where}): {str(e).split(' at /')[0]}",
                  file=sys.stderr)
            return 1
        raise
    signal.signal(signal.SIGINT, on_signal)          # from here on: a clean shutdown
    signal.signal(signal.SIGTERM, on_signal)
    log = logging.getLogger("cablesvc.run")
    log.info("cablesvc %s: robot %s, source %s, model %s, zenoh %s", robot.name, robot.name,
             json.dumps(src, default=str), params.model,
             opts.zenoh_config_file or f"peer on {', '.join(opts.listen or ('tcp/127.0.0.1:7447',))}")
    if daemon.restored_from:
        log.info("hysteresis state restored from %s", daemon.restored_from)
    worker = threading.Thread(target=daemon.run, args=(stop,), name="cablesvc-loop", daemon=True)
    if controller is not None:
        controller.start()
    worker.start()
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    try:
        if args.no_view:
            while worker.is_alive() and not stop.is_set():
                stop.wait(0.1)
                if deadline is not None and time.monotonic() >= deadline:
                    stop.set()
        else:
            _view(daemon, robot, geom, stop, worker, deadline)
    finally:
        stop.set()
        t0 = time.monotonic()
        if controller is not None:
            controller.stop()
        worker.join(1.0)
        daemon.close()
        st = daemon.status()
        log.info("stopped in %.2f s after %d ticks; input %s; latency %s", time.monotonic() - t0, st["ticks"],
                 json.dumps(st["input"]), json.dumps(st["latency_us"]))
    return 0


def _view(daemon, robot, geom, stop: threading.Event, worker: threading.Thread, deadline) -> None:
    """Live terminal view of forces and alarms (main thread), refreshed eight times a second."""
    import numpy as np
    from rich.console import Group
    from rich.live import Live
    from rich.table import Table

    def render():
        st = daemon.status()
        v = daemon.view()
        lat = st["latency_us"]
        head = (f"cablesvc · {robot.name} · {st['input']['source']} · {st['tick_rate_hz']:.0f} Hz · "
                f"{st['ticks']} ticks · latency p50/p99 {lat.get('p50_us', 0)}/{lat.get('p99_us', 0)} us · "
                f"rejected {sum(st['input'].get('rejected', {}).values())}")
        tb = Table(title=head, expand=False)
        for col in ("cable", "predicted N", "measured N", "residual N", "elongation mm", "wrap deg", "slack"):
            tb.add_column(col, justify="right")
        if v is not None:
            for i in range(geom.n_cables):
                tb.add_row(geom.cable_names[i], f"{v['force'][i]:8.2f}", f"{v['measured'][i]:8.2f}",
                           f"{v['residual'][i]:+7.2f}", f"{v['elongation'][i] * 1e3:7.3f}",
                           f"{np.degrees(v['wrap_angle'][i]):6.1f}", "yes" if v["slack"][i] else "")
        al = Table(title="active alarms", expand=False)
        for col in ("code", "cable", "severity", "since s", "message"):
            al.add_column(col)
        for a in st["alarms_active"]:
            al.add_row(a["code"], "" if a.get("cable") is None else geom.cable_names[a["cable"]], a["severity"],
                       f"{a.get('since', 0):.2f}", a["message"])
        return Group(tb, al)

    with Live(render(), refresh_per_second=8, transient=False) as live:
        while worker.is_alive() and not stop.is_set():
            stop.wait(0.125)
            live.update(render())
            if deadline is not None and time.monotonic() >= deadline:
                stop.set()
