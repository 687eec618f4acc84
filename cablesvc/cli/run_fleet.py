"""``cablesvc run --config fleet.toml``: several robots in one daemon, one Zenoh session.

The file is checked by :class:`cablesvc.config.daemon.FleetConfig`, planned by
:func:`cablesvc.service.plan.plan_fleet` (each robot's files loaded, its source built,
nothing opened) and run here (cablesvc.service.fleet). The command line adds only the
shared settings (:class:`~cablesvc.config.daemon.RunOverrides`); a flag that configures one
robot is refused. Every problem is one line naming the file and the entry
(``fleet.toml: robots[1].source.path: ...``).
"""

from __future__ import annotations

import json
import logging
import signal
import sys
import threading
import time
from typing import Any

from cablesvc.cli.failures import zenoh_failure
from cablesvc.cli.run_session import (StartupInterrupted, print_last_frame, reload_on_sighup, view,
                                       wait_until_stopped)
from cablesvc.errors import ConfigError, ServiceError

__all__ = ["per_robot_flags", "run_fleet", "run_overrides"]


# flags that configure one robot: in a fleet config each [[robots]] entry says these
_PER_ROBOT_FLAGS = (("robot", "--robot"), ("params", "--params"), ("source", "--source"),
                    ("interface", "--interface"), ("channel", "--channel"), ("bitrate", "--bitrate"),
                    ("fd", "--fd"), ("dbc", "--dbc"), ("deadline", "--deadline"), ("host", "--host"),
                    ("port", "--port"), ("unit", "--unit"), ("register_map", "--register-map"),
                    ("poll_rate", "--poll-rate"), ("replay", "--replay"), ("speed", "--speed"),
                    ("scenario", "--scenario"), ("rate", "--rate"), ("seed", "--seed"), ("record", "--record"),
                    ("snapshot", "--snapshot"))


def run_overrides(args):
    """The flags of ``cablesvc run`` that every robot of the daemon shares (a
    :class:`~cablesvc.config.daemon.RunOverrides`)."""
    from cablesvc.config.daemon import RunOverrides

    return RunOverrides(zenoh_config=args.zenoh_config, listen=args.listen, connect=args.connect,
                        encoding=args.encoding, snapshot_interval=args.snapshot_interval,
                        no_snapshot=bool(args.no_snapshot), wait_subscriber=args.wait_subscriber,
                        overwrite=bool(getattr(args, "overwrite", False)),
                        record_encoding=getattr(args, "record_encoding", None) or "protobuf")


def per_robot_flags(args) -> list[str]:
    """The flags given that configure one robot (a fleet config's entries say these)."""
    flags = [flag for attr, flag in _PER_ROBOT_FLAGS if getattr(args, attr, None) not in (None, False)]
    if getattr(args, "loop", False):
        flags.append("--loop")
    return flags


def run_fleet(args, cfg: dict[str, Any], file: str) -> int:
    """``cablesvc run --config fleet.toml``: several robots in one daemon (cablesvc.service.fleet).
    Start-up is all or nothing; after it, SIGINT / SIGTERM stop every robot (each writes its
    snapshot) and the process exits 0, or 1 when a robot's loop ended with an error."""
    import zenoh

    from cablesvc.config.daemon import FleetConfigError, fleet_config, zenoh_where
    from cablesvc.service.fleet import Fleet, FleetError, FleetStartError
    from cablesvc.service.plan import plan_fleet

    if flags := per_robot_flags(args):
        raise FleetConfigError(f"{file}: {', '.join(flags)} configure(s) one robot and do(es) not apply to a fleet "
                               "config; set it in the [[robots]] entry")
    shared, plans = plan_fleet(fleet_config(cfg, file), file, run_overrides(args))
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
    last_frame: list = []
    try:
        for c in controllers:
            c.start()
        fleet.start(stop)
        if args.no_view:
            wait_until_stopped(lambda: bool(fleet.running()), stop, deadline)
        else:
            view([(fleet.daemons[n], fleet.daemons[n].robot, fleet.daemons[n].geom) for n in fleet.names], stop,
                  lambda: bool(fleet.running()), deadline, last_frame)
    finally:
        stop.set()
        t0 = time.monotonic()
        for c in controllers:
            c.stop()
        fleet.close()
        elapsed = time.monotonic() - t0
        print_last_frame(last_frame)
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
