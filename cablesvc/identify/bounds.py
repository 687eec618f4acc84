"""Parameter bounds of the optimisers: the one reader of the forms a caller may pass.

:func:`parse_bounds` is used by the particle swarm (:mod:`cablesvc.identify.pso`, finite
bounds), the least-squares refinement and the multi-start SQP (:mod:`cablesvc.identify.local`).
"""

from __future__ import annotations

from typing import Any, Optional

import numpy as np

__all__ = ["parse_bounds"]


def parse_bounds(bounds: Any, n: Optional[int] = None, *, finite: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``(lb, ub)``: two new 1-D float arrays of equal length, from the bounds of n parameters.

    Accepts a :class:`scipy.optimize.Bounds`, a pair ``(lb, ub)`` of numpy arrays, a pair
    ``(lb, ub)`` of sequences, or a sequence of ``(lo, hi)`` pairs, one per parameter (None
    in a pair means unbounded). A 2x2 nested list/tuple of numbers is read as two ``(lo, hi)``
    pairs (the ``scipy.optimize.minimize`` convention); pass numpy arrays ``(lb, ub)`` to
    mean the other reading.

    ``n``: the number of parameters (None: taken from the bounds). With ``n``, None bounds
    mean unbounded and scalar bounds broadcast to every parameter. ``finite``: every bound
    must be finite (the swarm and the multi-start draw their points between them).
    Raises ValueError naming what is wrong.
    """
    what = "a sequence of" if n is None else str(n)
    if bounds is None:
        if n is None or finite:
            raise ValueError(f"bounds: expected (lb, ub) or {what} (lo, hi) pairs, got None")
        return np.full(n, -np.inf), np.full(n, np.inf)
    if hasattr(bounds, "lb") and hasattr(bounds, "ub"):
        lb, ub = bounds.lb, bounds.ub
    elif isinstance(bounds, (tuple, list)) and len(bounds) == 2 and all(isinstance(b, np.ndarray) for b in bounds):
        lb, ub = bounds
    else:
        try:
            rows = list(bounds)
        except TypeError:
            raise ValueError(f"bounds: expected (lb, ub) or {what} (lo, hi) pairs, got {bounds!r}") from None
        if (n is None or len(rows) == n) and all(np.ndim(r) == 1 and len(r) == 2 for r in rows):
            lb = [(-np.inf if r[0] is None else r[0]) for r in rows]
            ub = [(np.inf if r[1] is None else r[1]) for r in rows]
        elif len(rows) == 2:
            lb, ub = rows
        else:
            raise ValueError(f"bounds: expected (lb, ub) or {what} (lo, hi) pairs, got {len(rows)} rows")
    if n is None:
        lb = np.atleast_1d(np.array(lb, dtype=float))
        ub = np.atleast_1d(np.array(ub, dtype=float))
        if lb.shape != ub.shape or lb.ndim != 1:
            raise ValueError(f"bounds: lb and ub must be 1-D of equal length, got {lb.shape} and {ub.shape}")
    else:
        lb = np.broadcast_to(np.asarray(lb, dtype=float), (n,)).copy()
        ub = np.broadcast_to(np.asarray(ub, dtype=float), (n,)).copy()
    if finite and not (np.all(np.isfinite(lb)) and np.all(np.isfinite(ub))):
        raise ValueError("bounds: PSO needs finite lower and upper bounds for every parameter")
    if np.any(ub < lb):
        raise ValueError(f"bounds: upper < lower for parameter index(es) {np.flatnonzero(ub < lb).tolist()}")
    return lb, ub
