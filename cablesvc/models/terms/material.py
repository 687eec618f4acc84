"""Terms of the cable material's law beyond the baseline: rate dependence (:class:`Viscous`),
amplitude-dependent stiffness and damping (:class:`AmplitudeStiffness`) and asymmetric
hardening of the elastic backbone (:class:`AsymmetricHardening`). The references they take
from the training ticks (:func:`amplitude_varies`, :func:`elongation_centre_scale`) are
shared with the baseline's recalibration (:mod:`cablesvc.models.terms.recalibration`).
"""

from __future__ import annotations

import numpy as np

from cablesvc.models.terms.base import Term
from cablesvc.models.terms.signals import Signals, smooth_sign

__all__ = ["Viscous", "AmplitudeStiffness", "AsymmetricHardening", "amplitude_varies", "elongation_centre_scale"]


def amplitude_varies(s: Signals, c: int) -> bool:
    """Whether the reversal amplitude of cable ``c`` varies (by more than 1 um) over the
    recording: the amplitude-dependent columns are then identifiable."""
    return float(np.ptp(s.amplitude[:, c])) > 1e-6


def elongation_centre_scale(s: Signals, c: int) -> tuple[float, float]:
    """The mean elongation [m] of cable ``c`` on the training ticks and the standard deviation
    about it [m] (at least 1e-12): the centre and scale of a polynomial in x - mean x."""
    x = s.x[:, c]
    xm = s.train_mean(x)
    return xm, max(float(np.std(x[s.train] - xm)), 1e-12)


class Viscous(Term):
    """Viscous rate dependence (Kelvin-Voigt damper in parallel with the cable):

        delta_f = c_v dx/dt,   c_v [N s/m] >= 0

    (dx/dt the backward difference of the elongation, as the live kernel has it)."""

    name = "viscous"
    label = "viscous rate dependence"
    equation = "c_v dx/dt (Kelvin-Voigt)"
    variable = "elongation rate dx/dt [m/s]"
    params = ("c_v",)
    units = ("N s/m",)
    lower = (0.0,)
    follows_direction = True

    def columns(self, g, R, h, out):
        np.copyto(out[0], g.v)

    def evidence(self, s, c, h):
        return s.v[:, c]


class AmplitudeStiffness(Term):
    """Amplitude-dependent stiffness and damping (002 eq 8: K1..K3 and the loop area S_a are
    functions of the elongation amplitude A). To first order in A around its mean the
    baseline misses a stiffness slope and a friction-like loop width that grow with A:

        delta_f = K1_A (A - A_mean) (x - x_mean) + d_A A tanh(v / v_s)

    K1_A [N/m^2], d_A [N/m]; A from the reversal points; v_s = 1e-4 m/s."""

    model_form = True
    name = "amplitude"
    label = "amplitude-dependent stiffness and damping"
    equation = "K1_A (A - mean A)(x - mean x) + d_A A tanh(v/v_s)  (002 eq 8)"
    variable = "amplitude x direction of motion, A sgn(v) [m]"
    params = ("K1_A", "d_A")
    units = ("N/m^2", "N/m")
    ref_names = ("A_mean", "x_mean")

    def applies(self, s, c):
        return amplitude_varies(s, c)

    def refs(self, s, c, h):
        return {"A_mean": s.train_mean(s.amplitude[:, c]), "x_mean": s.train_mean(s.x[:, c])}

    def columns(self, g, R, h, out):
        o0, o1 = out
        np.subtract(g.amplitude, R["A_mean"], out=o0)
        np.subtract(g.x, R["x_mean"], out=o1)
        np.multiply(o0, o1, out=o0)
        smooth_sign(g.v, 1e-4, out=o1)
        np.multiply(o1, g.amplitude, out=o1)

    def evidence(self, s, c, h):
        return s.amplitude[:, c] * np.sign(s.v[:, c])


class AsymmetricHardening(Term):
    """Asymmetric hardening (001 Ch 4: the elastic backbone k1 x + k2 x^2 + k3 x^3 of the
    modified asymmetric Bouc-Wen model; k2 makes loading and unloading sides differ,
    k3 hardens). Around the mean elongation the baseline misses

        delta_f = k2 (x - x_mean)^2 + k3 (x - x_mean)^3,   k2 [N/m^2], k3 [N/m^3]

    (fitted on columns scaled by the training std s of x: k2 = k2_scaled / s, k3 =
    k3_scaled / s^2)."""

    model_form = True
    name = "asymmetric"
    label = "asymmetric hardening of the elastic backbone"
    equation = "k2 (x - mean x)^2 + k3 (x - mean x)^3  (001 Ch 4)"
    variable = "elongation x - mean x [m]"
    params = ("k2_scaled", "k3_scaled")
    units = ("N/m", "N/m")
    ref_names = ("x_mean", "x_scale")

    def refs(self, s, c, h):
        xm, sx = elongation_centre_scale(s, c)
        return {"x_mean": xm, "x_scale": sx}

    def columns(self, g, R, h, out):
        o0, o1 = out
        np.subtract(g.x, R["x_mean"], out=o0)          # xi
        np.divide(o0, R["x_scale"], out=o1)            # xi / s
        np.multiply(o0, o1, out=o0)                    # xi^2 / s
        np.multiply(o0, o1, out=o1)                    # xi^3 / s^2

    def physical(self, params, h, s, c):
        sc = self.refs(s, c, h)["x_scale"]
        return {"k2": params["k2_scaled"] / sc, "k3": params["k3_scaled"] / sc ** 2}

    def evidence(self, s, c, h):
        return s.x[:, c] - np.mean(s.x[:, c])
