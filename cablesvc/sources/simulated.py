"""Simulated robot controllers: they play the controller's side of a source's transport.

Used by the default demo (``cablesvc run`` without hardware), the tests and the benchmarks.
A :class:`SimulatedController` precomputes a digital-twin recording
(:func:`cablesvc.simulate.simulate_twin`) and plays it endlessly from a thread at
``rate`` ticks per second in real time. The motion is played forward, then backward, then
forward again, so the motor lengths never jump, while ``seq`` (+1 per tick) and ``t``
(seq / rate [s]) keep increasing. The measured forces are not the forward run's forces
read backwards: a hysteretic cable does not retrace its loop when the motion reverses
(the damping term changes sign), so playing them backwards would show the daemon a
model error of several newtons that no real cable has. The twin's truth model is
therefore run over the whole there-and-back motion, twice, and the second (periodic)
cycle is played in a loop: force and motion agree at every tick. Ticks are spaced by a deadline loop: sleep until just
before the tick's time, then spin for the last ``spin_s`` seconds.

Transports:

* :class:`CanController` sends the frames of :func:`~cablesvc.sources.can.encode_tick`
  on a python-can bus (``bus_config`` as returned by
  :func:`~cablesvc.netutil.loopback_bus_config`), classic CAN or CAN FD
  (``fd``). The frames of the whole recording are encoded once at start (one numpy pass);
  each tick only adds its t, seq and tick counters.
* :class:`ModbusController` runs a real pymodbus TCP server and updates its registers every
  tick (register map as for :class:`~cablesvc.sources.modbus_source.ModbusSource`); it counts
  the requests it receives (``read_requests``, ``write_requests``).

Run one in its own process (benchmarks, cross-process tests)::

    python -m cablesvc.sources.simulated --transport can --loopback --rate 1000 --seconds 10
    python -m cablesvc.sources.simulated --transport can --fd --port 43117 --rate 1000 --seconds 10
    python -m cablesvc.sources.simulated --transport modbus --port 5020 --rate 1000 --seconds 10
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import functools
import json
import os
import sys
import threading
import time
from typing import Any, Optional, Union

import numpy as np

from cablesvc.config.robot import Robot, load_robot
from cablesvc.recording import Recording
from cablesvc.sources.base import TickInput, find_robot_companion

__all__ = [
    "CanController",
    "ModbusController",
    "SimulatedController",
    "main",
    "run_controller_process",
]


#: how many ticks :meth:`SimulatedController.timing` keeps (a power of two)
_TIMING_RING = 1 << 16


#: packages whose code makes the twin's recordings (their source is part of the cache key)
_TWIN_PACKAGES = ("simulate", "models", "kinematics", "config")
#: cached motions kept in the cache directory (the newest; a few MB each)
_CACHE_KEEP = 12


@functools.lru_cache(maxsize=1)
def _twin_code_digest() -> str:
    """SHA-256 over the source of the packages the twin's result depends on (and the
    package version): a cached motion is never one that other code computed."""
    import hashlib
    from pathlib import Path

    import cablesvc

    h = hashlib.sha256(cablesvc.__version__.encode())
    root = Path(cablesvc.__file__).resolve().parent
    for pkg in _TWIN_PACKAGES:
        for f in sorted((root / pkg).rglob("*.py")):
            h.update(str(f.relative_to(root)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def controller_cache_dir() -> str:
    """Where simulated controllers keep their precomputed motion: ``$CABLESVC_CACHE_DIR``
    or ``$XDG_CACHE_HOME/cablesvc`` or ``~/.cache/cablesvc``, then ``controller/``."""
    base = os.environ.get("CABLESVC_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "cablesvc")
    return os.path.join(base, "controller")


def cached_there_and_back_recording(robot: Robot, scenario: str, *, duration: float, rate: float,
                                    seed: int) -> tuple[Recording, str]:
    """:func:`there_and_back_recording`, kept in :func:`controller_cache_dir` under a key of
    the robot (all its fields), the arguments and the twin's code: the embedded demo's 10 s
    at 1 kHz cost some 5 s of twin simulation at every start. A cache that cannot be read
    or written is skipped (the motion is computed). Returns (recording, what happened:
    ``"cached"``, ``"computed"`` or ``"computed (cache not written: ...)"``)."""
    import hashlib
    import logging
    import tempfile

    key = hashlib.sha256(json.dumps({"robot": robot.model_dump(mode="json", exclude={"source"}),
                                     "scenario": scenario, "duration": float(duration), "rate": float(rate),
                                     "seed": int(seed), "code": _twin_code_digest()},
                                    sort_keys=True, default=str).encode()).hexdigest()[:24]
    d = controller_cache_dir()
    path = os.path.join(d, f"{robot.name}-{scenario}-{key}.npz")
    fields = ("t", "seq", "motor_length", "position", "orientation", "force", "temperature")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: (z[k] if k in z.files else None) for k in fields}
            meta = json.loads(str(z["metadata"]))
            if str(z["robot"]) != robot.name:
                raise ValueError("robot name")
        return Recording(robot=robot.name, metadata=meta, **arrays), "cached"
    except Exception:       # missing, cut (BadZipFile), foreign: a cache, so compute instead
        pass
    rec = there_and_back_recording(robot, scenario, duration=duration, rate=rate, seed=seed)
    try:
        os.makedirs(d, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=d, suffix=".npz.tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, robot=np.array(rec.robot), metadata=np.array(json.dumps(rec.metadata)),
                         **{k: getattr(rec, k) for k in fields if getattr(rec, k) is not None})
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
        old = sorted((os.path.join(d, f) for f in os.listdir(d) if f.endswith(".npz")), key=os.path.getmtime)
        for f in old[:-_CACHE_KEEP]:                 # the newest few: other robots, rates, code versions
            try:
                os.unlink(f)
            except OSError:
                pass
    except OSError as e:
        logging.getLogger(__name__).debug("controller cache not written: %s", e)
        return rec, f"computed (cache not written: {e})"
    return rec, "computed"


def there_and_back_recording(robot: Robot, scenario: str, *, duration: float, rate: float,
                             seed: int) -> Recording:
    """One period of endless play: the twin's motion forward then backward (rows 0 .. n-1,
    n-2 .. 1), with the measured forces the twin's truth model gives on that motion.

    The truth model runs over two such periods from rest and the second is kept, so the
    hysteresis state at the end of the period is the one at its start: looping it is
    seamless. t and seq of the result are those of play (k / rate, k)."""
    from cablesvc.simulate import simulate_twin

    run = simulate_twin(robot, scenario, duration=duration, rate=rate, seed=seed)
    rec = run.recording
    n = rec.n_ticks
    if n < 2:
        raise ValueError("the controller needs a recording of at least 2 ticks")
    rows = np.concatenate([np.arange(n), np.arange(n - 2, 0, -1)])
    period = rows.size
    twice = np.concatenate([rows, rows])
    dt = 1.0 / float(rate)
    out = run.truth.run(t=np.arange(2 * period) * dt, dt=dt, elongation=run.elongation[twice],
                        motor_length=rec.motor_length[twice], wrap_angle=run.wrap_angle[twice],
                        free_length=run.free_length[twice], temperature=rec.temperature[twice],
                        rng=np.random.default_rng([seed, 4]))

    def take(a: Optional[np.ndarray]) -> Optional[np.ndarray]:
        return None if a is None else a[rows]

    metadata = dict(rec.metadata, playback="there-and-back cycle, forces from the truth model on it")
    return Recording(robot=rec.robot, metadata=metadata, t=np.arange(period) * dt,
                     seq=np.arange(period, dtype=np.int64), motor_length=rec.motor_length[rows],
                     position=take(rec.position), orientation=take(rec.orientation),
                     force=out.measured[period:], temperature=take(rec.temperature))


class SimulatedController:
    """Plays a twin recording as a controller would, at ``rate`` [Hz], from a thread.

    ``robot``: a :class:`Robot` or a robot name/path; ``scenario``, ``seed``, ``duration`` [s]:
    what :func:`cablesvc.simulate.simulate_recording` computes (``recording`` gives one
    directly instead). ``history``: keep the last that many sent ticks in :attr:`history`
    (0: none). ``spin_s`` [s]: busy-wait window before each tick (0: sleep only).
    ``start_seq``: seq of the first tick (t = seq / rate).

    :attr:`ticks_sent`, :attr:`last_sent`, :attr:`send_errors` (transport errors; the
    controller keeps ticking), :attr:`overruns` (times the thread fell more than 0.1 s
    behind and restarted its schedule), :attr:`late_ticks` (ticks whose sending began more
    than one period after their due time); :meth:`timing` gives how late the ticks were
    sent and how long sending took (percentiles over the last 65536 ticks).
    """

    def __init__(
        self,
        robot: Union[Robot, str, "os.PathLike[str]"],
        *,
        scenario: str = "trajectory",
        rate: float = 1000.0,
        seed: int = 0,
        duration: float = 60.0,
        history: int = 0,
        spin_s: float = 2e-4,
        start_seq: int = 0,
        recording: Optional[Recording] = None,
    ):
        self.robot = robot if isinstance(robot, Robot) else load_robot(robot)
        if not (rate > 0):
            raise ValueError(f"rate must be > 0 Hz, got {rate!r}")
        self.rate = float(rate)
        #: True when the recording is one whole there-and-back cycle played in a loop
        self.periodic = recording is None
        #: where the motion came from: "given", "cached" or "computed" (see
        #: :func:`cached_there_and_back_recording`)
        self.motion_source = "given"
        if recording is None:
            recording, self.motion_source = cached_there_and_back_recording(self.robot, scenario, duration=duration,
                                                                            rate=rate, seed=seed)
        if recording.n_ticks < 2:
            raise ValueError("the controller needs a recording of at least 2 ticks")
        if recording.n_cables != self.robot.n_cables:
            raise ValueError(f"recording has {recording.n_cables} cables, robot {self.robot.name} has "
                             f"{self.robot.n_cables}")
        self.recording = recording
        n = recording.n_ticks

        def present(a: Optional[np.ndarray]) -> np.ndarray:
            if a is None:
                return np.zeros(n, dtype=bool)
            return ~np.isnan(a.reshape(n, -1)).all(axis=1)

        # which rows have a force / a pose / a temperature (tick_at plays the others as None)
        self._has = {"force": present(recording.force),
                     "pose": present(recording.position) & present(recording.orientation),
                     "temperature": present(recording.temperature)}
        self.spin_s = max(0.0, float(spin_s))
        self.start_seq = int(start_seq)
        self.ticks_sent = 0
        self.send_errors = 0
        self.last_send_error: Optional[str] = None
        self.overruns = 0
        self.late_ticks = 0
        self.late_max_s = 0.0
        self._late_us = np.zeros(_TIMING_RING, dtype=np.float32)  # send start - due time [us]
        self._send_us = np.zeros(_TIMING_RING, dtype=np.float32)  # time in _send [us]
        self.last_sent: Optional[TickInput] = None
        self.history: Optional[collections.deque[TickInput]] = (
            collections.deque(maxlen=int(history)) if history else None
        )
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._max_ticks: Optional[int] = None
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ ticks
    def row_at(self, k: int) -> int:
        """The recording row of the k-th tick: a there-and-back twin cycle in a loop, or a
        given recording forward, then backward, then forward ..."""
        n = self.recording.n_ticks
        if self.periodic:
            return k % n
        period = 2 * n - 2
        j = k % period
        return j if j < n else period - j

    def tick_at(self, k: int) -> TickInput:
        """The k-th tick played (k >= 0): recording row by forward/backward play,
        seq = start_seq + k, t = seq / rate [s]. A row whose force (position, orientation,
        temperature) is all NaN has none (a pose needs both parts)."""
        i = self.row_at(k)
        rec = self.recording
        has = self._has
        force = rec.force[i].copy() if has["force"][i] else None
        pos = ori = None
        if has["pose"][i]:
            pos, ori = rec.position[i].copy(), rec.orientation[i].copy()
        temp = float(rec.temperature[i]) if has["temperature"][i] else None
        seq = self.start_seq + k
        return TickInput(seq=seq, t=seq / self.rate, motor_length=rec.motor_length[i].copy(), position=pos,
                         orientation=ori, force=force, temperature=temp, stamp_ns=0)

    # ------------------------------------------------------------------ transport
    def _open(self) -> None:
        """Open the transport (subclasses)."""

    def _send(self, tick: TickInput, k: Optional[int] = None) -> None:
        """Publish one tick (subclasses); ``k``: its index when it is ``tick_at(k)`` unchanged."""
        raise NotImplementedError

    def _close(self) -> None:
        """Close the transport (subclasses)."""

    # ------------------------------------------------------------------ run
    def start(self, ticks: Optional[int] = None) -> "SimulatedController":
        """Open the transport and start ticking (``ticks``: stop after that many; None: until
        :meth:`stop`)."""
        if self._thread is not None:
            raise RuntimeError("controller already started")
        self._open()
        self._max_ticks = ticks
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"cablesvc-sim-{type(self).__name__}", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        period = 1.0 / self.rate
        start = time.monotonic()
        k = 0
        while not self._stop.is_set():
            if self._max_ticks is not None and k >= self._max_ticks:
                break
            target = start + k * period
            now = time.monotonic()
            if target - now > self.spin_s:
                if self._stop.wait(target - now - self.spin_s):
                    break
            while time.monotonic() < target:
                pass
            tick = self.tick_at(k)
            tick.stamp_ns = t_send = time.monotonic_ns()
            try:
                self._send(tick, k)
            except Exception as exc:  # noqa: BLE001 - a transport error must not stop the controller
                self.send_errors += 1
                self.last_send_error = repr(exc)
            done = time.monotonic_ns()
            late = t_send * 1e-9 - target
            r = k & (_TIMING_RING - 1)
            self._late_us[r] = late * 1e6
            self._send_us[r] = (done - t_send) * 1e-3
            if late > period:
                self.late_ticks += 1
            if late > self.late_max_s:
                self.late_max_s = late
            with self._lock:
                self.ticks_sent += 1
                self.last_sent = tick
                if self.history is not None:
                    self.history.append(tick)
            k += 1
            late = time.monotonic() - (start + k * period)
            if late > 0.1:
                self.overruns += 1
                start = time.monotonic() - k * period

    def timing(self) -> dict[str, Any]:
        """How the ticks went out: ``late_p50_us``/``late_p99_us``/``late_max_us`` (send start
        after the due time), ``late_ticks`` (more than one period late), ``send_p50_us``/
        ``send_p99_us`` (time spent sending one tick), ``overruns``; percentiles over the
        last 65536 ticks."""
        n = min(self.ticks_sent, _TIMING_RING)
        out: dict[str, Any] = {"overruns": self.overruns, "late_ticks": self.late_ticks,
                               "late_max_us": round(self.late_max_s * 1e6, 1)}
        if n:
            late, send = self._late_us[:n], self._send_us[:n]
            out.update(late_p50_us=round(float(np.percentile(late, 50)), 1),
                       late_p99_us=round(float(np.percentile(late, 99)), 1),
                       send_p50_us=round(float(np.percentile(send, 50)), 1),
                       send_p99_us=round(float(np.percentile(send, 99)), 1))
        return out

    def wait(self, timeout: Optional[float] = None) -> bool:
        """Wait for a controller started with ``ticks`` to finish; True when it has."""
        th = self._thread
        if th is None:
            return True
        th.join(timeout)
        return not th.is_alive()

    def stop(self) -> None:
        """Stop ticking and close the transport (idempotent)."""
        self._stop.set()
        th = self._thread
        if th is not None and th is not threading.current_thread():
            th.join(2.0)
        self._thread = None
        self._close()

    def sent(self) -> list[TickInput]:
        """A copy of :attr:`history` (empty without history)."""
        with self._lock:
            return list(self.history) if self.history is not None else []

    def __enter__(self) -> "SimulatedController":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()


class CanController(SimulatedController):
    """A simulated controller on a CAN bus: every tick, the frames of
    :func:`~cablesvc.sources.can.encode_tick` (data frames, then SYNC).

    ``bus_config``: ``{"interface", "channel", "bitrate"?, "fd"?, "bus_kwargs"?}`` (for example
    :func:`~cablesvc.netutil.loopback_bus_config`); ``fd``: a CAN FD bus and the
    FD layout (None: from ``bus_config`` — its ``fd`` or ``bus_kwargs.fd`` — or from the DBC);
    ``dbc``: DBC file (None: ``<robot>.dbc``, or ``<robot>-fd.dbc`` with ``fd``);
    ``precompute``: encode the frames of every recording row once at start (t, seq and the
    tick counters are added per tick), else encode each tick as it goes. Other keywords as
    :class:`SimulatedController`. :attr:`precompute_s`: how long the precomputation took.
    """

    def __init__(self, robot: Union[Robot, str, "os.PathLike[str]"], bus_config: dict[str, Any],
                 dbc: Optional[Union[str, "os.PathLike[str]"]] = None, *, fd: Optional[bool] = None,
                 precompute: bool = True, **kwargs: Any):
        super().__init__(robot, **kwargs)
        from cablesvc.sources.can import dbc_suffix, load_can_layout

        self.bus_config = dict(bus_config)
        if fd is None:
            fd = bool(self.bus_config.get("fd") or (self.bus_config.get("bus_kwargs") or {}).get("fd"))
        path = dbc if dbc is not None else find_robot_companion(self.robot, dbc_suffix(fd))
        self.layout = load_can_layout(path, self.robot.n_cables)
        if self.layout.fd:
            fd = True
        #: whether the bus is opened as a CAN FD bus (python-can ``Bus(fd=True)``)
        self.fd = bool(fd)
        if self.fd:
            self.bus_config["fd"] = True
        self.frames_sent = 0
        self._bus: Any = None
        self._rows: Optional[np.ndarray] = None
        self._row_ints: list[int] = []
        self.precompute_s = 0.0
        self.precompute_error: Optional[str] = None
        if precompute:
            t0 = time.perf_counter()
            rec = self.recording
            try:
                self._rows = self.layout.tick.encode_rows(rec.motor_length, rec.force, rec.position,
                                                          rec.orientation, rec.temperature)
                # each row as one little-endian integer: the per-tick stamp is then a few ORs
                raw, width = self._rows.tobytes(), self._rows.shape[1]
                self._row_ints = [int.from_bytes(raw[a:a + width], "little") for a in range(0, len(raw), width)]
            except ValueError as exc:  # a value the DBC cannot carry: report it tick by tick instead
                self.precompute_error = str(exc)
            self.precompute_s = time.perf_counter() - t0

    def _open(self) -> None:
        from cablesvc.sources.can import open_bus

        self._bus = open_bus(self.bus_config)

    def tick_bytes(self, k: int) -> bytes:
        """The bytes of all frames of the k-th tick, end to end (what :meth:`frames` splits)."""
        tc = self.layout.tick
        if self._rows is not None:
            return tc.stamp(self._row_ints[self.row_at(k)], self.start_seq + k, (self.start_seq + k) / self.rate)
        return tc.encode(self.tick_at(k)).tobytes()

    def frames(self, k: int) -> list[Any]:
        """The python-can messages sent for the k-th tick (data frames, then SYNC)."""
        return self.layout.tick.messages(self.tick_bytes(k))

    def _send(self, tick: TickInput, k: Optional[int] = None) -> None:
        tc = self.layout.tick
        if k is not None and self._rows is not None:
            buf = tc.stamp(self._row_ints[self.row_at(k)], tick.seq, tick.t)
        else:
            buf = tc.encode(tick).tobytes()
        for msg in tc.messages(buf):
            self._bus.send(msg)
            self.frames_sent += 1

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.shutdown()


class ModbusController(SimulatedController):
    """A simulated controller serving its ticks over Modbus TCP (a real pymodbus server).

    ``host``/``port``: where the server listens (127.0.0.1 by default: stays on this host);
    ``unit``: Modbus device id; ``register_map``: TOML file (None: ``<robot>.modbus.toml``).
    Every tick the registers of the map are updated in one step on the server's event loop,
    so a read sees one whole tick. :attr:`read_requests` / :attr:`write_requests` count the
    requests received by function code (reads: 0x03, 0x04; anything else is a write).
    :meth:`server_down` / :meth:`server_up` stop and restart only the server (the
    controller keeps ticking), to simulate a lost connection.
    """

    def __init__(self, robot: Union[Robot, str, "os.PathLike[str]"], host: str = "127.0.0.1", port: int = 5020,
                 register_map: Optional[Union[str, "os.PathLike[str]"]] = None, unit: int = 1, **kwargs: Any):
        super().__init__(robot, **kwargs)
        from cablesvc.sources.modbus_source import load_register_map

        self.host = host
        self.port = int(port)
        self.unit = int(unit)
        path = register_map if register_map is not None else find_robot_companion(self.robot, ".modbus.toml")
        self.register_map = load_register_map(path, self.robot.n_cables)
        self.read_requests = 0
        self.write_requests = 0
        self.function_codes: collections.Counter[int] = collections.Counter()
        self._loop: Optional[asyncio.AbstractEventLoop] = None
        self._loop_thread: Optional[threading.Thread] = None
        self._server: Any = None
        self._blocks = self.register_map.encode(self.tick_at(0))

    # the server's event loop runs in its own thread for the controller's whole life
    def _open(self) -> None:
        ready = threading.Event()

        def main() -> None:
            loop = asyncio.new_event_loop()
            self._loop = loop
            asyncio.set_event_loop(loop)
            loop.call_soon(ready.set)
            try:
                loop.run_forever()
            finally:
                loop.close()

        self._loop_thread = threading.Thread(target=main, name="cablesvc-sim-modbus-server", daemon=True)
        self._loop_thread.start()
        ready.wait(5.0)
        self.server_up()

    def _trace_pdu(self, sending: bool, pdu: Any) -> Any:
        if not sending:
            fc = int(pdu.function_code)
            self.function_codes[fc] += 1
            if fc in (3, 4):
                self.read_requests += 1
            else:
                self.write_requests += 1
        return pdu

    async def _start_server(self) -> None:
        from pymodbus.server import ModbusTcpServer
        from pymodbus.simulator import DataType, SimData, SimDevice

        simdata = [SimData(address=a, count=n, values=0, datatype=DataType.REGISTERS)
                   for a, n in self.register_map.read_plan]
        server = ModbusTcpServer(SimDevice(id=self.unit, simdata=simdata), address=(self.host, self.port),
                                 trace_pdu=self._trace_pdu)
        await self._write(server, self._blocks)
        await server.serve_forever(background=True)
        self._server = server

    async def _write(self, server: Any, blocks: list[tuple[int, list[int]]]) -> None:
        # no await in SimCore suspends, so the blocks change together between two requests
        for start, regs in blocks:
            await server.async_setValues(self.unit, 16, start, regs)

    async def _stop_server(self) -> None:
        server, self._server = self._server, None
        if server is not None:
            await server.shutdown()

    def _call(self, coro: Any, timeout: float = 5.0) -> Any:
        assert self._loop is not None
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout)

    def server_up(self) -> None:
        """(Re)start the Modbus server on host:port, holding the latest tick."""
        if self._server is None:
            self._call(self._start_server())

    def server_down(self) -> None:
        """Stop the server and drop its connections (the controller keeps ticking)."""
        if self._server is not None:
            self._call(self._stop_server())

    def _send(self, tick: TickInput, k: Optional[int] = None) -> None:
        blocks = self.register_map.encode(tick)
        self._blocks = blocks
        server, loop = self._server, self._loop
        if server is not None and loop is not None:
            loop.call_soon_threadsafe(lambda: loop.create_task(self._write(server, blocks)))

    def _close(self) -> None:
        loop = self._loop
        if loop is None:
            return
        try:
            self._call(self._stop_server())
        except Exception:  # noqa: BLE001 - closing anyway
            pass
        loop.call_soon_threadsafe(loop.stop)
        if self._loop_thread is not None:
            self._loop_thread.join(2.0)
        self._loop = None
        self._loop_thread = None


# --------------------------------------------------------------------------------------
# process entry point
# --------------------------------------------------------------------------------------


def run_controller_process(
    transport: str,
    *,
    robot: str = "ipanema3",
    rate: float = 1000.0,
    seconds: Optional[float] = 10.0,
    ticks: Optional[int] = None,
    scenario: str = "trajectory",
    seed: int = 0,
    duration: float = 60.0,
    host: str = "127.0.0.1",
    port: Optional[int] = None,
    bus_config: Optional[dict[str, Any]] = None,
    fd: Optional[bool] = None,
    dbc: Optional[str] = None,
    register_map: Optional[str] = None,
    record: Optional[str] = None,
    out: Any = None,
) -> dict[str, Any]:
    """Run one simulated controller in this process until ``seconds`` [s] pass or ``ticks``
    ticks are sent; returns (and prints to ``out`` as JSON lines) ``{"event": "ready"}``
    when ticking starts and a summary at the end. ``record``: write the ticks sent to this
    recording file (.mcap/.csv) at the end. ``bus_config`` (CAN): default
    :func:`~cablesvc.netutil.loopback_bus_config` on ``port`` (with ``fd``);
    ``fd``: CAN FD bus and layout (None: as ``bus_config`` says). The summary has
    ``ticks_sent``, ``send_errors``, ``overruns`` and :meth:`SimulatedController.timing`."""
    out = sys.stdout if out is None else out
    keep = (ticks if ticks is not None else int(rate * (seconds or 0)) + 16) if record else 0
    common = dict(scenario=scenario, rate=rate, seed=seed, duration=duration, history=keep)
    ctl: SimulatedController
    if transport == "can":
        from cablesvc.netutil import loopback_bus_config

        cfg = bus_config if bus_config is not None else loopback_bus_config(port, fd=bool(fd))
        ctl = CanController(robot, cfg, dbc=dbc, fd=fd, **common)
        where = {"bus_config": ctl.bus_config, "fd": ctl.fd, "frames_per_tick": ctl.layout.frames_per_tick,
                 "dbc": ctl.layout.path, "precompute_s": round(ctl.precompute_s, 3)}
    elif transport == "modbus":
        ctl = ModbusController(robot, host=host, port=port if port is not None else 5020,
                               register_map=register_map, **common)
        where = {"host": host, "port": ctl.port}
    else:
        raise ValueError(f"transport must be 'can' or 'modbus', got {transport!r}")
    ctl.start(ticks=ticks)
    print(json.dumps({"event": "ready", "transport": transport, "robot": ctl.robot.name, "rate": rate, **where}),
          file=out, flush=True)
    try:
        deadline = None if seconds is None else time.monotonic() + seconds
        while True:
            if ctl.wait(0.05):
                break
            if deadline is not None and time.monotonic() >= deadline:
                break
    except KeyboardInterrupt:
        pass
    finally:
        ctl.stop()
    summary: dict[str, Any] = {"event": "done", "ticks_sent": ctl.ticks_sent, "send_errors": ctl.send_errors,
                               "last_send_error": ctl.last_send_error, **ctl.timing()}
    if isinstance(ctl, ModbusController):
        summary.update(read_requests=ctl.read_requests, write_requests=ctl.write_requests)
    if record:
        from cablesvc.recording import write_recording

        sent = ctl.sent()
        rec = Recording.from_ticks(ctl.robot.name, [
            {"seq": tk.seq, "t": tk.t, "motor_length": tk.motor_length, "position": tk.position,
             "orientation": tk.orientation, "force": tk.force, "temperature": tk.temperature} for tk in sent
        ], metadata={"generator": "cablesvc.sources.simulated", "transport": transport},
            n_cables=ctl.robot.n_cables)
        write_recording(record, rec)
        summary["record"] = str(record)
    print(json.dumps(summary), file=out, flush=True)
    return summary


def main(argv: Optional[list[str]] = None) -> int:
    """``python -m cablesvc.sources.simulated``: see :func:`run_controller_process`."""
    ap = argparse.ArgumentParser(prog="python -m cablesvc.sources.simulated",
                                 description="Run a simulated robot controller (CAN or Modbus TCP) in this process.")
    ap.add_argument("--transport", choices=["can", "modbus"], required=True)
    ap.add_argument("--robot", default="ipanema3")
    ap.add_argument("--rate", type=float, default=1000.0, help="ticks per second [Hz]")
    ap.add_argument("--seconds", type=float, default=10.0, help="run time [s] (0: until interrupted)")
    ap.add_argument("--ticks", type=int, default=None, help="stop after this many ticks")
    ap.add_argument("--scenario", default="trajectory")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=60.0, help="length of the precomputed twin recording [s]")
    ap.add_argument("--host", default="127.0.0.1", help="Modbus: listen address")
    ap.add_argument("--port", type=int, default=None, help="Modbus TCP port, or UDP port of the loopback CAN bus")
    ap.add_argument("--loopback", action="store_true", help="CAN: loopback_bus_config() (the default)")
    ap.add_argument("--bus-config", default=None, help="CAN: JSON {interface, channel, bitrate, fd, bus_kwargs}")
    ap.add_argument("--fd", action="store_true", default=None,
                    help="CAN: a CAN FD bus and the FD layout (robots/<robot>-fd.dbc); default: as --bus-config says")
    ap.add_argument("--dbc", default=None)
    ap.add_argument("--register-map", default=None)
    ap.add_argument("--record", default=None, help="write the ticks sent to this .mcap/.csv file")
    a = ap.parse_args(argv)
    bus_config = json.loads(a.bus_config) if a.bus_config else None
    summary = run_controller_process(
        a.transport, robot=a.robot, rate=a.rate, seconds=a.seconds if a.seconds > 0 else None, ticks=a.ticks,
        scenario=a.scenario, seed=a.seed, duration=a.duration, host=a.host, port=a.port, bus_config=bus_config,
        fd=a.fd, dbc=a.dbc, register_map=a.register_map, record=a.record,
    )
    return 0 if summary["send_errors"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
