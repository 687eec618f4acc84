"""Fitting terms to a residual and choosing among them.

:func:`fit_terms` fits a set of terms to one cable's residual: the linear parameters by
bounded linear least squares on the fitting ticks, the nonlinear hyper-parameters by a
coordinate search over each term's grid (and a bounded scalar search where a term asks for
it, e.g. dead time). :class:`ForwardSelector` chooses terms by *held-out* improvement: at
each step it tries every candidate term on every cable, fits on the training blocks and
scores on the validation blocks; a term counts on a cable when it lowers the validation
MSE by at least ``min_gain`` (relative) *and* pays for its parameters,

    n_valid log(MSE_new / MSE_old) + penalty * (p_linear + p_nonlinear) log(n_train) < 0,

and the term with the largest total penalised gain over the cables is added on the cables
where it counts. A term with a generic gain column (``Term.nuisance``: pulley k0,
temperature g) must also beat that column alone with its specific ones, and the columns are
held at 0 when the nuisance's owner (``offset_gain``) is on the same cable. After each
addition, terms that no longer earn their place on a cable are dropped (backward pruning,
jointly refitted), each term is tried in place of every unselected one (with
``offset_gain`` beside it when it carried the gain) and the best penalised replacement is
kept, and the pruning runs again. A term with ``delays_input`` (dead time) makes the other
terms on its cable see the delayed elongation and baseline force. The selector is
swappable: anything with a ``select(signals,
residual, terms, train, valid)`` method returning a :class:`Selection` works.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import lsq_linear, minimize_scalar

from cablesvc.models.terms import Design, Signals, Term
from cablesvc.serial import lag_one_correlation, variance_inflation

__all__ = ["DesignCache", "Fit", "Selection", "SelectOptions", "ForwardSelector", "fit_terms", "joint_designs",
           "predict_terms", "solve_designs", "strips_nuisance"]


@dataclass
class Fit:
    """Terms fitted on one cable: ``terms`` (in order), ``hyper`` and ``params`` per term
    name, ``contrib`` per term name (N,) [N] and ``pred`` their sum (N,) [N]."""

    terms: list[Term]
    hyper: dict[str, dict[str, float]]
    params: dict[str, dict[str, float]]
    contrib: dict[str, np.ndarray]
    pred: np.ndarray
    sse_fit: float
    dropped: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: per term name, the reference values its columns took from the training ticks
    refs: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return [t.name for t in self.terms]

    @property
    def n_params(self) -> int:
        return sum(len(self.params[t.name]) + t.n_hyper for t in self.terms)


class DesignCache:
    """Designs of (term, cable, hyper-parameters, input delay) computed once per discovery
    and shared by the fitting, the screen and the held-out tests; :meth:`get` with
    ``strip`` drops a term's generic (nuisance) columns where another term owns them."""

    def __init__(self) -> None:
        self.d: dict[tuple, Design] = {}

    def get(self, term: Term, s: Signals, c: int, h: dict[str, float], strip: bool = False,
            delay: float = 0.0) -> Design:
        key = (term.design_key, c, tuple(sorted((k, round(float(v), 12)) for k, v in h.items())), round(delay, 12))
        d = self.d.get(key)
        if d is None:
            if delay > 0:
                sk = ("signals", round(delay, 12))
                sd = self.d.get(sk)
                if sd is None:
                    sd = s.delayed(delay)
                    self.d[sk] = sd
                d = term.design(sd, c, h)
            else:
                d = term.design(s, c, h)
            self.d[key] = d
        if strip and term.nuisance and not term.owns_nuisance:
            d = d.without(term.nuisance)
        return d


class _NuisanceOnly(Term):
    """The generic (nuisance) columns of ``base`` alone: the yardstick its specific columns
    must beat (a pulley or temperature term must explain more than a plain gain)."""

    def __init__(self, base: Term):
        self.base = base
        self.name = base.name + "#nuisance"

    def design(self, s, c, h):
        return self.base.design(s, c, self.base.grid(s)[0]).only(self.base.nuisance)


def strips_nuisance(terms: list[Term]) -> bool:
    """Whether one of ``terms`` owns the generic (nuisance) columns, so that the others'
    copies of them are dropped from their designs."""
    return any(t.owns_nuisance for t in terms)


def n_fitted(fit: "Fit", t: Term) -> int:
    """Parameters of ``t`` that were fitted on this cable (linear ones not held at 0, plus
    the nonlinear ones)."""
    return len(fit.params[t.name]) - len(fit.dropped.get(t.name, ())) + t.n_hyper


def _bounded_lstsq(X: np.ndarray, y: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    if X.shape[1] == 0:
        return np.zeros(0)
    sc = np.sqrt(np.sum(X * X, axis=0))
    sc[sc == 0] = 1.0
    Xs = X / sc
    # normal equations of the column-scaled problem (a few columns, thousands of ticks):
    # G = L L^T, and the bounded problem is solved on the p x p triangle (same objective
    # up to a constant), far cheaper than an SVD or BVLS on all ticks
    G = Xs.T @ Xs
    b = Xs.T @ y
    try:
        L = np.linalg.cholesky(G + np.eye(G.shape[0]) * 1e-12 * max(float(np.trace(G)), 1e-300))
        if np.min(np.abs(np.diag(L))) < 1e-7 * np.max(np.abs(np.diag(L))):
            raise np.linalg.LinAlgError("ill-conditioned")
    except np.linalg.LinAlgError:
        p, *_ = np.linalg.lstsq(Xs, y, rcond=None)
        p = p / sc
        if np.all(p >= lo - 1e-15) and np.all(p <= hi + 1e-15):
            return p
        return lsq_linear(Xs, y, bounds=(lo * sc, hi * sc), method="bvls").x / sc
    z = solve_triangular(L, b, lower=True)
    p = solve_triangular(L.T, z, lower=False) / sc
    if np.all(p >= lo - 1e-15) and np.all(p <= hi + 1e-15):
        return p
    res = lsq_linear(L.T, z, bounds=(lo * sc, hi * sc), method="bvls")
    return res.x / sc


def solve_designs(designs: list[Design], r: np.ndarray, mask: np.ndarray) -> tuple[list[np.ndarray], np.ndarray, float]:
    """Joint bounded least squares of ``designs`` to ``r`` on the ticks of ``mask``:
    (parameters per design, prediction on all ticks, SSE on the masked ticks)."""
    n = r.shape[0]
    fixed = np.zeros(n)
    for d in designs:
        if d.fixed is not None:
            fixed = fixed + d.fixed
    cols = [d.X for d in designs if d.p]
    if cols:
        X = np.hstack(cols)
        lo = np.concatenate([d.lower for d in designs if d.p])
        hi = np.concatenate([d.upper for d in designs if d.p])
        p = _bounded_lstsq(X[mask], (r - fixed)[mask], lo, hi)
        pred = fixed + X @ p
    else:
        p = np.zeros(0)
        pred = fixed
    out, i = [], 0
    for d in designs:
        out.append(p[i:i + d.p])
        i += d.p
    e = (r - pred)[mask]
    return out, pred, float(e @ e)


def _assemble(terms, hypers, designs, plist, r, mask) -> Fit:
    contrib, params, dropped = {}, {}, {}
    for t, d, p in zip(terms, designs, plist):
        c = np.zeros(r.shape[0]) if d.fixed is None else d.fixed.copy()
        if d.p:
            c = c + d.X @ p
        contrib[t.name] = c
        params[t.name] = {n: float(v) for n, v in zip(d.names, p)}
        params[t.name].update({n: 0.0 for n in d.dropped})
        if d.dropped:
            dropped[t.name] = d.dropped
    pred = np.sum(list(contrib.values()), axis=0) if contrib else np.zeros(r.shape[0])
    e = (r - pred)[mask]
    return Fit(terms=list(terms), hyper={t.name: dict(h) for t, h in zip(terms, hypers)}, params=params,
               contrib=contrib, pred=pred, sse_fit=float(e @ e), dropped=dropped,
               refs={t.name: dict(d.refs) for t, d in zip(terms, designs)})


def _delay(terms: list[Term], hs: list[dict[str, float]]) -> float:
    for t, h in zip(terms, hs):
        if t.delays_input:
            return float(h.get("tau", 0.0))
    return 0.0


def joint_designs(terms, hs, s, c, cache, strip) -> list[Design]:
    """The designs of ``terms`` with hyper-parameters ``hs`` on cable ``c`` (from ``cache``),
    each seeing the input delay of the cable's dead-time term, if any."""
    tau = _delay(terms, hs)
    return [cache.get(t, s, c, h, strip, 0.0 if t.delays_input else tau) for t, h in zip(terms, hs)]


def fit_terms(s: Signals, c: int, r: np.ndarray, terms: list[Term], mask: np.ndarray,
              hypers: Optional[list[Optional[dict[str, float]]]] = None, cache: Optional[DesignCache] = None,
              passes: int = 1) -> Fit:
    """Fit ``terms`` jointly to the residual ``r`` (N,) [N] of cable ``c`` on the ticks of
    ``mask``. ``hypers``: starting hyper-parameters per term (None: searched on the grid).
    Every term's hyper-parameters are searched on its grid with the others held, for
    ``passes`` rounds, then refined by a bounded scalar search where the term asks."""
    cache = cache or DesignCache()
    strip = strips_nuisance(terms)
    hyp: list[dict[str, float]] = []
    for j, t in enumerate(terms):
        h = None if hypers is None or j >= len(hypers) else hypers[j]
        hyp.append(dict(h) if h is not None else dict(t.grid(s)[0]))
    if not terms:
        return _assemble([], [], [], [], r, mask)

    def designs(hs: list[dict[str, float]]) -> list[Design]:
        return joint_designs(terms, hs, s, c, cache, strip)

    def sse_with(j: int, h: dict[str, float]) -> float:
        return solve_designs(designs([h if i == j else hyp[i] for i in range(len(terms))]), r, mask)[2]

    todo = [j for j, t in enumerate(terms) if hypers is None or j >= len(hypers) or hypers[j] is None]
    for _ in range(max(1, passes)):
        for j in (todo if _ == 0 else range(len(terms))):
            t = terms[j]
            g = t.grid(s)
            if len(g) > 1:
                scores = [sse_with(j, h) for h in g]
                k = int(np.argmin(scores))
                hyp[j] = dict(g[k])
                if t.refine_hyper is not None:
                    key = t.refine_hyper
                    vals = [h[key] for h in g]
                    lo = vals[k - 1] if k > 0 else t.refine_bounds[0]
                    hi = vals[k + 1] if k + 1 < len(vals) else t.refine_bounds[1]
                    if hi > lo:
                        res = minimize_scalar(lambda v: sse_with(j, {**hyp[j], key: float(v)}), bounds=(lo, hi),
                                              method="bounded", options={"xatol": 1e-4 * max(hi - lo, 1e-12)})
                        if res.fun < scores[k]:
                            hyp[j] = {**hyp[j], key: float(res.x)}
    ds = designs(hyp)
    plist, _, _ = solve_designs(ds, r, mask)
    return _assemble(terms, hyp, ds, plist, r, mask)


def predict_terms(s: Signals, c: int, fit: Fit) -> np.ndarray:
    """The fitted terms' force correction (N,) [N] on (possibly new) signals ``s``."""
    out = np.zeros(s.n)
    tau = _delay(fit.terms, [fit.hyper[t.name] for t in fit.terms])
    sd = s.delayed(tau) if tau > 0 else s
    for t in fit.terms:
        d = t.design(s if t.delays_input else sd, c, fit.hyper[t.name])
        if d.fixed is not None:
            out = out + d.fixed
        if d.p:
            out = out + d.X @ np.array([fit.params[t.name].get(n, 0.0) for n in d.names])
    return out


@dataclass
class SelectOptions:
    """``min_gain``: relative drop of the validation MSE a term must bring on a cable;
    ``penalty``: weight of the parameter penalty (p log n_train); ``max_terms``: most
    terms per cable; ``prune``: drop terms that stop earning their place; ``min_effect``:
    the least drop of the validation MSE, in units of the cable's sensor-noise variance,
    a term must bring (a term must explain at least sqrt(min_effect) x the noise RMS, so
    second-order imperfections of a large term are not taken for another effect)."""

    min_gain: float = 0.05
    min_effect: float = 0.5
    penalty: float = 1.0
    max_terms: int = 3
    prune: bool = True
    swap: bool = True
    #: count the validation and training ticks at their AR(1) effective number,
    #: n (1 - rho) / (1 + rho), rho the lag-one correlation of the cable's current
    #: validation residual (a smooth residual of an imperfect baseline carries far fewer
    #: independent samples than ticks; Newey & West 1987)
    effective_n: bool = False


@dataclass
class Step:
    """One selection step (for the report): the term added, its cables and the validation
    MSE per cable before and after [N^2], and the scores of every candidate."""

    term: str
    cables: list[int]
    mse_before: dict[int, float]
    mse_after: dict[int, float]
    candidates: dict[str, float]
    pruned: list[tuple[int, str]] = field(default_factory=list)
    swapped: list[tuple[int, str, str]] = field(default_factory=list)


@dataclass
class Selection:
    """Outcome of a selection: per cable the chosen terms (a :class:`Fit` on the training
    ticks), the steps taken, and the validation MSE of the baseline per cable."""

    fits: dict[int, Fit]
    steps: list[Step]
    baseline_valid_mse: dict[int, float]
    #: names of the base terms on every cable (the recalibration nuisance): not findings
    base: tuple[str, ...] = ()

    def named(self) -> dict[str, list[int]]:
        """Term name -> cables it was chosen on (in the order terms were added)."""
        out: dict[str, list[int]] = {}
        for st in self.steps:
            out.setdefault(st.term, [])
        for c, f in sorted(self.fits.items()):
            for n in f.names:
                if n not in self.base:
                    out.setdefault(n, []).append(c)
        return {k: sorted(set(v)) for k, v in out.items() if v}


class ForwardSelector:
    """Greedy forward selection on held-out blocks with a parameter penalty (see module)."""

    def __init__(self, options: Optional[SelectOptions] = None):
        self.options = options or SelectOptions()
        self._base: set[str] = set()

    def _eff(self, r: np.ndarray, f: Fit, valid: np.ndarray, c: int) -> float:
        """(1 - rho) / (1 + rho) of the validation residual of fit ``f`` on cable ``c``
        (:mod:`cablesvc.serial`; lag-one pairs inside the validation blocks only); 1
        without ``effective_n``."""
        if not self.options.effective_n:
            return 1.0
        e = r[:, c] - f.pred
        e = np.where(valid, e - e[valid].mean(), 0.0) if valid.any() else e
        # the validation blocks, each its own run of ticks
        edges = np.flatnonzero(np.diff(valid.astype(np.int8))) + 1
        runs = [p for p, v in zip(np.split(e, edges), np.split(valid, edges)) if v[0]]
        return 1.0 / variance_inflation(lag_one_correlation(runs, floor=0.0, cap=0.999))

    def _n(self, fit: Fit) -> int:
        """Candidate terms on a fit (the base terms do not count against ``max_terms``)."""
        return sum(1 for t in fit.terms if t.name not in self._base)

    def _accept(self, old: float, new: float, p: int, n_v: int, n_tr: int, var: float = 0.0) -> float:
        """Penalised gain (> 0 when the term counts), 0 otherwise."""
        o = self.options
        if not (old > 0 and new > 0) or new > old * (1.0 - o.min_gain) or old - new < o.min_effect * var:
            return 0.0
        crit = n_v * math.log(new / old) + o.penalty * p * math.log(max(n_tr, 2))
        return -crit if crit < 0 else 0.0

    def _specific(self, s, c, r, cur, t, new, train, valid, cache, n_v, n_tr, var) -> bool:
        """Whether ``t``'s specific columns beat its generic (nuisance) ones alone: a term
        with a plain-gain column may only win on a residual its own signature explains."""
        if not t.nuisance or strips_nuisance(cur.terms + [t]):
            return True
        nt = _NuisanceOnly(t)
        f = fit_terms(s, c, r[:, c], cur.terms + [nt], train,
                      hypers=[cur.hyper[u.name] for u in cur.terms] + [{}], cache=cache)
        mse_n = float(np.mean((r[valid, c] - f.pred[valid]) ** 2))
        p_spec = len(t.design(s, c, t.grid(s)[0]).names) - len(t.nuisance) + t.n_hyper
        return self._accept(mse_n, new, p_spec, n_v, n_tr, var) > 0

    def _mse(self, r, f, valid, c) -> float:
        return float(np.mean((r[valid, c] - f.pred[valid]) ** 2))

    def _swap(self, s, c, r, fits, mse, terms, train, valid, cache, n_v, n_tr, var) -> list[tuple[str, str]]:
        """Jointly refit cable ``c`` with each selected term replaced by each unselected
        one; take the best replacement that lowers the penalised validation error, and
        repeat (at most twice). Returns the swaps (old, new)."""
        o = self.options
        done = []
        for _ in range(2):
            cur = fits[c]
            best = None
            owner = next((t for t in terms if t.owns_nuisance and t.applies(s, c)), None)
            for u in cur.terms:
                if u.name in self._base:
                    continue
                rest = [v for v in cur.terms if v.name != u.name]
                # u is replaced by one unselected term w; when u carries the generic gain and
                # its owner is absent, also by w together with that owner (the gain u took
                # goes back to offset_gain, the rest to w)
                options = [[w] for w in terms if w.name not in cur.names and w.applies(s, c)]
                if u.nuisance and owner is not None and owner.name not in cur.names and self._n(cur) < o.max_terms:
                    options += [[owner, w[0]] for w in options if w[0].name != owner.name]
                for add in options:
                    w = add[-1]
                    f = fit_terms(s, c, r[:, c], rest + add, train,
                                  hypers=[cur.hyper[v.name] for v in rest] + [None] * len(add), cache=cache)
                    new = self._mse(r, f, valid, c)
                    if not (0 < new < mse[c]):
                        continue
                    dp = sum(n_fitted(f, a) for a in add) - n_fitted(cur, u)
                    crit = n_v * math.log(new / mse[c]) + o.penalty * dp * math.log(max(n_tr, 2))
                    if crit < 0 and (best is None or crit < best[0]):
                        base = fit_terms(s, c, r[:, c], rest + add[:-1], train,
                                         hypers=[cur.hyper[v.name] for v in rest] + [None] * (len(add) - 1), cache=cache)
                        if not self._specific(s, c, r, base, w, new, train, valid, cache, n_v, n_tr, var):
                            continue
                        best = (crit, u, "+".join(a.name for a in add), f, new)
            if best is None:
                break
            _, u, w, f, new = best
            fits[c], mse[c] = f, new
            done.append((u.name, w))
        return done

    def _prune(self, s, c, r, fits, mse, train, valid, cache, n_v, n_tr, var, keep: Optional[str] = None):
        pruned = []
        changed = True
        while changed and len(fits[c].terms) >= 1:
            changed = False
            for u in list(fits[c].terms):
                if u.name == keep or u.name in self._base:
                    continue
                rest = [v for v in fits[c].terms if v.name != u.name]
                f = fit_terms(s, c, r[:, c], rest, train, hypers=[fits[c].hyper[v.name] for v in rest], cache=cache)
                new = self._mse(r, f, valid, c)
                # u stays only when it still pays for itself against the rest (jointly refitted)
                if self._accept(new, mse[c], n_fitted(fits[c], u), n_v, n_tr, var) <= 0:
                    fits[c], mse[c] = f, new
                    pruned.append((c, u.name))
                    changed = True
                    break
        return pruned

    def select(self, s: Signals, r: np.ndarray, terms: list[Term], train: np.ndarray,
               valid: np.ndarray, noise: Optional[np.ndarray] = None,
               base: Optional[list[Term]] = None) -> Selection:
        """``noise`` (m,) [N]: the sensor-noise std per cable (None: no absolute floor).
        ``base``: terms fitted on every cable from the start and never pruned or swapped
        (the baseline's recalibration nuisance): candidates must improve on them."""
        o = self.options
        m = r.shape[1]
        var = np.zeros(m) if noise is None else np.asarray(noise, float) ** 2
        n_v, n_tr = int(valid.sum()), int(train.sum())
        cache = DesignCache()
        self._base = {t.name for t in (base or [])}
        fits = {c: fit_terms(s, c, r[:, c], list(base or []), train, cache=cache) for c in range(m)}
        mse = {c: self._mse(r, fits[c], valid, c) for c in range(m)}
        base_mse = dict(mse)
        eff = {c: self._eff(r, fits[c], valid, c) for c in range(m)}
        steps: list[Step] = []
        for _ in range(o.max_terms * m):
            best = None
            cand_scores: dict[str, float] = {}
            for t in terms:
                score, sig, new_fits = 0.0, [], {}
                for c in range(m):
                    cur = fits[c]
                    if t.name in cur.names or self._n(cur) >= o.max_terms or not t.applies(s, c):
                        continue
                    f = fit_terms(s, c, r[:, c], cur.terms + [t], train,
                                  hypers=[cur.hyper[u.name] for u in cur.terms] + [None], cache=cache,
                                  passes=2 if any(u.n_hyper for u in cur.terms) else 1)
                    new = self._mse(r, f, valid, c)
                    nv, nt = max(2, int(n_v * eff[c])), max(2, int(n_tr * eff[c]))
                    g = self._accept(mse[c], new, n_fitted(f, t), nv, nt, var[c])
                    if g > 0 and self._specific(s, c, r, cur, t, new, train, valid, cache, nv, nt, var[c]):
                        score += g
                        sig.append(c)
                        new_fits[c] = (f, new)
                cand_scores[t.name] = score
                if score > 0 and (best is None or score > best[0]):
                    best = (score, t, sig, new_fits)
            if best is None:
                break
            _, t, sig, new_fits = best
            step = Step(term=t.name, cables=list(sig), mse_before={c: mse[c] for c in sig},
                        mse_after={c: new_fits[c][1] for c in sig}, candidates=cand_scores)
            for c in sig:
                fits[c], mse[c] = new_fits[c]
            if o.prune:
                for c in sig:
                    nv, nt = max(2, int(n_v * eff[c])), max(2, int(n_tr * eff[c]))
                    step.pruned += self._prune(s, c, r, fits, mse, train, valid, cache, nv, nt, var[c], keep=t.name)
                    if o.swap:
                        for a, b in self._swap(s, c, r, fits, mse, terms, train, valid, cache, nv, nt, var[c]):
                            step.swapped.append((c, a, b))
                        step.pruned += self._prune(s, c, r, fits, mse, train, valid, cache, nv, nt, var[c])
            for c in sig:
                eff[c] = self._eff(r, fits[c], valid, c)
            steps.append(step)
        return Selection(fits=fits, steps=steps, baseline_valid_mse=base_mse, base=tuple(sorted(self._base)))
