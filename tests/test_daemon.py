"""The live daemon: snapshots, and end to end with real sources, Zenoh and MCAP."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cablesvc.config import load_robot
from cablesvc.kernel import Predictor
from cablesvc.config.params import nominal_params
from cablesvc.service.snapshot import read_snapshot, write_snapshot


def _run_some_ticks(pred: Predictor, n: int, t0: float = 0.0):
    geom = pred.geom
    pos = np.zeros(3)
    quat = np.array([0, 0, 0, 1.0])
    L = pred.ik(pos[None], quat[None]).length[0].copy()
    outs = []
    for k in range(n):
        t = t0 + k * 1e-3
        ml = L - 4e-4 - 3e-4 * np.sin(2 * np.pi * 2.0 * t + np.arange(geom.n_cables))
        outs.append(pred.tick(t, ml, pos, quat).force.copy())
    return outs


def test_snapshot_round_trip_continues_the_hysteresis_exactly(tmp_path: Path):
    robot = load_robot("ipanema3")
    geom = robot.geometry()
    params = nominal_params(geom)
    a = Predictor(geom, params)
    _run_some_ticks(a, 700)
    path = tmp_path / "state" / "ipanema3.state.npz"
    alarm_state = {"drift": {"ewma": np.arange(8.0), "n": np.int64(5)}, "flag": np.bool_(True)}
    write_snapshot(path, {"robot": "ipanema3", "seq": 699}, a.state_dict(), alarm_state)
    meta, kernel, alarms = read_snapshot(path)
    assert meta["seq"] == 699
    np.testing.assert_array_equal(alarms["drift"]["ewma"], np.arange(8.0))
    assert int(alarms["drift"]["n"]) == 5 and bool(alarms["flag"])
    b = Predictor(geom, params)
    b.load_state_dict(kernel)
    fa = _run_some_ticks(a, 300, t0=0.7)
    fb = _run_some_ticks(b, 300, t0=0.7)
    np.testing.assert_array_equal(np.array(fa), np.array(fb))
    # a fresh kernel (no restore) would differ: the snapshot carries real memory
    c = Predictor(geom, params)
    fc = _run_some_ticks(c, 300, t0=0.7)
    assert np.max(np.abs(np.array(fc) - np.array(fa))) > 1e-3
    # no temporary files are left behind
    assert [p.name for p in path.parent.iterdir()] == [path.name]


def test_damaged_snapshot_is_reported_not_loaded(tmp_path: Path):
    path = tmp_path / "s.npz"
    path.write_bytes(b"PK\x03\x04 this is not a snapshot")
    with pytest.raises(ValueError, match="s.npz"):
        read_snapshot(path)


# ---- end to end: daemon subprocess, real sources, a separate subscriber process ----------

import json
import signal
import subprocess
import sys
import time

from cablesvc.recording import read_recording, write_recording
from cablesvc.simulate import simulate_recording
from cablesvc.netutil import free_tcp_port
from reference import assert_matches_offline, offline_forces


def _daemon(args: list[str], zport: int, tmp_path: Path, *, snapshot: Path | None = None) -> subprocess.Popen:
    snap = ["--snapshot", str(snapshot), "--snapshot-interval", "0.5"] if snapshot else ["--no-snapshot"]
    return subprocess.Popen([sys.executable, "-m", "cablesvc", "run", *args, "--no-view", *snap,
                             "--listen", f"tcp/127.0.0.1:{zport}", "--log-level", "INFO"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _subscriber(zport: int, count: int) -> subprocess.Popen:
    """`cablesvc listen --json` in its own process: the client side users run."""
    return subprocess.Popen([sys.executable, "-m", "cablesvc", "listen", "--robot", "ipanema3", "--connect",
                             f"tcp/127.0.0.1:{zport}", "--json", "--count", str(count)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _collect(sub: subprocess.Popen, timeout: float) -> list[dict]:
    out, err = sub.communicate(timeout=timeout)
    msgs = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    forces = [m["payload"] for m in msgs if m.get("kind") == "forces"]
    assert forces, f"subscriber got nothing; stderr:\n{err[-2000:]}"
    return forces


def _sigterm(proc: subprocess.Popen, timeout: float = 10.0) -> tuple[int, str]:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, err


def test_replay_daemon_publishes_what_the_offline_kernel_computes(tmp_path: Path):
    rec = simulate_recording("ipanema3", "trajectory", None, duration=4.0, rate=250.0, seed=3)
    path = tmp_path / "rec.mcap"
    write_recording(path, rec)
    zport = free_tcp_port()
    sub = _subscriber(zport, 300)
    time.sleep(0.5)
    d = _daemon(["--source", "replay", "--replay", str(path), "--speed", "1", "--record", str(tmp_path / "out.mcap"),
                 "--wait-subscriber", "20"],
                zport, tmp_path)
    forces = _collect(sub, 60)
    code, err = _sigterm(d)
    assert code == 0, err
    assert assert_matches_offline(forces, offline_forces(rec)) >= 250
    # the --record file holds the inputs it ran on and the forces it published
    out = read_recording(tmp_path / "out.mcap")
    np.testing.assert_array_equal(out.motor_length, rec.motor_length[: out.n_ticks])


def test_snapshot_at_sigterm_is_restored_and_the_hysteresis_continues(tmp_path: Path):
    rec = simulate_recording("ipanema3", "hold-sine", None, duration=4.0, rate=200.0, seed=5)
    half = rec.n_ticks // 2
    # one log file that grows (the state belongs to its source, the file): its first half,
    # then the second half where it continues
    first = second = tmp_path / "log.mcap"
    write_recording(first, rec.slice(0, half))
    snap = tmp_path / "state" / "ipanema3.state.npz"
    zport = free_tcp_port()
    d = _daemon(["--source", "replay", "--replay", str(first), "--speed", "0"], zport, tmp_path, snapshot=snap)
    _, err = d.communicate(timeout=60)                  # a replay at full speed ends by itself
    assert d.returncode == 0, err
    assert snap.exists()
    write_recording(second, rec.slice(half, None))
    sub = _subscriber(zport, 50)
    time.sleep(0.5)
    d2 = _daemon(["--source", "replay", "--replay", str(second), "--speed", "1", "--wait-subscriber", "20"], zport,
                 tmp_path, snapshot=snap)
    forces = _collect(sub, 60)
    code, err = _sigterm(d2)
    assert code == 0, err
    assert "restored" in err
    # forces after the restart equal one uninterrupted offline run over both halves
    assert assert_matches_offline(forces, offline_forces(rec)) >= 40


def test_modbus_controller_to_subscriber(tmp_path: Path):
    from cablesvc.sources.simulated import ModbusController

    mport, zport = free_tcp_port(), free_tcp_port()
    ctl = ModbusController("ipanema3", host="127.0.0.1", port=mport, rate=100.0, duration=4.0, history=5000)
    ctl.start()
    try:
        sub = _subscriber(zport, 150)
        time.sleep(0.5)
        d = _daemon(["--source", "modbus", "--port", str(mport), "--poll-rate", "400",
                     "--record", str(tmp_path / "out.mcap")], zport, tmp_path)
        forces = _collect(sub, 60)
        code, err = _sigterm(d)
    finally:
        ctl.stop()
    assert code == 0, err
    assert ctl.write_requests == 0                      # the daemon never writes to the controller
    out = read_recording(tmp_path / "out.mcap")         # what the daemon received...
    sent = {tk.seq: tk for tk in ctl.sent()}
    for k in range(out.n_ticks):                        # ...is what the controller sent
        np.testing.assert_allclose(out.motor_length[k], sent[int(out.seq[k])].motor_length, rtol=0,
                                   atol=0.5e-7 + 1e-12)   # register resolution 0.1 um
    assert assert_matches_offline(forces, offline_forces(out)) >= 100


def test_can_controller_in_another_process_to_subscriber(tmp_path: Path):
    from cablesvc.bench.e2e import write_daemon_config
    from cablesvc.netutil import free_udp_port, loopback_bus_config

    bus = loopback_bus_config(free_udp_port())
    zport = free_tcp_port()
    cfg = tmp_path / "daemon.toml"
    write_daemon_config(cfg, "ipanema3", f"tcp/127.0.0.1:{zport}",
                        {"kind": "can", "interface": bus["interface"], "channel": bus["channel"],
                         "deadline_s": 0.05, "bus_kwargs": bus["bus_kwargs"]})
    sub = _subscriber(zport, 200)
    d = subprocess.Popen([sys.executable, "-m", "cablesvc", "run", "--config", str(cfg), "--no-view", "--no-snapshot",
                          "--record", str(tmp_path / "out.mcap")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    time.sleep(3.0)
    ctl = subprocess.run([sys.executable, "-m", "cablesvc.sources.simulated", "--transport", "can", "--rate", "200",
                          "--seconds", "3", "--duration", "4", "--bus-config", json.dumps(bus),
                          "--record", str(tmp_path / "sent.mcap")], capture_output=True, text=True, timeout=120)
    assert ctl.returncode == 0, ctl.stderr
    forces = _collect(sub, 60)
    code, err = _sigterm(d)
    assert code == 0, err
    out = read_recording(tmp_path / "out.mcap")
    sent = read_recording(tmp_path / "sent.mcap")
    idx = {int(s): k for k, s in enumerate(sent.seq)}
    for k in range(out.n_ticks):                        # received = sent, within the DBC resolution (10 nm)
        np.testing.assert_allclose(out.motor_length[k], sent.motor_length[idx[int(out.seq[k])]], rtol=0, atol=1e-8)
    assert assert_matches_offline(forces, offline_forces(out)) >= 150


def test_bad_ticks_in_a_replay_are_rejected_counted_alarmed_and_the_rest_published(tmp_path: Path):
    """A CSV with a NaN length, a tick going back in time and a duplicate seq: each is
    rejected with its reason, counted in status, raises input_fault; every good tick still
    produces exactly one forces message."""
    rec = simulate_recording("ipanema3", "hold-sine", None, duration=1.0, rate=200.0, seed=2)
    good = tmp_path / "good.csv"
    write_recording(good, rec)
    lines = good.read_text().splitlines()
    hdr = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    cols = lines[hdr].split(",")
    rows = lines[hdr + 1:]
    ml = cols.index(next(c for c in cols if c.startswith("motor_length") or c.startswith("l0") or c == "l1"))
    bad_rows = list(rows)
    r = bad_rows[50].split(",")
    r[ml] = "nan"
    bad_rows[50] = ",".join(r)                          # NaN motor length
    bad_rows.insert(101, bad_rows[99])                  # time going backwards + duplicate seq
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines[: hdr + 1] + bad_rows) + "\n")
    zport = free_tcp_port()
    from cablesvc.service.zenoh_io import Listener, make_config
    got, alarms = [], []
    lst = Listener("ipanema3", make_config(listen=(f"tcp/127.0.0.1:{zport}",)),
                   on_forces=lambda p, ns: got.append(p["seq"]), on_alarm=lambda p, ns: alarms.append(p))
    try:
        d = _daemon(["--source", "replay", "--replay", str(bad), "--speed", "1", "--wait-subscriber", "20",
                     "--connect", f"tcp/127.0.0.1:{zport}", "--listen", f"tcp/127.0.0.1:{free_tcp_port()}"],
                    free_tcp_port(), tmp_path)
        _, err = d.communicate(timeout=60)
        time.sleep(0.5)
    finally:
        lst.close()
    assert d.returncode == 0, err
    line = next(x for x in err.splitlines() if "stopped in" in x)
    counters = json.loads(line.split("; input ")[1].split("; latency")[0])
    assert sum(counters["rejected"].values()) == 2, counters
    assert counters["accepted"] == rec.n_ticks - 1
    assert sorted(got) == sorted(set(got)) and len(got) == rec.n_ticks - 1   # one message per accepted tick
    assert 50 not in got
    assert any(a["code"] == "input_fault" and a["action"] == "raise" for a in alarms), alarms
    assert "input rejected" in err


def test_kill_9_then_restart_resumes_from_the_last_snapshot(tmp_path: Path):
    """kill -9 mid-run: the --record file is readable up to its last flushed chunk, the
    snapshot on disk is whole, and a restart from it follows the uninterrupted run far more
    closely than a cold start does (the force transient after the restart)."""
    rec = simulate_recording("ipanema3", "hold-sine", None, duration=8.0, rate=200.0, seed=11)
    full = tmp_path / "full.mcap"
    write_recording(full, rec)
    snap = tmp_path / "state" / "ipanema3.state.npz"
    zport = free_tcp_port()
    d = _daemon(["--source", "replay", "--replay", str(full), "--speed", "1", "--record", str(tmp_path / "out.mcap")],
                zport, tmp_path, snapshot=snap)
    try:
        seq = -1
        end = time.monotonic() + 60
        while time.monotonic() < end and seq < 500:       # 2.5 s of the recording snapshotted
            time.sleep(0.05)
            if snap.exists():
                try:
                    seq = read_snapshot(snap)[0]["seq"] or -1
                except ValueError:
                    pass                                   # never a torn file: see the assert below
        assert seq >= 500, "no snapshot reached seq 500"
    finally:
        d.send_signal(signal.SIGKILL)
        d.communicate(timeout=10)
    meta, kernel, _ = read_snapshot(snap)                  # whole and readable after kill -9
    s = int(meta["seq"])
    from cablesvc.recording import RecordingTruncatedWarning
    with pytest.warns(RecordingTruncatedWarning):           # no footer: the writer was killed
        partial = read_recording(tmp_path / "out.mcap")   # read up to the last flushed chunk
    assert partial.truncation is not None and partial.n_ticks > 0
    np.testing.assert_array_equal(partial.motor_length, rec.motor_length[: partial.n_ticks])
    # the log goes on in the same file (the state belongs to its source) from the tick after
    # the snapshot (a jump of more than one tick's move would be a cold start, by design:
    # test_restart_clean.py)
    k0 = s + 1
    rest = full
    write_recording(rest, rec.slice(k0, None))
    sub = _subscriber(zport, 100)
    time.sleep(0.5)
    d2 = _daemon(["--source", "replay", "--replay", str(rest), "--speed", "1", "--wait-subscriber", "20"], zport,
                 tmp_path, snapshot=snap)
    forces = _collect(sub, 60)
    code, err = _sigterm(d2)
    assert code == 0, err
    assert "restored" in err and "not restor" not in err, err
    uninterrupted = offline_forces(rec)
    cold = offline_forces(rec.slice(k0, None))
    got = {m["seq"]: np.array(m["force"]) for m in forces}
    seqs = sorted(got)[:100]
    dev_restart = max(np.max(np.abs(got[q] - uninterrupted[q])) for q in seqs)
    dev_cold = max(np.max(np.abs(cold[q] - uninterrupted[q])) for q in seqs)
    print(f"restart after kill -9: max |f - uninterrupted| {dev_restart:.4f} N over {len(seqs)} ticks; "
          f"cold start {dev_cold:.4f} N")
    assert dev_restart < 0.25 * dev_cold


def test_subscriber_restart_while_the_daemon_runs(tmp_path: Path):
    """A client that goes away and comes back gets the forces again; the daemon never notices."""
    rec = simulate_recording("ipanema3", "hold-sine", None, duration=8.0, rate=200.0, seed=4)
    path = tmp_path / "rec.mcap"
    write_recording(path, rec)
    zport = free_tcp_port()
    sub = _subscriber(zport, 40)
    d = _daemon(["--source", "replay", "--replay", str(path), "--speed", "1", "--wait-subscriber", "20"],
                zport, tmp_path)
    first = _collect(sub, 60)                      # the first client takes 40 messages and exits
    sub2 = _subscriber(zport, 40)                  # a new client process
    second = _collect(sub2, 60)
    code, err = _sigterm(d)
    assert code == 0, err
    assert min(m["seq"] for m in second) > max(m["seq"] for m in first)
    offline = offline_forces(rec)
    assert assert_matches_offline(first + second, offline) == 80


def test_pipeline_baseline_passes_every_tick_through_with_the_daemons_message_shape():
    """``bench e2e``'s pipeline baseline: controller process -> pass-through daemon (CAN
    source, no kernel) -> Zenoh -> this process. Every tick sent arrives once, stamped by
    the source before it was received here, in a message that follows the forces schema."""
    from cablesvc.bench.e2e import run_three_processes
    from cablesvc.service.messages import FORCES_SCHEMA, check_schema

    got: list[tuple[dict, int]] = []
    run = run_three_processes(200.0, 2.0, lambda payload, ns: got.append((payload, ns)), passthrough=True)
    sent = int(run["summary"]["ticks_sent"])
    seqs = [p["seq"] for p, _ in got]
    assert sent >= 300
    assert len(seqs) == len(set(seqs)) == sent
    assert all(ns > p["stamp_ns"] for p, ns in got)
    assert check_schema(got[-1][0], FORCES_SCHEMA) == []
    assert run["status"]["input"]["accepted"] == sent
    assert run["status"]["published"] == sent


def test_recording_has_every_alarm_raise_before_its_clear_and_status_survives_close(tmp_path: Path):
    """A replay whose controller pauses 0.3 s: input_stale is raised by the daemon's watch
    (outside a tick) and cleared by the next tick. The --record MCAP must hold both, raise
    first, and status() after close() still says what the publisher put and skipped."""
    import json
    import threading

    from mcap.reader import make_reader

    from cablesvc.recording import write_recording
    from cablesvc.service.daemon import Daemon, DaemonOptions
    from cablesvc.simulate import simulate_recording
    from cablesvc.netutil import free_tcp_port

    rec = simulate_recording("planar4", "trajectory", None, duration=1.0, rate=100.0, seed=1)
    rec.t[50:] += 0.3
    write_recording(tmp_path / "gap.mcap", rec)
    robot = load_robot("planar4")
    d = Daemon(DaemonOptions(robot=robot, params=nominal_params(robot.geometry()),
                             source={"kind": "replay", "path": str(tmp_path / "gap.mcap"), "speed": 1},
                             record=tmp_path / "out.mcap", listen=(f"tcp/127.0.0.1:{free_tcp_port()}",)))
    try:
        d.run(threading.Event())
        before = d.status()
    finally:
        d.close()
    after = d.status()
    assert before["ticks"] == after["ticks"] == 100
    # no subscriber: nothing was put, every tick was skipped, before and after close
    assert (before["published"], before["skipped_no_subscriber"]) == (0, 100)
    assert (after["published"], after["skipped_no_subscriber"]) == (0, 100)
    with open(tmp_path / "out.mcap", "rb") as f:
        alarms = [json.loads(m.data) for _s, _c, m in make_reader(f).iter_messages(topics=["/cablesvc/alarms"])]
    events = [(a["action"], a["code"], a.get("cable")) for a in alarms]
    assert ("raise", "input_stale", None) in events and ("clear", "input_stale", None) in events
    state: dict = {}
    for action, code, cable in events:
        if action == "clear":
            assert state.get((code, cable)) == "raise", f"clear of {code} without a raise before it: {events}"
        state[(code, cable)] = action
