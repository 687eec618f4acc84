"""Linear elastic cable with a smooth transition into slack (eq 3 of 002)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cablesvc.models.base import CableModel, ModelParameterError, ModelState
from cablesvc.models.space import FitStats, Space, column


def smooth_slack(x: np.ndarray, width: np.ndarray, out: np.ndarray, tmp: np.ndarray) -> np.ndarray:
    """C1 ramp: ``x`` for x >= w, 0 for x <= -w, ``(x + w)^2 / (4 w)`` in between [m].

    Replaces the kink of eq 3 of 002 (f = c*dl for dl > 0, 0 otherwise), which the paper
    notes gives numerical problems at dl = 0, by a quadratic blend of half-width ``w``.
    Outside the band it is exactly eq 3. Written with ``out=`` only (no temporaries):
    ramp = (clip(x, -w, w) + w)^2 / (4 w) + max(x - w, 0).
    """
    np.maximum(x, -width, out=tmp)
    np.minimum(tmp, width, out=tmp)          # y = clip(x, -w, w)
    np.add(tmp, width, out=tmp)
    np.multiply(tmp, tmp, out=tmp)
    np.divide(tmp, width, out=tmp)
    np.multiply(tmp, 0.25, out=tmp)          # (y + w)^2 / (4w)
    np.subtract(x, width, out=out)
    np.maximum(out, 0.0, out=out)            # max(x - w, 0)
    np.add(out, tmp, out=out)
    return out


@dataclass
class LinearState(ModelState):
    x_prev: np.ndarray


class LinearElastic(CableModel):
    """Linear elastic cable, eq 3 of 002: ``f = c * x`` for x > 0, slack otherwise.

    Stiffness ``c = ea / l0`` [N/m] with ``ea`` the axial stiffness E*A [N] and ``l0`` the
    unstretched free length [m] passed to ``step``; when ``step`` gets no ``l0`` the
    parameter ``l_ref`` [m] is used. The slack transition is the C1 quadratic blend of
    :func:`smooth_slack` with half-width ``slack_width`` [m]. No memory: the state only
    keeps the last elongation (for diagnostics).
    """

    name = "linear"
    param_names = ("ea", "l_ref", "slack_width")
    defaults = {"l_ref": 1.0, "slack_width": 1e-4}
    param_docs = {
        "ea": "axial stiffness E*A [N]",
        "l_ref": "unstretched length used when step() gets no l0 [m]",
        "slack_width": "half-width of the smooth slack transition [m]",
    }
    stiffness_params = ("ea",)      # eq 3 of 002
    hysteretic = False
    has_nominal = True

    @classmethod
    def nominal(cls, ea, cable_length):
        """E*A of the robot file; ``l0`` is the motor length, so the free length is unused."""
        return {"params": {"ea": np.asarray(ea, float).tolist()}, "identification": {"nominal": True}}

    @classmethod
    def search_space(cls, s: FitStats, *, degree: int = 3) -> Space:
        """``ea`` [N] searched as log10 within a factor 5 of the slope times the mean motor
        length, bounded to a factor 1000 in least squares; ``slack_width`` fixed at its
        default, ``l_ref`` unused (the motor length is passed as l0, as the kernel does)."""
        ea0 = s.kk * np.mean(s.l0, axis=0)
        lo, hi = np.log10(ea0 / 5), np.log10(ea0 * 5)
        return Space(cls.name, ["ea"], ["N"], column(lo), column(hi), lambda S: 10.0 ** S, lambda V: np.log10(V),
                     column(ea0 * 1e-3), column(ea0 * 1e3), {}, column(ea0),
                     notes=["linear: ea identified; slack_width fixed at its default; l0 = motor length"])

    @classmethod
    def unfitted_values(cls, m, ea, length, names):
        return {"ea": np.asarray(ea, float).copy()}

    def check_params(self) -> None:
        for p in ("ea", "l_ref", "slack_width"):
            if np.any(self.params[p] <= 0):
                raise ModelParameterError(f"linear: {p} must be > 0")
        self._tmp = np.empty(self.shape)
        self._ramp = np.empty(self.shape)

    def create_state(self, x0=0.0) -> LinearState:
        return LinearState(x_prev=self._x0(x0))

    def step(self, state: LinearState, x, dt, l0=None):
        smooth_slack(x, self.params["slack_width"], self._ramp, self._tmp)
        np.divide(self.params["ea"], self.params["l_ref"] if l0 is None else l0, out=self._tmp)
        np.multiply(self._ramp, self._tmp, out=self.force)
        np.copyto(state.x_prev, x)
        return self.force
