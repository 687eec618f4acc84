"""Local identification: least squares / Levenberg-Marquardt refinement (002 eqs 12-14),
constrained multi-start SQP (001 Ch 5) and warm-started tracking (002 Sec 3).

* :func:`refine` minimises ``1/2 sum_i r_i(p)^2`` (eq 13 of 002) with the residuals of
  eq 12, ``r_i(p) = F(p, x_i) - F_M,i`` [N], by :func:`scipy.optimize.least_squares`
  (``"trf"``: trust-region reflective, honours bounds; ``"lm"``: Levenberg-Marquardt as in
  002, unbounded). Each step solves the linearised normal equation of eq 14. At the end
  it fills the Jacobian statistics of :mod:`cablesvc.identify.identifiability`.
* :func:`multistart_sqp` is the identification of 001 Ch 5: minimise ``f(x) = e^T e``
  (eq 5.2) subject to linear inequalities ``A x <= b``, nonlinear inequalities ``c(x) <= 0``
  (e.g. the mesh-point constraints of :func:`meshpoint_constraint`) and bounds, by SLSQP
  from several Latin-hypercube starts, because the sign functions of hysteresis models
  make the problem non-convex (001 Sec 5.1).
* :func:`track` re-identifies periodically from the previous result: 002 reports that
  local optimisation works well "for long term parameter tracking or repeated adjustment
  after certain time periods" once a global method gave the first estimate.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np
from scipy.optimize import LinearConstraint, NonlinearConstraint, least_squares, minimize

from cablesvc.identify.identifiability import jacobian_statistics
from cablesvc.identify.bounds import parse_bounds
from cablesvc.identify.result import IdentifyResult

__all__ = ["refine", "multistart_sqp", "track", "meshpoint_constraint", "linear_inequality"]


def _fill_statistics(res: IdentifyResult, jac: np.ndarray, residual: np.ndarray) -> IdentifyResult:
    st = jacobian_statistics(jac, residual, names=res.get("names"), x=res["x"])
    res.update(jac=jac, residual=residual, stderr=st.stderr, covariance=st.covariance, correlation=st.correlation,
               cond=st.cond, cond_raw=st.cond_raw, sigma2=st.sigma2, redundant=st.groups)
    return res


def refine(residuals: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, bounds: Any = None, *,
           method: str = "trf", x_scale: Any = "jac", names: Sequence[str] | None = None,
           statistics: bool = True, **kw: Any) -> IdentifyResult:
    """Least-squares refinement (eqs 12-14 of 002) of ``residuals(x) -> (N,)`` from ``x0``.

    ``method``: ``"trf"`` (bounded) or ``"lm"`` (Levenberg-Marquardt, 002's choice; scipy's
    MINPACK LM does not take bounds: they are then only checked afterwards and a solution
    outside them is reported in ``message``). ``x0`` is clipped into the bounds for
    ``"trf"``. Further keywords go to :func:`scipy.optimize.least_squares` (``jac``,
    ``max_nfev``, ``ftol``, ``xtol``, ``gtol``, ``diff_step``, ``loss`` ...).

    Returns an :class:`IdentifyResult`: ``fun = 1/2 sum r^2`` (eq 13) [N^2 for force
    residuals], ``nfev`` (all residual evaluations, finite-difference ones included),
    ``nit`` (Jacobian evaluations), ``history`` (best ``fun`` after each residual
    evaluation), ``jac``, ``residual``, ``stderr``, ``covariance``, ``correlation``, ``cond``
    (equilibrated), ``cond_raw``, ``sigma2`` (residual variance), ``redundant`` (groups),
    ``active_mask`` and ``method``. ``statistics=False`` skips the statistics (for big
    stacked problems whose blocks the caller analyses itself; ``jac`` and ``residual`` are
    still returned, ``jac`` possibly sparse).
    """
    x0 = np.atleast_1d(np.asarray(x0, dtype=float)).copy()
    n = x0.size
    if names is not None and len(names) != n:
        raise ValueError(f"names: {len(names)} names for {n} parameters")
    lb, ub = parse_bounds(bounds, n)
    if method not in ("trf", "lm", "dogbox"):
        raise ValueError(f"method must be 'trf', 'lm' or 'dogbox', got {method!r}")
    best = [np.inf]
    history: list[float] = []
    count = [0]

    def wrapped(x):
        r = np.asarray(residuals(x), dtype=float).reshape(-1)
        count[0] += 1
        c = 0.5 * float(r @ r) if np.all(np.isfinite(r)) else np.inf
        best[0] = min(best[0], c)
        history.append(best[0])
        return r

    if method == "lm":
        ls = least_squares(wrapped, x0, method="lm", x_scale=x_scale, **kw)
    else:
        x0c = np.clip(x0, lb, ub)
        ls = least_squares(wrapped, x0c, bounds=(lb, ub), method=method, x_scale=x_scale, **kw)
    msg = ls.message
    if method == "lm" and bounds is not None and (np.any(ls.x < lb) or np.any(ls.x > ub)):
        out = np.flatnonzero((ls.x < lb) | (ls.x > ub)).tolist()
        msg += f" (solution outside the bounds for parameter index(es) {out}: 'lm' is unbounded)"
    res = IdentifyResult(x=ls.x, fun=float(ls.cost), nfev=count[0], nit=int(ls.njev or 0), success=bool(ls.success),
                         message=msg, names=list(names) if names is not None else None,
                         history=np.asarray(history), active_mask=ls.active_mask, method=f"least_squares/{method}",
                         status=ls.status, optimality=float(ls.optimality))
    if not statistics:
        res.update(jac=ls.jac, residual=np.asarray(ls.fun, dtype=float))
        return res
    J = ls.jac.toarray() if hasattr(ls.jac, "toarray") else np.asarray(ls.jac, dtype=float)
    return _fill_statistics(res, J, np.asarray(ls.fun, dtype=float))


def track(residuals: Callable[[np.ndarray], np.ndarray], previous: IdentifyResult, bounds: Any = None,
          **kw: Any) -> IdentifyResult:
    """Warm-started :func:`refine` for periodic re-identification (002 Sec 3, Fig 6: the
    model drifts, e.g. a 0.4 N offset after days; a local method from the last estimate
    tracks it cheaply). Starts at ``previous.x`` with ``previous.names``; by default at most
    ``10 (n + 1)`` residual evaluations (``max_nfev``) and ``"lm"`` when ``bounds`` is None,
    ``"trf"`` otherwise. Adds ``drift = x - previous.x`` and ``drift_sigma`` (the drift in
    units of the previous standard errors, NaN where those are unknown)."""
    x_prev = np.asarray(previous["x"], dtype=float)
    n = x_prev.size
    kw.setdefault("method", "lm" if bounds is None else "trf")
    kw.setdefault("names", previous.get("names"))
    kw.setdefault("max_nfev", 10 * (n + 1))
    res = refine(residuals, x_prev, bounds, **kw)
    drift = res["x"] - x_prev
    se = previous.get("stderr")
    with np.errstate(divide="ignore", invalid="ignore"):
        ds = drift / np.asarray(se, dtype=float) if se is not None else np.full(n, np.nan)
    res.update(drift=drift, drift_sigma=ds, method="track/" + res["method"])
    return res


def linear_inequality(A: np.ndarray, b: np.ndarray) -> LinearConstraint:
    """``A x <= b`` (001 Sec 5.1.2, "negative null form") as a scipy LinearConstraint."""
    A = np.atleast_2d(np.asarray(A, dtype=float))
    return LinearConstraint(A, -np.inf, np.asarray(b, dtype=float))


def meshpoint_constraint(model_at: Callable[[np.ndarray], np.ndarray], measured: np.ndarray,
                         margin: float = 0.1) -> NonlinearConstraint:
    """Mesh-point constraints of 001 Sec 5.1.2: at chosen points of the measured loop the
    model must pass within an uncertainty margin, ``|F(x_i) - F_m(x_i)| <= margin |F_m(x_i)|``.

    ``model_at(p) -> (k,)`` model output [N] at the k mesh points for parameters p;
    ``measured`` ``(k,)`` [N]. Written as 2k smooth inequalities
    ``margin |F_m| -+ (F - F_m) >= 0`` (001 advises no more mesh points than parameters)."""
    Fm = np.asarray(measured, dtype=float).reshape(-1)
    tol = margin * np.abs(Fm)

    def c(p):
        d = np.asarray(model_at(p), dtype=float).reshape(-1) - Fm
        return np.concatenate([tol - d, tol + d])

    return NonlinearConstraint(c, 0.0, np.inf)


def _violation(constraints: Sequence[Any], x: np.ndarray) -> float:
    """Largest constraint violation at x (0 when feasible)."""
    worst = 0.0
    for c in constraints:
        if isinstance(c, LinearConstraint):
            v = np.atleast_1d(c.A @ x)
            lo, hi = np.broadcast_to(c.lb, v.shape), np.broadcast_to(c.ub, v.shape)
            worst = max(worst, float(np.max(np.maximum(lo - v, 0.0), initial=0.0)),
                        float(np.max(np.maximum(v - hi, 0.0), initial=0.0)))
        elif isinstance(c, NonlinearConstraint):
            v = np.atleast_1d(np.asarray(c.fun(x), dtype=float))
            lo, hi = np.broadcast_to(c.lb, v.shape), np.broadcast_to(c.ub, v.shape)
            worst = max(worst, float(np.max(np.maximum(lo - v, 0.0), initial=0.0)),
                        float(np.max(np.maximum(v - hi, 0.0), initial=0.0)))
        else:
            v = np.atleast_1d(np.asarray(c["fun"](x, *c.get("args", ())), dtype=float))
            if c["type"] == "eq":
                worst = max(worst, float(np.max(np.abs(v), initial=0.0)))
            else:
                worst = max(worst, float(np.max(np.maximum(-v, 0.0), initial=0.0)))
    return worst


def multistart_sqp(fun: Callable[[np.ndarray], float], bounds: Any, *, constraints: Sequence[Any] = (),
                   starts: int = 8, seed: Any = None, jac: Any = None, names: Sequence[str] | None = None,
                   method: str = "SLSQP", feasibility_tol: float = 1e-6,
                   options: dict[str, Any] | None = None) -> IdentifyResult:
    """Constrained multi-start SQP of 001 Ch 5.

    Minimises the scalar ``fun(x)`` (001 eq 5.2: ``e^T e`` of the model error, [N^2] for
    force) within finite ``bounds`` subject to ``constraints``: scipy ``LinearConstraint``
    (e.g. :func:`linear_inequality`), ``NonlinearConstraint`` (e.g.
    :func:`meshpoint_constraint`) or SLSQP dicts. ``starts`` start points come from a
    Latin hypercube over the bounds (``scipy.stats.qmc.LatinHypercube``, seeded); each run
    is ``scipy.optimize.minimize(method="SLSQP")`` (or ``"trust-constr"``). ``jac`` is passed
    on (None: finite differences).

    Returns the best feasible run (largest violation <= ``feasibility_tol``; when no run is
    feasible, the least infeasible one with ``success=False``) with ``starts_result`` (one
    IdentifyResult per start, each with ``x0`` and ``violation``), ``history`` (best
    feasible objective after each start), ``violation`` and ``method``.
    """
    lb, ub = parse_bounds(bounds, finite=True)      # finite: the Latin-hypercube starts are drawn in them
    n = lb.size
    if names is not None and len(names) != n:
        raise ValueError(f"names: {len(names)} names for {n} parameters")
    if method not in ("SLSQP", "trust-constr"):
        raise ValueError(f"method must be 'SLSQP' or 'trust-constr', got {method!r}")
    from scipy.stats import qmc       # scipy.stats costs half a second: only where it is used

    sampler = qmc.LatinHypercube(d=n, seed=seed)
    X0 = qmc.scale(sampler.random(int(starts)), lb, ub) if n else np.zeros((int(starts), 0))
    cons = list(constraints)
    runs: list[IdentifyResult] = []
    history: list[float] = []
    best_feasible = np.inf
    total_nfev = 0
    total_nit = 0
    for x0 in X0:
        with np.errstate(all="ignore"):
            r = minimize(fun, x0, method=method, jac=jac, bounds=list(zip(lb, ub)), constraints=cons,
                         options=dict(options or {}))
        x = np.clip(np.asarray(r.x, dtype=float), lb, ub)
        f = float(fun(x))
        viol = _violation(cons, x)
        total_nfev += int(getattr(r, "nfev", 0))
        total_nit += int(getattr(r, "nit", 0))
        run = IdentifyResult(x=x, fun=f, nfev=int(getattr(r, "nfev", 0)), nit=int(getattr(r, "nit", 0)),
                             success=bool(r.success) and viol <= feasibility_tol, message=str(r.message),
                             names=list(names) if names is not None else None, x0=x0, violation=viol,
                             method=method)
        runs.append(run)
        if viol <= feasibility_tol and np.isfinite(f):
            best_feasible = min(best_feasible, f)
        history.append(best_feasible)
    feas = [r for r in runs if r["violation"] <= feasibility_tol and np.isfinite(r["fun"])]
    if feas:
        best = min(feas, key=lambda r: r["fun"])
        msg = f"best of {len(runs)} starts ({len(feas)} feasible): {best['message']}"
        ok = True
    else:
        best = min(runs, key=lambda r: (r["violation"], r["fun"]))
        msg = f"no feasible solution in {len(runs)} starts (least violation {best['violation']:.3g})"
        ok = False
    return IdentifyResult(x=best["x"], fun=best["fun"], nfev=total_nfev, nit=total_nit, success=ok, message=msg,
                          names=list(names) if names is not None else None, history=np.asarray(history),
                          starts_result=runs, violation=best["violation"], method=f"multistart-{method}")
