"""Discovery and identification at the size of real logs (issue 17 item 1): the streamed
path (cablesvc.discover.stream) against the in-memory one, piece boundaries inside
hysteresis branches, decimation, the bounded group sampling, and the chunk reader."""

from __future__ import annotations

import numpy as np
import pytest

from cablesvc.config.robot import load_robot
from cablesvc.discover import discover, library
from cablesvc.discover.pipeline import baseline_params, build_signals
from cablesvc.discover.stream import BlockAccumulator, discover_stream, read_reduced, reduced_recording
from cablesvc.models.reversal import amplitude_stream, reversal_amplitude
from cablesvc.recording import read_recording, write_recording
from cablesvc.recording.chunks import iter_chunks
from cablesvc.simulate import TruthConfig, effect_from_spec, simulate_recording

ROBOT = "ipanema3"


def _sim(path, specs, seed, duration, rate):
    eff = [effect_from_spec(s, 8) for s in specs]
    return simulate_recording(ROBOT, "trajectory", path, truth=TruthConfig(effects=eff, noise_std=0.1),
                              duration=duration, rate=rate, seed=seed)


def test_amplitude_stream_equals_the_whole_record():
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(0, 2e-6, (6000, 3)), axis=0) + 1e-4 * np.sin(np.arange(6000)[:, None] / 90.0 + [0, 1, 2])
    want = reversal_amplitude(x)
    assert np.count_nonzero(np.diff(want[:, 0])) > 20            # many reversals
    for cuts in ([6000], [1, 2, 997, 3000, 6000], list(range(37, 6000, 211)) + [6000]):
        st, parts, a = None, [], 0
        for b in cuts:
            amp, st = amplitude_stream(x[a:b], st)
            parts.append(amp)
            a = b
        np.testing.assert_array_equal(np.concatenate(parts), want)


def test_chunk_reader_equals_read_recording(tmp_path):
    rec = _sim(None, [], 2, 12.0, 200)          # 2400 ticks: three binary blocks
    for name, enc in (("r.mcap", "protobuf"), ("j.mcap", "json"), ("c.csv", None)):
        p = tmp_path / name
        write_recording(p, rec, **({"encoding": enc} if enc else {}))
        whole = read_recording(p)
        parts = list(iter_chunks(p, 333))
        assert len(parts) >= 3
        for k in ("t", "motor_length", "position", "orientation", "force", "temperature"):
            np.testing.assert_array_equal(np.concatenate([getattr(q, k) for q in parts]), getattr(whole, k), err_msg=k)


def test_piece_boundaries_inside_hysteresis_branches_change_nothing(tmp_path):
    """1 kHz, decimated by 10: pieces of 777 ticks (not a multiple of the decimation, so
    means straddle the pieces) give the very signals one piece gives, though the
    elongation moves at every boundary (mid-branch for the hysteresis and the amplitude)."""
    p = tmp_path / "k.mcap"
    _sim(p, ["pulley:0.004@1,4"], 5, 8.0, 1000)
    rob = load_robot(ROBOT)
    base = baseline_params(rob)
    one = read_reduced(p, rob, base, chunk_ticks=10**6)
    many = read_reduced(p, rob, base, chunk_ticks=777)
    assert one.info["decimation"] == 10 and one.signals.n == 800
    for k in ("t", "y", "v_slide", "amplitude", "temperature"):      # read and averaged: the very numbers
        np.testing.assert_array_equal(getattr(many.signals, k), getattr(one.signals, k), err_msg=k)
    # through the inverse kinematics, whose vectorised loops may round the last bit of a
    # cable length differently for a batch of 77 poses than for one of 800 (3.6e-15 m on
    # this machine, 2e-9 N after the hysteresis model): equal to within that rounding. A
    # state carried wrongly across a piece boundary is off by millimetres and newtons
    for k in ("f0", "x", "v", "wrap", "free_length"):
        np.testing.assert_allclose(getattr(many.signals, k), getattr(one.signals, k), rtol=1e-9, atol=1e-9,
                                   err_msg=k)
    # most boundaries fell inside branches: the elongation was moving there on every cable
    at = np.arange(777, 8000, 777) // 10
    assert int(np.sum(np.all(np.abs(one.signals.v[at]) > 0, axis=1))) >= 5


def test_streamed_without_decimation_is_the_in_memory_discovery(tmp_path):
    """A 100 Hz recording no longer than the group budget: the streamed path reads it in
    pieces and must give the in-memory signals, terms and parameters."""
    p = tmp_path / "s.mcap"
    rec = _sim(p, ["viscous:8000@3", "creep:0.8@2"], 11, 20.0, 100)
    rob = load_robot(ROBOT)
    terms = library(["viscous", "creep", "pulley"])
    a = discover(rec, rob, terms=terms, exact_baseline=True)
    b = discover_stream(p, rob, terms=terms, exact_baseline=True, chunk_ticks=500)
    assert b.options["stream"]["decimation"] == 1 and b.options["stream"]["groups_kept"] == 2
    s = build_signals(read_recording(p), rob, baseline_params(rob))
    for k in ("f0", "x", "v", "amplitude"):
        np.testing.assert_allclose(getattr(b.signals, k), getattr(s, k), rtol=0, atol=1e-12, err_msg=k)
    assert sorted(a.named) == sorted(b.named) == ["creep", "viscous"]
    for fa, fb in zip(sorted(a.findings, key=lambda f: f.term), sorted(b.findings, key=lambda f: f.term)):
        assert fa.cables == fb.cables
        for c in fa.cables:
            for k, v in fa.params[c].items():
                if isinstance(v, float):
                    assert fb.params[c][k] == pytest.approx(v, rel=1e-9, abs=1e-12), (fa.term, c, k)


def test_decimation_keeps_the_terms_and_their_parameters(tmp_path):
    """1 kHz in memory against the streamed path decimated to 100 Hz: the same terms on the
    same cables and the same physical parameters (viscous c_v within 3 %, pulley mu within 3 %)."""
    p = tmp_path / "d.mcap"
    rec = _sim(p, ["viscous:8000@3", "pulley:0.004@1"], 7, 12.0, 1000)
    rob = load_robot(ROBOT)
    terms = library(["viscous", "pulley"])
    a = discover(rec, rob, terms=terms, exact_baseline=True)
    b = discover_stream(p, rob, terms=terms, exact_baseline=True)
    assert b.options["stream"]["decimation"] == 10
    named = {f.term: f.cables for f in a.findings}
    assert named == {f.term: f.cables for f in b.findings} == {"viscous": [3], "pulley": [1]}
    fa = {f.term: f for f in a.findings}
    fb = {f.term: f for f in b.findings}
    assert fb["viscous"].params[3]["c_v"] == pytest.approx(fa["viscous"].params[3]["c_v"], rel=0.03)
    assert fb["pulley"].params[1]["mu"] == pytest.approx(fa["pulley"].params[1]["mu"], rel=0.03)
    assert fa["viscous"].params[3]["c_v"] == pytest.approx(8000, rel=0.05)


def test_group_sampling_is_bounded_and_spans_the_recording():
    for n_groups, k in ((5, 16), (60, 16), (360, 16), (1000, 6)):
        acc = BlockAccumulator(10.0, k)
        t = np.arange(0.0, n_groups * 10.0, 0.5)
        for a in range(0, t.size, 97):
            acc.add({"t": t[a:a + 97], "y": t[a:a + 97, None] * np.ones((1, 2))})
        out, starts, kept = acc.result()
        assert len(kept) <= k and (n_groups <= k or len(kept) > k // 2)
        assert kept[0] == 0 and kept[-1] >= n_groups - 2 * acc.stride      # the whole recording is spanned
        assert len(set(np.diff(kept))) <= 1                                   # evenly spaced
        assert out["t"].size == 20 * len(kept) and int(starts.sum()) == (1 if n_groups <= k else len(kept))


def test_reduced_recording_for_identify_is_the_block_means(tmp_path):
    p = tmp_path / "i.mcap"
    rec = _sim(p, [], 3, 3.0, 1000)
    red, info = reduced_recording(p, load_robot(ROBOT), chunk_ticks=333)
    assert info["decimation"] == 10 and red.t.size == 300 and info["gaps"] == 0
    np.testing.assert_allclose(red.force, rec.force.reshape(300, 10, 8).mean(axis=1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(red.motor_length, rec.motor_length.reshape(300, 10, 8).mean(axis=1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(red.t, rec.t.reshape(300, 10).mean(axis=1) - rec.t[0], rtol=0, atol=1e-12)


def test_bench_discover_scale_small(tmp_path):
    """The bench end to end on one small size: the recording made chunk by chunk, the
    discover child timed with its own peak RSS, the named terms per size."""
    from cablesvc.bench.discover_scale import run_discover_scale
    res = run_discover_scale([0.2], effect="pulley:0.004@1,4", directory=str(tmp_path))
    (row,) = res["rows"]
    assert row["ticks"] == 12_000 and row["analysis_ticks"] == 1200 and row["generate_seconds"] > 0
    assert row["named"] == ["pulley"] and row["cables"] == {"pulley": [1, 4]}
    assert 0 < row["seconds"] and 50 < row["peak_rss_mb"] < 2048
    assert res["same_terms_at_every_size"]


def test_scale_bench_counts_the_childs_own_memory_not_its_parents():
    # on Linux a child keeps the peak RSS of the process it was forked from across the
    # exec; the bench is run from large processes (a test session passes 2 GB), so the
    # child's own VmHWM is what counts. Here the parent holds 400 MB more than the child.
    import sys

    from cablesvc.bench.discover_scale import _timed_child
    ballast = np.ones(50_000_000)                        # 400 MB, touched
    rc, out, _, _, rss = _timed_child([sys.executable, "-m", "cablesvc", "--version"])
    assert rc == 0 and out.startswith("cablesvc")
    assert 5 < rss < 300, rss
    del ballast


def _one_winch_at_a_time(path, seconds_per_cable=10.0, rate=100.0):
    """A recording (pose at home) in which cable c alone moves, a 1 mm sine around 60 N,
    during the c-th window of ``seconds_per_cable`` s (002 Sec 4's calibration, each winch
    in turn); the other cables hold their tension (+ 0.1 N noise)."""
    from cablesvc.recording import Recording
    rng = np.random.default_rng(4)
    m = 8
    n = int(round(m * seconds_per_cable * rate))
    t = np.arange(n) / rate
    win = (t // seconds_per_cable).astype(int)
    move = np.zeros((n, m))
    move[np.arange(n), win] = 1e-3 * np.sin(2 * np.pi * 0.5 * t)
    f = 60.0 + 15000.0 * move + 0.1 * rng.standard_normal((n, m))
    rec = Recording(robot=ROBOT, metadata={}, t=t, seq=np.arange(n, dtype=np.int64), motor_length=2.0 - move,
                    position=np.zeros((n, 3)), orientation=np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), force=f,
                    temperature=None)
    write_recording(path, rec)
    return rec


def test_identify_sampling_keeps_every_winch_of_a_calibration_that_moves_one_at_a_time(tmp_path):
    """The even spread in time (discovery's sampling) keeps 2 of 8 groups and so 2 of the 8
    cables that moved; identification's excitation-aware selection keeps every cable's
    movement even when asked for 2 groups (a fit on cables that never move in the ticks
    kept is no fit: the CLI wrote K1 = 0.6 N/m for such cables before)."""
    from cablesvc.discover.stream import COVER, select_groups
    p = tmp_path / "seq.mcap"
    _one_winch_at_a_time(p)
    rob = load_robot(ROBOT)
    spread, info_s = reduced_recording(p, rob, max_groups=2)
    moving = lambda r: set(np.flatnonzero(np.ptp(r.force, axis=0) > 10.0).tolist())      # noqa: E731
    assert len(moving(spread)) <= 2 and info_s["groups_kept"] == 2
    red, info = reduced_recording(p, rob, max_groups=2, select="excitation")
    assert moving(red) == set(range(8))
    assert info["groups_kept"] == 8 and info["groups_to_cover_every_cable"] == 8 and info["groups_seen"] == 8
    # the platform is held still (a calibration): kept whole when it has no more groups than
    # held_groups (the amplitude model's per-level fit needs every level), selected otherwise
    assert info["position_std_m"] == 0.0 and "held_calibration" not in info
    _, whole = reduced_recording(p, rob, max_groups=2, select="excitation", held_groups=8)
    assert whole["held_calibration"] and whole["groups_kept"] == 8
    _, over = reduced_recording(p, rob, max_groups=2, select="excitation", held_groups=7)
    assert "held_calibration" not in over
    # the selection alone: a cable excited in two groups needs only one of them; at least k
    score = np.full((12, 3), 0.1)
    score[[1, 7], 0] = [5.0, 4.0]
    score[4, 1] = 3.0
    score[10, 2] = 8.0
    chosen, needed = select_groups(score, 5)
    assert needed == 3 and len(chosen) == 5 and chosen == sorted(chosen)
    assert {4, 10} <= set(chosen) and ({1, 7} & set(chosen))
    assert select_groups(score, 20) == (list(range(12)), 0)
    const = score.copy()
    const[:, 2] = 0.0                                             # a cable whose force never varies
    chosen, needed = select_groups(const, 1)
    assert needed == 2 and len(chosen) == 2 and COVER <= 1.0


def test_identify_cli_fits_a_long_sequential_calibration_on_every_cable(tmp_path):
    """`cablesvc identify --model amplitude` on 002 Sec 4's calibration (hold-sine, one
    winch after the other, 29 040 ticks at 100 Hz: longer than the streaming threshold)
    fits every cable to the noise: the whole recording is used, not 3 groups of it."""
    from cablesvc.cli.main import main
    from cablesvc.config.params import load_params
    from cablesvc.simulate import simulate_recording
    p = tmp_path / "cal.mcap"
    simulate_recording(ROBOT, "hold-sine", p, rate=100.0, seed=3, mode="sequential")
    out = tmp_path / "p.toml"
    assert main(["identify", "--model", "amplitude", "--robot", ROBOT, str(p), "--out", str(out), "--quiet"]) == 0
    ident = load_params(out).identification
    assert "stream" not in ident or ident["stream"]["groups_kept"] == ident["stream"]["groups_seen"]
    rmse = np.asarray(ident["rmse"], float)
    assert rmse.shape == (8,) and np.all(rmse < 0.13), rmse


def _with_dropouts(rec):
    import dataclasses
    f = rec.force.copy()
    f[300:420, 2] = np.nan                      # a force sensor drops out for 1.2 s
    pos = rec.position.copy()
    pos[700] = np.nan                           # one pose missing
    temp = rec.temperature.copy()
    temp[50:60] = np.nan                        # the thermometer too (interpolated)
    return dataclasses.replace(rec, force=f, position=pos, temperature=temp)


def test_readings_that_drop_out_are_left_out_counted_and_named(tmp_path):
    """Ticks with a force, pose or length that is not finite (a dropout written as null)
    are left out, counted and named in the report; discovery on what is left names the
    same terms with the same parameters (it failed with 'SVD did not converge' before).
    A temperature with holes is interpolated in time there; missing on most ticks, the
    column is left out."""
    rob = load_robot(ROBOT)
    rec = _sim(None, ["viscous:8000@3", "pulley:0.004@1"], 7, 12.0, 100)
    terms = library(["viscous", "pulley", "temperature"])
    a = discover(rec, rob, terms=terms, exact_baseline=True)
    b = discover(_with_dropouts(rec), rob, terms=terms, exact_baseline=True)
    dr = b.options["dropped"]
    assert dr["ticks"] == 121 and dr["of"] == 1200 and dr["runs"] == 2 and not dr["temperature_column_dropped"]
    assert dr["temperature_interpolated"] == 10
    assert dr["channels"]["force of cable 2"]["ticks"] == 120 and dr["channels"]["pose"]["ticks"] == 1
    assert dr["channels"]["force of cable 2"]["first_t"] == pytest.approx(3.0)
    text = "\n".join(b.summary())
    assert "left out 121 of 1200 ticks" in text and "force of cable 2 missing on 120 ticks" in text
    assert b.to_json()["dropped"]["ticks"] == 121 and np.all(np.isfinite(b.signals.temperature))
    k = np.flatnonzero(np.isclose(b.signals.t, rec.t[55] - rec.t[0]))[0]
    assert b.signals.temperature[k] == pytest.approx(np.interp(rec.t[55], rec.t[[49, 60]], rec.temperature[[49, 60]]))
    sparse = _with_dropouts(rec)
    sparse.temperature[::2] = np.nan                        # missing on half the ticks and more: left out
    c = discover(sparse, rob, terms=terms, exact_baseline=True)
    assert c.options["dropped"]["temperature_column_dropped"] and c.signals.temperature is None
    assert "temperature column was left out" in "\n".join(c.summary())
    assert {f.term: f.cables for f in a.findings} == {f.term: f.cables for f in b.findings} \
        == {"viscous": [3], "pulley": [1]}
    fa = {f.term: f for f in a.findings}
    fb = {f.term: f for f in b.findings}
    assert fb["viscous"].params[3]["c_v"] == pytest.approx(fa["viscous"].params[3]["c_v"], rel=0.05)
    assert fb["pulley"].params[1]["mu"] == pytest.approx(fa["pulley"].params[1]["mu"], rel=0.05)
    assert "dropped" not in a.options


def test_force_glitches_are_left_out_counted_and_named():
    """A force reading that jumps by tens of newtons for one or two ticks (a bus error, an
    electrical spike) is not sensor noise: left in, it sets the cable's noise floor several
    times too high. It is left out as a missing reading is, counted and named, and the rest
    of the recording gives the same findings and noise floor as without it."""
    import dataclasses
    rob = load_robot(ROBOT)
    rec = _sim(None, ["viscous:8000@3", "pulley:0.004@1"], 7, 12.0, 100)
    terms = library(["viscous", "pulley", "temperature"])
    a = discover(rec, rob, terms=terms, exact_baseline=True)
    f = rec.force.copy()
    f[200, 3] += 25.0                           # one reading 25 N off
    f[650:652, 1] -= (40.0, 38.0)               # two readings in a row
    f[900, 5] += 1.5                            # small, but 15 x the noise
    b = discover(dataclasses.replace(rec, force=f), rob, terms=terms, exact_baseline=True)
    dr = b.options["dropped"]
    assert dr["ticks"] == 4 and dr["runs"] == 3
    ch = dr["channels"]
    assert {k: v["ticks"] for k, v in ch.items()} == {"force of cable 3 (glitch)": 1, "force of cable 1 (glitch)": 2,
                                                     "force of cable 5 (glitch)": 1}
    assert ch["force of cable 3 (glitch)"]["glitch"] == "force"
    assert ch["force of cable 3 (glitch)"]["off_N"] == [pytest.approx(25.0, abs=0.5)]
    assert ch["force of cable 3 (glitch)"]["first_t"] == pytest.approx(2.0)
    text = "\n".join(b.summary())
    assert "force of cable 1: 2 readings more than 10 robust standard deviations off its neighbours" in text
    np.testing.assert_allclose(b.noise, a.noise, rtol=0.05)
    assert {f.term: f.cables for f in b.findings} == {f.term: f.cables for f in a.findings} \
        == {"viscous": [3], "pulley": [1]}
    assert "dropped" not in a.options                    # the clean recording has no glitch


def test_streamed_path_leaves_out_a_mean_a_glitch_threw_off(tmp_path):
    """1 kHz decimated by 10: one raw reading 200 N off moves its 10-tick mean by 20 N, far
    off its neighbours; that analysis tick is left out and counted, and discovery on the rest
    gives the same findings and noise floor as on the clean recording."""
    import dataclasses
    rob = load_robot(ROBOT)
    rec = _sim(None, ["viscous:8000@3"], 7, 12.0, 1000)
    clean, spiky = tmp_path / "c.mcap", tmp_path / "s.mcap"
    write_recording(clean, rec)
    f = rec.force.copy()
    f[5003, 4] += 200.0
    f[8000, 2] -= 300.0
    write_recording(spiky, dataclasses.replace(rec, force=f))
    terms = library(["viscous", "pulley"])
    a = discover_stream(clean, rob, terms=terms, exact_baseline=True)
    b = discover_stream(spiky, rob, terms=terms, exact_baseline=True)
    st = b.options["stream"]
    assert st["glitch_ticks"] == 2 and st["glitches_per_cable"] == {4: 1, 2: 1}
    assert st["analysis_ticks"] == a.options["stream"]["analysis_ticks"] - 2 and "glitch_ticks" not in a.options["stream"]
    assert "2 analysis ticks left out as glitches" in "\n".join(b.summary())
    np.testing.assert_allclose(b.noise, a.noise, rtol=0.05)
    assert {f.term: f.cables for f in b.findings} == {f.term: f.cables for f in a.findings} == {"viscous": [3]}


def test_glitches_leave_steps_kinks_and_noise_alone_and_say_which_reading_jumped():
    from cablesvc.discover.pipeline import reading_glitches
    rng = np.random.default_rng(2)
    t = np.arange(6000) / 100.0
    smooth = (3.0 * np.abs(((0.25 * t) % 2.0) - 1.0)            # kinks at reversals
              + np.where(t > 20.0, 2.5, 0.0)                     # a step (a friction's sign)
              + 0.8 * np.sin(2 * np.pi * 0.07 * t))
    f0 = 200.0 + 40.0 * np.sin(2 * np.pi * 0.1 * t)[:, None] * np.ones(3)   # the baseline's force
    y = f0 + smooth[:, None] + 0.1 * rng.standard_normal((6000, 3))
    gf, ge = reading_glitches(y, f0)
    assert not gf.any() and not ge.any()
    assert not any(g.any() for g in reading_glitches(f0 + smooth[:, None], f0))   # no noise: nothing to judge by
    y[1000, 0] += 2.0                           # the force reading jumps
    y[3000:3002, 2] += 5.0
    f0g = f0.copy()
    f0g[4000, 1] -= 3.0                         # the elongation did, and the baseline's force with it
    gf, ge = reading_glitches(y, f0g)
    assert set(zip(*np.nonzero(gf))) == {(1000, 0), (3000, 2), (3001, 2)}
    assert set(zip(*np.nonzero(ge))) == {(4000, 1)}


def test_a_pose_that_jumps_for_a_tick_is_named_as_such():
    """The pose is recorded 1 mm off for one tick (a tracker's glitch): the elongation and
    the baseline's force jump, the measured force does not. The tick is left out and the
    report says it was the pose or a length, not the force."""
    import dataclasses
    rob = load_robot(ROBOT)
    rec = _sim(None, ["viscous:8000@3"], 7, 12.0, 100)
    pos = rec.position.copy()
    pos[500] += (1e-3, 0.0, 0.0)
    b = discover(dataclasses.replace(rec, position=pos), rob, terms=library(["viscous", "pulley"]),
                 exact_baseline=True)
    ch = b.options["dropped"]["channels"]
    # every cable's elongation jumped on that tick; where the baseline's force follows the
    # rate, the backward difference jumps back on the next one
    assert len(ch) == 8 and all(k.startswith("elongation of cable") and v["glitch"] == "elongation"
                                and v["ticks"] in (1, 2) and v["first_t"] == pytest.approx(5.0) for k, v in ch.items())
    assert "the pose or a motor length jumped for a tick or two (first at t = 5 s): the baseline's force on cables 0, 1, 2" in "\n".join(b.summary())
    assert {f.term: f.cables for f in b.findings} == {"viscous": [3]}


def test_streamed_path_leaves_out_a_mean_with_no_reading_and_averages_the_rest(tmp_path):
    """1 kHz decimated by 10: a dropout over 50 ticks (5 whole means) leaves 5 analysis ticks
    out; a single missing reading is left out of its mean, which averages the other 9."""
    import dataclasses
    p = tmp_path / "n.mcap"
    rec = _sim(None, ["viscous:8000@3"], 7, 12.0, 1000)
    f = rec.force.copy()
    f[3000:3050, 1] = np.nan
    f[5003, 4] = np.nan
    write_recording(p, dataclasses.replace(rec, force=f))
    rob = load_robot(ROBOT)
    red = read_reduced(p, rob, baseline_params(rob), chunk_ticks=777)
    assert red.info["dropped_ticks"] == 5 and red.signals.n == 1195
    assert np.all(np.isfinite(red.signals.y)) and np.all(np.isfinite(red.signals.f0))
    k = int(np.flatnonzero(np.isclose(red.t, rec.t[5000:5010].mean() - rec.t[0]))[0])
    assert red.signals.y[k, 4] == pytest.approx(np.mean(np.delete(rec.force[5000:5010, 4], 3)), abs=1e-9)
    d = discover_stream(p, rob, terms=library(["viscous", "pulley"]), exact_baseline=True)
    assert {f.term: f.cables for f in d.findings} == {"viscous": [3]}
    assert "5 analysis ticks left out" in "\n".join(d.summary())
