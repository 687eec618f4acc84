"""Alarms: drift detector (step, ramp, an hour of noise, hysteresis, NaN, batch == tick by
tick), state alarms, input watch, the manager with a real kernel, snapshots and config."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from cablesvc.alarms import (
    ALARM_CODES,
    AlarmConfig,
    AlarmEvent,
    AlarmManager,
    DriftConfig,
    DriftDetector,
    InputWatch,
    StateAlarmConfig,
    StateAlarms,
    load_alarm_config,
)
from cablesvc.config import load_robot
from cablesvc.config.params import default_params
from cablesvc.kernel import Predictor
from cablesvc.kinematics import inverse_kinematics
from cablesvc.recording import ALARM_JSON_SCHEMA
from cablesvc.service.snapshot import read_snapshot, write_snapshot
from cablesvc.service.messages import ALARM_SCHEMA, check_schema

RATE = 1000.0
NOISE = 0.1
Q0 = np.array([0.0, 0.0, 0.0, 1.0])


def residuals(rng, n, m, k0=0, bias=None, offset=None):
    """(t, R): n ticks at 1 kHz from tick k0; R = bias + N(0, 0.1) + offset(t)."""
    t = (k0 + np.arange(n)) / RATE
    R = rng.standard_normal((n, m)) * NOISE
    if bias is not None:
        R += bias
    if offset is not None:
        R += offset(t)
    return t, R


def raises(events, cable=None):
    return [e for e in events if e.action == "raise" and (cable is None or e.cable == cable)]


# ---- drift: the acceptance cases -----------------------------------------------------------

def test_step_of_0p4_n_raises_within_15_s_with_the_right_offset():
    rng = np.random.default_rng(1)
    m = 4
    det = DriftDetector(m)                                   # the tuned defaults
    bias = np.array([0.4, -0.3, 0.1, 0.0])                   # a good model's nonzero mean residual
    signs = np.array([1.0, -1.0, 1.0, -1.0])
    t_step = 90.0
    t, R = residuals(rng, 120_000, m, bias=bias,
                     offset=lambda t: np.where(t[:, None] >= t_step, 0.4 * signs, 0.0))
    events = det.update_batch(t, R, seq=0)
    np.testing.assert_allclose(det.baseline, bias, atol=0.01)
    assert all(e.t >= t_step for e in events)               # nothing before the step
    for i in range(m):
        (ev,) = raises(events, i)
        delay = ev.t - t_step
        assert 5.0 < delay < 15.0
        assert ev.code == "drift" and ev.severity == "warning" and ev.seq == round(ev.t * RATE)
        assert abs(ev.since - t_step) < 1.0                  # change point estimate
        assert ev.offset_n * signs[i] == pytest.approx(0.4, abs=0.05)
        assert "re-identify" in ev.suggested_action
        assert check_schema(ev.payload(), ALARM_SCHEMA) == []
        assert check_schema(ev.payload(), ALARM_JSON_SCHEMA) == []


def test_ramp_of_0p4_n_per_hour_raises_at_about_0p22_n():
    rng = np.random.default_rng(2)
    m = 2
    det = DriftDetector(m)
    t0 = 70.0
    slope = 0.4 / 3600.0
    events = []
    for k0 in range(0, 2_400_000, 300_000):
        t, R = residuals(rng, 300_000, m, k0=k0, bias=np.array([0.2, -0.1]),
                         offset=lambda t: np.maximum(t[:, None] - t0, 0.0) * slope * np.array([1.0, -1.0]))
        events += det.update_batch(t, R, seq=k0)
    assert len(events) == 2 and {e.cable for e in events} == {0, 1}
    for e in events:
        delay = e.t - t0
        assert 1800.0 < delay < 2300.0                        # about 33 min (docs/messages.md)
        true = delay * slope
        assert abs(e.offset_n) == pytest.approx(true, abs=0.03)
        assert np.sign(e.offset_n) == (1 if e.cable == 0 else -1)


def test_an_hour_of_noise_raises_nothing():
    rng = np.random.default_rng(3)
    m = 4
    det = DriftDetector(m)
    bias = rng.uniform(-0.5, 0.5, m)
    events = []
    chunk = 600_000
    for k0 in range(0, 3_600_000, chunk):
        t, R = residuals(rng, chunk, m, k0=k0, bias=bias)
        events += det.update_batch(t, R, seq=k0)
    assert events == []
    assert det.ready.all() and not det.active.any()
    assert np.all(np.abs(det.offset) < 0.01)
    assert float(det.describe_state()["t_last"][0]) == pytest.approx(3599.999)


# ---- drift: behaviour ----------------------------------------------------------------------

def test_clear_needs_the_offset_below_clear_n_for_the_hold_time():
    rng = np.random.default_rng(4)
    cfg = DriftConfig(warmup_s=10.0)
    det = DriftDetector(1, cfg)

    def offset(t):
        o = np.where(t >= 20.0, 0.4, 0.0)
        o = np.where(t >= 60.0, 0.15, o)      # between clear_n (0.1) and k (0.2): stays raised
        o = np.where(t >= 200.0, 0.0, o)      # gone: clears after the EWMA decays + hold
        return o[:, None]
    t, R = residuals(rng, 300_000, 1, offset=offset)
    events = det.update_batch(t, R, seq=0)
    assert [e.action for e in events] == ["raise", "clear"]
    raise_ev, clear_ev = events
    assert 20.0 < raise_ev.t < 35.0
    # EWMA (tau 10 s) from 0.15 to 0.1 takes ~4 s, then 10 s hold; from 0.15 never below 0.1
    assert 200.0 + cfg.clear_hold_s < clear_ev.t < 200.0 + 30.0
    assert clear_ev.since == raise_ev.since and abs(clear_ev.offset_n) < cfg.clear_n
    assert not det.active[0] and det.cusum.max() < cfg.cusum_h_ns


def test_short_burst_does_not_raise_but_sustained_large_offset_does_quickly():
    rng = np.random.default_rng(5)
    det = DriftDetector(2, DriftConfig(warmup_s=10.0))
    # cable 0: 5 N for 0.5 s (a knock); cable 1: 5 N sustained
    t, R = residuals(rng, 40_000, 2, offset=lambda t: np.stack(
        [np.where((t >= 20.0) & (t < 20.5), 5.0, 0.0), np.where(t >= 20.0, 5.0, 0.0)], axis=1))
    events = det.update_batch(t, R, seq=0)
    assert raises(events, 0) == []
    (ev,) = raises(events, 1)
    assert ev.t - 20.0 < 4.0                          # h / (clip - k) + hold = 3.5 s
    assert ev.offset_n == pytest.approx(5.0, abs=0.1)


def test_nan_residuals_are_skipped():
    rng = np.random.default_rng(6)
    m = 3
    det = DriftDetector(m, DriftConfig(warmup_s=5.0))
    t, R = residuals(rng, 60_000, m, offset=lambda t: np.where(t[:, None] >= 20.0, 0.4, 0.0))
    R[:, 1] = np.nan                                   # cable 1 has no sensor
    R[::3, 2] = np.nan                                 # cable 2 misses a third of its samples
    events = det.update_batch(t[:40_000], R[:40_000], seq=0)
    assert {e.cable for e in raises(events)} == {0, 2}
    assert not det.ready[1] and np.isnan(det.baseline[1])
    before = det.state_dict()["state"]
    assert det.update(40.0, 40_000, np.full(m, np.nan)) == []
    np.testing.assert_array_equal(det.state_dict()["state"], before)   # a NaN tick changes nothing
    # a gap of measurements is weighted at most max_dt_s, not the length of the gap
    det2 = DriftDetector(1, DriftConfig(warmup_s=0.0, baseline_n=0.0))
    det2.update(0.0, 0, np.array([0.0]))
    det2.update(100.0, 1, np.array([1.0]))
    assert det2.cusum[0, 0] == pytest.approx((1.0 - 0.2) * 0.1)


def test_update_batch_is_exactly_update_tick_by_tick():
    rng = np.random.default_rng(7)
    m = 3
    cfg = DriftConfig(warmup_s=2.0, ewma_tau_s=2.0, cusum_h_ns=0.5, raise_hold_s=0.2, clear_hold_s=1.0)
    n = 40_000

    def offset(t):
        o = 0.5 * (np.sin(2 * np.pi * t / 14.0) > 0)[:, None] * np.array([1.0, -1.0, 0.8])
        return np.where(t[:, None] > 5.0, o, 0.0)
    t, R = residuals(rng, n, m, bias=np.array([0.1, 0.2, -0.3]), offset=offset)
    R[rng.random((n, m)) < 0.05] = np.nan
    t[20_000:20_010] = t[19_990]                        # time standing still
    a = DriftDetector(m, cfg)
    ev_a = []
    for k in range(n):
        ev_a += a.update(float(t[k]), k, R[k])
    b = DriftDetector(m, cfg)
    b._Eb = np.zeros((2 * m, b._Eb.shape[1]))          # tiny event buffer: the block is split
    ev_b = []
    cuts = [0, 1, 777, 5000, 5001, 23_456, n]
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        ev_b += b.update_batch(t[lo:hi], R[lo:hi], seq=lo)
    assert len(ev_a) > 10 and {e.action for e in ev_a} == {"raise", "clear"}
    assert ev_a == ev_b                                  # same events, fields bit-identical
    np.testing.assert_array_equal(a.state_dict()["state"], b.state_dict()["state"])


def test_baseline_preset_reset_and_state_round_trip():
    rng = np.random.default_rng(8)
    det = DriftDetector(2, DriftConfig(baseline_n=[0.5, -0.5]))
    assert det.ready.all()
    np.testing.assert_array_equal(det.baseline, [0.5, -0.5])
    t, R = residuals(rng, 30_000, 2, bias=np.array([0.9, -0.5]))
    ev = det.update_batch(t, R, seq=0)
    assert [e.cable for e in raises(ev)] == [0]          # +0.4 N against the preset baseline
    clone = DriftDetector(2, DriftConfig(baseline_n=[0.5, -0.5]))
    clone.load_state_dict(det.state_dict())
    t2, R2 = residuals(rng, 5000, 2, k0=30_000, bias=np.array([0.5, -0.5]))
    assert det.update_batch(t2, R2) == clone.update_batch(t2, R2)
    det.reset([0])
    assert not det.ready[0] and det.ready[1] and not det.active[0]
    with pytest.raises(ValueError, match="2 values"):
        det.update(1.0, 1, np.zeros(3))


# ---- state alarms ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def planar():
    geom = load_robot("planar4").geometry()
    L = inverse_kinematics(geom, np.zeros((1, 3)), Q0[None]).length[0]
    return geom, default_params(geom.ea, L, "amplitude")


def tick_output(m, force, slack=None, wres=None, amp=None):
    """A TickOutput-shaped record (only the fields StateAlarms reads)."""
    return SimpleNamespace(
        force=np.asarray(force, float), slack=np.zeros(m, bool) if slack is None else np.asarray(slack, bool),
        wrench_residual=np.zeros(6) if wres is None else np.asarray(wres, float),
        amplitude=np.full(m, 5e-4) if amp is None else np.asarray(amp, float))


def run_ticks(alarms, t0, t1, make, dt=0.01):
    out = []
    for k, t in enumerate(np.arange(t0, t1, dt)):
        out += alarms.update(float(t), k, make(t))
    return out


def test_slack_and_over_limit_raise_and_clear_with_hold_and_margin(planar):
    geom, params = planar
    m = geom.n_cables
    fmin, fmax = float(geom.force_min[0]), float(geom.force_max[0])
    sa = StateAlarms(geom, params)
    normal = [50.0] * m
    assert run_ticks(sa, 0.0, 1.0, lambda t: tick_output(m, normal)) == []
    # cable 0 goes slack, cable 3 over its limit
    f_bad = [0.5 * fmin, 50.0, 50.0, fmax + 5.0]
    ev = run_ticks(sa, 1.0, 2.0, lambda t: tick_output(m, f_bad, slack=[True, False, False, False]))
    assert [(e.action, e.code, e.cable) for e in ev] == [("raise", "over_limit", 3), ("raise", "slack", 0)]
    over, slack = ev
    assert over.t == pytest.approx(1.0) and over.severity == "error" and over.limit == fmax
    assert slack.t == pytest.approx(1.05, abs=0.011) and slack.since == pytest.approx(1.0)
    # just above force_min (inside the margin) and just under force_max (inside the margin): no clear
    f_mid = [fmin + 0.5, 50.0, 50.0, fmax - 0.5]
    assert run_ticks(sa, 2.0, 4.0, lambda t: tick_output(m, f_mid)) == []
    ev = run_ticks(sa, 4.0, 5.0, lambda t: tick_output(m, normal))
    assert sorted((e.action, e.code, e.cable) for e in ev) == [("clear", "over_limit", 3), ("clear", "slack", 0)]
    assert all(e.t == pytest.approx(4.5, abs=0.011) for e in ev)
    for e in ev:
        assert check_schema(e.payload("planar4"), ALARM_SCHEMA) == []


def test_amplitude_range_and_wrench_residual(planar):
    geom, params = planar
    m = geom.n_cables
    lo, hi = params.amplitude_range()
    weight = geom.mass * 9.81
    sa = StateAlarms(geom, params, StateAlarmConfig(slack=False, over_limit=False))
    f = [50.0] * m
    amps = np.array([5e-4, 1.2 * hi, 0.5 * lo, 1.05 * hi])   # cable 3 within the tolerance: no alarm
    ev = run_ticks(sa, 0.0, 2.0, lambda t: tick_output(m, f, amp=amps, wres=[0.3 * weight, 0, 0, 0, 0, 5.0]))
    got = sorted((e.code, e.cable) for e in ev)
    assert got == [("amplitude_range", 1), ("amplitude_range", 2), ("wrench_residual", None)]
    amp_ev = {e.cable: e for e in ev if e.code == "amplitude_range"}
    assert amp_ev[1].limit == hi and amp_ev[2].limit == lo and amp_ev[1].severity == "info"
    assert all(e.t == pytest.approx(1.0, abs=0.011) for e in amp_ev.values())       # 1 s hold
    wr = next(e for e in ev if e.code == "wrench_residual")
    assert wr.value == pytest.approx(0.3 * weight) and wr.t == pytest.approx(0.2, abs=0.011)
    # planar robot: fz is not part of the residual, so a huge fz changes nothing
    ev = run_ticks(sa, 2.0, 4.0, lambda t: tick_output(m, f, amp=np.full(m, 5e-4), wres=[0.1 * weight, 0, 1e4, 0, 0, 0]))
    assert sorted((e.action, e.code, e.cable) for e in ev) == [
        ("clear", "amplitude_range", 1), ("clear", "amplitude_range", 2), ("clear", "wrench_residual", None)]
    # models without an amplitude estimate (NaN) never raise it
    assert run_ticks(sa, 4.0, 6.0, lambda t: tick_output(m, f, amp=np.full(m, np.nan))) == []


def test_input_watch_stale_lost_and_recovery():
    w = InputWatch(stale_s=0.05, lost_s=1.0)
    w.start(100.0)
    assert w.poll(100.5) == []
    (lost0,) = w.poll(101.2)                              # nothing ever arrived: lost only
    assert lost0.code == "input_lost" and lost0.severity == "error" and lost0.seq is None
    ev = w.tick(3.0, 7, 101.3)
    assert [(e.action, e.code) for e in ev] == [("clear", "input_lost")]
    assert w.poll(101.33) == []
    (stale,) = w.poll(101.36)
    assert stale.code == "input_stale" and stale.since == 3.0 and stale.t == pytest.approx(3.06)
    assert w.poll(101.8) == []                            # raised once
    (lost,) = w.poll(102.31)
    assert lost.code == "input_lost" and lost.seq == 7 and lost.value == pytest.approx(1.01)
    assert w.poll(103.0) == []
    ev = w.tick(5.0, 8, 103.1)
    assert [(e.action, e.code) for e in ev] == [("clear", "input_stale"), ("clear", "input_lost")]
    assert w.active() == [] and w.poll(103.12) == []
    for e in ev + [stale, lost]:
        assert check_schema(e.payload(), ALARM_SCHEMA) == []


# ---- the manager with a real kernel --------------------------------------------------------

def test_manager_with_kernel_drift_active_set_counters_and_snapshot(planar, tmp_path):
    geom, params = planar
    m = geom.n_cables
    rate = 100.0                                          # 100 Hz keeps the kernel part short
    cfg = AlarmConfig(drift=DriftConfig(warmup_s=10.0))
    pos = np.array([0.05, -0.02, 0.0])
    L = inverse_kinematics(geom, pos[None], Q0[None]).length[0]
    ml = L - 2e-3                                           # every cable about 40 N
    probe = Predictor(geom, params)
    f_pred = probe.tick(0.0, ml, pos, Q0).force.copy()
    assert np.all(f_pred > geom.force_min) and np.all(f_pred < geom.force_max)
    rng = np.random.default_rng(9)
    bias = np.array([0.3, -0.2, 0.0, 0.1])

    def feed(mgr, pred, k0, k1, step_at=25.0):
        events = []
        for k in range(k0, k1):
            t = k / rate
            meas = f_pred + bias + rng.standard_normal(m) * NOISE + (0.6 if t >= step_at else 0.0) * (np.arange(m) == 2)
            out = pred.tick(t, ml, pos, Q0, meas)
            events += mgr.on_tick(t, k, out)
        return events
    mgr = AlarmManager(geom, params, cfg)
    pred = Predictor(geom, params)
    events = feed(mgr, pred, 0, 4000)
    drift = [e for e in events if e.code == "drift"]
    assert [(e.action, e.cable) for e in drift] == [("raise", 2)]
    assert 25.0 < drift[0].t < 35.0 and drift[0].offset_n == pytest.approx(0.6, abs=0.1)
    active = {(e.code, e.cable) for e in mgr.active()}
    assert ("drift", 2) in active
    assert mgr.counters["drift"] == 1
    # snapshot through the daemon's own write and read (np.savez), restore into a fresh manager
    path = tmp_path / "state.npz"
    write_snapshot(path, {}, {}, mgr.state_dict())
    loaded = read_snapshot(path)[2]
    mgr2 = AlarmManager(geom, params, cfg)
    mgr2.load_state_dict(loaded)
    assert {(e.code, e.cable) for e in mgr2.active()} == active and mgr2.counters == mgr.counters
    np.testing.assert_array_equal(mgr2.drift.state_dict()["state"], mgr.drift.state_dict()["state"])
    # after the restore the drift alarm clears like the original would: the offset goes away
    pred2 = Predictor(geom, params)
    ev2 = feed(mgr2, pred2, 4000, 8000, step_at=1e9)
    assert [(e.action, e.code, e.cable) for e in ev2 if e.code == "drift"] == [("clear", "drift", 2)]
    assert ("drift", 2) not in {(e.code, e.cable) for e in mgr2.active()}
    # idle: input watch through the manager
    now = time.monotonic()                                 # the manager stamps ticks with this clock
    assert [e.code for e in mgr2.on_idle(now + 1.5)] == ["input_stale", "input_lost"]
    assert {"input_stale", "input_lost"} <= {e.code for e in mgr2.active()}


def test_alarm_config_from_toml(tmp_path):
    p = tmp_path / "service.toml"
    p.write_text("[alarms.drift]\nwarmup_s = 30.0\ncusum_h_ns = 3\n[alarms.input]\nlost_s = 2.5\n"
                 "[alarms.state]\nslack = false\n")
    cfg = load_alarm_config(p)
    assert cfg.drift.warmup_s == 30.0 and cfg.drift.cusum_h_ns == 3.0 and cfg.drift.cusum_k_n == 0.2
    assert cfg.input.lost_s == 2.5 and cfg.state.slack is False
    assert AlarmConfig.from_toml("") == AlarmConfig()
    p.write_text("[alarms.drift]\ncusum_k_n = 2.0\n")       # k above clip: cannot detect anything
    with pytest.raises(ValueError, match="clip_n"):
        load_alarm_config(p)
    p.write_text("[alarms.drift]\nwarmup = 3\n")
    with pytest.raises(ValueError, match="warmup"):
        load_alarm_config(p)


def test_event_payload_round_trip_and_codes():
    ev = AlarmEvent("raise", "drift", 3, "warning", 12.5, float("nan"), None, "x", offset_n=float("inf"))
    p = ev.payload("r")
    assert p["since"] is None and p["offset_n"] is None and p["robot"] == "r"
    json.dumps(p, allow_nan=False)
    back = AlarmEvent.from_payload(ev.payload())
    assert back.code == "drift" and back.cable == 3 and back.t == 12.5
    assert set(ALARM_CODES) == {"drift", "spread", "slack", "over_limit", "wrench_residual", "input_stale", "input_lost", "input_fault",
                                "amplitude_range", "params_refused"}
    assert replace(ev, action="clear").key == ev.key
