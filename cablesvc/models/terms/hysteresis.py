"""Hysteresis missing from the baseline altogether: the Bouc-Wen term
(:class:`BoucWenHysteresis`), its state z over a record (:func:`bouc_wen_z`) and its live
form, both by the one Bouc-Wen step of :mod:`cablesvc.models.boucwen`.
"""

from __future__ import annotations

import numba
import numpy as np

from cablesvc.models.boucwen import bouc_wen_step_n1, bouc_wen_step_n1_np
from cablesvc.models.terms.base import LiveTerm, Term
from cablesvc.models.terms.signals import make_design

__all__ = ["BoucWenHysteresis", "bouc_wen_z"]


@numba.njit(cache=True)
def _bw_z(x, beta, gamma):
    """Normalised Bouc-Wen state z [m] driven by x [m] (000 eq 2 with A = 1, n = 1): one
    backward-Euler step of the law per tick (:func:`cablesvc.models.boucwen.bouc_wen_step_n1`;
    this term's beta is the law's gamma and its gamma the law's beta)."""
    N = x.shape[0]
    z = np.zeros(N)
    zk = 0.0
    for k in range(1, N):
        zk = bouc_wen_step_n1(zk, x[k] - x[k - 1], 1.0, gamma, beta)
        z[k] = zk
    return z


def bouc_wen_z(x: np.ndarray, beta: float, gamma: float) -> np.ndarray:
    """Bouc-Wen hysteretic displacement z [m] driven by the elongation x [m] (N,):
    dz = dx (1 - (beta + gamma sgn(z dx)) |z|) (000 eq 2, A = 1, n = 1, with this term's beta
    and gamma in the roles of 000's gamma and beta), integrated per tick by the backward-Euler
    step z' = (z + dx) / (1 + (beta + gamma sgn(z dx)) |dx|) of
    :func:`cablesvc.models.boucwen.bouc_wen_step_n1` (implicit in |z|, so stable for any dx
    when beta > |gamma|); z saturates at 1 / (beta + gamma) [m]. ``beta``, ``gamma`` [1/m].
    The live form (:class:`BoucWenHysteresis`) runs the same step."""
    return _bw_z(np.ascontiguousarray(x, dtype=np.float64), float(beta), float(gamma))


class BoucWenHysteresis(Term):
    """Hysteresis missing altogether (000 eqs 1-2, Bouc-Wen): a hysteretic force alpha_z z
    with z driven by the elongation,

        dz = dx (1 - (beta + gamma sgn(z dx)) |z|),   delta_f = k_z z + k_x (x - x_mean)

    k_z [N/m], k_x [N/m]; the loop shape (beta, gamma) [1/m] on a grid set by the saturation
    z_max = 1 / (beta + gamma) relative to the elongation's spread; z by the semi-implicit
    step of :func:`bouc_wen_z`, offline over the record and live tick by tick."""

    model_form = True
    name = "boucwen"
    label = "hysteresis missing (Bouc-Wen)"
    # the law as the code runs it (the string said (beta sgn(z dx) + gamma), 000's own naming)
    equation = ("k_z z + k_x (x - mean x), dz = dx (1 - (beta + gamma sgn(z dx)) |z|)  "
                "(000 eqs 1-2; this term's beta, gamma are 000's gamma, beta)")
    variable = "elongation x [m] (loop)"
    params = ("k_z", "k_x")
    units = ("N/m", "N/m")
    hypers = ("beta", "gamma")
    ref_names = ("x_mean",)
    n_hyper = 2

    def grid(self, s):
        sx = float(np.median(np.std(s.x[s.train], axis=0))) or 1e-3
        out = []
        for zmax in (0.05 * sx, 0.2 * sx, 0.8 * sx):
            for ratio in (0.5, 0.0, -0.5):         # gamma / beta: softening, symmetric, pinched
                beta = 1.0 / (zmax * (1.0 + ratio))
                out.append({"beta": beta, "gamma": ratio * beta})
        return out

    def refs(self, s, c, h):
        return {"x_mean": s.train_mean(s.x[:, c])}

    @staticmethod
    def law(z, x, x_mean, out):
        np.copyto(out[0], z)
        np.subtract(x, x_mean, out=out[1])

    def design(self, s, c, h):
        R = self.refs(s, c, h)
        X = np.empty((2, s.n))
        self.law(bouc_wen_z(s.x[:, c], h["beta"], h["gamma"]), s.x[:, c], R["x_mean"], X)
        return make_design(list(X), self.params, self.units, refs=R)

    def live(self, table, lanes, m):
        return _BoucWenLive(self, table, lanes, m)

    def evidence(self, s, c, h):
        return s.x[:, c]


class _BoucWenLive(LiveTerm):
    """Bouc-Wen z per (lane, cable), the step of :func:`bouc_wen_z` in its numpy form
    (:func:`cablesvc.models.boucwen.bouc_wen_step_n1_np`)."""

    def __init__(self, term, table, lanes, m):
        super().__init__(term, table, lanes, m)
        self.z = np.zeros((lanes, m))
        self.x_prev = np.zeros((lanes, m))
        self.started = np.zeros(1, bool)
        self.dx = np.zeros((lanes, m))
        self.s = np.zeros((lanes, m))
        self.den = np.zeros((lanes, m))

    def write(self, g):
        # first tick: dx = 0, so z stays 0 (offline z[0] = 0)
        np.copyto(self.x_prev, g.x, where=~self.started[0])
        self.started[0] = True
        np.subtract(g.x, self.x_prev, out=self.dx)
        np.copyto(self.x_prev, g.x)
        # the law's beta is this term's gamma, its gamma this term's beta (see _bw_z)
        bouc_wen_step_n1_np(self.z, self.dx, self.H["gamma"], self.H["beta"], self.s, self.den)
        self.term.law(self.z, g.x, self.R["x_mean"], self.cols)

    def state_dict(self):
        return {"z": self.z.copy(), "x_prev": self.x_prev.copy(), "started": self.started.copy()}

    def load_state_dict(self, d):
        if "z" not in d or np.shape(d["z"]) != self.z.shape:     # a file without this term before
            return
        np.copyto(self.z, d["z"])
        np.copyto(self.x_prev, d["x_prev"])
        np.copyto(self.started, d["started"])
