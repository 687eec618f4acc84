"""The amplitude-dependent cable model of paper 002 Sec 3, identified from a hold recording.

Eq 8 of 002 for one cable, with xi = x - x_center [m] and v = dxi/dt [m/s]::

    F = K0 + K1(A) xi + K2(A) xi^2 + K3(A) xi^3 + S_a(A) |v|^alpha(A) sgn(v) / (A (A w)^alpha(A) l pi)

(K_k in N/m^k, S_a the loop area [J], alpha dimensionless, A the amplitude [m], w the
angular frequency [rad/s]; the damping normalisation is the kernel's, see
:class:`cablesvc.models.AmplitudeDependent`).

What is per level (decided from the paper): Sec 3 says that for a given amplitude level
eq 8 has a five-dimensional parameter space in which K0 "determines the pretensioned
cable state with A = 0 and v = 0", leaving ``p_M = [K1 K2 K3 S_a]`` (eq 10), and eq 8 also
writes ``alpha(A)``. So per level we fit K0, K1, K2, K3, S_a and alpha (K0 too, since it
has to be estimated from the data), and then build the amplitude model
``p_M,i = f_A,i(A)`` ("just a one dimensional problem"):

* K0 is not amplitude dependent (eq 8 writes K0, not K0(A)): f_A is the
  standard-error-weighted mean of the per-level values;
* K1, K2, K3 and alpha: weighted least-squares polynomial in A, S_a: weighted polynomial
  of ln S_a in ln A (a loop area grows roughly like a power of A), weights
  ``1 / stderr^2`` from the per-level fits; degree 0, 1 or 2 (at most levels - 1): the
  lowest one that passes a chi^2 goodness-of-fit test at 1 % (a stricter level keeps
  chance rejections rare when many cables and parameters are fitted). Levels at which a
  parameter is barely identifiable (K3 at 0.1 mm, say) therefore hardly move its f_A,
  and a parameter is not given an amplitude dependence the data do not show.

The amplitude table written for the kernel samples every f_A on ``table_points``
geometrically spaced amplitudes between the smallest and the largest fitted level (the
kernel interpolates linearly between them and holds the end values outside).

Pipeline (:func:`fit_amplitude_model`):

1. elongation from inverse kinematics on the recorded pose minus the motor lengths;
2. :func:`segment_levels`: reversal points of each cable's elongation, half-cycles of equal
   amplitude and centre grouped into levels (at least ``min_half_cycles`` of them);
3. x_center per cable: the median of the level centres (the pretension working point);
4. per level, all selected cables at once: an alpha grid simulated as lanes of ONE
   amplitude-model instance gives the damping regressor for each alpha, linear least
   squares gives K0..K3, S_a for each (variable projection: eq 8 is linear in them), then
   :func:`~cablesvc.identify.local.refine` (002 eqs 12-14) polishes all six with a
   finite-difference Jacobian computed in one batched model call (lane j perturbs
   parameter j of every cable) and gives their standard errors;
5. f_A per parameter and cable, the tables, a :class:`~cablesvc.config.params.ModelParams`.

The model state of each level fit starts at the level's first reversal point as if that
reversal had just been detected (last reversal point = the start, amplitude and half
period from the segmentation), so the kernel's online amplitude/frequency estimator is
exact from the first sample of the window.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy import sparse
from scipy.stats import chi2 as chi2_dist

from cablesvc.identify.local import refine
from cablesvc.identify.result import IdentifyResult
from cablesvc.models import AmplitudeDependent

__all__ = [
    "Level", "segment_levels", "reversal_points", "LevelFit", "AmplitudeFit", "fit_levels",
    "fit_amplitude_function", "fit_amplitude_model", "PER_LEVEL", "simulate_amplitude",
]

#: the parameters fitted per amplitude level, in this order (units N, N/m, N/m^2, N/m^3, J, -)
PER_LEVEL = ("K0", "K1", "K2", "K3", "S_a", "alpha")
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


def reversal_points(x: np.ndarray, eps: float) -> np.ndarray:
    """Indices of the turning points of ``x`` (N,): a running extreme is confirmed as a
    reversal once x has moved back from it by more than ``eps`` [m] (hysteresis against
    noise and quantisation). On a flat top the last sample of the flat is the reversal,
    as in the kernel (whose direction flips at the first sample moving the other way)."""
    x = np.asarray(x, dtype=float)
    out: list[int] = []
    direction = 0
    hi = lo = ext = 0
    for i in range(1, x.size):
        xi = x[i]
        if direction == 0:
            if xi > x[hi]:
                hi = i
            if xi < x[lo]:
                lo = i
            if x[hi] - x[lo] > eps:
                direction = 1 if hi > lo else -1
                ext = hi if direction == 1 else lo
        elif direction == 1:
            if xi >= x[ext]:
                ext = i
            elif x[ext] - xi > eps:
                out.append(ext)
                direction, ext = -1, i
        else:
            if xi <= x[ext]:
                ext = i
            elif xi - x[ext] > eps:
                out.append(ext)
                direction, ext = 1, i
    return np.asarray(out, dtype=int)


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


# --------------------------------------------------------------------------------------
# per-level fits
# --------------------------------------------------------------------------------------


@dataclass
class LevelFit:
    """Fit of eq 8 at one amplitude level, all fitted cables (``cables``)."""

    amplitude: np.ndarray          # (m_fit,) [m] amplitude per cable (from the segmentation)
    levels: list[Level]            # one per fitted cable
    results: list[IdentifyResult]  # one per fitted cable: x = K0, K1, K2, K3, S_a, alpha
    x: np.ndarray                  # (T, m_fit) elongation of the window [m]
    force: np.ndarray              # (T, m_fit) measured [N]
    model: np.ndarray              # (T, m_fit) fitted model [N]
    t: np.ndarray                  # (T,) [s]

    @property
    def rmse(self) -> np.ndarray:
        return np.sqrt(np.mean((self.model - self.force) ** 2, axis=0))


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
    # each cable's simulation starts at its own first reversal: shift cables so that all
    # windows start at row 0 (pad the end with the last sample)
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
        # residuals from the level's second reversal on: before it the recorded system's
        # own amplitude estimate still holds the previous level (one half-cycle is needed)
        first = int(lv.reversals[1] - lv.start) if lv.reversals.size > 1 else 0
        mask[first:n, c] = True
    A = np.array([lv.amplitude for lv in levels])
    Th = np.array([lv.half_period for lv in levels])
    # direction of the motion after the first reversal (towards the next reversal point)
    rising = np.array([x[lv.reversals[1], c] > x[lv.reversals[0], c] if lv.reversals.size > 1
                       else X[min(1, T - 1), c] >= X[0, c] for c, lv in enumerate(levels)])
    xc = np.asarray(x_center, float)
    xi = X - xc

    rows = [np.flatnonzero(mask[:, c]) for c in range(m)]
    basis = [np.stack([np.ones(r.size), xi[r, c], xi[r, c] ** 2, xi[r, c] ** 3], axis=1) for c, r in enumerate(rows)]

    # 1) variable projection on an alpha grid: the damping regressor of each alpha is one
    #    lane of a single model run (K = 0, S_a = 1); eq 8 is linear in K0..K3 and S_a
    G = len(alpha_grid)
    vals = {k: np.zeros((G, m)) for k in PER_LEVEL}
    vals["S_a"][:] = 1.0
    vals["alpha"][:] = np.asarray(alpha_grid, float)[:, None]
    D = simulate_amplitude(X, dt, vals, xc, A, Th, rising)          # (T, G, m) [N per J]
    theta0 = np.zeros((m, 6))
    for c in range(m):
        r, y = rows[c], Fm[rows[c], c]
        best = (np.inf, None)
        for g in range(G):
            Phi = np.column_stack([basis[c], D[r, g, c]])
            sc = np.linalg.norm(Phi, axis=0)
            sc[sc == 0] = 1.0
            coef = np.linalg.lstsq(Phi / sc, y, rcond=None)[0] / sc
            if coef[4] < 0:                                   # no negative loop area
                coef[4] = 0.0
                coef[:4] = np.linalg.lstsq(basis[c], y, rcond=None)[0]
            ss = float(np.sum((Phi @ coef - y) ** 2))
            if ss < best[0]:
                best = (ss, np.append(coef, alpha_grid[g]))
        theta0[c] = best[1]

    # 2) least-squares refinement (002 eqs 12-14) of all six per cable, all cables stacked
    #    into one problem with a block-diagonal Jacobian; residuals cable after cable.
    #    Given alpha the model is linear in K0..K3 and S_a, so one run with two lanes
    #    (S_a = 1 at alpha and at alpha + h) gives the force and the whole Jacobian.
    names = list(PER_LEVEL)
    h_alpha = 1e-6
    cache: dict[str, Any] = {}

    def damping_pair(th: np.ndarray) -> np.ndarray:
        key = th[:, 5].tobytes()
        if cache.get("key") != key:
            v = {k: np.zeros((2, m)) for k in PER_LEVEL}
            v["S_a"][:] = 1.0
            v["alpha"][0] = th[:, 5]
            v["alpha"][1] = th[:, 5] + h_alpha
            cache["key"], cache["D"] = key, simulate_amplitude(X, dt, v, xc, A, Th, rising)   # (T, 2, m)
        return cache["D"]

    def model_force(th: np.ndarray) -> np.ndarray:
        D = damping_pair(th)[:, 0, :]
        return th[:, 0] + xi * (th[:, 1] + xi * (th[:, 2] + xi * th[:, 3])) + th[:, 4] * D

    def residuals(th_flat):
        F = model_force(th_flat.reshape(m, 6))
        return np.concatenate([F[rows[c], c] - Fm[rows[c], c] for c in range(m)])

    def jac(th_flat):
        th = th_flat.reshape(m, 6)
        Dd = damping_pair(th)
        blocks = []
        for c in range(m):
            r = rows[c]
            blk = np.empty((r.size, 6))
            blk[:, :4] = basis[c]                                  # dF/dK_k = xi^k
            blk[:, 4] = Dd[r, 0, c]                                # dF/dS_a
            blk[:, 5] = th[c, 4] * (Dd[r, 1, c] - Dd[r, 0, c]) / h_alpha   # dF/dalpha
            blocks.append(blk)
        return sparse.block_diag(blocks, format="csr")

    lb = np.tile([-np.inf, -np.inf, -np.inf, -np.inf, 0.0, 0.0], m)
    ub = np.tile([np.inf, np.inf, np.inf, np.inf, np.inf, ALPHA_MAX], m)
    th0 = theta0.reshape(-1).copy()
    th0[5::6] = np.clip(th0[5::6], 1e-6, ALPHA_MAX - 1e-6)
    th0[4::6] = np.maximum(th0[4::6], 1e-300)
    kw = {} if max_nfev is None else {"max_nfev": max_nfev}
    res = refine(residuals, th0, (lb, ub), method="trf", jac=jac, tr_solver="lsmr", statistics=False, **kw)
    theta = res.x.reshape(m, 6).copy()
    # exact linear least squares for K0..K3, S_a at the final alpha (the iterative trust-region
    # sub-solver leaves the weakly determined linear directions slightly short of the optimum)
    Dfin = damping_pair(theta)[:, 0, :]
    for c in range(m):
        r, y = rows[c], Fm[rows[c], c]
        Phi = np.column_stack([basis[c], Dfin[r, c]])
        sc = np.linalg.norm(Phi, axis=0)
        sc[sc == 0] = 1.0
        coef = np.linalg.lstsq(Phi / sc, y, rcond=None)[0] / sc
        if coef[4] < 0:
            coef[4] = 0.0
            coef[:4] = np.linalg.lstsq(basis[c], y, rcond=None)[0]
        theta[c, :5] = coef
    Jfin = jac(theta.reshape(-1))
    rfin = residuals(theta.reshape(-1))
    # the fitted force from the kernel model itself (not the linear shortcut)
    F_fit = simulate_amplitude(X, dt, {k: theta[:, j][None, :].copy() for j, k in enumerate(names)},
                               xc, A, Th, rising)[:, 0, :]
    # per-cable statistics from the diagonal blocks
    from cablesvc.identify.identifiability import jacobian_statistics
    results = []
    i0 = 0
    for c in range(m):
        n = rows[c].size
        Jc = Jfin[i0: i0 + n, 6 * c: 6 * c + 6].toarray()
        rc = rfin[i0: i0 + n]
        i0 += n
        st = jacobian_statistics(Jc, rc, names=names, x=theta[c])
        results.append(IdentifyResult(
            x=theta[c].copy(), fun=0.5 * float(rc @ rc), nfev=res.nfev, nit=res.nit, success=res.success,
            message=res.message, names=names, history=res.history, jac=Jc, residual=rc, stderr=st.stderr,
            covariance=st.covariance, correlation=st.correlation, cond=st.cond, cond_raw=st.cond_raw,
            sigma2=st.sigma2, redundant=st.groups, method="varpro+least_squares/trf",
            rmse=float(np.sqrt(np.mean(rc ** 2)))))
    Xw = np.where(mask, X, np.nan)
    return LevelFit(amplitude=A, levels=list(levels), results=results, x=Xw, force=np.where(mask, Fm, np.nan),
                    model=np.where(mask, F_fit, np.nan), t=np.arange(T) * dt)


# --------------------------------------------------------------------------------------
# f_A: parameters as functions of the amplitude
# --------------------------------------------------------------------------------------


@dataclass
class AmplitudeFunction:
    """``p = f_A(A)`` for one parameter of one cable: polynomial ``coef`` (highest power
    first, numpy.polyval order) in ``A`` [m] or, when ``log``, of ln p in ln A."""

    name: str
    coef: np.ndarray
    log: bool
    degree: int
    chi2: float

    def __call__(self, A: np.ndarray) -> np.ndarray:
        A = np.asarray(A, dtype=float)
        if self.log:
            return np.exp(np.polyval(self.coef, np.log(A)))
        return np.polyval(self.coef, A)


def fit_amplitude_function(name: str, A: np.ndarray, p: np.ndarray, se: np.ndarray, *,
                           max_degree: int = 2, constant: bool = False, log: bool = False,
                           significance: float = 0.01) -> AmplitudeFunction:
    """Weighted least-squares f_A (see module docstring), weights 1/se^2. Degree: the
    lowest (0, 1, ... ``max_degree``) whose weighted residual chi^2 passes the chi^2
    goodness-of-fit test at ``significance`` (levels - degree - 1 degrees of freedom).
    ``log``: fit ln p against ln A with se_ln = se / p (needs p > 0)."""
    A = np.asarray(A, float)
    p = np.asarray(p, float)
    se = np.asarray(se, float)
    if log and np.all(p > 0):
        u, y, s = np.log(A), np.log(p), se / p
    else:
        log = False
        u, y, s = A, p, se
    ok = np.isfinite(y) & np.isfinite(s) & (s > 0)
    if not np.any(ok):
        ok = np.isfinite(y)
        s = np.ones_like(y)
    u, y, s = u[ok], y[ok], s[ok]
    w = 1.0 / s
    top = 0 if constant else min(max_degree, u.size - 1)
    best = None
    for d in range(top + 1):
        V = np.vander(u, d + 1)
        coef = np.linalg.lstsq(V * w[:, None], y * w, rcond=None)[0]
        chi2 = float(np.sum(((V @ coef - y) * w) ** 2))
        best = (None, coef, d, chi2)
        dof = u.size - (d + 1)
        # the lowest degree the per-level values are statistically consistent with
        if dof <= 0 or chi2_dist.sf(chi2, dof) >= significance:
            break
    return AmplitudeFunction(name=name, coef=best[1], log=log, degree=best[2], chi2=best[3])


# --------------------------------------------------------------------------------------
# the whole pipeline
# --------------------------------------------------------------------------------------


@dataclass
class AmplitudeFit:
    """Result of :func:`fit_amplitude_model`.

    ``cables``: fitted robot cable indices; ``levels[c]``: the levels found on cable column
    c; ``fits``: one :class:`LevelFit` per amplitude level used (in order of amplitude);
    ``held_out``: amplitudes [m] excluded from the fit; ``functions[c][name]``: f_A;
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
                        hold_out: Sequence[float] = (), table_points: int = 32, rel_tol: float = 0.05,
                        min_half_cycles: int = 4, max_degree: int = 2, progress: Any = None,
                        max_levels_per_amplitude: int = 1) -> AmplitudeFit:
    """Identify the amplitude model of 002 Sec 3 from elongations ``x`` (N, m_fit) [m] and
    measured forces ``force`` (N, m_fit) [N] at times ``t`` (N,) [s] (columns = the robot
    cables listed in ``cables``, default 0..m_fit-1).

    ``hold_out``: amplitudes [m] whose levels are NOT used (matched within ``rel_tol``), for
    validation. Raises ValueError when fewer than one level remains. ``progress``: optional
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
            progress(i, len(use), f"level {np.median([lv.amplitude for lv in g]) * 1e3:.3g} mm")
        fits.append(fit_levels(t, x, force, g, xc))
    if progress is not None:
        progress(len(use), len(use), "amplitude functions")
    A_lv = np.array([[f.amplitude[c] for f in fits] for c in range(m)])      # (m, L)
    lo, hi = float(A_lv.min()), float(A_lv.max())
    grid = np.geomspace(lo, hi, table_points) if hi > lo else np.array([lo])
    functions = []
    tables = {k: np.empty((m, grid.size)) for k in PER_LEVEL}
    for c in range(m):
        fn = {}
        for j, k in enumerate(PER_LEVEL):
            p = np.array([f.results[c].x[j] for f in fits])
            se = np.array([f.results[c].stderr[j] for f in fits])
            fn[k] = fit_amplitude_function(k, A_lv[c], p, se, max_degree=max_degree, constant=(k == "K0"),
                                           log=(k == "S_a"))
            tables[k][c] = fn[k](grid)
        tables["S_a"][c] = np.maximum(tables["S_a"][c], 0.0)
        tables["alpha"][c] = np.clip(tables["alpha"][c], 0.0, ALPHA_MAX)
        functions.append(fn)
    return AmplitudeFit(cables=cables, levels=lv_per_cable, fits=fits, held_out=held, functions=functions,
                        x_center=xc, table_amplitudes=grid, tables=tables, t=t, x=x, force=force)
