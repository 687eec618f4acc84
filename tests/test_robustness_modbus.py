"""Robustness of the Modbus source against awkward register maps and misbehaving servers.

Every test talks to a real pymodbus server on 127.0.0.1 (the simulated controller, or a
pymodbus server misconfigured on purpose); nothing is mocked.

* A 2- or 4-register value is never split across two read requests (the plan covers whole
  values), so a map whose ``t`` or ``seq`` sits at the 125-register request limit is read.
* A server that accepts connections but never answers a read is one outage: one
  ``disconnected``, reconnect attempts with backoff (not a spin), one ``reconnected`` when
  a working server is back.
* A float ``missing`` sentinel (``-999.9``) is compared as the value the registers can hold;
  one the type cannot hold is refused at load naming the file and the field.
"""

from __future__ import annotations

import asyncio
import dataclasses
import struct
import threading
import time

import numpy as np
import pytest

from cablesvc.recording import Recording
from cablesvc.simulate import simulate_recording
from cablesvc.sources import SourceConfigError, TickInput, load_register_map, open_source
from cablesvc.netutil import free_tcp_port
from cablesvc.sources.simulated import ModbusController
from cablesvc.sources.modbus_source import MAX_REGISTERS_PER_READ


@pytest.fixture(scope="module")
def twin(robot) -> Recording:
    return simulate_recording(robot, "trajectory", None, duration=1.0, rate=500.0, seed=3)


def _collect(src, n: int, timeout: float = 10.0) -> list[TickInput]:
    got: list[TickInput] = []
    end = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < end:
        tick = src.recv(timeout=0.1)
        if tick is not None:
            got.append(tick)
    return got


# t (float64, 4 registers) at 123..126: across the first 125-register boundary
T_AT_LIMIT = """
format = 1
registers = "holding"
max_gap = 125
[fields.seq]
address = 0
type = "uint32"
[fields.motor_length]
address = 2
type = "int32"
scale = 1e-7
[fields.t]
address = 123
type = "float64"
"""

# seq (uint32, 2 registers) at 124..125: the seq re-read and the first request both need it whole
SEQ_AT_LIMIT = """
format = 1
registers = "holding"
max_gap = 125
[fields.motor_length]
address = 0
type = "int32"
scale = 1e-7
[fields.t]
address = 16
type = "float64"
[fields.seq]
address = 124
type = "uint32"
"""


def _assert_whole_values(rmap) -> None:
    for name, els in rmap.elements.items():
        for e in els:
            inside = [(a, n) for a, n in rmap.read_plan if a <= e.address and e.address + e.width <= a + n]
            assert inside, f"{name}[{e.index}] at {e.address}..{e.address + e.width - 1} split by {rmap.read_plan}"
    assert all(n <= MAX_REGISTERS_PER_READ for _, n in rmap.read_plan)


@pytest.mark.parametrize("text", [T_AT_LIMIT, SEQ_AT_LIMIT], ids=["t_at_limit", "seq_at_limit"])
def test_values_at_the_request_limit_are_never_split_and_are_read_live(tmp_path, robot, twin, text):
    path = tmp_path / "limit.modbus.toml"
    path.write_text(text)
    rmap = load_register_map(path, robot.n_cables)
    _assert_whole_values(rmap)
    # seq whole in the first request (it is read again after the others)
    seq = rmap.elements["seq"][0]
    a, n = rmap.read_plan[0]
    assert a <= seq.address and seq.address + seq.width <= a + n

    port = free_tcp_port()
    ctl = ModbusController(robot, port=port, register_map=path, rate=50.0, recording=twin, history=4000)
    ctl.start()
    try:
        with open_source(robot, {"kind": "modbus", "port": port, "register_map": str(path),
                                 "rate_hz": 200.0, "timeout_s": 0.5}) as src:
            ticks = _collect(src, 10)
            assert len(ticks) == 10, (src.counters.as_dict(), src.problems())
            sent = {t.seq: t for t in ctl.sent()}
            for tick in ticks:
                want = sent[tick.seq]
                assert tick.t == want.t  # float64: exact
                np.testing.assert_allclose(tick.motor_length, want.motor_length, rtol=0, atol=0.6e-7)
            counters = src.counters.as_dict()
            assert "bad_frame" not in counters["rejected"], counters
            assert "disconnected" not in counters["events"], counters
    finally:
        ctl.stop()
    assert ctl.write_requests == 0


def test_random_maps_plan_whole_values(tmp_path):
    rng = np.random.default_rng(11)
    types = ["int16", "uint16", "int32", "uint32", "float32", "float64"]
    widths = {"int16": 1, "uint16": 1, "int32": 2, "uint32": 2, "float32": 2, "float64": 4}
    for k in range(60):
        # lay the fields out one after the other with random gaps, in random order
        names = ["seq", "t", "motor_length", "force", "temperature"]
        rng.shuffle(names)
        addr = int(rng.integers(0, 130))
        lines = ["format = 1", 'registers = "holding"', f"max_gap = {int(rng.integers(0, 126))}"]
        for name in names:
            typ = str(rng.choice(["uint16", "uint32"])) if name == "seq" else str(rng.choice(types))
            count = 8 if name in ("motor_length", "force") else 1
            lines += [f"[fields.{name}]", f"address = {addr}", f'type = "{typ}"']
            addr += count * widths[typ] + int(rng.integers(0, 60))
        path = tmp_path / f"r{k}.modbus.toml"
        path.write_text("\n".join(lines) + "\n")
        _assert_whole_values(load_register_map(path, 8))


# --------------------------------------------------------------------------------------
# reconnect backoff
# --------------------------------------------------------------------------------------


class _DeafServer:
    """A real pymodbus TCP server speaking the RTU framing: it accepts connections but never
    understands (so never answers) a Modbus TCP request: every read times out."""

    def __init__(self, port: int):
        self.port = port
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="test-deaf-modbus", daemon=True)
        self.thread.start()
        self.server = self._call(self._start())

    def _call(self, coro):
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(5.0)

    async def _start(self):
        from pymodbus import FramerType
        from pymodbus.server import ModbusTcpServer
        from pymodbus.simulator import DataType, SimData, SimDevice

        server = ModbusTcpServer(SimDevice(id=1, simdata=[SimData(address=0, count=60, values=0,
                                                                  datatype=DataType.REGISTERS)]),
                                 address=("127.0.0.1", self.port), framer=FramerType.RTU)
        await server.serve_forever(background=True)
        return server

    def stop(self) -> None:
        if self.server is None:
            return
        self._call(self.server.shutdown())
        self.server = None
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(2.0)


def test_reads_failing_after_connect_back_off_and_are_one_outage(robot, twin):
    port = free_tcp_port()
    deaf = _DeafServer(port)
    ctl = None
    try:
        src = open_source(robot, {"kind": "modbus", "port": port, "rate_hz": 200.0, "timeout_s": 0.05})
        with src:
            reasons: list[str] = []
            end = time.monotonic() + 2.0
            while time.monotonic() < end:
                assert src.recv(timeout=0.05) is None
                reasons += [p.reason for p in src.problems()]
            # connects work, every read times out after 0.05 s: without backoff ~40 cycles in 2 s
            assert src.requests < 20, (src.requests, src.counters.as_dict())
            assert reasons.count("disconnected") == 1, reasons
            assert "reconnected" not in reasons, reasons
            assert src.counters.events == {"disconnected": 1}

            # a working controller takes the port: ticks flow, one reconnected closes the outage
            deaf.stop()
            ctl = ModbusController(robot, port=port, rate=100.0, recording=twin, history=4000)
            ctl.start()
            got = _collect(src, 5, timeout=15.0)
            assert len(got) == 5, (src.counters.as_dict(), src.problems())
            assert src.counters.events == {"disconnected": 1, "reconnected": 1}, src.counters.as_dict()
    finally:
        deaf.stop()
        if ctl is not None:
            ctl.stop()


# --------------------------------------------------------------------------------------
# float missing sentinels
# --------------------------------------------------------------------------------------

F32_MISSING = """
format = 1
registers = "holding"
[fields.seq]
address = 0
type = "uint32"
[fields.t]
address = 2
type = "float64"
[fields.motor_length]
address = 6
type = "float32"
[fields.temperature]
address = 22
type = "float32"
missing = -999.9
[fields.force]
address = 24
type = "float32"
missing = -999.9
"""


def test_float32_missing_sentinel_is_recognised_as_the_controller_stores_it(tmp_path, robot, twin):
    path = tmp_path / "f32.modbus.toml"
    path.write_text(F32_MISSING)
    rmap = load_register_map(path, 8)
    # registers as a controller writes them: -999.9 stored as a float32
    sentinel = [int.from_bytes(b, "big") for b in (lambda p: (p[:2], p[2:]))(struct.pack(">f", -999.9))]
    tick = TickInput(seq=5, t=1.5, motor_length=np.full(8, 2.0), position=None, orientation=None,
                     force=np.full(8, 100.0), temperature=20.0, stamp_ns=0)
    (start, regs), = rmap.encode(tick)
    regs = list(regs)
    regs[22 - start:24 - start] = sentinel
    for i in range(8):
        regs[24 + 2 * i - start:26 + 2 * i - start] = sentinel
    got = rmap.decode({start: regs}, 0)
    assert isinstance(got, TickInput)
    assert got.temperature is None and got.force is None, (got.temperature, got.force)

    # live: a controller playing ticks without force/temperature every other row
    n = twin.n_ticks
    force = twin.force.copy()
    force[::2] = np.nan
    temperature = np.where(np.arange(n) % 2 == 0, np.nan, 25.0)
    rec = dataclasses.replace(twin, force=force, temperature=temperature)
    port = free_tcp_port()
    ctl = ModbusController(robot, port=port, register_map=path, rate=50.0, recording=rec, history=4000)
    ctl.start()
    try:
        with open_source(robot, {"kind": "modbus", "port": port, "register_map": str(path),
                                 "rate_hz": 200.0}) as src:
            ticks = _collect(src, 12)
            assert len(ticks) == 12, (src.counters.as_dict(), src.problems())
            sent = {t.seq: t for t in ctl.sent()}
            assert any(sent[t.seq].force is None for t in ticks) and any(sent[t.seq].force is not None for t in ticks)
            for tick in ticks:
                want = sent[tick.seq]
                assert (tick.force is None) == (want.force is None), (tick.seq, tick.force)
                assert (tick.temperature is None) == (want.temperature is None), (tick.seq, tick.temperature)
    finally:
        ctl.stop()


def test_missing_sentinels_the_type_cannot_hold_are_refused_naming_file_and_field(tmp_path):
    bad = tmp_path / "bad.modbus.toml"
    bad.write_text(F32_MISSING.replace("missing = -999.9\n[fields.force]", "missing = 1e39\n[fields.force]"))
    with pytest.raises(SourceConfigError) as ei:
        load_register_map(bad, 8)
    msg = str(ei.value)
    assert str(bad) in msg and "fields.temperature.missing" in msg and "float32" in msg
    assert "fields.force" not in msg  # -999.9 is fine: one message per problem


def test_integer_and_float64_missing_sentinels_still_work(tmp_path):
    text = F32_MISSING.replace('address = 22\ntype = "float32"\nmissing = -999.9',
                               'address = 22\ntype = "int16"\nscale = 0.01\nmissing = -32768')
    text = text.replace('address = 24\ntype = "float32"\nmissing = -999.9',
                        'address = 24\ntype = "float64"\nmissing = -999.9')
    path = tmp_path / "mixed.modbus.toml"
    path.write_text(text)
    rmap = load_register_map(path, 8)
    none = TickInput(seq=1, t=0.5, motor_length=np.full(8, 3.0), position=None, orientation=None, force=None,
                     temperature=None, stamp_ns=0)
    got = rmap.decode(dict(rmap.encode(none)), 0)
    assert got.temperature is None and got.force is None
    some = dataclasses.replace(none, force=np.full(8, 12.5), temperature=21.5)
    got = rmap.decode(dict(rmap.encode(some)), 0)
    np.testing.assert_array_equal(got.force, some.force)
    assert abs(got.temperature - 21.5) < 1e-9
    # an integer sentinel out of range is still refused
    path.write_text(text.replace("missing = -32768", "missing = -40000"))
    with pytest.raises(SourceConfigError, match=r"fields\.temperature\.missing"):
        load_register_map(path, 8)
