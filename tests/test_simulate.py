"""Digital twin (cablesvc.simulate): scenarios, truth model, effects, recordings."""

import json

import numpy as np
import pytest

from cablesvc.config.params import default_params
from cablesvc.kinematics import inverse_kinematics, platform_wrench, structure_matrix
from cablesvc.models import loop_area, simulate
from cablesvc.recording import read_recording
from cablesvc.simulate import (
    EFFECTS,
    SCENARIOS,
    Creep,
    OffsetGain,
    Pulley,
    SimulationError,
    TruthConfig,
    effect_from_spec,
    list_effects,
    simulate_recording,
    simulate_twin,
)

RATE = 1000.0
NOISE = 0.1  # the default sensor noise the visibility criterion refers to [N]
# a short hold-sine: one 1 mm block of 2 cycles at 2 Hz, 2 s in all
SHORT_HOLD = dict(amplitudes=[1e-3], cycles=2, frequency=2.0, settle=0.3, rest=0.2)


def quiet(*effects, **kw):
    return TruthConfig(noise_std=0.0, effects=list(effects), **kw)


@pytest.fixture(scope="module")
def hold_base(robot):
    return simulate_twin(robot, "hold-sine", truth=quiet(), **SHORT_HOLD)


@pytest.fixture(scope="module")
def traj_base(robot):
    return simulate_twin(robot, "trajectory", truth=quiet(), duration=6.0, seed=2)


def elongation_of(rec, geom):
    """x = l(pose) - motor_length, recomputed from the recording alone."""
    return inverse_kinematics(geom, rec.position, rec.orientation).length - rec.motor_length


# ---- hold scenarios -------------------------------------------------------------------

def test_hold_sine_is_the_base_model_on_the_recorded_elongation(robot):
    geom = robot.geometry()
    amps = [1e-4, 5e-4, 1.5e-3]
    run = simulate_twin(robot, "hold-sine", truth=quiet(), amplitudes=amps, cycles=2, frequency=1.25,
                        settle=0.5, rest=0.2)
    rec = run.recording
    x = elongation_of(rec, geom)
    # base model rebuilt independently: nominal amplitude model for EA and the home lengths
    L_home = inverse_kinematics(geom, np.zeros(3), np.array([0, 0, 0, 1.0])).length[0]
    model = default_params(geom.ea, L_home, "amplitude").build(geom.n_cables, 1)
    expected = simulate(model, x[:, None, :], 1.0 / RATE, l0=rec.motor_length[:, None, :])[:, 0, :]
    np.testing.assert_array_equal(rec.force, expected)

    n = run.plan.info["samples_per_cycle"]
    assert n == 800
    blocks = run.plan.info["blocks"]
    assert [b["amplitude"] for b in blocks] == amps
    for b in blocks:
        s, e = b["start"], b["stop"]
        xb = x[s:e + 1]
        # requested amplitude on every cable (all excited together by default)
        np.testing.assert_allclose((xb.max(0) - xb.min(0)) / 2, b["amplitude"], rtol=0, atol=1e-9)
        # pretension 60 N: mean over whole cycles once the model has seen two reversals
        mean = rec.force[s + n:e].mean(0)
        assert np.all(np.abs(mean - 60.0) < 0.5), (b["amplitude"], mean)
    # position held
    assert np.ptp(rec.position, axis=0).max() == 0.0


@pytest.mark.parametrize("scenario", ["hold-triangle", "hold-trapezoid"])
def test_hold_shapes(robot, scenario):
    run = simulate_twin(robot, scenario, truth=quiet(), amplitudes=[2.5e-4, 1e-3], cycles=2, frequency=2.0,
                        settle=0.3, rest=0.1, mode="sequential", cables=[2])
    x = elongation_of(run.recording, robot.geometry())
    n = run.plan.info["samples_per_cycle"]
    for b in run.plan.info["blocks"]:
        s, e = b["start"], b["stop"]
        xb = x[s:e + 1, 2]
        assert (xb.max() - xb.min()) / 2 == pytest.approx(b["amplitude"], abs=1e-9)
        if scenario == "hold-triangle":   # constant speed 4 A f between the corners
            v = np.abs(np.diff(xb)) * RATE
            assert np.median(v) == pytest.approx(4 * b["amplitude"] * 2.0, rel=1e-6)
        else:                             # holds at the top and bottom: many samples at the extremes
            assert np.mean(np.isclose(xb, xb.max(), atol=1e-12, rtol=0)) > 0.2
        assert abs(run.recording.force[s + n:e, 2].mean() - 60.0) < 0.5
    # sequential on cable 2 only: the other cables hold still, at the pretension
    others = np.delete(x, 2, axis=1)
    assert np.ptp(others, axis=0).max() < 1e-12
    assert np.abs(np.delete(run.recording.force, 2, axis=1) - 60.0).max() < 0.05


def test_hysteresis_in_default_truth_and_not_in_linear_base(robot):
    areas = {}
    for base in ("amplitude", "linear"):
        run = simulate_twin(robot, "hold-sine", truth=quiet(base_model=base), **SHORT_HOLD)
        b = run.plan.info["blocks"][0]
        n = run.plan.info["samples_per_cycle"]
        sl = slice(b["stop"] - n, b["stop"])           # last full cycle
        areas[base] = loop_area(run.elongation[sl, 0], run.recording.force[sl, 0])
        assert json.loads(run.recording.metadata["truth"])["base"]["model"] == base
    # nominal loss factor 0.1: S_a = 0.1 pi K1 A^2 ~ 4 mJ at 1 mm; the linear cable has none
    assert areas["amplitude"] > 2e-3
    assert abs(areas["linear"]) < 1e-3 * areas["amplitude"]


# ---- effects: right cables, visible, off at 0 ------------------------------------------

@pytest.mark.parametrize("name", sorted(EFFECTS))
def test_effect_acts_on_exactly_the_chosen_cables(robot, hold_base, name):
    chosen = [1, 6]
    F0 = hold_base.recording.force
    run = simulate_twin(robot, "hold-sine", truth=quiet(EFFECTS[name](cables=chosen)), **SHORT_HOLD)
    d = run.recording.force - F0
    rms = np.sqrt(np.mean(d ** 2, axis=0))
    assert np.all(rms[chosen] > 4 * NOISE), (name, rms)
    others = [i for i in range(8) if i not in chosen]
    np.testing.assert_array_equal(d[:, others], 0.0)
    # magnitude 0 switches it off entirely
    off = simulate_twin(robot, "hold-sine", truth=quiet(EFFECTS[name](magnitude=0.0, cables=chosen)),
                        **SHORT_HOLD)
    np.testing.assert_array_equal(off.recording.force, F0)
    truth = json.loads(run.recording.metadata["truth"])
    assert [(e["name"], e["cables"]) for e in truth["effects"]] == [(name, chosen)]


def test_deadtime_shifts_the_force_by_tau(robot, hold_base):
    tau = 0.0375  # 37.5 ticks
    run = simulate_twin(robot, "hold-sine", truth=quiet(effect_from_spec(f"deadtime:{tau}@0")), **SHORT_HOLD)
    b = hold_base.plan.info["blocks"][0]
    s, e = b["start"], b["stop"] - 200
    f0 = hold_base.recording.force[:, 0]
    f1 = run.recording.force[:, 0]
    lags = np.arange(0, 200)
    # cross-correlation over a fixed window of the undelayed force (no overlap bias)
    xc = [np.corrcoef(f0[s:e], f1[s + k:e + k])[0, 1] for k in lags]
    assert abs(lags[int(np.argmax(xc))] - tau * RATE) <= 1.0
    np.testing.assert_array_equal(run.recording.force[:, 1:], hold_base.recording.force[:, 1:])


def test_viscous_adds_cv_times_rate(robot, hold_base):
    cv = 800.0
    run = simulate_twin(robot, "hold-sine", truth=quiet(effect_from_spec(f"viscous:{cv}")), **SHORT_HOLD)
    x = elongation_of(run.recording, robot.geometry())
    v = np.vstack([np.zeros((1, 8)), np.diff(x, axis=0) * RATE])
    np.testing.assert_allclose(run.recording.force - hold_base.recording.force, cv * v, rtol=0, atol=1e-8)


def test_temperature_residual_is_cT_dT_times_force(robot, hold_base):
    cT = 0.02
    run = simulate_twin(robot, "hold-sine", truth=quiet(effect_from_spec(f"temperature:{cT}")), **SHORT_HOLD)
    T = run.recording.temperature
    assert np.ptp(T) > 1.0 and abs(T.mean() - 21.0) < 3.0        # a few K around 21 C
    np.testing.assert_array_equal(T, hold_base.recording.temperature)  # channel is there either way
    expected = cT * (T - 21.0)[:, None] * hold_base.recording.force
    np.testing.assert_allclose(run.recording.force - hold_base.recording.force, expected, rtol=1e-9, atol=1e-9)


def test_offset_gain_is_exact(robot, hold_base):
    o = 3.0
    e = effect_from_spec(f"offset_gain:{o}@4")
    assert isinstance(e, OffsetGain) and e.gain == pytest.approx(o / 600.0)
    run = simulate_twin(robot, "hold-sine", truth=quiet(e), **SHORT_HOLD)
    F0 = hold_base.recording.force
    np.testing.assert_allclose(run.recording.force[:, 4], (1 + o / 600.0) * F0[:, 4] + o, rtol=1e-12, atol=1e-12)
    # a sensor effect: the true cable force is unchanged
    np.testing.assert_array_equal(run.output.force, hold_base.output.force)


def test_creep_is_a_monotone_drift_reaching_its_magnitude(robot, hold_base):
    D = 1.5
    run = simulate_twin(robot, "hold-sine", truth=quiet(Creep(magnitude=D, cables=(3,))), **SHORT_HOLD)
    r = run.recording.force[:, 3] - hold_base.recording.force[:, 3]
    assert r[0] == 0.0
    assert np.all(np.diff(r) <= 1e-12)
    assert r[-1] == pytest.approx(-D, abs=1e-9)
    # settling: the first half of the run drifts more than the second
    h = r.size // 2
    assert -r[h] > r[h] - r[-1]


def test_sag_matters_only_at_low_tension(robot):
    geom = robot.geometry()
    w = 0.2
    rms = {}
    for pre in (60.0, 600.0):
        kw = dict(SHORT_HOLD, pretension=pre)
        base = simulate_twin(robot, "hold-sine", truth=quiet(), **kw)
        run = simulate_twin(robot, "hold-sine", truth=quiet(effect_from_spec(f"sag:{w}")), **kw)
        r = run.recording.force - base.recording.force
        rms[pre] = np.sqrt(np.mean(r ** 2))
        # sag lengthens the hanging cable beyond its chord: tension rises by k s(F)
        F = run.recording.force
        k = geom.ea / run.truth.cable_length
        s = w ** 2 * run.free_length ** 3 / (24.0 * F ** 2)
        np.testing.assert_allclose(r, k * s, rtol=1e-9, atol=1e-9)
    assert rms[60.0] > 4 * NOISE
    assert rms[600.0] < 0.02 * rms[60.0]


def test_pulley_residual_follows_wrap_angle_and_direction(robot, traj_base):
    mu = 0.02
    run = simulate_twin(robot, "trajectory", truth=quiet(Pulley(magnitude=mu)), duration=6.0, seed=2)
    e = run.truth.effects[0]
    F0 = traj_base.recording.force
    r = run.recording.force - F0
    a = run.wrap_angle
    assert np.ptp(a, axis=0).max() > 0.02                      # the wrap angles change along the path
    ml = run.recording.motor_length
    v_in = np.vstack([np.zeros((1, 8)), -np.diff(ml, axis=0) * RATE])  # hauling in > 0
    stiff = F0 * e.kappa * (a - e.alpha_ref)
    Fs = F0 + stiff
    friction = mu * Fs * 2 * np.sin(a / 2) * np.tanh(v_in / e.v_s)
    np.testing.assert_allclose(r, stiff + friction, rtol=1e-9, atol=1e-9)
    # what a discovery tool would see: residual minus the slow stiffness part against
    # bearing load (eq 19) times direction of motion
    moving = np.abs(v_in) > 1e-3
    reg = (F0 * 2 * np.sin(a / 2) * np.sign(v_in))[moving]
    assert np.corrcoef((r - stiff)[moving], reg)[0, 1] > 0.95
    assert np.corrcoef(r[moving], reg)[0, 1] > 0.8


def test_pulley_needs_pulleys():
    for e in (Pulley(cables=(0,)), Pulley()):
        with pytest.raises(SimulationError, match="no pulley"):
            simulate_twin("cogiro", "hold-sine", truth=quiet(e), **SHORT_HOLD)


# ---- trajectory -------------------------------------------------------------------------

def test_trajectory_tensions_and_recording_roundtrip(robot, tmp_path):
    geom = robot.geometry()
    out = tmp_path / "traj.mcap"
    rec = simulate_recording(robot, "trajectory", out, duration=3.0, seed=4,
                             truth=TruthConfig(effects=[effect_from_spec("pulley:0.02@2,5")]))
    run = simulate_twin(robot, "trajectory", duration=3.0, seed=4,
                        truth=TruthConfig(effects=[effect_from_spec("pulley:0.02@2,5")]))
    assert run.recording.equals(rec)
    assert np.linalg.norm(np.ptp(rec.position, axis=0)) > 0.1     # it moves
    F = rec.force
    assert np.all(F > 0)
    assert np.all(F >= geom.force_min) and np.all(F <= geom.force_max)
    # the commanded tension distribution balances the weight: A^T f + w = 0
    ik = inverse_kinematics(geom, rec.position, rec.orientation)
    AT = structure_matrix(ik.unit, ik.anchor_world)
    w = platform_wrench(geom, ik.rotation)
    f_cmd = run.plan.info["force_command"]
    res = np.einsum("nim,nm->ni", AT, f_cmd) + w
    assert np.abs(res).max() < 1e-6
    assert f_cmd.min() >= run.plan.info["f_lo"].min() - 1e-6
    assert f_cmd.max() <= run.plan.info["f_hi"].max() + 1e-6
    # measured near commanded: the controller inverts the elastic part at the largest table
    # amplitude (K1 = 0.85 k); the amplitude model is up to 1/0.85 stiffer while its amplitude
    # estimate is smaller (at the start, after small reversals); plus hysteresis and pulley
    ratio = F / f_cmd
    assert np.all(np.abs(ratio - 1) < 0.25)
    back = read_recording(out)
    assert back.equals(rec)
    md = back.metadata
    assert back.robot == "ipanema3" and md["scenario"] == "trajectory" and md["seed"] == "4"
    truth = json.loads(md["truth"])
    assert truth["effects"] == [{"name": "pulley", "magnitude": 0.02, "unit": "-", "cables": [2, 5],
                                 "options": {"v_s": 5e-4, "stiffness_ratio": 2.0, "alpha_ref": np.pi / 2}}]
    assert "must not read" in truth["notice"]


def test_trajectory_planar_robot():
    run = simulate_twin("planar4", "trajectory", duration=3.0, kind="sines", truth=quiet())
    geom = run.truth.geom
    rec = run.recording
    assert np.all(rec.position[:, 2] == 0.0)
    f = run.plan.info["force_command"]
    ik = inverse_kinematics(geom, rec.position, rec.orientation)
    res = np.einsum("nim,nm->ni", structure_matrix(ik.unit, ik.anchor_world), f) + platform_wrench(geom, ik.rotation)
    assert np.abs(res[:, [0, 1, 5]]).max() < 1e-6
    assert np.all(rec.force > geom.force_min) and np.all(rec.force < geom.force_max)


# ---- seeds, specs, errors -----------------------------------------------------------------

def test_reproducible_with_seed(robot, tmp_path):
    a = simulate_recording(robot, "trajectory", duration=1.0, seed=5)
    b = simulate_recording(robot, "trajectory", tmp_path / "b.csv", duration=1.0, seed=5)
    c = simulate_recording(robot, "trajectory", duration=1.0, seed=6)
    assert a.equals(b)
    assert read_recording(tmp_path / "b.csv").equals(a)
    assert not np.array_equal(a.force, c.force)
    assert not np.array_equal(a.temperature, c.temperature)
    assert not np.array_equal(a.motor_length, c.motor_length)
    # noise only: same scenario, other noise seed
    d = simulate_recording(robot, "trajectory", duration=1.0, seed=5, truth=TruthConfig(seed=99))
    np.testing.assert_array_equal(d.motor_length, a.motor_length)
    assert 0.05 < np.std(d.force - a.force) < 0.2


def test_effect_specs():
    e = effect_from_spec("pulley:0.02@2,5")
    assert isinstance(e, Pulley) and e.magnitude == 0.02 and e.cables == (2, 5)
    assert e.describe() == "pulley:0.02@2,5"
    c = effect_from_spec("creep")
    assert c.magnitude == Creep.default_magnitude and c.cables is None and c.describe() == "creep:2@all"
    assert effect_from_spec("sag@0-2").cables == (0, 1, 2)
    assert effect_from_spec("offset_gain:-1.5@all").magnitude == -1.5
    for bad, msg in [("friction:1", "unknown effect"), ("pulley:abc", "not a number"),
                     ("pulley:0.1@9", "out of range"), ("pulley:0.1@x", "index"), ("", "expected")]:
        with pytest.raises(SimulationError, match=msg):
            effect_from_spec(bad, 8)
    with pytest.raises(SimulationError, match="tau must be >= 0"):
        effect_from_spec("deadtime:-0.1")
    lines = list_effects()
    assert len(lines) == len(EFFECTS) and all(any(l.startswith(n) for l in lines) for n in EFFECTS)


def test_bad_options_are_reported(robot):
    with pytest.raises(SimulationError, match="unknown option.*amplitude"):
        simulate_twin(robot, "hold-sine", amplitude=[1e-3])
    with pytest.raises(SimulationError, match="unknown scenario"):
        simulate_twin(robot, "wobble")
    with pytest.raises(SimulationError, match="out of range"):
        simulate_twin(robot, "hold-sine", truth=quiet(effect_from_spec("viscous@8")), **SHORT_HOLD)
    with pytest.raises(SimulationError, match="cables"):
        simulate_twin(robot, "hold-sine", cables=[9], **SHORT_HOLD)
    with pytest.raises(SimulationError, match=r"\.mcap or \.csv"):
        simulate_recording(robot, "hold-sine", "rec.txt")
    assert set(SCENARIOS) == {"hold-sine", "hold-triangle", "hold-trapezoid", "trajectory"}
    assert all(fn.__doc__ for fn in SCENARIOS.values())


def test_hold_duration_repeats_and_cuts(robot):
    run = simulate_twin(robot, "hold-sine", truth=quiet(), duration=4.5, **SHORT_HOLD)
    rec = run.recording
    assert rec.n_ticks == 4500 and rec.t[-1] == pytest.approx(4.499)
    assert len(run.plan.info["blocks"]) >= 2                 # one pass is 2.0 s
    assert np.all(np.diff(rec.seq) == 1) and rec.validate() == []


def test_amplitude_backbone_is_one_law_with_the_lookup_explicit():
    """The twin's elastic curve and the model's step evaluate the same backbone law
    (models.amplitude.backbone); only the table lookup at A differs, and it is an explicit
    choice: the step's nearest point of the resampled grid, the twin's linear interpolation."""
    from cablesvc.config.params import ModelParams
    from cablesvc.models import AmplitudeDependent
    from cablesvc.simulate import ElasticCurve

    amps = [1e-4, 5e-4, 1.5e-3]
    tables = {"amplitudes": amps, "K0": [[50.0, 50.0, 50.0], [80.0, 80.0, 80.0]],
              "K1": [[2e5, 1.6e5, 1.2e5], [3e5, 2.5e5, 2e5]], "K2": [[1e6, 2e6, 3e6], [0.0, 1e6, 4e6]],
              "K3": [[1e9, 5e8, 2e8], [2e9, 1e9, 0.0]], "S_a": [0.0] * 3, "alpha": [0.0] * 3}
    opts = {"x_center": [2e-4, -1e-4], "amplitude_init": [3.3e-4, 1.234e-3], "omega_init": 1.0}
    model = AmplitudeDependent(shape=(1, 2), **tables, **opts)
    x = np.array([[7e-4, -3e-4]])
    state = model.create_state(x)
    stepped = model.step(state, x, 1e-3).copy()          # at rest, no loop area: the backbone alone
    A0 = np.asarray(opts["amplitude_init"])
    nearest = model.backbone_force(x, A0, interpolation="nearest")
    np.testing.assert_array_equal(stepped, nearest)
    linear = model.backbone_force(x, A0, interpolation="linear")
    xi = x[0] - np.asarray(opts["x_center"])
    for c in range(2):
        K = [np.interp(A0[c], amps, np.asarray(tables[k][c])) for k in ("K0", "K1", "K2", "K3")]
        assert linear[0, c] == pytest.approx(K[0] + K[1] * xi[c] + K[2] * xi[c] ** 2 + K[3] * xi[c] ** 3, rel=1e-12)
    assert not np.array_equal(linear, nearest)               # the grid's nearest point is not A itself
    np.testing.assert_allclose(linear, nearest, rtol=1e-3)
    params = ModelParams(model="amplitude", params=opts, tables=tables)
    np.testing.assert_array_equal(ElasticCurve(params, 2).force(x), linear)
    with pytest.raises(ValueError, match="interpolation"):
        model.backbone_force(x, A0, interpolation="cubic")


def test_twin_sag_and_sag_term_solve_the_same_irvine_equation():
    """The twin's sag effect and the discovery/live sag term share one solve (the closed-form
    root of the Irvine equation) and reach the same tension."""
    from cablesvc.models.terms import Sag as SagTerm
    from cablesvc.simulate.effects import RunInfo, Sag

    sag = Sag(magnitude=0.6)
    k = np.array([2e4, 5e4, 1e5, 3e5])
    sag.bind(RunInfo(n_cables=4, dt=1e-3, n_ticks=1, duration=1.0, stiffness=k, has_pulley=np.zeros(4, bool)))
    L = np.array([1.5, 3.0, 6.0, 9.0])
    for f_base in (np.full(4, 0.5), np.full(4, 5.0), np.array([2.0, 40.0, 300.0, 1500.0])):
        F = sag.solve(f_base, L)
        cc = k * 0.6 ** 2 * L ** 3 / 24.0
        np.testing.assert_allclose(F - f_base - cc / F ** 2, 0.0, atol=1e-9 * float(np.max(F)))
        np.testing.assert_allclose(F, SagTerm.solve(f_base, cc), rtol=1e-11)
        assert np.all(F > f_base)                     # sag raises the tension at a given elongation
