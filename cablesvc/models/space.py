"""Identification search spaces of the cable models (what :meth:`CableModel.search_space`
returns) and the data statistics they are scaled by. Pure numpy."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


@dataclass
class Space:
    """Identified parameters of one model for K cables.

    ``names``: model parameter names (LM works on them, in model units); ``search_lb/ub``
    (K, n) bounds of the PSO search space and ``to_model(S)`` maps search values (..., K, n)
    to model values (..., K, n); ``lb/ub`` (K, n) model-space bounds for least squares;
    ``fixed``: other model parameters, name -> (K,); ``options``: build options;
    ``x0``: (K, n) data-driven start in model space; ``notes``: what was fixed and why."""

    model: str
    names: list[str]
    units: list[str]
    search_lb: np.ndarray
    search_ub: np.ndarray
    to_model: Callable[[np.ndarray], np.ndarray]
    to_search: Callable[[np.ndarray], np.ndarray]
    lb: np.ndarray
    ub: np.ndarray
    fixed: dict[str, np.ndarray]
    x0: np.ndarray
    options: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def kwargs(self, V: np.ndarray) -> dict[str, np.ndarray]:
        """Model constructor parameters from model values V (L, K, n)."""
        L = V.shape[0]
        out = {k: np.ascontiguousarray(V[:, :, j]) for j, k in enumerate(self.names)}
        for k, v in self.fixed.items():
            out[k] = np.broadcast_to(np.asarray(v, float), (L, V.shape[1])).copy()
        return out

    def subspace(self, idx: list[int]) -> "Space":
        """The same space for the cables ``idx`` only."""
        return Space(self.model, self.names, self.units, self.search_lb[idx], self.search_ub[idx], self.to_model,
                     self.to_search, self.lb[idx], self.ub[idx], {k: np.asarray(v)[idx] for k, v in self.fixed.items()},
                     self.x0[idx], self.options, self.notes)


def linear_guess(x: np.ndarray, f: np.ndarray) -> tuple[float, float]:
    """F ~ k (x - x0): least-squares slope k [N/m] (>= a tiny positive) and x0 [m]."""
    A = np.column_stack([x, np.ones_like(x)])
    (k, b), *_ = np.linalg.lstsq(A, f, rcond=None)
    k = float(abs(k)) if k != 0 else 1.0
    return k, float(-b / k)


@dataclass
class FitStats:
    """What a search space is scaled by, per fitted cable (K of them): the data ``x``
    elongation (N, K) [m], ``f`` force (N, K) [N], ``l0`` motor length (N, K) [m], and
    ``kk`` the least-squares slope F/x [N/m], ``x0z`` its zero-force elongation [m],
    ``xm``/``xs`` the elongation's mean and std (>= 1e-7) [m], ``fs``/``fr`` the force's std
    and range (>= 1e-3) [N]."""

    x: np.ndarray
    f: np.ndarray
    l0: np.ndarray
    kk: np.ndarray
    x0z: np.ndarray
    xm: np.ndarray
    xs: np.ndarray
    fs: np.ndarray
    fr: np.ndarray

    @property
    def K(self) -> int:
        return self.x.shape[1]

    @classmethod
    def of(cls, x: np.ndarray, f: np.ndarray, l0: np.ndarray) -> "FitStats":
        K = x.shape[1]
        kk = np.empty(K)
        x0z = np.empty(K)
        for c in range(K):
            kk[c], x0z[c] = linear_guess(x[:, c], f[:, c])
        return cls(x=x, f=f, l0=l0, kk=kk, x0z=x0z, xm=x.mean(axis=0), xs=np.maximum(x.std(axis=0), 1e-7),
                   fs=np.maximum(f.std(axis=0), 1e-3), fr=np.maximum(np.ptp(f, axis=0), 1e-3))


def identity(S: np.ndarray) -> np.ndarray:
    """Search coordinates that are the model's own."""
    return S


def column(v: Any) -> np.ndarray:
    """(K,) -> (K, 1)."""
    return np.asarray(v, float)[:, None]


def hysteresis_to_model(S):
    """Search -> model coordinates of the Bouc-Wen-type spaces: columns 1, 2 searched as
    log10, column 3 as a ratio to column 2 (gamma / beta: the loop shape)."""
    V = np.array(S, dtype=float, copy=True)
    V[..., 1] = 10.0 ** S[..., 1]
    V[..., 2] = 10.0 ** S[..., 2]
    V[..., 3] = S[..., 3] * V[..., 2]
    return V


def hysteresis_to_search(V):
    """Inverse of :func:`hysteresis_to_model`."""
    S = np.array(V, dtype=float, copy=True)
    S[..., 1] = np.log10(np.maximum(V[..., 1], 1e-300))
    S[..., 2] = np.log10(np.maximum(V[..., 2], 1e-300))
    S[..., 3] = V[..., 3] / np.where(V[..., 2] != 0, V[..., 2], 1.0)
    return S


def hysteresis_search_columns(s: FitStats) -> tuple[np.ndarray, np.ndarray]:
    """Search bounds (K, 4) of the Bouc-Wen variable's columns (hysteretic stiffness as
    log10, beta as log10, gamma / beta, n) shared by the Bouc-Wen-type models: k_d from 1 %
    to 10 x the slope, beta around k_d / z^n with z ~ the force std, gamma / beta in
    [-0.95, 1] (bounded z, 000 Sec 2), n in [1, 3]."""
    K = s.K
    bscale = np.log10(s.kk / s.fs)                # beta ~ k_d / z^n with z ~ force std, n ~ 1
    lo = np.column_stack([np.log10(s.kk * 1e-2), bscale - 3, np.full(K, -0.95), np.full(K, 1.0)])
    hi = np.column_stack([np.log10(s.kk * 10), bscale + 5, np.ones(K), np.full(K, 3.0)])
    return lo, hi
