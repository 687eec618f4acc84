"""New parameters without a restart (issue 16, item 4): a put on cablesvc/<robot>/params or
SIGHUP switches the running daemon to new parameters at a tick boundary, keeps the
hysteresis state, misses no tick and reports the new model in status; a bad file is refused
with the reason and the old parameters stay.

Real daemons on real MCAP recordings, real Zenoh sessions on 127.0.0.1 (multicast scouting
off), `cablesvc run` as a subprocess for SIGHUP, and the router of deploy/ with real
certificates for the access control of the params key.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from cablesvc.config.params import nominal_params
from cablesvc.config import load_robot
from cablesvc.config.params import default_params, load_params
from cablesvc.kernel import Predictor
from cablesvc.kinematics import inverse_kinematics
from cablesvc.recording import ALARMS_TOPIC, FORCES_TOPIC, write_recording
from cablesvc.service.daemon import Daemon, DaemonOptions
from cablesvc.service.snapshot import params_fingerprint, read_snapshot
from cablesvc.service.zenoh_io import Listener, Publisher, keys, make_config
from cablesvc.simulate import simulate_recording
from cablesvc.netutil import free_tcp_port

from reference import offline_forces

REPO = Path(__file__).resolve().parents[1]
SWITCH = 300                      # ticks replayed before the new parameters are put


@pytest.fixture(scope="module")
def rec():
    return simulate_recording("ipanema3", "hold-sine", None, duration=4.0, rate=200.0, seed=5)


@pytest.fixture(scope="module")
def geom(robot):
    return robot.geometry()


def _linear(geom):
    L = inverse_kinematics(geom, np.zeros((1, 3)), np.array([[0, 0, 0, 1.0]])).length[0]
    return default_params(geom.ea, L, "linear")


def _wait(cond, limit_s: float = 10.0, what: str = "condition"):
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


def _daemon(tmp_path: Path, rec, port: int, params, **kw) -> Daemon:
    path = tmp_path / "rec.mcap"
    write_recording(path, rec)
    robot = load_robot("ipanema3")
    return Daemon(DaemonOptions(robot=robot, params=params, source={"kind": "replay", "path": str(path), "speed": 0},
                                record=tmp_path / "out.mcap", listen=(f"tcp/127.0.0.1:{port}",), **kw))


def _client(port: int) -> zenoh.Session:
    return zenoh.open(make_config(listen=(), connect=(f"tcp/127.0.0.1:{port}",)))


def _recorded(path: Path) -> tuple[dict[int, np.ndarray], list[dict]]:
    forces, alarms = {}, []
    with open(path, "rb") as f:
        for _s, ch, m in make_reader(f).iter_messages(topics=[FORCES_TOPIC, ALARMS_TOPIC]):
            p = json.loads(m.data)
            if ch.topic == FORCES_TOPIC:
                forces[int(p["seq"])] = np.array(p["force"], float)
            else:
                alarms.append(p)
    return forces, alarms


def _run_switch_run(d: Daemon, put) -> None:
    """Replay SWITCH ticks, ``put()`` (new parameters over Zenoh), wait until the reload
    thread has handed them to the loop, replay the rest, close."""
    try:
        d.run(threading.Event(), max_ticks=SWITCH)
        assert d.stats.ticks == SWITCH
        put()
        _wait(lambda: d.status()["params_reload"]["pending"] or d.reload_counts["refused"], what="reload prepared")
        d.run(threading.Event())
    finally:
        d.close()


def _offline(rec, geom, params, start=0, state_from=None):
    """seq -> forces of a kernel with ``params`` over ticks start.. of ``rec`` (its state
    taken from the kernel ``state_from`` when given)."""
    pred = Predictor(geom, params)
    if state_from is not None:
        pred.load_state_dict(state_from.state_dict())
    res = {}
    for k in range(start, rec.n_ticks):
        out = pred.tick(float(rec.t[k]), rec.motor_length[k], rec.position[k], rec.orientation[k], rec.force[k],
                        None if rec.temperature is None else float(rec.temperature[k]))
        res[int(rec.seq[k])] = out.force.copy()
    return res, pred


def test_put_new_parameters_switches_at_a_tick_boundary_without_missing_a_tick(tmp_path, rec, geom):
    """(a) nominal amplitude model, then a put of a linear parameter file after SWITCH ticks:
    the forces are the old model's up to that tick and the linear model's from the next one
    on (the linear model has no memory: the reference is simply the linear kernel over the
    whole recording), every tick is published once, status reports the new fingerprint."""
    old, new = nominal_params(geom), _linear(geom)
    port = free_tcp_port()
    d = _daemon(tmp_path, rec, port, old, snapshot=tmp_path / "state.npz")
    client = _client(port)
    try:
        _run_switch_run(d, lambda: client.put(keys("ipanema3").params, new.to_toml()))
    finally:
        client.close()
    forces, _ = _recorded(tmp_path / "out.mcap")
    seqs = [int(q) for q in rec.seq]
    assert sorted(forces) == seqs                                        # no tick missed, none twice
    ref_old, ref_new = offline_forces(rec, params=old), offline_forces(rec, params=new)
    for q in seqs[:SWITCH]:
        np.testing.assert_array_equal(forces[q], ref_old[q], err_msg=f"seq {q}")
    for q in seqs[SWITCH:]:
        np.testing.assert_allclose(forces[q], ref_new[q], rtol=1e-12, atol=1e-9, err_msg=f"seq {q}")
    assert np.max(np.abs(ref_new[seqs[SWITCH]] - ref_old[seqs[SWITCH]])) > 0.1      # the switch is visible
    st = d.status()
    assert st["ticks"] == rec.n_ticks and st["recording"]["missing"] == 0
    m = st["model"]
    assert m["name"] == "linear" and m["fingerprint"] == params_fingerprint(new) != params_fingerprint(old)
    assert m["source"] == "zenoh put on cablesvc/ipanema3/params"
    assert m["active_since"]["seq"] == seqs[SWITCH - 1]
    last = st["params_reload"]["last"]
    assert st["params_reload"]["accepted"] == 1 and st["params_reload"]["refused"] == 0
    assert last["accepted"] and last["applied"] and last["state"].startswith("reset: the model family changed")
    # the snapshot describes the new parameters
    meta, kernel, _ = read_snapshot(tmp_path / "state.npz")
    assert meta["params"] == params_fingerprint(new) and meta["model"] == "linear"


def test_reloading_the_same_parameters_keeps_the_hysteresis_exactly(tmp_path, rec, geom):
    """(b) a put of the running (amplitude) parameters mid-run: the forces equal an
    uninterrupted run bit for bit, because the reversal points and the amplitude estimate
    carry over; a kernel started afresh at that tick would differ."""
    params = nominal_params(geom)
    port = free_tcp_port()
    d = _daemon(tmp_path, rec, port, params)
    client = _client(port)
    try:
        _run_switch_run(d, lambda: client.put(keys("ipanema3").params, params.to_toml()))
    finally:
        client.close()
    forces, _ = _recorded(tmp_path / "out.mcap")
    ref = offline_forces(rec, params=params)
    assert sorted(forces) == sorted(ref)
    for q in ref:
        np.testing.assert_array_equal(forces[q], ref[q], err_msg=f"seq {q}")
    st = d.status()
    assert st["params_reload"]["last"]["state"] == "kept (same model family)"
    assert st["params_reload"]["accepted"] == 1 and st["model"]["fingerprint"] == params_fingerprint(params)
    fresh, _ = _offline(rec, geom, params, start=SWITCH)
    diff = max(np.max(np.abs(fresh[q] - ref[q])) for q in fresh)
    assert diff > 1e-3, "a restart at the switch would not differ: the test would not see a lost state"


def test_same_family_new_values_keep_the_state_and_use_the_new_values(tmp_path, rec, geom):
    """Same family (amplitude), other values (K1 x 1.1): from the switch on the forces are those
    of the new values run on from the old kernel's state (not from rest)."""
    old = nominal_params(geom)
    tables = dict(old.tables)
    tables["K1"] = (np.asarray(old.tables["K1"]) * 1.1).tolist()
    new = type(old)(model=old.model, params=dict(old.params), options=dict(old.options), tables=tables,
                    identification={"discovered_terms": ["offset_gain"], "note": "test"})
    port = free_tcp_port()
    d = _daemon(tmp_path, rec, port, old)
    client = _client(port)
    try:
        _run_switch_run(d, lambda: client.put(keys("ipanema3").params, new.to_toml()))
    finally:
        client.close()
    forces, _ = _recorded(tmp_path / "out.mcap")
    pred = Predictor(geom, old)                           # the old kernel after SWITCH ticks
    for k in range(SWITCH):
        pred.tick(float(rec.t[k]), rec.motor_length[k], rec.position[k], rec.orientation[k], rec.force[k])
    ref_new, _ = _offline(rec, geom, new, start=SWITCH, state_from=pred)
    for q in ref_new:
        np.testing.assert_array_equal(forces[q], ref_new[q], err_msg=f"seq {q}")
    st = d.status()
    assert st["model"]["terms"] == ["offset_gain"] and st["model"]["fingerprint"] == params_fingerprint(new)


def test_bad_parameters_are_refused_with_the_reason_and_the_old_ones_stay(tmp_path, rec, geom):
    """(c) unparseable TOML, a failing check and a wrong cable count, put over Zenoh and as a
    get whose reply is the outcome: each refused with its reason (status, log, the
    params_refused alarm), the old parameters stay, the daemon goes on with every tick;
    a good file afterwards is accepted and clears the alarm."""
    old = nominal_params(geom)
    neg = type(old)(model=old.model, params=dict(old.params), options=dict(old.options),
                    tables={**old.tables, "K1": (-np.asarray(old.tables["K1"])).tolist()})
    bad_check = neg.to_toml()
    wrong_count = _linear(geom)
    wrong_count.params["ea"] = wrong_count.params["ea"][:3]
    bads = {"not TOML": ("format = 1\nmodel = [[", "TOML syntax"),
            "failing check": (bad_check, "tables.K1: the linear stiffness"),
            "wrong cable count": (wrong_count.to_toml(), "expected a number or a list of 8 values")}
    port = free_tcp_port()
    d = _daemon(tmp_path, rec, port, old)
    client = _client(port)
    replies = []
    try:
        d.run(threading.Event(), max_ticks=SWITCH)
        for n, (text, _why) in enumerate(bads.values(), start=1):
            client.put(keys("ipanema3").params, text)
            _wait(lambda: d.reload_counts["refused"] == n, what=f"refusal {n}")
        # a get with a bad payload: the reply is the outcome
        for r in client.get(keys("ipanema3").params, payload="model = 'nope'\nformat = 1\n", timeout=10.0):
            replies.append(json.loads(r.ok.payload.to_bytes()))
        st = d.status()
        d.run(threading.Event(), max_ticks=SWITCH + 100)          # still running, old parameters
        client.put(keys("ipanema3").params, old.to_toml())       # a good file clears the alarm
        _wait(lambda: d.status()["params_reload"]["pending"], what="good reload prepared")
        d.run(threading.Event())
        # a get without payload answers the active parameters
        active = [json.loads(r.ok.payload.to_bytes()) for r in client.get(keys("ipanema3").params, timeout=10.0)]
    finally:
        client.close()
        d.close()
    assert st["params_reload"]["refused"] == 4 and st["params_reload"]["accepted"] == 0
    assert st["model"]["fingerprint"] == params_fingerprint(old) and st["model"]["source"].startswith("nominal")
    refused = [a for a in st["alarms_active"] if a["code"] == "params_refused"]
    assert len(refused) == 1 and "model: must be one of" in refused[0]["message"]      # the latest reason
    reasons = [p["message"] for p in st["recent_problems"] if p["reason"] == "params_refused"]
    assert len(reasons) == 4
    for (_text, why), msg in zip(bads.values(), reasons):
        assert why in msg, (why, msg)
    assert len(replies) == 1 and replies[0]["accepted"] is False and "model: must be one of" in replies[0]["reason"]
    assert st["params_reload"]["last"]["reason"] == replies[0]["reason"]
    forces, alarms = _recorded(tmp_path / "out.mcap")
    ref = offline_forces(rec, params=old)
    assert sorted(forces) == sorted(ref)
    for q in ref:
        np.testing.assert_array_equal(forces[q], ref[q], err_msg=f"seq {q}")
    pr = [(a["action"]) for a in alarms if a["code"] == "params_refused"]
    assert pr == ["raise"] * 4 + ["clear"]
    end = d.status()
    assert "params_refused" not in [a["code"] for a in end["alarms_active"]]
    assert end["params_reload"]["accepted"] == 1
    assert active[0]["model"]["fingerprint"] == params_fingerprint(old)
    assert load_params_text_equal(active[0]["toml"], old)


def load_params_text_equal(text: str, params) -> bool:
    from cablesvc.config.params import parse_params
    return params_fingerprint(parse_params(text)) == params_fingerprint(params)


# ---- SIGHUP: `cablesvc run` re-reads its parameter file ---------------------------------------

def _status(lis: Listener) -> dict | None:
    return lis.status(timeout=2.0)


def test_sighup_rereads_the_parameter_file(tmp_path, geom):
    """(d) `cablesvc run` on a replay at real speed with --params; rewrite the file, SIGHUP:
    status reports the new model and fingerprint and the ticks go on; a broken file and
    SIGHUP: refused with the reason, the new model stays; the log says both."""
    rec = simulate_recording("ipanema3", "hold-sine", None, duration=30.0, rate=100.0, seed=7)
    path = tmp_path / "rec.mcap"
    write_recording(path, rec)
    pfile = tmp_path / "p.toml"
    old, new = nominal_params(geom), _linear(geom)
    old.save(pfile)
    port = free_tcp_port()
    proc = subprocess.Popen([sys.executable, "-m", "cablesvc", "run", "--source", "replay", "--replay", str(path),
                             "--speed", "1", "--params", str(pfile), "--no-view", "--no-snapshot",
                             "--listen", f"tcp/127.0.0.1:{port}", "--log-level", "INFO"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lis = Listener("ipanema3", make_config(listen=(), connect=(f"tcp/127.0.0.1:{port}",)))
    try:
        st0 = _wait(lambda: (s := _status(lis)) and s["ticks"] > 10 and s, 30.0, "the daemon's first ticks")
        assert st0["model"]["fingerprint"] == params_fingerprint(load_params(pfile))
        assert st0["params_reload"]["file"] == str(pfile)
        new.save(pfile)
        proc.send_signal(signal.SIGHUP)
        st1 = _wait(lambda: (s := _status(lis)) and s["model"]["name"] == "linear" and s, 10.0, "the new model")
        assert st1["model"]["fingerprint"] == params_fingerprint(load_params(pfile))
        assert "SIGHUP" in st1["model"]["source"] and st1["params_reload"]["accepted"] == 1
        t1 = st1["ticks"]
        pfile.write_text("format = 1\nmodel = \"linear\"\n[params]\nea = -5.0\n")
        proc.send_signal(signal.SIGHUP)
        st2 = _wait(lambda: (s := _status(lis)) and s["params_reload"]["refused"] == 1 and s, 10.0, "the refusal")
        assert st2["model"]["name"] == "linear" and st2["model"]["fingerprint"] == st1["model"]["fingerprint"]
        assert "params.ea" in st2["params_reload"]["last"]["reason"]
        _wait(lambda: (s := _status(lis)) and s["ticks"] > t1 + 20, 10.0, "ticks after the refusal")
        assert proc.poll() is None                                          # still running
    finally:
        lis.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err[-3000:]
    assert "new parameters active from the tick after seq" in err
    assert "refused, the old ones stay active" in err and "params.ea" in err


# ---- access control: only the operator's certificate may put parameters ----------------------

def _make_certs(d: Path) -> None:
    def run(*args):
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)
    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", "2",
        "-subj", "/CN=cablesvc-test-ca")
    (d / "ext.cnf").write_text("subjectAltName=DNS:localhost\n")
    for cn in ("router", "cablesvc-daemon", "cablesvc-viewer", "cablesvc-operator"):
        run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{cn}.key", "-out", f"{cn}.csr", "-subj", f"/CN={cn}")
        run("x509", "-req", "-in", f"{cn}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-out", f"{cn}.pem", "-days", "2", "-extfile", "ext.cnf")


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command to make certificates")
def test_router_access_control_lets_only_the_operator_put_parameters(tmp_path):
    """deploy/zenoh-router.json5 with real certificates: a put on cablesvc/r1/params from the
    operator's certificate reaches the daemon (and a get gets its reply); the same put from
    a viewer's certificate never arrives."""
    _make_certs(tmp_path)
    port = free_tcp_port()
    rc = make_config(str(REPO / "deploy" / "zenoh-router.json5"), listen=[f"tls/localhost:{port}"])
    for k, f in (("root_ca_certificate", "ca.pem"), ("listen_certificate", "router.pem"),
                 ("listen_private_key", "router.key")):
        rc.insert_json5(f"transport/link/tls/{k}", json.dumps(str(tmp_path / f)))

    def client(cn, mode="client", listen=()):
        c = make_config(str(REPO / "deploy" / "zenoh-peer.json5"), mode=mode, listen=list(listen),
                        connect=[f"tls/localhost:{port}"])
        c.insert_json5("transport/link/tls", json.dumps({
            "root_ca_certificate": str(tmp_path / "ca.pem"), "connect_certificate": str(tmp_path / f"{cn}.pem"),
            "connect_private_key": str(tmp_path / f"{cn}.key"), "enable_mtls": True, "verify_name_on_connect": True}))
        return c
    got: list[tuple[bytes, str]] = []
    router = zenoh.open(rc)
    opened = []
    try:
        pub = Publisher("r1", client("cablesvc-daemon", mode="peer", listen=[f"tcp/127.0.0.1:{free_tcp_port()}"]),
                        status=lambda: {"robot": "r1"})
        opened.append(pub)
        pub.serve_params(lambda data, origin: got.append((data, origin)),
                         lambda q, data: pub.reply_params(q, {"accepted": False, "echo": data.decode()}))
        viewer = zenoh.open(client("cablesvc-viewer"))
        opened.append(viewer)
        operator = zenoh.open(client("cablesvc-operator"))
        opened.append(operator)
        time.sleep(1.0)                              # declarations travel through the router
        viewer.put(keys("r1").params, b"from the viewer")
        assert [r for r in viewer.get(keys("r1").params, payload=b"viewer get", timeout=2.0) if r.ok] == []
        operator.put(keys("r1").params, b"from the operator")
        _wait(lambda: got, 10.0, "the operator's put")
        replies = [json.loads(r.ok.payload.to_bytes())
                   for r in operator.get(keys("r1").params, payload=b"operator get", timeout=5.0) if r.ok]
        time.sleep(0.5)
        assert got == [(b"from the operator", "zenoh put on cablesvc/r1/params")]
        assert replies == [{"accepted": False, "echo": "operator get"}]
    finally:
        for o in reversed(opened):
            o.close()
        router.close()


# ---- several robots in one daemon: each robot its own params key -------------------------------

def test_fleet_each_robot_takes_parameters_on_its_own_key(tmp_path):
    """A fleet (one Zenoh session, two robots): a put on cablesvc/ipanema3/params changes
    ipanema3's model only; planar4 keeps its parameters and sees no reload."""
    from cablesvc.service.fleet import Fleet

    opts = []
    for name, seed in (("ipanema3", 3), ("planar4", 4)):
        r = simulate_recording(name, "trajectory", None, duration=2.0, rate=200.0, seed=seed)
        path = tmp_path / f"{name}.mcap"
        write_recording(path, r)
        robot = load_robot(name)
        opts.append(DaemonOptions(robot=robot, params=nominal_params(robot.geometry()),
                                  source={"kind": "replay", "path": str(path), "speed": 0}))
    port = free_tcp_port()
    new = _linear(load_robot("ipanema3").geometry())
    fleet = Fleet(opts, listen=(f"tcp/127.0.0.1:{port}",))
    client = _client(port)
    try:
        a, b = fleet.daemons["ipanema3"], fleet.daemons["planar4"]
        fp_b = b.fingerprint
        client.put(keys("ipanema3").params, new.to_toml())
        _wait(lambda: a.status()["params_reload"]["pending"], what="ipanema3's reload prepared")
        fleet.run()
        st = fleet.status()
    finally:
        client.close()
        fleet.close()
    assert st["ipanema3"]["model"]["name"] == "linear"
    assert st["ipanema3"]["model"]["fingerprint"] == params_fingerprint(new)
    assert st["ipanema3"]["params_reload"]["key"] == "cablesvc/ipanema3/params"
    assert st["planar4"]["model"]["fingerprint"] == fp_b and st["planar4"]["model"]["name"] == "amplitude"
    assert st["planar4"]["params_reload"]["accepted"] == 0 and st["planar4"]["params_reload"]["refused"] == 0
    assert st["ipanema3"]["ticks"] == 400 and st["planar4"]["ticks"] == 400
