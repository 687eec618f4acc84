"""The one command line, run as users run it (subprocesses, real files)."""

import subprocess
import sys

import numpy as np

from cablesvc.recording import read_recording


def cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "cablesvc", *args], capture_output=True, text=True, timeout=timeout)


def test_help_lists_commands():
    r = cli("--help")
    assert r.returncode == 0
    for cmd in ("run", "simulate", "robots", "bench"):
        assert cmd in r.stdout


def test_simulate_writes_a_readable_recording(tmp_path):
    out = tmp_path / "rec.mcap"
    r = cli("simulate", "--robot", "ipanema3", "--scenario", "hold-sine", "--duration", "2", "--effect",
            "viscous@1,4", "--out", str(out))
    assert r.returncode == 0, r.stderr
    rec = read_recording(out)
    assert rec.robot == "ipanema3" and rec.n_cables == 8 and rec.n_ticks == 2000
    assert rec.has_force and rec.has_pose
    assert np.all(np.diff(rec.seq) == 1)


def test_robots_check_reports_every_problem(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('format = 1\nname = "x"\n[frame]\nanchors = [[0, 0]]\n')
    r = cli("robots", "check", str(bad))
    assert r.returncode == 1
    assert "bad.toml" in r.stderr and "frame.anchors[0]" in r.stderr and "platform" in r.stderr


def test_run_embedded_default_runs_and_stops_cleanly():
    """`cablesvc run` as the README runs it (simulated controller on virtual CAN, Zenoh peer),
    here on a free port and for a few seconds."""
    from cablesvc.netutil import free_tcp_port

    r = cli("run", "--no-view", "--no-snapshot", "--seconds", "2", "--listen", f"tcp/127.0.0.1:{free_tcp_port()}")
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stderr.splitlines() if "stopped in" in x)
    ticks = int(line.split(" after ")[1].split()[0])
    assert ticks > 500, line
    assert '"rejected": {}' in line, line


def test_run_view_shows_an_alarm_raised_before_any_tick():
    """With the terminal view on (the default) and a bus that never sends, input_lost is
    raised before the first tick, so its `since` is null: the view shows "-" and the daemon
    runs its time and exits 0."""
    from cablesvc.netutil import free_tcp_port

    r = cli("run", "--robot", "ipanema3", "--source", "can", "--interface", "virtual", "--channel", "cablesvc-silent",
            "--no-snapshot", "--seconds", "1.5", "--listen", f"tcp/127.0.0.1:{free_tcp_port()}")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "view failed" not in r.stderr
    assert "input_lost" in r.stdout
    line = next(x for x in r.stderr.splitlines() if "stopped in" in x)
    assert "after 0 ticks" in line


def test_run_rejects_flags_of_another_source():
    r = cli("run", "--source", "replay", "--host", "1.2.3.4")
    assert r.returncode != 0 and "--host does not apply to --source replay" in r.stderr


def test_run_start_up_failures_are_one_clear_line(tmp_path):
    """A Zenoh port already taken and an unknown CAN interface: exit 1, no traceback."""
    import socket

    from cablesvc.netutil import free_tcp_port

    rec = tmp_path / "r.mcap"
    assert cli("simulate", "--scenario", "hold-sine", "--duration", "0.5", "--out", str(rec)).returncode == 0
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = cli("run", "--source", "replay", "--replay", str(rec), "--no-view", "--no-snapshot",
                "--listen", f"tcp/127.0.0.1:{port}")
    assert r.returncode == 1
    assert "cannot open the Zenoh session" in r.stderr and str(port) in r.stderr and "Traceback" not in r.stderr
    r = cli("run", "--source", "can", "--interface", "nosuchif", "--no-view", "--no-snapshot",
            "--listen", f"tcp/127.0.0.1:{free_tcp_port()}")
    assert r.returncode == 1
    assert "source.interface" in r.stderr and "nosuchif" in r.stderr and "Traceback" not in r.stderr


def test_only_cablesvc_bench_builds_the_benchmarks_parsers():
    """A command other than ``bench`` parses without importing the benchmark modules (they
    pull in numpy, the robot model and the simulator: about a third of a second of start-up),
    and ``cablesvc bench`` still has every benchmark."""
    code = ("import sys\n"
            "from cablesvc.cli.main import main\n"
            "rc = main(sys.argv[1:])\n"
            "print('BENCH', sorted(m for m in sys.modules if m.startswith('cablesvc.bench')))\n")
    out = subprocess.run([sys.executable, "-c", code, "robots", "list"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "BENCH []" in out.stdout
    out = subprocess.run([sys.executable, "-m", "cablesvc", "bench", "--help"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    for name in ("kernel", "e2e", "soak", "alarms", "discover", "fleet", "read", "live-discovery", "discover-scale"):
        assert f"    {name} " in out.stdout or f"    {name}\n" in out.stdout, name
