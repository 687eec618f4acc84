"""Robustness of robot files and of the beam / bench kernel / identify CLIs.

Bad robot files give one message per problem naming the file and the field; bad CLI
arguments give one line on stderr naming the option or path, a meaningful exit code and
no traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cablesvc.config import RobotFileError, load_robot

REPO = Path(__file__).resolve().parents[1]
REPO_ROBOTS = REPO / "robots"

BASE = """\
format = 1
name = "base4"

[frame]
anchors = [[2.0, 2.0, 3.0], [-2.0, 2.0, 3.0], [-2.0, -2.0, 0.0], [2.0, -2.0, 0.0]]

[platform]
anchors = [[0.1, 0.1, 0.1], [-0.1, 0.1, 0.1], [-0.1, -0.1, -0.1], [0.1, -0.1, -0.1]]
mass = 5.0

[cable]
diameter = 0.004
ea = 1.0e5
force_min = 5.0
force_max = 2000.0
"""

PLANAR = """\
format = 1
name = "planar_t"
planar = true

[frame]
anchors = [[1.0, 1.0, 0.0], [-1.0, 1.0, 0.0], [-1.0, -1.0, 0.0], [1.0, -1.0, 0.0]]

[platform]
anchors = [[0.05, 0.05, 0.0], [-0.05, 0.05, 0.0], [-0.05, -0.05, 0.0], [0.05, -0.05, 0.0]]
mass = 2.0

[cable]
diameter = 0.001
ea = 2.0e4
force_min = 1.0
force_max = 200.0
"""


def _problems(tmp_path: Path, text: str) -> list[str]:
    f = tmp_path / "r.toml"
    f.write_text(text)
    with pytest.raises(RobotFileError) as ei:
        load_robot(f)
    assert all(str(f) in p for p in ei.value.problems)
    return ei.value.problems


def _subprocess_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    env = dict(os.environ, COLUMNS="200")
    return subprocess.run([sys.executable, "-m", "cablesvc", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


@pytest.fixture
def cli(capsys):
    """``cablesvc ARGS...`` in this process (fast): a CompletedProcess-like result. An
    uncaught exception (a traceback for the user) propagates and fails the test."""
    from cablesvc.cli.main import main

    def run(*args: str) -> subprocess.CompletedProcess:
        capsys.readouterr()
        try:
            code = main(list(args))
        except SystemExit as e:          # argparse errors
            code = e.code if isinstance(e.code, int) else 1
        out = capsys.readouterr()
        return subprocess.CompletedProcess(list(args), code, out.out, out.err)
    return run


def _one_line_error(r: subprocess.CompletedProcess, code: int, *needles: str) -> str:
    assert r.returncode == code, (r.returncode, r.stdout, r.stderr)
    err = r.stderr.strip()
    assert "Traceback" not in r.stderr + r.stdout, r.stderr
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("usage:")
             and not ln.startswith(" ")]
    assert len(lines) == 1, err
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


# ---- robot files -------------------------------------------------------------------------


def test_shipped_robots_still_load():
    for name in ("ipanema3", "cogiro", "planar4"):
        load_robot(REPO_ROBOTS / f"{name}.toml")


@pytest.mark.parametrize("bad", ["a/b c*", "x y", "r/1", "r*", "a$b", "q?", "h#1"])
def test_robot_name_must_be_a_key_chunk(tmp_path, bad):
    probs = _problems(tmp_path, BASE.replace('name = "base4"', f'name = "{bad}"'))
    assert len(probs) == 1, probs
    assert ": name: " in probs[0] and "letters, digits" in probs[0]


def test_robot_name_allowed_characters(tmp_path):
    f = tmp_path / "r.toml"
    f.write_text(BASE.replace('name = "base4"', 'name = "Robot_2.v-1"'))
    assert load_robot(f).name == "Robot_2.v-1"


def test_robots_check_rejects_bad_name(tmp_path):
    f = tmp_path / "r.toml"
    f.write_text(BASE.replace('name = "base4"', 'name = "a/b c*"'))
    r = _subprocess_cli("robots", "check", str(f))
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert "name:" in r.stdout + r.stderr


def test_messages_show_single_braces(tmp_path):
    probs = _problems(tmp_path, BASE + "\n[[cables]]\npulley = true\n")
    msg = next(p for p in probs if "cables[0].pulley" in p)
    assert "{center=" in msg and "{{" not in msg and "}}" not in msg
    probs = _problems(tmp_path, BASE + '\n[pulley]\nradius = 0.02\naxis = {x = 1}\n')
    msg = next(p for p in probs if "pulley.axis" in p)
    assert "{'x': 1}" in msg and "{{" not in msg


def test_duplicate_resolved_cable_names(tmp_path):
    # cable 0 has the default name "cable0", cable 1 is named "cable0"
    probs = _problems(tmp_path, BASE + '\n[[cables]]\n\n[[cables]]\nname = "cable0"\n')
    assert len(probs) == 1, probs
    assert "cables[1].name" in probs[0] and "'cable0'" in probs[0] and "duplicate" in probs[0]
    # cable 0 is named like the (unnamed) cable 2's default: the named one is blamed
    probs = _problems(tmp_path, BASE + '\n[[cables]]\nname = "cable2"\n')
    assert len(probs) == 1, probs
    assert "cables[0].name" in probs[0] and "'cable2'" in probs[0] and "cable 2" in probs[0]
    # two explicit names
    probs = _problems(tmp_path, BASE + '\n[[cables]]\nname = "a"\n[[cables]]\nname = "a"\n')
    assert len(probs) == 1 and "cables[1].name" in probs[0]


def test_empty_cable_name_rejected(tmp_path):
    probs = _problems(tmp_path, BASE + '\n[[cables]]\nname = ""\n')
    assert len(probs) == 1, probs
    assert "cables[0].name" in probs[0] and "empty" in probs[0]


def test_planar_cable_pulley_without_defaults_names_the_cable(tmp_path):
    probs = _problems(tmp_path, PLANAR + "\n[[cables]]\npulley = {radius = 0.02}\n")
    assert len(probs) == 1, probs
    assert "cables[0].pulley.axis" in probs[0] and "vertical" in probs[0]
    # with a [pulley] default whose axis is vertical, the default is blamed
    probs = _problems(tmp_path, PLANAR + "\n[pulley]\nradius = 0.02\n\n[[cables]]\npulley = {radius = 0.03}\n")
    assert any(": pulley.axis:" in p for p in probs), probs
    assert not any("cables[0].pulley.axis" in p for p in probs), probs


# ---- bench kernel ------------------------------------------------------------------------


def test_bench_kernel_short_run():
    from cablesvc.bench.kernel import run_kernel_bench
    for ticks in (1, 100, 700):
        res = run_kernel_bench("planar4", ticks=ticks, inputs=("normal", "slack"))
        assert [r.input for r in res] == ["normal", "slack", "machine"]
        assert all(r.ticks == ticks for r in res)


def test_bench_kernel_cli_short_ticks(cli):
    r = cli("bench", "kernel", "--robot", "planar4", "--ticks", "100", "--input", "normal", "--json")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("args,needle", [
    (["--ticks", "0"], "--ticks"),
    (["--ticks", "-5"], "--ticks"),
    (["--model", "boucwen"], "boucwen"),
    (["--cpu", "-1"], "-1"),
    (["--cpu", "100000"], "100000"),
])
def test_bench_kernel_bad_arguments(cli, args, needle):
    r = cli("bench", "kernel", "--robot", "planar4", "--input", "normal", "--json", *args)
    assert r.returncode in (1, 2), (r.returncode, r.stderr)
    _one_line_error(r, r.returncode, needle)


# ---- beam ---------------------------------------------------------------------------------


@pytest.mark.parametrize("action,args,needle", [
    ("simulate", ["--length", "0"], "--length"),
    ("simulate", ["--length", "-75"], "--length"),
    ("simulate", ["--steps", "0"], "--steps"),
    ("simulate", ["--cycles", "0"], "--cycles"),
    ("simulate", ["--elements", "0"], "--elements"),
    ("simulate", ["--amplitude", "0"], "--amplitude"),
    ("simulate", ["--amplitude", "-5"], "--amplitude"),
    ("simulate", ["--amplitude", "nan"], "--amplitude"),
    ("identify", ["--synthetic", "--amplitude", "0"], "--amplitude"),
    ("identify", ["--synthetic", "--particles", "0"], "--particles"),
    ("bridge", ["--ropes", "0"], "--ropes"),
    ("bridge", ["--length", "-1"], "--length"),
])
def test_beam_bad_numbers_are_argparse_errors(cli, action, args, needle):
    r = cli("beam", action, *args)
    _one_line_error(r, 2, needle)


def test_beam_identify_bad_data_files(cli, tmp_path):
    r = cli("beam", "identify", "--data", str(tmp_path / "nonexistent.csv"))
    _one_line_error(r, 2, "--data", "nonexistent.csv")
    one = tmp_path / "one.csv"
    one.write_text("t,x,f\n0.0,0.001,1.0\n")
    r = cli("beam", "identify", "--data", str(one))
    _one_line_error(r, 2, "--data", str(one))
    two = tmp_path / "two.csv"
    two.write_text("t,x\n" + "".join(f"{k * 0.01},{k * 1e-4}\n" for k in range(5)))
    r = cli("beam", "identify", "--data", str(two))
    _one_line_error(r, 2, "--data", str(two), "3 columns")
    junk = tmp_path / "junk.csv"
    junk.write_text("t,x,f\n1,2,abc\n")
    r = cli("beam", "identify", "--data", str(junk))
    _one_line_error(r, 2, "--data", str(junk))


def test_beam_output_paths_checked_first(cli, tmp_path):
    r = cli("beam", "bridge", "--write", str(tmp_path / "nonexistent" / "x.toml"))
    _one_line_error(r, 2, "--write", "nonexistent")
    afile = tmp_path / "afile"
    afile.write_text("x")
    r = cli("beam", "simulate", "--out", str(afile))
    _one_line_error(r, 2, "--out", str(afile))


# ---- identify -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def short_rec(tmp_path_factory):
    from cablesvc.simulate import simulate_recording
    p = tmp_path_factory.mktemp("rec") / "h.mcap"
    simulate_recording("planar4", "hold-sine", p, rate=200.0, duration=2.0)
    return p


def test_identify_out_folder_missing(cli, short_rec, tmp_path):
    out = tmp_path / "nonexistent" / "x.toml"
    r = cli("identify", str(short_rec), "--model", "linear", "--method", "lm", "--quiet", "--out", str(out))
    _one_line_error(r, 1, "--out", str(out))
    assert "wrote" not in r.stdout and "parameters" not in r.stdout    # checked before the fit


def test_identify_report_is_a_file(cli, short_rec, tmp_path):
    afile = tmp_path / "hostname"
    afile.write_text("x")
    r = cli("identify", str(short_rec), "--model", "linear", "--method", "lm", "--quiet", "--report", str(afile))
    _one_line_error(r, 1, "--report", str(afile), "not a directory")
    r = cli("identify", str(short_rec), "--model", "linear", "--method", "lm", "--quiet",
             "--report", str(afile / "sub"))
    _one_line_error(r, 1, "--report", str(afile))
