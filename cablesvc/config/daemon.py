"""The daemon's configuration (``cablesvc run --config FILE``), as pydantic models.

Two shapes of one TOML file (``deploy/cablesvc.toml``, ``deploy/fleet.example.toml``):

- a **daemon config**, one robot: ``robot``, ``params``, ``record``, ``snapshot``,
  ``snapshot_interval``, tables ``[source]`` and ``[alarms]``, and the Zenoh keys
  ``zenoh_config``, ``listen``, ``connect``, ``encoding`` (:class:`DaemonConfig`);
- a **fleet config**, several robots in one daemon: the Zenoh keys at the top (one session,
  shared) and one ``[[robots]]`` table per robot with the robot's keys
  (:class:`FleetConfig`, :class:`RobotEntry`).

A ``[source]`` table has a ``kind``: ``sim`` (the embedded simulated controller on a virtual
CAN bus, :class:`SimSource`, the default) or a bus source (``can``, ``modbus``, ``replay``)
whose fields the source checks itself (``cablesvc.sources.open_source``). These models
check the file's shape only: nothing is loaded or opened here. A file that does not fit
is a :class:`FleetConfigError` whose message names the file and the entry
(``fleet.toml: robots[1].source.kind: ...``); :func:`load_config` reads a file and
:func:`daemon_config` / :func:`fleet_config` check a parsed one.

What the command line says on top of a file is :class:`RunOverrides` (the settings every
robot of the daemon shares: Zenoh, snapshots, recording) and, for a single robot,
:class:`RobotOverrides`; :func:`zenoh_settings` merges the Zenoh keys. The planner
(:mod:`cablesvc.service.plan`) turns a checked config and its overrides into what the
daemon runs.
"""

from __future__ import annotations

import math
import tomllib
from typing import Any, ClassVar, Literal, Optional

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictInt,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from cablesvc.errors import ConfigError

__all__ = ["FleetConfigError", "DaemonConfig", "FleetConfig", "RobotEntry", "SimSource", "ZenohSettings",
           "SHARED_KEYS", "ROBOT_KEYS", "SIM_KEYS", "SINGLE_SIM_KEYS", "SOURCE_KINDS", "load_config",
           "is_fleet_config", "daemon_config", "fleet_config", "is_endpoint", "seconds_ok", "RunOverrides",
           "RobotOverrides", "zenoh_settings", "zenoh_where"]

#: the Zenoh keys: one session for the whole daemon (top of a fleet config)
SHARED_KEYS = ("zenoh_config", "listen", "connect", "encoding")
#: one robot's keys (a daemon config, or each [[robots]] entry of a fleet config)
ROBOT_KEYS = ("robot", "params", "source", "record", "snapshot", "snapshot_interval", "alarms")
#: the [source] table of kind "sim" in a fleet entry (each robot on its own virtual CAN bus)
SIM_KEYS = ("kind", "fd", "dbc", "scenario", "rate", "seed")
#: ... and in a single-robot daemon config (which may name the virtual bus and the deadline)
SINGLE_SIM_KEYS = SIM_KEYS + ("interface", "channel", "deadline_s")
#: the source kinds of ``cablesvc run`` (sim: the embedded simulated controller)
SOURCE_KINDS = ("sim", "can", "modbus", "replay")


class FleetConfigError(ConfigError, ValueError):
    """A daemon or fleet config that cannot be used; the message names the file and the
    entry (``fleet.toml: robots[1].source.path: ...``)."""


def _bad(msg: str, key: str | None = None) -> PydanticCustomError:
    """A validation error with our own words; ``key`` is appended to the error's location
    (an unknown key found by a model validator)."""
    return PydanticCustomError("cablesvc_config", "{msg}", {"msg": msg, "key": key})


def is_endpoint(v: str) -> bool:
    """A Zenoh endpoint has the form ``proto/address`` (``tcp/127.0.0.1:7447``)."""
    proto, _, addr = v.partition("/")
    return bool(proto) and bool(addr) and v == v.strip()


def seconds_ok(v: Any, *, zero: bool = False) -> bool:
    """A number of seconds: finite and > 0 (>= 0 with ``zero``); bools are not numbers here."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return False
    return v >= 0 if zero else v > 0


#: what each path-valued key holds, for its message
_PATHS = {"zenoh_config": "a path to a Zenoh JSON5 file",
          "robot": "a robot name in robots/ or a path to a robot .toml",
          "params": "a path to a parameter file from `cablesvc identify`",
          "record": "a path to an .mcap file", "snapshot": "a path to a state file"}


def _path(v: Any, info: ValidationInfo) -> Any:
    """A path-valued key: a non-empty string (or absent)."""
    if v is not None and (not isinstance(v, str) or not v):
        raise _bad(f"expected {_PATHS[info.field_name]}, got {v!r}")
    return v


class ZenohSettings(BaseModel):
    """The Zenoh keys, shared by every robot of the daemon: ``zenoh_config`` (a JSON5 file for
    a router, TLS or access control), ``listen`` / ``connect`` endpoints (one string or a
    list) and the forces ``encoding`` (``json`` or ``compact``)."""

    model_config = ConfigDict(extra="forbid")

    zenoh_config: Optional[str] = None
    listen: Optional[tuple[str, ...]] = None
    connect: Optional[tuple[str, ...]] = None
    encoding: Literal["json", "compact"] = "json"

    _zenoh_config = field_validator("zenoh_config", mode="before")(_path)

    @field_validator("listen", "connect", mode="before")
    @classmethod
    def _endpoints(cls, v: Any) -> Any:
        vals = [v] if isinstance(v, str) else v
        if v is not None and (not isinstance(vals, list) or not all(isinstance(x, str) and is_endpoint(x)
                                                                    for x in vals)):
            raise _bad(f"expected a list of Zenoh endpoints like [\"tcp/127.0.0.1:7447\"], got {v!r}")
        return None if v is None else tuple(vals)

    @field_validator("encoding", mode="before")
    @classmethod
    def _encoding(cls, v: Any) -> Any:
        if v not in ("json", "compact"):
            raise _bad(f"expected \"json\" or \"compact\", got {v!r}")
        return v


class SimSource(BaseModel):
    """``[source] kind = "sim"``: the embedded simulated controller (a digital twin of the
    robot) sending on a virtual CAN bus that the daemon reads. ``fd`` (default true: the FD
    layout, needed for 1 kHz), ``dbc``, ``scenario`` (default trajectory), ``rate`` [Hz]
    (default 1000; checked against the robot when it is built), ``seed``; a single-robot
    config may also name the bus (``interface``, ``channel``) and ``deadline_s``."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["sim"] = "sim"
    fd: Optional[StrictBool] = None
    dbc: Optional[str] = None
    scenario: Optional[str] = None
    rate: Any = None
    seed: Optional[StrictInt] = None
    interface: Optional[str] = None
    channel: Optional[str] = None
    deadline_s: Optional[float] = None


def _source(v: Any, table: str, sim_keys: tuple[str, ...], *, check_kind: bool) -> dict[str, Any]:
    """A [source] table: a dict with a ``kind`` (default sim; with ``check_kind`` one of
    :data:`SOURCE_KINDS`, else the source names an unknown one itself); a sim source's keys
    and values are checked here, a bus source's by the source when it is built."""
    if not isinstance(v, dict):
        raise _bad(f"expected a table ({table}) with a kind, got {v!r}")
    src = dict(v)
    kind = src.get("kind", "sim")
    if check_kind and kind not in SOURCE_KINDS:
        raise _bad(f"expected one of {', '.join(SOURCE_KINDS)}, got {kind!r}", key="kind")
    if kind == "sim":
        bad = sorted(set(src) - set(sim_keys))
        if bad:
            raise _bad(f"unknown for kind \"sim\" (the embedded simulated controller); it takes "
                       f"{', '.join(sim_keys)}", key=bad[0])
        try:
            SimSource.model_validate(src)
        except ValidationError as ex:
            err = ex.errors()[0]
            raise _bad(err.get("msg"), key=".".join(str(x) for x in err.get("loc", ())) or None) from None
    return src


class _RobotKeys(BaseModel):
    """One robot's keys (shared by :class:`DaemonConfig` and :class:`RobotEntry`)."""

    model_config = ConfigDict(extra="forbid")

    robot: Optional[str] = None
    params: Optional[str] = None
    source: dict[str, Any] = Field(default_factory=lambda: {"kind": "sim"})
    record: Optional[str] = None
    snapshot: Optional[str] = None
    snapshot_interval: Optional[float] = None
    alarms: Optional[Any] = None       # an AlarmConfig (cablesvc.alarms), checked by it

    _paths = field_validator("robot", "params", "record", "snapshot", mode="before")(_path)

    #: the [source] table's name, the keys of its kind "sim", whether its kind is checked here
    SOURCE_TABLE: ClassVar[str] = "[source]"
    SIM_SOURCE_KEYS: ClassVar[tuple[str, ...]] = SINGLE_SIM_KEYS
    CHECK_KIND: ClassVar[bool] = True

    @field_validator("source", mode="before")
    @classmethod
    def _source(cls, v: Any) -> Any:
        return _source(v, cls.SOURCE_TABLE, cls.SIM_SOURCE_KEYS, check_kind=cls.CHECK_KIND)

    @field_validator("snapshot_interval", mode="before")
    @classmethod
    def _interval(cls, v: Any) -> Any:
        if v is not None and not seconds_ok(v):
            raise _bad(f"expected seconds > 0 (a finite number), got {v!r}")
        return v

    @field_validator("alarms", mode="before")
    @classmethod
    def _alarms(cls, v: Any) -> Any:
        from cablesvc.alarms import AlarmConfig

        if v is None:
            return None
        if not isinstance(v, dict):
            raise _bad(f"expected a table ([alarms]), got {v!r}")
        try:
            return AlarmConfig.model_validate(v)
        except ValidationError as ex:
            err = ex.errors()[0]
            raise _bad(err.get("msg"), key=".".join(str(x) for x in err.get("loc", ())) or None) from None


class DaemonConfig(ZenohSettings, _RobotKeys):
    """A single-robot daemon config: one robot's keys and the Zenoh keys at the top.
    ``robot`` None: ipanema3; ``params`` None: the nominal parameters at the home pose."""

    @model_validator(mode="before")
    @classmethod
    def _keys(cls, data: Any) -> Any:
        allowed = SHARED_KEYS + ROBOT_KEYS
        for k in data:
            if k not in allowed:
                raise _bad(f"unknown key; a daemon config has {', '.join(allowed)} (or [[robots]] tables for a "
                           "fleet)", key=k)
        return data


class RobotEntry(_RobotKeys):
    """One ``[[robots]]`` entry of a fleet config; ``robot`` is required."""

    robot: str
    SOURCE_TABLE: ClassVar[str] = "[robots.source]"
    SIM_SOURCE_KEYS: ClassVar[tuple[str, ...]] = SIM_KEYS
    CHECK_KIND: ClassVar[bool] = False      # open_source names an unknown kind (robots[i].source.kind: ...)

    @model_validator(mode="before")
    @classmethod
    def _keys(cls, data: Any) -> Any:
        for k in data:
            if k in SHARED_KEYS:
                raise _bad(f"the Zenoh settings are shared by every robot; set {k} at the top of the file", key=k)
            if k not in ROBOT_KEYS:
                raise _bad(f"unknown key; an entry has {', '.join(ROBOT_KEYS)}", key=k)
        if not isinstance(data.get("robot"), str) or not data["robot"]:
            raise _bad("missing or not a string (a robot name in robots/ or a path to a robot .toml)", key="robot")
        return data


class FleetConfig(ZenohSettings):
    """A fleet config: the Zenoh keys (shared) and one :class:`RobotEntry` per robot."""

    robots: list[RobotEntry]

    @model_validator(mode="before")
    @classmethod
    def _keys(cls, data: Any) -> Any:
        for k in data:
            if k in ROBOT_KEYS:
                raise _bad("belongs in each [[robots]] entry of a fleet config (this file has [[robots]] tables)",
                           key=k)
            if k not in SHARED_KEYS and k != "robots":
                raise _bad(f"unknown key; a fleet config has {', '.join(SHARED_KEYS)} and [[robots]] tables", key=k)
        entries = data.get("robots")
        if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
            raise _bad(f"expected one or more [[robots]] tables, got {entries!r}", key="robots")
        return data


def _where(loc: tuple[Any, ...]) -> str:
    """``("robots", 1, "source")`` -> ``robots[1].source``."""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _config_error(file: str, ex: ValidationError) -> FleetConfigError:
    """The first problem of ``ex`` as one line: ``<file>: <entry>: <message>``."""
    err = ex.errors()[0]
    loc = tuple(err.get("loc", ()))
    key = (err.get("ctx") or {}).get("key")
    if key:
        loc += (key,)
    where = _where(loc)
    return FleetConfigError(f"{file}: {where}: {err.get('msg')}" if where else f"{file}: {err.get('msg')}")


def daemon_config(cfg: dict[str, Any], file: str) -> DaemonConfig:
    """Check a parsed single-robot config; :class:`FleetConfigError` names ``file`` and the key."""
    try:
        return DaemonConfig.model_validate(cfg)
    except ValidationError as ex:
        raise _config_error(file, ex) from None


def fleet_config(cfg: dict[str, Any], file: str) -> FleetConfig:
    """Check a parsed fleet config; :class:`FleetConfigError` names ``file`` and the entry."""
    try:
        return FleetConfig.model_validate(cfg)
    except ValidationError as ex:
        raise _config_error(file, ex) from None


def is_fleet_config(cfg: dict[str, Any]) -> bool:
    """A config with ``[[robots]]`` tables describes several robots in one daemon."""
    return "robots" in cfg


def load_config(path: str | None) -> dict[str, Any]:
    """The parsed TOML of a config file (``{}`` for None); a file that cannot be read or is
    not TOML is a :class:`FleetConfigError` naming it."""
    if not path:
        return {}
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise FleetConfigError(f"config file {path} not found") from None
    except IsADirectoryError:
        raise FleetConfigError(f"config file {path} is a directory, not a TOML file") from None
    except UnicodeDecodeError as e:
        raise FleetConfigError(f"{path}: not valid TOML: not UTF-8 text ({e.reason} at byte {e.start})") from None
    except tomllib.TOMLDecodeError as e:
        raise FleetConfigError(f"{path}: not valid TOML: {e}") from None
    except OSError as e:
        raise FleetConfigError(f"cannot read config file {path}: {e.strerror or e}") from None


class RunOverrides(BaseModel):
    """What the command line sets on top of a daemon or fleet config, for every robot of the
    daemon: the Zenoh keys (``zenoh_config``, ``listen``, ``connect``, ``encoding``; None:
    the file's), the snapshot interval [s] (None: the file's, else 5 s), ``no_snapshot``
    (neither restore nor write the hysteresis state), ``wait_subscriber`` [s] (wait for a
    forces subscriber before reading the source), and the recording's ``overwrite`` and
    ``record_encoding`` (protobuf or json). ``cablesvc run`` checks its flags' values before
    it builds this (one line naming the flag)."""

    model_config = ConfigDict(extra="forbid")

    zenoh_config: Optional[str] = None
    listen: Optional[tuple[str, ...]] = None
    connect: Optional[tuple[str, ...]] = None
    encoding: Optional[Literal["json", "compact"]] = None
    snapshot_interval: Optional[float] = None
    no_snapshot: bool = False
    wait_subscriber: float = 0.0
    overwrite: bool = False
    record_encoding: Literal["protobuf", "json"] = "protobuf"


class RobotOverrides(BaseModel):
    """What the command line sets on top of a single-robot daemon config: the ``robot``,
    ``params``, ``record`` and ``snapshot`` files and the embedded simulated controller's
    ``scenario``, ``rate`` [Hz] and ``seed`` (None: the file's, else the defaults). A fleet
    config takes none of these (each [[robots]] entry says them)."""

    model_config = ConfigDict(extra="forbid")

    robot: Optional[str] = None
    params: Optional[str] = None
    record: Optional[str] = None
    snapshot: Optional[str] = None
    scenario: Optional[str] = None
    rate: Optional[float] = None
    seed: Optional[int] = None


def zenoh_settings(z: ZenohSettings, run: RunOverrides) -> dict[str, Any]:
    """The shared Zenoh settings, the overrides first: ``zenoh_config_file``, ``listen``,
    ``connect`` (None: not given) and ``encoding``. The file's values were checked by
    :class:`ZenohSettings` even where an override replaces them: a bad file is a bad file."""
    listen = run.listen or z.listen
    connect = run.connect or z.connect
    return {"zenoh_config_file": run.zenoh_config or z.zenoh_config,
            "listen": tuple(listen) if listen else None, "connect": tuple(connect) if connect else None,
            "encoding": run.encoding or z.encoding}


def zenoh_where(shared: dict[str, Any]) -> str:
    """Where the Zenoh session was to be opened, for a message: its config file or endpoints."""
    return shared["zenoh_config_file"] or f"listen {', '.join(shared['listen'] or ('tcp/127.0.0.1:7447',))}"
