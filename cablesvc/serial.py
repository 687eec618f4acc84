"""Serial correlation of a residual: one estimate of its lag-one correlation, and the
AR(1) variance inflation that follows from it.

n serially correlated samples with lag-one correlation rho carry about n (1 - rho) /
(1 + rho) independent ones (AR(1); Bartlett 1946, Bayley & Hammersley 1946), so the
variance of a mean-like statistic grows by (1 + rho) / (1 - rho). Identification uses it to
judge a score test on a smooth misfit (:mod:`cablesvc.identify.amplitude_joint`), discovery's
forward selector to count ticks at their effective number (:mod:`cablesvc.discover.select`).
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

__all__ = ["lag_one_correlation", "variance_inflation"]


def lag_one_correlation(pieces: Iterable[np.ndarray], floor: float = 0.0, cap: float = 0.99) -> float:
    """Lag-one correlation rho of a residual given as ``pieces`` (each a time-ordered run
    of ticks; pairs never span two pieces), pooled: sum e_t e_(t+1) / sum e_t^2 over all
    pieces, clipped to [``floor``, ``cap``]. 0 when the residual is zero."""
    num = den = 0.0
    for e in pieces:
        e = np.asarray(e, dtype=np.float64)
        if e.size > 1:
            num += float(e[1:] @ e[:-1])
        den += float(e @ e)
    if den <= 0.0:
        return 0.0
    return min(max(num / den, floor), cap)


def variance_inflation(rho: float) -> float:
    """(1 + rho) / (1 - rho): by how much serial correlation rho inflates the variance of a
    mean-like statistic (the reciprocal of the effective share of the samples)."""
    return (1.0 + rho) / (1.0 - rho)
