"""Quasi-static finite-element solver for the hysteretic geometrically exact beam of paper 000.

Model (paper 000, Sec 3)
------------------------
Planar, shear-deformable, geometrically exact (Reissner / special Cosserat) beam of
reference length ``l`` [m], straight along e1. Unknowns: displacements ``u(s)``, ``v(s)``
[m] and section rotation ``theta(s)`` [rad].

* Strains, eqs 6-8: stretch ``nu = (1 + u') cos(theta) + v' sin(theta)`` [-], shear strain
  ``eta = -(1 + u') sin(theta) + v' cos(theta)`` [-], curvature ``mu = theta'`` [1/m].
* Elastic laws, eq 9: ``N = EA (nu - 1)``, ``Q = G A* eta`` [N]; ``A* = kappa A`` with
  Cowper's shear coefficient ``kappa = 6 (1 + nu_P) / (7 + 6 nu_P)`` of a solid circle
  (nu_P = Poisson's ratio).
* Hysteretic moment, eqs 15-18: ``M = EJ_e mu + M_h + k3 mu^3`` [N m] with
  ``dM_h = {EJ_h - [gamma + beta sgn(M_h dmu)] |M_h|^n} dmu`` (eq 16 multiplied by dt),
  ``EJ_e = delta psi EJ``, ``EJ_h = (1 - delta) psi EJ`` [N m^2], ``J = pi d^4 / 64``.
  ``gamma, beta`` in N^(1-n) m^(2-n) (Table 2 units), ``n`` [-], ``k3`` [N m^3].
* Equilibrium, eqs 10-12 with the inertia terms dropped (the test of Sec 6 runs at
  omega = 0.628 rad/s, so it is quasi-static) and no distributed loads: solved in weak
  form, i.e. the internal virtual work ``int (N dnu + Q deta + M dmu) ds`` balances the
  work of the end reactions.

Discretisation
--------------
Two-node elements, linear interpolation of (u, v, theta), ONE Gauss point per element
(uniformly reduced integration). Why it is free of shear locking: with full (2-point)
integration the linear element cannot represent ``eta = v' - theta = 0`` together with a
non-zero curvature, so the shear energy GA* l^2/EJ ~ 1e4 times larger than the bending
energy locks the element; evaluated at the element midpoint the shear strain constraint
becomes one condition per element that linear fields can satisfy (the classical
reduced-integration Timoshenko / Simo-Vu-Quoc element). The element has no spurious
zero-energy modes (rank 3 = 6 dof - 3 rigid-body modes), and curvature and stretch are
constant per element so the single point integrates bending and axial terms exactly.
Its discretisation error is O(h^2): for the linear guided beam the deflection error is
1/N^2 of the bending part (N elements), verified in ``tests/test_beam.py``.

With one Gauss point the contact force ``n = N b1 + Q b2`` is constant per element and,
at equilibrium, identical in every element (no distributed load), so the restoring force
of Sec 6, ``f = N sin(theta) + Q cos(theta)`` at s = 0 (the e2 component of n), is read
from the first element and equals the e2 reaction at the moving end.

Solution
--------
Load (displacement) stepping with full Newton-Raphson. The tangent is consistent: the
element stiffness ``h (B^T D B + G)`` with the geometric part ``G`` from the second
derivatives of (nu, eta) in theta, and ``D_M = EJ_e + dM_h/dmu + 3 k3 mu^2`` where
``dM_h/dmu`` is the exact derivative of the discrete hysteresis update at the Gauss point:
eq 16 is rate independent, so M_h is integrated in the curvature increment of the step
with the trapezoidal rule over ``m`` sub-steps (m fixed per step from the predicted
increment so that no sub-step exceeds a fraction of the yield curvature
``mu_y = M_sat / EJ_h``, ``M_sat = (EJ_h / (gamma + beta))^(1/n)``), and the derivative is
carried through the sub-steps by the chain rule. The history variable is the converged
``(mu, M_h)`` of the last step; every Newton iterate re-integrates from it.
A step whose Newton iteration fails is split into 4, 16, 64 sub-increments.

Lanes: :func:`solve_path` runs several parameter sets (and/or load paths) in one call, one
numba-compiled Newton loop per lane, lanes spread over threads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from cablesvc.errors import SimulationError
from cablesvc.lanes import run_lanes
from cablesvc.models.boucwen import bouc_wen_rate

__all__ = [
    "Section", "BeamParams", "SolverOptions", "PathResult", "Loop", "PARAM_NAMES",
    "ROPE_7x19", "ROPE_7x7", "TABLE3", "TABLE4", "TABLE6", "OMEGA", "MODES",
    "solve_path", "stabilised_loop", "loop_path",
]

OMEGA = 0.628                      # rad/s, test frequency of 000 Sec 6
PARAM_NAMES = ("psi", "delta", "gamma", "beta", "n", "k3")
MODES = {"guided": 0, "rotation": 1, "force": 2}


@dataclass(frozen=True)
class Section:
    """Circular cross section of the equivalent beam (000 Sec 6): diameter [m], Young's
    modulus E [Pa], Poisson's ratio [-]; shear coefficient kappa of A* = kappa A [-]
    (default Cowper's 6(1+nu)/(7+6nu) for a solid circle)."""

    diameter: float
    E: float = 206e9
    poisson: float = 0.3
    shear_coefficient: float | None = None

    @property
    def A(self) -> float:          # m^2
        return math.pi * self.diameter ** 2 / 4.0

    @property
    def J(self) -> float:          # m^4
        return math.pi * self.diameter ** 4 / 64.0

    @property
    def G(self) -> float:          # Pa
        return self.E / (2.0 * (1.0 + self.poisson))

    @property
    def kappa(self) -> float:
        if self.shear_coefficient is not None:
            return float(self.shear_coefficient)
        return 6.0 * (1.0 + self.poisson) / (7.0 + 6.0 * self.poisson)

    @property
    def EA(self) -> float:         # N
        return self.E * self.A

    @property
    def GAs(self) -> float:        # N
        return self.G * self.kappa * self.A

    @property
    def EJ(self) -> float:         # N m^2
        return self.E * self.J


ROPE_7x19 = Section(diameter=0.010)      # 000 Sec 4/6: 7x19, d = 10 mm, E = 206 GPa, 0.3
ROPE_7x7 = Section(diameter=0.006)       # 7x7, d = 6 mm


@dataclass(frozen=True)
class BeamParams:
    """Parameters of eqs 15-18 of 000: psi [-], delta [-], gamma and beta
    [N^(1-n) m^(2-n)], n [-], k3 [N m^3]."""

    psi: float
    delta: float
    gamma: float
    beta: float
    n: float
    k3: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.psi, self.delta, self.gamma, self.beta, self.n, self.k3], dtype=float)

    @classmethod
    def from_array(cls, a) -> "BeamParams":
        a = np.asarray(a, dtype=float).ravel()
        return cls(*[float(v) for v in a[:5]], k3=float(a[5]) if a.size > 5 else 0.0)


# Paper 000, Table 3 (7x19, l = 75 mm, per amplitude [mm]), Table 4 (their means) and
# Table 6 (7x7, l = 100 mm, identified at A = 15 mm). k3 = 0 a priori (Sec 6).
TABLE3 = {
    5: BeamParams(0.0159, 0.251, 1.478, 1.729, 1.275),
    10: BeamParams(0.0162, 0.240, 1.391, 1.103, 1.152),
    15: BeamParams(0.0166, 0.21, 1.218, 1.151, 1.165),
    20: BeamParams(0.0168, 0.186, 1.684, 1.989, 1.285),
}
TABLE3_MSE_PERCENT = {5: 0.43, 10: 0.44, 15: 0.40, 20: 0.50}
TABLE4 = BeamParams(0.0164, 0.222, 1.443, 1.493, 1.219)
TABLE6 = BeamParams(0.0355, 0.201, 1.987, 1.188, 1.134)
TABLE2_BOUNDS = {"psi": (0.008, 0.025), "delta": (0.1, 0.6), "gamma": (0.8, 2.0), "beta": (0.8, 2.0),
                 "n": (1.0, 1.3)}


@dataclass
class SolverOptions:
    """Discretisation: ``n_elements`` two-node elements; ``steps_per_cycle`` load steps per
    period of the sine; ``cycles`` periods simulated (the last is returned as the
    stabilised one); ``substep_fraction``: largest hysteresis sub-step as a fraction of the
    yield curvature mu_y; Newton ``tol`` (increment, translations divided by l) and
    ``max_iter``; ``threads``: use numba's threads for several lanes."""

    n_elements: int = 24
    steps_per_cycle: int = 240
    cycles: int = 2
    substep_fraction: float = 0.25
    tol: float = 1e-11
    max_iter: int = 25
    threads: bool = True


# ---------------------------------------------------------------------------------------
# numba kernels
# ---------------------------------------------------------------------------------------

@numba.njit(cache=True, inline="always")
def _g(M, h, EJh, gam, bet, n):
    """dM_h/dmu of eq 16 and its derivative in M_h, for an increment of sign sgn(h): eq 16 is
    the Bouc-Wen law of 000 eq 1 in the curvature (k = EJ_h), so the slope is
    :func:`cablesvc.models.boucwen.bouc_wen_rate`'s dz'/dv at v = sgn(h) and its derivative
    in M_h is dz'/dz / v (v = +-1; h = 0 reads only the slope)."""
    sh = 1.0 if h > 0.0 else (-1.0 if h < 0.0 else 0.0)
    _, g, gz, _p = bouc_wen_rate(EJh, bet, gam, n, sh, M)
    return g, gz * sh


@numba.njit(cache=True)
def _bw_update(M0, dmu, nsub, EJh, gam, bet, n, mscale):
    """Trapezoidal integration of eq 16 over the curvature increment dmu in nsub equal
    sub-steps. Returns (M_h at the end, dM_h/d(dmu)) with the derivative exact for the
    discrete map (chain rule through the sub-steps)."""
    if dmu == 0.0:
        g, gp = _g(M0, 0.0, EJh, gam, bet, n)
        return M0, g
    h = dmu / nsub
    M = M0
    dM = 0.0
    for _ in range(nsub):
        g0, gp0 = _g(M, h, EJh, gam, bet, n)
        M1 = M + h * g0
        for _it in range(50):
            g1, gp1 = _g(M1, h, EJh, gam, bet, n)
            R = M1 - M - 0.5 * h * (g0 + g1)
            Jr = 1.0 - 0.5 * h * gp1
            d = R / Jr
            M1 -= d
            if abs(d) <= 1e-15 * (abs(M1) + mscale):
                break
        g1, gp1 = _g(M1, h, EJh, gam, bet, n)
        dM = (dM * (1.0 + 0.5 * h * gp0) + 0.5 * (g0 + g1) / nsub) / (1.0 - 0.5 * h * gp1)
        M = M1
    return M, dM


@numba.njit(cache=True)
def _band_solve(Ab, b, ndof, kd):
    """Gaussian elimination without pivoting on a band matrix Ab[i, kd + j - i] (the
    tangent is symmetric and, at stable equilibria, positive definite). b is overwritten
    with the solution. Returns False on a zero pivot."""
    for k in range(ndof):
        piv = Ab[k, kd]
        if piv == 0.0 or not np.isfinite(piv):
            return False
        iend = min(ndof, k + kd + 1)
        for i in range(k + 1, iend):
            lik = Ab[i, kd + k - i] / piv
            if lik != 0.0:
                for j in range(k, iend):
                    Ab[i, kd + j - i] -= lik * Ab[k, kd + j - k]
                b[i] -= lik * b[k]
    for k in range(ndof - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, min(ndof, k + kd + 1)):
            s -= Ab[k, kd + j - k] * b[j]
        b[k] = s / Ab[k, kd]
    return True


@numba.njit(cache=True)
def _element_state(q, e, h, EA, GAs, EJe, EJh, gam, bet, n, k3, mu_c, Mh_c, nsub, mscale, out):
    """Strains, stress resultants and hysteresis update of element e at its Gauss point.
    out = [c, s, nu, eta, mu, N, Q, M, Mh, dM/dmu]."""
    a = 3 * e
    du = (q[a + 3] - q[a]) / h
    dv = (q[a + 4] - q[a + 1]) / h
    th = 0.5 * (q[a + 2] + q[a + 5])
    mu = (q[a + 5] - q[a + 2]) / h
    c = math.cos(th)
    s = math.sin(th)
    nu = (1.0 + du) * c + dv * s                  # eq 8
    eta = -(1.0 + du) * s + dv * c                # eq 8
    Mh, dMh = _bw_update(Mh_c, mu - mu_c, nsub, EJh, gam, bet, n, mscale)   # eq 16
    out[0] = c
    out[1] = s
    out[2] = nu
    out[3] = eta
    out[4] = mu
    out[5] = EA * (nu - 1.0)                      # eq 9
    out[6] = GAs * eta                            # eq 9
    out[7] = EJe * mu + Mh + k3 * mu * mu * mu    # eq 15
    out[8] = Mh
    out[9] = EJe + dMh + 3.0 * k3 * mu * mu


@numba.njit(cache=True)
def _assemble(q, ne, h, EA, GAs, EJe, EJh, gam, bet, n, k3, mu_c, Mh_c, nsub, mscale,
              R, Ab, kd, st, Mh_t, mu_t):
    """Internal force vector R and banded consistent tangent Ab; element states in st."""
    R[:] = 0.0
    Ab[:, :] = 0.0
    Bn = np.empty(6)
    Bq = np.empty(6)
    Bm = np.zeros(6)
    av = np.zeros(6)
    bv = np.zeros(6)
    tv = np.zeros(6)
    av[0] = -1.0 / h
    av[3] = 1.0 / h
    bv[1] = -1.0 / h
    bv[4] = 1.0 / h
    tv[2] = 0.5
    tv[5] = 0.5
    Bm[2] = -1.0 / h
    Bm[5] = 1.0 / h
    out = np.empty(10)
    for e in range(ne):
        _element_state(q, e, h, EA, GAs, EJe, EJh, gam, bet, n, k3, mu_c[e], Mh_c[e], nsub[e], mscale, out)
        c, s, nu, eta, mu = out[0], out[1], out[2], out[3], out[4]
        N, Q, M, Dm = out[5], out[6], out[7], out[9]
        Mh_t[e] = out[8]
        mu_t[e] = mu
        for k in range(10):
            st[e, k] = out[k]
        Bn[0] = -c / h
        Bn[1] = -s / h
        Bn[2] = 0.5 * eta
        Bn[3] = c / h
        Bn[4] = s / h
        Bn[5] = 0.5 * eta
        Bq[0] = s / h
        Bq[1] = -c / h
        Bq[2] = -0.5 * nu
        Bq[3] = -s / h
        Bq[4] = c / h
        Bq[5] = -0.5 * nu
        nx = N * c - Q * s
        ny = N * s + Q * c
        gtt = N * nu + Q * eta
        a0 = 3 * e
        for i in range(6):
            R[a0 + i] += h * (N * Bn[i] + Q * Bq[i] + M * Bm[i])
            for j in range(6):
                kij = EA * Bn[i] * Bn[j] + GAs * Bq[i] * Bq[j] + Dm * Bm[i] * Bm[j]
                kij += -ny * (av[i] * tv[j] + tv[i] * av[j]) + nx * (bv[i] * tv[j] + tv[i] * bv[j]) \
                    - gtt * tv[i] * tv[j]
                Ab[a0 + i, kd + j - i] += h * kij


@numba.njit(cache=True)
def _newton(q, ne, h, L, EA, GAs, EJe, EJh, gam, bet, n, k3, mu_c, Mh_c, nsub, mscale,
            fixed, fext, tol, max_iter, R, Ab, kd, st, Mh_t, mu_t, rhs):
    """Newton-Raphson on the free dofs; prescribed dofs already hold their values in q."""
    ndof = q.size
    for it in range(max_iter):
        _assemble(q, ne, h, EA, GAs, EJe, EJh, gam, bet, n, k3, mu_c, Mh_c, nsub, mscale, R, Ab, kd, st, Mh_t, mu_t)
        for i in range(ndof):
            rhs[i] = fext[i] - R[i]
        for i in range(ndof):
            if fixed[i]:
                rhs[i] = 0.0
                for j in range(-kd, kd + 1):
                    Ab[i, kd + j] = 0.0
                    if 0 <= i + j < ndof:
                        Ab[i + j, kd - j] = 0.0
                Ab[i, kd] = 1.0
        if not _band_solve(Ab, rhs, ndof, kd):
            return False
        dmax = 0.0
        for i in range(ndof):
            if not np.isfinite(rhs[i]):
                return False
            q[i] += rhs[i]
            sc = 1.0 / L if i % 3 != 2 else 1.0
            d = abs(rhs[i]) * sc
            if d > dmax:
                dmax = d
        if dmax < tol:
            # states at the converged q
            _assemble(q, ne, h, EA, GAs, EJe, EJh, gam, bet, n, k3, mu_c, Mh_c, nsub, mscale, R, Ab, kd, st,
                      Mh_t, mu_t)
            return True
    return False


@numba.njit(cache=True)
def _run_lane(mode, L, EA, GAs, EJ, par, path, ne, rec0, sub_frac, tol, max_iter,
              out_tip, out_g):
    """One lane along the load path. mode 0: v(l) = path, theta(l) = 0, u(l) free (eq 28);
    mode 1: theta(l) = path, u(l), v(l) free; mode 2: dead end force along e2 = path [N],
    u, v, theta free at l. Records steps >= rec0. Returns 0 or the failing step (1-based)."""
    psi, delta, gam, bet, n, k3 = par[0], par[1], par[2], par[3], par[4], par[5]
    EJt = psi * EJ
    EJe = delta * EJt                                   # eq 18
    EJh = (1.0 - delta) * EJt                           # eq 18
    h = L / ne
    ndof = 3 * (ne + 1)
    kd = 5
    q = np.zeros(ndof)                                  # eq 29: u = theta = 0 at t = 0
    dq_prev = np.zeros(ndof)
    fixed = np.zeros(ndof, dtype=np.bool_)
    fixed[0] = True                                     # eq 28 at s = 0
    fixed[1] = True
    fixed[2] = True
    last = 3 * ne
    if mode == 0:
        fixed[last + 1] = True
        fixed[last + 2] = True
        pdof = last + 1
    elif mode == 1:
        fixed[last + 2] = True
        pdof = last + 2
    else:
        pdof = -1
    fext = np.zeros(ndof)
    R = np.empty(ndof)
    rhs = np.empty(ndof)
    Ab = np.zeros((ndof, 2 * kd + 1))
    st = np.zeros((ne, 10))
    mu_c = np.zeros(ne)
    Mh_c = np.zeros(ne)
    Mh_t = np.zeros(ne)
    mu_t = np.zeros(ne)
    nsub = np.ones(ne, dtype=np.int64)
    q_save = np.empty(ndof)
    q_start = np.empty(ndof)
    mu_save = np.empty(ne)
    Mh_save = np.empty(ne)
    if EJh > 0.0 and gam + bet > 0.0:
        Msat = (EJh / (gam + bet)) ** (1.0 / n)         # the law's bound (models.boucwen.bouc_wen_bound)
        mu_y = Msat / EJh
        mscale = Msat
    else:
        mu_y = 1e300
        mscale = 1.0
    dstep = sub_frac * mu_y
    nsteps = path.size
    p_prev = 0.0
    dp_prev = 0.0
    for k in range(nsteps):
        p_new = path[k]
        nsplit = 1
        ok = False
        while not ok:
            q_save[:] = q
            mu_save[:] = mu_c
            Mh_save[:] = Mh_c
            ok = True
            for j in range(1, nsplit + 1):
                for i in range(ndof):
                    q_start[i] = q[i]
                pj = p_prev + (p_new - p_prev) * j / nsplit
                dp = pj - (p_prev + (p_new - p_prev) * (j - 1) / nsplit)
                # predictor: last converged increment scaled to this increment
                if dp_prev != 0.0:
                    r = dp / dp_prev
                    for i in range(ndof):
                        q[i] += r * dq_prev[i]
                elif mode == 0 and k == 0:
                    for nd in range(ne + 1):
                        xi = nd / ne
                        q[3 * nd + 1] = pj * (3.0 * xi * xi - 2.0 * xi * xi * xi)
                        q[3 * nd + 2] = pj * 6.0 * (xi - xi * xi) / L
                for i in range(3):
                    q[i] = 0.0
                if mode == 0:
                    q[last + 1] = pj
                    q[last + 2] = 0.0
                elif mode == 1:
                    q[last + 2] = pj
                else:
                    fext[last + 1] = pj
                # hysteresis sub-steps for this increment, from the predicted curvatures
                for e in range(ne):
                    dmu = abs((q[3 * e + 5] - q[3 * e + 2]) / h - mu_c[e])
                    m = int(math.ceil(dmu / dstep)) if dstep < 1e299 else 1
                    nsub[e] = min(max(m, 1), 10000)
                conv = _newton(q, ne, h, L, EA, GAs, EJe, EJh, gam, bet, n, k3, mu_c, Mh_c, nsub, mscale,
                               fixed, fext, tol, max_iter, R, Ab, kd, st, Mh_t, mu_t, rhs)
                # the sub-step counts came from the predictor; recount them from the
                # converged curvature increments and solve again until they agree
                for _again in range(4):
                    if not conv or dstep >= 1e299:
                        break
                    more = False
                    for e in range(ne):
                        m = min(max(int(math.ceil(abs(mu_t[e] - mu_c[e]) / dstep)), 1), 10000)
                        if m != nsub[e]:
                            nsub[e] = m
                            more = True
                    if not more:
                        break
                    conv = _newton(q, ne, h, L, EA, GAs, EJe, EJh, gam, bet, n, k3, mu_c, Mh_c, nsub, mscale,
                                   fixed, fext, tol, max_iter, R, Ab, kd, st, Mh_t, mu_t, rhs)
                if not conv:
                    ok = False
                    break
                for i in range(ndof):
                    dq_prev[i] = q[i] - q_start[i]
                dp_prev = dp
                mu_c[:] = mu_t
                Mh_c[:] = Mh_t
            if not ok:
                q[:] = q_save
                mu_c[:] = mu_save
                Mh_c[:] = Mh_save
                dp_prev = 0.0
                nsplit *= 4
                if nsplit > 64:
                    return k + 1
        p_prev = p_new
        if k >= rec0:
            r_ = k - rec0
            out_tip[r_, 0] = q[last]
            out_tip[r_, 1] = q[last + 1]
            out_tip[r_, 2] = q[last + 2]
            out_tip[r_, 3] = st[0, 5] * st[0, 1] + st[0, 6] * st[0, 0]      # f = N sin + Q cos, element 1
            for e in range(ne):
                out_g[r_, e, 0] = st[e, 4]     # mu
                out_g[r_, e, 1] = st[e, 7]     # M
                out_g[r_, e, 2] = st[e, 8]     # M_h
                out_g[r_, e, 3] = st[e, 5]     # N
                out_g[r_, e, 4] = st[e, 6]     # Q
    return 0


@numba.njit(cache=True, parallel=True)
def _run_lanes_parallel(mode, L, EA, GAs, EJ, par, path, ne, rec0, sub_frac, tol, max_iter, out_tip, out_g, status):
    for lane in numba.prange(par.shape[0]):
        status[lane] = _run_lane(mode, L, EA, GAs, EJ, par[lane], path[lane], ne, rec0, sub_frac, tol, max_iter,
                                 out_tip[lane], out_g[lane])


@numba.njit(cache=True)
def _run_lanes_serial(mode, L, EA, GAs, EJ, par, path, ne, rec0, sub_frac, tol, max_iter, out_tip, out_g, status):
    for lane in range(par.shape[0]):
        status[lane] = _run_lane(mode, L, EA, GAs, EJ, par[lane], path[lane], ne, rec0, sub_frac, tol, max_iter,
                                 out_tip[lane], out_g[lane])


# ---------------------------------------------------------------------------------------
# Python API
# ---------------------------------------------------------------------------------------

@dataclass
class PathResult:
    """Recorded steps of :func:`solve_path` (lanes first).

    ``tip`` (lanes, steps, 4): u(l) [m], v(l) [m], theta(l) [rad], f [N] (e2 component of
    the contact force, = N sin(theta) + Q cos(theta) at s = 0). ``gauss`` (lanes, steps,
    elements, 5): mu [1/m], M [N m], M_h [N m], N [N], Q [N] at the Gauss points located at
    ``s`` [m]. ``status`` (lanes,): 0, or the 1-based step where Newton failed (that lane's
    records are then NaN)."""

    tip: np.ndarray
    gauss: np.ndarray
    s: np.ndarray
    status: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        return self.status == 0


def _as_params(params) -> np.ndarray:
    if isinstance(params, BeamParams):
        params = params.as_array()
    P = np.atleast_2d(np.asarray(params, dtype=float))
    if P.shape[1] == 5:
        P = np.hstack([P, np.zeros((P.shape[0], 1))])
    if P.shape[1] != 6:
        raise SimulationError(f"params: expected (lanes, 5 or 6) = psi, delta, gamma, beta, n[, k3]; got {P.shape}")
    bad = (P[:, 0] <= 0) | (P[:, 1] <= 0) | (P[:, 1] > 1) | (P[:, 4] < 1.0) | (P[:, 2] + P[:, 3] < 0)
    if np.any(bad):
        raise SimulationError(f"params: need psi > 0, 0 < delta <= 1, n >= 1, gamma + beta >= 0 (lanes {np.flatnonzero(bad).tolist()})")
    return np.ascontiguousarray(P)


def solve_path(section: Section, length: float, params, path, *, mode: str = "guided", record_from: int = 0,
               options: SolverOptions | None = None) -> PathResult:
    """Quasi-static solution along a load path, lanes batched.

    ``params``: :class:`BeamParams`, or array ``(lanes, 5|6)`` (psi, delta, gamma, beta, n[, k3]).
    ``path``: ``(steps,)`` or ``(lanes, steps)`` values of the controlled quantity per load
    step, starting from the undeformed state (eq 29): mode ``"guided"`` v(l) [m] with
    theta(l) = 0 and u(l) free (eq 28); ``"rotation"`` theta(l) [rad] with u(l), v(l)
    free (uniform-curvature test); ``"force"`` a dead end force along e2 [N] with the end
    free (elastica benchmark). Steps before ``record_from`` are not recorded.
    """
    opt = options or SolverOptions()
    P = _as_params(params)
    X = np.atleast_2d(np.asarray(path, dtype=float))
    lanes = max(P.shape[0], X.shape[0])
    if P.shape[0] == 1 and lanes > 1:
        P = np.repeat(P, lanes, axis=0)
    if X.shape[0] == 1 and lanes > 1:
        X = np.repeat(X, lanes, axis=0)
    if P.shape[0] != X.shape[0]:
        raise SimulationError(f"params has {P.shape[0]} lanes but path has {X.shape[0]}")
    X = np.ascontiguousarray(X)
    if mode not in MODES:
        raise SimulationError(f"mode must be one of {sorted(MODES)}")
    ne = int(opt.n_elements)
    if ne < 1:
        raise SimulationError("n_elements must be >= 1")
    nsteps = X.shape[1]
    rec0 = int(record_from)
    nrec = nsteps - rec0
    tip = np.full((lanes, nrec, 4), np.nan)
    gauss = np.full((lanes, nrec, ne, 5), np.nan)
    status = np.zeros(lanes, dtype=np.int64)
    args = (MODES[mode], float(length), section.EA, section.GAs, section.EJ, P, X, ne, rec0,
            float(opt.substep_fraction), float(opt.tol), int(opt.max_iter), tip, gauss, status)
    run_lanes(_run_lanes_parallel, _run_lanes_serial, lanes, *args, threads=opt.threads)
    failed = status != 0
    tip[failed] = np.nan
    gauss[failed] = np.nan
    s = (np.arange(ne) + 0.5) * (length / ne)
    return PathResult(tip=tip, gauss=gauss, s=s, status=status)


@dataclass
class Loop:
    """A stabilised force-displacement cycle (the last simulated period).

    ``t`` (m,) [s], ``x`` (lanes, m) prescribed end displacement [m], ``f`` (lanes, m)
    restoring force [N]; ``result`` the :class:`PathResult` of the recorded cycle (moments
    along the span etc.); ``amplitude`` (lanes,) [m]; ``length`` [m]."""

    t: np.ndarray
    x: np.ndarray
    f: np.ndarray
    result: PathResult
    amplitude: np.ndarray
    length: float
    omega: float = OMEGA
    info: dict = field(default_factory=dict)

    @property
    def status(self) -> np.ndarray:
        return self.result.status

    def area(self) -> np.ndarray:
        """Loop area = energy dissipated per cycle, closed trapezoidal integral of f dx [J]."""
        return np.sum(0.5 * (self.f[:, 1:] + self.f[:, :-1]) * np.diff(self.x, axis=1), axis=1)


def loop_path(amplitude, *, omega: float = OMEGA, steps_per_cycle: int = 240, cycles: int = 2):
    """Times and displacements x = A sin(omega t) (000 Sec 6) from t = 0 over ``cycles``
    periods with ``steps_per_cycle`` steps each. Returns ``t (steps,)``, ``x (lanes, steps)``
    and the index where the last period starts. (t = 0, x = 0 is the initial state and is
    not a load step.)"""
    A = np.atleast_1d(np.asarray(amplitude, dtype=float))
    T = 2.0 * np.pi / omega
    nst = int(steps_per_cycle) * int(cycles)
    t = np.arange(1, nst + 1) * (T / steps_per_cycle)
    x = A[:, None] * np.sin(omega * t)[None, :]
    rec0 = nst - int(steps_per_cycle) - 1          # include the point closing the previous cycle
    return t, x, rec0


def stabilised_loop(section: Section, length: float, params, amplitude, *, omega: float = OMEGA,
                    options: SolverOptions | None = None) -> Loop:
    """Test of 000 Sec 6 (eqs 28-29): clamped at s = 0, end s = l clamped in rotation and
    moved by x = A sin(omega t) along e2 with u(l) free, from the undeformed state, for
    ``options.cycles`` periods; returns the last (stabilised) period, steps_per_cycle + 1
    samples that close the loop. ``params`` lanes and ``amplitude`` [m] lanes broadcast."""
    opt = options or SolverOptions()
    P = _as_params(params)
    A = np.atleast_1d(np.asarray(amplitude, dtype=float))
    lanes = max(P.shape[0], A.size)
    if A.size == 1:
        A = np.repeat(A, lanes)
    t, x, rec0 = loop_path(A, omega=omega, steps_per_cycle=opt.steps_per_cycle, cycles=max(1, opt.cycles))
    res = solve_path(section, length, P, x, mode="guided", record_from=rec0, options=opt)
    return Loop(t=t[rec0:], x=x[:, rec0:], f=res.tip[:, :, 3], result=res, amplitude=A, length=float(length),
                omega=omega)
