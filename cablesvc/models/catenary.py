"""Sag of a hanging cable (Irvine's taut-cable approximation): the one Newton solve.

A cable of weight per length w hanging over the chord L under tension f is longer than the
chord by s = w^2 L^3 / (24 f^2). Where the cable path of stiffness k takes that length up
over a tension f0 without sag, the tension solves

    f = f0 + cc / f^2,        cc = k w^2 L^3 / 24 [N^3]

:func:`irvine_tension` finds that root, used by the twin's ``sag`` effect
(:class:`cablesvc.simulate.effects.Sag`, iterated to convergence from f0) and by the sag
term of discovery and the live kernel (:class:`cablesvc.models.terms.Sag`, a fixed
:data:`SAG_NEWTON` steps from max(f0, cbrt(cc)) so that the kernel runs in fixed time).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["SAG_NEWTON", "irvine_tension"]

#: Newton steps of the sag equation, offline and live (a fixed count: the live kernel runs
#: in fixed time). From f = max(f0, cbrt(c), 1) the iterates of the concave, increasing
#: f - f0 - c / f^2 rise monotonically to the root; 8 steps reach it to ~1e-12 relative
#: for sag up to the tension itself (``tests/test_live_terms.py``).
SAG_NEWTON = 8


def irvine_tension(f0: np.ndarray, cc: np.ndarray, floor: float = 1.0, out: Optional[np.ndarray] = None,
                   tmp: Optional[np.ndarray] = None, *, steps: int = SAG_NEWTON, cbrt_start: bool = True,
                   tol: Optional[float] = None) -> np.ndarray:
    """Root f >= f0 of f - f0 - cc / f^2 = 0 (f0 [N], cc [N^3] >= 0), f floored at ``floor`` N.

    Newton from f = max(f0, cbrt(cc), floor) (``cbrt_start=False``: from max(f0, floor));
    g(f) = f - f0 - cc / f^2 is increasing and concave, so Newton from the left rises to
    the unique root. ``steps`` Newton steps; with ``tol``, it stops earlier once every
    step is at most ``tol`` x max(1, f). Into ``out`` (shape of f0 and cc broadcast), with
    the scratch ``tmp`` (2, *shape): nothing allocated when both are given.
    """
    shape = np.broadcast_shapes(np.shape(f0), np.shape(cc))
    f = np.empty(shape) if out is None else out
    w = np.empty((2,) + shape) if tmp is None else tmp
    a, b = w[0], w[1]
    if cbrt_start:
        np.cbrt(cc, out=a)
        np.maximum(f0, a, out=f)
        np.maximum(f, floor, out=f)
    else:
        np.maximum(f0, floor, out=f)
    for _ in range(int(steps)):
        np.multiply(f, f, out=a)                   # f^2
        np.divide(cc, a, out=b)                    # cc / f^2
        np.subtract(f, f0, out=a)
        np.subtract(a, b, out=a)                   # g = f - f0 - cc/f^2
        np.divide(b, f, out=b)
        np.multiply(b, 2.0, out=b)
        np.add(b, 1.0, out=b)                      # g' = 1 + 2 cc / f^3
        np.divide(a, b, out=a)                     # the Newton step
        np.subtract(f, a, out=f)
        np.maximum(f, floor, out=f)
        if tol is not None and np.all(np.abs(a) <= tol * np.maximum(1.0, f)):
            break
    return f
