"""Cable models identified from simulated recordings, the CLI and the 002 Sec 4 bench.

The truth parameters come from the objects the tests build (or, where noted, are read
back only to score); identification itself sees the recording only."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cablesvc.bench.cable_experiment import effective_values, experiment_truth, run_cable_experiment
from cablesvc.cli.main import main
from cablesvc.config import load_robot
from cablesvc.config.params import load_params
from cablesvc.identify.amplitude_levels import damping_regressor, level_trace, segment_levels, simulate_amplitude
from cablesvc.models.reversal import reversal_amplitude, reversal_points
from cablesvc.models import AmplitudeDependent
from cablesvc.identify.cable import IdentifyError, cable_data, identify_cable
from cablesvc.recording import write_recording
from cablesvc.simulate import TruthConfig, simulate_recording

ROBOT = "planar4"
HOLD = dict(rate=500.0, frequency=1.0, settle=0.5, rest=0.5)


@pytest.fixture(scope="module")
def amp_truth():
    return experiment_truth(ROBOT)


@pytest.fixture(scope="module")
def hold_rec(amp_truth):
    return simulate_recording(ROBOT, "hold-sine", truth=TruthConfig(base=amp_truth, noise_std=0.1), seed=3,
                              amplitudes=[5e-4, 1e-3, 1.5e-3], **HOLD)


def test_segment_levels_finds_the_amplitude_levels(hold_rec):
    d = cable_data(hold_rec, ROBOT, [1])
    lv = segment_levels(d.x[:, 0], d.t)
    assert [round(v.amplitude * 1e4, 6) for v in lv] == [5.0, 10.0, 15.0]
    assert all(v.half_period == pytest.approx(0.5) for v in lv)
    assert all(v.reversals.size >= 5 for v in lv)
    # a reversal is the sample where the motion turns
    x = np.array([0, 1, 2, 3, 2, 1, 0, 1, 2, 2, 2, 1], float)
    assert reversal_points(x, 0.5).tolist() == [3, 6, 10]


def test_segment_levels_with_a_measured_pose_that_carries_micrometres_of_noise(hold_rec):
    """5 um of noise on the elongation (a measured, not commanded, pose) made a reversal of
    every wiggle, and `cablesvc identify` stopped with 'no amplitude level left to fit';
    the threshold now rises above the noise and the same levels are found."""
    d = cable_data(hold_rec, ROBOT, [1])
    x = d.x[:, 0] + 5e-6 * np.random.default_rng(2).standard_normal(d.x.shape[0])
    lv = segment_levels(x, d.t)
    assert [round(v.amplitude * 1e4) for v in lv] == [5, 10, 15]
    assert all(v.half_period == pytest.approx(0.5, abs=0.02) for v in lv)


def test_reversal_amplitude_is_known_from_the_sample_that_confirms_the_turn():
    x = np.array([0, 1, 2, 3, 2, 1, 0, 1, 2, 2, 2, 1], float)
    ext, seen = reversal_points(x, 0.5, confirmed=True)
    assert ext.tolist() == [3, 6, 10] and seen.tolist() == [4, 7, 11]
    # |0 - 3| / 2 from sample 7 on, |2 - 0| / 2 from sample 11; nothing before two turns
    expect = [0.0] * 7 + [1.5] * 4 + [1.0]
    assert reversal_amplitude(x, 0.5).tolist() == expect
    # columns are cables; a mirrored cable has the same amplitude
    np.testing.assert_array_equal(reversal_amplitude(np.c_[x, -x], 0.5), np.c_[expect, expect])
    # no samples, or one: no reversal, the input's shape
    assert reversal_amplitude(np.zeros(0)).shape == (0,) and reversal_amplitude(np.zeros((0, 3))).shape == (0, 3)
    assert reversal_amplitude(np.ones((1, 2))).tolist() == [[0.0, 0.0]]


@pytest.mark.parametrize("quantum", [1e-8, 1e-7])
def test_offline_reversal_amplitude_equals_the_live_models_estimate(quantum):
    """Discovery's amplitude signal and the amplitude model's online A follow one rule:
    on a noisy, bus-quantised sine whose amplitude steps, they agree sample for sample once
    the live estimator is past its start (it assumes rising motion and an initial A)."""
    rng = np.random.default_rng(7)
    dt = 1e-3
    t = np.arange(12_000) * dt
    amp = np.where(t < 6.0, 4e-4, 1.1e-3)
    x = 2e-3 - amp * np.cos(2 * np.pi * 0.5 * t) + rng.normal(0, 5e-8, t.size)
    x = np.round(x / quantum) * quantum
    deadband = 1e-6
    model = AmplitudeDependent((1, 1), amplitudes=[1e-4, 2e-3], K0=60.0, K1=2e5, reversal_deadband=deadband)
    state = model.create_state(x[:1].reshape(1, 1))
    live = np.empty(t.size)
    live[0] = state.memory[1, 0, 0]
    for k in range(1, t.size):
        model.step(state, x[k].reshape(1, 1), dt)
        live[k] = state.memory[1, 0, 0]
    offline = reversal_amplitude(x, deadband)
    _, seen = reversal_points(x, deadband, confirmed=True)
    assert seen.size == 11                                  # 2 turns a cycle (6 cycles), no noise turns
    after = seen[2]
    np.testing.assert_allclose(live[after:], offline[after:], rtol=1e-12, atol=0)
    # and both are the true amplitudes, within the noise on the extremes
    assert offline[seen[4]] == pytest.approx(4e-4, rel=1e-3)
    assert offline[-1] == pytest.approx(1.1e-3, rel=1e-3)


def test_identify_linear_from_short_recording():
    rec = simulate_recording(ROBOT, "hold-sine", truth=TruthConfig(base_model="linear", noise_std=0.1), seed=4,
                             amplitudes=[5e-4, 1e-3], **HOLD)
    ea_true = load_robot(ROBOT).geometry().ea          # the linear truth uses the robot's E*A
    fit = identify_cable(rec, ROBOT, "linear", cables=[0, 3], seed=1, iterations=15)
    assert fit.params.model == "linear"
    for j, c in enumerate([0, 3]):
        r = fit.results[j]
        assert r.x[0] == pytest.approx(ea_true[c], rel=2e-3)
        assert abs(r.x[0] - ea_true[c]) <= 4 * r.stderr[0]
    assert np.all(fit.rmse < 0.11)
    assert len(fit.swarm) == 2 and fit.swarm[0].history.size == 16
    ea = np.asarray(fit.params.params["ea"])
    assert ea.shape == (4,) and ea[1] == ea_true[1]                  # cables not fitted keep the nominal
    shared = identify_cable(rec, ROBOT, "linear", cables=[0, 1, 2, 3], shared=True, method="lm")
    assert len(shared.results) == 1
    assert shared.results[0].x[0] == pytest.approx(ea_true[0], rel=2e-3)


def test_identify_amplitude_model_recovers_truth(hold_rec, amp_truth):
    fit = identify_cable(hold_rec, ROBOT, "amplitude", cables=[0, 2])
    assert fit.amplitude is not None and len(fit.amplitude.fits) == 3
    assert np.all(fit.rmse < 0.13)
    for A in (5e-4, 1e-3, 1.5e-3):
        tv = effective_values(amp_truth, 4, A)
        iv = effective_values(fit.params, 4, A)
        rel = {k: np.abs(iv[k][[0, 2]] - tv[k][[0, 2]]) / np.abs(tv[k][[0, 2]]) for k in tv}
        assert np.all(rel["K0"] < 1e-3) and np.all(rel["K1"] < 0.01), (A, rel)
        assert np.all(rel["S_a"] < 0.02) and np.all(rel["K2"] < 0.05) and np.all(rel["K3"] < 0.05), (A, rel)
        if A >= 1e-3:
            assert np.all(rel["alpha"] < 0.05), (A, rel)
    xc_true = np.asarray(amp_truth.params["x_center"])[[0, 2]]
    assert np.allclose(fit.amplitude.x_center, xc_true, rtol=1e-6)
    # per-level standard errors cover the truth at the largest level
    lt = fit.amplitude.level_table(0)
    tv = effective_values(amp_truth, 4, lt["A"][-1])
    for k in ("K0", "K1", "S_a", "alpha"):
        assert abs(lt[k][-1] - tv[k][0]) <= 4 * lt[k + "_se"][-1], k


def test_identify_errors_are_clear(hold_rec):
    with pytest.raises(IdentifyError, match="out of range"):
        identify_cable(hold_rec, ROBOT, "linear", cables=[4])
    with pytest.raises(IdentifyError, match="unknown model"):
        identify_cable(hold_rec, ROBOT, "spline")
    with pytest.raises(IdentifyError, match="cables"):
        identify_cable(hold_rec, "ipanema3", "linear")


def test_cli_writes_loadable_params_and_report(tmp_path, hold_rec):
    rec_path = tmp_path / "hold.mcap"
    write_recording(rec_path, hold_rec)
    out = tmp_path / "params.toml"
    rep = tmp_path / "report"
    code = main(["identify", "--model", "amplitude", "--robot", ROBOT, str(rec_path), "--cables", "1",
                 "--out", str(out), "--report", str(rep), "--quiet"])
    assert code == 0
    p = load_params(out)
    assert p.model == "amplitude" and p.robot == ROBOT
    model = p.build(4, 1)                                    # what cablesvc run --params builds
    assert model.shape == (1, 4)
    assert p.identification["cables"] == [1]
    # the elongations the backbone was fitted on (levels up to 1.5 mm about x_center) are
    # written for the fitted cable; the others keep no limit
    lo, hi = np.asarray(p.params["xi_lo"]), np.asarray(p.params["xi_hi"])
    assert -1.6e-3 < lo[1] < -1.4e-3 and 1.4e-3 < hi[1] < 1.6e-3, (lo, hi)
    assert np.all(lo[[0, 2, 3]] == -1.0) and np.all(hi[[0, 2, 3]] == 1.0)
    assert np.allclose(model.params["xi_lo"][0], lo) and np.allclose(model.params["xi_hi"][0], hi)
    text = (rep / "report.md").read_text()
    pngs = sorted(f.name for f in rep.glob("*.png"))
    assert pngs == ["convergence.png", "loops_cable1.png", "residuals.png"]
    for n in pngs:
        assert f"]({n})" in text
        assert (rep / n).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # linear model through the CLI, least squares only
    out2 = tmp_path / "lin.toml"
    assert main(["identify", "--model", "linear", str(rec_path), "--cables", "0,2", "--method", "lm",
                 "--out", str(out2), "--quiet"]) == 0
    assert load_params(out2).model == "linear"


def test_cli_errors_exit_1(tmp_path, hold_rec, capsys):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    assert main(["identify", "--model", "linear", str(bad), "--quiet"]) == 1
    assert "cannot read the recording" in capsys.readouterr().err
    good = tmp_path / "hold.mcap"
    write_recording(good, hold_rec)
    assert main(["identify", "--model", "spline", str(good), "--quiet"]) == 1
    assert "unknown model" in capsys.readouterr().err
    assert main(["identify", "--model", "linear", str(good), "--cables", "0,9", "--quiet"]) == 1
    assert "out of range" in capsys.readouterr().err
    assert main(["identify", "--model", "linear", str(good), "--method", "annealing", "--quiet"]) == 1
    assert "unknown method" in capsys.readouterr().err
    # the defaults: model amplitude, method pso+lm, seed 0 (what the parameter file records);
    # a short swarm, since only the defaults not given are checked here
    short = ["--particles", "8", "--iterations", "5"]
    out = tmp_path / "defaults.toml"
    assert main(["identify", str(good), "--cables", "0", "--out", str(out), "--quiet", *short]) == 0
    p = load_params(out)
    assert p.model == "amplitude", p.model
    out = tmp_path / "defaults_linear.toml"
    assert main(["identify", "--model", "linear", str(good), "--cables", "0", "--out", str(out), "--quiet",
                 *short]) == 0
    p = load_params(out)
    assert p.identification["method"] == "pso+lm" and p.identification["seed"] == 0, p.identification


def test_cable_experiment_bench_small():
    """A reduced 002 Sec 4 experiment: one cable, 0.75 mm held out."""
    res = run_cable_experiment(ROBOT, cables=[0], rate=500.0, frequency=1.0, cycles=3,
                               fit_levels=(2.5e-4, 5e-4, 1e-3, 1.5e-3), held_out=7.5e-4)
    json.dumps(res)
    assert res["levels_found_mm"] == pytest.approx([0.25, 0.5, 1.0, 1.5])
    assert res["held_out_rmse_max_n"] <= 0.11
    assert res["max_rel_err"]["K0"] < 0.02 and res["max_rel_err"]["K1"] < 0.02
    assert res["met"]["held_out_rmse"] and res["met"]["determined_params_within_2pct"]
    # the joint fit: constant truth K2, K3 come out constant, the f_A follow the truth over the range
    assert res["f_A_degrees_cable0"]["K2"] == 0 and res["f_A_degrees_cable0"]["K3"] == 0
    assert res["f_A_degrees_cable0"]["K1"] >= 1
    assert res["f_A_range_max_rel_err"]["K1"] < 0.01 and res["f_A_range_max_rel_err"]["S_a"] < 0.03
    s = res["sensitivity_table1_truth_cable0"]["1.5 mm"]
    assert 0.8 < s["K1"] < 1.1 and s["K3"] < s["K1"] and s["K2"] < s["K1"]


def test_bench_parser_registers_cable_experiment():
    import argparse

    from cablesvc.bench import cable_experiment
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="bench")
    cable_experiment.add_parser(sub)
    args = p.parse_args(["cable-experiment", "--json", "--cycles", "4"])
    assert args.json and args.cycles == 4 and args.func is cable_experiment.cmd_cable_experiment


def test_damping_regressor_is_the_kernel_damping():
    """The trace-based damping regressor equals the kernel model's damping force per unit S_a."""
    dt = 1e-3
    t = np.arange(2001) * dt
    x = np.stack([1e-3 - 5e-4 * np.cos(2 * np.pi * t), 2e-3 - 1e-4 * np.cos(2 * np.pi * t)], axis=1)
    xc, A, Th = np.array([1e-3, 2e-3]), np.array([5e-4, 1e-4]), np.array([0.5, 0.5])
    rising = np.array([True, True])
    base, pref = level_trace(x, dt, xc, A, Th, rising)
    for alpha in (0.0, 0.3, 1.7):
        vals = {k: np.zeros((1, 2)) for k in ("K0", "K1", "K2", "K3", "S_a", "alpha")}
        vals["S_a"][:] = 1.0
        vals["alpha"][:] = alpha
        kern = simulate_amplitude(x, dt, vals, xc, A, Th, rising)[:, 0, :]
        mine = damping_regressor(base, pref, alpha)
        assert np.allclose(mine, kern, rtol=1e-10, atol=1e-12 * np.abs(kern).max())
        D, dD = damping_regressor(base, pref, alpha + 0.1, derivative=True)
        h = 1e-6
        fd = (damping_regressor(base, pref, alpha + 0.1 + h) - damping_regressor(base, pref, alpha + 0.1 - h)) / (2 * h)
        assert np.allclose(dD, fd, rtol=1e-5, atol=1e-8 * np.abs(fd).max())


def test_joint_fit_selects_forms_and_keeps_held_out_out(hold_rec, amp_truth):
    from cablesvc.identify.amplitude_fit import fit_amplitude_model
    d = cable_data(hold_rec, ROBOT, [0, 2])
    af = fit_amplitude_model(d.t, d.x, d.force, cables=d.cables, hold_out=[1e-3])
    assert [round(float(np.median(f.amplitude)) * 1e4, 6) for f in af.fits] == [5.0, 15.0]   # 1 mm never fitted
    assert af.held_out and abs(af.held_out[0] - 1e-3) < 1e-5
    for c in range(2):
        fn = af.functions[c]
        assert fn["K0"].degree == 0 and fn["K2"].degree == 0 and fn["K3"].degree == 0
        assert af.joint[c]["forms"] == {k: fn[k].degree for k in ("K1", "K2", "K3", "S_a", "alpha")}
        # the joint fit's standard error of f_A at a level is finite and positive
        se = fn["K1"].stderr([5e-4, 1.5e-3])
        assert np.all(np.isfinite(se)) and np.all(se > 0)
    # K1 at the held-out 1 mm level, predicted by the f_A fitted on 0.5 and 1.5 mm only
    tv = effective_values(amp_truth, 4, 1e-3)
    k1 = np.array([af.functions[c]["K1"](1e-3) for c in range(2)])
    assert np.all(np.abs(k1 - tv["K1"][[0, 2]]) / tv["K1"][[0, 2]] < 0.01)


def test_backbone_curvature_enters_only_when_the_data_show_it(hold_rec, amp_truth):
    """K2 and K3 start absent (held at 0) and enter through the same score test as any
    further degree: a calibration of a cable without curvature gives none (a K3 fitted on
    +-1.5 mm and extrapolated to the centimetres of a trajectory is hundreds of newtons of
    nothing), one with it gives it back (the existing recovery test holds)."""
    import dataclasses
    from cablesvc.identify.amplitude_fit import fit_amplitude_model
    flat_tables = dict(amp_truth.tables)
    n = len(flat_tables["amplitudes"])
    m = len(flat_tables["K1"])
    flat_tables["K2"] = [[0.0] * n for _ in range(m)]
    flat_tables["K3"] = [[0.0] * n for _ in range(m)]
    flat = dataclasses.replace(amp_truth, tables=flat_tables)
    rec = simulate_recording(ROBOT, "hold-sine", truth=TruthConfig(base=flat, noise_std=0.1), seed=3,
                             amplitudes=[5e-4, 1e-3, 1.5e-3], **HOLD)
    d = cable_data(rec, ROBOT, [0, 2])
    af = fit_amplitude_model(d.t, d.x, d.force, cables=d.cables)
    for c in range(2):
        fn = af.functions[c]
        assert fn["K2"].degree == -1 and fn["K3"].degree == -1, {k: fn[k].degree for k in fn}
        assert fn["K3"](2e-2) == 0.0 and fn["K2"].coef.size == 0
    # the same cables with curvature: both enter
    d2 = cable_data(hold_rec, ROBOT, [0, 2])
    af2 = fit_amplitude_model(d2.t, d2.x, d2.force, cables=d2.cables)
    assert all(af2.functions[c][k].degree >= 0 for c in range(2) for k in ("K2", "K3"))


def test_residual_inflation_counts_serial_correlation():
    from cablesvc.identify.amplitude_joint import residual_inflation
    rng = np.random.default_rng(0)
    white = [rng.standard_normal(5000) for _ in range(3)]
    assert 0.95 < residual_inflation(white) < 1.06
    rho = 0.9
    pieces = []
    for _ in range(3):
        e = rng.standard_normal(20000)
        x = np.empty_like(e)
        x[0] = e[0]
        for i in range(1, e.size):
            x[i] = rho * x[i - 1] + e[i]
        pieces.append(x)
    assert abs(residual_inflation(pieces) / ((1 + rho) / (1 - rho)) - 1.0) < 0.1
    # anti-correlated residuals keep the plain test (rho floored at 0)
    alt = [np.tile([1.0, -1.0], 1000)]
    assert residual_inflation(alt) == 1.0


def _bench_calibration(wave: str):
    """A calibration recording of the realistic bench's robot 0 (fleet 161803, Bouc-Wen
    truth law: a rate-independent loop): platform clamped at home, each winch in turn,
    six levels of ``wave`` (002 Sec 4: hold_sine or hold_triangle)."""
    from cablesvc.bench import discover_cases as dc
    from cablesvc.kinematics import inverse_kinematics
    from cablesvc.recording import Recording
    from cablesvc.simulate import scenarios
    from cablesvc.simulate.twin import Ambient
    rob = load_robot(dc.ROBOT)
    geom = rob.geometry()
    variant = dc.robot_variant(0, 161803, 1.0, geom, "boucwen")
    ctx = scenarios.ScenarioContext(geom=geom, rate=dc.RATE, duration=None, rng=np.random.default_rng([5, 1]),
                                    elastic=dc._nominal_elastic(geom))
    plan = getattr(scenarios, wave)(ctx, amplitudes=dc.CAL_AMPLITUDES, mode="sequential")
    ml = inverse_kinematics(geom, plan.position, plan.orientation).length - plan.elongation
    temp = Ambient().profile(plan.t, np.random.default_rng([5, 2]))
    eq = dc.equilibrium_run(geom, variant, [], [], t=plan.t, dt=1.0 / dc.RATE, position=plan.position,
                            orientation=plan.orientation, motor_length=ml, temperature=temp, balance=False)
    force = eq.measured + dc.NOISE * np.random.default_rng([5, 3]).standard_normal(eq.measured.shape)
    return rob, Recording(robot=rob.name, metadata={}, t=plan.t, seq=np.arange(plan.t.size), motor_length=ml,
                          position=plan.position, orientation=plan.orientation, force=force, temperature=temp)


def test_a_damping_rate_law_no_level_shows_is_held_rate_independent():
    """A triangle wave's speed is constant within a level, so |v|^alpha is one constant that
    S_a takes and no level tells alpha: fitted anyway, alpha(A) went to its bound 3 at the
    small amplitudes, and the identified model's damping force, (|v| T / (pi A))^alpha S_a q / A,
    ran to 83 and 248 N RMS on two cables of this very calibration when a cable next moved
    after a long hold (T the time since its last reversal). Held at 0 (a rate-independent
    loop, what this truth law has), the model fits its own calibration to the noise."""
    from cablesvc.identify.amplitude_levels import _alpha_unidentified
    assert _alpha_unidentified(np.array([10.0, 10.001, 10.002]), 1000)          # flat within chi2(1)
    assert not _alpha_unidentified(np.array([10.0, 10.2, 11.0]), 1000)         # 0.2 / (10 / 994) = 20 > 3.84
    rob, rec = _bench_calibration("hold_triangle")
    fit = identify_cable(rec, rob, "amplitude")
    assert np.all(np.asarray(fit.rmse) < 0.15), fit.rmse
    assert all(np.all(np.asarray(fit.params.tables["alpha"][c]) == 0.0) for c in range(8))
    assert all(np.all(np.asarray(r["levels"]["alpha"]) == 0.0) for r in fit.results)
    # a sine calibration of the same robot tells alpha at its larger levels (its speed goes
    # through every value of a cycle; at 0.1 mm the loop is too small to tell it either):
    # alpha(A) is fitted there as before
    fit_sine = identify_cable(_bench_calibration("hold_sine")[1], rob, "amplitude")
    assert np.all(np.asarray(fit_sine.rmse) < 0.25)
    for c, r in enumerate(fit_sine.results):
        assert np.all(np.asarray(r["levels"]["alpha"])[-3:] > 0.0)
        assert np.any(np.asarray(fit_sine.params.tables["alpha"][c]) > 0.0)
