"""Alarm robustness: restored alarms whose detector is now disabled, and hold/warm-up timers
after the controller clock restarts (t jumps back, or an older snapshot is restored).

Real :class:`Predictor` and :class:`AlarmManager` objects at 100 Hz; the assertions are on
which events happen within generous windows, not on exact timings."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest

from cablesvc.alarms import AlarmConfig, AlarmManager, DriftConfig, StateAlarmConfig
from cablesvc.config import load_robot
from cablesvc.config.params import default_params
from cablesvc.kernel import Predictor
from cablesvc.kinematics import inverse_kinematics
from cablesvc.service.snapshot import read_snapshot, write_snapshot

RATE = 100.0
Q0 = np.array([0.0, 0.0, 0.0, 1.0])
POS = np.array([0.05, -0.02, 0.0])


@pytest.fixture(scope="module")
def robot():
    geom = load_robot("planar4").geometry()
    L0 = inverse_kinematics(geom, np.zeros((1, 3)), Q0[None]).length[0]
    params = default_params(geom.ea, L0, "amplitude")
    L = inverse_kinematics(geom, POS[None], Q0[None]).length[0]
    taut = L - 2e-3                       # every cable well tensioned
    slack = L + 2e-3                      # every cable slack
    f_taut = Predictor(geom, params).tick(0.0, taut, POS, Q0).force.copy()
    assert np.all(f_taut > geom.force_min + 5.0)
    return geom, params, taut, slack, f_taut


def feed(mgr, pred, t0, seconds, ml, meas=None, k0=0):
    """Ticks at RATE from controller time t0 for ``seconds``; returns the manager's events."""
    events = []
    for k in range(int(round(seconds * RATE))):
        t = t0 + k / RATE
        out = pred.tick(t, ml, POS, Q0, None if meas is None else meas(t))
        events += mgr.on_tick(t, k0 + k, out)
    return events


def keys(events, code, action=None):
    return sorted((e.action, e.cable) for e in events if e.code == code and (action is None or e.action == action))


def savez_round_trip(state: dict) -> dict:
    """What the daemon's snapshot does with the alarm state: its own write and read."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "state.npz"
        write_snapshot(path, {}, {}, state)
        return read_snapshot(path)[2]


def snapshot_codes(mgr) -> set:
    return {(p["code"], p["cable"]) for p in json.loads(str(np.asarray(mgr.state_dict()["active"])[()]))}


# ---- restored alarms whose detector is disabled now ------------------------------------------

def test_restored_slack_alarm_is_dropped_when_slack_is_disabled(robot):
    geom, params, taut, slack, _ = robot
    m = geom.n_cables
    mgr = AlarmManager(geom, params)
    ev = feed(mgr, Predictor(geom, params), 0.0, 1.0, slack)
    assert keys(ev, "slack") == [("raise", i) for i in range(m)]
    snap = savez_round_trip(mgr.state_dict())

    # same config: the slack alarms survive the restore (and so does their channel state)
    same = AlarmManager(geom, params)
    same.load_state_dict(snap)
    assert {("slack", i) for i in range(m)} <= {(e.code, e.cable) for e in same.active()}

    cfg = AlarmConfig(state=StateAlarmConfig(slack=False))
    mgr2 = AlarmManager(geom, params, cfg)
    mgr2.load_state_dict(snap)
    assert [e for e in mgr2.active() if e.code == "slack"] == []
    assert not any(code == "slack" for code, _ in snapshot_codes(mgr2))
    st = mgr2.state.state_dict()["state"]
    assert np.all(st[0, :m] == 0.0) and np.all(np.isnan(st[1:, :m]))      # slack channels inactive
    assert mgr2.counters == mgr.counters                                   # history kept
    # the restored run goes on: healthy then slack again; nothing about slack ever appears
    pred2 = Predictor(geom, params)
    ev2 = feed(mgr2, pred2, 10.0, 2.0, taut) + feed(mgr2, pred2, 12.0, 1.0, slack)
    assert keys(ev2, "slack") == []
    assert [e for e in mgr2.active() if e.code == "slack"] == []
    assert not any(code == "slack" for code, _ in snapshot_codes(mgr2))


def test_restored_drift_alarm_is_dropped_when_drift_is_disabled(robot):
    geom, params, taut, _, f_taut = robot
    cfg = AlarmConfig(drift=DriftConfig(warmup_s=1.0))
    mgr = AlarmManager(geom, params, cfg)
    step = lambda t: f_taut + (1.0 if t >= 2.0 else 0.0) * (np.arange(geom.n_cables) == 2)   # noqa: E731
    ev = feed(mgr, Predictor(geom, params), 0.0, 10.0, taut, meas=step)
    assert keys(ev, "drift") == [("raise", 2)]
    snap = savez_round_trip(mgr.state_dict())

    mgr2 = AlarmManager(geom, params, AlarmConfig(drift=DriftConfig(warmup_s=1.0, enabled=False)))
    mgr2.load_state_dict(snap)
    assert [e for e in mgr2.active() if e.code == "drift"] == []
    assert ("drift", 2) not in snapshot_codes(mgr2)
    assert not mgr2.drift.active.any()
    np.testing.assert_array_equal(mgr2.drift.baseline, mgr.drift.baseline)   # baseline kept
    ev2 = feed(mgr2, Predictor(geom, params), 20.0, 2.0, taut, meas=lambda t: f_taut)
    assert keys(ev2, "drift") == [] and ("drift", 2) not in snapshot_codes(mgr2)


# ---- hold timers after the controller clock restarts -----------------------------------------

def test_pending_slack_raise_restarts_when_the_clock_goes_back(robot):
    geom, params, taut, slack, _ = robot
    m = geom.n_cables
    mgr = AlarmManager(geom, params)
    pred = Predictor(geom, params)
    assert keys(feed(mgr, pred, 0.0, 2.0, taut), "slack") == []
    # slack starts at t = 3600 s, for less than the 0.05 s raise hold
    assert keys(feed(mgr, pred, 3600.0, 0.03, slack), "slack") == []
    # the controller restarts: t from 0 again, the cables stay slack for 2 s (40 x the hold)
    ev = feed(mgr, pred, 0.0, 2.0, slack)
    raised = [e for e in ev if e.code == "slack" and e.action == "raise"]
    assert sorted(e.cable for e in raised) == list(range(m))
    assert all(0.0 <= e.since <= e.t < 1.0 for e in raised)              # on the new time base


def test_pending_slack_clear_restarts_after_restoring_an_older_snapshot(robot):
    geom, params, taut, slack, _ = robot
    m = geom.n_cables
    mgr = AlarmManager(geom, params)
    pred = Predictor(geom, params)
    assert keys(feed(mgr, pred, 3590.0, 1.0, slack), "slack") == [("raise", i) for i in range(m)]
    # tension is back at t = 3600 s for less than the 0.5 s clear hold, then a snapshot
    assert keys(feed(mgr, pred, 3600.0, 0.2, taut), "slack") == []
    snap = savez_round_trip(mgr.state_dict())
    # a restarted daemon with a restarted controller (t from 0) restores it; tension stays back
    mgr2 = AlarmManager(geom, params)
    mgr2.load_state_dict(snap)
    assert {("slack", i) for i in range(m)} <= {(e.code, e.cable) for e in mgr2.active()}
    ev = feed(mgr2, Predictor(geom, params), 0.0, 3.0, taut)
    assert keys(ev, "slack") == [("clear", i) for i in range(m)]
    assert all(e.t < 2.0 for e in ev if e.code == "slack")
    assert [e for e in mgr2.active() if e.code == "slack"] == []


def test_pending_drift_raise_and_clear_restart_when_the_clock_goes_back(robot):
    geom, params, taut, _, f_taut = robot
    cfg = AlarmConfig(drift=DriftConfig(warmup_s=1.0, raise_hold_s=1.0, ewma_tau_s=0.5, clear_hold_s=2.0))
    mgr = AlarmManager(geom, params, cfg)
    pred = Predictor(geom, params)
    off = lambda t: f_taut + 1.0 * (np.arange(geom.n_cables) == 2)        # noqa: E731
    ok = lambda t: f_taut                                                    # noqa: E731
    assert keys(feed(mgr, pred, 3590.0, 2.0, taut, meas=ok), "drift") == []
    assert mgr.drift.ready.all()
    # a 1 N offset from t = 3600 s: the CUSUM passes h after about 2.5 s, the 1 s hold is pending
    assert keys(feed(mgr, pred, 3600.0, 3.0, taut, meas=off), "drift") == []
    # clock restart; the offset stays: the raise comes on the new time base
    ev = feed(mgr, pred, 0.0, 5.0, taut, meas=off)
    assert keys(ev, "drift") == [("raise", 2)]
    # the offset goes away at t = 10 s; |EWMA| < clear_n after about 1.2 s; restart again
    # while the 2 s clear hold is pending
    assert keys(feed(mgr, pred, 10.0, 2.5, taut, meas=ok), "drift") == []
    ev = feed(mgr, pred, 0.0, 6.0, taut, meas=ok)
    assert keys(ev, "drift") == [("clear", 2)]
    assert not mgr.drift.active.any()


def test_drift_warmup_finishes_when_the_clock_goes_back(robot):
    geom, params, taut, _, f_taut = robot
    mgr = AlarmManager(geom, params, AlarmConfig(drift=DriftConfig(warmup_s=5.0)))
    pred = Predictor(geom, params)
    feed(mgr, pred, 3600.0, 2.0, taut, meas=lambda t: f_taut)
    assert not mgr.drift.ready.any()
    feed(mgr, pred, 0.0, 8.0, taut, meas=lambda t: f_taut)          # clock restart, 8 s > warm-up
    assert mgr.drift.ready.all()
