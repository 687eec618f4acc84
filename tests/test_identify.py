"""Identification core: PSO (000 Sec 5), least squares and tracking (002 eqs 12-14),
multi-start SQP (001 Ch 5), identifiability and the eq 11 sensitivity."""

from __future__ import annotations

import numpy as np
import pytest

from cablesvc.identify import IdentifyResult, normalized_mse, pso
from cablesvc.identify.identifiability import jacobian_statistics, redundant_groups, sensitivity
from cablesvc.identify.local import linear_inequality, meshpoint_constraint, multistart_sqp, refine, track
from cablesvc.identify.pso import initial_population, pso_lockstep
from cablesvc.models import BoucWen, from_benchmark, simulate

TARGET = np.array([1.5, -2.0, 0.25])


def shifted_sphere(X):
    """Module-level (picklable) batched objective with its minimum 0 at TARGET."""
    return np.sum((np.asarray(X) - TARGET) ** 2, axis=1)


def rosenbrock(X):
    X = np.asarray(X)
    return (1 - X[:, 0]) ** 2 + 100 * (X[:, 1] - X[:, 0] ** 2) ** 2


# ---------------------------------------------------------------------------- PSO

def test_pso_finds_minimum_of_known_functions():
    r = pso(shifted_sphere, [(-5, 5)] * 3, particles=20, iterations=150, seed=3, names=["a", "b", "c"])
    assert isinstance(r, IdentifyResult)
    # the paper's coefficients (c1 + c2 = 4.1 with w = 0.8) keep the swarm exploring: it
    # gets close, not exact (LM refinement does the rest)
    assert np.allclose(r.x, TARGET, atol=0.08)
    assert r.fun < 1e-2
    assert r.nfev == 20 * (150 + 1) and r.nit == 150
    assert r.history.shape == (151,) and np.all(np.diff(r.history) <= 0)      # best never gets worse
    assert r.as_dict()["a"] == pytest.approx(r.x[0])
    rb = pso(rosenbrock, (np.array([-2.0, -1.0]), np.array([2.0, 3.0])), particles=30, iterations=300, seed=1)
    assert np.allclose(rb.x, [1.0, 1.0], atol=0.05) and rb.fun < 1e-3


def test_pso_paper_defaults_and_one_batched_call_per_iteration():
    calls = []

    def fun(X):
        calls.append(X.shape)
        return shifted_sphere(X)

    r = pso(fun, [(-5, 5)] * 3, seed=0)
    # 000 Sec 5: p = 10 particles, q = 75 iterations; initial population + 75 calls
    assert len(calls) == 76 and all(s == (10, 3) for s in calls)
    assert r.nit == 75 and r.nfev == 760


def test_pso_reproducible_with_seed():
    bounds = [(-2.0, 2.0), (-1.0, 3.0)]          # a sequence of (lo, hi) pairs
    a = pso(rosenbrock, bounds, particles=12, iterations=40, seed=42)
    b = pso(rosenbrock, bounds, particles=12, iterations=40, seed=42)
    c = pso(rosenbrock, bounds, particles=12, iterations=40, seed=43)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.history, b.history)
    assert np.array_equal(a.population, b.population)
    assert not np.array_equal(a.population, c.population)


def test_pso_workers_give_identical_results():
    one = pso(shifted_sphere, [(-5, 5)] * 3, particles=9, iterations=30, seed=7, workers=1)
    two = pso(shifted_sphere, [(-5, 5)] * 3, particles=9, iterations=30, seed=7, workers=2)
    assert np.array_equal(one.x, two.x)
    assert np.array_equal(one.history, two.history)
    assert np.array_equal(one.population, two.population)
    with pytest.raises(TypeError, match="picklable"):
        pso(lambda X: X[:, 0], [(0, 1)], workers=2, iterations=1)


def test_pso_particles_stay_within_bounds_and_reset_to_nearest_bound():
    lb, ub = np.array([0.0, -1.0]), np.array([1.0, 2.0])
    seen = []

    def fun(X):
        seen.append(X.copy())
        # minimum far outside the box, beyond the upper bound of x0 and the lower of x1
        return (X[:, 0] - 10.0) ** 2 + (X[:, 1] + 10.0) ** 2

    r = pso(fun, (lb, ub), particles=15, iterations=40, seed=5)
    allX = np.concatenate(seen)
    assert np.all(allX >= lb) and np.all(allX <= ub)
    assert r.x[0] == 1.0 and r.x[1] == -1.0          # reset onto the closest boundary
    assert np.any(allX[:, 0] == 1.0)


def test_pso_tol_stops_early_and_callback_sees_best():
    log = []
    r = pso(shifted_sphere, [(-5, 5)] * 3, particles=20, iterations=500, seed=2, tol=1e-2,
            callback=lambda it, x, f: log.append((it, f)))
    assert r.success and r.fun <= 1e-2 and r.nit < 500
    assert "tol" in r.message
    assert log[-1] == (r.nit, r.fun)
    stop = pso(shifted_sphere, [(-5, 5)] * 3, seed=2, callback=lambda it, x, f: it >= 3)
    assert stop.nit == 3 and "callback" in stop.message


def test_gaussian_initial_population_on_the_bounds():
    rng = np.random.default_rng(0)
    lb, ub = np.array([0.0, 10.0]), np.array([4.0, 40.0])
    X = initial_population(rng, lb, ub, 20000)
    assert np.all(X >= lb) and np.all(X <= ub)
    assert np.allclose(X.mean(axis=0), (lb + ub) / 2, rtol=0.01)
    # std (ub - lb) / 6 before clipping: clipping at +-3 sigma shrinks it by < 1.5 %
    assert np.allclose(X.std(axis=0), (ub - lb) / 6, rtol=0.03)


def test_pso_seed_particle_x0():
    r = pso(shifted_sphere, [(-5, 5)] * 3, particles=5, iterations=0, seed=1, x0=TARGET)
    assert r.fun == 0.0 and np.array_equal(r.x, TARGET)


def test_pso_lockstep_independent_swarms_one_call():
    calls = []
    targets = np.array([[1.0, 2.0], [-3.0, 0.5]])

    def fun(S):
        calls.append(S.shape)
        return np.sum((S - targets[:, None, :]) ** 2, axis=2)

    rs = pso_lockstep(fun, [[(-5, 5)] * 2] * 2, particles=12, iterations=80, seed=0)
    assert all(s == (2, 12, 2) for s in calls) and len(calls) == 81
    for r, t in zip(rs, targets):
        assert np.allclose(r.x, t, atol=0.05)


def test_normalized_mse_eq25():
    rng = np.random.default_rng(1)
    y = rng.normal(5.0, 2.0, 1000)
    assert normalized_mse(y, y) == 0.0
    assert normalized_mse(np.full_like(y, y.mean()), y) == pytest.approx(1.0)
    model = np.stack([y + 0.1, y - 0.2, y])                # three lanes
    v = normalized_mse(model, y)
    assert v.shape == (3,)
    assert np.allclose(v, [0.01 / y.var(), 0.04 / y.var(), 0.0])


# ---------------------------------------------------------------------------- least squares

BW_TRUE = {"k_e": 800.0, "k_d": 2000.0, "beta": 40.0, "gamma": 15.0, "n": 1.5}
BW_NAMES = list(BW_TRUE)


def _bw_data(noise=0.05, seed=0):
    t = np.linspace(0, 4, 500)
    x = 0.04 * np.sin(2 * np.pi * 0.5 * t) * (0.4 + 0.6 * t / 4)
    f = simulate(BoucWen((1, 1), **BW_TRUE), x, t[1] - t[0])
    rng = np.random.default_rng(seed)
    return t, x, f + noise * rng.standard_normal(f.shape)


def _bw_residuals(t, x, fm):
    def res(p):
        m = BoucWen((1, 1), **dict(zip(BW_NAMES, p)))
        return simulate(m, x, t[1] - t[0]) - fm
    return res


@pytest.mark.parametrize("method", ["trf", "lm"])
def test_refine_recovers_boucwen_with_covering_stderr(method):
    t, x, fm = _bw_data()
    truth = np.array(list(BW_TRUE.values()))
    x0 = truth * np.array([1.15, 0.85, 1.2, 0.8, 1.1])
    bounds = None if method == "lm" else ([0, 0, 0, -100, 0.5], [1e4, 1e4, 1e3, 1e3, 4])
    r = refine(_bw_residuals(t, x, fm), x0, bounds, method=method, names=BW_NAMES)
    assert r.success
    err = np.abs(r.x - truth)
    assert np.all(err / truth < 0.05)
    assert np.all(err <= 4 * r.stderr), (r.x, r.stderr)        # the standard errors cover the truth
    assert np.all(r.stderr > 0) and np.all(np.isfinite(r.stderr))
    assert r.correlation.shape == (5, 5) and np.allclose(np.diag(r.correlation), 1.0)
    assert r.cond >= 1.0 and r.jac.shape == (500, 5)
    assert np.sqrt(r.sigma2) == pytest.approx(0.05, rel=0.15)   # residual std ~ the noise


def test_track_follows_a_drift_with_few_evaluations():
    t, x, fm = _bw_data(noise=0.02, seed=1)
    truth = np.array(list(BW_TRUE.values()))
    first = refine(_bw_residuals(t, x, fm), truth * 1.05, None, method="lm", names=BW_NAMES)
    # days later the cable is 10 % stiffer elastically (002 Fig 6: the model drifts)
    drifted = dict(BW_TRUE, k_e=880.0)
    f2 = simulate(BoucWen((1, 1), **drifted), x, t[1] - t[0]) + 0.02 * np.random.default_rng(2).standard_normal(x.shape)
    tr = track(_bw_residuals(t, x, f2), first)
    assert tr.nfev <= 10 * (5 + 1)
    assert tr.x[0] == pytest.approx(880.0, rel=0.01)
    assert tr.drift[0] == pytest.approx(80.0, rel=0.1)
    assert tr.drift_sigma[0] > 10                                # far outside the old uncertainty
    assert tr.names == BW_NAMES


# ---------------------------------------------------------------------------- SQP

def test_multistart_sqp_respects_linear_constraint_violated_by_unconstrained_optimum():
    f = lambda p: (p[0] - 2.0) ** 2 + (p[1] - 1.0) ** 2
    con = linear_inequality([[1.0, 1.0]], [1.0])               # x + y <= 1; (2, 1) violates it
    r = multistart_sqp(f, [(-5, 5), (-5, 5)], constraints=[con], starts=6, seed=0, names=["x", "y"])
    assert r.success
    assert r.x[0] + r.x[1] <= 1.0 + 1e-6
    assert np.allclose(r.x, [1.0, 0.0], atol=1e-4)              # projection of (2, 1) on x + y = 1
    assert len(r.starts_result) == 6 and all("x0" in s for s in r.starts_result)
    assert r.history.shape == (6,)


def test_multistart_sqp_meshpoint_constraint():
    # data: a line with a large disturbance near x = 1; least squares would tilt the line,
    # the mesh points (001 Sec 5.1.2) pin the model within 2 % of the measured force at x = 0 and 0.5
    xs = np.linspace(0, 1, 21)
    F = 10.0 + 5.0 * xs
    F[-3:] += 8.0
    model = lambda p, x: p[0] + p[1] * x
    sse = lambda p: float(np.sum((model(p, xs) - F) ** 2))
    free = multistart_sqp(sse, [(0, 30), (-20, 40)], starts=4, seed=1)
    mesh_x = np.array([0.0, 0.5])
    mesh_F = 10.0 + 5.0 * mesh_x
    assert np.any(np.abs(model(free.x, mesh_x) - mesh_F) > 0.02 * mesh_F)   # unconstrained violates it
    con = meshpoint_constraint(lambda p: model(p, mesh_x), mesh_F, margin=0.02)
    r = multistart_sqp(sse, [(0, 30), (-20, 40)], constraints=[con], starts=4, seed=1)
    assert r.success and r.violation <= 1e-6
    assert np.all(np.abs(model(r.x, mesh_x) - mesh_F) <= 0.02 * mesh_F + 1e-6)


# ---------------------------------------------------------------------------- identifiability

def test_identifiability_flags_a_redundant_product_pair():
    t = np.linspace(0, 1, 300)
    rng = np.random.default_rng(3)
    y = 6.0 * t + 0.5 * t ** 2 + 0.01 * rng.standard_normal(t.size)
    res = lambda p: p[0] * p[1] * t + p[2] * t ** 2 - y      # only a*b acts
    r = refine(res, [2.0, 2.5, 0.4], [(0.1, 10), (0.1, 10), (-5, 5)], names=["a", "b", "c"])
    assert len(r.redundant) == 1
    g = r.redundant[0]
    assert sorted(g.names) == ["a", "b"]
    assert g.log_direction["a"] == pytest.approx(-g.log_direction["b"], abs=1e-6)
    assert g.identifiable == "a^1 * b^1"
    assert "a" in g.describe() and "unidentifiable" in g.describe()
    assert np.all(r.stderr[:2] > 1e3 * np.abs(r.x[:2]))        # individually undetermined
    assert r.stderr[2] < 0.1 * abs(r.x[2])
    assert r.x[0] * r.x[1] == pytest.approx(6.0, rel=1e-2)     # the product is determined
    # a well-posed problem has no group
    st = jacobian_statistics(np.column_stack([t, t ** 2]), np.zeros_like(t), names=["p", "q"])
    assert st.groups == [] and np.isfinite(st.cond)


def test_boucwen_benchmark_parameterisation_has_one_redundant_direction():
    """Benchmark convention (alpha, beta, gamma, delta, nu): only beta*gamma and
    beta*delta act, so (beta, gamma, delta) has a null direction; the 000 form does not."""
    t = np.linspace(0, 4, 400)
    x = 0.03 * np.sin(2 * np.pi * 0.5 * t)
    bench = np.array([2000.0, 4.0, 10.0, 3.75, 1.5])           # alpha, beta, gamma, delta, nu
    h = 1e-6 * bench
    lanes = np.repeat(bench[None], 6, axis=0)
    for j in range(5):
        lanes[j + 1, j] += h[j]
    pars = [from_benchmark(*row, k_lin=800.0) for row in lanes]
    model = BoucWen((6, 1), **{k: np.array([p[k] for p in pars])[:, None] for k in pars[0]})
    F = simulate(model, np.repeat(x[:, None, None], 6, axis=1), t[1] - t[0])[:, :, 0]   # all in one call
    J = (F[:, 1:] - F[:, :1]) / h
    groups = redundant_groups(J, ["alpha", "beta", "gamma", "delta", "nu"], bench, rtol=1e-4)
    assert len(groups) == 1
    g = groups[0]
    assert set(g.names) == {"beta", "gamma", "delta"}
    d = g.log_direction
    # d ln beta = -d ln gamma = -d ln delta keeps beta*gamma and beta*delta fixed
    assert d["beta"] == pytest.approx(-d["gamma"], rel=1e-3) and d["beta"] == pytest.approx(-d["delta"], rel=1e-3)
    # the 000 form (k_d, beta_000, gamma_000, n): no redundancy
    J000 = J[:, [0, 4]]
    assert redundant_groups(J000, ["k_d", "n"]) == []


def test_sensitivity_eq11():
    # O = 3 p0^2 p1 : arc elasticities ((O2-O1)/mean O) / ((I2-I1)/mean I)
    out = lambda P: 3.0 * P[:, 0] ** 2 * P[:, 1] + 0.0 * P[:, 2]
    s = sensitivity(out, np.array([2.0, 5.0, 0.0]), rel_step=0.1, names=["p0", "p1", "p2"])
    expected_p0 = ((1.1 ** 2 - 0.9 ** 2) / ((1.1 ** 2 + 0.9 ** 2) / 2)) / (0.2 / 1.0)
    assert s["S"][0] == pytest.approx(expected_p0)
    assert s["S"][1] == pytest.approx(1.0)
    assert np.isnan(s["S"][2])                       # eq 11 is undefined at a zero parameter
    assert s["names"] == ["p0", "p1", "p2"]


def test_one_bounds_reader_for_swarm_and_local_fits():
    from scipy.optimize import Bounds

    from cablesvc.identify.bounds import parse_bounds

    # every form gives the same (lb, ub)
    forms = [Bounds([0.0, -1.0], [2.0, 3.0]), (np.array([0.0, -1.0]), np.array([2.0, 3.0])),
             [(0.0, 2.0), (-1.0, 3.0)], np.array([[0.0, 2.0], [-1.0, 3.0]])]
    for f in forms:
        lb, ub = parse_bounds(f)
        assert lb.tolist() == [0.0, -1.0] and ub.tolist() == [2.0, 3.0]
    lb, ub = parse_bounds(([0.0, 1.0, 2.0], [4.0, 5.0, 6.0]))       # (lb, ub) of three parameters
    assert lb.tolist() == [0.0, 1.0, 2.0] and ub.tolist() == [4.0, 5.0, 6.0]
    # with n (the local fits): None means unbounded, scalars broadcast
    lb, ub = parse_bounds([(None, 1.0), (0.0, None)], 2)
    assert lb.tolist() == [-np.inf, 0.0] and ub.tolist() == [1.0, np.inf]
    lb, ub = parse_bounds(None, 3)
    assert np.all(np.isneginf(lb)) and np.all(np.isposinf(ub))
    lb, ub = parse_bounds((0.0, 1.0), 3)
    assert lb.tolist() == [0.0] * 3 and ub.tolist() == [1.0] * 3
    # the swarm and the multi-start need finite bounds; nobody takes upper < lower
    with pytest.raises(ValueError, match="finite"):
        parse_bounds([(None, 1.0), (0.0, 2.0)], 2, finite=True)
    with pytest.raises(ValueError, match="finite"):
        pso(lambda X: np.sum(X * X, axis=1), [(0.0, np.inf)], particles=4, iterations=2, seed=0)
    with pytest.raises(ValueError, match=r"upper < lower for parameter index\(es\) \[1\]"):
        parse_bounds([(0.0, 1.0), (3.0, 2.0)])
    with pytest.raises(ValueError, match="3 \\(lo, hi\\) pairs"):
        parse_bounds([(0.0, 1.0)] * 4, 3)
