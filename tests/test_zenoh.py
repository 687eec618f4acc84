"""Zenoh outputs with real sessions on loopback: payload round trips (JSON and compact),
alarms, status queries, liveliness, close, configuration, a listener in another process,
and the router configuration of deploy/ with real TLS certificates and access control.

Sessions listen on free 127.0.0.1 ports only, multicast scouting off, peers connect
explicitly. Waits are bounded loops on a condition, never assertions on durations."""

from __future__ import annotations

import json
import math
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from cablesvc.alarms import AlarmEvent
from cablesvc.kernel.predictor import TickOutput
from cablesvc.recording import ALARM_JSON_SCHEMA, FORCES_JSON_SCHEMA
from cablesvc.service.messages import (
    ALARM_SCHEMA,
    COMPACT_ENCODING,
    FORCES_SCHEMA,
    STATUS_SCHEMA,
    check_schema,
    decode,
    encode,
    forces_payload,
)
from cablesvc.service.zenoh_io import DEFAULT_LISTEN, Listener, Publisher, keys, make_config

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(cond, limit_s: float = 15.0, what="condition"):
    """Poll ``cond`` until true; fail (not a timing assertion: a hang detector) after limit_s.
    ``what`` names the condition in the failure, a callable is read at the failure (counts)."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(0.01)
    pytest.fail(f"{what() if callable(what) else what} not reached")


def tricky_output(m: int = 5, seed: int = 0) -> TickOutput:
    """A tick output with awkward floats: thirds, subnormals, -0.0, huge, NaN gaps."""
    rng = np.random.default_rng(seed)
    force = rng.uniform(0, 500, m)
    force[0] = 1.0 / 3.0
    force[1] = 5e-324
    meas = force + rng.normal(0, 0.1, m)
    meas[2] = np.nan                              # one cable without sensor
    return TickOutput(
        t=1234.5678901234567, force=force, elongation=rng.normal(0, 1e-3, m) * np.pi,
        wrap_angle=np.array([-0.0, 1e-300, 2.5, 0.1, 3.0])[:m], slack=rng.random(m) < 0.5,
        wrench_residual=rng.normal(0, 10, 6), measured=meas, residual=meas - force,
        position=np.array([0.1, -0.2, 1.7976931348623157e308]), orientation=np.array([0.0, 0.0, 0.6, 0.8]),
        amplitude=np.full(m, np.nan), temperature=21.25, pose_from_fk=True, fk_residual=1e-9)


@pytest.fixture
def endpoint():
    return f"tcp/127.0.0.1:{free_port()}"


def pair(endpoint, robot="r1", encoding="json", status=None, listener_robot="r1", **kw):
    pub = Publisher(robot, make_config(listen=(endpoint,)), encoding=encoding, status=status)
    lis = Listener(listener_robot, make_config(listen=(), connect=(endpoint,)), **kw)
    wait_until(pub.subscribed, what="subscriber matched")
    wait_until(lambda: pub.subscribed("alarms"), what="alarm subscriber matched")
    return pub, lis


# ---- messages ----------------------------------------------------------------------------

def test_forces_payload_schema_and_exact_round_trip_of_both_encodings():
    names = [f"c{i}" for i in range(5)]
    p = forces_payload("r1", 41, tricky_output(), 987654321, names)
    assert check_schema(p, FORCES_SCHEMA) == []
    assert check_schema(p, FORCES_JSON_SCHEMA) == []              # superset of the MCAP schema
    assert p["measured"][2] is None and p["residual"][2] is None and p["amplitude"] is None
    js, enc_j = encode(p, "json")
    assert enc_j == "application/json" and b"NaN" not in js and b"Infinity" not in js
    cb, enc_c = encode(p, "compact")
    assert enc_c == COMPACT_ENCODING and len(cb) < len(js)
    for data, enc in ((js, enc_j), (cb, enc_c), (cb, enc_c + ";anything")):
        back = decode(data, enc)
        assert back == p
        assert math.copysign(1.0, back["wrap_angle"][0]) == -1.0   # -0.0 kept
    # no measured force at all: measured and residual are null, not lists of nulls
    out = tricky_output()
    out.measured[:] = np.nan
    out.residual[:] = np.nan
    p2 = forces_payload("r1", 42, out, 1, names)
    assert p2["measured"] is None and p2["residual"] is None
    assert decode(*encode(p2, "compact")) == p2
    with pytest.raises(ValueError, match="forces"):
        encode({"code": "x"}, "compact")
    with pytest.raises(ValueError, match="magic"):
        decode(b"garbage", COMPACT_ENCODING)
    with pytest.raises(ValueError, match="unknown encoding"):
        decode(js, "text/csv")


# ---- publisher and listener ----------------------------------------------------------------

def test_no_forces_message_is_lost_while_the_subscriber_stalls(endpoint):
    """Forces block under congestion: a subscriber whose callback stalls for 300 ms, twice,
    while the daemon keeps publishing as fast as it can, still gets every message once and
    in order (under DROP congestion control the full queue loses a burst at each stall)."""
    names = [f"c{i}" for i in range(5)]
    got: list[int] = []
    stalls = []

    def on_forces(payload, receive_ns):
        got.append(payload["seq"])
        if payload["seq"] in (500, 2500):
            t0 = time.monotonic()
            time.sleep(0.3)
            stalls.append(time.monotonic() - t0)

    # The daemon's config closes a link blocked for 1 s (BLOCK_CLOSE_US). On this shared VM the
    # test once stopped at message 483 with nothing more for 15 s, most likely a stall of the
    # listener's thread over 1 s that closed the link (not shown): the documented price of the
    # 1 s, not what this test is about.
    # Here the link may stay blocked 10 s, so only the congestion control is tested: under DROP
    # the 300 ms stalls still lose a burst each (checked: 3 of 3 runs with DROP failed, at 838,
    # 2385 and 2293 messages; with 4000 messages, all of which fit in the queue, DROP passed
    # one run in two).
    cfg = make_config(listen=(endpoint,))
    cfg.insert_json5("transport/link/tx/queue/congestion_control/block/wait_before_close", "10000000")
    pub = Publisher("r1", cfg, encoding="json")
    lis = Listener("r1", make_config(listen=(), connect=(endpoint,)), on_forces=on_forces)
    wait_until(pub.subscribed, what="subscriber matched")
    try:
        out = tricky_output()
        n = 20000       # ~5 MB: more than the 16-batch transmit queue holds, so DROP must lose
        for k in range(n):
            pub.publish_forces(forces_payload("r1", k, out, time.monotonic_ns(), names))
        wait_until(lambda: len(got) >= n, what=lambda: f"{n} forces messages (got {len(got)}, the first {got[:3]})")
        assert got == list(range(n))
        assert len(stalls) == 2 and lis.decode_errors == 0
    finally:
        lis.close()
        pub.close()


@pytest.mark.parametrize("encoding", ["json", "compact"])
def test_forces_arrive_exactly_in_either_encoding(endpoint, encoding):
    pub, lis = pair(endpoint, encoding=encoding)
    try:
        sent = [forces_payload("r1", k, tricky_output(seed=k), time.monotonic_ns(), [f"c{i}" for i in range(5)])
                for k in range(20)]
        got = []
        for p in sent:                    # one at a time: the order of arrival is checked too
            pub.publish_forces(p)
            got.append(lis.forces(timeout=10.0))
        assert all(g is not None for g in got)
        assert [g.payload for g in got] == sent
        assert {g.key for g in got} == {"cablesvc/r1/forces"}
        assert {g.encoding for g in got} == {"application/json" if encoding == "json" else COMPACT_ENCODING}
        assert all(g.receive_ns >= p["stamp_ns"] for g, p in zip(got, sent))
        assert lis.decode_errors == 0 and pub.forces_published == 20
    finally:
        lis.close()
        pub.close()


def test_alarms_are_delivered_with_the_robot_and_match_the_schemas(endpoint):
    received = []
    done = threading.Event()

    def on_alarm(p, ns):
        received.append((p, ns))
        if len(received) == 2:
            done.set()
    pub, lis = pair(endpoint, on_alarm=on_alarm)
    try:
        ev = [AlarmEvent("raise", "drift", 2, "warning", 100.5, 90.0, 100500, "cable 2 drifted", offset_n=0.41,
                         suggested_action="re-identify the cable model (cablesvc identify ...)", value=0.41, limit=0.2),
              AlarmEvent("clear", "over_limit", 0, "error", 101.0, 100.9, 101000, "back", value=1490.0, limit=1499.0)]
        for e in ev:
            pub.publish_alarm(e.payload())
        assert done.wait(10.0)
        for (p, ns), e in zip(received, ev):
            assert p == {**e.payload(), "robot": "r1"}
            assert check_schema(p, ALARM_SCHEMA) == [] and check_schema(p, ALARM_JSON_SCHEMA) == []
            assert isinstance(ns, int)
    finally:
        lis.close()
        pub.close()


def test_status_query_liveliness_and_close(endpoint):
    calls = []

    def status():
        calls.append(1)
        return {"robot": "r1", "ticks": np.int64(12), "tick_rate_hz": float("nan"), "latency_us": {"p50_us": 12.5},
                "alarms_active": [AlarmEvent("raise", "slack", 1, "warning", 1.0, 0.9, 10, "slack").payload()],
                "last": {"seq": 10, "t": np.float64(1.0)}}
    pub, lis = pair(endpoint, status=status)
    try:
        st = lis.status(timeout=5.0)
        assert st == {"robot": "r1", "ticks": 12, "tick_rate_hz": None, "latency_us": {"p50_us": 12.5},
                      "alarms_active": [status()["alarms_active"][0]], "last": {"seq": 10, "t": 1.0}}
        assert check_schema(st, STATUS_SCHEMA) == []
        assert lis.alive() == ["r1"]
        # a second robot's daemon on another port is seen by a wildcard listener
        ep2 = f"tcp/127.0.0.1:{free_port()}"
        pub2 = Publisher("r2", make_config(listen=(ep2,)), status=lambda: {"robot": "r2"})
        every = Listener(None, make_config(listen=(), connect=(endpoint, ep2)))
        try:
            assert wait_until(lambda: every.alive() == ["r1", "r2"], what="both tokens")
            assert sorted(s["robot"] for s in every.statuses(timeout=5.0)) == ["r1", "r2"]
        finally:
            every.close()
            pub2.close()
        # close: idempotent, publishing afterwards is a no-op, the token disappears
        closer = threading.Thread(target=pub.close)
        closer.start()
        closer.join(30.0)
        assert not closer.is_alive() and pub.closed
        pub.close()
        pub.publish_forces(forces_payload("r1", 1, tricky_output(), 1, list("abcde")))
        pub.publish_alarm({"action": "clear"})
        wait_until(lambda: lis.alive() == [], what="liveliness token gone")
        assert lis.status(timeout=0.5) is None
    finally:
        lis.close()
        lis.close()
        pub.close()


def test_failing_status_gives_no_answer_and_bad_messages_are_counted(endpoint):
    def broken():
        raise RuntimeError("not ready")
    pub, lis = pair(endpoint, status=broken)
    try:
        assert lis.status(timeout=5.0) is None
        assert pub.status_queries >= 1
        # garbage on the forces key from a raw session: counted, skipped, the next good one arrives
        pub.session.put(keys("r1").forces, b"\x00\x01", encoding=zenoh.Encoding(COMPACT_ENCODING))
        good = forces_payload("r1", 7, tricky_output(), 1, list("abcde"))
        pub.publish_forces(good)
        r = lis.forces(timeout=10.0)
        assert r is not None and r.payload == good
        # the raw put and the publisher's put may arrive in either order
        wait_until(lambda: lis.decode_errors == 1, what="the garbage message counted")
        assert lis.forces(timeout=0.0) is None
    finally:
        lis.close()
        pub.close()


def test_forces_are_not_encoded_while_nobody_listens(endpoint):
    pub = Publisher("r1", make_config(listen=(endpoint,)))
    try:
        p = forces_payload("r1", 1, tricky_output(), 1, list("abcde"))
        pub.publish_forces(p)
        assert pub.forces_skipped == 1 and pub.forces_published == 0
    finally:
        pub.close()


def test_a_subscriber_zenoh_knows_of_gets_the_next_tick_even_before_the_matching_notification(endpoint):
    """Zenoh's matching notification runs on its own thread and, on a loaded machine, came
    tens of ms after ``subscribed()`` read true: the ticks in between were skipped (a CI run
    lost the first 130 of 20000 messages; 2 of 15 runs of the stall test lost 845 and 1076).
    Here the notification is held back outright: the publish must still go out."""
    pub = Publisher("r1", make_config(listen=(endpoint,)))
    lis = Listener("r1", make_config(listen=(), connect=(endpoint,)))
    try:
        wait_until(lambda: pub._forces_matched, what="matching notification")
        pub._forces_matched = False                 # as if the notification had not come yet
        pub.publish_forces(forces_payload("r1", 7, tricky_output(), 1, list("abcde")))
        got = lis.forces(timeout=10.0)
        assert got is not None and got.payload["seq"] == 7
        assert pub.forces_skipped == 0 and pub.forces_published == 1
    finally:
        lis.close()
        pub.close()


# ---- configuration ------------------------------------------------------------------------

def test_make_config_is_a_loopback_peer_without_multicast():
    cfg = make_config()
    assert json.loads(cfg.get_json("mode")) == "peer"
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False
    assert json.loads(cfg.get_json("listen/endpoints")) == [DEFAULT_LISTEN] == ["tcp/127.0.0.1:7447"]
    assert json.loads(cfg.get_json("connect/endpoints")) == []
    c2 = make_config(listen=("tcp/127.0.0.1:7500", "tcp/[::1]:7500"), connect="tcp/127.0.0.1:7447")
    assert json.loads(c2.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7500", "tcp/[::1]:7500"]
    assert json.loads(c2.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447"]
    with pytest.raises(ValueError):
        make_config(listen=("localhost",))
    with pytest.raises(ValueError):
        keys("a/b")
    assert keys(None).forces == "cablesvc/*/forces" and keys("ipanema3").alive == "cablesvc/ipanema3/alive"


def test_config_files_load_and_only_explicit_arguments_override_them():
    peer = make_config(str(REPO / "deploy" / "zenoh-peer.json5"), connect=["tcp/127.0.0.1:9"])
    assert json.loads(peer.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]      # from the file
    assert json.loads(peer.get_json("connect/endpoints")) == ["tcp/127.0.0.1:9"]       # overridden
    assert json.loads(peer.get_json("scouting/multicast/enabled")) is False
    router = make_config(str(REPO / "deploy" / "zenoh-router.json5"))
    assert json.loads(router.get_json("mode")) == "router"
    assert json.loads(router.get_json("transport/link/tls/enable_mtls")) is True
    acl = json.loads(router.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"


def _make_certs(d: Path) -> None:
    def run(*args):
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)
    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", "2",
        "-subj", "/CN=cablesvc-test-ca")
    (d / "ext.cnf").write_text("subjectAltName=DNS:localhost\n")
    for cn in ("router", "cablesvc-daemon", "cablesvc-viewer", "intruder"):
        run("req", "-newkey", "rsa:2048", "-nodes", "-keyout", f"{cn}.key", "-out", f"{cn}.csr", "-subj", f"/CN={cn}")
        run("x509", "-req", "-in", f"{cn}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-out", f"{cn}.pem", "-days", "2", "-extfile", "ext.cnf")


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command to make certificates")
def test_router_config_with_tls_and_access_control(tmp_path):
    """deploy/zenoh-router.json5 for real: TLS with client certificates; the daemon's
    certificate may publish, a viewer's may read but not publish, another may do nothing."""
    _make_certs(tmp_path)
    port = free_port()
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
    router = zenoh.open(rc)
    opened = []
    try:
        pub = Publisher("r1", client("cablesvc-daemon", mode="peer", listen=[f"tcp/127.0.0.1:{free_port()}"]),
                        status=lambda: {"robot": "r1"})
        opened.append(pub)
        viewer = Listener("r1", client("cablesvc-viewer"))
        opened.append(viewer)
        intruder = Listener("r1", client("intruder"))
        opened.append(intruder)
        wait_until(pub.subscribed, what="viewer's subscription reaches the daemon through the router")
        p = forces_payload("r1", 3, tricky_output(), 1, list("abcde"))
        pub.publish_forces(p)
        r = viewer.forces(timeout=10.0)
        assert r is not None and r.payload == p
        assert viewer.status(timeout=5.0) == {"robot": "r1"} and viewer.alive() == ["r1"]
        # the viewer cannot publish a fake alarm; the intruder sees nothing at all
        fake = viewer.session.declare_publisher(keys("r1").alarms)
        fake.put(json.dumps(AlarmEvent("raise", "slack", 0, "warning", 0.0, 0.0, 0, "FAKE").payload()))
        real = AlarmEvent("raise", "slack", 1, "warning", 1.0, 1.0, 1, "real").payload()
        pub.publish_alarm(real)
        a = viewer.alarms(timeout=10.0)
        assert a is not None and a.payload["message"] == "real"
        assert viewer.alarms(timeout=0.5) is None
        assert intruder.forces(timeout=0.0) is None and intruder.alarms(timeout=0.0) is None
        assert intruder.status(timeout=1.0) is None and intruder.alive() == []
    finally:
        for o in reversed(opened):
            o.close()
        router.close()


# ---- the listener in another process ---------------------------------------------------------

def test_listen_command_in_a_subprocess_prints_json_lines(endpoint):
    pub = Publisher("r1", make_config(listen=(endpoint,)), encoding="compact")
    proc = subprocess.Popen(
        [sys.executable, "-m", "cablesvc.cli.listen_cmd", "listen", "--robot", "r1", "--connect", endpoint,
         "--json", "--count", "5", "--timeout", "60"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    sent = {}
    try:
        wait_until(lambda: pub.subscribed() or proc.poll() is not None, 60.0, "listener subscribed")
        wait_until(lambda: pub.subscribed("alarms") or proc.poll() is not None, 60.0, "alarm subscriber")
        alarm = AlarmEvent("raise", "input_stale", None, "warning", 0.5, 0.45, 4, "no input").payload()
        pub.publish_alarm(alarm)
        k = 0
        end = time.monotonic() + 60.0
        while proc.poll() is None and time.monotonic() < end:
            p = forces_payload("r1", k, tricky_output(seed=k), time.monotonic_ns(), list("abcde"))
            sent[k] = p
            pub.publish_forces(p)
            k += 1
            time.sleep(0.02)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        pub.close()
    assert proc.returncode == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    forces = [x for x in lines if x["kind"] == "forces"]
    assert len(forces) == 5
    for x in forces:
        assert x["key"] == "cablesvc/r1/forces" and x["payload"] == sent[x["payload"]["seq"]]
    assert [x["payload"] for x in lines if x["kind"] == "alarm"] == [{**alarm, "robot": "r1"}]


def test_listen_command_status_and_alive_in_process(endpoint, capsys):
    from cablesvc.cli.main import main

    pub = Publisher("r1", make_config(listen=(endpoint,)), status=lambda: {"robot": "r1", "ticks": 3})
    try:
        assert main(["listen", "--status", "--robot", "r1", "--connect", endpoint, "--json"]) == 0
        assert json.loads(capsys.readouterr().out) == {"robot": "r1", "ticks": 3}
        assert main(["listen", "--alive", "--connect", endpoint, "--json"]) == 0
        assert json.loads(capsys.readouterr().out) == ["r1"]
    finally:
        pub.close()
    assert main(["listen", "--status", "--robot", "r1", "--connect", endpoint, "--wait", "0.3"]) == 1
    assert "no daemon answered" in capsys.readouterr().err
