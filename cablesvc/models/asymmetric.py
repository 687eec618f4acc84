"""Modified, asymmetric Bouc-Wen model of the wire-rope isolator report (001, Ch 4)."""

from __future__ import annotations

import numpy as np

from cablesvc.models.boucwen import BoucWenFamily, BoucWenState
from cablesvc.models.space import (FitStats, Space, hysteresis_search_columns, hysteresis_to_model,
                                   hysteresis_to_search)


#: the state is the Bouc-Wen family's (last elongation and z)
AsymmetricState = BoucWenState


class AsymmetricBoucWen(BoucWenFamily):
    """Modified asymmetric Bouc-Wen model with parameters (b, c, alpha, beta, gamma, n, k1, k2, k3).

    The report 001 (Ch 4, eqs 4.1-4.3, after Ni, Ko & Wong) describes the model as a
    symmetric Bouc-Wen hysteretic variable z "modulated" by a nonlinear elastic stiffness,
    with a nonlinear spring force F1(x) and a shaping function F2 that produces the
    hardening overlap of the loading envelope. Its equation images are lost; the form
    chosen and implemented here is::

        F  = F1(xi) + F2(xi) z                              [N]
        F1 = k1 xi + k2 xi^2 + k3 xi^3                      (nonlinear spring, eq 4.3a-b)
        F2 = b + c xi^2                                     (shaping function, eq 4.3c)
        z' = alpha xi' - beta |xi'| |z|^(n-1) z - gamma xi' |z|^n        (eq 4.1 / 4.3d)

    with xi = x - x_center. z' is eq 1 of 000 with k_d = alpha, beta_000 = beta,
    gamma_000 = gamma, so z is bounded by (alpha/(beta+gamma))^(1/n) for beta+gamma > 0
    (the "finite ultimate value z_max" of 001 Sec 4.1). Why this form gives the features
    of 001 Sec 3.4:

    * the even term k2 xi^2 (k2 > 0) adds force in tension and removes it in compression:
      the loop is asymmetric and, relative to the linear part, the asymmetry grows with
      amplitude (k2 A^2 / (k1 A) ~ A);
    * the tangent stiffness k1 + 2 k2 xi + 3 k3 xi^2 grows for xi > 0 (hardening in
      tension) and, for k2 > 0 and small k3, falls for xi < 0 (softening in compression);
    * once z saturates at +-z_max, F2(xi) z = (b + c xi^2) z_max grows with xi^2 on every
      loading branch, so loading branches of different amplitudes run on one hardening
      envelope (the "hardening overlapping loading envelope").

    Units: x, xi [m]; k_i [N/m^i]; b dimensionless, c [1/m^2]; alpha dimensionless in the
    sense z' = alpha xi' (z then has units of m times alpha's unit: here alpha [N/m] so z
    is in N... when z is in N F2 is dimensionless); beta, gamma [1/(m N^(n-1))]; n [-].
    Integrated as :class:`~cablesvc.models.boucwen.BoucWenIntegrator`.
    """

    name = "asymmetric"
    param_names = ("b", "c", "alpha", "beta", "gamma", "n", "k1", "k2", "k3", "x_center")
    defaults = {"x_center": 0.0, "k2": 0.0, "k3": 0.0, "c": 0.0}
    param_docs = {
        "b": "constant part of the shaping function F2 [-]", "c": "quadratic part of F2 [1/m^2]",
        "alpha": "hysteretic stiffness at z = 0 [N/m]", "beta": "shape parameter [1/(m N^(n-1))]",
        "gamma": "shape parameter [1/(m N^(n-1))]", "n": "smoothness exponent [-]",
        "k1": "linear stiffness [N/m]", "k2": "quadratic stiffness [N/m^2]", "k3": "cubic stiffness [N/m^3]",
        "x_center": "elongation where xi = 0 [m]",
    }

    hysteretic_stiffness = "alpha"
    stiffness_params = ("k1",)          # k1 of 001 eq 4.3
    nonnegative_params = ("alpha",)

    @classmethod
    def search_space(cls, s: FitStats, *, degree: int = 3) -> Space:
        """``c, alpha, beta, gamma, n, k1, k2, k3, x_center`` (alpha, beta as log10, gamma as
        gamma / beta) with ``b = 1`` fixed: scaling z by s and (b, c) by 1/s (alpha by s, beta
        and gamma by s^(1-n)) leaves the force unchanged, so only the products are
        identifiable."""
        K, x, kk = s.K, s.x, s.kk
        names = ["c", "alpha", "beta", "gamma", "n", "k1", "k2", "k3", "x_center"]
        X = np.maximum(np.abs(x - s.x0z).max(axis=0), 1e-6)
        d = np.maximum(4 * s.xs, 0.5 * np.abs(s.xm - s.x0z))
        hlo, hhi = hysteresis_search_columns(s)
        slb = np.column_stack([-1 / X ** 2, hlo, np.zeros(K), -kk / X, -kk / X ** 2, s.x0z - d])
        sub = np.column_stack([1 / X ** 2, hhi, 3 * kk, kk / X, kk / X ** 2, s.x0z + d])
        lb = np.column_stack([np.full(K, -np.inf), np.zeros(K), np.zeros(K), np.full(K, -np.inf), np.full(K, 0.3)]
                             + [np.full(K, -np.inf)] * 4)
        ub = np.column_stack([np.full(K, np.inf)] * 4 + [np.full(K, 6.0)] + [np.full(K, np.inf)] * 4)
        start = hysteresis_to_model(0.5 * (slb + sub))
        return Space(cls.name, names, ["1/m^2", "N/m", "1/(m N^(n-1))", "1/(m N^(n-1))", "-", "N/m", "N/m^2",
                                       "N/m^3", "m"], slb, sub, hysteresis_to_model, hysteresis_to_search, lb, ub,
                     {"b": np.ones(K)}, start,
                     notes=["asymmetric: b = 1 fixed (z -> s z with b, c -> b/s, c/s, alpha -> s alpha and "
                            "beta, gamma -> s^(1-n) beta, gamma leaves the force unchanged)"])

    @classmethod
    def unfitted_values(cls, m, ea, length, names):
        """As the Bouc-Wen family's, with b = 0 (no shaping of z)."""
        values = super().unfitted_values(m, ea, length, names)
        values["b"] = np.zeros(m)
        return values

    def check_params(self):
        super().check_params()
        self._s = np.empty(self.shape)

    def _force(self, z):
        p, xi, t, s = self.params, self._xi, self._t, self._s
        # F1 = xi (k1 + xi (k2 + xi k3))
        np.multiply(xi, p["k3"], t)
        np.add(t, p["k2"], t)
        np.multiply(t, xi, t)
        np.add(t, p["k1"], t)
        np.multiply(t, xi, t)
        # F2 z = (b + c xi^2) z
        np.multiply(xi, xi, s)
        np.multiply(s, p["c"], s)
        np.add(s, p["b"], s)
        np.multiply(s, z, s)
        np.add(t, s, self.force)
