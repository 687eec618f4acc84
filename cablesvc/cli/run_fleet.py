"""``cablesvc run --config fleet.toml``: several robots in one daemon, one Zenoh session.

The file is checked by :class:`cablesvc.config.daemon.FleetConfig`; :func:`plan_fleet`
then loads each robot's files and builds its source (opens nothing) and
:func:`run_fleet` runs them (cablesvc.service.fleet). Every problem is one line naming the
file and the entry (``fleet.toml: robots[1].source.path: ...``).
"""

from __future__ import annotations

import json
import logging
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cablesvc.cli.failures import zenoh_failure
from cablesvc.cli.run_session import StartupInterrupted, reload_on_sighup, view, wait_until_stopped
from cablesvc.cli.run_sim import sim_controller, sim_rate_problem, sim_source_id
from cablesvc.config.daemon import FleetConfigError, ZenohSettings, fleet_config
from cablesvc.errors import ConfigError, ServiceError

__all__ = ["RobotPlan", "plan_fleet", "run_fleet", "zenoh_settings", "zenoh_where"]


# flags that configure one robot: in a fleet config each [[robots]] entry says these
_PER_ROBOT_FLAGS = (("robot", "--robot"), ("params", "--params"), ("source", "--source"),
                    ("interface", "--interface"), ("channel", "--channel"), ("bitrate", "--bitrate"),
                    ("fd", "--fd"), ("dbc", "--dbc"), ("deadline", "--deadline"), ("host", "--host"),
                    ("port", "--port"), ("unit", "--unit"), ("register_map", "--register-map"),
                    ("poll_rate", "--poll-rate"), ("replay", "--replay"), ("speed", "--speed"),
                    ("scenario", "--scenario"), ("rate", "--rate"), ("seed", "--seed"), ("record", "--record"),
                    ("snapshot", "--snapshot"))


@dataclass
class RobotPlan:
    """One robot of a fleet, ready to start: its daemon options, its source (built, not
    opened), its simulated controller (``kind = "sim"`` only) and its entry (``robots[i]``)."""

    where: str
    options: Any                 # DaemonOptions
    source: Any = None
    controller: Any = None


def zenoh_settings(args, z: ZenohSettings) -> dict[str, Any]:
    """The shared Zenoh settings, command-line flags first: ``zenoh_config_file``,
    ``listen``, ``connect`` (None: not given) and ``encoding``. The file's values were
    checked by :class:`ZenohSettings` even where a flag overrides them: a bad file is a bad file."""
    listen = args.listen or z.listen
    connect = args.connect or z.connect
    return {"zenoh_config_file": args.zenoh_config or z.zenoh_config,
            "listen": tuple(listen) if listen else None, "connect": tuple(connect) if connect else None,
            "encoding": args.encoding or z.encoding}


def zenoh_where(shared: dict[str, Any]) -> str:
    """Where the Zenoh session was to be opened, for a message: its config file or endpoints."""
    return shared["zenoh_config_file"] or f"listen {', '.join(shared['listen'] or ('tcp/127.0.0.1:7447',))}"


def plan_fleet(args, cfg: dict[str, Any], file: str) -> tuple[dict[str, Any], list[RobotPlan]]:
    """Check a fleet config and build what each robot needs: (shared Zenoh settings, plans).

    Every problem is a :class:`FleetConfigError` naming ``file`` and the entry
    (``robots[1].source.path: recording x.mcap not found``): per-robot command-line flags,
    what :class:`~cablesvc.config.daemon.FleetConfig` refuses (unknown keys, Zenoh keys
    inside an entry, a bad source or alarms table), a robot or parameter file that does not
    load, a bus source whose fields or files are wrong, two entries with the same robot
    name, the same record or snapshot file. Nothing is opened; simulated controllers are
    built (not started) only once every entry is valid.
    """
    from cablesvc.config import load_robot
    from cablesvc.config.params import load_params, nominal_params
    from cablesvc.service.daemon import DaemonOptions
    from cablesvc.service.snapshot import default_snapshot_path
    from cablesvc.service.fleet import duplicate_names
    from cablesvc.sources import SourceConfigError, open_source

    flags = [flag for attr, flag in _PER_ROBOT_FLAGS if getattr(args, attr, None) not in (None, False)]
    if getattr(args, "loop", False):
        flags.append("--loop")
    if flags:
        raise FleetConfigError(f"{file}: {', '.join(flags)} configure(s) one robot and do(es) not apply to a fleet "
                               "config; set it in the [[robots]] entry")
    fc = fleet_config(cfg, file)
    shared = zenoh_settings(args, fc)

    plans: list[RobotPlan] = []
    sims: list[tuple[int, dict[str, Any]]] = []
    for i, e in enumerate(fc.robots):
        where = f"{file}: robots[{i}]"
        try:
            robot = load_robot(e.robot)
            geom = robot.geometry()
        except Exception as ex:  # noqa: BLE001 - RobotFileError and friends: one message
            raise FleetConfigError(f"{where}.robot: {ex}") from None
        try:
            params = load_params(e.params) if e.params else nominal_params(geom)
        except Exception as ex:  # noqa: BLE001 - ParamFileError lists every problem
            raise FleetConfigError(f"{where}.params: {ex}") from None
        if params.robot and params.robot != robot.name:
            raise FleetConfigError(f"{where}.params: {params.source} was identified for robot {params.robot!r}, "
                                   f"not {robot.name!r}")
        src = dict(e.source)
        src.setdefault("kind", "sim")
        source = None
        if src["kind"] == "sim":
            sims.append((i, src))
        else:
            try:
                source = open_source(robot, src)       # checks every field and the files it names; opens nothing
            except SourceConfigError as ex:
                raise FleetConfigError(f"{where}.{ex}") from None
        if args.snapshot_interval is not None:
            interval = args.snapshot_interval
        else:
            interval = 5.0 if e.snapshot_interval is None else e.snapshot_interval
        snapshot = None
        if not args.no_snapshot:
            live = src["kind"] not in ("sim", "replay")        # the default file is the live robot's
            snapshot = e.snapshot or (default_snapshot_path(robot.name) if live else None)
            snapshot = Path(snapshot) if snapshot else None
        record = Path(e.record) if e.record else None
        opts = DaemonOptions(robot=robot, params=params, source=src, encoding=shared["encoding"],
                             params_file=str(e.params) if e.params else None,
                             zenoh_config_file=shared["zenoh_config_file"], listen=shared["listen"],
                             connect=shared["connect"], record=record, snapshot=snapshot,
                             snapshot_interval_s=float(interval), alarm_config=e.alarms,
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
            controller, can_src = sim_controller(plan.options.robot, src, scenario=src.get("scenario"),
                                                 rate=src.get("rate"), seed=src.get("seed"),
                                                 channel=f"cablesvc-sim-{os.getpid()}-{plan.options.robot.name}")
        except Exception as ex:  # noqa: BLE001 - no DBC for this robot, a bad scenario, ...: one line
            raise FleetConfigError(f"{file}: {plan.where}.source (sim): {ex}") from None
        plan.controller = controller
        plan.options.source = can_src
        plan.options.source_id = sim_source_id(plan.options.robot.name)
    return shared, plans


def run_fleet(args, cfg: dict[str, Any], file: str) -> int:
    """``cablesvc run --config fleet.toml``: several robots in one daemon (cablesvc.service.fleet).
    Start-up is all or nothing; after it, SIGINT / SIGTERM stop every robot (each writes its
    snapshot) and the process exits 0, or 1 when a robot's loop ended with an error."""
    import zenoh

    from cablesvc.service.fleet import Fleet, FleetError, FleetStartError

    shared, plans = plan_fleet(args, cfg, file)
    try:
        fleet = Fleet([p.options for p in plans], zenoh_config_file=shared["zenoh_config_file"],
                      listen=shared["listen"], connect=shared["connect"], sources=[p.source for p in plans])
    except FleetStartError as e:
        if isinstance(e.cause, StartupInterrupted):
            raise e.cause from None                  # SIGINT / SIGTERM while opening: exit 130 as usual
        cause = str(e.cause).split(" at /")[0]
        raise ServiceError(f"{file}: robots[{e.index}] ({e.robot}): cannot start: {cause}") from None
    except FleetError as e:
        raise ConfigError(f"{file}: {e}") from None
    except zenoh.ZError as e:                        # the shared session: one clear line
        raise zenoh_failure("open the Zenoh session", zenoh_where(shared), e) from None
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, on_signal)          # from here on: a clean shutdown
    signal.signal(signal.SIGTERM, on_signal)
    if hasattr(signal, "SIGHUP"):
        reload_on_sighup(list(fleet.daemons.values()))
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
            wait_until_stopped(lambda: bool(fleet.running()), stop, deadline)
        else:
            view([(fleet.daemons[n], fleet.daemons[n].robot, fleet.daemons[n].geom) for n in fleet.names], stop,
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
