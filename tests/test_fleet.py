"""Several robots in one daemon (cablesvc.service.fleet, ``cablesvc run --config fleet.toml``).

End to end with real components: one daemon subprocess serves ipanema3 and planar4, each
from its own replay, over one Zenoh session; a Listener on loopback (multicast scouting
off, peers connect explicitly) receives both robots' forces, each matching its own offline
kernel to 1e-9 with nothing crossing over; a bad tick in one robot's input is rejected and
alarmed for that robot only while the other goes on; the status queryable answers per
robot; SIGTERM stops everything with exit 0 and a snapshot per robot. Plus the fleet
config's errors (each names the file and the entry), start-up failure of one robot (the
others and the session are closed again), and publishers sharing one session.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from cablesvc.config.daemon import FleetConfigError, RunOverrides, fleet_config
from cablesvc.config.params import nominal_params
from cablesvc.config import load_robot
from cablesvc.recording import read_recording, write_recording
from cablesvc.service.daemon import DaemonOptions
from cablesvc.service.snapshot import read_snapshot
from cablesvc.service.fleet import Fleet, FleetError, FleetStartError
from cablesvc.service.plan import plan_fleet
from cablesvc.service.zenoh_io import Listener, Publisher, keys, make_config
from cablesvc.simulate import simulate_recording
from cablesvc.netutil import free_tcp_port
from reference import offline_forces


def _csv_with_nan_length(good: Path, bad: Path, row: int) -> None:
    """Copy a recording CSV with one motor length of data row ``row`` replaced by NaN."""
    lines = good.read_text().splitlines()
    hdr = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    cols = lines[hdr].split(",")
    ml = cols.index(next(c for c in cols if c.startswith("motor_length") or c.startswith("l0") or c == "l1"))
    rows = lines[hdr + 1:]
    r = rows[row].split(",")
    r[ml] = "nan"
    rows[row] = ",".join(r)
    bad.write_text("\n".join(lines[: hdr + 1] + rows) + "\n")


def _toml_str(p: Path | str) -> str:
    return json.dumps(str(p))          # a JSON string is a valid TOML basic string


# ---- end to end -------------------------------------------------------------------------

def test_one_daemon_serves_two_robots_each_from_its_own_replay(tmp_path: Path):
    rate, duration = 200.0, 6.0
    rec_a = simulate_recording("ipanema3", "trajectory", None, duration=duration, rate=rate, seed=3)
    path_a = tmp_path / "ipanema3.mcap"
    write_recording(path_a, rec_a)
    rec_b = simulate_recording("planar4", "trajectory", None, duration=duration, rate=rate, seed=4)
    good_b = tmp_path / "planar4-good.csv"
    write_recording(good_b, rec_b)
    bad_row = 40                                   # planar4's input has one NaN motor length
    path_b = tmp_path / "planar4.csv"
    _csv_with_nan_length(good_b, path_b, bad_row)
    rec_b = read_recording(good_b)                 # what the daemon reads from the CSV, bit for bit
    offline = {"ipanema3": offline_forces(rec_a, "ipanema3"),
               "planar4": offline_forces(rec_b, "planar4", skip=frozenset({bad_row}))}
    n_cables = {"ipanema3": 8, "planar4": 4}

    lport, dport = free_tcp_port(), free_tcp_port()
    snaps = {"ipanema3": tmp_path / "state" / "ipanema3.state.npz", "planar4": tmp_path / "state" / "p4.npz"}
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(f"""
listen = ["tcp/127.0.0.1:{dport}"]
connect = ["tcp/127.0.0.1:{lport}"]
encoding = "json"

[[robots]]
robot = "ipanema3"
snapshot = {_toml_str(snaps["ipanema3"])}
record = {_toml_str(tmp_path / "ipanema3-out.mcap")}
[robots.source]
kind = "replay"
path = {_toml_str(path_a)}
speed = 1.0

[[robots]]
robot = "planar4"
snapshot = {_toml_str(snaps["planar4"])}
[robots.source]
kind = "replay"
path = {_toml_str(path_b)}
speed = 1.0
""")
    got: dict[str, list[dict]] = {"ipanema3": [], "planar4": []}
    alarms: list[tuple[str, dict]] = []

    def take(r) -> None:
        robot = r.key.split("/")[1]
        assert r.key == keys(robot).forces and r.payload["robot"] == robot, (r.key, r.payload["robot"])
        got[robot].append(r.payload)

    lst = Listener(None, make_config(listen=(f"tcp/127.0.0.1:{lport}",)))   # every robot's keys
    d = None
    try:
        d = subprocess.Popen([sys.executable, "-m", "cablesvc", "run", "--config", str(cfg), "--no-view",
                              "--snapshot-interval", "0.5", "--wait-subscriber", "20", "--log-level", "INFO"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        end = time.monotonic() + 45
        while time.monotonic() < end and min(len(v) for v in got.values()) < 300 and d.poll() is None:
            r = lst.forces(timeout=0.2)
            if r is not None:
                take(r)
        assert min(len(v) for v in got.values()) >= 300, {k: len(v) for k, v in got.items()}
        # both robots are alive and answer their own status (the replays still run: 6 s each)
        assert lst.alive() == ["ipanema3", "planar4"]
        statuses = {s["robot"]: s for s in lst.statuses()}
        assert sorted(statuses) == ["ipanema3", "planar4"]
        for robot, st in statuses.items():
            assert st["fleet"] == {"robots": ["ipanema3", "planar4"], "running": True, "error": None}, st["fleet"]
            assert st["ticks"] >= 300 and st["input"]["source"] == "replay"
            assert st["snapshot"]["path"] == str(snaps[robot])
        assert sum(statuses["planar4"]["input"]["rejected"].values()) == 1, statuses["planar4"]["input"]
        assert sum(statuses["ipanema3"]["input"].get("rejected", {}).values()) == 0
        assert "recording" in statuses["ipanema3"] and "recording" not in statuses["planar4"]
        one = Listener("planar4", make_config(listen=(), connect=(f"tcp/127.0.0.1:{dport}",)))
        try:                                        # a robot's own status key answers for that robot only
            only = one.statuses()
        finally:
            one.close()
        assert [s["robot"] for s in only] == ["planar4"]
        assert d.poll() is None, "the daemon ended before SIGTERM"
        t0 = time.monotonic()
        d.send_signal(signal.SIGTERM)
        _, err = d.communicate(timeout=20)
        took = time.monotonic() - t0
        while (r := lst.forces(timeout=0.3)) is not None:
            take(r)
        while (a := lst.alarms(timeout=0.1)) is not None:
            alarms.append((a.key, a.payload))
    finally:
        if d is not None and d.poll() is None:
            d.kill()
            d.communicate(timeout=10)
        lst.close()

    assert d.returncode == 0, err[-3000:]
    assert "Traceback" not in err
    assert took < 10.0, f"SIGTERM took {took:.1f} s"    # the process, interpreter exit included
    for robot in ("ipanema3", "planar4"):
        m = re.search(rf"robot {robot} stopped in ([0-9.]+) s after (\d+) ticks", err)
        assert m, err[-3000:]
        assert float(m.group(1)) < 2.0                 # every daemon, its snapshot and the session: < 2 s
        msgs = got[robot]
        seqs = [p["seq"] for p in msgs]
        assert len(seqs) == len(set(seqs))             # one message per tick
        ref = offline[robot]
        for p in msgs:                                 # each robot's forces are its own kernel's
            f = np.array(p["force"], float)
            assert f.shape == (n_cables[robot],) and len(p["cables"]) == n_cables[robot]
            np.testing.assert_allclose(f, ref[p["seq"]], rtol=1e-9, atol=1e-9 * np.max(np.abs(ref[p["seq"]])))
        meta, kernel, _ = read_snapshot(snaps[robot])  # written at SIGTERM, at the last tick processed
        assert meta["robot"] == robot and meta["seq"] >= max(seqs) and kernel
    assert int(rec_b.seq[bad_row]) not in {p["seq"] for p in got["planar4"]}
    # the bad tick raised input_fault on planar4's alarms key, and nothing on ipanema3's
    faults = [(k, a) for k, a in alarms if a["code"] == "input_fault" and a["action"] == "raise"]
    assert faults and all(k == keys("planar4").alarms and a["robot"] == "planar4" for k, a in faults), alarms
    assert not [a for k, a in alarms if k == keys("ipanema3").alarms and a["code"] == "input_fault"]
    out = read_recording(tmp_path / "ipanema3-out.mcap")   # ipanema3's own --record file: its own inputs
    assert out.n_cables == 8 and out.n_ticks >= 300
    np.testing.assert_array_equal(out.motor_length, rec_a.motor_length[: out.n_ticks])


# ---- fleet configs ----------------------------------------------------------------------

def _plan(text: str):
    """What ``cablesvc run --config fleet.toml --no-view`` plans from ``text``."""
    import tomllib
    return plan_fleet(fleet_config(tomllib.loads(text), "fleet.toml"), "fleet.toml", RunOverrides())


def test_fleet_config_errors_name_the_file_and_the_entry(tmp_path: Path):
    rec = tmp_path / "r.mcap"
    write_recording(rec, simulate_recording("ipanema3", "hold-sine", None, duration=0.2, rate=100.0, seed=1))
    p4 = tmp_path / "p4.mcap"
    write_recording(p4, simulate_recording("planar4", "hold-sine", None, duration=0.2, rate=100.0, seed=1))

    def entry(robot: str, path: Path, extra: str = "") -> str:
        return (f"[[robots]]\nrobot = \"{robot}\"\n{extra}\n[robots.source]\nkind = \"replay\"\n"
                f"path = {_toml_str(path)}\nspeed = 0\n")

    shared, plans = _plan("listen = [\"tcp/127.0.0.1:7999\"]\n" + entry("ipanema3", rec) + entry("planar4", p4))
    assert [p.options.robot.name for p in plans] == ["ipanema3", "planar4"] and shared["listen"] == (
        "tcp/127.0.0.1:7999",)
    assert [p.where for p in plans] == ["robots[0]", "robots[1]"]
    assert plans[1].options.source["path"] == str(p4) and plans[1].source is not None
    assert plans[0].options.snapshot is None and plans[1].options.snapshot is None   # replays: no default state file

    cases = [
        (entry("ipanema3", rec) + entry("ipanema3", rec, 'snapshot = "b.npz"'),
         r"^fleet\.toml: robots\[1\]\.robot: robot name 'ipanema3' is already used by robots\[0\]"),
        (entry("ipanema3", rec) + entry("planar4", tmp_path / "missing.mcap"),
         r"^fleet\.toml: robots\[1\]\.source\.path: recording .*missing\.mcap not found"),
        (entry("ipanema3", rec) + entry("planar4", p4, "colour = \"red\""),
         r"^fleet\.toml: robots\[1\]\.colour: unknown key"),
        (entry("ipanema3", rec, 'listen = ["tcp/127.0.0.1:1"]'),
         r"^fleet\.toml: robots\[0\]\.listen: the Zenoh settings are shared"),
        (entry("ipanema3", rec) + "[[robots]]\nrobot = \"planar4\"\n[robots.source]\nkind = \"carrier-pigeon\"\n",
         r"^fleet\.toml: robots\[1\]\.source\.kind: 'carrier-pigeon' is unknown"),
        (entry("ipanema3", rec) + "[[robots]]\nparams = \"x.toml\"\n",
         r"^fleet\.toml: robots\[1\]\.robot: missing"),
        (entry("ipanema3", rec) + entry("nosuchrobot", p4),
         r"^fleet\.toml: robots\[1\]\.robot: .*nosuchrobot"),
        (entry("ipanema3", rec, 'snapshot = "same.npz"') + entry("planar4", p4, 'snapshot = "same.npz"'),
         r"^fleet\.toml: robots\[1\]\.snapshot: .*same\.npz is also robots\[0\]'s snapshot file"),
        ('robot = "ipanema3"\n' + entry("planar4", p4), r"^fleet\.toml: robot: belongs in each \[\[robots\]\] entry"),
        ("robots = []\n", r"^fleet\.toml: robots: expected one or more \[\[robots\]\] tables"),
        ('encoding = "xml"\n' + entry("planar4", p4), r"^fleet\.toml: encoding: expected"),
    ]
    for text, pattern in cases:
        with pytest.raises(FleetConfigError, match=pattern):
            _plan(text)
    # a flag that configures one robot does not apply to a fleet config: one line, exit 1
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(entry("planar4", p4))
    r = subprocess.run([sys.executable, "-m", "cablesvc", "run", "--config", str(cfg), "--no-view", "--replay", str(rec)],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1 and re.search(r"fleet\.toml: --replay configure", r.stderr), r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_the_shipped_fleet_example_is_a_valid_fleet_config():
    """deploy/fleet.example.toml, with the site files it names (parameters, register map)
    swapped for ones in this repository: two robots, the shared Zenoh keys, no error."""
    import tomllib

    example = Path(__file__).resolve().parents[1] / "deploy" / "fleet.example.toml"
    cfg = tomllib.loads(example.read_text())
    for e in cfg["robots"]:
        e.pop("params", None)                      # /etc/cablesvc/...: written by `cablesvc identify` on site
    assert cfg["robots"][1]["source"]["kind"] == "modbus"
    cfg["robots"][1]["source"]["register_map"] = str(example.parents[1] / "robots" / "ipanema3.modbus.toml")
    shared, plans = plan_fleet(fleet_config(cfg, "fleet.example.toml"), "fleet.example.toml", RunOverrides())
    assert shared["listen"] == ("tcp/127.0.0.1:7447",) and shared["encoding"] == "json"
    assert [p.options.robot.name for p in plans] == ["ipanema3", "cogiro"]
    assert [p.options.source["kind"] for p in plans] == ["can", "modbus"]


def test_cli_says_which_robot_cannot_start(tmp_path: Path):
    """One robot's source fails to open: exit 1, one line naming the entry and the robot."""
    p4 = tmp_path / "p4.mcap"
    write_recording(p4, simulate_recording("planar4", "hold-sine", None, duration=0.2, rate=100.0, seed=1))
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(f"""listen = ["tcp/127.0.0.1:{free_tcp_port()}"]
[[robots]]
robot = "planar4"
[robots.source]
kind = "replay"
path = {_toml_str(p4)}
[[robots]]
robot = "ipanema3"
[robots.source]
kind = "can"
interface = "nosuchif"
""")
    r = subprocess.run([sys.executable, "-m", "cablesvc", "run", "--config", str(cfg), "--no-view", "--no-snapshot"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert f"{cfg}: robots[1] (ipanema3): cannot start" in r.stderr and "nosuchif" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


# ---- the Fleet class --------------------------------------------------------------------

def _options(robot: str, source: dict, snapshot: Path | None = None) -> DaemonOptions:
    rob = load_robot(robot)
    return DaemonOptions(robot=rob, params=nominal_params(rob.geometry()), source=source, snapshot=snapshot)


def test_fleet_rejects_duplicate_names_and_closes_what_it_opened_when_a_robot_fails(tmp_path: Path):
    rec = tmp_path / "r.mcap"
    write_recording(rec, simulate_recording("planar4", "hold-sine", None, duration=0.2, rate=100.0, seed=1))
    replay = {"kind": "replay", "path": str(rec), "speed": 0}
    with pytest.raises(FleetError, match=r"robots\[1\]: robot name 'planar4' is already used by robots\[0\]"):
        Fleet([_options("planar4", replay), _options("planar4", replay)], listen=(f"tcp/127.0.0.1:{free_tcp_port()}",))

    port = free_tcp_port()
    snap = tmp_path / "planar4.npz"
    bad_can = {"kind": "can", "interface": "nosuchif", "channel": "x"}
    with pytest.raises(FleetStartError, match=r"robots\[1\] \(ipanema3\): cannot start") as ei:
        Fleet([_options("planar4", replay, snap), _options("ipanema3", bad_can)], listen=(f"tcp/127.0.0.1:{port}",))
    assert ei.value.index == 1 and ei.value.robot == "ipanema3"
    assert snap.exists()                            # planar4's daemon was closed (its final snapshot)
    s = zenoh.open(make_config(listen=(f"tcp/127.0.0.1:{port}",)))   # and the shared session: port free
    s.close()


def test_fleet_runs_each_robot_to_its_own_end_and_closes_in_time(tmp_path: Path):
    """In process: two replays of different lengths; the short one ending does not stop the
    long one; close() writes both snapshots and frees the shared session's port."""
    short, long_ = tmp_path / "s.mcap", tmp_path / "l.mcap"
    write_recording(short, simulate_recording("planar4", "hold-sine", None, duration=0.3, rate=100.0, seed=1))
    write_recording(long_, simulate_recording("ipanema3", "hold-sine", None, duration=1.0, rate=100.0, seed=2))
    port = free_tcp_port()
    snaps = {"planar4": tmp_path / "p.npz", "ipanema3": tmp_path / "i.npz"}
    fleet = Fleet([_options("planar4", {"kind": "replay", "path": str(short), "speed": 1}, snaps["planar4"]),
                   _options("ipanema3", {"kind": "replay", "path": str(long_), "speed": 1}, snaps["ipanema3"])],
                  listen=(f"tcp/127.0.0.1:{port}",))
    try:
        fleet.start()
        end = time.monotonic() + 20
        while time.monotonic() < end and "planar4" in fleet.running():
            time.sleep(0.02)
        assert fleet.running() == ["ipanema3"]     # planar4's replay ended, ipanema3 goes on
        st = fleet.status()
        assert st["planar4"]["ticks"] == 30 and st["planar4"]["fleet"]["running"] is False
        assert st["ipanema3"]["fleet"]["running"] is True
        end = time.monotonic() + 20
        while time.monotonic() < end and fleet.running():
            time.sleep(0.02)
        assert fleet.status()["ipanema3"]["ticks"] == 100
    finally:
        t0 = time.monotonic()
        fleet.close()
        took = time.monotonic() - t0
    assert took < 2.0
    for robot, p in snaps.items():
        assert read_snapshot(p)[0]["robot"] == robot
    s = zenoh.open(make_config(listen=(f"tcp/127.0.0.1:{port}",)))
    s.close()


def test_publishers_sharing_a_session_leave_it_to_its_owner():
    port = free_tcp_port()
    session = zenoh.open(make_config(listen=(f"tcp/127.0.0.1:{port}",)))
    lst = Listener(None, make_config(listen=(), connect=(f"tcp/127.0.0.1:{port}",)))
    try:
        a = Publisher("ra", session=session, status=lambda: {"robot": "ra"})
        b = Publisher("rb", session=session, status=lambda: {"robot": "rb"})
        assert not a.owns_session and not b.owns_session
        end = time.monotonic() + 10
        while time.monotonic() < end and lst.alive() != ["ra", "rb"]:
            time.sleep(0.05)
        assert lst.alive() == ["ra", "rb"]
        a.close()                                   # withdraws ra only; the session stays open
        end = time.monotonic() + 10
        while time.monotonic() < end and lst.alive() != ["rb"]:
            time.sleep(0.05)
        assert lst.alive() == ["rb"]
        assert [s["robot"] for s in lst.statuses()] == ["rb"]
        b.close()
        with pytest.raises(ValueError, match="exactly one of config"):
            Publisher("rc")
    finally:
        lst.close()
        session.close()
