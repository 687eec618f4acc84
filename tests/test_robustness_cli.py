"""Bad arguments and configs of `cablesvc run`, `listen` and `simulate`: one clear line on
stderr naming the flag, key or path, a meaningful exit status, never a traceback; and a
`run` whose loop died with an error does not exit 0."""

import subprocess
import sys

import pytest

from cablesvc.netutil import free_tcp_port


def cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "cablesvc", *args], capture_output=True, text=True, timeout=timeout)


def run(*args, timeout=120):
    return cli("run", "--no-view", "--no-snapshot", "--listen", f"tcp/127.0.0.1:{free_tcp_port()}", *args,
               timeout=timeout)


def one_line(r, code, *words):
    assert r.returncode == code, (r.returncode, r.stderr[-2000:])
    assert "Traceback" not in r.stderr, r.stderr[-2000:]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    hit = [ln for ln in lines if all(w in ln for w in words)]
    assert hit, (words, r.stderr[-2000:])


@pytest.mark.parametrize("flag, value", [("--snapshot-interval", "-1"), ("--snapshot-interval", "nan"),
                                         ("--seconds", "nan"), ("--seconds", "-2"), ("--rate", "-100"),
                                         ("--rate", "nan"), ("--rate", "0"), ("--wait-subscriber", "inf")])
def test_run_rejects_bad_numbers(flag, value):
    r = run(flag, value, timeout=30)
    one_line(r, 2, flag, value)


@pytest.mark.parametrize("flag", ["--listen", "--connect"])
def test_run_rejects_bad_endpoints(flag):
    r = run(flag, "bogus", "--seconds", "3", timeout=30)
    one_line(r, 2, flag, "bogus")


def test_run_robot_without_dbc_is_one_line(tmp_path):
    # every shipped robot has its DBC files: a robot file of our own without them
    from pathlib import Path
    text = (Path(__file__).resolve().parent.parent / "robots" / "planar4.toml").read_text()
    robot = tmp_path / "nodbc.toml"
    robot.write_text(text.replace('name = "planar4"', 'name = "nodbc"'))
    r = run("--robot", str(robot), "--seconds", "3", timeout=60)
    one_line(r, 1, "nodbc", "dbc")


CONFIGS = {
    "snapshot_interval = \"x\"\n": "snapshot_interval",
    "snapshot_interval = nan\n": "snapshot_interval",
    "source = 5\n": "source",
    "[source]\nkind = \"sim\"\nbogus = 1\n": "source.bogus",
    "[source]\nkind = \"carrier-pigeon\"\n": "source.kind",
    "[alarms]\nfoo = 1\n": "alarms.foo",
    "robot = 5\n": "robot",
    "params = 5\n": "params",
    "record = 5\n": "record",
    "encoding = \"xml\"\n": "encoding",
    "listen = 5\n": "listen",
    "listen = \"bogus\"\n": "listen",
    "frobnicate = 1\n": "frobnicate",
}


@pytest.mark.parametrize("text", list(CONFIGS))
def test_run_config_errors_name_file_and_key(tmp_path, text):
    cfg = tmp_path / "d.toml"
    cfg.write_text(text)
    r = run("--config", str(cfg), "--seconds", "3", timeout=60)
    one_line(r, 1, "d.toml", CONFIGS[text])


def test_run_config_listen_may_be_one_string(tmp_path):
    """`listen = "tcp/..."` is one endpoint, not a list of characters."""
    port = free_tcp_port()
    cfg = tmp_path / "d.toml"
    cfg.write_text(f'listen = "tcp/127.0.0.1:{port}"\n[source]\nkind = "sim"\nfd = true\n')
    r = cli("run", "--no-view", "--no-snapshot", "--config", str(cfg), "--seconds", "0.5", timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert f"tcp/127.0.0.1:{port}" in r.stderr


def test_run_config_unreadable_files(tmp_path):
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(b'robot = "caf\xe9"\n')
    one_line(run("--config", str(bad), timeout=30), 1, "latin1.toml", "UTF-8")
    one_line(run("--config", str(tmp_path), timeout=30), 1, str(tmp_path), "directory")


def test_run_loop_error_is_not_exit_0():
    """A loop that dies with an error makes `run` exit 1 (as a fleet does), not 0."""
    port = free_tcp_port()
    code = ("import sys, cablesvc.service.daemon as d\n"
            "def boom(self, stop, **kw): raise RuntimeError('loop exploded')\n"
            "d.Daemon.run = boom\n"
            "from cablesvc.cli.main import main\n"
            f"sys.exit(main(['run', '--no-view', '--no-snapshot', '--listen', 'tcp/127.0.0.1:{port}', "
            "'--seconds', '20']))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stderr[-2000:]
    assert "loop exploded" in r.stderr


@pytest.mark.parametrize("args, code, words", [
    (["--connect", "bogus", "--status"], 2, ("--connect", "bogus")),
    (["--zenoh-config", "/nonexistent/z.json5", "--status"], 1, ("/nonexistent/z.json5",)),
    (["--wait", "-1", "--status"], 2, ("--wait", "-1")),
    (["--wait", "nan", "--alive"], 2, ("--wait", "nan")),
    (["--robot", "a/b", "--status"], 2, ("--robot", "a/b")),
])
def test_listen_bad_arguments(args, code, words):
    one_line(cli("listen", *args, timeout=30), code, *words)


def test_simulate_out_in_missing_directory(tmp_path):
    out = tmp_path / "nonexistent" / "o.csv"
    r = cli("simulate", "--duration", "0.1", "--out", str(out), timeout=60)
    one_line(r, 2, str(out))
    assert not out.parent.exists()


def test_identify_and_discover_take_the_robot_the_recording_names_and_say_when_there_is_none(tmp_path):
    """Without --robot, both commands use the robot of the recording's metadata; a CSV
    without a '# robot:' line is one line naming the file and the robots there are (it
    was 'robot file : 1 problem / no robot named ''' from identify, and discover asked for
    --robot even when the recording named it)."""
    from cablesvc.recording import write_recording
    from cablesvc.simulate import simulate_recording
    rec = simulate_recording("planar4", "trajectory", duration=10.0, rate=100.0, seed=1)
    named = tmp_path / "named.csv"
    write_recording(named, rec)
    bare = tmp_path / "bare.csv"
    bare.write_text("".join(ln for ln in named.read_text().splitlines(keepends=True) if not ln.startswith("# robot")))
    for cmd in ("identify", "discover"):
        one_line(cli(cmd, str(bare)), 1, str(bare), "names no robot", "--robot", "planar4")
    r = cli("discover", str(named), "--json")
    assert r.returncode == 0, r.stderr[-2000:]
    assert '"robot": "planar4"' in r.stdout
