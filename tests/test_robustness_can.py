"""Robustness of the CAN source against a failing adapter, a slow adapter and clock steps.

The failing / slow adapters are small real python-can buses (subclasses of python-can's
``virtual`` bus) registered as interfaces for the test; nothing of python-can is mocked.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import can
import can.util
import numpy as np
import pytest
from can.interfaces.virtual import VirtualBus

from cablesvc.simulate import simulate_recording
from cablesvc.sources import TickAssembler, TickInput, encode_tick, load_can_layout, open_source

REPO = Path(__file__).resolve().parents[1]
DBCS = (REPO / "robots" / "ipanema3.dbc", REPO / "robots" / "ipanema3-fd.dbc")


class FlakyBus(VirtualBus):
    """Opens fine; while ``failing`` every receive fails (adapter bus-off, link down)."""

    opens = 0
    failing = True

    def __init__(self, *a, **kw):
        type(self).opens += 1
        super().__init__(*a, **kw)

    def _recv_internal(self, timeout):
        if type(self).failing:
            raise can.CanOperationError("bus-off / ENETDOWN")
        return super()._recv_internal(timeout)


class SlowBus(VirtualBus):
    """The first open fails (adapter unplugged); later opens take 3 s (USB enumerating)."""

    opens = 0
    instances: list = []

    def __init__(self, *a, **kw):
        type(self).opens += 1
        if type(self).opens == 1:
            raise can.CanInitializationError("no such device")
        time.sleep(3.0)
        super().__init__(*a, **kw)
        self.closed = False
        type(self).instances.append(self)

    def shutdown(self):
        self.closed = True
        super().shutdown()


@pytest.fixture()
def adapters(monkeypatch):
    """Register FlakyBus and SlowBus as python-can interfaces for one test."""
    import can.interfaces

    monkeypatch.setitem(can.interfaces.BACKENDS, "cablesvc_test_flaky", (__name__, "FlakyBus"))
    monkeypatch.setitem(can.interfaces.BACKENDS, "cablesvc_test_slow", (__name__, "SlowBus"))
    monkeypatch.setattr(can.util, "VALID_INTERFACES",
                        frozenset(can.util.VALID_INTERFACES) | {"cablesvc_test_flaky", "cablesvc_test_slow"})
    FlakyBus.opens, FlakyBus.failing = 0, True
    SlowBus.opens, SlowBus.instances = 0, []
    yield


def _channel() -> str:
    return f"cablesvc-robust-{time.monotonic_ns()}"


def test_bus_that_fails_every_receive_backs_off_and_reports_one_outage(robot, adapters):
    ch = _channel()
    src = open_source(robot, {"kind": "can", "interface": "cablesvc_test_flaky", "channel": ch})
    src.open()
    try:
        time.sleep(1.5)
        # backoff 0.05 s doubling: a handful of reopens, not thousands
        assert FlakyBus.opens <= 25, FlakyBus.opens
        assert src.counters.events == {"disconnected": 1}, dict(src.counters.events)
        assert src.counters.problems_dropped == 0
        probs = src.problems()
        assert [p.reason for p in probs] == ["disconnected"] and "bus-off" in probs[0].message
        # the adapter recovers: one reconnected closes the outage, ticks flow again
        FlakyBus.failing = False
        rec = simulate_recording(robot, "trajectory", None, duration=0.2, rate=500.0, seed=5)
        layout = load_can_layout(DBCS[0], robot.n_cables)
        tx = can.Bus(interface="virtual", channel=ch)
        got = []
        try:
            end = time.monotonic() + 10
            k = 0
            while not got and time.monotonic() < end:
                row = dict(seq=int(rec.seq[k]), t=float(rec.t[k]), motor_length=rec.motor_length[k],
                           force=rec.force[k], position=rec.position[k], orientation=rec.orientation[k],
                           temperature=float(rec.temperature[k]))
                for m in encode_tick(layout, row):
                    tx.send(m)
                k = (k + 1) % rec.n_ticks
                tick = src.recv(timeout=0.05)
                if tick is not None:
                    got.append(tick)
        finally:
            tx.shutdown()
        assert got, (src.counters.as_dict(), src.problems())
        assert src.counters.events["disconnected"] == 1 and src.counters.events["reconnected"] == 1
    finally:
        t = time.monotonic()
        src.close()
        assert time.monotonic() - t < 1.5


def test_close_does_not_wait_for_a_slow_bus_open(robot, adapters):
    src = open_source(robot, {"kind": "can", "interface": "cablesvc_test_slow", "channel": _channel()})
    src.open()                      # the first open fails: the receive thread retries (3 s)
    time.sleep(0.4)
    assert SlowBus.opens == 2       # inside the slow open now
    t = time.monotonic()
    src.close()
    took = time.monotonic() - t
    assert took < 1.2, f"close() took {took:.2f} s"
    # the bus that finished opening after close() is shut down, not leaked
    end = time.monotonic() + 8
    while not SlowBus.instances and time.monotonic() < end:
        time.sleep(0.05)
    assert len(SlowBus.instances) == 1
    while not SlowBus.instances[0].closed and time.monotonic() < end:
        time.sleep(0.05)
    assert SlowBus.instances[0].closed
    assert not [th for th in threading.enumerate() if th.name.startswith("cablesvc-can-") and th.is_alive()
                and th.name.endswith(str(src.config.channel))]
    assert src.counters.events == {"disconnected": 1}


def _ticks(n: int):
    q = np.array([0.0, 0.0, 0.0, 1.0])
    return [TickInput(seq=s, t=s * 1e-3, motor_length=np.full(8, 2.0), position=np.zeros(3), orientation=q,
                      force=np.full(8, 10.0), temperature=20.0, stamp_ns=0) for s in range(n)]


@pytest.mark.parametrize("dbc", DBCS, ids=lambda p: p.stem)
@pytest.mark.parametrize("split", [False, True], ids=["between_ticks", "inside_a_tick"])
def test_assembler_survives_the_wall_clock_stepping_back(dbc, split):
    """NTP steps the clock back 10 s mid-stream: every tick is still delivered, the step is
    one clock_step event, nothing is rejected."""
    lay = load_can_layout(dbc, 8)
    asm = TickAssembler(lay, deadline_s=0.005)
    wall = 1000.0
    out = []
    for tick in _ticks(400):
        msgs = encode_tick(lay, tick)
        for k, m in enumerate(msgs):
            if tick.seq == 200 and k == (len(msgs) - 1 if split else 0):
                wall -= 10.0
            m.timestamp = wall + k * 1e-5
            out += asm.feed(m, now_ns=0)
        wall += 1e-3
    delivered = [ev.seq for ev in out if isinstance(ev, TickInput)]
    others = [ev.reason for ev in out if not isinstance(ev, TickInput)]
    assert delivered == list(range(400))
    assert others == ["clock_step"]
    assert asm.pending == 0


def test_assembler_still_expires_ticks_after_a_clock_step():
    """After the re-base the deadline works as before on the new clock."""
    lay = load_can_layout(DBCS[0], 8)
    asm = TickAssembler(lay, deadline_s=0.005)
    t0, t1 = _ticks(2)
    for k, m in enumerate(encode_tick(lay, t0)):
        m.timestamp = 500.0 + k * 1e-5
        asm.feed(m)
    msgs = encode_tick(lay, t1)
    msgs[0].timestamp = 490.0       # clock stepped back 10 s
    assert [r.reason for r in asm.feed(msgs[0])] == ["clock_step"]
    assert asm.expire(bus_time=490.002) == []
    assert [r.reason for r in asm.expire(bus_time=490.010)] == ["missing_frames"]


def test_can_source_counts_a_clock_step_as_an_event_and_keeps_every_tick(robot):
    ch = _channel()
    layout = load_can_layout(DBCS[0], robot.n_cables)
    rec = simulate_recording(robot, "trajectory", None, duration=0.2, rate=500.0, seed=7)
    # the sender below is a Python loop sharing the GIL (5 ms switch interval) with the
    # source's reader thread: on a loaded machine it can stall longer than the default 5 ms
    # deadline between two frames of one tick, which is not what this test is about
    src = open_source(robot, {"kind": "can", "interface": "virtual", "channel": ch, "deadline_s": 0.1})
    tx = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    got = []
    with src:
        try:
            for k in range(rec.n_ticks):
                # receive times 10 s ahead, then the clock is stepped back to the right time
                wall = time.time() + (10.0 if k < rec.n_ticks // 2 else 0.0)
                row = dict(seq=int(rec.seq[k]), t=float(rec.t[k]), motor_length=rec.motor_length[k],
                           force=rec.force[k], position=rec.position[k], orientation=rec.orientation[k],
                           temperature=float(rec.temperature[k]))
                for j, m in enumerate(encode_tick(layout, row)):
                    m.timestamp = wall + j * 1e-5
                    tx.send(m)
                time.sleep(0.001)
            end = time.monotonic() + 10
            while len(got) < rec.n_ticks and time.monotonic() < end:
                tick = src.recv(timeout=0.2)
                if tick is not None:
                    got.append(tick.seq)
        finally:
            tx.shutdown()
    assert got == [int(s) for s in rec.seq], (src.counters.as_dict(), src.problems())
    assert not src.counters.rejected
    assert src.counters.events["clock_step"] == 1
