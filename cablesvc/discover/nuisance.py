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
              + sum_a (c_ra + c_ra_e E) sgn(v) (|v| / v_ref)^a,   a = 0, 0.25
              [+ sum_r (c_sr s_r(x) + c_ir d_r(x)),   r = 0.3, 1, 3 mm: where most cables show a
               rate-independent loop]

with f0 the baseline force [N], xi = x - mean x the elongation about its training mean
[m] and s its training std [m], h = f0 - P3(x) the baseline's hysteretic part (f0 minus its
least-squares cubic backbone in x on the training ticks) [N], A the reversal amplitude [m]
(002 eq 8) and v_s = 1e-4 m/s. Parameters: o [N] force offset at zero force (pretension),
k_s [-] stiffness scale, a_h [-] loop-area scale, c2, c3 [N] backbone curvature
(001 Ch 4 backbone k2, k3), K1_A [N/m^2] and d_A [N/m] the amplitude dependence of
002 eq 8. The last columns are 002 eq 8's damping rate law, sgn(v) |v|^a at a = 0 (dry
friction) and 0.25, with its level free instead of fixed by the loop area over the reversal
amplitude and frequency: a level c_ra [N at v_ref = 1 mm/s] and one growing with the
elongation's envelope E [mm] (half the range x has covered since the first tick, another
amplitude estimate than the last reversal points), c_ra_e [N/mm]. An identified baseline's
damping is the loop area of millimetre sines at one working point; along a trajectory its
amplitude normalisation is the least reliable part of the law (issue 15 lists "another
amplitude estimator" among the model-form errors). The exponents stay well below a viscous
force's 1, so that a Kelvin-Voigt damper keeps a part of its own. Only inputs enter these columns (never the
measured force). The bracketed columns are Prandtl-Ishlinskii stops (elastic-perfectly-plastic
elements of widths r driven by x, :mod:`cablesvc.models.play`), a rate-independent loop that
002 eq 8 cannot draw (a rope's strand slip), with the loop's unknown state at the
recording's start (d_r, 1 on the first tick, 0 once the elongation has moved 2 r one way);
:func:`loop_gate` adds them on every cable of a
robot where most of its cables gain from them on held-out blocks (the model form is
the cable type's, on every cable; a concealed effect is on some).

The terms that only reshape the baseline's own hysteresis (``amplitude``, ``asymmetric``,
``boucwen``: :attr:`Term.model_form`) and the sensor's offset and gain (which a force
offset and stiffness scale also produce; :mod:`cablesvc.discover.equilibrium` tells them
apart) are inside this nuisance and are not offered as concealed effects.

The class itself lives with the other terms in :mod:`cablesvc.models.terms` (its offline
and live forms in one place): the kernel runs the recalibration a discovery writes
(``term_baseline`` in the parameter file) every tick, like any discovered term.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cablesvc.models.terms import Recalibration, hysteretic_part
from cablesvc.models.terms.recalibration import DAMPING_LEVELS, DAMPING_PER_MM, INITIAL, STOP_WIDTHS, STOPS

__all__ = ["Recalibration", "hysteretic_part", "describe_recalibration", "loop_gate"]


def loop_gate(s: Any, r: np.ndarray, noise: np.ndarray, blocks: list, alpha: float = 0.05,
              cache: Any = None) -> dict[str, Any]:
    """Whether this robot's recalibration takes the rate-independent loop (the stops of
    :class:`Recalibration`): on each cable, the recalibration without the stops against the
    one with them, leave-one-block-out on ``blocks`` (the screen's units), one-sided
    Wilcoxon signed-rank test of the per-block gains; the loop is used on every cable when it
    helps at level ``alpha`` on most of them (more than half). The loop is its stops and their
    state at the recording's start: asked about the stops alone, the gate took the loop on
    fewer recordings of a robot whose cables all have one (docs/discovery.md, "The loop's
    state at the recording's start"). The baseline's model form is the
    cable type's and lies on every cable; a concealed effect lies on some, so it cannot
    bring a loop into the nuisance by itself, and a robot whose cables show no loop
    (the development bench's truth law) keeps the recalibration without it. Returns
    {"used", "cables" (those where it helped), "p" and "gain" per cable [noise variances],
    "alpha", "widths_mm"}. ``cache``: the discovery's design cache, so that the variant
    chosen is not built again."""
    from cablesvc.discover.evidence import block_gain_test, loo_errors
    from cablesvc.discover.select import DesignCache
    with_loop, without = Recalibration(stops=True), Recalibration(stops=False)
    cache = cache if cache is not None else DesignCache()
    p, gain = [], []
    for c in range(s.m):
        e1 = loo_errors(s, c, r[:, c], [with_loop], [{}], blocks, cache)
        e0 = loo_errors(s, c, r[:, c], [without], [{}], blocks, cache)
        t = block_gain_test(e0, e1, float(noise[c]))
        p.append(float(t["p"]))
        gain.append(float(t["gain"]))
    helped = [c for c in range(s.m) if p[c] < alpha]
    return {"used": 2 * len(helped) > s.m, "cables": helped, "p": p, "gain": gain, "alpha": float(alpha),
            "widths_mm": [1e3 * w for w in STOP_WIDTHS]}


def describe_recalibration(params: dict[str, Any]) -> str:
    """Plain words for one cable's recalibration: stiffness, pretension, loop area, damping."""
    parts = [f"stiffness {100.0 * params.get('k_s', 0.0):+.1f} %",
             f"pretension/offset {params.get('o', 0.0):+.2f} N",
             f"loop area {100.0 * params.get('a_h', 0.0):+.0f} %"]
    level = sum(params.get(n, 0.0) for n in DAMPING_LEVELS)
    per_mm = sum(params.get(n, 0.0) for n in DAMPING_PER_MM)
    if level or per_mm:
        parts.append(f"damping at 1 mm/s {level:+.2f} N and {per_mm:+.2f} N per mm of envelope")
    loop = [params.get(n, 0.0) for n in STOPS]
    if any(loop):
        parts.append("rate-independent loop " + ", ".join(f"{v:+.2f} N at {1e3 * w:g} mm" for v, w in zip(loop, STOP_WIDTHS)))
        start = sum(params.get(n, 0.0) for n in INITIAL)
        if start:
            parts.append(f"its state at the recording's start {start:+.2f} N")
    return ", ".join(parts)
