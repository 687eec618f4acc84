"""Issue 7 acceptance at the daemon level: "nothing lost" and "faults survived".

Real components only: the daemon is a ``cablesvc run`` subprocess, its outputs are read by a
real Zenoh :class:`Listener` on 127.0.0.1 (multicast scouting off), inputs come from real
MCAP files, a real python-can bus (udp_multicast, loopback only) and a real pymodbus server.

* Reconciliation: faults of every kind are injected at known places into a long run; every
  accepted tick is published exactly once, every rejected one is counted under its reason,
  and accepted + rejected = sent.
* Faults survived: the Modbus server going away and coming back on the same port, the Zenoh
  router the daemon and its clients meet at being killed and restarted, and a Zenoh endpoint
  that is not there at start-up.

Forces go out with congestion control DROP (the newest value matters) and the publisher
has no counter of what Zenoh dropped; these tests run at 250-500 ticks/s, where the
transmit queue never fills, so any missing seq is a real loss.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from cablesvc.recording import McapRecordingWriter, read_recording
from cablesvc.service.zenoh_io import Listener, make_config
from cablesvc.simulate import simulate_recording
from cablesvc.netutil import free_tcp_port
from reference import assert_matches_offline, offline_forces

ROBOT = "ipanema3"


# ---- helpers ----------------------------------------------------------------------------

def _daemon(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "cablesvc", "run", *args, "--no-view", "--no-snapshot",
                             "--log-level", "INFO"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _stop(proc: subprocess.Popen, timeout: float = 15.0) -> tuple[int, str]:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate(timeout=5)
    return proc.returncode, err


def _final_input(err: str) -> dict:
    """The input counters of the daemon's last log line (``status()["input"]`` at shutdown)."""
    line = next(x for x in err.splitlines() if "stopped in" in x)
    return json.loads(line.split("; input ")[1].split("; latency")[0])


class Collector:
    """A Listener that keeps every forces seq (and payload) and every alarm, thread-safely."""

    def __init__(self, cfg, keep_forces: bool = False):
        self.lock = threading.Lock()
        self.seqs: list[int] = []
        self.forces: list[dict] = []
        self.alarms: list[dict] = []
        self.keep = keep_forces
        self.listener = Listener(ROBOT, cfg, on_forces=self._f, on_alarm=self._a)

    def _f(self, p, ns):
        with self.lock:
            self.seqs.append(p["seq"])
            if self.keep:
                self.forces.append(p)

    def _a(self, p, ns):
        with self.lock:
            self.alarms.append(p)

    def count(self) -> int:
        with self.lock:
            return len(self.seqs)

    def wait_count(self, n: int, timeout: float) -> int:
        end = time.monotonic() + timeout
        while time.monotonic() < end and self.count() < n:
            time.sleep(0.05)
        return self.count()

    def wait_quiet(self, quiet_s: float = 1.0, timeout: float = 30.0) -> None:
        """Until no new forces arrived for ``quiet_s``."""
        end = time.monotonic() + timeout
        last, since = -1, time.monotonic()
        while time.monotonic() < end:
            n = self.count()
            if n != last:
                last, since = n, time.monotonic()
            elif time.monotonic() - since > quiet_s:
                return
            time.sleep(0.05)

    def status(self, within: float = 30.0) -> dict | None:
        """The daemon's status; a get with no queryable matching returns at once, so ask
        again until one answers or ``within`` [s] has passed."""
        end = time.monotonic() + within
        while True:
            st = self.listener.status(timeout=5.0)
            if st is not None or time.monotonic() > end:
                return st
            time.sleep(0.2)

    def close(self):
        self.listener.close()


def _client_cfg(zport: int, mode: str = "peer"):
    return make_config(mode=mode, listen=(), connect=(f"tcp/127.0.0.1:{zport}",))


# ---- 1. reconciliation: replay of an MCAP file with faults injected ----------------------

def _row(rec, k):
    return dict(seq=int(rec.seq[k]), t=float(rec.t[k]), motor_length=rec.motor_length[k].copy(),
                force=rec.force[k].copy(), position=rec.position[k].copy(),
                orientation=rec.orientation[k].copy(), temperature=float(rec.temperature[k]))


FAULTS = ("nan_length", "inf_force", "negative_length", "huge_length", "huge_force", "bad_quaternion",
          "time_backwards", "duplicate_seq", "seq_backwards")
REASON = {"nan_length": "nonfinite", "inf_force": "nonfinite", "negative_length": "out_of_range",
          "huge_length": "out_of_range", "huge_force": "out_of_range", "bad_quaternion": "bad_quaternion",
          "time_backwards": "time_backwards", "duplicate_seq": "duplicate_seq", "seq_backwards": "seq_backwards"}


def _faulty_stream(rec, every: int = 40, skip_every: int = 700):
    """The ticks of ``rec`` with a bad tick inserted before every ``every``-th good one
    (cycling through FAULTS) and, every ``skip_every`` ticks, a run of 1-3 good ticks left
    out (skipped seqs: accepted with a gap, counted in missed_ticks).
    Returns (rows in file order, accepted seqs, injected reasons Counter, missed ticks)."""
    rows, accepted, injected = [], [], Counter()
    missed = 0
    last = None                                  # the last good row written
    n_fault = 0
    k = 0
    while k < rec.n_ticks:
        if k > 0 and k % skip_every == 0 and k + 4 < rec.n_ticks:
            gap = 1 + (k // skip_every) % 3
            k += gap                             # these seqs never reach the daemon
            missed += gap
        good = _row(rec, k)
        if last is not None and k % every == 0:
            kind = FAULTS[n_fault % len(FAULTS)]
            n_fault += 1
            bad = _row(rec, k)
            j = n_fault % 8
            if kind == "nan_length":
                bad["motor_length"][j] = np.nan
            elif kind == "inf_force":
                bad["force"][j] = np.inf             # MCAP stores it as null: read back as NaN
            elif kind == "negative_length":
                bad["motor_length"][j] = -0.25
            elif kind == "huge_length":
                bad["motor_length"][j] = 1e4
            elif kind == "huge_force":
                bad["force"][j] = 1e9
            elif kind == "bad_quaternion":
                bad["orientation"] = bad["orientation"] * 1.5
            elif kind == "time_backwards":
                bad["t"] = last["t"] - 0.5 / 500.0   # new seq, clock went back
            elif kind == "duplicate_seq":
                bad = {**last}                        # the last tick again
            elif kind == "seq_backwards":
                bad["seq"] = last["seq"] - 5
            rows.append(bad)
            injected[REASON[kind]] += 1
        rows.append(good)
        accepted.append(good["seq"])
        last = good
        k += 1
    return rows, accepted, injected, missed


def test_replay_with_injected_faults_reconciles_every_seq(tmp_path: Path):
    rec = simulate_recording(ROBOT, "hold-sine", None, duration=6.0, rate=500.0, seed=7)    # 3000 ticks
    rows, accepted, injected, missed = _faulty_stream(rec, every=20)
    path = tmp_path / "faults.mcap"
    w = McapRecordingWriter(path, ROBOT)
    for r in rows:
        w.write_input(r["seq"], r["t"], r["motor_length"], r["force"], r["position"], r["orientation"],
                      r["temperature"])
    w.close()
    assert len(injected) == 6 and sum(injected.values()) > 100 and missed > 0
    sent = len(rows)

    zport = free_tcp_port()
    col = Collector(_client_cfg(zport), keep_forces=True)
    try:
        d = _daemon(["--source", "replay", "--replay", str(path), "--speed", "1", "--wait-subscriber", "30",
                     "--listen", f"tcp/127.0.0.1:{zport}", "--record", str(tmp_path / "out.mcap")])
        try:
            _, err = d.communicate(timeout=90)         # the replay ends by itself
        finally:
            if d.poll() is None:
                d.kill()
        col.wait_quiet(1.0)
    finally:
        col.close()
    assert d.returncode == 0, err[-3000:]

    # the daemon's counters: accepted + rejected = sent, rejected by reason = injected
    inp = _final_input(err)
    assert inp["source"] == "replay"
    assert inp["accepted"] == len(accepted), inp
    assert Counter(inp["rejected"]) == injected, (inp["rejected"], injected)
    assert inp["accepted"] + sum(inp["rejected"].values()) == sent
    assert inp["missed_ticks"] == missed
    assert inp["problems_dropped"] == 0

    # published: exactly the accepted seqs, each once, in order
    dup = [s for s, n in Counter(col.seqs).items() if n > 1]
    lost = sorted(set(accepted) - set(col.seqs))
    extra = sorted(set(col.seqs) - set(accepted))
    assert not dup and not lost and not extra, f"duplicates {dup[:10]}, lost {lost[:10]} ({len(lost)}), " \
                                               f"not accepted but published {extra[:10]}"
    assert col.seqs == accepted

    # the --record file holds the same ticks; the forces are the offline kernel's over them
    out = read_recording(tmp_path / "out.mcap")
    assert out.seq.tolist() == accepted
    assert_matches_offline(col.forces[::50], offline_forces(out))

    # bad input: a message naming the source, an input_fault alarm
    assert f"input rejected (nonfinite): replay {path}" in err
    raised = [a for a in col.alarms if a["code"] == "input_fault" and a["action"] == "raise"]
    assert raised and str(path) in raised[0]["message"], col.alarms[:5]


# ---- 3. Zenoh router restart ------------------------------------------------------------

ROUTER_SCRIPT = textwrap.dedent("""
    import sys, time, zenoh
    from cablesvc.service.zenoh_io import make_config
    s = zenoh.open(make_config(mode="router", listen=(sys.argv[1],)))
    print("ready", flush=True)
    while True:
        time.sleep(1)
""")


def _router(endpoint: str, tmp_path: Path) -> subprocess.Popen:
    script = tmp_path / "router.py"
    script.write_text(ROUTER_SCRIPT)
    p = subprocess.Popen([sys.executable, str(script), endpoint], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    line = p.stdout.readline()
    assert line.strip() == "ready", p.communicate(timeout=10)
    return p


def _kill(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.send_signal(signal.SIGKILL)
    p.communicate(timeout=10)


def test_zenoh_router_restart_the_daemon_and_its_client_carry_on(tmp_path: Path):
    """The daemon (peer) and a client meet at a router; the router is killed (-9) and started
    again on the same port: the daemon keeps running, the client gets forces again, and
    they are still the offline kernel's."""
    rec = simulate_recording(ROBOT, "hold-sine", None, duration=40.0, rate=250.0, seed=9)
    path = tmp_path / "rec.mcap"
    from cablesvc.recording import write_recording
    write_recording(path, rec)
    rport, dport = free_tcp_port(), free_tcp_port()
    rep = f"tcp/127.0.0.1:{rport}"
    router = _router(rep, tmp_path)
    d = col = None
    try:
        col = Collector(_client_cfg(rport, mode="client"), keep_forces=True)
        d = _daemon(["--source", "replay", "--replay", str(path), "--speed", "1", "--wait-subscriber", "30",
                     "--connect", rep, "--listen", f"tcp/127.0.0.1:{dport}"])
        assert col.wait_count(250, 40) >= 250, "no forces through the router"
        before = col.count()
        _kill(router)
        time.sleep(2.0)
        n_down = col.count()
        assert d.poll() is None, "the daemon died with the router"
        router = _router(rep, tmp_path)
        t_up = time.monotonic()
        got = col.wait_count(n_down + 250, 30)
        t_back = time.monotonic()
        assert got >= n_down + 250, f"no forces after the router restart ({got - n_down} in {t_back - t_up:.1f} s)"
        print(f"router restart: {before} forces before, {n_down - before} while down (in flight), "
              f"{got - n_down} after; back {t_back - t_up:.2f} s after the restart")
        st = col.status()
        assert st is not None and st["robot"] == ROBOT
        assert d.poll() is None
        with col.lock:
            forces = list(col.forces)
        seqs = [m["seq"] for m in forces]
        assert len(seqs) == len(set(seqs)) and seqs == sorted(seqs)    # no repeat, no reorder
        assert_matches_offline(forces, offline_forces(rec))
        assert st["skipped_no_subscriber"] > 0     # while the router was down nobody matched
    finally:
        if col is not None:
            col.close()
        if d is not None:
            code, err = _stop(d)
        _kill(router)
    assert code == 0, err[-3000:]


# ---- 4. a Zenoh endpoint that is not there at start-up -----------------------------------

def test_unreachable_zenoh_endpoint_at_start_up(tmp_path: Path):
    """As a peer (the default) the daemon starts although nothing listens at its --connect
    endpoint, runs, and connects when a router appears there later (Zenoh retries the
    connect endpoints with backoff, 1 s doubling to 4 s). As a client (a config file with
    mode "client") there is nothing to run without: it exits 1 with one clear line."""
    rec = simulate_recording(ROBOT, "hold-sine", None, duration=40.0, rate=250.0, seed=10)
    path = tmp_path / "rec.mcap"
    from cablesvc.recording import write_recording
    write_recording(path, rec)
    rport = free_tcp_port()
    rep = f"tcp/127.0.0.1:{rport}"
    log = tmp_path / "daemon.log"
    with open(log, "w") as logf:
        d = subprocess.Popen([sys.executable, "-m", "cablesvc", "run", "--source", "replay", "--replay", str(path),
                              "--speed", "1", "--connect", rep, "--listen", f"tcp/127.0.0.1:{free_tcp_port()}",
                              "--no-view", "--no-snapshot", "--log-level", "INFO"],
                             stdout=subprocess.DEVNULL, stderr=logf, text=True)
    router = col = None
    try:
        end = time.monotonic() + 40                     # started: the daemon logs its configuration
        while time.monotonic() < end and d.poll() is None and "cablesvc ipanema3: robot" not in log.read_text():
            time.sleep(0.1)
        assert d.poll() is None, log.read_text()[-3000:]
        assert "cablesvc ipanema3: robot" in log.read_text(), log.read_text()[-3000:]
        time.sleep(2.0)                                 # connect attempts fail meanwhile
        assert d.poll() is None, log.read_text()[-3000:]
        t_router = time.monotonic()
        router = _router(rep, tmp_path)
        col = Collector(_client_cfg(rport, mode="client"), keep_forces=True)
        assert col.wait_count(100, 30) >= 100, "the daemon never connected to the router that came up"
        st = col.status()
        assert st is not None
        assert st["uptime_s"] > time.monotonic() - t_router + 1.5     # it was running before the router
        with col.lock:
            forces = list(col.forces)
        assert_matches_offline(forces, offline_forces(rec))
    finally:
        if col is not None:
            col.close()
        code, _ = _stop(d)
        if router is not None:
            _kill(router)
    err = log.read_text()
    assert code == 0, err[-3000:]
    assert "Traceback" not in err

    cfg = tmp_path / "client.json5"
    cfg.write_text(json.dumps({"mode": "client", "connect": {"endpoints": [rep]},
                               "scouting": {"multicast": {"enabled": False}}}))
    t0 = time.monotonic()
    d = _daemon(["--source", "replay", "--replay", str(path), "--zenoh-config", str(cfg)])
    _, err = d.communicate(timeout=30)
    assert d.returncode == 1, err[-3000:]
    assert "cannot open the Zenoh session" in err and str(cfg) in err, err[-3000:]
    assert "Traceback" not in err
    assert time.monotonic() - t0 < 25


# ---- 2. Modbus server lost and back on the same port -------------------------------------

def test_modbus_server_down_and_back_the_daemon_reconnects(tmp_path: Path):
    """The Modbus server stops mid-run (connections dropped, port closed) and comes back on
    the same port 2.5 s later: the daemon stays up, reports disconnected / reconnected,
    raises input_lost during the outage and clears it after, rejects nothing, and the forces
    after the reconnection are the offline kernel's over what it received."""
    from cablesvc.sources.simulated import ModbusController

    mport, zport = free_tcp_port(), free_tcp_port()
    ctl = ModbusController(ROBOT, host="127.0.0.1", port=mport, rate=100.0, duration=4.0, history=10_000)
    ctl.start()
    col = d = None
    try:
        col = Collector(_client_cfg(zport), keep_forces=True)
        d = _daemon(["--source", "modbus", "--port", str(mport), "--poll-rate", "400",
                     "--listen", f"tcp/127.0.0.1:{zport}", "--record", str(tmp_path / "out.mcap")])
        assert col.wait_count(100, 40) >= 100, "no forces before the outage"
        ctl.server_down()
        time.sleep(2.5)
        n_down = col.count()
        with col.lock:
            last_before = col.seqs[-1]
        ctl.server_up()
        assert col.wait_count(n_down + 150, 30) >= n_down + 150, "no forces after the server came back"
        assert d.poll() is None
        st = col.status()
        assert st is not None
        inp = st["input"]
        print(f"modbus outage: input {json.dumps(inp)}")
        assert inp["events"].get("disconnected", 0) >= 1 and inp["events"].get("reconnected", 0) >= 1, inp
        assert inp["rejected"] == {}, inp                    # a lost link is an event, not bad input
        assert inp["missed_ticks"] >= 150                    # ~2.5 s at 100 Hz never seen
        reasons = [p["reason"] for p in st["recent_problems"]]
        assert "disconnected" in reasons and "reconnected" in reasons
        assert reasons.index("disconnected") < len(reasons) - 1 - reasons[::-1].index("reconnected")
        assert not any(a["code"] == "input_lost" for a in st["alarms_active"]), st["alarms_active"]
        assert st["publish_errors"] == 0
    finally:
        if col is not None:
            col.close()
        if d is not None:
            code, err = _stop(d)
        ctl.stop()
    assert code == 0, err[-3000:]
    assert "disconnected" in err and "reconnected" in err
    assert "Traceback" not in err
    # input_lost raised during the outage and cleared when ticks came back, in that order
    lost = [(a["action"], a.get("seq")) for a in col.alarms if a["code"] == "input_lost"]
    k = lost.index(("raise", last_before)) if ("raise", last_before) in lost else None
    assert k is not None, f"no input_lost raised after seq {last_before}: {lost}"
    assert lost[k + 1:k + 2] and lost[k + 1][0] == "clear" and lost[k + 1][1] > last_before, lost
    assert not any(a["code"] == "input_fault" for a in col.alarms)
    # what the daemon received is what the controller sent; forces after the reconnection
    # equal the offline kernel's over the received ticks (gap included)
    out = read_recording(tmp_path / "out.mcap")
    sent = {tk.seq: tk for tk in ctl.sent()}
    for k in range(out.n_ticks):
        np.testing.assert_allclose(out.motor_length[k], sent[int(out.seq[k])].motor_length, rtol=0,
                                   atol=0.5e-7 + 1e-12)
    after = [m for m in col.forces if m["seq"] > last_before]
    assert len(after) >= 150
    assert assert_matches_offline(after, offline_forces(out)) == len(after)
    assert set(out.seq.tolist()) >= {m["seq"] for m in col.forces}


# ---- 1b. reconciliation over a real CAN FD bus with frame-level faults ---------------------

CAN_FAULTS = ("missing_frame", "unknown_id", "wrong_dlc", "time_backwards", "duplicate_seq", "seq_backwards")


def test_can_bus_with_injected_faults_reconciles_every_seq(tmp_path: Path):
    """A sender in this process puts 3500 ticks (CAN FD, robots/ipanema3-fd.dbc: one data
    frame and a SYNC per tick) on a loopback udp_multicast bus at 500 ticks/s, with data
    frames left out, frames of unknown id, frames of the wrong length, a clock going back,
    repeated and backward seqs and skipped ticks. The daemon's status afterwards: rejected by
    reason = injected, accepted + rejected ticks = ticks sent; the subscriber got exactly the
    accepted seqs; input_fault was raised naming the bus and cleared once the faults stopped."""
    import can

    from cablesvc.bench.e2e import write_daemon_config
    from cablesvc.sources import encode_tick, load_can_layout
    from cablesvc.netutil import free_udp_port, loopback_bus_config
    from cablesvc.sources import open_bus

    REPO = Path(__file__).resolve().parents[1]
    layout = load_can_layout(REPO / "robots" / "ipanema3-fd.dbc", 8)
    assert layout.frames_per_tick == 2
    rate = 500.0
    rec = simulate_recording(ROBOT, "hold-sine", None, duration=7.0, rate=rate, seed=12)     # 3500 ticks
    plan: list[list] = []                 # per slot: the frames to send
    accepted: list[int] = []
    injected = Counter()
    ticks_sent = extra_frames = missed = 0
    last = None
    n_fault = 0
    for k in range(rec.n_ticks):
        row = _row(rec, k)
        if k > 0 and k % 600 == 0:        # skipped ticks: never sent
            missed += 1
            continue
        if last is not None and k % 12 == 0 and k < rec.n_ticks - 1500:   # the last 3 s are clean
            kind = CAN_FAULTS[n_fault % len(CAN_FAULTS)]
            n_fault += 1
            if kind == "missing_frame":       # this tick's data frame is lost: its SYNC comes alone
                plan.append(encode_tick(layout, row)[1:])
                ticks_sent += 1
                injected["missing_frames"] += 1
                last = row                       # not accepted; the next tick is 2 seqs on
                missed += 1
                continue
            if kind == "wrong_dlc":           # a 24-byte data frame where the DBC says 32
                msgs = encode_tick(layout, row)
                bad = can.Message(arbitration_id=msgs[0].arbitration_id, data=bytes(msgs[0].data[:24]),
                                  is_fd=True, is_extended_id=False)
                plan.append([bad, msgs[1]])
                ticks_sent += 1
                extra_frames += 1
                injected["bad_frame"] += 1       # the frame...
                injected["missing_frames"] += 1  # ...and its tick
                last = row
                missed += 1
                continue
            if kind == "unknown_id":
                plan.append([can.Message(arbitration_id=0x7AB, data=bytes(32), is_fd=True, is_extended_id=False)])
                extra_frames += 1
                injected["bad_frame"] += 1
            else:
                bad = dict(last)
                if kind == "time_backwards":
                    bad = {**row, "t": last["t"] - 0.5 / rate}
                elif kind == "seq_backwards":
                    bad = {**row, "seq": last["seq"] - 3}
                plan.append(encode_tick(layout, bad))
                ticks_sent += 1
                injected[kind] += 1
        plan.append(encode_tick(layout, row))
        ticks_sent += 1
        accepted.append(row["seq"])
        last = row
    assert len(injected) == 5 and sum(injected.values()) > 150

    bus_cfg = loopback_bus_config(free_udp_port(), fd=True)
    zport = free_tcp_port()
    cfg = tmp_path / "daemon.toml"
    write_daemon_config(cfg, ROBOT, f"tcp/127.0.0.1:{zport}",
                        {"kind": "can", "interface": bus_cfg["interface"], "channel": bus_cfg["channel"], "fd": True,
                         "deadline_s": 0.2, "bus_kwargs": bus_cfg["bus_kwargs"]})
    col = Collector(_client_cfg(zport))
    d = _daemon(["--config", str(cfg)])
    bus = open_bus(bus_cfg)
    try:
        if col.status(within=40) is None:
            pytest.fail(f"the daemon did not answer a status query; its log:\n{_stop(d)[1][-3000:]}")
        time.sleep(1.0)                                  # its bus is open right after its Zenoh session
        t0 = time.monotonic()
        for i, msgs in enumerate(plan):
            target = t0 + i / rate
            dt = target - time.monotonic()
            if dt > 0:
                time.sleep(dt)
            for m in msgs:
                bus.send(m)
        send_s = time.monotonic() - t0
        col.wait_quiet(1.5)
        end = time.monotonic() + 20                      # input_fault clears 5 s after the last rejection
        while time.monotonic() < end and not any(a["code"] == "input_fault" and a["action"] == "clear"
                                                 for a in list(col.alarms)):
            time.sleep(0.1)
        st = col.status()
        assert d.poll() is None
    finally:
        bus.shutdown()
        col.close()
        code, err = _stop(d)
    assert code == 0, err[-3000:]
    assert st is not None
    inp = st["input"]
    print(f"CAN: {ticks_sent} ticks + {extra_frames} stray frames in {send_s:.1f} s; daemon input {json.dumps(inp)}")
    assert Counter(inp["rejected"]) == injected, (inp["rejected"], dict(injected))
    assert inp["accepted"] == len(accepted)
    assert inp["accepted"] + sum(v for r, v in inp["rejected"].items() if r != "bad_frame") == ticks_sent
    assert inp["rejected"].get("bad_frame", 0) == extra_frames
    assert inp["missed_ticks"] == missed
    assert st["ticks"] == len(accepted) and st["published"] == len(accepted)
    assert st["skipped_no_subscriber"] == 0 and st["publish_errors"] == 0
    dup = [s for s, n in Counter(col.seqs).items() if n > 1]
    lost = sorted(set(accepted) - set(col.seqs))
    assert not dup and not lost, f"duplicates {dup[:10]}, lost {lost[:10]} ({len(lost)} of {len(accepted)})"
    assert col.seqs == accepted
    fault = [a for a in col.alarms if a["code"] == "input_fault"]
    assert [a["action"] for a in fault] == ["raise", "clear"], fault
    assert f"can {bus_cfg['interface']}:{bus_cfg['channel']}" in fault[0]["message"]
