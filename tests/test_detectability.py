"""Detection limits: what a recording can show beside the baseline's recalibration
(:mod:`cablesvc.discover.detectability`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cablesvc.config import load_robot
from cablesvc.discover.detectability import describe_limits, detection_limits, unmimicked_share
from cablesvc.discover.screen import BlockScreen
from cablesvc.discover.pipeline import baseline_params, build_signals, split_blocks
from cablesvc.simulate import TruthConfig, simulate_recording

ROBOT = "ipanema3"


def test_unmimicked_share_of_known_signatures():
    rng = np.random.default_rng(1)
    n = 400
    t = np.linspace(0.0, 1.0, n)
    N = np.column_stack([np.ones(n), t])                  # an offset and a ramp
    inside = 2.0 - 3.0 * t
    assert unmimicked_share(N, inside) == pytest.approx(0.0, abs=1e-12)
    b = rng.standard_normal(n)
    b -= N @ np.linalg.lstsq(N, b, rcond=None)[0]         # orthogonal to the span
    assert unmimicked_share(N, b) == pytest.approx(1.0, abs=1e-12)
    # a mix: the share left is the orthogonal part's mean square over the whole one's
    u = inside + 0.5 * b
    want = np.sum((0.5 * b) ** 2) / np.sum(u ** 2)
    assert unmimicked_share(N, u) == pytest.approx(want, rel=1e-10)
    # several columns: the freest combination of them counts (here b alone)
    assert unmimicked_share(N, np.column_stack([inside, u])) == pytest.approx(1.0, abs=1e-10)
    # zero columns are ignored; none left: nothing can be seen
    assert unmimicked_share(N, np.column_stack([np.zeros(n), u])) == pytest.approx(want, rel=1e-10)
    assert unmimicked_share(N, np.zeros(n)) == 0.0
    # a rank-deficient nuisance (a column twice) gives the same answer
    assert unmimicked_share(np.column_stack([N, N[:, 1]]), u) == pytest.approx(want, rel=1e-8)


def test_a_sign_the_term_cannot_take_does_not_count():
    # two columns whose difference the nuisance cannot mimic but whose positive
    # combinations it mostly can (a creep's settling and steady parts both lengthen the
    # cable): free when any sign is allowed, mostly mimicked when both must be >= 0
    from cablesvc.discover.detectability import HeldOutFit
    rng = np.random.default_rng(6)
    n = 500
    t = np.linspace(0.0, 1.0, n)
    N = np.column_stack([np.ones(n), t])
    w = rng.standard_normal(n)
    w -= N @ np.linalg.lstsq(N, w, rcond=None)[0]
    c = 3.0 * np.linalg.norm(w) / np.sqrt(n) * np.ones(n)      # |c|^2 = 9 |w|^2
    cols = np.column_stack([c + w, c - w])
    fit = HeldOutFit(N)
    assert fit.share(cols) == pytest.approx(1.0, abs=1e-9)
    assert fit.share(cols, np.array([True, True])) == pytest.approx(0.1, rel=1e-6)
    assert fit.share(cols, np.array([True, False])) == pytest.approx(1.0, abs=1e-9)   # (1, -1) is allowed


def test_held_out_share_is_at_least_the_in_sample_one():
    # held out, each block fitted by the others: a shape in the nuisance's span is still
    # reproduced exactly; any other is left at least as much as by the in-sample fit, and
    # one that only the block's own ticks pin down (a cubic where one block alone
    # reaches far in x) is left far more
    rng = np.random.default_rng(2)
    n = 600
    blocks = [np.arange(i, i + 50) for i in range(0, n, 50)]
    x = rng.uniform(0.0, 1.0, n)
    x[550:] += 2.0                                         # the last block alone reaches x > 2
    N = np.column_stack([np.ones(n), x, x ** 2])
    assert unmimicked_share(N, 1.0 - 2.0 * x + 0.5 * x ** 2, blocks) == pytest.approx(0.0, abs=1e-9)
    for u in (np.sin(5.0 * x), rng.standard_normal(n), np.exp(x)):
        assert unmimicked_share(N, u, blocks) >= unmimicked_share(N, u) - 1e-12
    cubic = x ** 3                                         # fitted by a parabola only with the far block
    assert unmimicked_share(N, cubic) < 0.01 and unmimicked_share(N, cubic, blocks) > 0.2


def test_required_gain_follows_the_screen_rule():
    screen = BlockScreen(alpha=0.05, share_min=0.9, gain_min=0.25)
    assert screen.required_gain(0.0) == 0.25
    assert screen.required_gain(-1.0) == 0.25
    assert screen.required_gain(1.0) == pytest.approx(9.0)
    # at exactly the required gain the screen's share condition holds, just below it fails
    for excess in (0.05, 0.5, 3.0):
        g = screen.required_gain(excess)
        assert screen._ok({"gain": g * (1 + 1e-9), "before": 1.0 + excess + g}, 0.001)
        assert not screen._ok({"gain": 0.97 * g, "before": 1.0 + excess + 0.97 * g}, 0.001)


@pytest.fixture(scope="module")
def signals():
    rob = load_robot(ROBOT)
    rec = simulate_recording(ROBOT, "trajectory", None, truth=TruthConfig(effects=[], noise_std=0.1),
                             duration=20.0, rate=100, seed=5)
    s = build_signals(rec, rob, baseline_params(rob))
    train, valid, _ = split_blocks(s.t, 2.5)
    s.train = train
    return s, train, valid


def test_the_floor_is_what_the_screen_can_name(signals):
    # a sag signature on cable 3 (its freest shape on this trajectory), white noise
    # elsewhere, a perfect baseline (so the limit is the floor): at twice its floor the
    # screen names it, at half of it the screen cannot (the floor is a lower bound of what
    # can be named)
    from cablesvc.discover.evidence import block_ids
    from cablesvc.discover.screen import BlockScreen
    from cablesvc.models.terms import LIBRARY, Recalibration
    s, train, valid = signals
    sag, c, sigma = LIBRARY["sag"], 3, 0.1
    noise = np.full(s.m, sigma)
    blocks = block_ids(s.t, 1.25, train | valid)          # the screen's test units
    lim = detection_limits(s, [sag], Recalibration(), blocks, noise, 0.0, BlockScreen())[("sag", c)]
    assert 0.0 < lim["free"] < 1.0 and math.isfinite(lim["limit_rms_N"])
    assert lim["limit_rms_N"] == lim["floor_rms_N"] == pytest.approx(sigma * math.sqrt(0.25 / lim["free"]))
    shape = sag.design(s, c, lim["hyper"]).fixed
    shape = shape / np.sqrt(np.mean(shape[train | valid] ** 2))
    base = sigma * np.random.default_rng(8).standard_normal(s.y.shape)
    tests = {}
    for k in (2.0, 0.5):
        r = base.copy()
        r[:, c] += k * lim["limit_rms_N"] * shape
        sel = BlockScreen().select(s, r, [sag], train, valid, noise=noise, base=[Recalibration()])
        tests[k] = sel.tests[("sag", c)]
        assert ("sag" in sel.named() and c in sel.named()["sag"]) == (k > 1)
    assert tests[2.0]["gain"] > 0.25 > tests[0.5]["gain"]
    # no test block (a recording too short for one): nothing to say, no error
    assert detection_limits(s, [sag], Recalibration(), [], noise, 0.0, BlockScreen()) == {}


def test_limits_in_the_discovery_report(tmp_path):
    # creep named beyond a recalibrated, wrong baseline: the other terms get their limits,
    # in words and in the JSON; every limit is at least the noise-only bound and they all
    # come from one required gain
    from tests.test_discover_identified import _rec, _wrong_baseline

    from cablesvc.discover import discover
    d = discover(_rec(["creep:0.8@2"], seed=11), ROBOT, _wrong_baseline())
    assert d.named == ["creep"]
    terms = {row["term"] for row in d.detection}
    assert "creep" not in terms and {"viscous", "temperature", "sag"} <= terms
    lines = d.summary()
    head = next(i for i, line in enumerate(lines) if line.startswith("what this recording cannot show"))
    assert all(lines[head + 1 + i].startswith("  " + row["term"] + " (") for i, row in enumerate(d.detection))
    doc = d.to_json()
    assert doc["detection_limits"] == d.detection
    excess = d.options["model_form_excess_noise_var"]           # per cable, in its noise variances
    assert len(excess) == 8 and min(excess) >= 0.0
    # one excess in N^2 for the robot: the same over each cable's noise variance
    np.testing.assert_allclose(np.array(excess) * d.noise ** 2, excess[0] * d.noise[0] ** 2, rtol=1e-9)
    for row in d.detection:
        for c, lim in row["limit_rms_N"].items():
            free = 1.0 - row["mimicked"][c]
            sigma, floor = d.noise[int(c)], row["floor_rms_N"][c]
            assert lim >= floor >= sigma * math.sqrt(0.25) * (1 - 1e-9)
            if math.isfinite(lim):      # one required gain each: a perfect baseline's, the model form's
                assert (floor / sigma) ** 2 * free == pytest.approx(0.25)
                ex = excess[int(c)]
                assert (lim / sigma) ** 2 * free == pytest.approx(BlockScreen().required_gain(ex, ex))
        assert row["min_floor_rms_N"] == min(row["floor_rms_N"].values())
        assert "even with a perfect baseline" in row["words"]
    # the creep's own cable: the limits of every term are there too, named or not
    assert {"creep@2", "viscous@2"} <= set(d.options["limits"])
    # and the report draws them
    from cablesvc.discover.report import write_report
    files = write_report(d, tmp_path / "rep")
    assert (tmp_path / "rep" / "limits.png").stat().st_size > 10_000 and files["limits"].endswith("limits.png")
    assert '<img src="limits.png">' in (tmp_path / "rep" / "index.html").read_text()


def test_describe_limits_words_and_order():
    def v(free, floor, lim):
        return {"free": free, "floor_rms_N": floor, "limit_rms_N": lim}
    lim = {("sag", 0): v(0.004, 1.0, 2.0), ("sag", 1): v(0.002, 1.4, 2.8), ("pulley", 0): v(0.5, 0.05, 0.1),
           ("creep", 1): v(0.0, math.inf, math.inf), ("viscous", 0): v(0.3, 0.1, 0.2)}
    rows = describe_limits(lim, skip={"viscous"}, labels={"sag": "sag at low tension"})
    assert [r["term"] for r in rows] == ["creep", "sag", "pulley"]      # the worst shown first
    assert "cannot be told from the baseline's recalibration" in rows[0]["words"]
    assert rows[1]["words"].startswith("sag (sag at low tension): not told from the baseline's recalibration "
                                       "below 1-1.4 N RMS even with a perfect baseline, about 2-2.8 N RMS with "
                                       "this one's model form, on cables 0, 1")
    assert "(the recalibration mimics 99.6-99.8 %" in rows[1]["words"]
    assert "(the recalibration mimics 50 %" in rows[2]["words"]
    # no model form: one figure
    one = describe_limits({("creep", 0): v(0.2, 0.1, 0.1), ("creep", 1): v(0.5, 0.07, 0.07)})[0]["words"]
    assert one == ("creep (creep): not told from the baseline's recalibration below 0.07-0.1 N RMS even with a "
                   "perfect baseline (this one's model form adds nothing to it), on cables 0, 1 (the "
                   "recalibration mimics 50-80 % of its shape over this recording)")


def test_held_out_fits_hold_what_the_screen_holds():
    # the limits' held-out fit of the recalibration must be the screen's own: the amplitude
    # columns held within each fold's support (Design.held), else a block whose amplitude
    # no other block reached extrapolates here and not in the screen, and the limits claim
    # a shape is free that the screen's recalibration absorbs
    from cablesvc.discover.detectability import HeldOutFit, held_out_left
    from cablesvc.discover.evidence import block_ids, loo_errors
    from cablesvc.models.terms import Recalibration
    from cablesvc.config.params import ModelParams
    rob = load_robot(ROBOT)
    p = baseline_params(rob)
    tables = dict(p.tables)                 # a baseline whose stiffness follows the amplitude
    tables["K1"] = (np.asarray(tables["K1"], float) * np.linspace(0.9, 1.1, len(tables["amplitudes"]))).tolist()
    p = ModelParams(model=p.model, params=dict(p.params), options=dict(p.options), tables=tables,
                    robot=p.robot, identification=dict(p.identification), source="<amplitude>")
    rec = simulate_recording(ROBOT, "trajectory", None, truth=TruthConfig(effects=[], noise_std=0.1),
                             duration=20.0, rate=100, seed=5)
    s = build_signals(rec, rob, p)
    train, valid, _ = split_blocks(s.t, 2.5)
    s.train = train
    blocks = block_ids(s.t, 1.25, train | valid)
    nuis = Recalibration()
    assert nuis.design(s, 2, {}).held                       # the recalibration holds some columns
    t = s.t - s.t[0]
    f = np.zeros((s.n, s.m))
    f[:, 2] = -0.5 * (1.0 - np.exp(-t / 5.0))                # a settling creep
    f[:, 5] = 0.3 * np.sin(2 * np.pi * 0.13 * t) * s.x[:, 5] / np.max(np.abs(s.x[:, 5]))
    f[:, 3] = 0.02 * s.f0[:, 3] + 0.3                       # a stiffness and pretension error
    got = held_out_left(s, nuis, blocks, f, [2, 3, 5])
    assert got[3] < 1e-12                                    # the recalibration's own: nothing left
    assert got[2] > 1e-4                                     # a settling creep is not all absorbed here
    for c in (2, 5):
        want = float(np.mean(np.concatenate(loo_errors(s, c, f[:, c], [nuis], [{}], blocks)) ** 2))
        assert got[c] == pytest.approx(want, rel=1e-3)      # the same fit, up to its scaling
    # and without the hold the two differ on this trajectory (the test can fail)
    mask = np.zeros(s.n, bool)
    for b in blocks:
        mask[b] = True
    pos = np.cumsum(mask) - 1
    nd = nuis.design(s, 2, {})
    free = HeldOutFit(nd.X[mask], [pos[b] for b in blocks]).left(f[np.concatenate(blocks), 2][:, None])
    assert float(np.mean(free ** 2)) > 1.1 * got[2]
