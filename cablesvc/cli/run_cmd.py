"""``cablesvc run``: the live daemon (embedded simulated controller by default)."""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import signal
import sys
import threading
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

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


def _load_config(path: str | None) -> dict[str, Any]:
    if not path:
        return {}
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise SystemExit(f"cablesvc run: config file {path} not found")
    except IsADirectoryError:
        raise SystemExit(f"cablesvc run: config file {path} is a directory, not a TOML file")
    except UnicodeDecodeError as e:
        raise SystemExit(f"cablesvc run: {path}: not valid TOML: not UTF-8 text ({e.reason} at byte {e.start})")
    except tomllib.TOMLDecodeError as e:
        raise SystemExit(f"cablesvc run: {path}: not valid TOML: {e}")
    except OSError as e:
        raise SystemExit(f"cablesvc run: cannot read config file {path}: {e.strerror or e}")


def _sim_controller(robot, src: dict[str, Any], *, scenario: str | None, rate: float | None, seed: int | None,
                    channel: str):
    """The embedded default: a simulated controller (not started) on a virtual CAN bus, and
    the CAN source config that reads that bus: (controller, source dict)."""
    from cablesvc.sources.controller import CanController

    bus = {"interface": src.get("interface") or "virtual", "channel": channel}
    # 10 s of twin motion, played forwards and backwards without end
    fd = src.get("fd", True) is not False          # 1 kHz needs the FD layout (docs/sources.md)
    src = {**src, "fd": fd}
    controller = CanController(robot, bus, dbc=src.get("dbc"), scenario=scenario or "trajectory",
                               rate=1000.0 if rate is None else rate, seed=seed or 0, duration=10.0, fd=fd)
    # the controller thread shares the interpreter: allow it to be held off by the GIL mid-tick
    return controller, {"kind": "can", "interface": bus["interface"], "channel": channel, "deadline_s": 0.05,
                        **{k: v for k, v in src.items() if k in ("dbc", "deadline_s", "fd")}}


def sim_rate_problem(rate: Any, n_cables: int) -> str | None:
    """Why the embedded controller cannot tick at ``rate`` [Hz] (None: the default), or None:
    above the rate the daemon's kernel can follow (cablesvc.cli.limits.MAX_LIVE_RATE_HZ), or
    more memory than there is for the motion it precomputes. Checked before it is built."""
    from cablesvc.cli.limits import MAX_LIVE_RATE_HZ, SIM_CONTROLLER_SECONDS, memory_problem, twin_bytes

    if rate is None:
        return None
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (math.isfinite(rate) and rate > 0):
        return f"rate: expected a tick rate in Hz > 0 (a finite number), got {rate!r}"
    if rate > MAX_LIVE_RATE_HZ:
        return (f"rate {rate:g} Hz: the daemon's kernel cannot follow a controller faster than {MAX_LIVE_RATE_HZ} Hz "
                "(half a tick at its fastest measured 53 us per tick; cablesvc/cli/limits.py)")
    return memory_problem(f"rate {rate:g} Hz x the {SIM_CONTROLLER_SECONDS:g} s the simulated controller precomputes",
                          twin_bytes(rate * SIM_CONTROLLER_SECONDS, n_cables))


def sim_source_id(robot_name: str) -> str:
    """The snapshot identity of an embedded simulated controller: a new one at every start
    (it starts from rest), so no later start restores its state."""
    import uuid

    return f"sim:{robot_name}:{uuid.uuid4().hex}"


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


# ---- fleet configs: several robots in one daemon ---------------------------------------

FLEET_SHARED_KEYS = ("zenoh_config", "listen", "connect", "encoding")
FLEET_ROBOT_KEYS = ("robot", "params", "source", "record", "snapshot", "snapshot_interval", "alarms")
# the embedded simulated controller, per robot of a fleet (each on its own virtual CAN bus)
FLEET_SIM_KEYS = ("kind", "fd", "dbc", "scenario", "rate", "seed")
# flags that configure one robot: in a fleet config each [[robots]] entry says these
_PER_ROBOT_FLAGS = (("robot", "--robot"), ("params", "--params"), ("source", "--source"),
                    ("interface", "--interface"), ("channel", "--channel"), ("bitrate", "--bitrate"),
                    ("fd", "--fd"), ("dbc", "--dbc"), ("deadline", "--deadline"), ("host", "--host"),
                    ("port", "--port"), ("unit", "--unit"), ("register_map", "--register-map"),
                    ("poll_rate", "--poll-rate"), ("replay", "--replay"), ("speed", "--speed"),
                    ("scenario", "--scenario"), ("rate", "--rate"), ("seed", "--seed"), ("record", "--record"),
                    ("snapshot", "--snapshot"))


class FleetConfigError(ValueError):
    """A fleet config (``[[robots]]``) that cannot be used; the message names the file and the
    entry (``fleet.toml: robots[1].source.path: ...``)."""


@dataclass
class RobotPlan:
    """One robot of a fleet, ready to start: its daemon options, its source (built, not
    opened), its simulated controller (``kind = "sim"`` only) and its entry (``robots[i]``)."""

    where: str
    options: Any                 # DaemonOptions
    source: Any = None
    controller: Any = None


def is_fleet_config(cfg: dict[str, Any]) -> bool:
    """A config with ``[[robots]]`` tables describes several robots in one daemon."""
    return "robots" in cfg


def _endpoints_of(value: Any, where: str) -> tuple[str, ...]:
    vals = [value] if isinstance(value, str) else value
    if not isinstance(vals, list) or not all(isinstance(v, str) and _is_endpoint(v) for v in vals):
        raise FleetConfigError(f"{where}: expected a list of Zenoh endpoints like [\"tcp/127.0.0.1:7447\"], "
                               f"got {value!r}")
    return tuple(vals)


def _is_endpoint(v: str) -> bool:
    """A Zenoh endpoint has the form ``proto/address`` (``tcp/127.0.0.1:7447``)."""
    proto, _, addr = v.partition("/")
    return bool(proto) and bool(addr) and v == v.strip()


def _seconds_ok(v: Any, *, zero: bool = False) -> bool:
    """A number of seconds: finite and > 0 (>= 0 with ``zero``); bools are not numbers here."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return False
    return v >= 0 if zero else v > 0


def check_flags(args) -> str | None:
    """The command-line values that no config can fix: a one-line message for the first bad
    one (exit status 2), or None."""
    for flag, v, zero in (("--snapshot-interval", args.snapshot_interval, False), ("--seconds", args.seconds, False),
                          ("--rate", args.rate, False), ("--wait-subscriber", args.wait_subscriber, True)):
        if v is not None and not _seconds_ok(v, zero=zero):
            what = "a tick rate in Hz > 0" if flag == "--rate" else f"seconds {'>=' if zero else '>'} 0"
            return f"{flag}: expected {what} (a finite number), got {v!r}"
    for flag, vals in (("--listen", args.listen), ("--connect", args.connect)):
        for v in vals or ():
            if not _is_endpoint(v):
                return f"{flag}: a Zenoh endpoint looks like tcp/127.0.0.1:7447, got {v!r}"
    return None


SINGLE_SOURCE_KINDS = ("sim", "can", "modbus", "replay")
# the [source] table of a single-robot config with kind = "sim" (the embedded simulated controller)
SINGLE_SIM_KEYS = FLEET_SIM_KEYS + ("interface", "channel", "deadline_s")


def _alarm_error(ex: Exception) -> str:
    """pydantic's message on one line: ``foo: Extra inputs are not permitted; ...``."""
    errors = getattr(ex, "errors", None)
    if callable(errors):
        try:
            return "; ".join(f"{'.'.join(str(x) for x in err.get('loc', ())) or '(table)'}: {err.get('msg')}"
                             for err in errors())
        except Exception:  # noqa: BLE001 - fall back to the first line
            pass
    return str(ex).splitlines()[0] if str(ex) else type(ex).__name__


def check_single_config(cfg: dict[str, Any], file: str) -> None:
    """Check a single-robot config (no [[robots]]) the way :func:`plan_fleet` checks a fleet
    entry: unknown keys and values of the wrong type are a :class:`FleetConfigError` naming
    the file and the key (``daemon.toml: source: expected a table ...``)."""
    allowed = FLEET_SHARED_KEYS + FLEET_ROBOT_KEYS
    for k in cfg:
        if k not in allowed:
            raise FleetConfigError(f"{file}: {k}: unknown key; a daemon config has {', '.join(allowed)} "
                                   "(or [[robots]] tables for a fleet)")
    for k, what in (("robot", "a robot name in robots/ or a path to a robot .toml"),
                    ("params", "a path to a parameter file from `cablesvc identify`"),
                    ("record", "a path to an .mcap file"), ("snapshot", "a path to a state file"),
                    ("zenoh_config", "a path to a Zenoh JSON5 file")):
        if k in cfg and (not isinstance(cfg[k], str) or not cfg[k]):
            raise FleetConfigError(f"{file}: {k}: expected {what}, got {cfg[k]!r}")
    if "snapshot_interval" in cfg and not _seconds_ok(cfg["snapshot_interval"]):
        raise FleetConfigError(f"{file}: snapshot_interval: expected seconds > 0 (a finite number), "
                               f"got {cfg['snapshot_interval']!r}")
    if "source" in cfg:
        src = cfg["source"]
        if not isinstance(src, dict):
            raise FleetConfigError(f"{file}: source: expected a table ([source]) with a kind, got {src!r}")
        kind = src.get("kind", "sim")
        if kind not in SINGLE_SOURCE_KINDS:
            raise FleetConfigError(f"{file}: source.kind: expected one of {', '.join(SINGLE_SOURCE_KINDS)}, "
                                   f"got {kind!r}")
        if kind == "sim":
            bad = sorted(set(src) - set(SINGLE_SIM_KEYS))
            if bad:
                raise FleetConfigError(f"{file}: source.{bad[0]}: unknown for kind \"sim\" (the embedded simulated "
                                       f"controller); it takes {', '.join(SINGLE_SIM_KEYS)}")
    if "alarms" in cfg:
        from cablesvc.alarms import AlarmConfig
        if not isinstance(cfg["alarms"], dict):
            raise FleetConfigError(f"{file}: alarms: expected a table ([alarms]), got {cfg['alarms']!r}")
        try:
            AlarmConfig.model_validate(cfg["alarms"])
        except Exception as ex:  # noqa: BLE001 - pydantic's message names the field
            raise FleetConfigError(f"{file}: alarms.{_alarm_error(ex)}") from None


def fleet_shared(args, cfg: dict[str, Any], file: str) -> dict[str, Any]:
    """The shared Zenoh settings of a fleet config, command-line flags first:
    ``zenoh_config_file``, ``listen``, ``connect`` (None: not given) and ``encoding``."""
    # the file's values are checked even where a flag overrides them: a bad file is a bad file
    cfg_listen = None if cfg.get("listen") is None else _endpoints_of(cfg["listen"], f"{file}: listen")
    cfg_connect = None if cfg.get("connect") is None else _endpoints_of(cfg["connect"], f"{file}: connect")
    listen = args.listen or cfg_listen
    connect = args.connect or cfg_connect
    zc = args.zenoh_config or cfg.get("zenoh_config")
    if zc is not None and not isinstance(zc, str):
        raise FleetConfigError(f"{file}: zenoh_config: expected a path to a Zenoh JSON5 file, got {zc!r}")
    enc = args.encoding or cfg.get("encoding", "json")
    if enc not in ("json", "compact"):
        raise FleetConfigError(f"{file}: encoding: expected \"json\" or \"compact\", got {enc!r}")
    return {"zenoh_config_file": zc, "listen": tuple(listen) if listen else None,
            "connect": tuple(connect) if connect else None, "encoding": enc}


def plan_fleet(args, cfg: dict[str, Any], file: str) -> tuple[dict[str, Any], list[RobotPlan]]:
    """Check a fleet config and build what each robot needs: (shared Zenoh settings, plans).

    Every problem is a :class:`FleetConfigError` naming ``file`` and the entry
    (``robots[1].source.path: recording x.mcap not found``): unknown keys, Zenoh keys inside
    an entry (they are shared), per-robot command-line flags, a bad robot / parameter /
    source / alarms table, two entries with the same robot name, the same record or
    snapshot file. Nothing is opened; simulated controllers are built (not started) only
    once every entry is valid.
    """
    from cablesvc.alarms import AlarmConfig
    from cablesvc.config import load_robot
    from cablesvc.config.params import load_params, nominal_params
    from cablesvc.service.daemon import DaemonOptions, default_snapshot_path
    from cablesvc.service.fleet import duplicate_names
    from cablesvc.sources import SourceConfigError, open_source

    flags = [flag for attr, flag in _PER_ROBOT_FLAGS if getattr(args, attr, None) not in (None, False)]
    if getattr(args, "loop", False):
        flags.append("--loop")
    if flags:
        raise FleetConfigError(f"{file}: {', '.join(flags)} configure(s) one robot and do(es) not apply to a fleet "
                               "config; set it in the [[robots]] entry")
    for k in cfg:
        if k in FLEET_ROBOT_KEYS:
            raise FleetConfigError(f"{file}: {k}: belongs in each [[robots]] entry of a fleet config "
                                   "(this file has [[robots]] tables)")
        if k not in FLEET_SHARED_KEYS and k != "robots":
            raise FleetConfigError(f"{file}: {k}: unknown key; a fleet config has {', '.join(FLEET_SHARED_KEYS)} "
                                   "and [[robots]] tables")
    entries = cfg["robots"]
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise FleetConfigError(f"{file}: robots: expected one or more [[robots]] tables, got {entries!r}")
    shared = fleet_shared(args, cfg, file)

    plans: list[RobotPlan] = []
    sims: list[tuple[int, dict[str, Any]]] = []
    for i, e in enumerate(entries):
        where = f"{file}: robots[{i}]"
        for k in e:
            if k in FLEET_SHARED_KEYS:
                raise FleetConfigError(f"{where}.{k}: the Zenoh settings are shared by every robot; "
                                       f"set {k} at the top of the file")
            if k not in FLEET_ROBOT_KEYS:
                raise FleetConfigError(f"{where}.{k}: unknown key; an entry has {', '.join(FLEET_ROBOT_KEYS)}")
        if not isinstance(e.get("robot"), str) or not e["robot"]:
            raise FleetConfigError(f"{where}.robot: missing or not a string (a robot name in robots/ or a path to "
                                   "a robot .toml)")
        try:
            robot = load_robot(e["robot"])
            geom = robot.geometry()
        except Exception as ex:  # noqa: BLE001 - RobotFileError and friends: one message
            raise FleetConfigError(f"{where}.robot: {ex}") from None
        try:
            params = load_params(e["params"]) if e.get("params") else nominal_params(geom)
        except Exception as ex:  # noqa: BLE001 - ParamFileError lists every problem
            raise FleetConfigError(f"{where}.params: {ex}") from None
        if params.robot and params.robot != robot.name:
            raise FleetConfigError(f"{where}.params: {params.source} was identified for robot {params.robot!r}, "
                                   f"not {robot.name!r}")
        src = e.get("source", {"kind": "sim"})
        if not isinstance(src, dict):
            raise FleetConfigError(f"{where}.source: expected a table ([robots.source]) with a kind, got {src!r}")
        src = dict(src)
        src.setdefault("kind", "sim")
        source = None
        if src["kind"] == "sim":
            bad = sorted(set(src) - set(FLEET_SIM_KEYS))
            if bad:
                raise FleetConfigError(f"{where}.source.{bad[0]}: unknown for kind \"sim\" (the embedded simulated "
                                       f"controller); it takes {', '.join(FLEET_SIM_KEYS)}")
            sims.append((i, src))
        else:
            try:
                source = open_source(robot, src)       # checks every field and the files it names; opens nothing
            except SourceConfigError as ex:
                raise FleetConfigError(f"{where}.{ex}") from None
        alarm_cfg = None
        if "alarms" in e:
            try:
                alarm_cfg = AlarmConfig.model_validate(e["alarms"])
            except Exception as ex:  # noqa: BLE001 - pydantic's message names the field
                raise FleetConfigError(f"{where}.alarms: {ex}") from None
        interval = e.get("snapshot_interval", 5.0) if args.snapshot_interval is None else args.snapshot_interval
        if not _seconds_ok(interval):
            raise FleetConfigError(f"{where}.snapshot_interval: expected seconds > 0, got {interval!r}")
        snapshot = None
        if not args.no_snapshot:
            live = src["kind"] not in ("sim", "replay")        # the default file is the live robot's
            snapshot = e.get("snapshot") or (default_snapshot_path(robot.name) if live else None)
            snapshot = Path(snapshot) if snapshot else None
        record = Path(e["record"]) if e.get("record") else None
        opts = DaemonOptions(robot=robot, params=params, source=src, encoding=shared["encoding"],
                             params_file=str(e["params"]) if e.get("params") else None,
                             zenoh_config_file=shared["zenoh_config_file"], listen=shared["listen"],
                             connect=shared["connect"], record=record, snapshot=snapshot,
                             snapshot_interval_s=float(interval), alarm_config=alarm_cfg,
                             wait_subscriber_s=args.wait_subscriber,
                             record_overwrite=bool(getattr(args, "overwrite", False)),
                             record_encoding=getattr(args, "record_encoding", None) or "protobuf")
        plans.append(RobotPlan(where=f"robots[{i}]", options=opts, source=source))

    for first, again, name in duplicate_names([p.options.robot.name for p in plans]):
        raise FleetConfigError(f"{file}: robots[{again}].robot: robot name {name!r} is already used by "
                               f"robots[{first}]; names must be unique (each robot publishes under "
                               f"cablesvc/<name>/ and snapshots to its own file)")
    for what in ("record", "snapshot"):
        paths = [None if getattr(p.options, what) is None else os.path.abspath(getattr(p.options, what))
                 for p in plans]
        for first, again, path in duplicate_names(paths):
            if path is not None:
                raise FleetConfigError(f"{file}: robots[{again}].{what}: {path} is also robots[{first}]'s {what} "
                                       "file; each robot needs its own")
    # a robot's record file must not be another robot's replay input (its own is refused by its daemon)
    replays = {os.path.realpath(p.options.source["path"]): j for j, p in enumerate(plans)
               if p.options.source.get("kind") == "replay" and p.options.source.get("path")}
    for i, p in enumerate(plans):
        j = replays.get(os.path.realpath(p.options.record)) if p.options.record is not None else None
        if j is not None:
            raise FleetConfigError(f"{file}: robots[{i}].record: {p.options.record} is robots[{j}]'s replay input; "
                                   "recording onto it would destroy it")

    for i, src in sims:
        plan = plans[i]
        if why := sim_rate_problem(src.get("rate"), plan.options.robot.n_cables):
            raise FleetConfigError(f"{file}: {plan.where}.source.{why}")
        try:
            controller, can_src = _sim_controller(plan.options.robot, src, scenario=src.get("scenario"),
                                                  rate=src.get("rate"), seed=src.get("seed"),
                                                  channel=f"cablesvc-sim-{os.getpid()}-{plan.options.robot.name}")
        except Exception as ex:  # noqa: BLE001 - no DBC for this robot, a bad scenario, ...: one line
            raise FleetConfigError(f"{file}: {plan.where}.source (sim): {ex}") from None
        plan.controller = controller
        plan.options.source = can_src
        plan.options.source_id = sim_source_id(plan.options.robot.name)
    return shared, plans


class _StartupInterrupted(Exception):
    pass


def _interrupt_startup(signum, frame):
    raise _StartupInterrupted(signal.Signals(signum).name)


#: SIGHUP received while starting (before a daemon could take it): reload once it runs
_HUP_EARLY: list[int] = []


def _hup_during_startup(signum, frame):
    _HUP_EARLY.append(signum)


def _reload_on_sighup(daemons) -> None:
    """From here on SIGHUP makes every daemon re-read its parameter file (the handler only
    queues the request; each daemon's reload thread reads and checks the file, its loop
    switches between two ticks). A SIGHUP that came during start-up is served now."""
    def on_hup(signum, frame):
        for d in daemons:
            d.request_reload(origin="SIGHUP")

    signal.signal(signal.SIGHUP, on_hup)
    if _HUP_EARLY:
        _HUP_EARLY.clear()
        on_hup(signal.SIGHUP, None)


def cmd_run(args) -> int:
    """Start-up (loading files, precomputing the simulated controller, opening the bus and
    Zenoh) takes a few seconds; SIGINT or SIGTERM during it ends the process cleanly with
    status 130 instead of a traceback. SIGHUP during it is kept and served once the daemon
    runs (its default action would kill the process)."""
    signal.signal(signal.SIGINT, _interrupt_startup)
    signal.signal(signal.SIGTERM, _interrupt_startup)
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, _hup_during_startup)
    try:
        return _cmd_run(args)
    except _StartupInterrupted as e:
        print(f"cablesvc run: {e} during start-up; nothing was running yet", file=sys.stderr)
        return 130


def _cmd_run(args) -> int:
    from cablesvc.config import load_robot
    from cablesvc.config.params import load_params, nominal_params
    from cablesvc.service.daemon import Daemon, DaemonOptions, default_snapshot_path

    logging.basicConfig(level=getattr(logging, str(args.log_level).upper(), logging.INFO),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    bad = check_flags(args)
    if bad:
        print(f"cablesvc run: {bad}", file=sys.stderr)
        return 2
    cfg = _load_config(args.config)
    if is_fleet_config(cfg):
        return _run_fleet(args, cfg, str(args.config))
    file = str(args.config)
    try:
        check_single_config(cfg, file)
        shared = fleet_shared(args, cfg, file)
    except FleetConfigError as e:
        print(f"cablesvc run: {e}", file=sys.stderr)
        return 1
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
        from cablesvc.sources import SourceConfigError
        sim = {k: src.pop(k) for k in ("scenario", "rate", "seed") if k in src}
        scenario = args.scenario if args.scenario is not None else sim.get("scenario")
        rate = args.rate if args.rate is not None else sim.get("rate")
        seed = args.seed if args.seed is not None else sim.get("seed")
        if why := sim_rate_problem(rate, robot.n_cables):
            print(f"cablesvc run: {'--' if args.rate is not None else 'source.'}{why}", file=sys.stderr)
            return 2
        try:
            controller, src = _sim_controller(robot, src, scenario=scenario, rate=rate, seed=seed,
                                              channel=src.get("channel") or f"cablesvc-sim-{os.getpid()}")
        except (SourceConfigError, ValueError, TypeError, KeyError) as e:
            # no DBC for this robot, an unknown scenario, a bad rate in the config: one line
            msg = e.args[0] if isinstance(e, KeyError) and e.args else e
            print(f"cablesvc run: cannot start the simulated controller (source sim) for robot {robot.name!r}: "
                  f"{msg}", file=sys.stderr)
            return 1
    elif args.scenario is not None or args.rate is not None or args.seed is not None:
        print("cablesvc run: --scenario, --rate and --seed apply to --source sim only", file=sys.stderr)
        return 2
    snapshot = None
    if not args.no_snapshot:
        # the default state file is the live robot's: a replay or the embedded simulator (a
        # new simulated controller at every start) uses one only when given one
        live = controller is None and src["kind"] != "replay"
        snapshot = args.snapshot or cfg.get("snapshot") or (default_snapshot_path(robot.name) if live else None)
        snapshot = Path(snapshot) if snapshot else None
    alarm_cfg = None
    if "alarms" in cfg:
        from cablesvc.alarms import AlarmConfig
        alarm_cfg = AlarmConfig.model_validate(cfg["alarms"])       # checked above
    interval = cfg.get("snapshot_interval", 5.0) if args.snapshot_interval is None else args.snapshot_interval
    opts = DaemonOptions(
        robot=robot, params=params, source=src,
        zenoh_config_file=shared["zenoh_config_file"],
        listen=shared["listen"],
        connect=shared["connect"],
        encoding=shared["encoding"],
        record=Path(args.record or cfg["record"]) if (args.record or cfg.get("record")) else None,
        snapshot=snapshot,
        snapshot_interval_s=float(interval),
        alarm_config=alarm_cfg,
        wait_subscriber_s=args.wait_subscriber,
        record_overwrite=bool(getattr(args, "overwrite", False)),
        record_encoding=getattr(args, "record_encoding", None) or "protobuf",
        source_id=None if controller is None else sim_source_id(robot.name),
        params_file=str(params_file) if params_file else None,
    )
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    try:
        daemon = Daemon(opts)
    except Exception as e:  # noqa: BLE001 - start-up failures get one clear line, not a traceback
        from cablesvc.service.daemon import StartError
        from cablesvc.sources import SourceConfigError
        if isinstance(e, (SourceConfigError, StartError)):
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
    if hasattr(signal, "SIGHUP"):
        _reload_on_sighup([daemon])
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
    try:
        if args.no_view:
            while worker.is_alive() and not stop.is_set():
                stop.wait(0.1)
                if deadline is not None and time.monotonic() >= deadline:
                    stop.set()
        else:
            _view([(daemon, robot, geom)], stop, worker.is_alive, deadline)
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


def _run_fleet(args, cfg: dict[str, Any], file: str) -> int:
    """``cablesvc run --config fleet.toml``: several robots in one daemon (cablesvc.service.fleet).
    Start-up is all or nothing; after it, SIGINT / SIGTERM stop every robot (each writes its
    snapshot) and the process exits 0, or 1 when a robot's loop ended with an error."""
    from cablesvc.service.fleet import Fleet, FleetError, FleetStartError

    try:
        shared, plans = plan_fleet(args, cfg, file)
    except FleetConfigError as e:
        print(f"cablesvc run: {e}", file=sys.stderr)
        return 1
    try:
        fleet = Fleet([p.options for p in plans], zenoh_config_file=shared["zenoh_config_file"],
                      listen=shared["listen"], connect=shared["connect"], sources=[p.source for p in plans])
    except FleetStartError as e:
        if isinstance(e.cause, _StartupInterrupted):
            raise e.cause from None                  # SIGINT / SIGTERM while opening: exit 130 as usual
        cause = str(e.cause).split(" at /")[0]
        print(f"cablesvc run: {file}: robots[{e.index}] ({e.robot}): cannot start: {cause}", file=sys.stderr)
        return 1
    except FleetError as e:
        print(f"cablesvc run: {file}: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # noqa: BLE001 - the shared session: one clear line
        if type(e).__module__.startswith("zenoh") or type(e).__name__ == "ZError":
            where = shared["zenoh_config_file"] or f"listen {', '.join(shared['listen'] or ('tcp/127.0.0.1:7447',))}"
            print(f"cablesvc run: cannot open the Zenoh session ({where}): {str(e).split(' at /')[0]}",
                  file=sys.stderr)
            return 1
        raise
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, on_signal)          # from here on: a clean shutdown
    signal.signal(signal.SIGTERM, on_signal)
    if hasattr(signal, "SIGHUP"):
        _reload_on_sighup(list(fleet.daemons.values()))
    log = logging.getLogger("cablesvc.run")
    log.info("cablesvc fleet of %d robots (%s), zenoh %s", len(plans), ", ".join(fleet.names),
             shared["zenoh_config_file"] or f"peer on {', '.join(shared['listen'] or ('tcp/127.0.0.1:7447',))}")
    for p in plans:
        d = fleet.daemons[p.options.robot.name]
        log.info("%s: robot %s, source %s, model %s%s", p.where, d.name, json.dumps(p.options.source, default=str),
                 p.options.params.model, f"; hysteresis state restored from {d.restored_from}" if d.restored_from
                 else "")
    controllers = [p.controller for p in plans if p.controller is not None]
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    try:
        for c in controllers:
            c.start()
        fleet.start(stop)
        if args.no_view:
            while fleet.running() and not stop.is_set():
                stop.wait(0.1)
                if deadline is not None and time.monotonic() >= deadline:
                    stop.set()
        else:
            _view([(fleet.daemons[n], fleet.daemons[n].robot, fleet.daemons[n].geom) for n in fleet.names], stop,
                  lambda: bool(fleet.running()), deadline)
    finally:
        stop.set()
        t0 = time.monotonic()
        for c in controllers:
            c.stop()
        fleet.close()
        elapsed = time.monotonic() - t0
        statuses = fleet.status()
        for name, st in statuses.items():
            log.info("robot %s stopped in %.2f s after %d ticks; input %s; latency %s", name, elapsed, st["ticks"],
                     json.dumps(st["input"]), json.dumps(st["latency_us"]))
    failed = {n: st["fleet"]["error"] for n, st in statuses.items() if st["fleet"]["error"]}
    for n, err in failed.items():
        log.error("robot %s: its loop ended with an error: %s", n, err)
    lost = [f"robot {n}: {line}" for n, d in fleet.daemons.items() for line in d.exit_problems()]
    for line in lost:
        print(f"cablesvc run: {line}", file=sys.stderr)
    return 1 if failed or lost else 0


def _since(v) -> str:
    """An alarm's ``since`` [s] for the view: null (raised before the first tick) is "-"."""
    return "-" if v is None else f"{v:.2f}"


def _view(robots, stop: threading.Event, alive: Callable[[], bool], deadline) -> None:
    """Live terminal view of forces and alarms (main thread), refreshed eight times a second:
    one forces table per robot (``robots``: (daemon, robot, geometry) tuples) and the
    active alarms of all of them. Runs while ``alive()`` and ``stop`` is not set."""
    import numpy as np
    from rich.console import Group
    from rich.live import Live
    from rich.table import Table
    from rich.text import Text

    several = len(robots) > 1

    def render():
        parts = []
        al = Table(title="active alarms", expand=False)
        for col in (("robot",) if several else ()) + ("code", "cable", "severity", "since s", "message"):
            al.add_column(col)
        for daemon, robot, geom in robots:
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
            parts.append(tb)
            for a in st["alarms_active"]:
                al.add_row(*((robot.name,) if several else ()), a["code"],
                           "" if a.get("cable") is None else geom.cable_names[a["cable"]], a["severity"],
                           _since(a.get("since")), a["message"])
        return Group(*parts, al)

    failed = [False]

    def safe_render():
        # the view is a window on the daemon, never a reason for it to stop: a view that
        # cannot draw says why (once in the log) and the loop goes on
        try:
            return render()
        except Exception as e:  # noqa: BLE001
            if not failed[0]:
                logging.getLogger("cablesvc.run").exception("the terminal view failed; the daemon keeps running")
                failed[0] = True
            return Text(f"terminal view failed ({e!r}); the daemon keeps running, see the log")

    with Live(safe_render(), refresh_per_second=8, transient=False) as live:
        while alive() and not stop.is_set():
            stop.wait(0.125)
            live.update(safe_render())
            if deadline is not None and time.monotonic() >= deadline:
                stop.set()
