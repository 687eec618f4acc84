"""The fixed-time kernel (Predictor): consistency with the models and kinematics, FK
without pose, slack, residuals, snapshots and allocation-free ticks."""

import json
import subprocess
import sys
import tracemalloc

import numpy as np
import pytest

from cablesvc.config import load_robot
from cablesvc.config.params import ModelParams, ParamFileError, default_params, load_params
from cablesvc.kernel import Predictor
from cablesvc.kinematics import inverse_kinematics, platform_wrench, structure_matrix
from cablesvc.kinematics.rotation import quat_to_matrix
from cablesvc.models import simulate

Q0 = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.fixture(scope="module")
def ipanema(robot):
    g = robot.geometry()
    L = inverse_kinematics(g, np.zeros((1, 3)), Q0[None]).length[0]
    return g, L


def sine_lengths(L, k_lin, ticks, rate=1000.0, A=4e-4):
    t = np.arange(ticks) / rate
    x = 60.0 / k_lin + A * np.sin(2 * np.pi * 1.0 * t[:, None] + np.arange(L.size))
    return t, L[None, :] - x, x


def test_kernel_force_equals_model_on_ik_elongation(ipanema):
    g, L = ipanema
    params = default_params(g.ea, L, "amplitude")
    pred = Predictor(g, params)
    pos = np.array([0.3, -0.2, 0.1])
    q = np.array([0.0, 0.0, np.sin(0.05), np.cos(0.05)])
    Lp = inverse_kinematics(g, pos[None], q[None]).length[0]
    t, ml, x = sine_lengths(Lp, g.ea / Lp, 3000)
    out_f, out_x = [], []
    for k in range(len(t)):
        o = pred.tick(t[k], ml[k], pos, q)
        out_f.append(o.force.copy())
        out_x.append(o.elongation.copy())
    assert np.allclose(np.array(out_x), x, atol=1e-12)
    ref = simulate(params.build(g.n_cables), x[:, None, :], 1e-3)[:, 0, :]
    # dt from float tick times vs a constant 1e-3: agreement to round-off of the clock
    assert np.allclose(np.array(out_f), np.maximum(ref, 0), rtol=1e-9, atol=1e-9)


def test_wrench_residual_is_eq2(ipanema):
    g, L = ipanema
    pred = Predictor(g, default_params(g.ea, L, "linear"))
    pos = np.array([0.5, 0.4, -0.2])
    q = np.array([np.sin(0.1), 0.0, 0.0, np.cos(0.1)])
    ik = inverse_kinematics(g, pos[None], q[None])
    ml = ik.length[0] - 4e-3
    o = pred.tick(0.0, ml, pos, q)
    AT = structure_matrix(ik.unit, ik.anchor_world)[0]
    w = platform_wrench(g, quat_to_matrix(q[None]))[0]
    assert np.allclose(o.wrench_residual, AT @ o.force + w, atol=1e-9)
    # weight is in the residual: the z force row carries -m g plus the cables' pull
    assert np.allclose(w[:3], [0, 0, -g.mass * 9.81])


def test_fk_without_pose_finds_equilibrium(ipanema):
    """Motor lengths from an equilibrium pose: the elasto-static FK returns that pose."""
    g, L = ipanema
    params = default_params(g.ea, L, "linear")
    pred = Predictor(g, params, fk_iterations=6)
    # pose path at a trial pose, then let the FK find the equilibrium for the same motor lengths
    ml = L - 60.0 / (g.ea / L)
    o = pred.tick(0.0, ml)
    assert o.pose_from_fk
    assert o.fk_residual < 1e-6
    assert np.linalg.norm(o.wrench_residual) < 1e-6
    p_eq, q_eq = o.position.copy(), o.orientation.copy()
    # the same motor lengths with the equilibrium pose measured give the same forces
    f_fk = o.force.copy()
    pred2 = Predictor(g, params)
    o2 = pred2.tick(0.0, ml, p_eq, q_eq)
    assert np.allclose(o2.force, f_fk, rtol=1e-9)
    # warm start: a small change of motor lengths moves the pose a little, residual stays small
    o3 = pred.tick(0.001, ml + 1e-4)
    assert o3.fk_residual < 1e-3
    assert np.linalg.norm(o3.position - p_eq) < 0.01


def test_fk_recovers_after_a_tick_it_cannot_solve(ipanema):
    """Infinite motor lengths make the FK's system singular (NaN, not an exception, from
    the solve): that tick raises, and the next good tick starts again from the geometric
    FK instead of warm-starting from a NaN pose, with or without reset()."""
    g, L = ipanema
    params = default_params(g.ea, L, "linear")
    ml = L - 60.0 / (g.ea / L)
    for call_reset in (False, True):
        pred = Predictor(g, params)
        good = pred.tick(0.0, ml).position.copy()
        with pytest.raises(FloatingPointError, match="FK diverged"), np.errstate(invalid="ignore"):
            pred.tick(0.001, np.full(g.n_cables, np.inf))
        if call_reset:
            pred.reset()
        o = pred.tick(0.002, ml)
        assert np.all(np.isfinite(o.force)) and o.fk_residual < 1e-3
        assert np.allclose(o.position, good, atol=1e-6)


def test_slack_flag_and_residual(ipanema):
    g, L = ipanema
    pred = Predictor(g, default_params(g.ea, L, "linear"))
    ml = L - 60.0 / (g.ea / L)
    ml[2] = L[2] + 0.01          # cable 2 paid out 1 cm too much: slack
    meas = np.full(g.n_cables, 55.0)
    o = pred.tick(0.0, ml, np.zeros(3), Q0, force=meas)
    assert o.slack[2] and not o.slack[[0, 1, 3, 4, 5, 6, 7]].any()
    assert o.force[2] == 0.0
    assert np.allclose(o.residual, meas - o.force)
    o = pred.tick(0.001, ml, np.zeros(3), Q0)
    assert np.all(np.isnan(o.residual)) and np.all(np.isnan(o.measured))


def test_snapshot_restore_continues_exactly(ipanema):
    g, L = ipanema
    params = default_params(g.ea, L, "amplitude")
    t, ml, _ = sine_lengths(L, g.ea / L, 2000)
    a = Predictor(g, params)
    for k in range(1200):
        a.tick(t[k], ml[k], np.zeros(3), Q0)
    snap = a.state_dict()
    b = Predictor(g, params)
    b.load_state_dict(snap)
    for k in range(1200, 2000):
        fa = a.tick(t[k], ml[k], np.zeros(3), Q0).force.copy()
        fb = b.tick(t[k], ml[k], np.zeros(3), Q0).force.copy()
        assert np.array_equal(fa, fb)


@pytest.mark.parametrize("with_pose,ticks", [(True, 10_000), (False, 3_000)], ids=["pose", "no-pose-fk"])
def test_tick_allocates_nothing_over_thousands_of_ticks(ipanema, with_pose, ticks):
    """Both paths, the measured pose and the elasto-static FK from motor lengths alone,
    keep no memory and make only small transient Python objects (no arrays) per tick.
    (The FK path runs fewer ticks under tracemalloc, which slows it ~10 x: an array kept
    per tick, >= 96 B, would still pass the 512 B limit after 6 ticks.)"""
    g, L = ipanema
    pred = Predictor(g, default_params(g.ea, L, "amplitude"))
    t, ml, _ = sine_lengths(L, g.ea / L, ticks + 300)
    meas = np.full(g.n_cables, 60.0)
    pos, quat = (np.zeros(3), Q0) if with_pose else (None, None)
    tracemalloc.start()
    for k in range(300):
        pred.tick(t[k], ml[k], pos, quat, meas, 21.0)
    base, _ = tracemalloc.get_traced_memory()
    tracemalloc.reset_peak()
    for k in range(300, ticks + 300):
        pred.tick(t[k], ml[k], pos, quat, meas, 21.0)
    cur, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert pred.out.pose_from_fk is not with_pose
    assert cur - base < 512, f"memory grew by {cur - base} B over {ticks} ticks"
    assert peak - base < 4096, f"a tick allocated temporaries: peak {peak - base} B above baseline"


@pytest.mark.parametrize("robot", ["planar4", "cogiro"])
def test_fk_tracks_the_equilibrium_pose_of_moving_motor_lengths(robot):
    """Motor lengths made from a moving platform at equilibrium (linear cables): the FK,
    warm-started tick after tick, finds that pose and the pose path's forces. Planar
    robots solve the three planar wrench rows only, and keep z and the tilt at zero."""
    g = load_robot(robot).geometry()
    params = default_params(g.ea, inverse_kinematics(g, np.zeros((1, 3)), Q0[None]).length[0], "linear")
    ref = Predictor(g, params, fk_iterations=8)
    fk = Predictor(g, params)
    # equilibrium poses along a path: the reference FK from cold at each, many iterations
    for k in range(60):
        t = k * 1e-3
        L0 = inverse_kinematics(g, np.zeros((1, 3)), Q0[None]).length[0]
        ml = L0 - 60.0 / (g.ea / L0) + 2e-3 * np.sin(2 * np.pi * 5.0 * t + np.arange(g.n_cables))
        ref.reset()
        o_ref = ref.tick(t, ml)
        assert o_ref.fk_residual < 1e-6
        o = fk.tick(t, ml)
        assert o.pose_from_fk
        assert o.fk_residual < 1e-3
        assert np.allclose(o.position, o_ref.position, atol=1e-7)
        assert np.allclose(o.orientation, o_ref.orientation, atol=1e-7)
        assert np.isclose(np.linalg.norm(o.orientation), 1.0, atol=1e-12)
        if g.planar:
            assert o.position[2] == 0.0 and o.orientation[0] == 0.0 and o.orientation[1] == 0.0
        forces = Predictor(g, params).tick(t, ml, o.position.copy(), o.orientation.copy()).force
        assert np.allclose(o.force, forces, rtol=1e-12, atol=1e-9)


def test_params_file_round_trip_and_errors(tmp_path, ipanema):
    g, L = ipanema
    p = default_params(g.ea, L, "amplitude")
    p.robot = "ipanema3"
    f = tmp_path / "p.toml"
    p.save(f)
    q = load_params(f)
    assert q.model == "amplitude" and q.robot == "ipanema3"
    assert np.allclose(np.asarray(q.tables["K1"]), np.asarray(p.tables["K1"]))
    assert q.amplitude_range() == (1e-4, 1.5e-3)
    bad = tmp_path / "bad.toml"
    bad.write_text('format = 1\nmodel = "boucwen"\n[params]\nk_e = 1.0\nkd = 2.0\n[options]\nsubstepz = 2\n')
    with pytest.raises(ParamFileError) as e:
        load_params(bad)
    msg = str(e.value)
    assert "bad.toml" in msg and "params.kd" in msg and "options.substepz" in msg
    with pytest.raises(ParamFileError, match="params.k_e: expected a number or a list of 8"):
        ModelParams(model="boucwen", params={"k_e": [1.0, 2.0], "k_d": 1, "beta": 1, "gamma": 1}).build(8)


def test_bench_kernel_cli_json():
    # every row but two of the three term rows (their cost is warming up 3000 ticks each;
    # tests/test_live_terms.py runs those rows through run_kernel_bench)
    inputs = [a for k in ("normal", "reversal", "slack", "large", "no_pose", "terms") for a in ("--input", k)]
    out = subprocess.run([sys.executable, "-m", "cablesvc", "bench", "kernel", "--ticks", "1000", "--json", *inputs],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert [r["input"] for r in rows] == ["normal", "reversal", "slack", "large", "no_pose", "terms", "machine"]
    machine = rows.pop()
    terms = rows[5:]
    rows = rows[:5]
    for r in terms:              # every term on every cable, against the plain kernel timed in alternate blocks
        assert r["plain_p50_us"] > 0 and r["kernel_p50_ratio"] == r["p50_us"] / r["plain_p50_us"]
        # numpy's small internal caches still settle (~0.06 B/tick over 1000 ticks); an array
        # kept per tick would be >= 96 B/tick, one Python float 24 B/tick
        assert r["alloc_bytes_per_tick"] < 1.0
    # the same-run machine baseline: a fixed numpy workload sized to the kernel's median
    assert machine["model"] == "none" and machine["calls"] > 10 and machine["scheduling"] == "default"
    assert 0 < machine["p50_us"] <= machine["p99_us"] <= machine["max_us"]
    assert 0.2 < machine["p50_us"] / rows[0]["p50_us"] < 5
    for r in rows:
        assert set(r) == {"robot", "model", "input", "ticks", "p50_us", "p99_us", "p999_us", "max_us",
                          "alloc_bytes_per_tick"}
        assert r["robot"] == "ipanema3" and r["model"] == "amplitude" and r["ticks"] == 1000
        assert 0 < r["p50_us"] <= r["p99_us"] <= r["p999_us"] <= r["max_us"]
        # nothing kept per tick, with or without a pose (measured 0.056-0.08 B/tick over 1000
        # ticks: numpy's caches settling; one float kept per tick would be 24 B/tick)
        assert r["alloc_bytes_per_tick"] < 1.0
