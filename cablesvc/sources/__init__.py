"""Inputs of the live daemon: one :class:`Source` interface, transports chosen by configuration.

::

    from cablesvc.sources import open_source
    src = open_source("ipanema3", {"kind": "can", "interface": "socketcan", "channel": "can0"})
    with src:
        while not src.finished:
            tick = src.recv(timeout=0.1)        # TickInput or None
            for p in src.problems():            # rejected inputs, by reason
                ...

Kinds (:data:`SOURCES`): ``can`` (:class:`CanSource`, python-can + a DBC; the package
:mod:`cablesvc.sources.can`), ``modbus`` (:class:`ModbusSource`, Modbus TCP polling,
read-only), ``replay`` (:class:`ReplaySource`, MCAP/CSV recordings). Simulated controllers
for each transport are in :mod:`cablesvc.sources.simulated`; loopback buses and free ports
for them, the benches and the tests in :mod:`cablesvc.netutil`. How to run beside a real
controller: ``docs/sources.md``.
"""

from __future__ import annotations

import os
from typing import Annotated, Any, Mapping, Union

from pydantic import Field, TypeAdapter, ValidationError

from cablesvc.config.robot import Robot, load_robot
from cablesvc.sources.base import (
    DEFAULT_MAX_MOTOR_LENGTH,
    Problem,
    Rejection,
    Source,
    SourceConfigError,
    SourceCounters,
    ThreadedSource,
    TickInput,
    TickValidator,
)
from cablesvc.sources.can import (
    CanLayout,
    CanSource,
    CanSourceConfig,
    TickAssembler,
    encode_tick,
    load_can_layout,
    make_dbc,
    open_bus,
)
from cablesvc.sources.modbus_source import ModbusSource, ModbusSourceConfig, RegisterMap, load_register_map
from cablesvc.sources.replay import ReplaySource, ReplaySourceConfig

__all__ = [
    "DEFAULT_MAX_MOTOR_LENGTH",
    "SOURCES",
    "CanLayout",
    "CanSource",
    "CanSourceConfig",
    "ModbusSource",
    "ModbusSourceConfig",
    "Problem",
    "RegisterMap",
    "Rejection",
    "ReplaySource",
    "ReplaySourceConfig",
    "Source",
    "SourceConfig",
    "SourceConfigError",
    "SourceCounters",
    "ThreadedSource",
    "TickAssembler",
    "TickInput",
    "TickValidator",
    "encode_tick",
    "load_can_layout",
    "load_register_map",
    "make_dbc",
    "open_bus",
    "open_source",
    "parse_source_config",
]

#: A source configuration: one of the pydantic models, chosen by its ``kind`` field.
SourceConfig = Annotated[Union[CanSourceConfig, ModbusSourceConfig, ReplaySourceConfig], Field(discriminator="kind")]

#: kind -> Source class (python-can style registry).
SOURCES: dict[str, type[Source]] = {"can": CanSource, "modbus": ModbusSource, "replay": ReplaySource}

_ADAPTER: TypeAdapter[Any] = TypeAdapter(SourceConfig)


def _loc(loc: tuple[Any, ...]) -> str:
    parts = [str(p) for p in loc]
    # pydantic puts the union tag first ("can", "interface"); the field path is the rest
    if parts and parts[0] in SOURCES:
        parts = parts[1:]
    return ".".join(parts) or "<config>"


def parse_source_config(config: Union[Mapping[str, Any], CanSourceConfig, ModbusSourceConfig, ReplaySourceConfig]):
    """Validate a source configuration (a dict, e.g. a TOML table, or a config model).

    Raises :class:`SourceConfigError` naming each bad field (``source.port: Input should be
    less than or equal to 65535 (got 70000)``) and, for an unknown ``kind``, the kinds known.
    """
    if isinstance(config, (CanSourceConfig, ModbusSourceConfig, ReplaySourceConfig)):
        return config
    if not isinstance(config, Mapping):
        raise SourceConfigError(f"source: expected a table with a 'kind' key, got {type(config).__name__}")
    kind = config.get("kind")
    if kind not in SOURCES:
        raise SourceConfigError(
            f"source.kind: {'missing' if kind is None else repr(kind) + ' is unknown'}; "
            f"known kinds: {', '.join(SOURCES)}"
        )
    try:
        return _ADAPTER.validate_python(dict(config))
    except ValidationError as exc:
        lines = [f"source.{_loc(e['loc'])}: {e['msg']} (got {e.get('input')!r})" for e in exc.errors(include_url=False)]
        raise SourceConfigError(f"source ({kind}): " + "; ".join(lines)) from None


def open_source(robot: Union[Robot, str, "os.PathLike[str]"], config: Any) -> Source:
    """Build the source ``config`` describes for ``robot`` (not yet opened: call
    ``open()`` or use it in a ``with`` block).

    ``robot``: a :class:`Robot` or a robot name/path; ``config``: a dict or a config model
    (``kind`` = ``can``, ``modbus`` or ``replay``). Raises :class:`SourceConfigError` for a
    bad configuration, naming the field (also for the files it names: DBC, register map,
    recording path), and :class:`~cablesvc.config.RobotFileError` for a bad robot.
    """
    rob = robot if isinstance(robot, Robot) else load_robot(robot)
    cfg = parse_source_config(config)
    if isinstance(cfg, ReplaySourceConfig) and not cfg.path.is_file():
        raise SourceConfigError(f"source.path: recording {cfg.path} not found")
    if isinstance(cfg, CanSourceConfig) and cfg.dbc is not None and not cfg.dbc.is_file():
        raise SourceConfigError(f"source.dbc: DBC file {cfg.dbc} not found")
    if isinstance(cfg, ModbusSourceConfig) and cfg.register_map is not None and not cfg.register_map.is_file():
        raise SourceConfigError(f"source.register_map: register map {cfg.register_map} not found")
    return SOURCES[cfg.kind](rob, cfg)

