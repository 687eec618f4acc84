"""Amplitude levels of a hold recording and the per-level fits of eq 8 of 002 (steps 2 and 4
of :func:`cablesvc.identify.amplitude_fit.fit_amplitude_model`).

:func:`segment_levels` finds the levels (runs of half-cycles of equal amplitude and centre,
from the reversal points of the elongation); :func:`level_trace` and
:func:`simulate_amplitude` run the kernel's amplitude model with lanes;
:func:`damping_regressor` is its damping term as a regressor; :func:`fit_levels` fits eq 8
with constant K0..K3, S_a, alpha per level (alpha grid with variable projection, then
:func:`~cablesvc.identify.local.refine` with the analytic Jacobian). Units: SI.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import digamma

from cablesvc.identify.identifiability import jacobian_statistics
from cablesvc.identify.local import refine
from cablesvc.identify.result import IdentifyResult
from cablesvc.models import AmplitudeDependent
from cablesvc.models.amplitude import SPEED_RATIO_MAX, damping_normaliser
from cablesvc.models.reversal import reversal_points
from cablesvc.robust import robust_std

__all__ = ["PER_LEVEL", "FREE", "UNITS", "ALPHA_GRID", "ALPHA_MAX", "Level", "segment_levels", "simulate_amplitude",
           "level_trace", "damping_regressor", "LevelData", "LevelFit", "lin_solve", "fit_levels"]

#: the parameters of eq 8 at one amplitude level, in this order (units N, N/m, N/m^2, N/m^3, J, -)
PER_LEVEL = ("K0", "K1", "K2", "K3", "S_a", "alpha")
#: the amplitude-dependent ones (f_A); K0 is one constant
FREE = ("K1", "K2", "K3", "S_a", "alpha")
UNITS = {"K0": "N", "K1": "N/m", "K2": "N/m^2", "K3": "N/m^3", "S_a": "J", "alpha": "-", "x_center": "m"}
ALPHA_GRID = np.linspace(0.0, 2.0, 21)
ALPHA_MAX = 3.0


@dataclass
class Level:
    """One amplitude level of one cable: samples ``start..stop`` (inclusive, both reversal
    points), amplitude A [m], centre [m], half period [s], reversal sample indices."""

    cable: int
    start: int
    stop: int
    amplitude: float
    center: float
    half_period: float
    reversals: np.ndarray

    @property
    def omega(self) -> float:
        return float(np.pi / self.half_period)


def segment_levels(x: np.ndarray, t: np.ndarray, *, cable: int = 0, rel_tol: float = 0.05,
                   min_half_cycles: int = 4, eps: float | None = None) -> list[Level]:
    """Split one cable's elongation ``x`` (N,) [m] at times ``t`` (N,) [s] into amplitude levels.

    Consecutive half-cycles (reversal to reversal) whose half-amplitudes agree within
    ``rel_tol`` and whose midpoints agree within ``rel_tol`` times the amplitude form a
    level; runs shorter than ``min_half_cycles`` (ramps between levels) are dropped.
    ``eps`` [m] is the reversal-detection threshold (default 0.1 % of the peak-to-peak
    elongation, at least 1 nm, and at least 10 x the noise of the elongation, estimated from
    the median absolute second difference: a pose that is measured rather than commanded
    carries micrometres of noise, which would otherwise make a reversal of every wiggle)."""
    x = np.asarray(x, dtype=float)
    t = np.asarray(t, dtype=float)
    if eps is None:
        eps = max(1e-9, 1e-3 * (float(np.ptp(x)) if x.size else 0.0))
        if x.size > 10:
            d2 = np.diff(x, 2)
            sigma = float(robust_std(d2)) / np.sqrt(6.0)
            eps = max(eps, 10.0 * sigma)
    r = reversal_points(x, eps)
    if r.size < 2:
        return []
    half = 0.5 * np.abs(np.diff(x[r]))
    mid = 0.5 * (x[r[1:]] + x[r[:-1]])
    dur = np.diff(t[r])
    levels: list[Level] = []
    i = 0
    H = half.size
    while i < H:
        j = i + 1
        while j < H:
            a_ref = np.median(half[i:j])
            c_ref = np.median(mid[i:j])
            if abs(half[j] - a_ref) > rel_tol * a_ref or abs(mid[j] - c_ref) > rel_tol * a_ref:
                break
            j += 1
        if j - i >= min_half_cycles:
            idx = r[i: j + 1]
            levels.append(Level(cable=cable, start=int(idx[0]), stop=int(idx[-1]),
                                amplitude=float(np.median(half[i:j])), center=float(np.median(mid[i:j])),
                                half_period=float(np.median(dur[i:j])), reversals=idx.copy()))
        i = j
    return levels


# --------------------------------------------------------------------------------------
# the model, simulated with lanes
# --------------------------------------------------------------------------------------


def simulate_amplitude(x: np.ndarray, dt: float, values: dict[str, np.ndarray], x_center: np.ndarray,
                       amplitude: np.ndarray, half_period: np.ndarray, rising: np.ndarray) -> np.ndarray:
    """Run the kernel's amplitude model with one constant table row per (lane, cable).

    ``x`` (T, m) [m]; ``values[name]`` (L, m) for each of :data:`PER_LEVEL`; ``x_center``,
    ``amplitude`` [m], ``half_period`` [s], ``rising`` (bool: the motion after sample 0 goes
    up) all (m,). The state starts at sample 0 as a just-detected reversal of a cycle of
    that amplitude and half period. Returns the force (T, L, m) [N]."""
    L = next(iter(values.values())).shape[0]
    m = x.shape[1]
    A = np.asarray(amplitude, float)
    # one table row: a grid of one tiny amplitude, so the kernel's floor max(A, grid[0]) never binds
    model = AmplitudeDependent((L, m), amplitudes=[1e-12], x_center=x_center, amplitude_init=A,
                               omega_init=np.pi / np.asarray(half_period, float),
                               **{k: np.asarray(values[k], float)[..., None] for k in PER_LEVEL})
    st = model.create_state(np.broadcast_to(x[0], (L, m)))
    st.memory[0] = x[0]                                   # the start is the last reversal point
    st.memory[1] = A                                      # amplitude and half period of the level
    st.memory[2] = np.asarray(half_period, float)
    st.memory[3] = 0.0                                    # ... detected now (clock 0)
    st.direction[...] = np.where(rising, 1.0, -1.0)       # already moving the coming way
    out = np.empty((x.shape[0], L, m))
    xs = np.ascontiguousarray(np.broadcast_to(np.asarray(x, float)[:, None, :], (x.shape[0], L, m)))
    step = model.step
    for k in range(x.shape[0]):
        out[k] = step(st, xs[k], dt if k else 0.0)
    return out


def level_trace(x: np.ndarray, dt: float, x_center: np.ndarray, amplitude: np.ndarray, half_period: np.ndarray,
                rising: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Damping-regressor factors of one level window, from ONE run of the kernel model.

    ``x`` (T, m) [m], the other arguments (m,) as in :func:`simulate_amplitude`. The
    kernel's damping force is ``S_a q(alpha) / A' (|dx| T_h / (dt pi A'))^alpha sgn`` with its
    online amplitude estimate A' (floored at the table's smallest amplitude), half period
    T_h and direction sgn, which depend on the elongation only. Returns ``(base, pref)``
    (T, m) with ``base = min(|dx| T_h / (max(dt, 1e-12) pi A'), SPEED_RATIO_MAX)`` and ``pref = sgn / A'`` so
    that the damping force per unit S_a is :func:`damping_regressor` ``(base, pref, alpha)``."""
    m = x.shape[1]
    A = np.asarray(amplitude, float)
    amin = 1e-12                                          # the one-point grid of simulate_amplitude
    z = np.zeros((1, m, 1))
    model = AmplitudeDependent((1, m), amplitudes=[amin], x_center=x_center, amplitude_init=A,
                               omega_init=np.pi / np.asarray(half_period, float), K0=z, K1=z, K2=z, K3=z, S_a=z,
                               alpha=z)
    st = model.create_state(x[0][None])
    st.memory[0] = x[0]
    st.memory[1] = A
    st.memory[2] = np.asarray(half_period, float)
    st.memory[3] = 0.0
    st.direction[...] = np.where(rising, 1.0, -1.0)
    T = x.shape[0]
    Aest = np.empty((T, m))
    Th = np.empty((T, m))
    sg = np.empty((T, m))
    xs = np.ascontiguousarray(np.asarray(x, float))
    for k in range(T):
        model.step(st, xs[k][None], dt if k else 0.0)
        Aest[k] = st.memory[1, 0]
        Th[k] = st.memory[2, 0]
        sg[k] = st.direction[0]
    aeff = np.maximum(Aest, amin)
    dx = np.abs(np.diff(xs, axis=0, prepend=xs[:1]))
    dts = np.full((T, 1), max(dt, 1e-12))
    dts[0] = 1e-12
    base = np.minimum(dx * Th / (dts * np.pi * aeff), SPEED_RATIO_MAX)      # as the kernel holds it
    return base, sg / aeff


def damping_regressor(base: np.ndarray, pref: np.ndarray, alpha: Any, *, derivative: bool = False):
    """``q(alpha) base^alpha pref`` (the kernel's damping force for S_a = 1 J) and, with
    ``derivative``, also its derivative with respect to alpha. ``alpha`` broadcasts."""
    alpha = np.asarray(alpha, float)
    q = damping_normaliser(alpha)
    D = q * np.power(base, alpha) * pref
    if not derivative:
        return D
    # d ln q / d alpha = -d ln I / d alpha = -(psi(alpha/2 + 1) - psi(alpha/2 + 3/2)) / 2
    dlnq = -0.5 * (digamma(alpha / 2 + 1.0) - digamma(alpha / 2 + 1.5))
    with np.errstate(divide="ignore"):
        lb = np.where(base > 0, np.log(np.where(base > 0, base, 1.0)), 0.0)
    return D, D * (lb + dlnq)


# --------------------------------------------------------------------------------------
# per-level fits
# --------------------------------------------------------------------------------------


@dataclass
class LevelData:
    """The samples of one level of one cable that the residuals use (from the level's
    second reversal on): ``xi`` = x - x_center [m], measured force ``y`` [N] and the damping
    factors ``base``, ``pref`` of :func:`level_trace`; ``amplitude`` [m]."""

    amplitude: float
    xi: np.ndarray
    y: np.ndarray
    base: np.ndarray
    pref: np.ndarray


@dataclass
class LevelFit:
    """Fit of eq 8 at one amplitude level, all fitted cables (``cables``)."""

    amplitude: np.ndarray          # (m_fit,) [m] amplitude per cable (from the segmentation)
    levels: list[Level]            # one per fitted cable
    results: list[IdentifyResult]  # one per fitted cable: x = K0, K1, K2, K3, S_a, alpha
    x: np.ndarray                  # (T, m_fit) elongation of the window [m]
    force: np.ndarray              # (T, m_fit) measured [N]
    model: np.ndarray              # (T, m_fit) fitted model [N] (the kernel model run)
    t: np.ndarray                  # (T,) [s]
    data: list[LevelData] = field(default_factory=list, repr=False)   # per cable
    #: (m_fit,) bool: the level could not tell alpha (:func:`_alpha_unidentified`); fitted at 0
    alpha_fixed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def rmse(self) -> np.ndarray:
        return np.sqrt(np.nanmean((self.model - self.force) ** 2, axis=0))


def lin_solve(Phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Column-scaled linear least squares: normal equations of the equilibrated matrix (far
    faster than an SVD for these tall, few-column problems), an SVD solve when those are
    ill-conditioned."""
    sc = np.linalg.norm(Phi, axis=0)
    sc[sc == 0] = 1.0
    G = (Phi.T @ Phi) / np.outer(sc, sc)
    g = (Phi.T @ y) / sc
    if np.linalg.cond(G) < 1e10:
        return np.linalg.solve(G, g) / sc
    return np.linalg.lstsq(Phi / sc, y, rcond=None)[0] / sc


#: chi-square(1) 95 % quantile: the variable projection's profile ss(alpha) - min ss, in
#: units of the residual variance, under which alpha values are not told apart (Wilks)
ALPHA_PROFILE_CHI2 = 3.841


def _alpha_unidentified(profile: np.ndarray, n: int) -> bool:
    """Whether the profile ss(alpha) [N^2] over the alpha grid of a level of ``n`` samples
    stays within ALPHA_PROFILE_CHI2 residual variances of its minimum everywhere: every
    alpha of the grid is then inside the 95 % profile-likelihood interval, and the level
    cannot tell the damping's rate law (a triangle wave: |v| constant within the level, so
    |v|^alpha is a constant S_a takes). Left to the fit, alpha then lands anywhere in its
    range (0 or 2 on a triangle calibration of the realistic bench), and a level's alpha of
    2 made the damping force of the identified model (|v| T / (pi A))^2 S_a q / A run to
    hundreds of newtons when it next moved after a long hold."""
    lo = float(np.min(profile))
    if not np.isfinite(lo) or n <= 7:
        return False
    s2 = lo / (n - 6)
    return bool(s2 > 0 and float(np.max(profile)) - lo <= ALPHA_PROFILE_CHI2 * s2)


def _level_linear(d: LevelData, alpha: float) -> np.ndarray:
    """K0..K3, S_a (S_a >= 0) at a given alpha: linear least squares."""
    B = np.stack([np.ones(d.xi.size), d.xi, d.xi ** 2, d.xi ** 3], axis=1)
    Phi = np.column_stack([B, damping_regressor(d.base, d.pref, alpha)])
    coef = lin_solve(Phi, d.y)
    if coef[4] < 0:                                       # no negative loop area
        coef = np.append(lin_solve(B, d.y), 0.0)
    return coef


def fit_levels(t: np.ndarray, x: np.ndarray, force: np.ndarray, levels: list[Level], x_center: np.ndarray,
               *, alpha_grid: np.ndarray = ALPHA_GRID, max_nfev: int | None = None) -> LevelFit:
    """Fit K0..K3, S_a, alpha of eq 8 for one level of every cable (columns of x, force).

    ``levels[c]`` is the level of cable column c; each cable is fitted on its own samples
    ``levels[c].start .. stop``; the windows are shifted to start together so that all
    cables run as the cables of one model instance. Samples are taken as uniformly spaced
    (dt = median time step [s]). Returns a :class:`LevelFit`.
    """
    m = x.shape[1]
    dt = float(np.median(np.diff(t)))
    T = max(lv.stop - lv.start for lv in levels) + 1
    X = np.empty((T, m))
    Fm = np.empty((T, m))
    mask = np.zeros((T, m), dtype=bool)
    for c, lv in enumerate(levels):
        n = lv.stop - lv.start + 1
        X[:n, c] = x[lv.start: lv.stop + 1, c]
        X[n:, c] = x[lv.stop, c]
        Fm[:n, c] = force[lv.start: lv.stop + 1, c]
        Fm[n:, c] = force[lv.stop, c]
        first = int(lv.reversals[1] - lv.start) if lv.reversals.size > 1 else 0
        mask[first:n, c] = True
    A = np.array([lv.amplitude for lv in levels])
    Th = np.array([lv.half_period for lv in levels])
    rising = np.array([x[lv.reversals[1], c] > x[lv.reversals[0], c] if lv.reversals.size > 1
                       else X[min(1, T - 1), c] >= X[0, c] for c, lv in enumerate(levels)])
    xc = np.asarray(x_center, float)
    xi = X - xc
    base, pref = level_trace(X, dt, xc, A, Th, rising)
    names = list(PER_LEVEL)
    results = []
    data = []
    theta = np.zeros((m, 6))
    alpha_fixed = np.zeros(m, dtype=bool)
    for c in range(m):
        r = np.flatnonzero(mask[:, c])
        d = LevelData(amplitude=float(A[c]), xi=xi[r, c].copy(), y=Fm[r, c].copy(), base=base[r, c].copy(),
                      pref=pref[r, c].copy())
        data.append(d)
        # 1) variable projection on an alpha grid
        best = (np.inf, None)
        profile = []
        for a in alpha_grid:
            coef = _level_linear(d, float(a))
            Dg = damping_regressor(d.base, d.pref, float(a))
            ss = float(np.sum((coef[0] + d.xi * (coef[1] + d.xi * (coef[2] + d.xi * coef[3])) + coef[4] * Dg
                               - d.y) ** 2))
            profile.append(ss)
            if ss < best[0]:
                best = (ss, np.append(coef, a))
        B = np.stack([np.ones(d.xi.size), d.xi, d.xi ** 2, d.xi ** 3], axis=1)

        def residuals(th, d=d, B=B):
            return B @ th[:4] + th[4] * damping_regressor(d.base, d.pref, th[5]) - d.y

        def jac(th, d=d, B=B):
            D, dD = damping_regressor(d.base, d.pref, th[5], derivative=True)
            return np.column_stack([B, D, th[4] * dD])

        alpha_fixed[c] = _alpha_unidentified(np.array(profile), d.y.size)
        if alpha_fixed[c]:
            # the level cannot tell the damping's rate law (a triangle's speed is constant
            # within a level, so |v|^alpha is one constant S_a takes): rate-independent
            th = np.append(_level_linear(d, 0.0), 0.0)
            run = dict(nfev=len(alpha_grid), nit=0, success=True, history=np.array(profile),
                       method="varpro (alpha fixed at 0)",
                       message=("alpha not identifiable at this level (the variable projection's profile over "
                                f"alpha {alpha_grid[0]:g}..{alpha_grid[-1]:g} stays within the 95 % bound): "
                                "alpha = 0, a rate-independent loop"))
        else:
            th0 = best[1].copy()
            th0[5] = np.clip(th0[5], 1e-6, ALPHA_MAX - 1e-6)
            th0[4] = max(th0[4], 1e-300)
            # 2) least-squares refinement of all six (002 eqs 12-14), analytic Jacobian
            kw = {} if max_nfev is None else {"max_nfev": max_nfev}
            # LM is unbounded: a step may take alpha far out of range (to inf on a loop the law
            # fits poorly), which overflows the regressor; such a result is refitted bounded
            # below, so its floating-point warnings are not the user's concern
            with np.errstate(over="ignore", invalid="ignore"):
                res = refine(residuals, th0, None, method="lm", jac=jac, statistics=False, **kw)
            th = np.asarray(res.x, float).copy()
            if not (0.0 <= th[5] <= ALPHA_MAX):                # LM is unbounded: keep alpha in range
                res = refine(residuals, th0, ([-np.inf] * 4 + [0.0, 0.0], [np.inf] * 5 + [ALPHA_MAX]),
                             method="trf", jac=jac, statistics=False, **kw)
                th = np.asarray(res.x, float).copy()
            th[:5] = _level_linear(d, float(th[5]))           # exact linear part at the final alpha
            run = dict(nfev=res.nfev, nit=res.nit, success=res.success, message=res.message,
                       history=res.history, method="varpro+least_squares/lm")
        Jc, rc = jac(th), residuals(th)
        if alpha_fixed[c]:
            Jc[:, 5] = 0.0                                  # alpha held, not estimated
        st = jacobian_statistics(Jc, rc, names=names, x=th)
        theta[c] = th
        results.append(IdentifyResult(
            x=th, fun=0.5 * float(rc @ rc), names=names, jac=Jc, residual=rc, stderr=st.stderr,
            covariance=st.covariance, correlation=st.correlation, cond=st.cond, cond_raw=st.cond_raw,
            sigma2=st.sigma2, redundant=st.groups, rmse=float(np.sqrt(np.mean(rc ** 2))), **run))
    # the fitted force from the kernel model itself (not the regressor shortcut)
    F_fit = simulate_amplitude(X, dt, {k: theta[:, j][None, :].copy() for j, k in enumerate(names)},
                               xc, A, Th, rising)[:, 0, :]
    return LevelFit(amplitude=A, levels=list(levels), results=results, x=np.where(mask, X, np.nan),
                    force=np.where(mask, Fm, np.nan), model=np.where(mask, F_fit, np.nan), t=np.arange(T) * dt,
                    data=data, alpha_fixed=alpha_fixed)
