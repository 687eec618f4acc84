"""What a recording can show beyond the baseline's recalibration: detection limits.

With an identified baseline, discovery first recalibrates the baseline family on the
training ticks (:mod:`.nuisance`) and names a term only for what it explains beyond that
(:mod:`.screen`). Over a given trajectory the recalibration's columns (offset, stiffness
scale, loop area, backbone curvature, amplitude dependence) can reproduce part of a term's
own force signature: over 30 s of point-to-point motion a creep drift looks much like an
offset plus a stiffness change, and sag (a softening at low tension) much like a backbone
curvature. That part of an effect is absorbed and cannot be told from a recalibration on
this recording, however good the method.

:func:`detection_limits` measures it per (term, cable), from the inputs only (no measured
force enters):

* ``free``: the largest share of the term's signature (mean square over the screen's
  test blocks, over every direction of its columns and every grid value of its
  hyper-parameters; a coefficient that cannot be negative, like a creep's, keeps its
  sign) that the recalibration's columns leave on held-out blocks, each
  block's part fitted on all the other blocks, as the screen's test does: the largest
  generalised eigenvalue of (R^T R, U^T U), U the term's columns and fixed part, R what
  the held-out fits leave of them. 1 means nothing of it can be mimicked, 0 that all of
  it can. (Held out, not in-sample: a sag concentrated at the lowest tensions is fitted
  well by a backbone curvature that sees those ticks, and poorly by one that does not);
* ``floor_rms_N`` and ``limit_rms_N``: the smallest effect RMS [N] on that cable that
  the screen could name, with a perfect baseline and with this one's model form. The
  screen asks the held-out gain g (noise variances) of a term to be at least
  ``gain_min`` and at least ``share_min`` of what the recalibrated baseline leaves beyond
  the noise, ``excess + g`` (``excess``: what it leaves on an effect-free cable, the
  baseline's model form; the pipeline takes the median over the recording's cables,
  since a cable's own excess holds its own effect). An effect of RMS E leaves about
  g = free E^2 / sigma^2 after the recalibration, so it is named only when
  E >= sigma sqrt(need / free), need = max(gain_min, share_min excess / (1 - share_min)),
  or, on a cable left no worse than the robot's typical excess, at most max(gain_min,
  gain_further, typical_gain x typical) (the screen's other route: the effect stands out above what
  the baseline leaves on the median cable;
  :meth:`~cablesvc.discover.screen.BlockScreen.required_gain`, beside the rule it inverts).
  With a perfect baseline (excess 0) that is the floor, sigma sqrt(gain_min / free):
  below it no baseline, however good, lets the screen name the term. The limit with the
  baseline's model form is an estimate for a typical cable (the affected cable's own
  model form may be smaller or larger). The block test's significance is in neither,
  and the term's most favourable shape is assumed.

An effect below its floor is not "absent": the recording cannot tell it from a
recalibration. The report says so per term (:func:`describe_limits`), so that "nothing
found" reads as what it is, and what a longer recording or one that revisits the
calibration pose would add.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from cablesvc.discover.evidence import own_part
from cablesvc.discover.screen import BlockScreen
from cablesvc.discover.select import DesignCache
from cablesvc.models.terms import Signals, Term

__all__ = ["HeldOutFit", "unmimicked_share", "detection_limits", "held_out_left", "describe_limits"]


def _basis(A: np.ndarray, with_keep: bool = False):
    """The columns of ``A`` that are finite and not all zero, each scaled to unit norm
    (and, ``with_keep``, which columns those are)."""
    A = np.asarray(A, float)
    if A.ndim == 1:
        A = A[:, None]
    keep = np.all(np.isfinite(A), axis=0) & np.any(A != 0.0, axis=0)
    A = A[:, keep]
    A = A / np.linalg.norm(A, axis=0) if A.shape[1] else A
    return (A, keep) if with_keep else A


def _block_rows(s: Signals, blocks: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The ticks in ``blocks`` (mask (n,)) and each block as indices into those ticks."""
    mask = np.zeros(s.n, bool)
    for b in blocks:
        mask[b] = True
    pos = np.cumsum(mask) - 1
    return mask, [pos[np.asarray(b, int)] for b in blocks]


def _nuisance_fit(s: Signals, nuisance: Term, c: int, mask: np.ndarray, local: list[np.ndarray],
                  cache: DesignCache) -> "HeldOutFit":
    """The held-out fit of ``nuisance``'s columns on cable ``c`` (its fixed part as one more
    column), on the masked ticks, its held columns held as the screen holds them."""
    nd = cache.get(nuisance, s, c, {})
    N = nd.X[mask]
    if nd.fixed is not None:
        N = np.column_stack([N, nd.fixed[mask]])
    return HeldOutFit(N, local, _held(nd))


def _held(design: Any) -> np.ndarray:
    """Which columns of a nuisance design (its ``X``, then its fixed part if any) the
    held-out fits hold within their support (``Design.held``)."""
    held = [n in (design.held or ()) for n in design.names][:design.X.shape[1]]
    held += [False] * (design.X.shape[1] - len(held))
    return np.array(held + ([False] if design.fixed is not None else []), bool)


#: directions drawn in the cone of the sign-constrained columns (deterministic)
_CONE_DRAWS = 4096


class HeldOutFit:
    """Least-squares fits of the columns of ``nuisance`` (n, q), each block's rows fitted
    on all the other blocks (``blocks``: index arrays into the rows), or on all rows when
    ``blocks`` is None; the per-block normal matrices are inverted once, so that many
    signatures are fitted against one nuisance cheaply (:meth:`share`)."""

    def __init__(self, nuisance: np.ndarray, blocks: Optional[list[np.ndarray]] = None,
                 held: Optional[np.ndarray] = None):
        self.rows = None if blocks is None else np.concatenate([np.asarray(b, int) for b in blocks])
        N, keep = _basis(nuisance, with_keep=True)
        self.N = N if self.rows is None else N[self.rows]
        self.Nb: Optional[list[np.ndarray]] = None
        if blocks is not None:
            self.edges = np.cumsum([0] + [len(b) for b in blocks])
            G = self.N.T @ self.N
            self.P = [np.linalg.pinv(G - self.N[a:b].T @ self.N[a:b], rcond=1e-10)
                      for a, b in zip(self.edges[:-1], self.edges[1:])]
            hold = None if held is None else np.asarray(held, bool).reshape(-1)[keep]
            if hold is not None and np.any(hold):
                self.Nb = self._held_rows(hold)

    def _held_rows(self, hold: np.ndarray) -> list[np.ndarray]:
        """Each block's rows of the nuisance as the screen's held-out fit predicts with them:
        the held columns' own part (beyond the other columns, fitted on the fold's ticks) held
        within the range it took on the fold's ticks, as
        :func:`~cablesvc.discover.evidence.loo_errors` holds them. The prediction stays linear
        in the fitted coefficients, so a block's prediction is these rows times the fold's
        coefficients. Without it a block whose amplitude no other block reached extrapolated
        the recalibration here and not in the screen, and a creep the recalibration absorbs
        (development seed 8675309, case 1: 1e-4 N^2 left held out by the screen) seemed to
        leave 0.39 N^2."""
        N = self.N
        Xo, Xh = N[:, ~hold], N[:, hold]
        Gb = [Xo[a:b].T @ Xo[a:b] for a, b in zip(self.edges[:-1], self.edges[1:])]
        gb = [Xo[a:b].T @ Xh[a:b] for a, b in zip(self.edges[:-1], self.edges[1:])]
        Gt, gt = sum(Gb), sum(gb)
        out = []
        for k, (a, b) in enumerate(zip(self.edges[:-1], self.edges[1:])):
            own = own_part(Xo, Xh, Gt - Gb[k], gt - gb[k])
            fold = np.ones(N.shape[0], bool)
            fold[a:b] = False
            lo, hi = own[fold].min(axis=0), own[fold].max(axis=0)
            rows = N[a:b].copy()
            rows[:, hold] += np.clip(own[a:b], lo, hi) - own[a:b]
            out.append(rows)
        return out

    def left(self, U: np.ndarray) -> np.ndarray:
        """What the fits leave of the columns ``U`` (rows as the nuisance's, in block order
        when held out)."""
        N = self.N
        if N.shape[1] == 0:
            return U.copy()
        if self.rows is None:
            return U - N @ np.linalg.lstsq(N, U, rcond=None)[0]
        H = N.T @ U
        R = np.empty_like(U)
        for k, (P, a, b) in enumerate(zip(self.P, self.edges[:-1], self.edges[1:])):
            Nk, Uk = N[a:b], U[a:b]
            R[a:b] = Uk - (Nk if self.Nb is None else self.Nb[k]) @ (P @ (H - Nk.T @ Uk))
        return R

    def share(self, cols: np.ndarray, nonneg: Optional[np.ndarray] = None) -> float:
        """Largest share (0..1) of the mean square of any signature ``cols @ beta`` (n, p)
        that the fits leave (see :func:`unmimicked_share`); ``nonneg`` (p,) bool: the
        coefficients that cannot be negative (a creep that only lengthens the cable), so
        only signatures a term can make count."""
        U, keep = _basis(cols, with_keep=True)
        if U.shape[1] == 0:
            return 0.0
        if self.rows is not None:
            U = U[self.rows]
        R = self.left(U)
        # whiten U's own span (an orthonormal basis of it): the largest eigenvalue of what
        # is left of that basis is the largest share left of any combination
        _, Ru = np.linalg.qr(U)
        du = np.abs(np.diag(Ru))
        ok = du > 1e-10 * max(float(du.max()), 1e-300)
        if not np.any(ok):
            return 0.0
        Rinv = np.linalg.pinv(Ru[np.ix_(ok, ok)])
        W = R[:, ok] @ Rinv
        w, V = np.linalg.eigh(W.T @ W)
        top = float(np.clip(w[-1], 0.0, 1.0))
        sign = np.zeros(U.shape[1], bool) if nonneg is None else np.asarray(nonneg, bool)[keep]
        if not np.any(sign[ok]):
            return top
        beta = Rinv @ V[:, -1]                  # the freest combination, in the columns kept
        s_ok = sign[ok]
        if np.all(beta[s_ok] >= -1e-12) or np.all(beta[s_ok] <= 1e-12):
            return top
        # the freest combination needs a sign the term cannot take: search the cone
        Uo, Ro = U[:, ok], R[:, ok]
        G, H = Uo.T @ Uo, Ro.T @ Ro
        B = np.random.default_rng(0).standard_normal((Uo.shape[1], _CONE_DRAWS))
        B = np.concatenate([B, np.eye(Uo.shape[1])], axis=1)
        B[s_ok] = np.abs(B[s_ok])
        num = np.einsum("ik,ij,jk->k", B, H, B)
        den = np.einsum("ik,ij,jk->k", B, G, B)
        good = den > 1e-12 * float(den.max())
        return float(np.clip(np.max(num[good] / den[good]), 0.0, 1.0)) if np.any(good) else 0.0


def unmimicked_share(nuisance: np.ndarray, cols: np.ndarray, blocks: Optional[list[np.ndarray]] = None) -> float:
    """Largest share (0..1) of the mean square of any signature ``cols @ beta`` that a
    least-squares fit of the columns of ``nuisance`` (n, q) leaves. ``cols`` (n, p).

    Without ``blocks`` the fit is on all rows (what a projection leaves). With ``blocks``
    (index arrays into the rows) it is held out, as the screen's test is: each block's
    part is what the fit on all the other blocks leaves there, so a shape the nuisance
    follows only by fitting each block to itself counts as free. Columns that are zero
    are ignored; 0.0 when none is left."""
    return HeldOutFit(nuisance, blocks).share(cols)


def detection_limits(s: Signals, terms: list[Term], nuisance: Term, blocks: list[np.ndarray], noise: np.ndarray,
                     excess: Any, screen: BlockScreen,
                     cache: Optional[DesignCache] = None,
                     typical: Any = None) -> dict[tuple[str, int], dict[str, float]]:
    """Per (term, cable) on which the term applies: ``free`` (share of its signature the
    recalibration ``nuisance`` cannot mimic on held-out ``blocks``, the screen's test units:
    index arrays of ticks), ``floor_rms_N`` and ``limit_rms_N`` (the smallest effect RMS
    the screen could name there with a perfect baseline and with ``excess``; inf when
    ``free`` is 0) and ``hyper`` (the grid value of its hyper-parameters where its shape
    is freest).
    ``noise`` (m,) [N]; ``excess`` [noise variances] what the recalibrated baseline leaves
    beyond the noise on an effect-free cable, per cable (m,) or one value for all;
    ``screen`` the :class:`~cablesvc.discover.screen.BlockScreen` whose rule the limits invert
    (:meth:`~cablesvc.discover.screen.BlockScreen.required_gain`); ``cache`` its
    :class:`~cablesvc.discover.select.DesignCache`, so designs are built once; ``typical``
    the robot's typical excess the screen compared with, per cable (m,) or one value for all
    [noise variances] (None: the share rule alone)."""
    ex = np.broadcast_to(np.asarray(excess, float), (s.m,))
    typ = None if typical is None else np.broadcast_to(np.asarray(typical, float), (s.m,))
    out: dict[tuple[str, int], dict[str, float]] = {}
    if not blocks:                  # too short for a single test block: nothing to say
        return out
    cache = cache if cache is not None else DesignCache()
    floor = screen.required_gain(0.0)               # a perfect baseline
    mask, local = _block_rows(s, blocks)

    for c in range(s.m):
        need = screen.required_gain(float(ex[c]), None if typ is None else float(typ[c]))
        fitter = _nuisance_fit(s, nuisance, c, mask, local, cache)
        for t in terms:
            if not t.applies(s, c):
                continue
            best, best_h = 0.0, {}
            for h in t.grid(s):
                d = cache.get(t, s, c, h, strip=True)         # without its generic (nuisance) columns
                cols = [d.X[mask, j] for j in range(d.p)]
                nonneg = [bool(lo == 0.0) for lo in np.asarray(d.lower, float)[:d.p]]
                if d.fixed is not None:
                    cols.append(d.fixed[mask])
                    nonneg.append(False)
                if cols:
                    share = fitter.share(np.column_stack(cols), np.array(nonneg))
                    if share > best:
                        best, best_h = share, dict(h)
            lim, flo = ((float(noise[c]) * math.sqrt(need / best), float(noise[c]) * math.sqrt(floor / best))
                        if best > 0 else (math.inf, math.inf))
            out[(t.name, c)] = {"free": best, "floor_rms_N": flo, "limit_rms_N": lim, "hyper": best_h,
                                "need_noise_var": need}
    return out


def held_out_left(s: Signals, nuisance: Term, blocks: list[np.ndarray], force: np.ndarray, cables: list[int],
                  cache: Optional[DesignCache] = None) -> dict[int, float]:
    """Mean square [N^2] per cable of what the recalibration ``nuisance``, fitted on all the
    other ``blocks`` (index arrays of ticks, the screen's test units), leaves of the force
    ``force[:, c]`` (N, m) [N] on each block: of a known effect's force, the most a term
    could gain held out beside the recalibration if it followed that force exactly (in
    noise variances once divided by the noise's). Unlike :func:`detection_limits` it needs
    the effect itself, so it serves a benchmark that knows its truth, not a recording."""
    if not blocks:
        return {int(c): 0.0 for c in cables}
    cache = cache if cache is not None else DesignCache()
    mask, local = _block_rows(s, blocks)
    order = np.concatenate([np.asarray(b, int) for b in blocks])
    out = {}
    for c in cables:
        R = _nuisance_fit(s, nuisance, c, mask, local, cache).left(np.asarray(force, float)[order, c][:, None])
        out[int(c)] = float(np.mean(R * R))
    return out


def _pct(share: float) -> str:
    """A share as a percentage for words: 99.6 % reads "99.6", not "100"."""
    v = 100.0 * share
    if 99.0 < v < 100.0:
        return f"{min(v, 99.9):.1f}"
    if 0.0 < v < 1.0:
        return f"{max(v, 0.1):.1f}"
    return f"{v:.0f}"


def _range(values: list[float]) -> str:
    lo, hi = min(values), max(values)
    if math.isinf(lo):
        return "inf"
    if hi <= 1.05 * lo:
        return f"{lo:.2g}"
    return f"{lo:.2g}-{'inf' if math.isinf(hi) else f'{hi:.2g}'}"


def describe_limits(limits: dict[tuple[str, int], dict[str, float]], skip: set[str] = frozenset(),
                    labels: Optional[dict[str, str]] = None) -> list[dict[str, Any]]:
    """Per term (those not in ``skip``), over its cables: the ranges of the floor and of
    the limit [N RMS] and of the share the recalibration mimics, with a plain-words
    sentence; sorted from the term the recording shows worst."""
    by: dict[str, list[tuple[int, dict[str, float]]]] = {}
    for (n, c), v in limits.items():
        if n not in skip:
            by.setdefault(n, []).append((c, v))
    rows = []
    for n, cv in by.items():
        cv.sort()
        floors = [v["floor_rms_N"] for _, v in cv]
        lims = [v["limit_rms_N"] for _, v in cv]
        mim = [1.0 - v["free"] for _, v in cv]
        cables = [c for c, _ in cv]
        p_lo, p_hi = _pct(min(mim)), _pct(max(mim))
        label = (labels or {}).get(n, n)
        if math.isinf(min(floors)):
            words = (f"{n} ({label}): cannot be told from the baseline's recalibration on this recording "
                     f"(it mimics all of its shape)")
        else:
            same = all(lim <= flo * (1 + 1e-9) for lim, flo in zip(lims, floors))
            words = (f"{n} ({label}): not told from the baseline's recalibration below {_range(floors)} N RMS "
                     + ("even with a perfect baseline (this one's model form adds nothing to it)" if same else
                        f"even with a perfect baseline, about {_range(lims)} N RMS with this one's model form")
                     + f", on cables {', '.join(map(str, cables))} (the recalibration mimics "
                     f"{p_lo if p_lo == p_hi else p_lo + '-' + p_hi} % of its shape over this recording)")
        rows.append({"term": n, "cables": cables, "floor_rms_N": {str(c): v["floor_rms_N"] for c, v in cv},
                     "limit_rms_N": {str(c): v["limit_rms_N"] for c, v in cv},
                     "mimicked": {str(c): 1.0 - v["free"] for c, v in cv}, "min_floor_rms_N": min(floors),
                     "min_limit_rms_N": min(lims), "max_limit_rms_N": max(lims), "words": words})
    rows.sort(key=lambda r: -r["min_floor_rms_N"] if math.isfinite(r["min_floor_rms_N"]) else -math.inf)
    return rows
