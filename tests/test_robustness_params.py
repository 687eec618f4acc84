"""Bad parameter files: one clear message per problem naming the file and the field, never a
traceback and never a value accepted that later breaks the kernel."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cablesvc
from cablesvc.config.params import ModelParams, ParamFileError, load_params
from cablesvc.models import AmplitudeDependent, ModelParameterError
from cablesvc.models.boucwen import BoucWen
from cablesvc.models.polynomial import PolynomialHysteresis

AMP_TABLES = """
[tables]
amplitudes = [1e-4, 5e-4, 1.5e-3]
K0 = [0.0, 0.0, 0.0]
K1 = [1.5e4, 1.5e4, 1.5e4]
S_a = [1e-4, 1e-3, 1e-2]
alpha = [0.3, 0.3, 0.3]
"""
BW_PARAMS = """
[params]
k_e = 1e4
k_d = 1e4
beta = 1.0
gamma = 0.5
n = 1.0
f0 = 60.0
"""


def _write(tmp_path: Path, name: str, text: str) -> Path:
    f = tmp_path / name
    f.write_text(text)
    return f


def _load_error(f: Path) -> str:
    """Load and build (8 cables) f; it must fail with a ParamFileError naming the file."""
    with pytest.raises(ParamFileError) as e:
        load_params(f).build(8)
    msg = str(e.value)
    assert f.name in msg
    return msg


def _amp(params: str = "", ident: str = "") -> str:
    return 'format = 1\nmodel = "amplitude"\n' + (f"[params]\n{params}\n" if params else "") + AMP_TABLES + (
        f"\n[identification]\n{ident}\n" if ident else "")


# -- 1. amplitude model: omega_init / amplitude_init -------------------------------------------------

@pytest.mark.parametrize("line", ["omega_init = 0", "omega_init = -1", "omega_init = [1.0, 1, 1, 1, 0, 1, 1, 1]",
                                  "amplitude_init = 0", "amplitude_init = -5e-4"])
def test_amplitude_init_values_must_be_positive(tmp_path, line):
    name = line.split()[0]
    msg = _load_error(_write(tmp_path, "amp.toml", _amp(line)))
    assert f"params.{name}" in msg and "> 0" in msg


def test_amplitude_init_values_checked_in_memory_and_by_the_model():
    tabs = {"amplitudes": [1e-4, 1e-3], "K0": [0.0, 0.0], "K1": [1e4, 1e4]}
    with pytest.raises(ParamFileError, match="params.omega_init: must be > 0"):
        ModelParams(model="amplitude", params={"omega_init": 0.0}, tables=tabs).build(8)
    with pytest.raises(ModelParameterError, match="omega_init must be > 0"):
        AmplitudeDependent((1, 2), omega_init=0.0, **tabs)
    with pytest.raises(ModelParameterError, match="amplitude_init must be > 0"):
        AmplitudeDependent((1, 2), amplitude_init=-1e-3, **tabs)
    AmplitudeDependent((1, 2), omega_init=2.0, amplitude_init=1e-3, **tabs)      # valid values still build


def test_bench_kernel_cli_rejects_zero_omega_init(tmp_path):
    f = _write(tmp_path, "omega0.toml", _amp("omega_init = 0"))
    root = Path(cablesvc.__file__).resolve().parents[1]      # where the robots/ folder is
    out = subprocess.run([sys.executable, "-m", "cablesvc", "bench", "kernel", "--params", str(f), "--ticks", "300",
                          "--json"], capture_output=True, text=True, timeout=300, cwd=root, env=dict(os.environ))
    assert out.returncode != 0
    assert "Traceback" not in out.stderr
    assert "omega0.toml" in out.stderr and "params.omega_init" in out.stderr
    for line in out.stdout.splitlines():         # nothing NaN published
        assert "NaN" not in line and json.loads(line) is not None


# -- 2. Bouc-Wen options.substeps / options.integrator ------------------------------------------------

@pytest.mark.parametrize("value", ['"x"', "0", "-2", "true", "2.5", '"4"'])
def test_boucwen_substeps_invalid(tmp_path, value):
    f = _write(tmp_path, "bw.toml", f'format = 1\nmodel = "boucwen"\n[options]\nsubsteps = {value}\n' + BW_PARAMS)
    msg = _load_error(f)
    assert "options.substeps" in msg and "integer >= 1" in msg


def test_boucwen_substeps_and_integrator_valid_and_model_level(tmp_path):
    f = _write(tmp_path, "bw.toml", 'format = 1\nmodel = "boucwen"\n[options]\nsubsteps = 3\nintegrator = "rk4"\n'
               + BW_PARAMS)
    m = load_params(f).build(8)
    assert m.integrator.substeps == 3 and m.integrator.integrator == "rk4"
    bad = _write(tmp_path, "bwi.toml", 'format = 1\nmodel = "boucwen"\n[options]\nintegrator = 5\n' + BW_PARAMS)
    assert "options.integrator" in _load_error(bad)
    with pytest.raises(ModelParameterError, match="substeps must be an integer"):
        BoucWen(k_e=1.0, k_d=1.0, beta=1.0, gamma=0.5, substeps="x")
    with pytest.raises(ParamFileError, match="options.substeps"):
        ModelParams(model="boucwen", params={"k_e": 1, "k_d": 1, "beta": 1, "gamma": 1},
                    options={"substeps": "x"}).build(8)


# -- 3. identification.amplitude_range --------------------------------------------------------------

@pytest.mark.parametrize("value", ['"x"', "[1e-4]", "[nan, 1.5e-3]", "[1e-4, inf]", "[1.5e-3, 1e-4]",
                                   "[-1e-4, 1e-3]", '[1e-4, "a"]', "[1e-4, 1e-3, 2e-3]", "[true, 1e-3]", "[0, 0]"])
def test_amplitude_range_invalid(tmp_path, value):
    f = _write(tmp_path, "amp.toml", _amp(ident=f"amplitude_range = {value}"))
    with pytest.raises(ParamFileError) as e:
        load_params(f)           # at load, not at run start-up
    msg = str(e.value)
    assert "amp.toml" in msg and "identification.amplitude_range" in msg


def test_amplitude_range_valid(tmp_path):
    f = _write(tmp_path, "amp.toml", _amp(ident="amplitude_range = [1e-4, 1.5e-3]"))
    assert load_params(f).amplitude_range() == (1e-4, 1.5e-3)
    # one amplitude level (lo = hi) is what identification writes for a single level
    f = _write(tmp_path, "amp1.toml", _amp(ident="amplitude_range = [1e-3, 1e-3]"))
    assert load_params(f).amplitude_range() == (1e-3, 1e-3)


# -- 4. polynomial degree, empty amplitude tables, booleans ------------------------------------------

@pytest.mark.parametrize("value", ['"x"', "2", "0", "true", "3.0"])
def test_polynomial_degree_invalid(tmp_path, value):
    f = _write(tmp_path, "poly.toml", f'format = 1\nmodel = "polynomial"\n[options]\ndegree = {value}\n')
    msg = _load_error(f)
    assert "options.degree" in msg and "odd integer" in msg
    assert "not supported" not in msg


def test_polynomial_degree_valid_and_model_level(tmp_path):
    f = _write(tmp_path, "poly.toml", 'format = 1\nmodel = "polynomial"\n[options]\ndegree = 5\n[params]\na1 = 1.0e4\na5 = 1.0\n')
    assert load_params(f).build(8).degree == 5
    with pytest.raises(ModelParameterError, match="degree must be an odd integer"):
        PolynomialHysteresis(degree="x")


def test_amplitude_empty_tables(tmp_path):
    f = _write(tmp_path, "amp.toml", 'format = 1\nmodel = "amplitude"\n[tables]\namplitudes = []\n')
    msg = _load_error(f)
    assert "tables.amplitudes" in msg and "tables.K0: required" in msg and "tables.K1: required" in msg
    assert "__init__" not in msg
    with pytest.raises(ParamFileError, match="tables.K1: required") as e:
        ModelParams(model="amplitude", tables={"amplitudes": [1e-3], "K0": [0.0]}).build(8)
    assert "__init__" not in str(e.value)


@pytest.mark.parametrize("text,field", [
    ('format = 1\nmodel = "linear"\n[params]\nea = true\n', "params.ea"),
    ('format = 1\nmodel = "linear"\n[params]\nea = [1e5, 1e5, 1e5, true, 1e5, 1e5, 1e5, 1e5]\n', "params.ea"),
    ('format = true\nmodel = "linear"\n[params]\nea = 1e5\n', "format"),
    ('format = 1.0\nmodel = "linear"\n[params]\nea = 1e5\n', "format"),
    ('format = 1\nmodel = "amplitude"\n[tables]\namplitudes = [1e-4, 1e-3]\nK0 = [0.0, 0.0]\nK1 = [true, 1e4]\n',
     "tables.K1"),
])
def test_booleans_are_not_numbers(tmp_path, text, field):
    f = _write(tmp_path, "b.toml", text)
    msg = _load_error(f)
    assert f"  - {field}:" in msg


def test_every_problem_listed_once(tmp_path):
    f = _write(tmp_path, "many.toml", 'format = true\nmodel = "amplitude"\n[params]\nomega_init = 0\n'
               'amplitude_init = -1\n' + AMP_TABLES + "\n[identification]\namplitude_range = [1e-4]\n")
    msg = _load_error(f)
    for field in ("format", "params.omega_init", "params.amplitude_init", "identification.amplitude_range"):
        assert msg.count(f"  - {field}:") == 1, msg


def test_valid_files_still_load(tmp_path):
    f = _write(tmp_path, "ok.toml", _amp("omega_init = 3.0\namplitude_init = [5e-4, 5e-4, 5e-4, 5e-4, 5e-4, 5e-4, "
                                         "5e-4, 5e-4]", "amplitude_range = [1e-4, 1.5e-3]"))
    m = load_params(f).build(8)
    assert np.allclose(m.params["omega_init"], 3.0)
