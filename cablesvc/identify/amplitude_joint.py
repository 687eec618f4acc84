"""The amplitude functions f_A of 002 Sec 3 (step 5 of
:func:`cablesvc.identify.amplitude_fit.fit_amplitude_model`): every parameter of eq 8 as a
function of the amplitude, fitted jointly over all fitted levels of a cable (one
least-squares problem per cable, LM of 002 eq 14, analytic Jacobian), the polynomial
degrees chosen by forward selection with a Bonferroni-divided score test (see the
pipeline's docstring for the forms and the selection rule). Units: SI.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import chi2 as chi2_dist

from cablesvc.identify.identifiability import jacobian_statistics
from cablesvc.identify.local import refine
from cablesvc.identify.result import IdentifyResult
from cablesvc.serial import lag_one_correlation, variance_inflation
from cablesvc.identify.amplitude_levels import ALPHA_MAX, FREE, PER_LEVEL, LevelData, LevelFit, damping_regressor, lin_solve

__all__ = ["AmplitudeFunction", "fit_amplitude_function", "POWER", "OPTIONAL", "fit_joint", "residual_inflation"]


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
    if degree < 0:                                   # absent: the parameter is held at 0
        return AmplitudeFunction(name=name, coef=np.zeros(0), scale=scale, power=power, degree=-1)
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

#: the backbone's curvature coefficients start absent (degree -1, held at 0) and enter
#: the model only through the same score test as any further degree. A calibration of
#: +-1.5 mm hardly shows them (K3 xi^3 of a realistic K3 ~ 1e6 N/m^3 is a few mN there):
#: fitted anyway, K3 came out at -1e7 to -1e8 N/m^3 with standard errors of the same size
#: or larger, and the baseline extrapolated K3 xi^3 to hundreds of newtons at the 20 mm of
#: a trajectory. A coefficient the data do not show is not extrapolated
OPTIONAL = ("K2", "K3")


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
        th[idx] = lin_solve(Phi[:, idx], self.y)
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
        beta = lin_solve(J, cur["r"])
        pr = J @ beta
        return float(pr @ pr) / s2


def residual_inflation(residuals: list[np.ndarray]) -> float:
    """Variance inflation (1 + rho) / (1 - rho) of a residual's mean-like statistics under
    lag-one serial correlation rho (AR(1); Bartlett 1946, Bayley & Hammersley 1946: n
    correlated samples carry about n (1 - rho) / (1 + rho) independent ones), rho pooled
    over the pieces ``residuals`` (each in time order) and floored at 0, so white
    residuals keep the plain test."""
    return variance_inflation(lag_one_correlation(residuals, floor=0.0, cap=0.99))


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
        # ... times the variance inflation of that residual's serial correlation: where the
        # richest model still misses the loop's shape (another hysteresis law than eq 8),
        # its residual is smooth, not sensor noise, and a score test counting every sample
        # as independent takes any extra column for a significant one
        s2 = [v * residual_inflation([f.results[c].residual for f in fits]) for c, v in enumerate(s2)]
        forms = [{k: (-1 if k in OPTIONAL else 0) for k in FREE} for _ in range(m)]
        # a cable whose levels could none of them tell the damping's rate law (a triangle
        # calibration: |v| constant within each level) keeps alpha at 0, a rate-independent
        # loop: freed here, the joint fit took alpha(A) to its bound 3 at the small
        # amplitudes, where nothing holds it, and the identified model's damping ran to
        # thousands of newtons when the cable next moved after a long hold
        no_alpha = [bool(all(c < f.alpha_fixed.size and f.alpha_fixed[c] for f in fits)) for c in range(m)]
        for c in range(m):
            if no_alpha[c]:
                forms[c]["alpha"] = -1
        cur = [pb.fit(forms[c], _start(pb, lx[c], lse[c], forms[c])) for c, pb in enumerate(probs)]
        step = 0
        while True:
            cands = [(c, k) for c in range(m) for k in FREE if forms[c][k] < probs[c].D
                     and not (k == "alpha" and no_alpha[c])]
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
