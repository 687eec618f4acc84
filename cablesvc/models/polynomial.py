"""Polynomial hysteresis F = g(x) + h(x) sgn(x') (eqs 4-7 of 002)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cablesvc.models.base import CableModel, ModelParameterError, ModelState
from cablesvc.models.reversal import REVERSAL_DEADBAND, flip, track_reversals


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

    def __init__(self, shape=(1, 1), degree: int = 3, **params):
        if (isinstance(degree, (bool, np.bool_)) or not isinstance(degree, (int, np.integer))
                or degree < 1 or degree % 2 == 0):
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
