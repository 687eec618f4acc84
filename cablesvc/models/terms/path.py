"""Terms of the cable's path between winch and platform: the redirection pulley's friction and
wrap-angle stiffness (:class:`PulleyFriction`) and the sag at low tension (:class:`Sag`,
with its live form).
"""

from __future__ import annotations

import math

import numpy as np

from cablesvc.models.catenary import IrvineScratch, irvine_tension
from cablesvc.models.terms.base import LiveTerm, Term
from cablesvc.models.terms.signals import smooth_sign

__all__ = ["PulleyFriction", "Sag"]


class PulleyFriction(Term):
    """Redirection pulley (002 Sec 4, eq 19, Figs 9-11). The wheel carries the resultant
    F_b = f sqrt(2 (1 + cos beta)) of the two cable segments (eq 19, beta the angle between
    them); with the wrap angle alpha = pi - beta, F_b = 2 f sin(alpha / 2). The bearing's
    Coulomb friction mu F_b opposes the cable sliding over the wheel (sign of the haul-in
    speed v_slide, smoothed over v_s), and the wrapped arc changes the apparent stiffness
    linearly in alpha:

        delta_f = mu F_b tanh(v_slide / v_s) + f (k_0 + k_alpha (alpha - alpha_mean))

    mu [-] >= 0, k_0 [-], k_alpha [1/rad]; v_s [m/s] on a grid."""

    name = "pulley"
    label = "pulley wrap-angle friction and stiffness"
    equation = "mu * 2 f sin(alpha/2) * tanh(v_slide/v_s) + f (k0 + k_alpha (alpha - mean alpha))  (002 Sec 4 eq 19)"
    variable = "wrap-angle bearing load x direction of sliding, 2 f sin(alpha/2) sgn(v_slide) [N]"
    params = ("mu", "k_alpha", "k0")
    units = ("-", "1/rad", "-")
    lower = (0.0, -np.inf, -np.inf)
    hypers = ("v_s",)
    ref_names = ("alpha_mean",)
    n_hyper = 1
    nuisance = ("k0",)
    follows_direction = True
    #: its own explaining variable is the direction of sliding over the wheel: a stiffness
    #: that varies with the wrap angle alone is a pose-dependent stiffness, which the
    #: baseline's own model form also draws (measured on the Bouc-Wen truth's controls:
    #: k_alpha did all the work of every false pulley finding, mu none)
    signature = ("mu",)

    def applies(self, s, c):
        return bool(s.has_pulley[c]) and float(np.max(s.wrap[:, c])) > 1e-6

    refine_hyper = "v_s"
    refine_bounds = (1e-5, 0.05)

    def grid(self, s):
        return [{"v_s": float(v)} for v in np.geomspace(1e-4, 1e-2, 7)]

    def refs(self, s, c, h):
        return {"alpha_mean": s.train_mean(s.wrap[:, c])}

    def columns(self, g, R, h, out):
        o0, o1, o2 = out
        np.maximum(g.f0, 0.0, out=o0)
        np.multiply(g.wrap, 0.5, out=o1)
        np.sin(o1, out=o1)
        np.multiply(o0, o1, out=o0)
        np.multiply(o0, 2.0, out=o0)                   # F_b = 2 f sin(alpha/2)
        smooth_sign(g.v_slide, h["v_s"], out=o1)
        np.multiply(o0, o1, out=o0)
        np.subtract(g.wrap, R["alpha_mean"], out=o1)
        np.multiply(g.f0, o1, out=o1)
        np.copyto(o2, g.f0)

    def evidence(self, s, c, h):
        return 2.0 * np.maximum(s.f0[:, c], 0.0) * np.sin(0.5 * s.wrap[:, c]) * np.sign(s.v_slide[:, c])


class Sag(Term):
    """Sag at low tension (Irvine's taut-cable approximation): a cable of weight per length
    w hanging over the chord L under tension f is longer than the chord by
    s = w^2 L^3 / (24 f^2). At a given pose the cable is thus stretched by s more than the
    baseline assumes, and the whole cable path (stiffness k_c, from the winch, unknown:
    it includes the length stored between winch and pulley) takes it up:

        f = f0 + k_c s(f) = f0 + q L^3 / f^2,   q = w^2 k_c / 24 [N^3/m^3],   delta_f = f - f0

    (the closed-form root of :func:`cablesvc.models.catenary.irvine_tension`, the same calls
    every tick; f - q L^3 / f^2 increases in f, so the root is unique). q >= 0 is the
    nonlinear parameter (grid, then bounded scalar search; a parameter file with q < 0 is
    refused live); the report gives w = sqrt(24 q / k) with k = EA / (mean free length).
    L the free length, f >= 1 N."""

    name = "sag"
    label = "sag at low tension"
    equation = "f = f0 + k_c w^2 L^3 / (24 f^2)  (Irvine, taut cable)"
    variable = "1 / tension^2 [1/N^2]"
    hypers = ("q",)
    has_fixed = True
    refine_hyper = "q"
    refine_bounds = (0.0, 1e8)
    n_hyper = 1

    def grid(self, s):
        return [{"q": q} for q in np.r_[0.0, np.geomspace(1.0, 1e8, 25)]]

    #: the tension under sag (:func:`cablesvc.models.catenary.irvine_tension`: closed form,
    #: floored at 1 N, fixed time)
    solve = staticmethod(irvine_tension)

    def fixed_part(self, g, R, h, out):
        cc = np.empty(np.shape(out))
        self._fixed(g, h, out, cc, IrvineScratch(np.shape(out)))

    def _fixed(self, g, h, out, cc, scratch):
        np.power(g.free_length, 3, out=cc)
        np.multiply(cc, h["q"], out=cc)
        self.solve(g.f0, cc, out=out, scratch=scratch)
        np.maximum(g.f0, 1.0, out=cc)
        np.subtract(out, cc, out=out)

    def live(self, table, lanes, m):
        return _SagLive(self, table, lanes, m)

    def physical(self, params, h, s, c):
        k = s.ea[c] / float(np.mean(s.free_length[:, c]))
        return {"q": h["q"], "unit_q": "N^3/m^3", "w": math.sqrt(24.0 * max(h["q"], 0.0) / k), "unit_w": "N/m"}

    def evidence(self, s, c, h):
        return 1.0 / np.maximum(s.f0[:, c], 1.0) ** 2


class _SagLive(LiveTerm):
    """The sag term live: one row, its fixed part (no linear parameter)."""

    n_fixed = 1

    def __init__(self, term, table, lanes, m):
        super().__init__(term, table, lanes, m)
        q = self.H["q"].reshape(-1)
        bad = np.flatnonzero(~(np.isfinite(q) & (q >= 0)))
        if bad.size:                # the closed form needs cc >= 0: refused, not NaN forces
            raise ValueError(f"term_{term.name}.q: {float(q[bad[0]])!r} on cable {int(bad[0])}: must be a finite "
                             "number >= 0 N^3/m^3")
        self.cc = np.zeros((lanes, m))
        self.scratch = IrvineScratch((lanes, m))

    def write(self, g):
        self.term._fixed(g, self.H, self.cols[0], self.cc, self.scratch)
