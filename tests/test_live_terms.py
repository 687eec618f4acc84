"""Discovered physics runs live (issue 16, items 2-3): for every term of the library and the
baseline's recalibration, the kernel running a parameter file's terms tick by tick gives
the forces ``Discovery.predict()`` computes offline from the same file, and a snapshot taken
mid-run and restored gives the forces of an uninterrupted run."""

from __future__ import annotations

import numpy as np
import pytest

from cablesvc.config.params import load_params
from cablesvc.discover import discover
from cablesvc.discover.pipeline import Discovery, baseline_params, build_signals, split_blocks
from cablesvc.discover.select import Selection, fit_terms
from cablesvc.kernel import Predictor
from cablesvc.models.terms import LIBRARY, Recalibration, Sag, TermStack, cable_view, term_class
from cablesvc.models.terms.recalibration import envelope
from cablesvc.models.reversal import REVERSAL_DEADBAND, LiveReversalAmplitude, reversal_amplitude, reversal_points
from cablesvc.simulate import TruthConfig, effect_from_spec, simulate_recording

ROBOT = "ipanema3"
#: the effect each term is fitted to (one that gives its columns something to explain)
EFFECT = {
    "pulley": "pulley:0.004@1,4", "creep": "creep:0.8@2", "temperature": "temperature:-0.002@0,6",
    "viscous": "viscous:8000@3", "deadtime": "deadtime:0.25@5", "sag": "sag:0.5@6",
    "offset_gain": "offset_gain:0.6@2,7", "amplitude": "viscous:8000@3", "asymmetric": "sag:0.5@6",
    "boucwen": "pulley:0.004@1,4", "baseline": "offset_gain:0.6@2,7", "baseline+loop": "offset_gain:0.6@2,7",
}


def _recording(spec: str, seed: int = 5, scenario: str = "trajectory", duration: float = 8.0):
    eff = [effect_from_spec(spec, 8)]
    return simulate_recording(ROBOT, scenario, None, truth=TruthConfig(effects=eff, noise_std=0.1),
                              duration=duration, rate=100, seed=seed)


#: terms whose amplitude signal needs reversals: a held platform, sine-stretched cables
SCENARIO = {"amplitude": "hold-sine", "baseline": "hold-sine", "baseline+loop": "hold-sine"}


def _discovery(rec, robot, names: list[str], train_first_half: bool = False) -> Discovery:
    """Fit ``names`` (the deadtime first when present, as the selector orders it) on every
    cable on all ticks, the way the pipeline's final fit does, into a Discovery.
    ``train_first_half``: the references come from the first half of the ticks only."""
    base = baseline_params(robot)
    s = build_signals(rec, robot, base)
    train, valid, test = split_blocks(s.t, 2.0)
    if train_first_half:
        train = s.t < np.median(s.t)
    s.train = train
    r = s.y - s.f0
    # "baseline+loop": the recalibration with its rate-independent loop (the stops) fitted
    terms = [Recalibration(stops=True) if n == "baseline+loop" else term_class(n) for n in names]
    full = {}
    for c in range(s.m):
        ts = [t for t in terms if t.applies(s, c)]
        full[c] = fit_terms(s, c, r[:, c], ts, np.ones(s.n, bool))
    named = [n for n in names if n not in (Recalibration.name, "baseline+loop")]
    rm = np.sqrt(np.mean(r[test] ** 2, axis=0))
    return Discovery(robot=robot.name, baseline=base, signals=s, residual=r,
                     masks={"train": train, "valid": valid, "test": test}, location={}, selection=Selection(fits={}, steps=[], baseline_valid_mse={}),
                     final=full, full=full, findings=[_F(n) for n in named], rmse_before=rm, rmse_after=rm,
                     noise=np.full(s.m, 0.1))


class _F:
    def __init__(self, term):
        self.term = term


def _kernel_forces(rec, robot, params, start=0, stop=None, pred=None):
    pred = pred or Predictor(robot.geometry(), params)
    stop = rec.t.size if stop is None else stop
    out = []
    for k in range(start, stop):
        temp = None if rec.temperature is None else float(rec.temperature[k])
        o = pred.tick(float(rec.t[k]), rec.motor_length[k], rec.position[k], rec.orientation[k], rec.force[k], temp)
        out.append(o.force.copy())
    return np.array(out), pred


@pytest.mark.parametrize("names", [["pulley"], ["creep"], ["temperature"], ["viscous"], ["deadtime"], ["sag"],
                                   ["offset_gain"], ["amplitude"], ["asymmetric"], ["boucwen"], ["baseline"],
                                   ["baseline+loop"],
                                   ["deadtime", "baseline", "pulley", "viscous"]],
                         ids=lambda n: "+".join(n))
def test_live_kernel_equals_offline_predict(robot, tmp_path, names):
    rec = _recording(EFFECT[names[0]], scenario=SCENARIO.get(names[0], "trajectory"))
    d = _discovery(rec, robot, names)
    used = {t.name for f in d.full.values() for t in f.terms}
    assert set(n.split("+")[0] for n in names) <= used | {"temperature"} and used, "every term was fitted on some cable"
    if "baseline+loop" in names:                    # the loop's coefficients are in the file, not 0
        from cablesvc.models.terms.recalibration import INITIAL, STOPS
        for part in (STOPS, INITIAL):               # the stops and their initial state both run live
            assert any(f.params["baseline"][n] != 0.0 for f in d.full.values() for n in part)
    path = tmp_path / "augmented.toml"
    d.augmented_params().save(path)
    params = load_params(path)                      # through the file, as the daemon reads it
    live, _ = _kernel_forces(rec, robot, params)
    off = d.predict()
    contrib = off - d.signals.f0
    assert np.max(np.abs(contrib)) > 1e-3, "the terms contribute something"
    assert np.all(off > 1.0), "tensions stay positive, so the kernel's slack clamp is inactive"
    rel = np.max(np.abs(live - off) / np.maximum(np.abs(off), 1.0))
    assert rel < 1e-9, f"{names}: live vs offline max relative difference {rel:.3g}"


def test_snapshot_mid_run_gives_the_uninterrupted_forces(robot, tmp_path):
    rec = _recording("deadtime:0.25@5")
    d = _discovery(rec, robot, ["deadtime", "baseline", "boucwen", "creep", "pulley"])
    params = d.augmented_params()
    whole, _ = _kernel_forces(rec, robot, params)
    half = rec.t.size // 2
    first, p1 = _kernel_forces(rec, robot, params, 0, half)
    state = {k: v.copy() for k, v in p1.state_dict().items()}
    assert any(k.startswith("terms.") for k in state), "the terms' state is in the snapshot"
    p2 = Predictor(robot.geometry(), params)
    p2.load_state_dict(state)
    second, _ = _kernel_forces(rec, robot, params, half, None, pred=p2)
    np.testing.assert_array_equal(np.vstack([first, second]), whole)


def test_recalibration_discrepancy_is_held_within_its_training_range(robot, tmp_path):
    """Referenced on the first half of a hold-sine recording, the recalibration's amplitude
    columns meet larger amplitudes in the second half than the training ticks had: they are
    held at the training range (without the bounds they leave it on every cable), and the
    live kernel holds them exactly as the offline form does."""
    rec = _recording(EFFECT["baseline"], scenario="hold-sine")
    s = build_signals(rec, robot, baseline_params(robot))
    s.train = s.t < np.median(s.t)
    rc = Recalibration()
    idx = {n: rc.params.index(n) for n in ("K1_A", "d_A")}
    left = 0
    for c in range(s.m):
        d = rc.design(s, c, {})
        unbounded = dict(d.refs, **{f"{side}_{n}": v for n in idx for side, v in (("lo", -np.inf), ("hi", np.inf))})
        raw = np.empty((len(rc.params), s.n))
        rc.columns(cable_view(s, c), unbounded, {}, raw)
        for n, j in idx.items():
            lo, hi = d.refs[f"lo_{n}"], d.refs[f"hi_{n}"]
            col = d.X[:, d.names.index(n)]
            assert lo <= hi and np.all(col >= lo) and np.all(col <= hi)
            np.testing.assert_array_equal(col[s.train], raw[j][s.train])      # untouched where fitted
            np.testing.assert_array_equal(col, np.clip(raw[j], lo, hi))
            left += int(np.any((raw[j] < lo) | (raw[j] > hi)))
        # the damping level grows with the envelope only up to the largest one fitted
        E = envelope(s.x[:, c])
        assert d.refs["E_hi"] == np.max(E[s.train])
        for a in ("c_r0", "c_r25"):
            np.testing.assert_allclose(d.X[:, d.names.index(a + "_e")],
                                       d.X[:, d.names.index(a)] * np.minimum(E, d.refs["E_hi"]), rtol=1e-12, atol=0)
    assert left == 2 * s.m, "the second half reaches beyond the first half's range on every cable"

    dis = _discovery(rec, robot, ["baseline"], train_first_half=True)
    path = tmp_path / "augmented.toml"
    dis.augmented_params().save(path)
    params = load_params(path)
    assert "lo_d_A" in params.identification["term_baseline"]
    live, _ = _kernel_forces(rec, robot, params)
    off = dis.predict()
    assert np.max(np.abs(live - off) / np.maximum(np.abs(off), 1.0)) < 1e-9


def test_recalibration_damping_level_stops_growing_beyond_the_envelope_it_was_fitted_on():
    """Live, the elongation ramps 5 mm at 1 mm/s (envelope 2.5 mm) on a cable whose damping
    level grows 1 N per mm of envelope, fitted up to 1 mm: the force stops at 1 N; a file
    without the bound lets it reach 2.5 N."""
    def last_force(table, bad=None):
        stack = TermStack([Recalibration()], {"baseline": table}, 1)
        zero = np.zeros((1, 1))
        for k in range(501):
            x = np.nan if k == bad else 1e-5 * k
            f = stack.step(0.01 * k, zero, np.full((1, 1), x), zero, zero, zero, None)
        return float(f[0, 0])
    assert last_force({"c_r0_e": [1.0], "E_hi": [1.0]}) == pytest.approx(1.0, rel=1e-9)
    assert last_force({"c_r0_e": [1.0]}) == pytest.approx(2.5, rel=1e-9)
    # a non-finite reading mid-ramp does not end the envelope
    assert last_force({"c_r0_e": [1.0]}, bad=100) == pytest.approx(2.5, rel=1e-9)


def test_recalibration_file_without_bounds_runs_unclamped():
    """A parameter file written before the bounds existed has no ``lo_``/``hi_`` references:
    its discrepancy runs unclamped, as it did when it was written."""
    live = Recalibration().live({"k_s": [0.01] * 8, "d_A": [1.0] * 8, "lo_K1_A": [-2.0] * 8}, 1, 8)
    assert np.all(live.R["lo_d_A"] == -np.inf) and np.all(live.R["hi_d_A"] == np.inf)
    assert np.all(live.R["hi_K1_A"] == np.inf) and np.all(live.R["lo_K1_A"] == -2.0)
    assert np.all(live.R["E_hi"] == np.inf)


def test_live_amplitude_tracker_is_the_offline_rule():
    rng = np.random.default_rng(3)
    t = np.arange(4000) * 0.01
    x = 1e-3 * np.sin(0.7 * t)[:, None] * np.array([1.0, 0.3, 0.01]) + 3e-6 * rng.standard_normal((4000, 3))
    x[:50, 2] = 0.0                                  # a cable that does not move at first
    off = reversal_amplitude(x)
    stack = TermStack([LIBRARY["amplitude"]], {"amplitude": {"K1_A": [1.0] * 3, "d_A": [0.0] * 3}}, 3)
    live = np.array([stack.rev.step(x[k][None, :])[0].copy() for k in range(x.shape[0])])
    np.testing.assert_array_equal(live, off)
    assert np.count_nonzero(off[:, 0]) > 3000


def test_live_reversal_lanes_equal_the_whole_record_rule_exactly():
    """The live lanes class (the kernel's numpy step over (lanes, cables)) and the
    whole-record rule (numba) give the same amplitude bit for bit on a noisy sine, a
    bus-quantised one, a flat-topped one, a random walk and a cable that starts late; every
    lane of the same cable sees the same elongation, so also lane by lane."""
    rng = np.random.default_rng(11)
    n = 5000
    t = np.arange(n) * 0.01
    sine = 2e-4 * np.sin(0.9 * t)
    cols = [
        sine + 3e-7 * rng.standard_normal(n),                                      # noisy
        np.round((sine + 2e-7 * rng.standard_normal(n)) / 1e-7) * 1e-7,           # quantised (0.1 um)
        np.clip(2.5 * sine, -2e-4, 3e-4),                                           # flat tops and bottoms
        np.cumsum(1e-6 * rng.standard_normal(n)),                                   # random walk
        np.where(t < 20.0, 1e-3, 1e-3 + 5e-5 * np.sin(2.0 * (t - 20.0))),          # still, then moves
    ]
    x = np.column_stack(cols)
    want = reversal_amplitude(x)
    lanes = 3
    live = LiveReversalAmplitude(lanes, x.shape[1], REVERSAL_DEADBAND)
    got = np.empty((n, lanes, x.shape[1]))
    for k in range(n):
        got[k] = live.step(np.broadcast_to(x[k], (lanes, x.shape[1])))
    for lane in range(lanes):
        np.testing.assert_array_equal(got[:, lane], want)
    assert all(reversal_points(x[:, c], REVERSAL_DEADBAND).size >= 10 for c in range(x.shape[1]))  # many turns
    assert np.all(want[: int(20.0 / 0.01), 4] == 0.0)                                      # none while still


def _irvine_newton_80bit(f0, cc, floor=1.0, steps=200):
    """The sag equation's root by plain Newton in 80-bit floats (x86 long double) from
    max(f0, cbrt(cc), floor), many more steps than it needs: the reference."""
    f0, cc = np.asarray(f0, np.longdouble), np.asarray(cc, np.longdouble)
    f = np.maximum(np.maximum(f0, np.cbrt(cc)), floor)
    for _ in range(steps):
        f = np.maximum(f - (f - f0 - cc / f ** 2) / (1 + 2 * cc / f ** 3), floor)
    return f


def test_sag_closed_form_is_the_root_at_any_tension():
    """The closed-form solve (three branches selected by masks) is the root of
    f = f0 + cc / f^2 floored at 1 N to ~1e-14 relative from deep slack (f0 < 0) to high
    tension, with no floating-point warning; a cable without sag (cc = 0) gets
    max(f0, 1) exactly (the sag term then adds exactly 0)."""
    if np.finfo(np.longdouble).eps > 1e-18:
        pytest.skip("no 80-bit long double on this platform for the reference solve")
    rng = np.random.default_rng(3)
    n = 20000
    f0 = np.concatenate([rng.uniform(-3000.0, 3000.0, n), np.sign(rng.uniform(-1, 1, n)) * 10 ** rng.uniform(-12, 4, n),
                         [0.0, -0.0, 1e-300, -1e-300, 0.5, -0.5, 60.0]])
    cc = np.concatenate([10 ** rng.uniform(-3, 7, n), 10 ** rng.uniform(-12, 9, n), [5.0, 5.0, 5.0, 5.0, 0.0, 0.0, 0.0]])
    with np.errstate(all="raise"):
        f = Sag.solve(f0, cc)
    want = _irvine_newton_80bit(f0, cc)
    assert np.max(np.abs(f - want) / want) < 1e-13
    assert np.all(f >= 1.0)
    nosag = np.array([-50.0, -0.0, 0.3, 1.0, 7.5, 2500.0])
    np.testing.assert_array_equal(Sag.solve(nosag, np.zeros(6)), np.maximum(nosag, 1.0))


def test_delay_line_interpolates_as_np_interp_on_irregular_ticks():
    """The dead-time line (one gather of both taps for every signal and cable) gives
    np.interp of the history at t - tau per cable, bit for bit: on irregular ticks, a dead
    time of 0 (the newest value), taus between ticks and exactly on a tick, and a history
    shorter than the window (held at the first value, as offline) and longer (the ring
    wrapped many times)."""
    from cablesvc.models.terms.live import _DelayLine

    rng = np.random.default_rng(7)
    n, k, lanes, m = 50, 4, 2, 5
    line = _DelayLine(n, k, lanes, m)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 400))
    t -= t[0]
    vals = rng.normal(size=(t.size, k, lanes, m))
    tau = np.array([0.0, 1e-3, 3.3e-3, 0.02, 0.0])
    out = np.empty((k, lanes, m))
    for i in range(t.size):
        tau[4] = t[i] - t[max(i - 7, 0)]                # a tap exactly on a tick
        row = line.slot(t[i])
        np.copyto(row, vals[i])
        line.commit()
        line.at(t[i] - tau, out)
        for c in range(m):
            want = [np.interp(t[i] - tau[c], t[: i + 1], vals[: i + 1, a, b, c]) for a in range(k) for b in range(lanes)]
            np.testing.assert_array_equal(out[:, :, c].reshape(-1), want)


def test_negative_sag_parameter_is_refused_with_its_field():
    tab = {"sag": {"q": [10.0, -1.0] + [0.0] * 6}}
    with pytest.raises(ValueError, match=r"term_sag\.q: -1\.0 on cable 1: must be a finite number >= 0"):
        TermStack([LIBRARY["sag"]], tab, 8)


def test_missing_temperature_takes_the_mean(robot):
    tab = {"temperature": {"c_T": [0.01] * 8, "g": [0.002] * 8, "T_mean": [20.0] * 8}}
    stack = TermStack([LIBRARY["temperature"]], tab, 8)
    f0 = np.full((1, 8), 100.0)
    z = np.zeros((1, 8))
    a = stack.step(0.0, f0, z, z, z, z + 3.0, None).copy()
    b = stack.step(0.01, f0, z, z, z, z + 3.0, 25.0).copy()
    np.testing.assert_allclose(a, 0.2)                # g f only
    np.testing.assert_allclose(b, 100.0 * (0.01 * 5.0 + 0.002))


def test_unknown_term_in_a_parameter_file_is_refused():
    with pytest.raises(KeyError, match="unknown term 'friction'"):
        TermStack.from_params({"discovered_terms": ["friction"]}, 8)


@pytest.mark.parametrize("exact", [True, False], ids=["exact-baseline", "identified-baseline"])
def test_end_to_end_discover_file_runs_live(robot, exact):
    """What ``cablesvc discover --out`` writes runs live with the numbers of the report:
    with the twin's exact baseline the named viscous term; with the identified-baseline
    method also the baseline's recalibration on every cable."""
    rec = _recording("viscous:8000@3", seed=9, duration=20.0)
    d = discover(rec, robot, exact_baseline=exact)
    if exact:
        assert "viscous" in d.named
    else:
        assert "term_baseline" in d.augmented_params().identification
    live, _ = _kernel_forces(rec, robot, d.augmented_params())
    base, _ = _kernel_forces(rec, robot, d.baseline)
    off = d.predict()
    # the terms' part: live (kernel with terms - kernel without) vs offline (predict - f0); the
    # baselines themselves (per-tick kernel vs the vectorised simulate) differ by < 1e-8 relative
    assert np.max(np.abs(base - d.signals.f0) / np.maximum(np.abs(off), 1.0)) < 1e-8
    terms_live, terms_off = live - base, off - d.signals.f0
    assert np.max(np.abs(terms_off)) > 1e-2
    assert np.max(np.abs(terms_live - terms_off) / np.maximum(np.abs(off), 1.0)) < 1e-9


def test_bench_kernel_terms_rows_report_the_ratio():
    """The bench row with every term on every cable runs (planar4 and ipanema3 layouts) and
    reports its p50 against the same kernel without terms, timed in alternate blocks."""
    from cablesvc.bench.kernel import as_dicts, run_kernel_bench
    res = as_dicts(run_kernel_bench("planar4", ticks=300, inputs=("normal", "terms", "terms_no_temperature"),
                                    machine_baseline=False))
    by = {r["input"]: r for r in res}
    assert "kernel_p50_ratio" not in by["normal"]
    for k in ("terms", "terms_no_temperature"):
        assert by[k]["plain_p50_us"] > 0
        assert by[k]["kernel_p50_ratio"] == pytest.approx(by[k]["p50_us"] / by[k]["plain_p50_us"])


def test_creep_clock_starts_at_the_files_origin():
    tab = {"creep": {"a": [0.0] * 8, "b": [1e-5] * 8, "tau": [10.0] * 8, "k": [1e5] * 8}}
    stack = TermStack.from_params({"discovered_terms": ["creep"], "term_creep": tab["creep"],
                                   "terms_clock_origin": 100.0}, 8)
    z = np.zeros((1, 8))
    out = stack.step(110.0, z + 50.0, z, z, z, z + 3.0, None)
    np.testing.assert_allclose(out, -1e5 * 1e-5 * 10.0)        # -k b (t - origin)


def test_discovery_since_runs_live_from_the_recordings_start(robot):
    """``discover(..., since=T)``: the baseline runs over the whole recording and the terms
    are fitted on the ticks from T on; the kernel that ran from the start with the written
    file gives, from T on, the forces predict() gives."""
    rec = _recording("viscous:800@3", seed=4, duration=30.0)
    d = discover(rec, robot, exact_baseline=True, since=10.0)
    k0 = int(np.searchsorted(rec.t, rec.t[0] + 10.0 - 1e-9))
    assert d.signals.n == rec.t.size - k0 and "viscous" in d.named
    assert d.augmented_params().identification["terms_clock_origin"] == float(rec.t[k0])
    live, _ = _kernel_forces(rec, robot, d.augmented_params())
    base, _ = _kernel_forces(rec, robot, d.baseline)
    off = d.predict()
    terms_live, terms_off = (live - base)[k0:], off - d.signals.f0
    assert np.max(np.abs(terms_live - terms_off) / np.maximum(np.abs(off), 1.0)) < 1e-9


def test_bench_live_discovery_one_effect(tmp_path):
    """The live-discovery flow on one effect (short): the daemon misses no tick, takes the
    augmented file, and its live residual on the affected cable drops to the held-out level."""
    from cablesvc.bench.live_discovery import run_effect
    r = run_effect("viscous", half=80.0, onset=62.0, workdir=tmp_path)
    assert r["missing"] == 0 and r["reload_accepted"]
    assert "viscous" in r["named"] and r["cables"] == [3]
    assert r["rmse_live_after"] < 0.5 * r["rmse_live_before"]
    assert r["rmse_live_after"] < 1.5 * r["rmse_discover_heldout"]


def test_reload_hand_over_between_files_with_other_terms(robot):
    """The daemon's reload hands the kernel state to the new kernel: from a file without
    terms to one with stateful terms (and back) the model memory is kept and the terms
    start fresh, without an error."""
    from cablesvc.service.params_reload import hand_over
    rec = _recording("deadtime:0.25@5")
    d = _discovery(rec, robot, ["deadtime", "boucwen", "creep"])
    plain, with_terms = d.baseline, d.augmented_params()
    _, p_old = _kernel_forces(rec, robot, plain, 0, 300)
    p_new = Predictor(robot.geometry(), with_terms)
    assert hand_over(p_old, p_new) == "kept (same model family)"
    more, _ = _kernel_forces(rec, robot, with_terms, 300, 400, pred=p_new)
    assert np.all(np.isfinite(more))
    p_back = Predictor(robot.geometry(), plain)
    assert hand_over(p_new, p_back) == "kept (same model family)"


def test_reload_into_terms_takes_the_rates_of_the_last_tick(robot):
    """A reload from a file without terms into one with a pulley term: the first tick after
    the hand-over uses the real sliding speed over the pulley (the previous tick's motor
    length comes with the state), so it equals a kernel that ran the terms from the start
    (the pulley term has no other memory). Without it the friction is 0 for one tick."""
    from cablesvc.service.params_reload import hand_over
    rec = _recording("pulley:0.004@1,4")
    d = _discovery(rec, robot, ["pulley"])
    plain, with_terms = d.baseline, d.augmented_params()
    assert max(abs(v) for v in with_terms.identification["term_pulley"]["mu"]) > 0
    _, p_old = _kernel_forces(rec, robot, plain, 0, 300)
    p_new = Predictor(robot.geometry(), with_terms)
    hand_over(p_old, p_new)
    after, _ = _kernel_forces(rec, robot, with_terms, 300, 310, pred=p_new)
    ref, _ = _kernel_forces(rec, robot, with_terms, 0, 310)
    np.testing.assert_allclose(after, ref[300:], rtol=1e-12, atol=1e-9)


def test_creep_fitted_after_it_began_keeps_what_had_crept():
    """Creep analysed from a time after it began (``discover --since`` after an alarm): the
    creep already there is the term's d0, and the settling time comes out of the scalar
    search between grid points, so the fitted law continues the truth past the data."""
    from cablesvc.models.terms import Creep, Signals
    rng = np.random.default_rng(3)
    n, m = 9000, 1
    t = np.arange(n) * 0.01 + 40.0
    z = np.zeros((n, m))
    s = Signals(t=t, dt=0.01, y=z.copy(), f0=z + 200.0, x=z + 0.01, v=z.copy(), v_slide=z.copy(), wrap=z.copy(),
                free_length=z + 2.0, temperature=None, amplitude=z.copy(), ea=np.array([30000.0]),
                has_pulley=np.array([False]), train=np.ones(n, bool))
    k = 30000.0 / 2.0
    truth = dict(d0=2e-5, a=5e-5, b=1e-7, tau=23.0)
    tr = t - t[0]
    r = -k * (truth["d0"] + truth["a"] * (1 - np.exp(-tr / truth["tau"])) + truth["b"] * tr)
    fit = fit_terms(s, 0, r + rng.normal(0, 0.02, n), [Creep()], np.ones(n, bool))
    assert fit.hyper["creep"]["tau"] == pytest.approx(truth["tau"], rel=0.1)
    for p in ("d0", "a"):
        assert fit.params["creep"][p] == pytest.approx(truth[p], rel=0.1)
    t2 = np.arange(0.0, 200.0, 1.0)
    law = lambda P, h: -k * (P["d0"] + P["a"] * (1 - np.exp(-t2 / h)) + P["b"] * t2)
    assert np.max(np.abs(law(fit.params["creep"], fit.hyper["creep"]["tau"]) - law(truth, truth["tau"]))) < 0.1


def test_onset_of_a_clocked_effect_starts_its_clock():
    """The live-discovery bench fades effects in at the onset; creep (``clocked``) starts
    creeping there instead of jumping to the creep it would have accumulated since the
    start."""
    from cablesvc.bench.live_discovery import make_onset_recording
    on, cables = make_onset_recording("creep:1.5@2", half=20.0, onset=10.0, ramp=1.0, seed=3)
    off, _ = make_onset_recording("creep:0@2", half=20.0, onset=10.0, ramp=1.0, seed=3)
    d = (on.force - off.force)[:, 2]
    t = on.t - on.t[0]
    assert np.all(d[t < 10.0] == 0.0)
    early, end = abs(d[np.searchsorted(t, 11.0)]), abs(d[-1])
    assert end > 1.0 and early < 0.25 * end
