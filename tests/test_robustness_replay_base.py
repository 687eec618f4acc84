"""Robustness of the replay source and of the checks every source shares (reviewer's bugs).

* a recording whose clock jumps to a huge finite value: recv never raises, never waits
  for it, the far tick is rejected as ``time_jump`` naming it and the replay goes on;
  a real jump (the ticks after it follow on) is played, reported as an event;
* a frozen controller repeating its last tick exactly never triggers a ``resync``;
  a real restart still does;
* a queue overflow keeps ``accepted`` = ticks delivered and accepted + rejected = ticks
  received.

Real components only: recordings written with ``cablesvc.recording``, real sources (the
replay source, the CAN source on python-can's in-process virtual bus).
"""

from __future__ import annotations

import time

import can
import numpy as np
import pytest

from cablesvc.recording import Recording, write_recording
from cablesvc.sources import TickInput, TickValidator, encode_tick, open_source


def _write(path, t, seq) -> None:
    n = len(t)
    rec = Recording(robot="ipanema3", metadata={}, t=np.asarray(t, dtype=np.float64),
                    seq=np.asarray(seq), motor_length=np.full((n, 8), 2.0))
    write_recording(path, rec)


def _play(src, timeout, calls=50) -> list[TickInput]:
    """recv until the replay is finished (at most ``calls`` calls: a replay that stalls fails)."""
    out = []
    for _ in range(calls):
        if src.finished:
            break
        tick = src.recv(timeout=timeout)
        if tick is not None:
            out.append(tick)
    return out


def _balanced(src) -> bool:
    c = src.counters
    return src.ticks_read == c.accepted + sum(v for k, v in c.rejected.items() if k != "recording_error")


# --------------------------------------------------------------------------------------
# replay: a clock value too far ahead to wait for
# --------------------------------------------------------------------------------------


# (MCAP log times stop at ~1.8e10 s; recv(None) only where the old code raised, not hung)
_FAR = [(suffix, big, speed, timeout)
        for suffix, big in [("csv", 1e300), ("csv", 1e290), ("csv", 1e12), ("mcap", 1e9)]
        for speed, timeout in [(1.0, 0.2), (1.0, 1e300), (0.0, 0.2)]]
_FAR += [("csv", 1e300, 1.0, None), ("csv", 1e290, 1.0, None)]


@pytest.mark.parametrize("suffix,big,speed,timeout", _FAR)
def test_a_far_clock_value_is_rejected_and_the_replay_goes_on(tmp_path, robot, suffix, big, speed, timeout):
    t = np.arange(6) * 1e-3
    t[2] = big                                     # one corrupted, finite clock value
    path = tmp_path / f"bigt.{suffix}"
    _write(path, t, np.arange(6))
    with open_source(robot, {"kind": "replay", "path": str(path), "speed": speed}) as src:
        ticks = _play(src, timeout)                # raised OverflowError / stalled before the fix
        problems = src.problems()
        counts = src.counters.as_dict()
        assert src.finished and _balanced(src)
    assert [k.seq for k in ticks] == [0, 1, 3, 4, 5]        # no data lost but the bad tick
    assert counts["rejected"] == {"time_jump": 1} and counts["accepted"] == 5
    assert "resync" not in counts["events"]
    (p,) = problems
    assert p.reason == "time_jump" and p.kind == "rejected"
    assert "tick seq 2" in p.message and repr(big) in p.message and str(path) in p.message


def test_a_real_jump_in_the_recording_is_played_at_once_and_reported(tmp_path, robot):
    """The ticks after the jump follow on from it: nothing is lost, pacing restarts there."""
    path = tmp_path / "jump.csv"
    _write(path, [0.0, 0.001, 0.002, 1000.0, 1000.001, 1000.002], np.arange(6))
    with open_source(robot, {"kind": "replay", "path": str(path), "speed": 1.0, "max_gap_s": 1.0}) as src:
        ticks = _play(src, 2.0, calls=20)          # before: tick 3 waited 1000 s, recv returned None
        problems = src.problems()
        counts = src.counters.as_dict()
    assert [k.seq for k in ticks] == list(range(6))
    assert counts["accepted"] == 6 and counts["rejected"] == {} and counts["events"] == {"time_jump": 1}
    assert [(p.reason, p.kind) for p in problems] == [("time_jump", "event")]
    assert "tick seq 3" in problems[0].message and "max_gap_s 1" in problems[0].message
    # real-time pacing still holds after the jump: tick 5 is 2 ms of recording after tick 3
    assert ticks[5].stamp_ns - ticks[3].stamp_ns >= 1_500_000


def test_a_gap_below_max_gap_s_is_still_waited_for(tmp_path, robot):
    path = tmp_path / "gap.csv"
    _write(path, [0.0, 30.0], [0, 1])
    with open_source(robot, {"kind": "replay", "path": str(path), "speed": 1.0}) as src:
        assert src.recv(timeout=5.0).seq == 0
        assert src.recv(timeout=0.05) is None and not src.finished
        assert src.problems() == [] and src.counters.events == {}


# --------------------------------------------------------------------------------------
# validator: a frozen controller
# --------------------------------------------------------------------------------------


def _good(seq: int, t: float) -> TickInput:
    return TickInput(seq=seq, t=t, motor_length=np.full(8, 2.0), position=None, orientation=None,
                     force=None, temperature=None, stamp_ns=0)


@pytest.mark.parametrize("seq_bits", [None, 24])
def test_exact_repeats_of_a_frozen_controller_never_resync(robot, seq_bits):
    v = TickValidator(robot, seq_bits=seq_bits, resync_after=100)
    assert v.check(_good(7, 0.007)) is None
    reasons = []
    for _ in range(300):
        rej = v.check(_good(7, 0.007))
        reasons.append(None if rej is None else rej.reason)
    assert reasons == ["duplicate_seq"] * 300       # before: every 101st was accepted
    assert v.counters.accepted == 1 and "resync" not in v.counters.events
    nxt = _good(8, 0.008)
    assert v.check(nxt) is None and nxt.seq == 8 and v.resync_note is None
    # a real restart (seq and t back, then increasing) still resyncs, even with repeats between
    v = TickValidator(robot, seq_bits=seq_bits, resync_after=3)
    assert v.check(_good(500, 0.5)) is None
    for k in range(3):
        assert v.check(_good(500, 0.5)).reason == "duplicate_seq"
        assert v.check(_good(k, 0.001 * k)).reason == "seq_backwards"
    restart = _good(3, 0.003)
    assert v.check(restart) is None and v.resync_note and restart.seq == 501
    assert v.counters.events["resync"] == 1


def test_a_frozen_controller_in_a_replay_delivers_its_tick_once(tmp_path, robot):
    seq = [0, 1, 2] + [2] * 300 + [3, 4]
    path = tmp_path / "frozen.mcap"
    _write(path, np.asarray(seq) * 1e-3, seq)
    with open_source(robot, {"kind": "replay", "path": str(path), "speed": 0}) as src:
        ticks = _play_all(src)
        counts = src.counters.as_dict()
        assert _balanced(src)
    assert [k.seq for k in ticks] == [0, 1, 2, 3, 4]         # before: a made-up seq 3 for the 101st repeat
    assert counts["rejected"] == {"duplicate_seq": 300} and counts["events"] == {}


def _play_all(src) -> list[TickInput]:
    out = []
    for _ in range(10_000):
        if src.finished:
            break
        tick = src.recv(timeout=5.0)
        if tick is not None:
            out.append(tick)
    return out


# --------------------------------------------------------------------------------------
# threaded sources: queue overflow
# --------------------------------------------------------------------------------------


def _can_tick(seq: int) -> TickInput:
    return TickInput(seq=seq, t=seq * 1e-3, motor_length=np.full(8, 2.0), position=np.zeros(3),
                     orientation=np.array([0, 0, 0, 1.0]), force=np.full(8, 10.0), temperature=20.0, stamp_ns=0)


def test_queue_overflow_keeps_accepted_equal_to_delivered(robot):
    n = 5000
    channel = f"overflow-{time.monotonic_ns()}"
    src = open_source(robot, {"kind": "can", "interface": "virtual", "channel": channel, "fd": True,
                              "deadline_s": 0.5})
    tx = can.Bus(interface="virtual", channel=channel, fd=True)
    try:
        with src:
            size = src.queue_size
            for s in range(n):                     # nobody reads while they arrive
                for m in encode_tick(src.layout, _can_tick(s)):
                    tx.send(m)
            deadline = time.monotonic() + 120.0
            while src.counters.rejected["queue_overflow"] < n - size and time.monotonic() < deadline:
                time.sleep(0.05)
            got = []
            while (tick := src.recv(timeout=0.5)) is not None:
                got.append(tick.seq)
            counts = src.counters.as_dict()
            problems = src.problems()
    finally:
        tx.shutdown()
    assert counts["rejected"] == {"queue_overflow": n - size}, counts
    assert counts["accepted"] == len(got) == size            # before: accepted 5000
    assert counts["accepted"] + sum(counts["rejected"].values()) == n
    assert got == list(range(n - size, n))                     # the newest kept, in order
    assert sum(p.reason == "queue_overflow" for p in problems) == n - size
    assert "tick seq 0 dropped" in problems[0].message
