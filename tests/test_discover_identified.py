"""Discovery with an identified, imperfect baseline (issue 15): the baseline's own
recalibration is the nuisance, block-level evidence, the equilibrium check that tells a
sensor error from a cable-model error, the verdict line and ``--calib``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cablesvc.config import load_robot
from cablesvc.config.params import ModelParams
from cablesvc.discover import discover
from cablesvc.discover.equilibrium import equilibrium_check
from cablesvc.discover.evidence import block_gain_test, holm
from cablesvc.discover.pipeline import baseline_params
from cablesvc.kinematics import inverse_kinematics, platform_wrench, structure_matrix
from cablesvc.simulate import TruthConfig, effect_from_spec, simulate_recording

ROBOT = "ipanema3"


def _rec(specs, seed=11, duration=20.0, path=None):
    eff = [effect_from_spec(s, 8) for s in specs]
    return simulate_recording(ROBOT, "trajectory", path, truth=TruthConfig(effects=eff, noise_std=0.1),
                              duration=duration, rate=100, seed=seed)


def _wrong_baseline(scale=1.06) -> ModelParams:
    """The twin's nominal model with every stiffness coefficient scaled: an honestly wrong
    baseline (the kind identification leaves away from its calibration point)."""
    rob = load_robot(ROBOT)
    p = baseline_params(rob)
    tables = dict(p.tables)
    tables["K1"] = (np.asarray(tables["K1"], float) * scale).tolist()
    return ModelParams(model=p.model, params=dict(p.params), options=dict(p.options), tables=tables,
                       robot=p.robot, identification=dict(p.identification), source="<scaled>")


def test_wrong_baseline_is_recalibrated_not_named():
    # the baseline is 6 % too stiff, nothing concealed: the exact-baseline method names
    # model-form and sensor terms for this mismatch; the identified mode recalibrates it
    rec = _rec([], seed=3)
    old = discover(rec, ROBOT, _wrong_baseline(), exact_baseline=True)
    assert old.named                     # what the issue measured: mismatch taken for physics
    d = discover(rec, ROBOT, _wrong_baseline())
    assert d.named == []
    assert d.recalibration["cables"]     # ... but reported as the baseline's own finding
    ks = [d.recalibration["per_cable"][str(c)]["k_s"] for c in d.recalibration["cables"]]
    assert np.median(ks) < 0             # the baseline is too stiff: scaled down
    assert d.summary()[0].startswith("verdict: nothing significant beyond the baseline's calibration")
    doc = d.to_json()
    assert doc["mode"] == "identified" and doc["verdict"] == d.summary()[0]
    assert "recalibration" in doc and "unexplained" in doc


def test_creep_named_beyond_the_recalibrated_baseline_with_a_p_value():
    d = discover(_rec(["creep:0.8@2"], seed=11), ROBOT, _wrong_baseline())
    assert d.named == ["creep"]
    assert d.findings[0].cables == [2]
    assert 0.0 <= d.findings[0].p_value < 0.05
    assert d.findings[0].share[2] >= 0.8                # it explains most of what is left
    doc = d.to_json()
    assert doc["findings"][0]["p_value"] == d.findings[0].p_value
    assert doc["findings"][0]["share"] == {"2": d.findings[0].share[2]}
    assert doc["findings"][0]["extended"] == []          # not tried from another cable
    assert "% of the held-out residual" in d.findings[0].sentence()
    assert d.summary()[0].startswith("verdict: creep on cable 2")


def test_block_gain_test_is_not_fooled_by_a_smooth_residual():
    # a smooth residual (random walk) and an unrelated smooth regressor: per tick they
    # correlate "significantly", per block the gain of fitting one to the other is noise
    rng = np.random.default_rng(1)
    n, k = 3000, 20
    hits = 0
    for _ in range(20):
        r = np.cumsum(rng.standard_normal(n)) * 0.01 + 0.1 * rng.standard_normal(n)
        z = np.cumsum(rng.standard_normal(n)) * 0.01
        blocks = np.array_split(np.arange(n), k)
        e0, e1 = [], []
        for b in blocks:
            m = np.ones(n, bool)
            m[b] = False
            X = np.column_stack([np.ones(n), z])
            beta, *_ = np.linalg.lstsq(X[m], r[m], rcond=None)
            beta0 = r[m].mean()
            e1.append(r[b] - X[b] @ beta)
            e0.append(r[b] - beta0)
        hits += block_gain_test(e0, e1, 0.1)["p"] < 0.05
    assert hits <= 3


def test_holm_adjusts_for_all_tries():
    adj = holm({"a": 0.001, "b": 0.02}, tries=10)
    assert adj["a"] == pytest.approx(0.01)
    assert adj["b"] == pytest.approx(0.18)


def _balanced(seed=0, n=2000, swing=0.0):
    """Poses near home and cable forces that balance the platform's weight exactly
    (002 eq 2), with a common pretension in the null space of A^T (``swing`` [N]: a
    0.4 Hz swing of that pretension, the internal force changing faster than the pose)."""
    rob = load_robot(ROBOT)
    g = rob.geometry()
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    P = np.column_stack([0.05 * np.sin(2 * np.pi * 0.11 * t), 0.04 * np.sin(2 * np.pi * 0.07 * t + 1),
                         0.03 * np.sin(2 * np.pi * 0.05 * t)])
    Q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    ik = inverse_kinematics(g, P, Q)
    AT = structure_matrix(ik.unit, ik.anchor_world)
    w = platform_wrench(g, ik.rotation)
    f = np.empty((n, g.n_cables))
    for i in range(n):
        pinv = np.linalg.pinv(AT[i])
        null = np.eye(g.n_cables) - pinv @ AT[i]
        f[i] = -pinv @ w[i] + null @ np.full(g.n_cables, 150.0 + swing * np.sin(2 * np.pi * 0.4 * t[i]))
    assert np.all(f > 10.0)
    return g, t, P, Q, f, rng


def test_equilibrium_tells_a_sensor_offset_from_a_balanced_recording():
    g, t, P, Q, f, rng = _balanced()
    y = f + 0.1 * rng.standard_normal(f.shape)
    noise = np.full(g.n_cables, 0.1)
    ok = equilibrium_check(g, t, P, Q, y, noise)
    assert ok["holds"] and ok["sensor"] == {} and ok["delay"] == {} and ok["ratio"] < 1.3
    y2 = y.copy()
    y2[:, 2] += 0.5                      # sensor offset on cable 2 only
    bad = equilibrium_check(g, t, P, Q, y2, noise)
    assert list(bad["sensor"]) == [2]
    assert bad["sensor"][2]["mean_N"] == pytest.approx(0.5, abs=0.1) and bad["holds"]


def test_equilibrium_says_when_it_cannot_place_a_sensor_error():
    """With 8 cables and 6 wrench rows, over poses within a few cm, offsets on cables 4, 5
    and 6 balance like one offset on cable 7 (the selection, fewest cables first, picks 7).
    The check must say that cables 4, 5, 6 balance as well, and the finding's words must
    carry it, instead of sending a user to recalibrate cable 7 alone."""
    g, t, P, Q, f, rng = _balanced()
    y = f + 0.1 * rng.standard_normal(f.shape)
    noise = np.full(g.n_cables, 0.1)
    y[:, [4, 5, 6]] += 0.5
    res = equilibrium_check(g, t, P, Q, y, noise)
    assert res["holds"]
    named = set(res["sensor"])
    alts = {c: set(v["or_cables"]) for c, v in res["sensor"].items()}
    # the truth is either what was named or, for one named cable, its alternative
    assert named == {4, 5, 6} or any(o == {4, 5, 6} and named == {c} for c, o in alts.items())
    assert all(not (o & named) for o in alts.values())          # an alternative names other cables
    from cablesvc.discover.pipeline import _placement
    text = _placement({c: v["or_cables"] for c, v in res["sensor"].items() if v["or_cables"]})
    if named != {4, 5, 6}:
        assert "4, 5, 6" in text and "cannot place" in text


@pytest.mark.parametrize("cables", [(1, 5, 7), (2, 5, 7), (0, 3, 7)])
def test_equilibrium_places_sensor_errors_as_a_set(cables):
    """Offsets on three cables balance much like one on another cable (on these poses, 1, 5
    and 7 like 3; 2, 5 and 7 like 0). A search that adds the cable explaining most first
    takes that other cable, after which the true ones no longer pay beside it (it named
    1, 3; 0; and 2, 3, 5). Scored as sets, the true one balances best and each of its
    cables earns its place."""
    g, t, P, Q, f, rng = _balanced()
    y = f + 0.1 * rng.standard_normal(f.shape)
    noise = np.full(g.n_cables, 0.1)
    y[:, list(cables)] += 0.5
    res = equilibrium_check(g, t, P, Q, y, noise)
    assert res["holds"] and res["ratio"] < 1.3
    assert sorted(res["sensor"]) == list(cables)
    for c in cables:
        assert res["sensor"][c]["mean_N"] == pytest.approx(0.5, abs=0.15)
        assert res["sensor"][c]["p"] < 0.01


def test_equilibrium_finds_a_force_channel_that_lags_and_how_much():
    """A reading that lags the present force by tau (the platform balances the force, the
    sensor shows the one of tau ago) breaks the balance along that cable's column; putting
    the lag back restores it. Neither a sensor offset nor another cable takes its place."""
    g, t, P, Q, f, rng = _balanced(swing=5.0)
    noise = np.full(g.n_cables, 0.1)
    y = f + 0.1 * rng.standard_normal(f.shape)
    ok = equilibrium_check(g, t, P, Q, y, noise, block=1.25)
    assert ok["holds"] and ok["delay"] == {} and ok["sensor"] == {}
    tau = 0.12
    y[:, 5] = np.interp(t - tau, t, f[:, 5]) + 0.1 * rng.standard_normal(t.size)
    res = equilibrium_check(g, t, P, Q, y, noise, block=1.25)
    assert res["ratio_raw"] > 2.0                    # the lag breaks the balance ...
    assert list(res["delay"]) == [5] and res["sensor"] == {}
    assert res["holds"] and res["ratio"] < 1.3       # ... and the lag put back restores it
    d = res["delay"][5]
    assert d["p"] < 0.01
    assert d["tau_s"] == pytest.approx(tau, abs=0.01)
    # a streamed discovery keeps groups of ticks with gaps between them: the lag is put
    # back within each stretch, never across a gap
    keep = np.r_[0:700, 1100:1500, 1700:2000]
    res = equilibrium_check(g, t[keep], P[keep], Q[keep], y[keep], noise, block=1.25)
    assert list(res["delay"]) == [5] and res["sensor"] == {} and res["ratio"] < 1.3
    assert res["delay"][5]["tau_s"] == pytest.approx(tau, abs=0.01)


def test_equilibrium_reports_when_the_forces_do_not_balance():
    g, t, P, Q, f, rng = _balanced()
    # forces of a pose 5 mm away: no sensor column explains that
    ik = inverse_kinematics(g, P + np.array([0.005, 0.0, 0.0]), Q)
    y = f + 0.1 * rng.standard_normal(f.shape)
    AT = structure_matrix(ik.unit, ik.anchor_world)
    AT0 = structure_matrix(*[getattr(inverse_kinematics(g, P, Q), k) for k in ("unit", "anchor_world")])
    drift = np.einsum("nim,nm->ni", AT - AT0, f)
    y = y + 0.2 * np.sin(2 * np.pi * 0.2 * t)[:, None] * np.linspace(-1, 1, f.shape[1])[None] \
        + np.einsum("ni,ni->n", drift, drift)[:, None] * 0.0
    res = equilibrium_check(g, t, P, Q, y, np.full(f.shape[1], 0.1))
    assert not res["holds"]


def test_cli_calib_identifies_then_discovers_and_prints_the_verdict_first(tmp_path, capsys):
    from cablesvc.cli.main import main
    simulate_recording(ROBOT, "hold-sine", tmp_path / "calib.mcap", truth=TruthConfig(noise_std=0.1),
                       duration=None, rate=100, seed=2)
    _rec(["creep:1.0@2"], seed=4, path=tmp_path / "r.mcap")
    assert main(["discover", "--robot", ROBOT, "--calib", str(tmp_path / "calib.mcap"), str(tmp_path / "r.mcap"),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["mode"] == "identified" and doc["verdict"].startswith("verdict: ")
    assert doc["baseline"]["model"] == "amplitude"
    assert main(["discover", "--robot", ROBOT, "--calib", str(tmp_path / "calib.mcap"), str(tmp_path / "r.mcap")]) == 0
    assert capsys.readouterr().out.splitlines()[0].startswith("verdict: ")
    assert main(["discover", "--robot", ROBOT, "--calib", str(tmp_path / "nope.mcap"), str(tmp_path / "r.mcap")]) == 1
    assert "nope.mcap" in capsys.readouterr().err


def test_block_screen_names_a_term_only_where_it_explains_most_of_the_residual():
    # cable 2: a viscous force alone; cable 5: a rate-dependent misfit of another form (a
    # relaxing branch, time constant 1 s, the kind an imperfect baseline leaves), which the
    # viscous column explains in part. Only on cable 2 does the term explain most of what
    # the recalibrated baseline leaves
    from cablesvc.discover.pipeline import build_signals, split_blocks
    from cablesvc.discover.screen import BlockScreen
    from cablesvc.models.terms import LIBRARY, Recalibration

    rob = load_robot(ROBOT)
    s = build_signals(_rec([], seed=5), rob, baseline_params(rob))
    train, valid, _ = split_blocks(s.t, 2.5)
    s.train = train
    rng = np.random.default_rng(4)
    r = 0.1 * rng.standard_normal(s.y.shape)
    r[:, 2] += 0.5 * s.v[:, 2] / np.sqrt(np.mean(s.v[:, 2] ** 2))
    r[:, 5] += 1.0 * _unit(_relaxing(s.x[:, 5], s.t, 1.0))
    noise = np.full(s.m, 0.1)
    sel = BlockScreen().select(s, r, [LIBRARY["viscous"]], train, valid, noise=noise, base=[Recalibration()])
    assert sel.named() == {"viscous": [2]}
    t2, t5 = sel.tests[("viscous", 2)], sel.tests[("viscous", 5)]
    assert t2["passed"] and t2["share"] > 0.8 and t2["p_holm"] < 0.05
    assert t5["share"] < 0.8 and t5["gain"] > 1.0 and not t5["passed"]
    # without the share rule and the test, the gain alone would name it on cable 5 too
    loose = BlockScreen(alpha=1.01, share_min=0.0).select(s, r, [LIBRARY["viscous"]], train, valid, noise=noise,
                                                           base=[Recalibration()])
    assert {2, 5} <= set(loose.named()["viscous"])


def test_block_screen_counts_the_share_beyond_the_noise():
    # a perfect baseline, a slow force drift of 2 x the noise RMS on cable 6: the
    # recalibration absorbs part of it, and what is left is about 2.5 noise variances
    # against 1 of noise. The old rule (share of the residual, noise included, >= 0.8)
    # refused it; the share of what exceeds the noise is nearly all of it
    from cablesvc.discover.pipeline import build_signals, split_blocks
    from cablesvc.discover.screen import BlockScreen
    from cablesvc.models.terms import LIBRARY, Recalibration

    rob = load_robot(ROBOT)
    s = build_signals(_rec([], seed=5), rob, baseline_params(rob))
    train, valid, _ = split_blocks(s.t, 2.5)
    s.train = train
    drift = 1.0 - np.exp(-s.t / 4.0) + 0.02 * s.t
    drift = -(drift - drift.mean()) / drift.std()          # creep lowers the force
    r = 0.1 * np.random.default_rng(5).standard_normal(s.y.shape)
    r[:, 6] += 0.2 * drift
    sel = BlockScreen().select(s, r, [LIBRARY["creep"]], train, valid, noise=np.full(s.m, 0.1),
                               base=[Recalibration()])
    t6 = sel.tests[("creep", 6)]
    assert sel.named() == {"creep": [6]}
    assert t6["share"] < 0.8 < 0.9 < t6["excess_share"]


def test_block_screen_rule():
    # named: significant, most of the excess over the noise, and at least gain_min
    from cablesvc.discover.screen import BlockScreen
    screen = BlockScreen(alpha=0.05, share_min=0.9, gain_min=0.25)
    assert screen._ok({"gain": 0.3, "before": 1.3}, 0.001)
    assert not screen._ok({"gain": 0.3, "before": 1.3}, 0.2)        # not significant
    assert not screen._ok({"gain": 0.1, "before": 1.1}, 0.001)      # too small to matter
    assert not screen._ok({"gain": 2.0, "before": 4.0}, 0.001)      # a part of a larger misfit
    assert screen._ok({"gain": 2.8, "before": 4.0}, 0.001)
    assert screen._ok({"gain": 0.3, "before": 0.9}, 0.001)          # nothing beyond the noise left


def test_exact_signed_rank_p_values_equal_scipys():
    from scipy import stats

    from cablesvc.discover.evidence import signed_rank_test
    rng = np.random.default_rng(3)
    for n in (5, 6, 12, 18, 33, 50):
        for shift in (-0.5, 0.0, 0.7):
            g = rng.standard_normal(n) + shift
            w, p = signed_rank_test(g)
            ref = stats.wilcoxon(g, alternative="greater")
            assert w == ref.statistic and p == pytest.approx(ref.pvalue, rel=1e-12, abs=1e-15)
    g = np.r_[np.ones(4), 2.0, 2.0, -1.0, 3.0]                # ties: scipy's own method
    assert signed_rank_test(g)[1] == pytest.approx(stats.wilcoxon(g, alternative="greater").pvalue)


def _screen_signals():
    from cablesvc.discover.pipeline import build_signals, split_blocks
    rob = load_robot(ROBOT)
    s = build_signals(_rec([], seed=5), rob, baseline_params(rob))
    train, valid, _ = split_blocks(s.t, 2.5)
    s.train = train
    return s, train, valid


def _unit(x):
    return x / np.sqrt(np.mean(x ** 2))


def _relaxing(x, t, tau):
    """A relaxing (Maxwell) branch's stretch [m]: dy/dt = dx/dt - y / tau, exact for x
    piecewise linear in t."""
    from scipy.signal import lfilter
    dt = float(np.median(np.diff(t)))
    a = np.exp(-dt / tau)
    return lfilter([tau / dt * (1.0 - a)], [1.0, -a], np.diff(x, prepend=x[0]))


def _WithoutDamping():
    """The recalibration without its damping columns (002 eq 8's rate law, level free)."""
    from cablesvc.models.terms import Recalibration
    from cablesvc.models.terms.recalibration import _RATE

    class WithoutDamping(Recalibration):
        def design(self, s, c, h):
            return super().design(s, c, h).without(_RATE)

    return WithoutDamping()


def _envelope_damping(x, t, alpha, t_env=30.0):
    """A damping force of 002 eq 8's rate law whose level follows a running envelope of x
    (half its peak-to-peak, the gap shrinking with ``t_env`` [s]) and whose speed scale is
    the running peak speed, decaying alike: not the baseline's reversal-point amplitude."""
    dt = float(np.median(np.diff(t)))
    out, hi, lo, ve = np.zeros(x.size), x[0], x[0], 1e-6
    for n in range(1, x.size):
        gap = hi - lo
        hi = max(x[n], hi - 0.5 * gap * dt / t_env)
        lo = min(x[n], lo + 0.5 * gap * dt / t_env)
        v = (x[n] - x[n - 1]) / dt
        ve = max(abs(v), ve * (1.0 - dt / t_env), 1e-6)
        out[n] = np.tanh(0.5 * (hi - lo) / 2e-3) * np.sign(v) * (abs(v) / ve) ** alpha
    return out


def test_recalibration_takes_a_damping_law_with_another_amplitude_estimate():
    # cables 2 and 3 carry 10 x the noise of a damping force of 002 eq 8's rate law whose
    # level follows a running envelope of the elongation (the realistic bench's truth
    # damps so; the baseline scales its damping by the last reversal amplitude); cable 2
    # also carries a viscous force. The recalibration's damping columns take the damping
    # law and leave the viscous force to be named
    from cablesvc.discover.evidence import block_ids, loo_errors
    from cablesvc.discover.screen import BlockScreen
    from cablesvc.models.terms import LIBRARY, Recalibration

    s, train, valid = _screen_signals()
    r = 0.1 * np.random.default_rng(8).standard_normal(s.y.shape)
    for c in (2, 3):               # an exponent the columns do not have (0 and 0.25)
        r[:, c] += 1.0 * _unit(_envelope_damping(s.x[:, c], s.t, 0.4))
    r[:, 2] += 1.0 * _unit(s.v[:, 2])
    blocks = block_ids(s.t, 1.25, train | valid)

    def excess(term):
        return np.mean([np.mean(e ** 2) for e in loo_errors(s, 3, r[:, 3], [term], [{}], blocks)]) / 0.01 - 1.0

    before, after = excess(_WithoutDamping()), excess(Recalibration())
    assert before > 2.0 and after < 0.1 * before
    sel = BlockScreen().select(s, r, [LIBRARY["viscous"]], train, valid, noise=np.full(s.m, 0.1),
                               base=[Recalibration()])
    assert sel.named() == {"viscous": [2]}
    from cablesvc.discover.nuisance import describe_recalibration
    fit = sel.fits[3].params["baseline"]
    assert abs(fit["c_r0_e"]) + abs(fit["c_r25_e"]) > 0.0
    assert "per mm of envelope" in describe_recalibration(fit)


def test_block_screen_names_a_second_effect_beside_the_first_on_one_cable():
    # cable 6: a viscous force and a creep drift. Creep alone cannot explain the residual
    # the viscous force dominates (its test alone fails), but beside the viscous term it
    # explains nearly all that is left; it was never tried there when only terms that
    # passed alone were tried beside the first. (The recalibration's damping columns take
    # part of a viscous force: at 20 x the noise beside this drift it explained 0.89 of the
    # excess, short of the 0.9 that names it; at 30 x, 0.95)
    from cablesvc.discover.screen import BlockScreen
    from cablesvc.models.terms import LIBRARY, Recalibration
    s, train, valid = _screen_signals()
    drift = 1.0 - np.exp(-s.t / 4.0) + 0.02 * s.t
    r = 0.1 * np.random.default_rng(5).standard_normal(s.y.shape)
    r[:, 6] += 3.0 * _unit(s.v[:, 6]) - 0.3 * (drift - drift.mean()) / drift.std()
    sel = BlockScreen().select(s, r, [LIBRARY["viscous"], LIBRARY["creep"]], train, valid, noise=np.full(s.m, 0.1),
                               base=[Recalibration()])
    assert sel.named() == {"viscous": [6], "creep": [6]}
    assert not sel.tests[("creep", 6)]["passed"]
    j = sel.joint[("creep", 6)]
    assert j["passed"] and j["excess_share"] > 0.9 and j["p_holm"] < 0.05


def test_block_screen_tries_a_named_mechanism_on_the_robots_other_cables():
    # viscous friction on cables 2 and 5; cable 5 also carries a rate-dependent misfit of
    # another form (a relaxing branch, 1 s), so the viscous term explains only 0.6-0.9 of
    # its excess and fails the
    # per-cable share. Named on cable 2, it is tried on the other cables with Holm over
    # those tries and share_robot; the share_robot equal to share_min turns that off
    from cablesvc.discover.screen import BlockScreen
    from cablesvc.models.terms import LIBRARY, Recalibration
    s, train, valid = _screen_signals()
    r = 0.1 * np.random.default_rng(6).standard_normal(s.y.shape)
    r[:, 2] += 0.5 * _unit(s.v[:, 2])
    r[:, 5] += 0.5 * _unit(s.v[:, 5]) + 0.6 * _unit(_relaxing(s.x[:, 5], s.t, 1.0))
    args = (s, r, [LIBRARY["viscous"]], train, valid)
    kw = dict(noise=np.full(s.m, 0.1), base=[Recalibration()])
    sel = BlockScreen(share_robot=0.5).select(*args, **kw)
    t5 = sel.tests[("viscous", 5)]
    assert 0.6 < t5["excess_share"] < 0.9 and not t5["passed"]
    assert sel.named() == {"viscous": [2, 5]}
    j = sel.joint[("viscous", 5)]
    assert j["robot"] and j["p_holm"] < 0.05 and j["p_holm"] <= 7 * j["p"]     # 7 further cables tried
    assert BlockScreen(share_robot=0.9).select(*args, **kw).named() == {"viscous": [2]}
    # a further cable's term must also carry at least gain_further noise variances
    assert j["gain"] < 1e3 and BlockScreen(gain_further=1e3).select(*args, **kw).named() == {"viscous": [2]}


def test_block_screen_holds_the_lag_the_balance_measured():
    # a force channel lagging 0.08 s and a viscous force on cable 4; the dead time comes
    # from outside evidence (the forces' balance) with its lag. Refitted on the force
    # residual, the lag shrinks to take up the viscous force; held, it is the balance's
    # lag and the viscous force is named beside it. The screen's mechanism is tried beside
    # the recalibration without its damping columns: with them, they take part of the
    # viscous force themselves and the lag does not shrink (measured: the refitted lag
    # stayed at 0.08 s, and the viscous force beside it explained 0.79-0.84 of the excess
    # at Holm p 0.10-0.51, unnamed)
    from cablesvc.discover.screen import BlockScreen
    from cablesvc.models.terms import LIBRARY
    s, train, valid = _screen_signals()
    dt = LIBRARY["deadtime"]
    r = 0.1 * np.random.default_rng(7).standard_normal(s.y.shape)
    r[:, 4] += dt.design(s, 4, {"tau": 0.08}).fixed + 0.5 * _unit(s.v[:, 4])
    terms = [LIBRARY["viscous"], dt]
    kw = dict(noise=np.full(s.m, 0.1), base=[_WithoutDamping()])
    held = BlockScreen().select(s, r, terms, train, valid, evidence={
        ("deadtime", 4): {"source": "balance", "p": 1e-6, "hyper": {"tau": 0.08}}}, **kw)
    assert held.fits[4].hyper["deadtime"]["tau"] == 0.08
    assert held.named() == {"deadtime": [4], "viscous": [4]}
    free = BlockScreen().select(s, r, terms, train, valid, evidence={
        ("deadtime", 4): {"source": "balance", "p": 1e-6}}, **kw)
    assert free.fits[4].hyper["deadtime"]["tau"] < 0.02 and free.named() == {"deadtime": [4]}


def test_held_out_recalibration_holds_its_amplitude_correction_where_no_other_block_went():
    # cable 3: the reversal amplitude is zero except in one block (one large swing), and the
    # residual is sensor noise only. Left out, that block lies beyond what the fold's fit
    # saw: the recalibration's amplitude correction must be held at its edge there, as the
    # fitted model holds it, not extrapolated (a term that tamed the extrapolation looked
    # like most of the residual and was named on a control of the realistic bench)
    from cablesvc.discover.evidence import block_ids, loo_errors
    from cablesvc.models.terms import Recalibration

    class Unheld(Recalibration):
        def design(self, s, c, h):
            d = super().design(s, c, h)
            d.held = ()
            return d

    s, train, valid = _screen_signals()
    c = 3
    blocks = block_ids(s.t, 1.25, train | valid)
    lone = blocks[7]
    a = np.zeros(s.n)
    a[lone] = 2e-3 * (1.0 + 0.5 * np.sin(np.linspace(0.0, 6.0, lone.size)))
    a[blocks[3]] = 1e-5
    s.amplitude = s.amplitude.copy()
    s.amplitude[:, c] = a
    r = 0.1 * np.random.default_rng(2).standard_normal(s.n)

    def per_block(term):
        return np.array([np.mean(e ** 2) / 0.01 for e in loo_errors(s, c, r, [term], [{}], blocks)])

    held, unheld = per_block(Recalibration()), per_block(Unheld())
    assert unheld[7] > 100.0                       # extrapolated: what the old estimate did
    assert held[7] < 1.5                           # held: the noise
    others = [k for k in range(len(blocks)) if k != 7]
    assert np.allclose(held[others], unheld[others], rtol=0.2)   # blocks within the support barely change


def test_travel_probe_finds_a_force_that_repeats_with_one_cables_travel():
    # every cable carries a smooth model-form misfit (a function of its elongation and a
    # power of its rate); cable 4 also carries 0.2 N that repeats every 0.1 m of its travel
    # (a drum running out of round). The probe finds that period beside the recalibration
    # and explains most of what is left there; elsewhere it gains far less than the noise
    from cablesvc.discover.evidence import block_ids
    from cablesvc.discover.periodic import MIN_TURNS, PERIOD_MIN, travel_periods, travel_probe
    from cablesvc.discover.pipeline import PERIODIC_GAIN_MIN
    from cablesvc.models.terms import Recalibration
    s, train, valid = _screen_signals()
    fit = train | valid
    blocks = block_ids(s.t, 1.25, fit)
    r = 0.1 * np.random.default_rng(4).standard_normal(s.y.shape)
    for c in range(s.m):
        r[:, c] += 0.3 * _unit(s.x[:, c] - s.x[:, c].mean()) ** 2 + 0.2 * _unit(np.sign(s.v[:, c]) * np.abs(s.v[:, c]) ** 0.5)
    r[:, 4] += 0.2 * np.sin(2.0 * np.pi * s.free_length[:, 4] / 0.1 + 0.7)
    for c in range(s.m):
        travel = np.ptp(s.free_length[fit, c])
        P = travel_periods(travel)
        assert P.size and P.min() >= PERIOD_MIN - 1e-12 and travel / P.max() >= MIN_TURNS - 1e-9
        pr = travel_probe(s, c, r[:, c], [Recalibration()], [{}], train, fit, blocks, 0.1)
        if c == 4:
            assert abs(pr["period_m"] - 0.1) < 0.002 and abs(pr["amplitude_N"] - 0.2) < 0.04
            assert pr["p"] < 0.01 and pr["excess_share"] > 0.5 and pr["gain"] > PERIODIC_GAIN_MIN
        else:
            assert pr["gain"] < 0.5 * PERIODIC_GAIN_MIN, (c, pr)
    assert travel_periods(3.9 * PERIOD_MIN).size == 0          # fewer than four turns of the shortest period


def test_block_screen_names_an_effect_that_stands_out_above_the_robots_model_form():
    # a term that leaves its cable no worse than the robot's typical excess and gains at
    # least three times it is named although it explains less than 90 % of its cable's
    # excess (that cable's own share of the model form stays); nothing else changes
    from cablesvc.discover.screen import BlockScreen, typical_excess
    screen = BlockScreen()
    t = {"gain": 6.0, "before": 8.0}                         # excess 7, share 0.857
    assert not screen._ok(t, 0.001)                          # the share rule alone
    assert screen._ok(t, 0.001, typical=1.5)                 # leaves 1.0 <= 1.5, gains 6 >= 4.5
    assert not screen._ok(t, 0.001, typical=2.5)             # gains less than 3 x 2.5
    assert not screen._ok(t, 0.001, typical=0.8)             # leaves more than the typical cable
    assert not screen._ok(t, 0.2, typical=1.5)               # still needs its block test
    assert not screen._ok(t, 0.001, share=0.9, typical=1.5)  # a given share is the share alone
    assert not BlockScreen(typical_gain=math.inf)._ok(t, 0.001, typical=1.5)
    # and, like a term named beside another, at least gain_further (3 noise variances)
    small = {"gain": 2.0, "before": 3.4}                     # excess 2.4, share 0.83
    assert not screen._ok(small, 0.001, typical=0.5)
    assert BlockScreen(gain_further=1.5)._ok(small, 0.001, typical=0.5)
    # the least gain it accepts is the one required_gain reports, for both routes
    for excess, typ in ((0.5, 1.0), (1.0, 1.0), (3.0, 1.0), (0.2, 0.0), (2.0, 4.0), (0.3, 0.4)):
        g = screen.required_gain(excess, typ)
        assert screen._ok({"gain": g * (1 + 1e-9), "before": 1.0 + excess + g}, 0.001, typical=typ)
        assert not screen._ok({"gain": 0.97 * g, "before": 1.0 + excess + 0.97 * g}, 0.001, typical=typ)
    assert screen.required_gain(1.0, 1.0) == pytest.approx(3.0)
    assert screen.required_gain(1.0) == pytest.approx(9.0)
    # the typical excess is the median cable's, beyond the noise, never below 0
    e = {c: [np.full(50, a), np.full(50, a)] for c, a in enumerate((0.1, 0.2, 0.3, 1.0, 0.05))}
    np.testing.assert_allclose(typical_excess(e, np.full(5, 0.1)), 3.0)  # 0.2 N: 4 noise variances
    # counted in N^2: the same force error of 0.03 N^2 on every cable, three of five cables
    # with sensors three times as noisy. Counted in each cable's own noise variances the
    # median was theirs, 0.33, and the quiet cables' ordinary excess of 3 stood 9 x above it
    noise = np.array([0.1, 0.1, 0.3, 0.3, 0.3])
    e = {c: [np.full(50, np.sqrt(sg ** 2 + 0.03))] for c, sg in enumerate(noise)}
    np.testing.assert_allclose(typical_excess(e, noise), 0.03 / noise ** 2)


def test_held_out_hold_of_the_recalibration_does_not_depend_on_the_term_beside_it():
    # leave-one-block-out holds the recalibration's amplitude correction within what the
    # fold's fit saw, by its own part beyond the recalibration's other columns. A term
    # tested beside it must not change that hold: where a term's column lies outside the
    # fold's range (time, on the first block), projecting on it moved the held part, and a
    # true creep on development seed 271828 (case 36) lost 158 noise variances on that
    # block from the hold alone, with the same coefficients
    from cablesvc.discover.evidence import _Held, block_ids
    from cablesvc.discover.select import DesignCache, joint_designs, strips_nuisance
    from cablesvc.models.terms import LIBRARY, Recalibration
    s, train, valid = _screen_signals()
    blocks = block_ids(s.t, 1.25, train | valid)
    allb = np.zeros(s.n, bool)
    for b in blocks:
        allb[b] = True
    R, C = Recalibration(), LIBRARY["creep"]
    cache = DesignCache()
    rng = np.random.default_rng(3)
    moved = 0
    for c in range(s.m):
        alone = joint_designs([R], [{}], s, c, cache, strips_nuisance([R]))
        both = joint_designs([R, C], [{}, {"tau": 5.0}], s, c, cache, strips_nuisance([R, C]))
        if not alone[0].held:
            continue
        p = rng.standard_normal(alone[0].p)
        h1, h2 = _Held(alone, blocks), _Held(both, blocks)
        for i, b in enumerate(blocks):
            mask = allb.copy()
            mask[b] = False
            ch1 = h1.change([p], i, mask, b)
            ch2 = h2.change([p, rng.standard_normal(both[1].p)], i, mask, b)
            assert np.allclose(ch1, ch2, rtol=1e-6, atol=1e-9 * (1.0 + np.abs(ch1).max())), (c, i)
            moved += bool(np.any(ch1 != 0.0))
    assert moved > 0           # some block is held at all: the comparison is not empty


def _bouc_wen_loop(x, z_y=2e-3):
    """A rate-independent Bouc-Wen loop (n = 2, beta 0.75, gamma 0.25; the realistic bench's
    ``--truth-hysteresis boucwen`` law) driven by the elongation x [m]: z / z_y in [-1, 1]."""
    from cablesvc.bench.truth import _bouc_wen
    z = np.zeros(x.size)
    for n in range(1, x.size):
        z[n] = _bouc_wen(z[n - 1], x[n] - x[n - 1], z_y)
    return z / z_y


def test_recalibration_takes_a_rate_independent_loop_only_where_most_cables_show_one():
    # a Bouc-Wen loop (not the stops' own form) at 5 x the noise on every cable: the gate
    # takes the recalibration's stops, which then leave far less of it held out. The same
    # loop on two cables only (a concealed effect's reach) or on none leaves them out
    from cablesvc.discover.evidence import block_ids, loo_errors
    from cablesvc.discover.nuisance import describe_recalibration, loop_gate
    from cablesvc.discover.select import fit_terms
    from cablesvc.models.terms import Recalibration
    from cablesvc.models.terms.recalibration import STOPS

    s, train, valid = _screen_signals()
    blocks = block_ids(s.t, 1.25, train | valid)
    noise = np.full(s.m, 0.1)
    rng = np.random.default_rng(21)
    loop = np.column_stack([0.5 * _unit(_bouc_wen_loop(s.x[:, c])) for c in range(s.m)])
    r = 0.1 * rng.standard_normal(s.y.shape) + loop
    g = loop_gate(s, r, noise, blocks)
    assert g["used"] and 2 * len(g["cables"]) > s.m, g

    def excess(term, c):
        return np.mean([np.mean(e ** 2) for e in loo_errors(s, c, r[:, c], [term], [{}], blocks)]) / 0.01 - 1.0

    for c in (0, 5):
        assert excess(Recalibration(stops=True), c) < 0.5 * excess(Recalibration(stops=False), c)
    fit = fit_terms(s, 0, r[:, 0], [Recalibration(stops=True)], train, hypers=[{}]).params["baseline"]
    assert any(fit[n] != 0.0 for n in STOPS) and "rate-independent loop" in describe_recalibration(fit)
    off = fit_terms(s, 0, r[:, 0], [Recalibration(stops=False)], train, hypers=[{}]).params["baseline"]
    assert all(off[n] == 0.0 for n in STOPS)          # held at 0, written so to the file
    some = 0.1 * rng.standard_normal(s.y.shape)
    some[:, [2, 6]] += loop[:, [2, 6]]
    g2 = loop_gate(s, some, noise, blocks)
    assert not g2["used"] and {2, 6} <= set(g2["cables"]), g2     # seen there, not taken robot-wide
    assert not loop_gate(s, 0.1 * rng.standard_normal(s.y.shape), noise, blocks)["used"]


def test_a_term_the_cables_own_loop_explains_as_well_is_not_named():
    # a control of the realistic bench with the Bouc-Wen truth (a rope whose strands slip:
    # a rate-independent loop on every cable, more on some): the gate leaves the loop out
    # of the nuisance, as most cables do not gain from it here, and the screen alone named
    # a sag and a temperature drift on two cables. Each must also beat the model-form
    # alternatives on its cable: the sag does not beat the recalibration with the loop's
    # stops, the temperature drift not the rope's relaxation, and the report says why they
    # are not named. (Seed 11235, control 92; until the amplitude model held its damping's
    # normalised speed at a sine's peak, 5e8ad31, seed 13579's control 81 showed this, with a
    # creep and a sag; with that change its gate takes the loop and nothing passes)
    from cablesvc.discover.screen import BlockScreen
    from cablesvc.models.terms import Recalibration, library

    spec, case, d = _bench_case(11235, "boucwen", 92)
    assert spec.kind == "control"
    assert not d.recalibration["loop"]["used"]
    refused = d.options["model_form_refused"]
    assert refused and d.named == []
    assert all(not v["passed"] for v in refused.values())
    assert refused["sag@6"]["alternative"] == "baseline+stops"
    assert any(line.startswith("not named: sag") and "rate-independent loop" in line for line in d.summary())
    assert d.to_json()["model_form_refused"].keys() == refused.keys()
    # the same screen without the alternative names them: what the bench counted as false
    cands = [t for t in library() if not t.model_form]
    alone = BlockScreen().select(d.signals, d.residual, cands, d.masks["train"], d.masks["valid"], noise=d.noise,
                                 base=[Recalibration()], block=d.options["block"] / 2.0)
    assert {f"{n}@{c}" for n, cs in alone.named().items() for c in cs} == set(refused)


@pytest.mark.parametrize("seed,exponent", [(1, 0.45), (3, 0.5)])
def test_a_damping_more_rate_dependent_than_the_columns_is_not_named_viscous(seed, exponent):
    # cable 2: the rope's own damping, 002 eq 8's rate law at an exponent above the
    # recalibration's (0, 0.25), 10 x the noise; cable 5: a viscous force (exponent 1). A
    # viscous term explains 90 % of the excess on both; on cable 2 the baseline's damping
    # law at exponent 0.5 (a model-form alternative) does as well in its place, on cable 5
    # it does not
    from cablesvc.discover.screen import BlockScreen
    from cablesvc.models.terms import LIBRARY, Recalibration
    from cablesvc.models.terms.recalibration import rate_power
    s, train, valid = _screen_signals()
    r = 0.1 * np.random.default_rng(seed).standard_normal(s.y.shape)
    col = np.empty(s.n)
    rate_power(s.v[:, 2], exponent, col)
    r[:, 2] += 1.0 * _unit(col)
    r[:, 5] += 0.5 * _unit(s.v[:, 5])
    args = (s, r, [LIBRARY["viscous"]], train, valid)
    kw = dict(noise=np.full(s.m, 0.1), base=[Recalibration()])
    alone = BlockScreen().select(*args, **kw)
    assert alone.named() == {"viscous": [2, 5]}
    alt = Recalibration(rate_exponents=(0.0, 0.5))
    sel = BlockScreen().select(*args, alternatives=[alt], **kw)
    assert sel.named() == {"viscous": [5]}
    v = sel.refused[("viscous", 2)]
    assert v["p"] >= 0.05 and v["alternative"] == alt.design_key == "baseline+rate0,0.5"
    assert "rate exponents 0, 0.5" in v["alternative_words"]
    assert sel.confirmed[("viscous", 5)]["p"] < 0.05
    # the alternative's columns are the default's with the second exponent changed
    d0, d1 = Recalibration().design(s, 2, {}), alt.design(s, 2, {})
    assert d0.names == d1.names
    same = [j for j, n in enumerate(d0.names) if not n.startswith("c_r25")]
    assert np.array_equal(d0.X[:, same], d1.X[:, same]) and not np.allclose(d0.X, d1.X)


def test_the_term_that_does_better_block_after_block_is_kept_first(monkeypatch):
    # a single temperature drift (cables 0 and 4) of the realistic bench, development seed
    # 86420, case 23. On cable 0 pulley friction and the temperature term both pass the
    # screen alone, with mean gains 53.3 and 53.2 noise variances (most of it on the first
    # block for both); the temperature term does better on most blocks, significantly so
    # head to head, and is the one kept. Kept by the mean gain alone, the pulley friction
    # went in first, the temperature then explained nothing beside it, and the report
    # named the wrong mechanism
    from cablesvc.bench.discover_cases import case_plan, planned_case
    from cablesvc.discover.screen import BlockScreen

    seed = 86420
    spec = case_plan(40, seed, 4, 1.0, 30.0, "envelope")[23]
    assert spec.kind == "single" and spec.names == ["temperature"]
    case = planned_case(spec, seed)
    sr = case.robot
    assert 0 in case.truth["cables"]
    d = discover(case.recording, sr.robot, case.baseline)
    tests = d.options["tests"]
    assert tests["pulley@0"]["passed"] and tests["temperature@0"]["passed"]
    assert tests["pulley@0"]["gain"] > tests["temperature@0"]["gain"]
    beat = tests["temperature@0"]["beat"]
    # head to head the mean gain is about nil (the first block again); the blocks decide
    assert beat["term"] == "pulley" and beat["p"] < 0.05 and abs(beat["gain"]) < 1.0
    assert {f.term: list(f.cables) for f in d.findings} == {"temperature": [0]}
    # the leader by mean gain alone: the other mechanism went in first and the temperature
    # explained nothing beside it. That pulley friction is now refused at the screen's last
    # step (its wrap-angle stiffness did the work, not its bearing friction), and nothing is
    # named: the true drift is found only where the blocks decide which term leads
    monkeypatch.setattr(BlockScreen, "_lead", lambda self, passing, *a: passing)
    d0 = discover(case.recording, sr.robot, case.baseline)
    assert d0.named == []
    assert d0.options["model_form_refused"]["pulley@0"]["alternative"] == "pulley-without-mu"


def _bench_case(seed, hysteresis, idx):
    """Case ``idx`` of the realistic bench's 40-case plan of ``seed`` on the truth
    ``hysteresis``, as ``cablesvc bench discover`` makes it: (spec, case, discovery)."""
    from cablesvc.bench.discover_cases import case_plan, planned_case

    spec = case_plan(40, seed, 4, 1.0, 30.0, hysteresis)[idx]
    case = planned_case(spec, seed)
    sr = case.robot
    return spec, case, discover(case.recording, sr.robot, case.baseline)


def test_a_loop_that_grows_with_the_force_is_not_named_pulley_friction():
    # seed 11235 of the realistic bench on the Bouc-Wen truth (a rope whose strands slip):
    # on control 81 pulley friction passed the screen on cables 4 and 5. The friction
    # between strands grows with the tension, and the recalibration's stops scaled by the
    # force (an alternative of the rope's own loop) explain those cables as well; on single
    # 28, a true pulley friction on cables 3 and 6 beats that alternative and stays named
    got = {idx: _bench_case(11235, "boucwen", idx) for idx in (81, 28)}
    spec, case, d = got[81]
    assert spec.kind == "control" and d.named == []
    refused = d.options["model_form_refused"]
    # both refused; cable 4 already by the rope's whole loop (the gate left it out there),
    # which is tried before the loop growing with the force
    assert {k for k in refused if k.startswith("pulley@")} == {"pulley@4", "pulley@5"}
    assert refused["pulley@5"]["alternative"].endswith("+force")
    assert refused["pulley@4"]["alternative"] == "baseline+loop"
    assert any("growing with the force" in line for line in d.summary() if line.startswith("not named: pulley"))
    spec, case, d = got[28]
    assert spec.names == ["pulley"]
    assert {f.term: sorted(f.cables) for f in d.findings} == {"pulley": sorted(case.truth["cables"])}
    confirmed = d.options["model_form_confirmed"]
    for c in case.truth["cables"]:       # the last alternative tried: the force-scaled loop
        assert confirmed[f"pulley@{c}"]["alternative"].endswith("+force")
        assert confirmed[f"pulley@{c}"]["p"] < 0.05 and confirmed[f"pulley@{c}"]["gain"] > 0


def test_a_pulley_is_named_only_where_its_bearing_friction_carries_evidence():
    # seed 223606 of the realistic bench on the Bouc-Wen truth: on control 90 pulley
    # friction passed the screen on cables 2 and 6 and beat every alternative of the rope's
    # own loop, but its wrap-angle stiffness column did all of that (a pose-dependent
    # stiffness, the baseline's model form): without mu, the term explains both cables as
    # well held out, and it is not named. On single 0 of seed 173205 (default truth) a true
    # pulley friction on cables 0, 1 and 2 owes its gain to mu and stays named
    got = {(seed, idx): _bench_case(seed, hy, idx) for seed, hy, idx in ((223606, "boucwen", 90),
                                                                          (173205, "envelope", 0))}
    spec, case, d = got[(223606, 90)]
    assert spec.kind == "control" and d.named == []
    refused = d.options["model_form_refused"]
    for c in (2, 6):
        v = refused[f"pulley@{c}"]
        assert v["alternative"] == "pulley-without-mu" and v["signature"]["params"] == ["mu"]
        assert v["p"] >= 0.05
    assert any("term without mu" in line and "carries no evidence" in line for line in d.summary()
               if line.startswith("not named: pulley on cables 2, 6"))
    doc = json.loads(json.dumps(d.to_json()))
    assert {k for k in doc["own_variable_tests"] if k.startswith("pulley@")} >= {"pulley@2", "pulley@6"}
    assert not doc["own_variable_tests"]["pulley@6"]["passed"]
    spec, case, d = got[(173205, 0)]
    assert spec.names == ["pulley"] and case.truth["cables"] == [0, 1, 2]
    assert {f.term: sorted(f.cables) for f in d.findings} == {"pulley": [0, 1, 2]}
    assert not any(k.startswith("pulley@") for k in d.options["model_form_refused"])
    own = d.options["own_variable_tests"]
    for c in (0, 1, 2):
        assert own[f"pulley@{c}"]["passed"] and own[f"pulley@{c}"]["p"] < 0.05 and own[f"pulley@{c}"]["gain"] > 0


def test_a_terms_signature_columns_are_left_out_of_its_reduced_design():
    from cablesvc.discover.select import DesignCache, joint_designs
    from cablesvc.models.terms import LIBRARY

    assert {n for n, t in LIBRARY.items() if t.signature} == {"pulley"}
    for t in LIBRARY.values():
        assert set(t.signature) <= set(t.params)
    rec = _rec([], seed=5, duration=12.0)
    d = discover(rec, load_robot(ROBOT), _wrong_baseline())
    s, pulley = d.signals, LIBRARY["pulley"]
    c = next(c for c in range(s.m) if pulley.applies(s, c))
    reduced = pulley.without_signature()
    assert reduced.name == pulley.name and reduced.design_key != pulley.design_key
    h = pulley.grid(s)[0]
    full, red = pulley.design(s, c, h), reduced.design(s, c, h)
    assert "mu" in full.names and "mu" not in red.names and "mu" in red.dropped
    keep = [full.names.index(n) for n in red.names]
    np.testing.assert_array_equal(red.X, full.X[:, keep])
    # the cache keeps the two apart
    cache = DesignCache()
    a, b = joint_designs([pulley], [h], s, c, cache, False), joint_designs([reduced], [h], s, c, cache, False)
    assert a[0].names != b[0].names


def test_the_force_scaled_loop_is_the_stops_times_the_force_over_its_mean():
    from cablesvc.models.terms import Recalibration
    from cablesvc.models.terms.recalibration import FORCE_LOOP, STOPS

    with pytest.raises(ValueError, match="force_loop needs stops"):
        Recalibration(force_loop=True)
    rec = _rec([], seed=5, duration=12.0)
    d = discover(rec, load_robot(ROBOT), _wrong_baseline())
    s = d.signals
    plain, forced = Recalibration(stops=True), Recalibration(stops=True, force_loop=True)
    a, b = plain.design(s, 2, {}), forced.design(s, 2, {})
    assert b.names[:len(a.names)] == a.names and tuple(b.names[len(a.names):]) == FORCE_LOOP
    assert forced.design_key.endswith("+force") and forced.design_key != plain.design_key
    f_mean = float(np.mean(s.f0[s.train, 2]))
    for st, fl in zip(STOPS, FORCE_LOOP):
        np.testing.assert_allclose(b.X[:, b.names.index(fl)], a.X[:, a.names.index(st)] * s.f0[:, 2] / f_mean,
                                   rtol=1e-12, atol=1e-12)
    assert "growing with the force" in forced.describe_alternative()
    # it confronts only the terms whose force follows the direction of motion (a loop)
    from cablesvc.models.terms import LIBRARY
    assert {n for n, t in LIBRARY.items() if forced.confronts(t)} == {"pulley", "viscous"}
    assert all(plain.confronts(t) for t in LIBRARY.values())


def test_a_maxwell_branch_relaxes_as_exp_minus_t_over_tau():
    from cablesvc.models.relaxation import relaxation_columns

    t = np.arange(0.0, 20.0, 0.01)
    t = np.delete(t, np.arange(1200, 1300))          # a 1 s gap in the record
    x = np.where(t >= 5.0 - 1e-9, 2e-3, 0.0)         # a 2 mm step at 5 s
    x[50] = np.nan                                   # a reading that dropped out
    out = np.empty((2, t.size))
    relaxation_columns(t, x, np.array([2.0, 8.0]), out)
    assert np.all(out[:, :500][:, np.isfinite(x[:500])] == 0.0)   # started relaxed, nothing moved
    assert out[0, 50] == out[0, 49] == 0.0           # a dropped reading holds the state
    for tau, row in zip((2.0, 8.0), out):
        after = t >= 5.0 - 1e-9
        np.testing.assert_allclose(row[after], 2e-3 * np.exp(-(t[after] - 5.0) / tau), rtol=1e-9, atol=1e-15)


def test_the_relaxation_alternative_is_maxwell_branches_and_confronts_temperature_only():
    from cablesvc.models.relaxation import relaxation_columns
    from cablesvc.models.terms import LIBRARY, Recalibration
    from cablesvc.models.terms.recalibration import RELAX, RELAX_TAUS

    rec = _rec([], seed=5, duration=12.0)
    d = discover(rec, load_robot(ROBOT), _wrong_baseline())
    s = d.signals
    plain, relaxed = Recalibration(), Recalibration(relax=True)
    a, b = plain.design(s, 3, {}), relaxed.design(s, 3, {})
    assert b.names[:len(a.names)] == a.names and tuple(b.names[len(a.names):]) == RELAX
    want = np.empty((len(RELAX_TAUS), s.n))
    relaxation_columns(s.t - s.t[0], s.x[:, 3], np.asarray(RELAX_TAUS), want)
    x_scale = b.refs["x_scale"]
    for n, w in zip(RELAX, want):
        np.testing.assert_allclose(b.X[:, b.names.index(n)], w / x_scale, rtol=1e-12, atol=1e-12)
    assert relaxed.design_key.endswith("+relax") and "viscoelastic relaxation" in relaxed.describe_alternative()
    assert {n for n, t in LIBRARY.items() if relaxed.confronts(t)} == {"temperature"}


def test_a_slow_force_the_ropes_relaxation_explains_is_not_named_temperature():
    # seed 11235 of the realistic bench on the Bouc-Wen truth: on control 82 a temperature
    # drift passed the screen on cable 4 (the rope's loop leaves a slow force there, and
    # the temperature's one slow swing follows it); Maxwell branches of 2 and 8 s explain
    # that cable as well held out, and it is not named. A true temperature drift (seed
    # 75319, default truth, single 30, cable 6) beats them and stays named
    got = {idx: _bench_case(seed, hy, idx) for seed, hy, idx in ((11235, "boucwen", 82), (75319, "envelope", 30))}
    spec, case, d = got[82]
    assert spec.kind == "control" and d.named == []
    assert d.options["model_form_refused"]["temperature@4"]["alternative"].endswith("+relax")
    assert any("viscoelastic relaxation" in line for line in d.summary() if line.startswith("not named: temperature"))
    spec, case, d = got[30]
    assert spec.names == ["temperature"] and case.truth["cables"] == [6]
    assert {f.term: sorted(f.cables) for f in d.findings} == {"temperature": [6]}
    conf = d.options["model_form_confirmed"]["temperature@6"]
    assert conf["alternative"].endswith("+relax") and conf["p"] < 0.05


def test_the_whole_loop_alternative_spares_only_the_terms_that_follow_time():
    from cablesvc.models.terms import LIBRARY, Recalibration

    rec = _rec([], seed=5, duration=12.0)
    d = discover(rec, load_robot(ROBOT), _wrong_baseline())
    s = d.signals
    loop, spare = Recalibration(stops=True), Recalibration(stops=True, spare_time=True)
    a, b = loop.design(s, 1, {}), spare.design(s, 1, {})
    assert b.names == a.names and spare.design_key == loop.design_key     # the same columns
    np.testing.assert_array_equal(b.X, a.X)
    assert "state at the start" in spare.describe_alternative()
    # only creep settles from the recording's start (as the loop's unknown state at the start
    # does), only temperature follows a slow course: those two are spared
    assert {n for n, t in LIBRARY.items() if t.settles} == {"creep"}
    assert {n for n, t in LIBRARY.items() if not spare.confronts(t)} == {"creep", "temperature"}
    assert all(loop.confronts(t) for t in LIBRARY.values())


def test_a_term_the_ropes_whole_loop_explains_is_not_named_where_the_gate_left_it_out():
    # seed 11235 of the realistic bench on the Bouc-Wen truth: on control 81 the gate left
    # the rope's loop out, and a pulley friction passed the screen on cable 4; the whole
    # loop, its unknown state at the start included, explains that cable as well held out,
    # and the term is not named. A true sag on the default truth (seed 75319, single 12,
    # cables 3, 4 and 6) beats the loop and stays named. (Until 5e8ad31, the amplitude
    # model's normalised-speed hold, control 93 of the same seed showed this with a sag on
    # cable 2; with it no sag passes the screen there)
    got = {idx: _bench_case(seed, hy, idx) for seed, hy, idx in ((11235, "boucwen", 81), (75319, "envelope", 12))}
    spec, case, d = got[81]
    assert spec.kind == "control" and d.named == []
    assert not d.recalibration["loop"]["used"]
    assert d.options["model_form_refused"]["pulley@4"]["alternative"] == "baseline+loop"
    assert any("state at the start" in line for line in d.summary() if line.startswith("not named: pulley on cable 4"))
    spec, case, d = got[12]
    assert spec.names == ["sag"] and case.truth["cables"] == [3, 4, 6]
    named = {f.term: sorted(f.cables) for f in d.findings}
    assert set(named) == {"sag"} and set(named["sag"]) <= {3, 4, 6}
    assert not any(k.startswith("sag@") for k in d.options["model_form_refused"])


def test_a_residual_a_refused_term_and_the_model_form_both_explain_is_reported_as_undecided():
    # seed 301511 of the realistic bench, default truth, single 2: a temperature drift on
    # cable 5 passed the screen there (it explains 91 % of what the recalibration leaves),
    # but the recalibration with the rope's own relaxation explains that cable as well held
    # out, so it is not named, and the residual is reported unexplained. Neither sentence
    # may then say which it is: the report says the recording cannot tell. Where a refused
    # term's cable keeps no unexplained residual (seed 11235, Bouc-Wen truth, control 82),
    # the refusal still reads as the baseline's model form
    got = {idx: _bench_case(seed, hy, idx) for seed, hy, idx in ((301511, "envelope", 2), (11235, "boucwen", 82))}
    spec, case, d = got[2]
    assert spec.names == ["temperature"] and case.truth["cables"] == [5]
    assert d.named == [] and "temperature@5" in d.options["model_form_refused"]
    assert any(5 in u["cables"] for u in d.unexplained)
    lines = d.summary()
    assert "temperature explains it, and so does the baseline's model form: cannot tell" in lines[0]
    refusal = [line for line in lines if line.startswith("not named: temperature on cable 5")]
    assert len(refusal) == 1 and "cannot tell a concealed temperature" in refusal[0]
    assert "not a concealed effect" not in refusal[0]
    left = [line for line in lines if line.startswith("unexplained residual remains on cables 5")]
    assert left and "temperature explains cable 5 too" in left[0] and "relaxation" in left[0]
    doc = json.loads(json.dumps(d.to_json()))
    tell = [t for u in doc["unexplained"] if 5 in u["cables"] for t in u["cannot_tell"]]
    assert [(t["term"], t["cable"]) for t in tell] == [("temperature", 5)] and tell[0]["alternative"].endswith("+relax")
    spec, case, d = got[82]
    assert spec.kind == "control" and d.named == [] and "temperature@4" in d.options["model_form_refused"]
    assert not any(4 in u["cables"] for u in d.unexplained)
    refusal = [line for line in d.summary() if line.startswith("not named: temperature")]
    assert refusal and refusal[0].endswith("the baseline's model form, not a concealed effect")


class _Named:
    def __init__(self, name):
        self.name = name


def test_partial_leads_take_only_strong_unnamed_unrefused_terms_on_cables_far_above_the_floor():
    from cablesvc.discover.pipeline import ALPHA, GAIN_FURTHER, partial_leads

    def t(gain, p, share=0.8):
        return {"gain": gain, "p_holm": p, "excess_share": share}

    floor = np.array([3.0, 3.0, 3.0, 3.0, 3.0])
    un = {c: {"excess": x} for c, x in enumerate([11.0, 11.0, 2.0, 11.0, 11.0])}
    tests = {("pulley", 0): t(9.0, 0.002), ("temperature", 0): t(7.0, 0.001),   # the strongest gain leads
             ("creep", 1): t(9.0, 2 * ALPHA),                                        # not significant
             ("pulley", 2): t(9.0, 0.002),                                           # excess under the floor
             ("creep", 3): t(GAIN_FURTHER - 0.1, 0.001),                             # gains too little
             ("viscous", 4): t(9.0, 0.002), ("sag", 4): t(8.0, 0.002)}               # refused / named there
    got = partial_leads(tests, {("viscous", 4): {}}, {4: [_Named("recal"), _Named("sag")]}, un, floor, set())
    assert list(got) == [0] and got[0]["term"] == "pulley" and got[0]["share"] == 0.8
    # a cable already reported unexplained keeps its own report
    assert partial_leads(tests, {}, {}, un, floor, {0}) == {4: {"term": "viscous", "gain": 9.0, "share": 0.8,
                                                               "p": 0.002}}


def test_a_cable_the_model_leaves_far_off_is_not_passed_over_in_silence():
    # seed 362880 of the realistic bench, default truth, single 14: a pulley friction on
    # cable 6 leaves 11 noise variances there held out; the library's pulley term explains
    # 81 % of it (p = 0.0018 after Holm), short of the share that names a term, and the
    # excess test, which reads the median block, missed it (the effect sits in a third of
    # the blocks). The report said "nothing significant" while the test RMSE after the model
    # was 6 x the noise there; it now reports the cable unexplained, with the lead
    spec, case, d = _bench_case(362880, "envelope", 14)
    assert spec.names == ["pulley"] and case.truth["cables"] == [6]
    assert d.named == []
    u = [u for u in d.unexplained if 6 in u["cables"]]
    assert len(u) == 1 and u[0]["leads"]["6"]["term"] == "pulley" and 0.5 < u[0]["leads"]["6"]["share"] < 0.9
    assert all(set(v["cables"]) == {6} for v in d.unexplained)       # no other cable
    assert "unexplained residual remains on cable 6" in d.verdict()
    line = [x for x in d.summary() if x.startswith("unexplained residual remains on cables 6")]
    assert line and "pulley explains 81 % of it held out" in line[0]
