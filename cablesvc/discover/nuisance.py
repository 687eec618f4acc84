"""The baseline's own recalibration: the nuisance a named term must beat (issue 15).

An identified baseline is wrong away from its calibration point (another tension, other
amplitudes and rates): a stiffness a few per cent off, a pretension offset, a loop of
another area, a backbone of another curvature. That is baseline mismatch, not missing
physics. Following Kennedy & O'Hagan (J. R. Stat. Soc. B 63, 2001: calibration plus a
discrepancy term) with the discrepancy constrained to the baseline's own state
(Brynjarsdottir & O'Hagan, Inverse Problems 30, 2014: an unconstrained discrepancy absorbs
the physics), :class:`Recalibration` refits, per cable and on the training blocks, the
baseline family's own parameters plus a smooth discrepancy in its own variables:

    delta_f = o + k_s f0 + a_h h + c2 xi^2 / s + c3 xi^3 / s^2 + K1_A (A - mean A) xi + d_A A tanh(v / v_s)

with f0 the baseline force [N], xi = x - mean x the elongation about its training mean
[m] and s its training std [m], h = f0 - P3(x) the baseline's hysteretic part (f0 minus its
least-squares cubic backbone in x on the training ticks) [N], A the reversal amplitude [m]
(002 eq 8) and v_s = 1e-4 m/s. Parameters: o [N] force offset at zero force (pretension),
k_s [-] stiffness scale, a_h [-] loop-area scale, c2, c3 [N] backbone curvature
(001 Ch 4 backbone k2, k3), K1_A [N/m^2] and d_A [N/m] the amplitude dependence of
002 eq 8. Only inputs enter these columns (never the measured force).

The terms that only reshape the baseline's own hysteresis (``amplitude``, ``asymmetric``,
``boucwen``: :attr:`Term.model_form`) and the sensor's offset and gain (which a force
offset and stiffness scale also produce; :mod:`cablesvc.discover.equilibrium` tells them
apart) are inside this nuisance and are not offered as concealed effects.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cablesvc.discover.terms import Signals, Term, _design, smooth_sign

__all__ = ["Recalibration", "hysteretic_part", "describe_recalibration"]


def hysteretic_part(s: Signals, c: int) -> np.ndarray:
    """The baseline's hysteretic part h (N,) [N] of cable ``c``: f0 minus the cubic in the
    elongation that fits f0 best on the training ticks (the backbone)."""
    x = s.x[:, c]
    xm = s.train_mean(x)
    sx = max(float(np.std(x[s.train] - xm)), 1e-12)
    xi = (x - xm) / sx
    V = np.column_stack([np.ones_like(xi), xi, xi ** 2, xi ** 3])
    coef, *_ = np.linalg.lstsq(V[s.train], s.f0[s.train, c], rcond=None)
    return s.f0[:, c] - V @ coef


class Recalibration(Term):
    """Recalibration of the baseline's own parameters plus a smooth discrepancy in its own
    state (see the module docstring for the equation and units). Owns the generic offset
    and gain columns (``pulley`` k0 and ``temperature`` g are held at 0 beside it)."""

    name = "baseline"
    label = "baseline recalibration (its own parameters and a smooth discrepancy in its own state)"
    equation = ("o + k_s f0 + a_h h + c2 xi^2/s + c3 xi^3/s^2 + K1_A (A - mean A) xi + d_A A tanh(v/v_s)"
                "  (002 eq 8, 001 Ch 4; Kennedy & O'Hagan 2001)")
    variable = "baseline force f0 [N]"
    owns_nuisance = True

    def design(self, s, c, h):
        x, f0, A = s.x[:, c], s.f0[:, c], s.amplitude[:, c]
        xi = x - s.train_mean(x)
        sx = max(float(np.std(xi[s.train])), 1e-12)
        cols = [np.ones(s.n), f0, hysteretic_part(s, c), xi ** 2 / sx, xi ** 3 / sx ** 2]
        names = ["o", "k_s", "a_h", "c2", "c3"]
        units = ["N", "-", "-", "N", "N"]
        if float(np.ptp(A)) > 1e-6:
            cols += [(A - s.train_mean(A)) * xi, A * smooth_sign(s.v[:, c], 1e-4)]
            names += ["K1_A", "d_A"]
            units += ["N/m^2", "N/m"]
        return _design(cols, names, units)

    def evidence(self, s, c, h):
        return s.f0[:, c]

    def physical(self, params, h, s, c):
        f0 = s.f0[:, c]
        return {**params, "mean_f0_N": float(np.mean(f0)),
                "offset_at_mean_N": float(params.get("o", 0.0) + params.get("k_s", 0.0) * np.mean(f0))}


def describe_recalibration(params: dict[str, Any]) -> str:
    """Plain words for one cable's recalibration: stiffness, pretension, loop area."""
    parts = [f"stiffness {100.0 * params.get('k_s', 0.0):+.1f} %",
             f"pretension/offset {params.get('o', 0.0):+.2f} N",
             f"loop area {100.0 * params.get('a_h', 0.0):+.0f} %"]
    return ", ".join(parts)
