"""Polynomial hysteresis F = g(x) + h(x) sgn(x') (eqs 4-7 of 002)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cablesvc.models.base import CableModel, ModelParameterError, ModelState, is_int
from cablesvc.models.space import FitStats, Space, identity
from cablesvc.models.reversal import REVERSAL_DEADBAND, flip, track_reversals


def _odd_degree(v) -> bool:
    """The polynomial's degree n_p is an odd integer >= 1 (n_g = n_p, n_h = n_p - 1)."""
    return is_int(v) and v >= 1 and v % 2 == 1


@dataclass
class PolynomialState(ModelState):
    extremum: np.ndarray       # running extremum of the current half-cycle [m]
    direction: np.ndarray      # sgn(x') with a dead-band: +1 rising, -1 falling


class PolynomialHysteresis(CableModel):
    """Polynomial hysteresis of 002, eqs 4-7.

    Upper branch (x' > 0) ``F_U = sum_i a_i xi^i`` (eq 4), lower branch (x' < 0)
    ``F_L = sum_i (-1)^(i+1) a_i xi^i`` (eq 5), combined (eq 6) as
    ``F = g(xi) + h(xi) sgn(x')`` with ``g = a1 xi + a3 xi^3 + ...`` (odd powers) and
    ``h = a0 + a2 xi^2 + ...`` (even powers), eq 7. (The text of eq 7 prints ``g = a1 +
    ...``; g = (F_U + F_L)/2 from eqs 4-5 has the odd terms a1*xi, a3*xi^3, which is what
    is implemented.) ``xi = x - x_center`` [m]; a_i in N/m^i. ``degree`` n_p must be odd
    (n_g = n_p, n_h = n_p - 1).

    sgn(x') switches only when the elongation has moved back by more than
    ``reversal_deadband`` [m] from the extremum of the current half-cycle
    (:mod:`cablesvc.models.reversal`), so a cable at rest stays on its branch and
    sensor or bus quantisation does not flip it.
    """

    name = "polynomial"
    param_docs = {"x_center": "elongation the polynomial is centred on [m]",
                  "reversal_deadband": "motion back from the last extremum that counts as a reversal [m]"}

    stiffness_params = ("a1",)       # a1 of eqs 4-7 of 002

    @classmethod
    def file_options(cls):
        return ("degree",)

    @classmethod
    def file_param_names(cls):
        return None                    # a0..a<degree>: checked when built, with the degree

    @classmethod
    def option_problem(cls, key, value, options):
        if key == "degree" and not _odd_degree(value):
            return f"options.degree: must be an odd integer >= 1, got {value!r}"
        return None

    @classmethod
    def search_space(cls, s: FitStats, *, degree: int = 3) -> Space:
        """``a0..a<degree>`` and ``x_center`` (g has only odd powers, so the pretension needs
        x_center as the zero-force elongation), searched around the data's scales."""
        K, x, f = s.K, s.x, s.f
        names = [f"a{i}" for i in range(degree + 1)] + ["x_center"]
        X = np.maximum(np.abs(x - s.x0z).max(axis=0), 1e-6)
        fmax = np.maximum(np.abs(f).max(axis=0), 1.0)
        slb = np.empty((K, degree + 2))
        sub = np.empty((K, degree + 2))
        for i in range(degree + 1):
            sc = 2.0 * fmax / X ** i
            slb[:, i], sub[:, i] = -sc, sc
        slb[:, 0], sub[:, 0] = 0.0, 0.5 * s.fr                   # half-width of the friction band
        slb[:, 1], sub[:, 1] = 0.0, 3.0 * s.kk                   # linear stiffness
        d = np.maximum(4 * s.xs, 0.5 * np.abs(s.xm - s.x0z))
        slb[:, -1], sub[:, -1] = s.x0z - d, s.x0z + d
        start = np.zeros((K, degree + 2))
        start[:, 1] = s.kk
        start[:, -1] = s.x0z
        return Space(cls.name, names, ["N"] + [f"N/m^{i}" for i in range(1, degree + 1)] + ["m"], slb, sub,
                     identity, identity, np.full_like(slb, -np.inf), np.full_like(sub, np.inf), {}, start,
                     options={"degree": int(degree)},
                     notes=[f"polynomial (degree {degree}): a0..a{degree} and x_center identified"])

    @classmethod
    def unfitted_values(cls, m, ea, length, names):
        """Zero coefficients but a1 = E*A / L: the linear elastic cable."""
        values = {nm: np.zeros(m) for nm in names}
        values["a1"] = np.asarray(ea, float) / length
        return values

    def __init__(self, shape=(1, 1), degree: int = 3, **params):
        if not _odd_degree(degree):
            raise ModelParameterError(f"polynomial: degree must be an odd integer >= 1, got {degree!r}")
        self.degree = int(degree)
        self.param_names = tuple(f"a{i}" for i in range(degree + 1)) + ("x_center", "reversal_deadband")
        self.defaults = {f"a{i}": 0.0 for i in range(degree + 1)} | {"x_center": 0.0,
                                                                    "reversal_deadband": REVERSAL_DEADBAND}
        self.param_docs = {f"a{i}": f"coefficient of xi^{i} [N/m^{i}]" for i in range(degree + 1)} | dict(
            PolynomialHysteresis.param_docs)
        super().__init__(shape, **params)
        self._xi = np.empty(self.shape)
        self._xi2 = np.empty(self.shape)
        self._g = np.empty(self.shape)
        self._h = np.empty(self.shape)
        self._back = np.empty(self.shape)
        self._rev = np.empty(self.shape, dtype=bool)
        self._odd = [self.params[f"a{i}"] for i in range(1, degree + 1, 2)]
        self._even = [self.params[f"a{i}"] for i in range(0, degree + 1, 2)]

    def check_params(self) -> None:
        if np.any(self.params["reversal_deadband"] < 0):
            raise ModelParameterError("polynomial: reversal_deadband must be >= 0 [m]")

    def create_state(self, x0=0.0) -> PolynomialState:
        return PolynomialState(extremum=self._x0(x0), direction=np.ones(self.shape))

    def step(self, state: PolynomialState, x, dt, l0=None):
        xi, xi2, g, h = self._xi, self._xi2, self._g, self._h
        track_reversals(x, state.direction, state.extremum, self.params["reversal_deadband"], self._back, self._rev)
        flip(x, state.direction, state.extremum, self._rev, self._back)
        np.subtract(x, self.params["x_center"], xi)
        np.multiply(xi, xi, xi2)
        # g = xi * (a1 + xi^2 (a3 + xi^2 (...)))  (Horner in xi^2)
        odd, even = self._odd, self._even
        np.copyto(g, odd[-1])
        for a in odd[-2::-1]:
            np.multiply(g, xi2, g)
            np.add(g, a, g)
        np.multiply(g, xi, g)
        np.copyto(h, even[-1])
        for a in even[-2::-1]:
            np.multiply(h, xi2, h)
            np.add(h, a, h)
        np.multiply(h, state.direction, h)
        np.add(g, h, self.force)
        return self.force
