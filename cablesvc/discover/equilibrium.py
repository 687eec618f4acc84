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
   approximate mass), then adds, cable by cable, the sensor columns A_i^T and A_i^T y_i
   while a leave-one-block-out test on per-block gains (the block is the unit; Holm over
   the cables) says they explain the wrench residual;
3. says whether equilibrium holds on the recording at all: when the whitened residual
   left is still well above 1, the measured forces do not balance for reasons no sensor
   column explains (dynamics, geometry, a dead time between pose and force), and a sensor
   error cannot be told from a cable's pretension or stiffness.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from cablesvc.discover.evidence import holm, t_test
from cablesvc.kinematics import PLANAR_WRENCH_ROWS, inverse_kinematics, platform_wrench, structure_matrix

__all__ = ["equilibrium_check"]

#: whitened mean square per wrench row under which the recording's forces count as balanced
HOLDS = 1.5
#: corrected p-value under which a cable's sensor columns count
ALPHA = 0.01


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


def _loo(Xw: np.ndarray, Ww: np.ndarray, blocks: list[np.ndarray]) -> list[np.ndarray]:
    """Held-out whitened squared residual per tick, per block (N ticks x r rows stacked)."""
    N, r, p = Xw.shape
    out = []
    allm = np.ones(N, bool)
    for b in blocks:
        m = allm.copy()
        m[b] = False
        if p:
            X = Xw[m].reshape(-1, p)
            sc = np.sqrt(np.sum(X * X, axis=0))
            sc[sc == 0] = 1.0
            beta, *_ = np.linalg.lstsq(X / sc, Ww[m].reshape(-1), rcond=None)
            pred = np.einsum("nrp,p->nr", Xw[b], beta / sc)
        else:
            pred = 0.0
        e = Ww[b] - pred
        out.append(np.sum(e * e, axis=1))
    return out


def equilibrium_check(geom: Any, t: np.ndarray, position: np.ndarray, orientation: np.ndarray, y: np.ndarray,
                      noise: np.ndarray, block: float = 2.5) -> dict[str, Any]:
    """Wrench balance of the measured forces ``y`` (N, m) [N] at the recorded pose (see the
    module docstring). ``noise`` (m,) [N] sensor-noise std per cable. Returns a JSON-able
    dict: ``ratio_raw`` / ``ratio`` whitened mean square per row before / after the fitted
    wrench and sensor columns, ``holds``, ``sensor`` {cable: {"o" [N], "g" [-], "p"}}
    (cables whose sensor columns explain the residual, Holm-corrected p), ``tried``."""
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
    sensor = {i: [wcol(AT[:, :, i]), wcol(AT[:, :, i] * y[:, i:i + 1])] for i in range(m)}
    blocks = _blocks(t, block)
    ratio_raw = float(np.mean(np.sum(Ww * Ww, axis=1)) / r)
    chosen: list[int] = []
    ps: dict[int, float] = {}
    cur = _loo(np.concatenate(base, axis=2), Ww, blocks)
    for _ in range(m):
        best = None
        for i in range(m):
            if i in chosen:
                continue
            X = np.concatenate(base + [c for j in chosen + [i] for c in sensor[j]], axis=2)
            e1 = _loo(X, Ww, blocks)
            g = np.array([float(np.mean(a - b)) / r for a, b in zip(cur, e1)])
            tt, p = t_test(g)
            if best is None or p < best[1] or (p == best[1] and tt > best[2]):
                best = (i, p, tt, e1)
        if best is None:
            break
        i, p, _, e1 = best
        adj = holm({**ps, i: p}, m)[i]
        if adj >= ALPHA:
            break
        chosen.append(i)
        ps[i] = adj
        cur = e1
    ratio = float(np.mean(np.concatenate(cur)) / r)
    # the sensor errors' size, fitted on all ticks with the chosen columns
    out_sensor: dict[int, dict[str, float]] = {}
    if chosen:
        X = np.concatenate(base + [c for j in chosen for c in sensor[j]], axis=2)
        beta, *_ = np.linalg.lstsq(X.reshape(-1, X.shape[2]), Ww.reshape(-1), rcond=None)
        for k, i in enumerate(chosen):
            o, g = float(beta[2 + 2 * k]), float(beta[3 + 2 * k])
            err = o + g * y[:, i]              # o and g trade off when the tension varies little
            out_sensor[i] = {"o": o, "g": g, "p": ps[i], "mean_N": float(np.mean(err)),
                             "rms_N": float(np.sqrt(np.mean(err ** 2)))}
    return {"ratio_raw": ratio_raw, "ratio": ratio, "holds": bool(ratio <= HOLDS), "threshold": HOLDS,
            "sensor": out_sensor, "tried": m, "blocks": len(blocks),
            "dynamic": math.sqrt(float(np.mean(np.sum(inert * inert, axis=1))))}
