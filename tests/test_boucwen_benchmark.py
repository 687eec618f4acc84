"""Bouc-Wen benchmark (issue 4): the benchmark's simulation reproduced, lanes, band-limited
input reconstruction, MATLAB-style decimation, sensitivities, and a short identification
on generated data, plus the ``cablesvc bench boucwen --json`` output.

The official test outputs are used here only to check the simulator with the published
parameters (finding how the benchmark simulated), never to estimate anything."""

import hashlib
import io
import json
import re
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import firwin, lfilter

from cablesvc.identify.boucwen_benchmark import (
    DEFAULT_DATA, SYNTHETIC_PRESETS, IdentifyOptions, ParamSpace, estimate_noise, evaluate, generate_benchmark_data, identify,
    load_benchmark, rmse, simulate_test_multisine, simulate_test_sweep, simulate_train,
)
from cablesvc.simulate.oscillator import (
    BENCHMARK_TRUTH, PARAM_NAMES, as_theta, bandlimited_upsample, decimate, decimate_fir, simulate, simulate_fine,
)

#: The official benchmark data ship with the package (cablesvc/data/boucwen): these tests
#: always run, in a clone too (issue 18).
OFFICIAL = DEFAULT_DATA


@pytest.fixture(scope="module")
def official():
    return load_benchmark(OFFICIAL)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A small benchmark-like data set (nu = 2): 3 periods of 1024 samples, short sweep."""
    d = tmp_path_factory.mktemp("bw_small")
    generate_benchmark_data(d, SYNTHETIC_PRESETS["nu2"], seed=3, periods=3, n_period=1024, sweep_samples=6000)
    return d


# ---- the benchmark's simulation ----------------------------------------------------------

def test_official_multisine_test_output_reproduced(official):
    """Published parameters -> steady-state period of the official multisine test output
    to rounding level (Newmark 1/4-1/2 + trapezoidal z at 15 kHz, FFT input, decimate 2-2-5)."""
    y = simulate_test_multisine(official.ms_u, as_theta(BENCHMARK_TRUTH))[0]
    assert rmse(y, official.ms_y) < 1e-13
    # the first (transient) period is not the test output: the steady state matters
    y0 = simulate(official.ms_u, as_theta(BENCHMARK_TRUTH), periods=1, tail=20, keep=slice(0, 8192))[0][0]
    assert rmse(y0, official.ms_y) > 1e-6


def test_official_sweep_test_output_reproduced(official):
    """The sweep was decimated in ONE decimate(y, 20, 'fir'); the input comes from its
    samples by band-limited reconstruction. Decimating 2-2-5 like the multisines is 100
    times worse already over the first 40000 samples (2.3e-6 m over the whole sweep)."""
    th = as_theta(BENCHMARK_TRUTH)
    y = simulate_test_sweep(official.sw_u, th)[0]
    assert rmse(y, official.sw_y) < 2e-9
    n = 40000
    y_fine = simulate_fine(bandlimited_upsample(official.sw_u[:n], 20, periodic=False), 1 / 15000, th)[0]
    ref = official.sw_y[: n - 10]
    assert rmse(decimate(y_fine, (20,))[0, : n - 10], ref) < 2e-9
    assert rmse(decimate(y_fine, (2, 2, 5))[0, : n - 10], ref) > 2e-7


def test_official_train_residual_is_the_noise(official):
    """With the published parameters the training residual is the stated noise (~8e-6 m
    band-limited; 7.4e-6 m measured) and matches the period-to-period noise estimate."""
    y = simulate_train(official.train_u[:8192], as_theta(BENCHMARK_TRUTH))[0][0]
    r = rmse(y, official.train_y)
    sigma = estimate_noise(official.train_y, 8192)
    assert 6e-6 < r < 8.5e-6
    assert abs(sigma / r - 1) < 0.05


# ---- building blocks -------------------------------------------------------------------

def test_lanes_identical_to_single_runs():
    rng = np.random.default_rng(0)
    u = bandlimited_upsample(50 * rng.standard_normal(600), 4)
    base = np.array([BENCHMARK_TRUTH[n] for n in PARAM_NAMES])
    th = np.array([base, base * [1.1, 0.8, 1.2, 0.9, 1.3, 0.7, 1.0], [3.5, 25, 2e4, 8e4, 30, 12, 2.0],
                   [1.2, 6, 6e4, 4e4, 150, -60, 1.5], base, [3.5, 25, 2e4, 8e4, 30, 12, 2.0]])
    y, dy, ok = simulate_fine(u, 1 / 3000, th, sensitivities=True)      # 6 lanes: threaded path
    assert ok.all()
    for i in range(th.shape[0]):
        y1, dy1, _ = simulate_fine(u, 1 / 3000, th[i], sensitivities=True)
        np.testing.assert_array_equal(y[i], y1[0])
        np.testing.assert_array_equal(dy[i], dy1[0])
    np.testing.assert_array_equal(y[0], y[4])
    assert not np.array_equal(y[0], y[1])


def test_sensitivities_match_finite_differences():
    rng = np.random.default_rng(1)
    u = bandlimited_upsample(50 * rng.standard_normal(400), 5)
    for p in ([2, 10, 5e4, 5e4, 800, -1100, 1.0], [1.2, 6, 6e4, 4e4, 150, -60, 1.5]):
        th = np.array([p], float)
        _, dy, _ = simulate_fine(u, 1 / 3750, th, sensitivities=True)
        for j in range(7):
            e = 1e-6 * abs(th[0, j])
            tp, tm = th.copy(), th.copy()
            tp[0, j] += e
            tm[0, j] -= e
            fd = (simulate_fine(u, 1 / 3750, tp)[0] - simulate_fine(u, 1 / 3750, tm)[0]) / (2 * e)
            assert np.max(np.abs(fd[0] - dy[0, j])) < 1e-5 * np.max(np.abs(dy[0, j])), (p, j)


def test_bandlimited_reconstruction_exact_for_periodic_bandlimited_signal():
    N, r = 512, 20
    rng = np.random.default_rng(2)
    k = np.arange(1, 100)                       # lines well below Nyquist (256)
    a, ph = rng.standard_normal(k.size), rng.uniform(0, 2 * np.pi, k.size)
    t_fine = np.arange(N * r) / (N * r)
    x_fine = (a[:, None] * np.cos(2 * np.pi * k[:, None] * t_fine + ph[:, None])).sum(0)
    up = bandlimited_upsample(x_fine[::r], r, periodic=True)
    np.testing.assert_allclose(up, x_fine, rtol=0, atol=1e-12 * np.abs(x_fine).max())
    # non-periodic (sweep-like) record: windowed sinc on the reflected extension
    n = 3000
    tf = np.arange(n * r) / (750.0 * r)
    sweep = 40 * np.sin(2 * np.pi * (18 * tf + tf ** 2 / 12))
    up = bandlimited_upsample(sweep[::r], r, periodic=False)
    assert up.size == sweep.size
    inner = slice(100 * r, (n - 100) * r)
    assert np.max(np.abs(up[inner] - sweep[inner])) < 1e-5 * 40
    assert np.max(np.abs(up[: (n - 1) * r + 1] - sweep[: (n - 1) * r + 1])) < 1e-2 * 40


def _matlab_decimate_reference(x, r, nfilt=30):
    """Literal transcription of the steps of MATLAB's decimate 'fir' branch with filter
    states (filter over the mirrored head, then the data, then the mirrored tail)."""
    b = firwin(nfilt + 1, 1.0 / r)
    nd = x.size
    nf = nfilt + 1
    head = 2 * x[0] - x[nf:0:-1]
    _, zi = lfilter(b, 1, head, zi=np.zeros(nfilt))
    odata, zf = lfilter(b, 1, x, zi=zi)
    tail = 2 * x[-1] - x[nd - 2:nd - 2 - 2 * nf:-1]
    itemp, _ = lfilter(b, 1, tail, zi=zf)
    gd = nfilt / 2
    lst = np.arange(int(round(gd + 1.25)), nd + 1, r)       # 1-based as in MATLAB
    out = odata[lst - 1]
    nout = -(-nd // r)
    nlen = nout - out.size
    nbeg = r - (nd - lst[-1])
    return np.concatenate([out, itemp[nbeg - 1:nbeg - 1 + nlen * r:r]])


def test_decimate_fir_matches_matlab_steps():
    x = np.random.default_rng(3).standard_normal(1000).cumsum()
    for r in (2, 5, 20, 25):
        for n in (1000, 997):
            np.testing.assert_allclose(decimate_fir(x[:n], r), _matlab_decimate_reference(x[:n], r),
                                       rtol=0, atol=1e-12)


def test_param_space_round_trip_and_jacobian():
    sp = ParamSpace()
    th = np.array([1.2, 6, 6e4, 4e4, 150, -60, 1.5])
    q = sp.to_q(th)
    np.testing.assert_allclose(sp.to_theta(q), th, rtol=1e-12)
    J = sp.dtheta_dq(q)
    for j in range(7):
        e = np.zeros(7)
        e[j] = 1e-6
        fd = (sp.to_theta(q + e) - sp.to_theta(q - e)) / 2e-6
        np.testing.assert_allclose(J[:, j], fd, rtol=1e-6, atol=1e-9 * np.abs(J).max())
    # the default box does not contain its own centre at the published values
    centre = sp.to_theta(0.5 * (sp.qlb + sp.qub))
    truth = np.array([BENCHMARK_TRUTH[n] for n in PARAM_NAMES])
    assert np.all(np.abs(np.log(np.abs(centre[:4] / truth[:4]))) > 0.3)


# ---- generated data and identification -------------------------------------------------

def test_generated_data_follow_the_benchmark_procedure(small):
    d = load_benchmark(small)
    th = as_theta(d.truth)
    assert d.period == 1024 and d.train_u.size == 3072 and d.sw_u.size == 6000
    assert rmse(simulate_test_multisine(d.ms_u, th)[0], d.ms_y) < 1e-13
    assert rmse(simulate_test_sweep(d.sw_u, th)[0], d.sw_y) < 1e-8
    sigma = estimate_noise(d.train_y, d.period)
    assert 0.8 < sigma / 8e-6 < 1.2
    assert 0.9 < rmse(simulate_train(d.train_u[:1024], th, periods=3)[0][0], d.train_y) / 8e-6 < 1.1


def test_short_identification_recovers_parameters(small):
    """nu = 2 data, a small swarm from the default wide box: parameters within a few
    standard errors, test RMSE below the 1e-6 m target."""
    d = load_benchmark(small)
    opt = IdentifyOptions(seed=0, pso_samples=1024, particles=12, iterations=15, starts=6)
    res = identify(d.train_u, d.train_y, options=opt, period=d.period)
    truth = np.array([d.truth[n] for n in PARAM_NAMES])
    z = (res.x - truth) / res.stderr
    assert np.all(np.abs(z) < 4), dict(zip(PARAM_NAMES, z))
    assert np.all(np.abs(res.x / truth - 1) < 0.05)
    scores = evaluate(res.x, d)
    assert scores["rmse_multisine"] < 1e-6 and scores["rmse_sinesweep"] < 1e-6
    assert 0.9 < res.rms_residual / 8e-6 < 1.1


def test_bench_json_output(small):
    from cablesvc.bench.boucwen import main

    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = main(["--data", str(small), "--json", "--seed", "1", "--particles", "10", "--iterations", "10"])
    assert rc == 0
    out = json.loads(buf.getvalue())
    for key in ("rmse_multisine", "rmse_sinesweep", "seconds", "params", "stderr", "truth", "met"):
        assert key in out
    assert set(out["params"]) == set(PARAM_NAMES)
    assert out["truth"]["nu"] == 2.0
    assert out["rmse_multisine"] < 1e-6 and out["rmse_sinesweep"] < 1e-6
    assert 0 < out["seconds"] < 120


# ---- the vendored data (issue 18: a clone stands alone) -----------------------------------

def test_default_data_is_the_vendored_official_benchmark(monkeypatch):
    """With no path and no $CABLESVC_BOUCWEN_DATA the official files are read from inside
    the installed package, complete (train, multisine test, sine sweep test)."""
    import cablesvc

    monkeypatch.delenv("CABLESVC_BOUCWEN_DATA", raising=False)
    d = load_benchmark()
    assert Path(cablesvc.__file__).resolve().parent in d.path.resolve().parents
    assert d.fs == 750.0 and d.period == 8192
    assert d.train_u.shape == d.train_y.shape == (40960,)
    assert d.ms_u.shape == d.ms_y.shape == (8192,)
    assert d.sw_u.shape == d.sw_y.shape == (153000,)


def test_vendored_files_match_the_checksums_in_their_readme():
    """The data README records the sha256 of each file as received: a re-export, a
    truncated copy or a Git LFS pointer in place of the data fails here."""
    readme = (DEFAULT_DATA / "README.md").read_text()
    sums = dict((name, h) for h, name in re.findall(r"\b([0-9a-f]{64})\s+(\S+\.h5)\b", readme))
    assert set(sums) == {"train.h5", "test.h5"}
    for name, h in sums.items():
        assert hashlib.sha256((DEFAULT_DATA / name).read_bytes()).hexdigest() == h, name
    assert "Licence" in readme and "10.4121/12967592" in readme


@pytest.mark.parametrize("content", [None, b"not hdf5", "empty-group"], ids=["missing", "not-hdf5", "no-multisine"])
def test_bench_bad_data_directory_is_one_line_error(tmp_path, capsys, content):
    """``bench boucwen --data DIR`` with no/garbled/wrong train.h5: exit 1 and one line on
    stderr naming the file, not a traceback."""
    from cablesvc.bench.boucwen import main

    if content == "empty-group":
        import h5py
        with h5py.File(tmp_path / "train.h5", "w") as f:
            f.create_group("other")
    elif content is not None:
        (tmp_path / "train.h5").write_bytes(content)
    rc = main(["--data", str(tmp_path), "--json"])
    err = capsys.readouterr().err
    assert rc == 1
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("cablesvc bench boucwen: ") and str(tmp_path / "train.h5") in err
    assert "Traceback" not in err
