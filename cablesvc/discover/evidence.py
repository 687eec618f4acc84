"""Honest statistics for discovery: the block, not the tick, is the unit of a test.

A residual left by an imperfect baseline is smooth (lag-one correlation > 0.99 at
100 Hz): n ticks carry about n (1 - rho) / (1 + rho) independent samples, so tests that
count ticks are far too lenient. Here every test is leave-one-block-out over the blocks
that fitting may use (training + validation, never the test blocks):

* the two models (with and without the term under test, all hyper-parameters held at the
  values selection found) are fitted on all blocks but one and scored on the held-out one;
* the per-block gain g_k = mean over block k of (e_0^2 - e_1^2) / sigma^2 (sigma the
  sensor-noise floor) is the unit (Kunsch, Ann. Statist. 17, 1989: blocks as the unit);
  the K gains are tested by a one-sided Wilcoxon signed-rank test (a term explains much
  in some blocks and little in others, so a t-test on so few, so unequal gains is weak);
* p-values of all (term, cable) tries are corrected by Holm's step-down procedure.
"""

from __future__ import annotations

import functools
import math
from typing import Optional

import numpy as np
from scipy import special

from cablesvc.discover.select import DesignCache, joint_designs, solve_designs, strips_nuisance
from cablesvc.models.terms import Signals, Term

__all__ = ["block_ids", "loo_errors", "block_gain_test", "excess_test", "holm", "signed_rank_test",
           "t_test"]


def block_ids(t: np.ndarray, block: float, mask: np.ndarray) -> list[np.ndarray]:
    """Index arrays of the blocks of ``block`` s whose ticks lie in ``mask`` (N,) bool."""
    k = np.floor((t - t[0]) / block).astype(int)
    out = []
    for b in np.unique(k[mask]):
        idx = np.flatnonzero(mask & (k == b))
        if idx.size >= 10:
            out.append(idx)
    return out


def loo_errors(s: Signals, c: int, r: np.ndarray, terms: list[Term], hypers: list[dict[str, float]],
               blocks: list[np.ndarray], cache: Optional[DesignCache] = None) -> list[np.ndarray]:
    """Held-out errors r - pred on each block, the terms' linear parameters fitted on all
    the other blocks (hyper-parameters held).

    The columns a design holds within their support (``Design.held``: the recalibration's
    amplitude discrepancy) are held, on the block left out, within the range they took on
    the ticks of that fold's fit, as the fitted model holds them within its training
    range: the error estimated is the one of the procedure that is run. Without that, a
    block whose reversal amplitude no other block reaches extrapolated the correction
    without limit (development seed 60606, a control: 388 noise variances on one block
    against 1.3 with no recalibration at all), and any term that happened to tame it
    seemed to explain most of what the recalibration leaves."""
    cache = cache or DesignCache()
    ds = joint_designs(terms, hypers, s, c, cache, strips_nuisance(terms))
    held = _Held(ds, blocks) if any(d.p and d.held for d in ds) else None
    allb = np.zeros(s.n, bool)
    for b in blocks:
        allb[b] = True
    out = []
    for i, b in enumerate(blocks):
        mask = allb.copy()
        mask[b] = False
        plist, pred, _ = solve_designs(ds, r, mask)
        pb = pred[b]
        if held is not None:
            pb = pb + held.change(plist, i, mask, b)
        out.append(r[b] - pb)
    return out


def own_part(Xo: np.ndarray, Xh: np.ndarray, G: np.ndarray, g: np.ndarray) -> np.ndarray:
    """The part of the held columns ``Xh`` (n, h) that the other columns ``Xo`` (n, q)
    cannot express, fitted on a fold's ticks: ``G`` = Xo^T Xo and ``g`` = Xo^T Xh over them
    (``G`` is changed). The columns are scaled (unit RMS or norm): a ridge of 1e-9 of the
    mean diagonal only settles the exact collinearities (the span is what matters, not the
    split). What :class:`_Held` and the detection limits' held-out fit hold."""
    if not Xo.shape[1]:
        return Xh
    diag = np.diag_indices(Xo.shape[1])
    G[diag] += 1e-9 * float(np.mean(G[diag])) + 1e-300
    return Xh - Xo @ np.linalg.solve(G, g)


class _Held:
    """The held columns of ``designs`` (``Design.held``) on each fold of a
    leave-one-block-out fit: :meth:`change` is the change of the prediction on the block
    left out when each held column is held within the range its own part took on the
    fold's fitted ticks. A held column's own part is what the other columns cannot express
    (its least-squares residual on them, fitted ticks): the recalibration's
    (A - mean A) xi is, where A does not vary, -mean A xi, which its backbone columns
    express exactly; holding the raw column there would break that cancellation instead
    of holding the amplitude's own correction. The other columns are those of the design
    that holds the column (the recalibration's own), not those of a term tested beside it:
    a term's column that lies outside the fold's range on the block left out (time, on the
    first block) moved the held part there, and the hold, not the term, decided the test
    (a true creep on development seed 271828 lost 158 noise variances on its first block
    that way). The projections use per-block Gram matrices, so a fold costs one small
    solve, not a least squares over the recording."""

    def __init__(self, designs: list, blocks: list[np.ndarray]):
        self.cols = [(k, j) for k, d in enumerate(designs) if d.p for j, n in enumerate(d.names) if n in d.held]
        hold = set(self.cols)
        own = {k for k, _j in self.cols}
        other = [d.X[:, [j for j in range(d.p) if (k, j) not in hold]] for k, d in enumerate(designs)
                 if d.p and k in own]
        Xo = np.hstack(other)
        scale = np.sqrt(np.mean(Xo * Xo, axis=0))
        self.Xo = Xo / np.where(scale > 0, scale, 1.0)
        self.Xh = np.column_stack([designs[k].X[:, j] for k, j in self.cols])
        self.G_b = [self.Xo[b].T @ self.Xo[b] for b in blocks]
        self.g_b = [self.Xo[b].T @ self.Xh[b] for b in blocks]
        self.G, self.g = sum(self.G_b), sum(self.g_b)

    def change(self, plist: list[np.ndarray], i: int, mask: np.ndarray, b: np.ndarray) -> np.ndarray:
        own = own_part(self.Xo, self.Xh, self.G - self.G_b[i], self.g - self.g_b[i])
        lo, hi = own[mask].min(axis=0), own[mask].max(axis=0)
        ob = own[b]
        coef = np.array([plist[k][j] for k, j in self.cols])
        return (np.clip(ob, lo, hi) - ob) @ coef


@functools.lru_cache(maxsize=64)
def _signed_rank_counts(n: int) -> np.ndarray:
    """Number of subsets of the ranks 1..n with each rank sum 0..n(n+1)/2: the exact null
    distribution of the signed-rank statistic W+ (times 2^n); cached per n (every test of
    one discovery has the same number of blocks), read-only."""
    c = np.zeros(n * (n + 1) // 2 + 1)
    c[0] = 1.0
    for k in range(1, n + 1):
        c[k:] = c[k:] + c[:-k].copy()
    c.flags.writeable = False
    return c


def signed_rank_test(g: np.ndarray) -> tuple[float, float]:
    """One-sided Wilcoxon signed-rank test of a location of g > 0 (block gains of very
    unequal size: a term may explain much in some blocks and little in others): (W, p).
    Exact for up to 50 blocks without ties or zeros (the null distribution of W+ counted
    here; the same p as ``scipy.stats.wilcoxon(g, alternative="greater")``, without the
    half second that importing scipy.stats costs every fleet worker); otherwise scipy's."""
    g = np.asarray(g, float)
    if g.size < 5 or not np.any(g != 0):
        return 0.0, 1.0
    a = np.abs(g)
    if g.size <= 50 and np.all(g != 0) and np.unique(a).size == a.size:
        ranks = np.empty(a.size)
        ranks[np.argsort(a)] = np.arange(1, a.size + 1)
        w = float(ranks[g > 0].sum())
        c = _signed_rank_counts(a.size)
        p = float(c[int(round(w)):].sum() / c.sum())
        return w, min(1.0, p)
    from scipy import stats
    res = stats.wilcoxon(g, alternative="greater")
    return float(res.statistic), float(res.pvalue)


def t_test(g: np.ndarray) -> tuple[float, float]:
    """One-sided t-test of mean(g) > 0: (t, p)."""
    k = g.size
    if k < 3:
        return 0.0, 1.0
    sd = float(np.std(g, ddof=1))
    mu = float(np.mean(g))
    if sd <= 0:
        return (math.inf, 0.0) if mu > 0 else (0.0, 1.0)
    t = mu / (sd / math.sqrt(k))
    return t, float(special.stdtr(k - 1, -t))     # Student's t survival function


def block_gain_test(e0: list[np.ndarray], e1: list[np.ndarray], noise: float) -> dict[str, float]:
    """Per-block gains g_k = mean(e0^2 - e1^2) / noise^2 and their one-sided Wilcoxon
    signed-rank test: {"gain": mean g (noise variances), "t" (the statistic), "p",
    "blocks", "positive": share of g_k > 0, "before": mean e0^2 (noise variances),
    "share": gain / before, the share of the held-out residual variance explained,
    "excess_share": gain / (before - 1), the share of what exceeds the noise variance
    (inf when nothing does)}."""
    var = max(noise, 1e-12) ** 2
    g = np.array([float(np.mean(a * a - b * b)) / var for a, b in zip(e0, e1)])
    b0 = np.array([float(np.mean(a * a)) / var for a in e0])
    t, p = signed_rank_test(g)
    gain = float(np.mean(g)) if g.size else 0.0
    before = float(np.mean(b0)) if b0.size else 0.0
    return {"gain": gain, "t": t, "p": p, "blocks": int(g.size),
            "positive": float(np.mean(g > 0)) if g.size else 0.0, "before": before,
            "share": gain / before if before > 0 else 0.0,
            "excess_share": gain / (before - 1.0) if before > 1.0 else math.inf}


def excess_test(e: list[np.ndarray], noise: float, floor: float) -> dict[str, float]:
    """Whether the held-out residual ``e`` (per block) exceeds the noise variance by more
    than ``floor`` noise variances: per-block excess x_k = mean(e^2) / noise^2 - 1 - floor,
    one-sided Wilcoxon signed-rank test. Returns {"excess": mean(e^2)/noise^2 - 1, "t", "p"}."""
    var = max(noise, 1e-12) ** 2
    x = np.array([float(np.mean(a * a)) / var - 1.0 for a in e])
    t, p = signed_rank_test(x - floor)
    return {"excess": float(np.mean(x)) if x.size else 0.0, "t": t, "p": p, "blocks": int(x.size)}


def holm(p: dict, tries: int) -> dict:
    """Holm step-down adjusted p-values of the hypotheses ``p`` (key -> p) out of
    ``tries`` tested in all (the untested ones count as p = 1)."""
    tries = max(int(tries), len(p), 1)
    order = sorted(p, key=lambda k: p[k])
    out, run = {}, 0.0
    for i, k in enumerate(order):
        run = max(run, min(1.0, (tries - i) * p[k]))
        out[k] = run
    return out
