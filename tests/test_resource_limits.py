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
from cablesvc.sources.controller import free_tcp_port

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
    r = cli("run", "--robot", robot, "--no-view", "--no-snapshot", "--seconds", "3",
            "--listen", f"tcp/127.0.0.1:{free_tcp_port()}")
    assert r.returncode == 0, r.stderr[-2000:]
    line = next(x for x in r.stderr.splitlines() if "stopped in" in x)
    ticks = int(line.split(" after ")[1].split()[0])
    assert ticks > 500, line
    assert '"rejected": {}' in line, line
