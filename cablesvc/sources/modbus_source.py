"""Modbus TCP input (pymodbus 3.16): poll a controller's registers, read-only.

The controller exposes one tick in registers described by a register map TOML file
(``robots/ipanema3.modbus.toml``; format in ``docs/sources.md``). :class:`ModbusSource`
polls it at ``rate_hz`` with pymodbus' ``AsyncModbusTcpClient`` on its own asyncio loop in
a background thread. It only ever calls read functions (``read_holding_registers``, 0x03,
or ``read_input_registers``, 0x04, as the map says): it never writes to the controller.

The whole map is read in as few contiguous requests as possible (one for the shipped map),
never splitting a 2- or 4-register value across two requests, so that one poll sees one
tick. When the map needs several requests, the one holding ``seq`` is sent first and
``seq`` is read again after the last; the poll is dropped as ``torn_read`` if it changed in
between. A poll that
sees the same ``seq`` as the previous poll is the same tick again (polling faster than the
controller ticks is normal) and is counted in ``counters.unchanged``, not as a problem.

Connection loss is reported once (``disconnected``), the client reconnects with backoff
(0.05 s doubling to 2 s) for as long as the source is open, and ``reconnected`` is
reported after the first successful read. A server that accepts connections but fails every
read is one outage: the backoff is reset only by a successful read. Exception responses
become ``modbus_error`` problems.
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import struct
import threading
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from cablesvc.config.robot import Robot
from cablesvc.errors import SourceError
from cablesvc.sources.base import (
    Rejection,
    SourceConfigError,
    ThreadedSource,
    TickInput,
    find_robot_companion,
)

__all__ = [
    "MAX_REGISTERS_PER_READ",
    "ModbusSource",
    "ModbusSourceConfig",
    "RegisterField",
    "RegisterMap",
    "RegisterMapFile",
    "load_register_map",
]

# pymodbus logs every failed connect at WARNING; the source reports those itself (once per
# outage), so keep pymodbus quiet unless the application configures logging for it.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

#: Most registers one read request may return (Modbus application protocol limit).
MAX_REGISTERS_PER_READ = 125

#: type name -> (struct code, number of 16-bit registers, is integer)
_TYPES: dict[str, tuple[str, int, bool]] = {
    "int16": ("h", 1, True),
    "uint16": ("H", 1, True),
    "int32": ("i", 2, True),
    "uint32": ("I", 2, True),
    "float32": ("f", 2, False),
    "float64": ("d", 4, False),
}
_INT_RANGE = {
    "int16": (-(1 << 15), (1 << 15) - 1),
    "uint16": (0, (1 << 16) - 1),
    "int32": (-(1 << 31), (1 << 31) - 1),
    "uint32": (0, (1 << 32) - 1),
}


# --------------------------------------------------------------------------------------
# register map file
# --------------------------------------------------------------------------------------


class RegisterField(BaseModel):
    """One field of the register map: where and how a value is stored.

    ``address``: first register (0-based, as in the requests); ``type``: int16, uint16,
    int32, uint32, float32, float64; ``scale``/``offset``: value = raw * scale + offset (SI
    units); ``word_order``: "big" (most significant register first) or "little";
    ``stride``: for vector fields, registers from one element to the next (default: the
    type's width, i.e. packed); ``missing``: the raw value that means "not measured" (for
    floats NaN always means so).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    address: int = Field(strict=True, ge=0, le=65535)
    type: Literal["int16", "uint16", "int32", "uint32", "float32", "float64"]
    scale: float = Field(default=1.0, strict=False, allow_inf_nan=False)
    offset: float = Field(default=0.0, allow_inf_nan=False)
    word_order: Literal["big", "little"] = "big"
    stride: Optional[int] = Field(default=None, strict=True, ge=1)
    missing: Optional[Union[int, float]] = None


class RegisterFields(BaseModel):
    """The ``[fields]`` table: one entry per tick field."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    seq: RegisterField
    t: RegisterField
    motor_length: RegisterField
    force: Optional[RegisterField] = None
    position: Optional[RegisterField] = None
    orientation: Optional[RegisterField] = None
    temperature: Optional[RegisterField] = None


class RegisterMapFile(BaseModel):
    """A register map file (``format = 1``): which read function and the fields."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    format: Literal[1]
    description: str = ""
    registers: Literal["holding", "input"]
    max_gap: int = Field(default=0, strict=True, ge=0, le=MAX_REGISTERS_PER_READ)
    fields: RegisterFields


def _loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (("." if out else "") + str(part))
    return out or "<top level>"


@dataclass(frozen=True)
class _Element:
    """One stored value: field name, element index, address, type."""

    field: str
    index: int
    address: int
    code: str
    width: int
    is_int: bool
    scale: float
    offset: float
    little: bool
    missing: Optional[Union[int, float]]


class RegisterMap:
    """A validated register map for a robot with ``n_cables`` cables.

    ``function``: "holding" or "input"; ``read_plan``: list of (address, count) requests,
    contiguous, each at most :data:`MAX_REGISTERS_PER_READ`, the one holding ``seq`` first;
    ``seq_bits``: width of the seq
    register. :meth:`decode` turns the registers of one poll into a tick; :meth:`encode`
    does the reverse (the simulated controller uses it).
    """

    def __init__(self, spec: RegisterMapFile, n_cables: int, path: str = "<register map>"):
        self.spec = spec
        self.path = path
        self.n_cables = int(n_cables)
        self.function = spec.registers
        problems: list[str] = []
        counts = {"seq": 1, "t": 1, "motor_length": self.n_cables, "force": self.n_cables,
                  "position": 3, "orientation": 4, "temperature": 1}
        self.elements: dict[str, list[_Element]] = {}
        for name, count in counts.items():
            f: Optional[RegisterField] = getattr(spec.fields, name)
            if f is None:
                continue
            code, width, is_int = _TYPES[f.type]
            stride = f.stride if f.stride is not None else width
            if stride < width:
                problems.append(f"{path}: fields.{name}.stride: {stride} is less than the {width} registers of {f.type}")
            if f.scale == 0:
                problems.append(f"{path}: fields.{name}.scale: must not be 0")
            missing: Optional[Union[int, float]] = f.missing
            if f.missing is not None:
                if is_int:
                    lo, hi = _INT_RANGE[f.type]
                    if not isinstance(f.missing, int) or not lo <= f.missing <= hi:
                        problems.append(f"{path}: fields.{name}.missing: {f.missing!r} is not a raw {f.type} value")
                elif not isinstance(f.missing, (int, float)):
                    problems.append(f"{path}: fields.{name}.missing: must be a number")
                else:
                    # compare with the value the registers can hold: -999.9 stored as float32
                    # reads back as -999.9000244..., which would never equal -999.9
                    try:
                        missing = struct.unpack(">" + code, struct.pack(">" + code, float(f.missing)))[0]
                    except (OverflowError, struct.error):
                        problems.append(f"{path}: fields.{name}.missing: {f.missing!r} cannot be stored "
                                        f"as {f.type}")
                        missing = None
            els = []
            for i in range(count):
                addr = f.address + i * stride
                if addr + width > 65536:
                    problems.append(f"{path}: fields.{name}: element {i} at {addr} runs past register 65535")
                els.append(_Element(name, i, addr, code, width, is_int, float(f.scale), float(f.offset),
                                    f.word_order == "little", missing))
            self.elements[name] = els
        seq = spec.fields.seq
        if seq.type not in ("uint16", "uint32") or seq.scale != 1 or seq.offset != 0 or seq.missing is not None:
            problems.append(f"{path}: fields.seq: must be uint16 or uint32 with scale 1, offset 0 and no missing value")
        if spec.fields.motor_length.missing is not None:
            problems.append(f"{path}: fields.motor_length.missing: motor lengths are always required")
        # overlaps
        owner: dict[int, str] = {}
        for name, els in self.elements.items():
            for e in els:
                for a in range(e.address, e.address + e.width):
                    label = f"{name}[{e.index}]" if len(els) > 1 else name
                    if a in owner and owner[a] != label:
                        problems.append(f"{path}: fields.{name}: register {a} of {label} is also used by {owner[a]}")
                    owner.setdefault(a, label)
        if problems:
            raise SourceConfigError(f"register map {path}: {len(problems)} problem(s):\n" + "\n".join(problems))
        self.seq_bits = 16 if seq.type == "uint16" else 32
        plan = self._plan(sorted((e.address, e.width) for els in self.elements.values() for e in els),
                          spec.max_gap)
        # the span holding seq goes first: with several requests, seq is read again after
        # the last one, and an unchanged seq proves every span in between saw one tick
        first = next(k for k, (a, n) in enumerate(plan) if a <= seq.address < a + n)
        self.read_plan = [plan[first]] + plan[:first] + plan[first + 1:]

    @staticmethod
    def _plan(values: list[tuple[int, int]], max_gap: int) -> list[tuple[int, int]]:
        """Requests covering ``values`` ((address, width), sorted, not overlapping), whole
        values only: a 2- or 4-register value is never split across two requests."""
        spans: list[list[int]] = []  # [first, last] register of each request
        for a, w in values:
            last = a + w - 1
            if spans and a - spans[-1][1] <= max_gap + 1 and last - spans[-1][0] < MAX_REGISTERS_PER_READ:
                spans[-1][1] = max(spans[-1][1], last)
            else:
                spans.append([a, last])
        return [(lo, hi - lo + 1) for lo, hi in spans]

    # ------------------------------------------------------------------ decode
    @staticmethod
    def _words(e: _Element, regs: list[int]) -> bytes:
        if e.little:
            regs = regs[::-1]
        return b"".join(int(r).to_bytes(2, "big") for r in regs)

    def _raw(self, e: _Element, blocks: dict[int, list[int]]) -> Union[int, float]:
        for start, regs in blocks.items():
            off = e.address - start
            if 0 <= off and off + e.width <= len(regs):
                return struct.unpack(">" + e.code, self._words(e, regs[off:off + e.width]))[0]
        raise KeyError(f"register {e.address} was not read")

    def _value(self, e: _Element, blocks: dict[int, list[int]]) -> float:
        raw = self._raw(e, blocks)
        if e.missing is not None and raw == e.missing:
            return math.nan
        if not e.is_int and math.isnan(raw):
            return math.nan
        return raw * e.scale + e.offset

    def raw_seq(self, blocks: dict[int, list[int]]) -> int:
        """The seq register of one poll (raw, modulo 2**seq_bits)."""
        return int(self._raw(self.elements["seq"][0], blocks))

    def decode(self, blocks: dict[int, list[int]], stamp_ns: int) -> Union[TickInput, Rejection]:
        """Registers of one poll (``{start address: registers}`` of :attr:`read_plan`) -> tick.

        A vector (force, pose) that is missing as a whole becomes None; one that is missing
        in part is rejected (``nonfinite``), naming the registers."""
        seq = self.raw_seq(blocks)
        t = self._value(self.elements["t"][0], blocks)
        where = f"registers of tick seq {seq}"
        ml = np.array([self._value(e, blocks) for e in self.elements["motor_length"]], dtype=np.float64)

        def vector(name: str) -> Union[None, np.ndarray, Rejection]:
            els = self.elements.get(name)
            if els is None:
                return None
            v = np.array([self._value(e, blocks) for e in els], dtype=np.float64)
            na = np.isnan(v)
            if na.all():
                return None
            if na.any():
                bad = ", ".join(f"{name}[{e.index}] (register {e.address})" for e, n in zip(els, na) if n)
                return Rejection("nonfinite", f"{where}: {bad} missing while the rest of {name} is given")
            return v

        force = vector("force")
        if isinstance(force, Rejection):
            return force
        pos = vector("position")
        if isinstance(pos, Rejection):
            return pos
        ori = vector("orientation")
        if isinstance(ori, Rejection):
            return ori
        if (pos is None) != (ori is None):
            return Rejection("nonfinite", f"{where}: {'position' if pos is None else 'orientation'} missing "
                                          f"while the other half of the pose is given")
        temp = None
        if "temperature" in self.elements:
            tv = self._value(self.elements["temperature"][0], blocks)
            temp = None if math.isnan(tv) else tv
        return TickInput(seq=seq, t=t, motor_length=ml, position=pos, orientation=ori, force=force,
                         temperature=temp, stamp_ns=stamp_ns)

    # ------------------------------------------------------------------ encode
    def _encode_value(self, e: _Element, value: Optional[float]) -> list[int]:
        if value is None or (isinstance(value, float) and math.isnan(value)):
            if e.missing is not None:
                raw: Union[int, float] = e.missing
            elif not e.is_int:
                raw = math.nan
            else:
                raise ValueError(f"{self.path}: fields.{e.field}[{e.index}] has no missing value; cannot store None")
        else:
            x = (float(value) - e.offset) / e.scale
            if e.is_int:
                raw = int(round(x))
                lo, hi = _INT_RANGE[next(k for k, v in _TYPES.items() if v[0] == e.code)]
                if not lo <= raw <= hi or raw == e.missing:
                    raise ValueError(f"{self.path}: fields.{e.field}[{e.index}]: {value!r} does not fit")
            else:
                raw = x
        b = struct.pack(">" + e.code, raw)
        regs = [int.from_bytes(b[k:k + 2], "big") for k in range(0, len(b), 2)]
        return regs[::-1] if e.little else regs

    def encode(self, tick: Any) -> list[tuple[int, list[int]]]:
        """The registers of one tick as ``[(start address, registers)]`` following
        :attr:`read_plan` (registers between fields are 0). ``seq`` is stored modulo
        2**seq_bits; None/NaN parts are stored as the field's missing value."""
        get = (lambda k: tick.get(k)) if isinstance(tick, dict) else (lambda k: getattr(tick, k, None))
        values: dict[str, Any] = {
            "seq": [int(get("seq")) % (1 << self.seq_bits)],
            "t": [float(get("t"))],
            "motor_length": np.asarray(get("motor_length"), dtype=np.float64).tolist(),
            "temperature": [get("temperature")],
        }
        for name, n in (("force", self.n_cables), ("position", 3), ("orientation", 4)):
            v = get(name)
            values[name] = [None] * n if v is None else np.asarray(v, dtype=np.float64).tolist()
        out: list[tuple[int, list[int]]] = []
        for start, count in self.read_plan:
            out.append((start, [0] * count))
        for name, els in self.elements.items():
            vals = values[name]
            for e in els:
                regs = self._encode_value(e, vals[e.index] if e.field != "seq" else vals[0])
                for start, block in out:
                    off = e.address - start
                    if 0 <= off < len(block):
                        block[off:off + len(regs)] = regs
                        break
        return out


def load_register_map(path: Union[str, os.PathLike[str]], n_cables: int) -> RegisterMap:
    """Read and validate a register map TOML file; :class:`SourceConfigError` lists every
    problem, each naming the file and the entry (``fields.force.type: ...``)."""
    p = Path(path)
    if not p.is_file():
        raise SourceConfigError(f"{p}: register map file not found")
    try:
        raw = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceConfigError(f"{p}: cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SourceConfigError(f"{p}: TOML syntax error: {exc}") from None
    try:
        spec = RegisterMapFile.model_validate(raw)
    except ValidationError as exc:
        lines = [f"{p}: {_loc(e['loc'])}: {e['msg']} (got {e.get('input')!r})" for e in exc.errors(include_url=False)]
        raise SourceConfigError(f"register map {p}: {len(lines)} problem(s):\n" + "\n".join(lines)) from None
    return RegisterMap(spec, n_cables, str(p))


# --------------------------------------------------------------------------------------
# the source
# --------------------------------------------------------------------------------------


class ModbusSourceConfig(BaseModel):
    """``kind = "modbus"``: poll a Modbus TCP server (the robot controller), read-only.

    ``host``/``port``: the server; ``unit``: Modbus device id; ``rate_hz`` [Hz]: polls per
    second (poll at least as fast as the controller ticks; repeated ticks are skipped);
    ``register_map``: TOML file (None: ``<robot>.modbus.toml`` found like robot files);
    ``timeout_s`` [s]: connect and response timeout.
    """

    model_config = ConfigDict(extra="forbid")

    kind: Literal["modbus"] = "modbus"
    host: str = "127.0.0.1"
    port: int = Field(default=5020, ge=1, le=65535)
    unit: int = Field(default=1, ge=0, le=255)
    rate_hz: float = Field(default=100.0, gt=0, le=10000, allow_inf_nan=False)
    register_map: Optional[Path] = None
    timeout_s: float = Field(default=1.0, gt=0, allow_inf_nan=False)


class ModbusSource(ThreadedSource):
    """Ticks polled from a Modbus TCP controller (see the module docstring).

    Read-only by construction: the only pymodbus calls made are ``connect``,
    ``read_holding_registers`` or ``read_input_registers`` (per the register map), and
    ``close``; no write function is ever called.
    """

    kind: ClassVar[str] = "modbus"

    def __init__(self, robot: Robot, config: ModbusSourceConfig):
        path = config.register_map
        if path is None:
            try:
                path = find_robot_companion(robot, ".modbus.toml")
            except SourceConfigError as exc:
                raise SourceConfigError(f"source.register_map: {exc}") from None
        self.register_map = load_register_map(path, robot.n_cables)
        super().__init__(robot, config)
        self.config: ModbusSourceConfig = config
        self._loop: Optional[asyncio.AbstractEventLoop] = None
        self._task: Optional[asyncio.Task] = None
        self._last_raw_seq: Optional[int] = None
        #: Read requests sent (successful or not); for tests and statistics.
        self.requests = 0

    def _seq_bits(self) -> Optional[int]:
        return self.register_map.seq_bits

    @property
    def label(self) -> str:
        return f"modbus {self.config.host}:{self.config.port} unit {self.config.unit}"

    def open(self) -> None:
        """Start the polling thread (connection problems are reported, not raised)."""
        if self._opened:
            return
        self._opened = True
        ready = threading.Event()
        self._start_thread(lambda: self._thread_main(ready), f"cablesvc-modbus-{self.config.port}")
        ready.wait(1.0)

    def _thread_main(self, ready: threading.Event) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            self._task = loop.create_task(self._main())
            ready.set()
            loop.run_until_complete(self._task)
        except asyncio.CancelledError:
            pass
        finally:
            ready.set()
            try:
                loop.run_until_complete(loop.shutdown_asyncgens())
            finally:
                loop.close()

    async def _read(self, client: Any) -> dict[int, list[int]]:
        fn = client.read_holding_registers if self.register_map.function == "holding" else client.read_input_registers
        blocks: dict[int, list[int]] = {}
        for start, count in self.register_map.read_plan:
            self.requests += 1
            rr = await fn(start, count=count, device_id=self.config.unit)
            if rr.isError():
                raise _ModbusErrorResponse(f"{self.register_map.function} registers {start}..{start + count - 1}: "
                                           f"exception response {rr!s}")
            regs = list(rr.registers)
            if len(regs) < count:
                raise _ModbusErrorResponse(f"registers {start}..{start + count - 1}: got {len(regs)} values")
            blocks[start] = regs[:count]
        return blocks

    async def _main(self) -> None:
        from pymodbus.client import AsyncModbusTcpClient

        cfg = self.config
        period = 1.0 / cfg.rate_hz
        backoff = 0.05
        down_since: Optional[float] = None
        client: Optional[Any] = None
        multi = len(self.register_map.read_plan) > 1
        next_poll = time.monotonic()

        async def lost(message: str) -> None:
            """The link is down: report ``disconnected`` (``message``) once per outage, drop
            the client, wait the backoff and double it (up to 2 s)."""
            nonlocal backoff, client, down_since
            if down_since is None:
                down_since = time.monotonic()
                self._report("disconnected", message, kind="event")
            if client is not None:
                client.close()
            client = None
            await asyncio.sleep(backoff)
            backoff = min(2.0, backoff * 2)

        try:
            while not self._stop.is_set():
                if client is None or not client.connected:
                    if client is not None:
                        client.close()
                    client = AsyncModbusTcpClient(cfg.host, port=cfg.port, timeout=cfg.timeout_s, retries=0,
                                                  reconnect_delay=0, name="cablesvc")
                    ok = False
                    err = "connection refused or timed out"
                    try:
                        ok = await client.connect()
                    except Exception as exc:  # noqa: BLE001 - socket errors of any kind
                        err = repr(exc)
                    if not ok:
                        await lost(f"cannot connect ({err}); retrying with backoff up to 2 s")
                        continue
                    # ``reconnected`` and the backoff reset wait for a successful read: a
                    # server that accepts and then fails every read is still one outage
                    next_poll = time.monotonic()
                blocks: Optional[dict[int, list[int]]] = None
                try:
                    blocks = await self._read(client)
                    again = await self._read_seq(client) if multi else None
                except _ModbusErrorResponse as exc:
                    self._report("modbus_error", str(exc))
                except asyncio.CancelledError:
                    raise
                except Exception as exc:  # noqa: BLE001 - pymodbus raises ModbusException, OSError, TimeoutError
                    await lost(f"connection lost: {exc!r}; reconnecting with backoff up to 2 s")
                    continue
                if blocks is not None:
                    backoff = 0.05
                    if down_since is not None:
                        self._report("reconnected", f"connected again after {time.monotonic() - down_since:.2f} s",
                                     kind="event")
                        down_since = None
                    try:
                        first = self.register_map.raw_seq(blocks)
                    except Exception as exc:  # noqa: BLE001 - a bad reply is a bad frame, not a lost link
                        self._report("bad_frame", f"cannot decode the seq register: {exc!r}")
                        blocks = None
                    else:
                        if multi and again != first:
                            self._report("torn_read", f"seq changed from {first} to {again} while the map "
                                                      f"was being read; poll dropped")
                            blocks = None
                if blocks is not None:
                    stamp = time.monotonic_ns()
                    seq = self.register_map.raw_seq(blocks)
                    if seq == self._last_raw_seq:
                        self.counters.unchanged += 1
                    else:
                        self._last_raw_seq = seq
                        try:
                            ev = self.register_map.decode(blocks, stamp)
                        except Exception as exc:  # noqa: BLE001 - never let a bad value kill the poller
                            ev = Rejection("bad_frame", f"cannot decode the registers of seq {seq}: {exc!r}")
                        if isinstance(ev, Rejection):
                            self._report(ev.reason, ev.message)
                        else:
                            self._deliver(ev)
                next_poll += period
                now = time.monotonic()
                if next_poll < now:  # behind: skip the missed slots rather than burst
                    next_poll = now + period - ((now - next_poll) % period)
                await asyncio.sleep(max(0.0, next_poll - now))
        finally:
            if client is not None:
                client.close()

    async def _read_seq(self, client: Any) -> int:
        e = self.register_map.elements["seq"][0]
        fn = client.read_holding_registers if self.register_map.function == "holding" else client.read_input_registers
        self.requests += 1
        rr = await fn(e.address, count=e.width, device_id=self.config.unit)
        if rr.isError():
            raise _ModbusErrorResponse(f"seq register {e.address}: exception response {rr!s}")
        if len(rr.registers) < e.width:
            raise _ModbusErrorResponse(f"seq register {e.address}: got {len(rr.registers)} values")
        return self.register_map.raw_seq({e.address: list(rr.registers)})

    def close(self) -> None:
        """Stop polling, close the connection, join the thread (idempotent, < 1 s)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        loop, task = self._loop, self._task
        if loop is not None and task is not None and not loop.is_closed():
            try:
                loop.call_soon_threadsafe(task.cancel)
            except RuntimeError:
                pass
        self._join_thread(0.9)


class _ModbusErrorResponse(SourceError):
    """The server answered a read with a Modbus exception response (or too few registers)."""
