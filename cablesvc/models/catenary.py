"""Sag of a hanging cable (Irvine's taut-cable approximation): the one solve of its tension.

A cable of weight per length w hanging over the chord L under tension f is longer than the
chord by s = w^2 L^3 / (24 f^2). Where the cable path of stiffness k takes that length up
over a tension f0 without sag, the tension solves

    f = f0 + cc / f^2,        cc = k w^2 L^3 / 24 [N^3]

:func:`irvine_tension` finds that root in closed form, used by the twin's ``sag`` effect
(:class:`cablesvc.simulate.effects.Sag`) and by the sag term of discovery and the live
kernel (:class:`cablesvc.models.terms.Sag`): the same numpy calls whatever the data, so the
kernel runs in fixed time.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

__all__ = ["IrvineScratch", "irvine_tension"]

#: |f0| is taken at least this [N] in the closed form (so that cc / |f0|^3 stays finite);
#: the root moves by less than that, far below a float's resolution of any tension >= 1 N
_F0_MIN = 1e-30


class IrvineScratch:
    """The buffers :func:`irvine_tension` works in, for arrays of ``shape`` (made once by
    the live form: the solve then allocates nothing)."""

    def __init__(self, shape: tuple[int, ...]):
        self.a = np.empty(shape)                    # |f0| (at least _F0_MIN)
        self.s = np.empty(shape)                    # sqrt(27 cc / (4 |f0|^3))
        self.u = np.empty((3,) + tuple(shape))      # the three branches' angles, then T, then f0 < 0's f
        self.lt1 = np.empty(shape, bool)            # s < 1
        self.neg = np.empty(shape, bool)            # f0 < 0


def irvine_tension(f0: np.ndarray, cc: np.ndarray, floor: float = 1.0, out: Optional[np.ndarray] = None,
                   scratch: Optional[IrvineScratch] = None) -> np.ndarray:
    """Root f > 0 of f - f0 - cc / f^2 = 0 (f0 [N], cc [N^3] >= 0), floored at ``floor`` N.

    Times f^2, f^3 - f0 f^2 - cc = 0: a cubic with exactly one positive root (for cc > 0;
    g(f) = f - f0 - cc / f^2 increases from -inf to +inf on f > 0). With a = |f0| and
    s = sqrt(27 cc / (4 a^3)), its trigonometric / hyperbolic solution is

        f0 >= 0:  f = f0 + (4 a / 3) T^2,  T = sinh(asinh(s) / 3)
        f0 < 0:   f = a s / (3 T),         T = cos(acos(s) / 3)    for s < 1 (the largest
                                                                   of three real roots),
                                           T = cosh(acosh(s) / 3)  for s >= 1

    (T the root of 4 T^3 + 3 T = s, resp. 4 T^3 - 3 T = s, by the triple-angle formulas; both
    forms equal (a / 3)(s / T), each written without cancellation: f - f0 >= 0 as a product
    where f0 >= 0, and no f0 + (f - f0) where a deep-slack f0 < 0 nearly cancels). Every
    branch is computed (its input clamped into its domain) and selected with masks, so the
    same calls run whatever the data. cc = 0 gives f = max(f0, floor) exactly. This is the
    root Newton's iteration from the left converges to (``tests/test_live_terms.py`` checks
    it against an 80-bit Newton solve). Into ``out`` (shape of f0 and cc broadcast) with the
    buffers ``scratch``: nothing allocated when both are given.
    """
    if out is None or scratch is None:              # (the live form gives both: no shape work per tick)
        shape = np.broadcast_shapes(np.shape(f0), np.shape(cc))
        out = np.empty(shape) if out is None else out
        scratch = IrvineScratch(shape) if scratch is None else scratch
    f, w = out, scratch
    a, s, u = w.a, w.s, w.u
    np.abs(f0, out=a)
    np.maximum(a, _F0_MIN, out=a)
    np.multiply(a, a, out=s)
    np.multiply(s, a, out=s)                        # a^3
    np.divide(cc, s, out=s)
    np.multiply(s, 6.75, out=s)
    np.sqrt(s, out=s)                               # s = sqrt(27 cc / (4 a^3))
    np.arcsinh(s, out=u[0])
    np.maximum(s, 1.0, out=u[1])
    np.arccosh(u[1], out=u[1])
    np.minimum(s, 1.0, out=u[2])
    np.arccos(u[2], out=u[2])
    np.divide(u, 3.0, out=u)
    np.sinh(u[0], out=u[0])
    np.cosh(u[1], out=u[1])
    np.cos(u[2], out=u[2])
    np.less(s, 1.0, out=w.lt1)
    np.copyto(u[1], u[2], where=w.lt1)              # f0 < 0: T by cos below s = 1, cosh above
    np.divide(s, u[1], out=u[2])                    # (T >= cos(pi / 6) there)
    np.multiply(u[2], a, out=u[2])
    np.divide(u[2], 3.0, out=u[2])                  # f0 < 0: f = a s / (3 T)
    np.multiply(u[0], u[0], out=f)
    np.multiply(f, a, out=f)
    np.multiply(f, 4.0 / 3.0, out=f)
    np.add(f, f0, out=f)                            # f0 >= 0: f = f0 + (4 a / 3) T^2
    np.less(f0, 0.0, out=w.neg)
    np.copyto(f, u[2], where=w.neg)
    np.maximum(f, floor, out=f)
    return f
