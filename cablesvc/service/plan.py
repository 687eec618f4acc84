"""The daemon's plan: a checked config and its overrides become what the daemon runs.

``cablesvc run`` parses its flags into :class:`~cablesvc.config.daemon.RunOverrides` (and,
for one robot, :class:`~cablesvc.config.daemon.RobotOverrides`) and calls
:func:`plan_daemon` with a :class:`~cablesvc.config.daemon.DaemonConfig` or
:func:`plan_fleet` with a :class:`~cablesvc.config.daemon.FleetConfig`. Each loads the
robot and parameter files, builds the source (opens nothing) or the embedded simulated
controller (built, not started; :mod:`cablesvc.sources.sim_controller`), picks the
snapshot file and interval, and returns :class:`RobotPlan` (its
:class:`~cablesvc.service.daemon.DaemonOptions`) with the shared Zenoh settings. A fleet
is checked as a whole as well: unique robot names, no record or snapshot file shared by two
robots, no robot recording onto another's replay input. Every problem of a fleet is a
:class:`~cablesvc.config.daemon.FleetConfigError` naming the file and the entry
(``fleet.toml: robots[1].source.path: recording x.mcap not found``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cablesvc.config.daemon import (
    DaemonConfig,
    FleetConfig,
    FleetConfigError,
    RobotOverrides,
    RunOverrides,
    zenoh_settings,
)
from cablesvc.errors import ConfigError, SourceError

__all__ = ["RobotPlan", "SimRateError", "plan_daemon", "plan_fleet"]

#: seconds between snapshots when neither the command line nor the config says
DEFAULT_SNAPSHOT_INTERVAL_S = 5.0


class SimRateError(ConfigError, ValueError):
    """The embedded simulated controller's rate is beyond what the daemon can follow (or
    would not fit in memory); like a bad command-line value, exit status 2."""

    exit_status = 2


@dataclass
class RobotPlan:
    """One robot, ready to start: its daemon options, its source (built, not opened; None
    for the embedded simulator, whose CAN source the daemon opens), its simulated controller
    (``kind = "sim"`` only) and its entry (``robots[i]`` in a fleet)."""

    where: str
    options: Any                 # DaemonOptions
    source: Any = None
    controller: Any = None


def _params_problem(params, robot) -> str | None:
    """A parameter file identified for another robot: the message, or None."""
    if params.robot and params.robot != robot.name:
        return f"{params.source} was identified for robot {params.robot!r}, not {robot.name!r}"
    return None


def _snapshot(run: RunOverrides, given: str | None, robot_name: str, live: bool) -> Path | None:
    """The state file: none with ``no_snapshot``; else the one given, else the live robot's
    default file (a replay or the embedded simulator, a new simulated controller at every
    start, uses one only when given one)."""
    from cablesvc.service.snapshot import default_snapshot_path

    if run.no_snapshot:
        return None
    snapshot = given or (default_snapshot_path(robot_name) if live else None)
    return Path(snapshot) if snapshot else None


def _interval(run: RunOverrides, given: float | None) -> float:
    """Seconds between snapshots: the override, else the config's, else the default."""
    if run.snapshot_interval is not None:
        return float(run.snapshot_interval)
    return float(DEFAULT_SNAPSHOT_INTERVAL_S if given is None else given)


def _options(run: RunOverrides, shared: dict[str, Any], **kw: Any):
    """DaemonOptions with the shared Zenoh settings and the run's overrides."""
    from cablesvc.service.daemon import DaemonOptions

    return DaemonOptions(encoding=shared["encoding"], zenoh_config_file=shared["zenoh_config_file"],
                         listen=shared["listen"], connect=shared["connect"], wait_subscriber_s=run.wait_subscriber,
                         record_overwrite=bool(run.overwrite), record_encoding=run.record_encoding or "protobuf",
                         **kw)


def plan_daemon(cfg: DaemonConfig, source: dict[str, Any], run: RunOverrides,
                one: RobotOverrides | None = None) -> tuple[dict[str, Any], RobotPlan]:
    """Plan a single-robot daemon: (shared Zenoh settings, its plan).

    ``source`` is the [source] table with the command line's source flags merged in (its
    ``kind``: sim, can, modbus or replay); ``one`` the robot's overrides. A parameter file
    identified for another robot is a :class:`ConfigError`; a simulated controller whose
    rate the daemon cannot follow a :class:`SimRateError` (naming ``--rate`` when the
    override gave it, else ``source.rate``), one that cannot be built (no DBC for the
    robot, an unknown scenario) a :class:`~cablesvc.errors.SourceError`. A bus source is
    built when the daemon starts; the simulated controller here (not started).
    """
    from cablesvc.config import load_robot
    from cablesvc.config.params import load_params, nominal_params
    from cablesvc.sources import SourceConfigError
    from cablesvc.sources.sim_controller import sim_controller, sim_rate_problem, sim_source_id

    one = one or RobotOverrides()
    shared = zenoh_settings(cfg, run)
    robot = load_robot(one.robot or cfg.robot or "ipanema3")
    geom = robot.geometry()
    params_file = one.params or cfg.params
    params = load_params(params_file) if params_file else nominal_params(geom)
    if why := _params_problem(params, robot):
        raise ConfigError(why)
    src = dict(source)
    controller = None
    if src["kind"] == "sim":
        sim = {k: src.pop(k) for k in ("scenario", "rate", "seed") if k in src}
        scenario = one.scenario if one.scenario is not None else sim.get("scenario")
        rate = one.rate if one.rate is not None else sim.get("rate")
        seed = one.seed if one.seed is not None else sim.get("seed")
        if why := sim_rate_problem(rate, robot.n_cables):
            raise SimRateError(f"{'--' if one.rate is not None else 'source.'}{why}")
        try:
            controller, src = sim_controller(robot, src, scenario=scenario, rate=rate, seed=seed,
                                             channel=src.get("channel") or f"cablesvc-sim-{os.getpid()}")
        except (SourceConfigError, ValueError, TypeError, KeyError) as e:
            # no DBC for this robot, an unknown scenario, a bad rate in the config: one line
            msg = e.args[0] if isinstance(e, KeyError) and e.args else e
            raise SourceError(f"cannot start the simulated controller (source sim) for robot {robot.name!r}: "
                              f"{msg}") from None
    record = one.record or cfg.record
    opts = _options(run, shared, robot=robot, params=params, source=src,
                    record=Path(record) if record else None,
                    snapshot=_snapshot(run, one.snapshot or cfg.snapshot, robot.name,
                                       live=controller is None and src["kind"] != "replay"),
                    snapshot_interval_s=_interval(run, cfg.snapshot_interval), alarm_config=cfg.alarms,
                    source_id=None if controller is None else sim_source_id(robot.name),
                    params_file=str(params_file) if params_file else None)
    return shared, RobotPlan(where="", options=opts, controller=controller)


def plan_fleet(fc: FleetConfig, file: str, run: RunOverrides) -> tuple[dict[str, Any], list[RobotPlan]]:
    """Plan a fleet (several robots in one daemon): (shared Zenoh settings, one plan per
    [[robots]] entry).

    Every problem is a :class:`FleetConfigError` naming ``file`` and the entry
    (``robots[1].source.path: recording x.mcap not found``): a robot or parameter file that
    does not load, a bus source whose fields or files are wrong, two entries with the same
    robot name, the same record or snapshot file, a record file that is another robot's
    replay input, a simulated controller that cannot run. Nothing is opened; simulated
    controllers are built (not started) only once every entry is valid. What
    :class:`FleetConfig` refuses (unknown keys, Zenoh keys inside an entry, a bad source or
    alarms table) was refused when ``fc`` was checked.
    """
    from cablesvc.config import load_robot
    from cablesvc.config.params import load_params, nominal_params
    from cablesvc.service.fleet import duplicate_names
    from cablesvc.sources import SourceConfigError, open_source
    from cablesvc.sources.sim_controller import sim_controller, sim_rate_problem, sim_source_id

    shared = zenoh_settings(fc, run)
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
        if why := _params_problem(params, robot):
            raise FleetConfigError(f"{where}.params: {why}")
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
        opts = _options(run, shared, robot=robot, params=params, source=src,
                        params_file=str(e.params) if e.params else None,
                        record=Path(e.record) if e.record else None,
                        snapshot=_snapshot(run, e.snapshot, robot.name, live=src["kind"] not in ("sim", "replay")),
                        snapshot_interval_s=_interval(run, e.snapshot_interval), alarm_config=e.alarms)
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
