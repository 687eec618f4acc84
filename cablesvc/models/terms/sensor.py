"""Terms of the measurement chain: dead time between length and force (:class:`DeadTime`, live
through the stack's delay line, :mod:`cablesvc.models.terms.live`) and the force sensor's
offset and gain error (:class:`OffsetGain`).
"""

from __future__ import annotations

import numpy as np

from cablesvc.models.terms.base import Term
from cablesvc.models.terms.signals import make_design

__all__ = ["DeadTime", "OffsetGain"]


class DeadTime(Term):
    """Dead time between length and force: the force follows the elongation of tau seconds
    ago. A time-invariant baseline driven by x(t - tau) gives f0(t - tau), so

        delta_f = f0(t - tau) - f0(t),   tau [s] in [0, 0.5]

    (no linear parameter; tau from a grid of ticks refined by a bounded scalar search;
    f0(t - tau) linearly interpolated between ticks, held at the first value before the
    start). Live, a delay line of the last
    :data:`~cablesvc.models.terms.live.DELAY_WINDOW_S` seconds holds f0, x,
    dx/dt and A (the other terms on the cable see them delayed, as offline)."""

    name = "deadtime"
    label = "dead time between length and force"
    equation = "f0(t - tau) - f0(t)"
    variable = "force rate -df0/dt [N/s]"
    hypers = ("tau",)
    has_fixed = True
    refine_hyper = "tau"
    refine_bounds = (0.0, 0.5)
    n_hyper = 1
    delays_input = True

    def grid(self, s):
        return [{"tau": tau} for tau in np.unique(np.r_[0.0, np.geomspace(s.dt, 0.5, 14)])]

    def design(self, s, c, h):
        f = s.f0[:, c]
        shifted = np.interp(s.t - h["tau"], s.t, f)
        return make_design([], (), (), fixed=shifted - f)

    def evidence(self, s, c, h):
        return -np.gradient(s.f0[:, c], s.t)


class OffsetGain(Term):
    """Force-sensor offset and gain error: measured = (1 + g) f + o:

        delta_f = o + g f,   o [N], g [-]."""

    model_form = True
    name = "offset_gain"
    label = "sensor offset and gain error"
    equation = "o + g f"
    variable = "predicted force f [N]"
    params = ("o", "g")
    units = ("N", "-")
    owns_nuisance = True

    def columns(self, g, R, h, out):
        out[0].fill(1.0)
        np.copyto(out[1], g.f0)

    def evidence(self, s, c, h):
        return s.f0[:, c]
