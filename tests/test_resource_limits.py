"""Resource limits of the command line, and the embedded simulator on every shipped robot.

Every command is run as a user runs it (a subprocess, real files, Zenoh on 127.0.0.1):
a rate, step count or duration that would need more memory than the machine has is
refused with one line naming the flag and a non-zero exit, before anything is allocated.
"""

import subprocess
import sys
from pathlib import Path

import pytest

from cablesvc.config import load_robot
from cablesvc.sources import make_dbc
from cablesvc.netutil import free_tcp_port

ROBOTS_DIR = Path(__file__).resolve().parent.parent / "robots"
SHIPPED = sorted(p.stem for p in ROBOTS_DIR.glob("*.toml") if not p.name.endswith(".modbus.toml"))


def cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "cablesvc", *args], capture_output=True, text=True,
                          timeout=timeout)


# ---- the embedded simulator on every robot -------------------------------------------------

@pytest.mark.parametrize("robot", SHIPPED)
@pytest.mark.parametrize("fd", [False, True])
def test_every_robot_ships_its_dbc_files_as_the_generator_writes_them(robot, fd):
    """robots/<robot>.dbc and robots/<robot>-fd.dbc exist for every robot file and are
    exactly what make_dbc writes for it (a robot edited without regenerating them fails)."""
    path = ROBOTS_DIR / f"{robot}{'-fd' if fd else ''}.dbc"
    assert path.is_file(), f"{path.name} missing: write it with cablesvc.sources.make_dbc"
    assert path.read_text() == make_dbc(load_robot(robot), fd)


@pytest.mark.parametrize("robot", SHIPPED)
def test_embedded_simulator_runs_for_every_robot(robot):
    """`cablesvc run --robot R` (the embedded simulated controller on a virtual CAN FD bus)
    runs for a few seconds on every shipped robot, and accepts its ticks."""
    r = cli("run", "--robot", robot, "--no-view", "--no-snapshot", "--seconds", "1.5",
            "--listen", f"tcp/127.0.0.1:{free_tcp_port()}")
    assert r.returncode == 0, r.stderr[-2000:]
    line = next(x for x in r.stderr.splitlines() if "stopped in" in x)
    ticks = int(line.split(" after ")[1].split()[0])
    assert ticks > 500, line
    assert '"rejected": {}' in line, line


# ---- rates, steps and durations -----------------------------------------------------------

def _one_line_refusal(r, *words):
    err = r.stderr.strip()
    assert r.returncode != 0, (r.returncode, err)
    assert "Traceback" not in err and "MemoryError" not in err, err
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err
    return err


@pytest.mark.parametrize("args,words", [
    (("--rate", "1e9"), ("--rate", "memory")),                        # f640b8f: tried to allocate 45 GiB
    (("--duration", "1e9"), ("--duration", "memory")),
    (("--rate", "2e6", "--duration", "30"), ("--rate", "--duration", "memory")),
    (("--rate", "inf"), ("--rate",)),
])
def test_simulate_refuses_a_run_that_cannot_fit_in_memory(tmp_path, args, words):
    out = tmp_path / "x.mcap"
    _one_line_refusal(cli("simulate", "--out", str(out), *args, timeout=60), "cablesvc simulate", *words)
    assert not out.exists()


def test_simulate_within_the_limits_still_runs(tmp_path):
    out = tmp_path / "x.mcap"
    r = cli("simulate", "--out", str(out), "--rate", "5000", "--duration", "0.5", timeout=120)
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 0


@pytest.mark.parametrize("rate", ["1e9", "20000"])
def test_run_refuses_a_sim_rate_beyond_what_the_daemon_can_follow(rate):
    """f640b8f: `run --rate 1e9` tried to allocate 224 GiB and died with a traceback."""
    from cablesvc.limits import MAX_LIVE_RATE_HZ

    err = _one_line_refusal(cli("run", "--rate", rate, "--no-view", "--no-snapshot", "--seconds", "2",
                                "--listen", f"tcp/127.0.0.1:{free_tcp_port()}", timeout=60), "--rate")
    assert str(MAX_LIVE_RATE_HZ) in err


def test_run_refuses_a_config_sim_rate_naming_the_field(tmp_path):
    cfg = tmp_path / "d.toml"
    cfg.write_text('[source]\nkind = "sim"\nrate = 1.0e9\n')
    _one_line_refusal(cli("run", "--config", str(cfg), "--no-view", "--no-snapshot", "--seconds", "2",
                          "--listen", f"tcp/127.0.0.1:{free_tcp_port()}", timeout=60), "source.rate")


@pytest.mark.parametrize("action,args", [
    ("simulate", ("--steps", "1000000000")),                            # f640b8f: traceback / hours
    ("simulate", ("--cycles", "1000000000")),
    ("identify", ("--synthetic", "--steps", "1000000000")),
    ("bridge", ("--elements", "100000000")),
])
def test_beam_refuses_a_run_that_cannot_fit_in_memory(tmp_path, action, args):
    _one_line_refusal(cli("beam", action, *args, timeout=60), f"cablesvc beam {action}", "memory")


def test_memory_estimates_follow_the_sizes():
    from cablesvc.limits import beam_bytes, memory_problem, twin_bytes

    assert beam_bytes(4, 480, 2, 24) == pytest.approx(2 * beam_bytes(4, 240, 2, 24), rel=0.01)
    assert twin_bytes(2000, 8) == 2 * twin_bytes(1000, 8) == 8 * twin_bytes(1000, 2)
    assert memory_problem("x", 1e9, available=4_000_000_000) is None
    assert "x would need about 3 GB" in memory_problem("x", 3e9, available=4_000_000_000)
