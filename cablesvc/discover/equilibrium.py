"""Sensor or cable? The platform's equilibrium tells a force-sensor error from a cable-model one.

The measured forces y of a platform satisfy the structure equation (002 eq 2)

    A^T f + w = M a           [N; N m]

with A^T the structure matrix at the recorded pose, w the gravity wrench of the robot
file's platform (mass m, centre of gravity c) and M a the inertial wrench [m a; (R c) x m a]
(slow motion: small). A stiffness or pretension error of the *cable model* changes no
measured force, so the measured forces still balance. A *sensor* offset o_i and gain g_i on
cable i (y_i = (1 + g_i) f_i + o_i) leaves the wrench residual

    W = A^T y + w - M a = A_i^T (o_i + g_i f_i)

along cable i's column of A^T. :func:`equilibrium_check` therefore

1. whitens W per tick with the covariance the sensor noise alone gives,
   S = A^T diag(sigma^2) A (sigma the per-cable noise floor), so a balanced recording has
   a mean whitened square of 1 per wrench row;
2. fits the free scales of the gravity and inertial wrenches (an unknown payload, an
   approximate mass);
3. offers, for every cable, explanations of a residual along its column: the sensor
   columns A_i^T and A_i^T y_i (offset and gain), or a dead time of its force channel. A
   reading that lags the present force by tau, y_i(t) = f_i(t - tau), leaves
   W = A_i^T (y_i(t) - y_i(t + tau)); putting the lag back (the reading tau later, smoothed,
   stands for the present force) has no free coefficient, tau is searched per cable. The
   explanation that explains most among those a leave-one-block-out test on per-block
   gains accepts (the block is the unit; Holm over every (cable, explanation) pair) is
   added, until none is accepted. Where none is, a third explanation is offered: both at
   once on one cable (one sensor chain can have an offset and a lag; then neither alone
   balances the platform: on a bench case of seed 90210 with lags on cables 0, 6, 7 and
   offsets on 0, 1, 4 the search stopped with the forces still 37 x the noise variance per
   row, and with it they balance to 1.2);
   it is kept only where each part earns its place on held-out blocks, else the part that
   does (or nothing). A lag is evidence in the dead time's own variable that no
   error of the cable model can produce: a cable law, however wrong, changes no measured
   force, and the platform balances the forces it reads;
4. places the sensor errors as a set: every set of up to ``SET_MAX`` cables is scored on
   held-out blocks beside the lags found, and the largest best set whose every cable earns
   its place beside the others is kept, unless a smaller one balances the platform as well
   (offsets on two or three cables can look like one on another cable, which a search
   adding one cable at a time takes first);
5. for each sensor error found, runs the selection again without that cable's sensor
   columns: with more cables than wrench rows, errors on other cables may balance the
   platform as well, and then the check says which (it cannot place the error);
6. says whether equilibrium holds on the recording at all: when the whitened residual
   left is still well above 1, the measured forces do not balance for reasons no sensor
   column explains (dynamics, geometry), and a sensor error cannot be told from a cable's
   pretension or stiffness.
"""

from __future__ import annotations

import itertools
import math
from typing import Any, Optional

import numpy as np
from scipy.optimize import minimize_scalar

from cablesvc.discover.evidence import holm, signed_rank_test, t_test
from cablesvc.kinematics import PLANAR_WRENCH_ROWS, inverse_kinematics, platform_wrench, structure_matrix

__all__ = ["equilibrium_check"]

#: sensor errors are placed as a set: every set of up to this many cables is scored ...
SET_MAX = 4
#: ... within this many held-out fits (fewer cables where a robot has many)
SET_EVALS = 1200
#: relative cut of the singular values in the sets' held-out fits (columns scaled to unit norm)
PINV_RTOL = 1e-12
#: whitened mean square per wrench row under which the recording's forces count as balanced
HOLDS = 1.5
#: corrected p-value under which a cable's sensor columns count
ALPHA = 0.01
#: ... and the least they must explain: mean held-out gain per wrench row, in whitened
#: noise variances (a consistent but negligible gain, a few mN, is not a sensor error)
MIN_GAIN = 0.1


#: the explanations of a wrench residual along one cable's column: its sensor's offset and
#: gain, a lag of its force channel, or both at once (one sensor chain can have both; then
#: neither alone balances the platform, and each alone failed its block test on
#: development cases with a 0.06-0.13 s lag and a 0.3-0.8 N offset on one cable)
KINDS = ("sensor", "delay", "sensor+delay")
SENSOR = ("sensor", "sensor+delay")
LAG = ("delay", "sensor+delay")


def _own(key: tuple[int, str]) -> list[tuple[int, str]]:
    """The sensor columns a lag is searched beside when the key is both at once."""
    return [(key[0], "sensor")] if key[1] == "sensor+delay" else []


def _clashes(key: tuple[int, str], chosen: list[tuple[int, str]]) -> bool:
    """Both at once is not offered for a cable with one of them chosen, nor either alone
    beside it."""
    kinds = {k for i, k in chosen if i == key[0]}
    return bool(kinds) and (key[1] == "sensor+delay" or "sensor+delay" in kinds)


def _whiten(AT: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Per tick L^-1 with L L^T = A^T diag(sigma^2) A (N, r, r)."""
    S = np.einsum("nim,m,njm->nij", AT, sigma ** 2, AT)
    r = S.shape[1]
    S = S + np.eye(r)[None] * 1e-12 * np.trace(S, axis1=1, axis2=2)[:, None, None]
    L = np.linalg.cholesky(S)
    return np.linalg.inv(L)


def _blocks(t: np.ndarray, block: float) -> list[np.ndarray]:
    k = np.floor((t - t[0]) / block).astype(int)
    return [np.flatnonzero(k == b) for b in np.unique(k) if np.sum(k == b) >= 10]


#: window of the local quadratic fit that smooths the measured force before it is shifted [s]
SMOOTH_S = 0.15
#: the lags tried for a force channel [s] (wider than the dead-time term's 0-0.5 s: a lag
#: the term cannot follow is still reported, with its size)
DELAYS_S = (0.01, 0.02, 0.03, 0.05, 0.07, 0.1, 0.14, 0.2, 0.28, 0.4, 0.56, 0.8, 1.1)


def _runs(t: np.ndarray) -> list[slice]:
    """The stretches of ``t`` without a gap (a step over 1.5 x the median step): a streamed
    discovery keeps groups of ticks with gaps between them."""
    if t.size < 2:
        return [slice(0, t.size)]
    d = np.diff(t)
    cut = np.flatnonzero(d > 1.5 * float(np.median(d))) + 1
    edges = [0, *cut.tolist(), t.size]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]


def smoothed_force(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The measured forces (N, m) [N] smoothed by a local quadratic fit over
    :data:`SMOOTH_S` (Savitzky-Golay) within each stretch without a gap, which keeps their
    shape and takes off most of the sensor noise."""
    from scipy.signal import savgol_filter
    out = np.array(y, float)
    if y.shape[0] < 2:
        return out
    dt = float(np.median(np.diff(t)))
    w = int(round(SMOOTH_S / max(dt, 1e-9))) | 1
    for run in _runs(t):
        if 5 <= w < run.stop - run.start:
            out[run] = savgol_filter(y[run], w, 2, axis=0)
    return out


def _solve(G: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Least-squares coefficients from the normal equations G beta = h (p, p), (p,), with
    the columns scaled to unit norm first (the weight, inertia and sensor columns differ
    by orders of magnitude)."""
    sc = np.sqrt(np.clip(np.diag(G), 0.0, None))
    sc[sc == 0] = 1.0
    beta, *_ = np.linalg.lstsq(G / np.outer(sc, sc), h / sc, rcond=None)
    return beta / sc


def _loo(Xw: np.ndarray, Ww: np.ndarray, blocks: list[np.ndarray]) -> list[np.ndarray]:
    """Held-out whitened squared residual per tick, per block (N ticks x r rows stacked):
    the columns fitted on every tick outside the block (normal equations, the block's own
    share subtracted from the total)."""
    N, r, p = Xw.shape
    if not p:
        return [np.sum(Ww[b] * Ww[b], axis=1) for b in blocks]
    G = np.einsum("nrp,nrq->npq", Xw, Xw)
    h = np.einsum("nrp,nr->np", Xw, Ww)
    Gt, ht = G.sum(axis=0), h.sum(axis=0)
    out = []
    for b in blocks:
        beta = _solve(Gt - G[b].sum(axis=0), ht - h[b].sum(axis=0))
        e = Ww[b] - Xw[b] @ beta
        out.append(np.sum(e * e, axis=1))
    return out


def equilibrium_check(geom: Any, t: np.ndarray, position: np.ndarray, orientation: np.ndarray, y: np.ndarray,
                      noise: np.ndarray, block: float = 2.5) -> dict[str, Any]:
    """Wrench balance of the measured forces ``y`` (N, m) [N] at the recorded pose (see the
    module docstring). ``noise`` (m,) [N] sensor-noise std per cable. Returns a JSON-able
    dict: ``ratio_raw`` / ``ratio`` whitened mean square per row before / after the fitted
    wrench and sensor columns, ``holds``, ``sensor`` {cable: {"o" [N], "g" [-], "p"}}
    (cables whose sensor columns explain the residual, Holm-corrected p; ``or_cables``: other
    cables whose sensor errors balance the platform as well on held-out blocks, empty where
    the balance places the error), ``delay``
    {cable: {"tau_s" [s], "p"}} (cables whose force channel lags), ``tried`` (the number of
    (cable, explanation) pairs the Holm correction counts)."""
    ik = inverse_kinematics(geom, np.asarray(position, float), np.asarray(orientation, float))
    AT = structure_matrix(ik.unit, ik.anchor_world)
    wg = platform_wrench(geom, ik.rotation)
    rows = list(PLANAR_WRENCH_ROWS) if getattr(geom, "planar", False) else list(range(6))
    AT, wg = AT[:, rows, :], wg[:, rows]
    N, r, m = AT.shape
    W = np.einsum("nim,nm->ni", AT, y) + wg
    acc = np.gradient(np.gradient(np.asarray(position, float), t, axis=0), t, axis=0)
    ma = geom.mass * acc
    Rc = np.einsum("nij,j->ni", ik.rotation, np.asarray(geom.center_of_gravity, float))
    inert = np.concatenate([ma, np.cross(Rc, ma)], axis=1)[:, rows]
    Li = _whiten(AT, np.maximum(np.asarray(noise, float), 1e-6))
    Ww = np.einsum("nij,nj->ni", Li, W)

    def wcol(col: np.ndarray) -> np.ndarray:          # (N, r) -> whitened (N, r, 1)
        return np.einsum("nij,nj->ni", Li, col)[:, :, None]

    base = [wcol(wg), wcol(inert)]
    ys = smoothed_force(t, y)

    LA = np.einsum("nij,njm->nim", Li, AT)         # whitened columns of A^T (N, r, m)

    runs = _runs(t)

    def ahead(i: int, tau: float) -> np.ndarray:
        # what putting back a lag of tau on cable i adds to the wrench residual (whitened):
        # its reading tau later stands for the present force, A_i^T (y_i(t + tau) - y_i(t))
        # (within each stretch without a gap; its last reading stands for what follows)
        later = np.empty(t.size)
        for run in runs:
            later[run] = np.interp(t[run] + tau, t[run], ys[run, i])
        return LA[:, :, i] * (later - ys[:, i])[:, None]

    # per cable, two explanations of a wrench residual along its column: a sensor offset
    # and gain (two linear columns), or a lag of its force channel (no free coefficient: the
    # lag tau is its one parameter, searched on all ticks)
    sensor = {i: [wcol(AT[:, :, i]), wcol(AT[:, :, i] * y[:, i:i + 1])] for i in range(m)}
    cands = [(i, kind) for i in range(m) for kind in KINDS]
    blocks = _blocks(t, block)
    ratio_raw = float(np.mean(np.sum(Ww * Ww, axis=1)) / r)
    tries = len(cands)

    def design(keys: list[tuple[int, str]], taus: dict[int, float]) -> tuple[np.ndarray, np.ndarray]:
        X = np.concatenate(base + [c for i, kind in keys if kind in SENSOR for c in sensor[i]], axis=2)
        target = Ww.copy()
        for i, kind in keys:
            if kind in LAG:
                target += ahead(i, taus[i])
        return X, target

    def fit_lag(i: int, keys: list[tuple[int, str]], taus: dict[int, float]) -> float:
        # the lag of cable i that balances best beside ``keys`` (least squares on all ticks):
        # grid, then a bounded search between the grid's neighbours of the best point. The
        # columns do not depend on the lag, only the target does
        X, target = design(keys, taus)
        G = np.einsum("nrp,nrq->pq", X, X)

        def sse(tau: float) -> float:
            T = target + ahead(i, tau)
            e = T - X @ _solve(G, np.einsum("nrp,nr->p", X, T))
            return float(np.sum(e * e))
        scores = [sse(tau) for tau in DELAYS_S]
        k = int(np.argmin(scores))
        lo, hi = DELAYS_S[max(k - 1, 0)], DELAYS_S[min(k + 1, len(DELAYS_S) - 1)]
        res = minimize_scalar(sse, bounds=(lo if k > 0 else 0.0, hi), method="bounded",
                              options={"xatol": 1e-4})
        return float(res.x) if res.fun < scores[k] else DELAYS_S[k]

    def loo_of(keys: list[tuple[int, str]], taus: dict[int, float]) -> list[np.ndarray]:
        return _loo(*design(keys, taus), blocks)

    def gains(e0: list[np.ndarray], e1: list[np.ndarray]) -> np.ndarray:
        return np.array([float(np.mean(a - b)) / r for a, b in zip(e0, e1)])

    # forward: the candidate that explains most (mean held-out gain) is added while it passes
    # Holm's correction over every (cable, explanation) pair. A lag's gain is large in fast
    # blocks and small in slow ones, hence the signed-rank test for it; a sensor error's is even.
    def forward(chosen: list[tuple[int, str]], taus: dict[int, float], ps: dict[tuple[int, str], float],
                allowed: list[tuple[int, str]]) -> tuple[list, dict, dict, list[np.ndarray]]:
        chosen, taus, ps = list(chosen), dict(taus), dict(ps)
        cur = loo_of(chosen, taus)
        # the simple explanations first; both at once on a cable only where none of them is
        # accepted (it has more freedom, and taken first it places a sensor error on a
        # lagging cable that the error of another cable's sensor would explain)
        tiers = [[k for k in allowed if k[1] != "sensor+delay"], [k for k in allowed if k[1] == "sensor+delay"]]
        for _ in range(len(allowed)):
            best = None
            for key in (k for tier in tiers for k in tier):
                if best is not None and key[1] == "sensor+delay":
                    break
                if key in chosen or _clashes(key, chosen):
                    continue
                tk = {**taus, key[0]: fit_lag(key[0], chosen + _own(key), taus)} if key[1] in LAG else taus
                e1 = loo_of(chosen + [key], tk)
                g = gains(cur, e1)
                gain = float(np.mean(g))
                if gain < MIN_GAIN:
                    continue
                # among the explanations the test accepts, the one that explains most: the
                # largest mean gain alone may be a lag that helps in a few fast blocks only
                # (measured: a lag on a cable whose sensor is also off had the largest gain
                # at p = 0.48 and stopped the search, while that sensor error had p = 2e-11)
                p = (signed_rank_test if key[1] in LAG else t_test)(g)[1]
                adj1 = holm({**ps, key: p}, tries)[key]
                if adj1 < ALPHA and (best is None or gain > best[1]):
                    best = (key, gain, g, e1, tk, adj1)
            if best is None:
                break
            key, _, g, e1, tk, adj1 = best
            chosen.append(key)
            taus = tk
            ps[key] = adj1
            cur = e1
        return chosen, taus, ps, cur

    chosen, taus, ps, cur = forward([], {}, {}, cands)

    # the sensor errors as one set: the forward search adds the cable that explains most at
    # each step, and where offsets on two or three cables together look much like one on
    # another cable, its first pick is that other cable and the true ones no longer pay
    # beside it (development seed 8675309: 5 of 14 sensor errors placed on wrong cables).
    # Every set of up to SET_MAX cables is scored held out; the set kept is the largest best
    # set whose every cable earns its place beside the others, unless a smaller such set
    # balances the platform as well (fewest cables, as the forward search)
    def best_sensor_set(chosen: list[tuple[int, str]], ps: dict[tuple[int, str], float],
                        cur: list[np.ndarray]) -> tuple[list, dict, list[np.ndarray]]:
        fixed = [k for k in chosen if k[1] != "sensor"]
        pool = [i for i in range(m) if (i, "sensor+delay") not in fixed]
        found = sum(1 for k in chosen if k[1] == "sensor")
        kmax = min(len(pool), max(SET_MAX, found))
        while kmax > found and sum(math.comb(len(pool), k) for k in range(kmax + 1)) > SET_EVALS:
            kmax -= 1
        # held-out fits of a set from per-block sums of the columns of every candidate
        # (the block's own share subtracted from the total, as _loo does)
        keys = fixed + [(i, "sensor") for i in pool if (i, "sensor") not in fixed]
        X, target = design(keys, taus)
        nb = len(base)
        at, col = nb, {}
        for key in keys:
            if key[1] in SENSOR:
                col[key] = [at, at + 1]
                at += 2
        fixed_cols = list(range(nb)) + [c for key in fixed if key in col for c in col[key]]
        Gb = np.stack([np.einsum("nrp,nrq->pq", X[b], X[b]) for b in blocks])
        hb = np.stack([np.einsum("nrp,nr->p", X[b], target[b]) for b in blocks])
        tb = np.array([float(np.sum(target[b] * target[b])) for b in blocks])
        Gt, ht = np.einsum("nrp,nrq->pq", X, X), np.einsum("nrp,nr->p", X, target)
        size = np.array([b.size * r for b in blocks], float)
        errs: dict[tuple[int, ...], np.ndarray] = {}

        def err(S: tuple[int, ...]) -> np.ndarray:
            # per block, the held-out whitened squared residual per tick and row (every
            # block's fold solved at once, columns scaled to unit norm as _solve does)
            if S not in errs:
                ix = np.array(fixed_cols + [c for i in S for c in col[(i, "sensor")]])
                G, h = Gb[:, ix][:, :, ix], hb[:, ix]
                A, v = Gt[np.ix_(ix, ix)][None] - G, ht[ix][None] - h
                sc = np.sqrt(np.clip(np.diagonal(A, axis1=1, axis2=2), 0.0, None))
                sc[sc == 0] = 1.0
                beta = np.einsum("bpq,bq->bp", np.linalg.pinv(A / (sc[:, :, None] * sc[:, None, :]),
                                                              rtol=PINV_RTOL), v / sc) / sc
                errs[S] = (tb - 2.0 * np.einsum("bp,bp->b", beta, h)
                           + np.einsum("bp,bpq,bq->b", beta, G, beta)) / size
            return errs[S]

        def mean(S: tuple[int, ...]) -> float:
            return float(np.sum(err(S) * size) / np.sum(size))

        def own(S: tuple[int, ...]) -> Optional[dict[tuple[int, str], float]]:
            # each cable of S against S without it: its adjusted p, or None where one fails
            raw = {}
            for i in S:
                g = err(tuple(j for j in S if j != i)) - err(S)
                if float(np.mean(g)) < MIN_GAIN:
                    return None
                raw[(i, "sensor")] = t_test(g)[1]
            adj = holm(raw, tries)
            return adj if all(v < ALPHA for v in adj.values()) else None

        best = {k: min(itertools.combinations(pool, k), key=mean) for k in range(kmax + 1)}
        earned = {k: own(best[k]) for k in best}
        ok = [k for k in best if earned[k] is not None]
        k = max(ok)
        for j in sorted(ok):              # a smaller set that balances as well is kept
            if j >= k:
                break
            g = err(best[j]) - err(best[k])
            if not (float(np.mean(g)) >= (MIN_GAIN if j == 0 else 0.0) and t_test(g)[1] < ALPHA):
                k = j
                break
        S = best[k]
        if sorted(S) == sorted(i for i, kind in chosen if kind == "sensor"):
            return chosen, ps, cur
        keep = {key: v for key, v in ps.items() if key[1] != "sensor"}
        chosen = fixed + [(i, "sensor") for i in S]
        return chosen, {**keep, **earned[k]}, loo_of(chosen, taus)

    chosen, ps, cur = best_sensor_set(chosen, ps, cur)
    # each lag was searched beside the ones before it: refit them beside all the others
    lagging = [(i, kind) for i, kind in chosen if kind in LAG]
    if len(lagging) > 1:
        for _ in range(2):
            for i, kind in lagging:
                rest = [k for k in chosen if k != (i, kind)] + _own((i, kind))
                taus = {**taus, i: fit_lag(i, rest, {j: v for j, v in taus.items() if j != i})}
        cur = loo_of(chosen, taus)
    # both at once on a cable is kept only where each part earns its place: where the lag
    # alone (or the sensor alone) balances as well on held-out blocks (not worse by MIN_GAIN
    # at p < ALPHA), that part is reported, and where nothing balances as well as that part,
    # nothing is
    def as_well(alt: list[tuple[int, str]], tk: dict[int, float], test) -> Optional[list[np.ndarray]]:
        e_alt = loo_of(alt, tk)
        g = gains(e_alt, cur)                            # > 0: the simpler one balances worse
        return None if (float(np.mean(g)) >= MIN_GAIN and test(g)[1] < ALPHA) else e_alt

    for i, kind in list(chosen):
        if kind != "sensor+delay":
            continue
        for part, test in (("delay", t_test), ("sensor", signed_rank_test)):
            alt = [k if k != (i, kind) else (i, part) for k in chosen]
            rest = {j: v for j, v in taus.items() if j != i}
            tk = {**rest, i: fit_lag(i, [k for k in alt if k != (i, part)], rest)} if part == "delay" else rest
            e_alt = as_well(alt, tk, test)
            if e_alt is not None:
                ps[(i, part)] = ps.pop((i, kind))
                chosen, taus, cur = alt, tk, e_alt
                alt = [k for k in chosen if k != (i, part)]
                e_alt = as_well(alt, rest, signed_rank_test if part == "delay" else t_test)
                if e_alt is not None:
                    ps.pop((i, part))
                    chosen, taus, cur = alt, rest, e_alt
                break
    ratio = float(np.mean(np.concatenate(cur)) / r)
    # which cable? With more cables than wrench rows, offsets on several cables can leave
    # nearly the wrench residual one offset on another cable leaves, over a trajectory whose
    # poses differ little. For each sensor error found, the selection is run again without
    # that cable's sensor columns: where other cables' sensor errors balance the platform as
    # well on held-out blocks (not worse by MIN_GAIN at p < ALPHA), the balance cannot place it
    others_of: dict[int, list[int]] = {}
    for i, kind in chosen:
        if kind not in SENSOR:
            continue
        # without this cable's sensor columns (its lag, if any, stays)
        rest = [k if k != (i, kind) else (i, "delay") for k in chosen if k != (i, "sensor")]
        alt, _, _, e_alt = forward(rest, taus, {k: v for k, v in ps.items() if k != (i, kind)},
                                   [(j, "sensor") for j in range(m)
                                    if j != i and not any(jj == j and kk in SENSOR for jj, kk in chosen)])
        added = sorted(j for j, kind2 in alt if (j, kind2) not in rest)
        if not added:
            continue
        g = gains(e_alt, cur)                              # > 0: the alternative balances worse
        if not (float(np.mean(g)) >= MIN_GAIN and t_test(g)[1] < ALPHA):
            others_of[i] = added
    # the sensor errors' sizes, fitted on all ticks with the chosen columns
    out_sensor: dict[int, dict[str, float]] = {}
    out_delay = {i: {"tau_s": taus[i], "p": ps[(i, kind)]} for i, kind in chosen if kind in LAG}
    if any(kind in SENSOR for _, kind in chosen):
        X, target = design(chosen, taus)
        beta, *_ = np.linalg.lstsq(X.reshape(-1, X.shape[2]), target.reshape(-1), rcond=None)
        j = 2
        for i, kind in chosen:
            if kind in SENSOR:
                o, g = float(beta[j]), float(beta[j + 1])
                err = o + g * y[:, i]          # o and g trade off when the tension varies little
                out_sensor[i] = {"o": o, "g": g, "p": ps[(i, kind)], "mean_N": float(np.mean(err)),
                                 "rms_N": float(np.sqrt(np.mean(err ** 2))),
                                 "or_cables": others_of.get(i, [])}
                j += 2
    return {"ratio_raw": ratio_raw, "ratio": ratio, "holds": bool(ratio <= HOLDS), "threshold": HOLDS,
            "sensor": out_sensor, "delay": out_delay, "tried": tries, "blocks": len(blocks),
            "dynamic": math.sqrt(float(np.mean(np.sum(inert * inert, axis=1))))}
