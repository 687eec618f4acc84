"""Maxwell branches: a spring in series with a dashpot, the rope's viscoelastic relaxation
(offline columns of a model-form alternative, :class:`cablesvc.models.terms.Recalibration`).

A branch of relaxation time tau [s] stretched by the elongation x carries the force
k_m y with dy/dt = dx/dt - y / tau: y is x minus its exponential average over the last
tau seconds, x - LP_tau(x), so a step of x decays as exp(-t/tau) (a polymer rope's force
relaxing after a move, seconds to minutes; 002 Fig 6 shows the slow end of it as drift).
:func:`relaxation_columns` integrates it exactly for a piecewise-constant x over each
tick's own time step (gaps in the record included), started relaxed (y = 0) at the first
finite tick; a non-finite x leaves the state as it was.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["relaxation_columns"]


@numba.njit(cache=True)
def _relax(t, x, taus, out):                       # pragma: no cover - compiled
    n = x.shape[0]
    for j in range(taus.shape[0]):
        started = False
        lp = 0.0                                   # the dashpot's end: x's exponential average
        xp = 0.0                                   # x held since the last finite tick
        tp = 0.0
        y = 0.0
        for i in range(n):
            xi = x[i]
            if np.isfinite(xi):
                if started:
                    a = np.exp(-(t[i] - tp) / taus[j])
                    lp = a * lp + (1.0 - a) * xp
                else:
                    lp = xi
                    started = True
                xp = xi
                tp = t[i]
                y = xi - lp
            out[j, i] = y


def relaxation_columns(t: np.ndarray, x: np.ndarray, taus: np.ndarray, out: np.ndarray) -> np.ndarray:
    """y_tau = x - LP_tau(x) (k, N) [unit of x] into ``out`` for the relaxation times
    ``taus`` (k,) [s] over the record ``x`` (N,) at times ``t`` (N,) [s] (see the module)."""
    _relax(np.ascontiguousarray(t, dtype=np.float64), np.ascontiguousarray(x, dtype=np.float64),
           np.ascontiguousarray(taus, dtype=np.float64), out)
    return out
