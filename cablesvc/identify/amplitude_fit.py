"""The amplitude-dependent cable model of paper 002 Sec 3, identified from a hold recording.

Eq 8 of 002 for one cable, with xi = x - x_center [m] and v = dxi/dt [m/s]::

    F = K0 + K1(A) xi + K2(A) xi^2 + K3(A) xi^3 + S_a(A) |v|^alpha(A) sgn(v) / (A (A w)^alpha(A) l pi)

(K_k in N/m^k, S_a the loop area [J], alpha dimensionless, A the amplitude [m], w the
angular frequency [rad/s]; the damping normalisation is the kernel's, see
:class:`cablesvc.models.AmplitudeDependent`).

What is per level (decided from the paper): Sec 3 says that for a given amplitude level
eq 8 has a five-dimensional parameter space in which K0 "determines the pretensioned
cable state with A = 0 and v = 0", leaving ``p_M = [K1 K2 K3 S_a]`` (eq 10), and eq 8 also
writes ``alpha(A)``. So K0 is ONE constant (eq 8 writes K0, not K0(A)) and K1, K2, K3,
S_a, alpha are the amplitude functions ``p_M,i = f_A,i(A)`` of Sec 3.

Forms of f_A: the paper gives none (eqs 15-17 fix the excitation ``-A cos wt`` and the
damping normalisation ``2 A (A w)^alpha int sin^(alpha+1)``, which eq 8 already contains,
not how the parameters vary with A). We use, with u = A / A_max (A_max the largest fitted
level):

* K1, K2, K3, alpha: polynomials in u of degree 0..2;
* S_a = A^2 g(u), g a polynomial in u of degree 0..2 [N/m]: the loop area of a hysteresis
  whose force amplitude is proportional to A grows like A^2 (for a loss factor eta and a
  stiffness K it is pi eta K A^2); g carries the amplitude dependence of eta K.

Degrees (model selection, per cable): forward selection starting from all degrees 0; at
each step the candidate "one more degree for one parameter" with the largest score
(Lagrange-multiplier) statistic is accepted when that statistic exceeds the chi^2(1)
quantile at ``significance`` (default 1 %) Bonferroni-divided by the number of candidates
tested in the step over all cables, so that the chance of giving any parameter of any
cable an amplitude dependence the data do not show stays below ``significance`` per step.
The noise variance of the statistic comes from the fit with every degree at its maximum.

Pipeline (:func:`fit_amplitude_model`):

1. elongation from inverse kinematics on the recorded pose minus the motor lengths;
2. :func:`segment_levels`: reversal points of each cable's elongation, half-cycles of equal
   amplitude and centre grouped into levels (at least ``min_half_cycles`` of them);
3. x_center per cable: the median of the level centres (the pretension working point);
4. per level (:func:`fit_levels`): eq 8 with constant K0, K1, K2, K3, S_a, alpha. The
   kernel's amplitude model is run ONCE per level to record its amplitude/half-period
   estimate and direction at every sample (they depend on the elongation only); the damping
   regressor of any alpha is then ``q(alpha) base^alpha pref`` (the kernel's damping term
   with S_a = 1, exactly, see :func:`level_trace`). An alpha grid with linear least squares
   for the other five (variable projection), then :func:`~cablesvc.identify.local.refine`
   (002 eqs 12-14) with the analytic Jacobian, gives per-level values and standard errors;
5. joint fit (:func:`fit_joint`): the coefficients of every f_A and K0 are fitted against
   ALL fitted levels' samples at once (one least-squares problem per cable, LM of 002
   eq 14, analytic Jacobian), started from weighted polynomial fits to the per-level
   values; degrees by the forward selection above;
6. the tables: every f_A sampled on ``table_points`` geometrically spaced amplitudes
   between the smallest and the largest fitted level (the kernel interpolates linearly
   between them and holds the end values outside), a ModelParams built by the caller.

The model state of each level starts at the level's first reversal point as if that
reversal had just been detected (last reversal point = the start, amplitude and half
period from the segmentation), so the kernel's online amplitude/frequency estimator is
exact from the first sample of the window; residuals count from the level's second
reversal (before it the recorded system's own estimate still holds the previous level).
Levels listed in ``hold_out`` are never used by any fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numba
import numpy as np
from scipy.special import digamma
from scipy.stats import chi2 as chi2_dist

from cablesvc.identify.identifiability import jacobian_statistics
from cablesvc.identify.local import refine
from cablesvc.identify.result import IdentifyResult
from cablesvc.models import AmplitudeDependent
from cablesvc.models.amplitude import damping_normaliser
from cablesvc.models.reversal import reversal_amplitude, reversal_points

__all__ = [
    "Level", "segment_levels", "reversal_points", "reversal_amplitude", "LevelFit", "AmplitudeFit", "fit_levels", "level_trace",
    "damping_regressor", "AmplitudeFunction", "fit_amplitude_function", "fit_joint", "fit_amplitude_model",
    "PER_LEVEL", "FREE", "simulate_amplitude",
]

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
    elongation, at least 1 nm)."""
    x = np.asarray(x, dtype=float)
    t = np.asarray(t, dtype=float)
    if eps is None:
        eps = max(1e-9, 1e-3 * (float(np.ptp(x)) if x.size else 0.0))
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
    (T, m) with ``base = |dx| T_h / (max(dt, 1e-12) pi A')`` and ``pref = sgn / A'`` so
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
    base = dx * Th / (dts * np.pi * aeff)
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

    @property
    def rmse(self) -> np.ndarray:
        return np.sqrt(np.nanmean((self.model - self.force) ** 2, axis=0))


def _lin_solve(Phi: np.ndarray, y: np.ndarray) -> np.ndarray:
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


def _level_linear(d: LevelData, alpha: float) -> np.ndarray:
    """K0..K3, S_a (S_a >= 0) at a given alpha: linear least squares."""
    B = np.stack([np.ones(d.xi.size), d.xi, d.xi ** 2, d.xi ** 3], axis=1)
    Phi = np.column_stack([B, damping_regressor(d.base, d.pref, alpha)])
    coef = _lin_solve(Phi, d.y)
    if coef[4] < 0:                                       # no negative loop area
        coef = np.append(_lin_solve(B, d.y), 0.0)
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
    for c in range(m):
        r = np.flatnonzero(mask[:, c])
        d = LevelData(amplitude=float(A[c]), xi=xi[r, c].copy(), y=Fm[r, c].copy(), base=base[r, c].copy(),
                      pref=pref[r, c].copy())
        data.append(d)
        # 1) variable projection on an alpha grid
        best = (np.inf, None)
        for a in alpha_grid:
            coef = _level_linear(d, float(a))
            Dg = damping_regressor(d.base, d.pref, float(a))
            ss = float(np.sum((coef[0] + d.xi * (coef[1] + d.xi * (coef[2] + d.xi * coef[3])) + coef[4] * Dg
                               - d.y) ** 2))
            if ss < best[0]:
                best = (ss, np.append(coef, a))
        th0 = best[1].copy()
        th0[5] = np.clip(th0[5], 1e-6, ALPHA_MAX - 1e-6)
        th0[4] = max(th0[4], 1e-300)
        B = np.stack([np.ones(d.xi.size), d.xi, d.xi ** 2, d.xi ** 3], axis=1)

        def residuals(th, d=d, B=B):
            return B @ th[:4] + th[4] * damping_regressor(d.base, d.pref, th[5]) - d.y

        def jac(th, d=d, B=B):
            D, dD = damping_regressor(d.base, d.pref, th[5], derivative=True)
            return np.column_stack([B, D, th[4] * dD])

        # 2) least-squares refinement of all six (002 eqs 12-14), analytic Jacobian
        kw = {} if max_nfev is None else {"max_nfev": max_nfev}
        res = refine(residuals, th0, None, method="lm", jac=jac, statistics=False, **kw)
        th = np.asarray(res.x, float).copy()
        if not (0.0 <= th[5] <= ALPHA_MAX):                # LM is unbounded: keep alpha in range
            res = refine(residuals, th0, ([-np.inf] * 4 + [0.0, 0.0], [np.inf] * 5 + [ALPHA_MAX]), method="trf",
                         jac=jac, statistics=False, **kw)
            th = np.asarray(res.x, float).copy()
        th[:5] = _level_linear(d, float(th[5]))           # exact linear part at the final alpha
        Jc, rc = jac(th), residuals(th)
        st = jacobian_statistics(Jc, rc, names=names, x=th)
        theta[c] = th
        results.append(IdentifyResult(
            x=th, fun=0.5 * float(rc @ rc), nfev=res.nfev, nit=res.nit, success=res.success, message=res.message,
            names=names, history=res.history, jac=Jc, residual=rc, stderr=st.stderr, covariance=st.covariance,
            correlation=st.correlation, cond=st.cond, cond_raw=st.cond_raw, sigma2=st.sigma2, redundant=st.groups,
            method="varpro+least_squares/lm", rmse=float(np.sqrt(np.mean(rc ** 2)))))
    # the fitted force from the kernel model itself (not the regressor shortcut)
    F_fit = simulate_amplitude(X, dt, {k: theta[:, j][None, :].copy() for j, k in enumerate(names)},
                               xc, A, Th, rising)[:, 0, :]
    return LevelFit(amplitude=A, levels=list(levels), results=results, x=np.where(mask, X, np.nan),
                    force=np.where(mask, Fm, np.nan), model=np.where(mask, F_fit, np.nan), t=np.arange(T) * dt,
                    data=data)


# --------------------------------------------------------------------------------------
# f_A: parameters as functions of the amplitude, fitted jointly over all levels
# --------------------------------------------------------------------------------------


@dataclass
class AmplitudeFunction:
    """``p = f_A(A) = A^power * sum_j coef[j] u^j`` with ``u = A / scale`` (``A`` [m]) for
    one parameter of one cable; ``cov``: covariance of ``coef`` (from the joint fit);
    ``chi2``: the score statistic of the next degree, which the selection did not accept
    (NaN when no higher degree was tested); ``log`` is always False (kept for readers of
    older fits)."""

    name: str
    coef: np.ndarray
    scale: float = 1.0
    power: int = 0
    degree: int = 0
    chi2: float = float("nan")
    cov: np.ndarray | None = None
    log: bool = False

    def basis(self, A: Any) -> np.ndarray:
        A = np.atleast_1d(np.asarray(A, dtype=float))
        u = A / self.scale
        return (A ** self.power)[:, None] * u[:, None] ** np.arange(self.coef.size)[None, :]

    def __call__(self, A: Any) -> np.ndarray:
        out = self.basis(A) @ self.coef
        return out if np.ndim(A) else out[0]

    def stderr(self, A: Any) -> np.ndarray:
        """Standard error of f_A(A) from ``cov`` (NaN without it)."""
        if self.cov is None:
            return np.full(np.shape(np.atleast_1d(A)), np.nan)
        G = self.basis(A)
        return np.sqrt(np.einsum("ij,jk,ik->i", G, self.cov, G))


def fit_amplitude_function(name: str, A: np.ndarray, p: np.ndarray, se: np.ndarray, *, degree: int = 0,
                           power: int = 0, scale: float | None = None) -> AmplitudeFunction:
    """Weighted (1/se^2) least-squares polynomial of ``p / A^power`` in ``u = A / scale`` of
    the given degree through per-level values ``p`` with standard errors ``se``: the start
    of the joint fit."""
    A = np.asarray(A, float)
    p = np.asarray(p, float)
    se = np.asarray(se, float)
    scale = float(np.max(A)) if scale is None else float(scale)
    y, s = p / A ** power, se / A ** power
    ok = np.isfinite(y) & np.isfinite(s) & (s > 0)
    if not np.any(ok):
        ok, s = np.isfinite(y), np.ones_like(y)
    u, y, w = A[ok] / scale, y[ok], 1.0 / s[ok]
    degree = int(min(degree, u.size - 1))
    V = u[:, None] ** np.arange(degree + 1)[None, :]
    coef = np.linalg.lstsq(V * w[:, None], y * w, rcond=None)[0]
    return AmplitudeFunction(name=name, coef=coef, scale=scale, power=power, degree=degree)


#: S_a = A^2 g(u); the others are polynomials in u
POWER = {"K0": 0, "K1": 0, "K2": 0, "K3": 0, "S_a": 2, "alpha": 0}


class _JointProblem:
    """Eq 8 with every parameter an f_A, all fitted levels of one cable stacked.

    The coefficient vector has the full layout ``K0, K1[0..D], K2[0..D], K3[0..D],
    S_a[0..D], alpha[0..D]`` (D the largest degree allowed); a boolean mask says which
    coefficients a form uses (the others are held at 0)."""

    def __init__(self, data: list[LevelData], max_degree: int):
        self.L = len(data)
        self.D = int(max(0, min(max_degree, self.L - 1)))
        self.A = np.array([d.amplitude for d in data])
        self.scale = float(self.A.max())
        self.u = self.A / self.scale
        self.lev = np.concatenate([np.full(d.y.size, i) for i, d in enumerate(data)])
        self.xi = np.concatenate([d.xi for d in data])
        self.y = np.concatenate([d.y for d in data])
        self.base = np.concatenate([d.base for d in data])
        self.pref = np.concatenate([d.pref for d in data])
        self.N = self.y.size
        n1 = self.D + 1
        self.names = ["K0"] + [f"{k}[{j}]" for k in FREE for j in range(n1)]
        self.P = len(self.names)
        U = self.u[self.lev]
        powU = U[:, None] ** np.arange(n1)[None, :]
        cols = [np.ones((self.N, 1))] + [(self.xi ** k)[:, None] * powU for k in (1, 2, 3)]
        self.Kcols = np.concatenate(cols, axis=1)                 # K0, K1[.], K2[.], K3[.]
        self.powU = powU
        self.powu = self.u[:, None] ** np.arange(n1)[None, :]     # (L, n1)
        self.nK = self.Kcols.shape[1]

    def sl(self, name: str) -> slice:
        if name == "K0":
            return slice(0, 1)
        i = FREE.index(name)
        return slice(1 + i * (self.D + 1), 1 + (i + 1) * (self.D + 1))

    def mask(self, forms: dict[str, int]) -> np.ndarray:
        mk = np.zeros(self.P, dtype=bool)
        mk[0] = True
        for k in FREE:
            s = self.sl(k)
            mk[s.start: s.start + forms[k] + 1] = True
        return mk

    def level_values(self, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """S_a (L,) [J] and alpha (L,) at the fitted levels."""
        Sa = self.A ** 2 * (self.powu @ th[self.sl("S_a")])
        al = np.clip(self.powu @ th[self.sl("alpha")], 1e-9, ALPHA_MAX)
        return Sa, al

    def damping(self, th: np.ndarray, derivative: bool = False):
        _, al = self.level_values(th)
        return damping_regressor(self.base, self.pref, al[self.lev], derivative=derivative)

    def residuals(self, th: np.ndarray) -> np.ndarray:
        Sa, _ = self.level_values(th)
        return self.Kcols @ th[: self.nK] + Sa[self.lev] * self.damping(th) - self.y

    def jac(self, th: np.ndarray) -> np.ndarray:
        Sa, _ = self.level_values(th)
        D, dD = self.damping(th, derivative=True)
        A2 = (self.A ** 2)[self.lev]
        return np.concatenate([self.Kcols, (A2 * D)[:, None] * self.powU, (Sa[self.lev] * dD)[:, None] * self.powU],
                              axis=1)

    def linear_solve(self, th: np.ndarray, mk: np.ndarray) -> np.ndarray:
        """Exact least squares for every coefficient but alpha's, alpha held (eq 8 is linear in them)."""
        th = th.copy()
        D = self.damping(th)
        A2 = (self.A ** 2)[self.lev]
        Phi = np.concatenate([self.Kcols, (A2 * D)[:, None] * self.powU], axis=1)
        lin = mk.copy()
        lin[self.sl("alpha")] = False
        idx = np.flatnonzero(lin)
        th[idx] = _lin_solve(Phi[:, idx], self.y)
        return th

    def fit(self, forms: dict[str, int], start: np.ndarray) -> dict[str, Any]:
        mk = self.mask(forms)
        act = np.flatnonzero(mk)
        th = np.where(mk, start, 0.0)
        th = self.linear_solve(th, mk)

        def res(p):
            full = th.copy()
            full[act] = p
            return self.residuals(full)

        def jac(p):
            full = th.copy()
            full[act] = p
            return self.jac(full)[:, act]

        out = refine(res, th[act], None, method="lm", jac=jac, statistics=False)
        th[act] = out.x
        th = self.linear_solve(th, mk)
        r = self.residuals(th)
        return {"theta": th, "mask": mk, "ss": float(r @ r), "r": r, "nfev": out.nfev, "nit": out.nit,
                "success": out.success, "message": out.message, "history": out.history}

    def score(self, cur: dict[str, Any], extra: int, s2: float, jac: np.ndarray | None = None) -> float:
        """Score (Lagrange-multiplier) statistic for freeing coefficient ``extra`` at the fit
        ``cur``: ||P r||^2 / s2 with P the projection on the columns of the enlarged form
        (asymptotically the likelihood-ratio chi^2 with 1 degree of freedom)."""
        idx = np.append(np.flatnonzero(cur["mask"]), extra)
        J = (self.jac(cur["theta"]) if jac is None else jac)[:, idx]
        beta = _lin_solve(J, cur["r"])
        pr = J @ beta
        return float(pr @ pr) / s2


def _start(prob: _JointProblem, level_x: np.ndarray, level_se: np.ndarray, forms: dict[str, int]) -> np.ndarray:
    """Full-layout start from the per-level values (L, 6) and standard errors."""
    th = np.zeros(prob.P)
    se0 = level_se[:, 0]
    w = np.where(np.isfinite(se0) & (se0 > 0), 1.0 / np.where(se0 > 0, se0, 1.0) ** 2, 0.0)
    th[0] = np.sum(w * level_x[:, 0]) / np.sum(w) if np.sum(w) > 0 else float(np.mean(level_x[:, 0]))
    for k in FREE:
        j = PER_LEVEL.index(k)
        f = fit_amplitude_function(k, prob.A, level_x[:, j], level_se[:, j], degree=forms[k], power=POWER[k],
                                   scale=prob.scale)
        s = prob.sl(k)
        th[s.start: s.start + f.coef.size] = f.coef
    return th


def fit_joint(fits: list[LevelFit], *, max_degree: int = 2, significance: float = 0.01,
              forms: list[dict[str, int]] | None = None) -> tuple[list[dict[str, AmplitudeFunction]], list[IdentifyResult],
                                                                    list[dict[str, Any]]]:
    """Joint least-squares fit of K0 and the f_A coefficients of every cable against the
    samples of all levels in ``fits`` (see the module docstring). ``forms`` (per cable
    ``{name: degree}``) skips the degree selection. Returns per cable the functions
    ``{name: AmplitudeFunction}`` (K0 included, degree 0), an IdentifyResult of the joint
    fit (coefficients in the full layout's order of the active ones, stderr, rmse) and the
    selection log (``{"step", "name", "degree", "score", "threshold", "accepted"}`` rows)."""
    m = len(fits[0].results)
    probs = [_JointProblem([f.data[c] for f in fits], max_degree) for c in range(m)]
    lx = [np.array([f.results[c].x for f in fits]) for c in range(m)]
    lse = [np.array([f.results[c].stderr for f in fits]) for c in range(m)]
    logs: list[list[dict[str, Any]]] = [[] for _ in range(m)]
    if forms is None:
        # noise variance from the per-level fits: every parameter free at every level, the
        # richest model, of which every f_A form is a special case
        s2 = [sum(float(f.results[c].residual @ f.results[c].residual) for f in fits)
              / max(pb.N - 6 * pb.L, 1) for c, pb in enumerate(probs)]
        forms = [{k: 0 for k in FREE} for _ in range(m)]
        cur = [pb.fit(forms[c], _start(pb, lx[c], lse[c], forms[c])) for c, pb in enumerate(probs)]
        step = 0
        while True:
            cands = [(c, k) for c in range(m) for k in FREE if forms[c][k] < probs[c].D]
            if not cands:
                break
            thr = float(chi2_dist.isf(significance / len(cands), 1))
            accepted = False
            for c, pb in enumerate(probs):
                mine = [k for cc, k in cands if cc == c]
                if not mine:
                    continue
                Jc = pb.jac(cur[c]["theta"])
                stats = {k: pb.score(cur[c], pb.sl(k).start + forms[c][k] + 1, s2[c], Jc) for k in mine}
                k = max(stats, key=stats.get)
                ok = stats[k] > thr
                for kk, v in stats.items():
                    logs[c].append({"step": step, "name": kk, "degree": forms[c][kk] + 1, "score": v,
                                    "threshold": thr, "accepted": bool(ok and kk == k)})
                if ok:
                    forms[c][k] += 1
                    cur[c] = pb.fit(forms[c], cur[c]["theta"])
                    accepted = True
            step += 1
            if not accepted:
                break
    else:
        cur = [pb.fit(forms[c], _start(pb, lx[c], lse[c], forms[c])) for c, pb in enumerate(probs)]
    functions, results = [], []
    for c, pb in enumerate(probs):
        fr = cur[c]
        act = np.flatnonzero(fr["mask"])
        J = pb.jac(fr["theta"])[:, act]
        names = [pb.names[i] for i in act]
        st = jacobian_statistics(J, fr["r"], names=names, x=fr["theta"][act])
        cov = np.zeros((pb.P, pb.P))
        cov[np.ix_(act, act)] = st.covariance
        fn: dict[str, AmplitudeFunction] = {}
        for k in PER_LEVEL:
            s = pb.sl(k)
            deg = 0 if k == "K0" else forms[c][k]
            sel = slice(s.start, s.start + deg + 1)
            nxt = [row["score"] for row in logs[c] if row["name"] == k and not row["accepted"]]
            fn[k] = AmplitudeFunction(name=k, coef=fr["theta"][sel].copy(), scale=pb.scale, power=POWER[k],
                                      degree=deg, chi2=float(nxt[-1]) if nxt else float("nan"),
                                      cov=cov[sel, sel].copy())
        functions.append(fn)
        r = fr["r"]
        results.append(IdentifyResult(
            x=fr["theta"][act].copy(), fun=0.5 * fr["ss"], nfev=fr["nfev"], nit=fr["nit"], success=fr["success"],
            message=fr["message"], names=names, history=fr["history"], residual=r, stderr=st.stderr,
            covariance=st.covariance, correlation=st.correlation, cond=st.cond, cond_raw=st.cond_raw,
            sigma2=st.sigma2, redundant=st.groups, method="joint least_squares/lm over all fitted levels",
            rmse=float(np.sqrt(np.mean(r ** 2))), forms=dict(forms[c])))
    return functions, results, logs


# --------------------------------------------------------------------------------------
# the whole pipeline
# --------------------------------------------------------------------------------------


@dataclass
class AmplitudeFit:
    """Result of :func:`fit_amplitude_model`.

    ``cables``: fitted robot cable indices; ``levels[c]``: the levels found on cable column
    c; ``fits``: one :class:`LevelFit` per amplitude level used (in order of amplitude);
    ``held_out``: amplitudes [m] excluded from every fit; ``functions[c][name]``: f_A from
    the joint fit; ``joint[c]``: its IdentifyResult; ``selection[c]``: the degree-selection log;
    ``x_center`` (m_fit,) [m]; ``table_amplitudes`` [m] and ``tables[name]`` (m_fit, n) the
    table written; ``params``: ModelParams for the whole robot (cables not fitted keep the
    nominal parameters given as ``fallback``)."""

    cables: list[int]
    levels: list[list[Level]]
    fits: list[LevelFit]
    held_out: list[float]
    functions: list[dict[str, AmplitudeFunction]]
    x_center: np.ndarray
    table_amplitudes: np.ndarray
    tables: dict[str, np.ndarray]
    joint: list[IdentifyResult] = field(default_factory=list)
    selection: list[list[dict[str, Any]]] = field(default_factory=list)
    params: Any = None
    t: np.ndarray | None = None
    x: np.ndarray | None = None
    force: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)

    def level_table(self, cable_col: int) -> dict[str, np.ndarray]:
        """Per-level fitted values and standard errors of one cable column:
        ``{"A": (L,), name: (L,), name + "_se": (L,)}``."""
        out: dict[str, np.ndarray] = {"A": np.array([f.amplitude[cable_col] for f in self.fits])}
        for j, k in enumerate(PER_LEVEL):
            out[k] = np.array([f.results[cable_col].x[j] for f in self.fits])
            out[k + "_se"] = np.array([f.results[cable_col].stderr[j] for f in self.fits])
        return out


def _match_levels(levels_per_cable: list[list[Level]], rel_tol: float = 0.05) -> list[list[Level]]:
    """Group the levels of all cables by amplitude: returns a list of groups, each with
    one level per cable (only amplitudes every cable has; first occurrence per cable)."""
    ref = levels_per_cable[0]
    groups = []
    used = [set() for _ in levels_per_cable]
    for lv in ref:
        grp = [lv]
        for c in range(1, len(levels_per_cable)):
            cand = [(i, o) for i, o in enumerate(levels_per_cable[c])
                    if i not in used[c] and abs(o.amplitude - lv.amplitude) <= rel_tol * lv.amplitude]
            if not cand:
                grp = None
                break
            # the one closest in time
            i, o = min(cand, key=lambda io: abs(io[1].start - lv.start))
            used[c].add(i)
            grp.append(o)
        if grp is not None:
            groups.append(grp)
    return groups


def fit_amplitude_model(t: np.ndarray, x: np.ndarray, force: np.ndarray, *, cables: Sequence[int] | None = None,
                        hold_out: Sequence[float] = (), table_points: int = 64, rel_tol: float = 0.05,
                        min_half_cycles: int = 4, max_degree: int = 2, significance: float = 0.01, progress: Any = None,
                        max_levels_per_amplitude: int = 1) -> AmplitudeFit:
    """Identify the amplitude model of 002 Sec 3 from elongations ``x`` (N, m_fit) [m] and
    measured forces ``force`` (N, m_fit) [N] at times ``t`` (N,) [s] (columns = the robot
    cables listed in ``cables``, default 0..m_fit-1).

    ``hold_out``: amplitudes [m] whose levels are NOT used (matched within ``rel_tol``), for
    validation (never used by any fit). ``max_degree``, ``significance``: the f_A degree
    selection (module docstring). Raises ValueError when fewer than one level remains. ``progress``: optional
    callable ``(done, total, text)``. See the module docstring for the method."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    force = np.asarray(force, float)
    m = x.shape[1]
    cables = list(range(m)) if cables is None else [int(c) for c in cables]
    lv_per_cable = [segment_levels(x[:, c], t, cable=cables[c], rel_tol=rel_tol, min_half_cycles=min_half_cycles)
                    for c in range(m)]
    if any(len(lv) == 0 for lv in lv_per_cable):
        bad = [cables[c] for c in range(m) if not lv_per_cable[c]]
        raise ValueError(f"no amplitude levels (>= {min_half_cycles} equal half-cycles) found on cable(s) {bad}: "
                         "the amplitude-model fit needs a hold-sine recording (cablesvc simulate --scenario hold-sine)")
    groups = _match_levels(lv_per_cable, rel_tol)
    held = []
    use = []
    seen: dict[float, int] = {}
    for g in groups:
        A = float(np.median([lv.amplitude for lv in g]))
        if any(abs(A - h) <= rel_tol * h for h in hold_out):
            if not any(abs(A - h) <= rel_tol * h for h in held):
                held.append(A)
            continue
        key = next((k for k in seen if abs(k - A) <= rel_tol * A), None)
        if key is not None and seen[key] >= max_levels_per_amplitude:
            continue
        seen[A if key is None else key] = seen.get(A if key is None else key, 0) + 1
        use.append(g)
    if not use:
        raise ValueError("no amplitude level left to fit (all held out?)")
    use.sort(key=lambda g: np.median([lv.amplitude for lv in g]))
    # x_center: the pretension working point, median of all level centres per cable
    xc = np.array([np.median([lv.center for lv in lv_per_cable[c]]) for c in range(m)])
    fits = []
    for i, g in enumerate(use):
        if progress is not None:
            progress(i, len(use) + 1, f"level {np.median([lv.amplitude for lv in g]) * 1e3:.3g} mm")
        fits.append(fit_levels(t, x, force, g, xc))
    if progress is not None:
        progress(len(use), len(use) + 1, "joint fit of the amplitude functions")
    functions, joint, logs = fit_joint(fits, max_degree=max_degree, significance=significance)
    if progress is not None:
        progress(len(use) + 1, len(use) + 1, "done")
    A_lv = np.array([[f.amplitude[c] for f in fits] for c in range(m)])      # (m, L)
    lo, hi = float(A_lv.min()), float(A_lv.max())
    grid = np.geomspace(lo, hi, table_points) if hi > lo else np.array([lo])
    tables = {k: np.empty((m, grid.size)) for k in PER_LEVEL}
    for c in range(m):
        for k in PER_LEVEL:
            tables[k][c] = functions[c][k](grid)
        tables["S_a"][c] = np.maximum(tables["S_a"][c], 0.0)
        tables["alpha"][c] = np.clip(tables["alpha"][c], 0.0, ALPHA_MAX)
    return AmplitudeFit(cables=cables, levels=lv_per_cable, fits=fits, held_out=held, functions=functions,
                        x_center=xc, table_amplitudes=grid, tables=tables, joint=joint, selection=logs, t=t, x=x,
                        force=force)
