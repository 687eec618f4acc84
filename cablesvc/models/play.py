"""The stop operator of Prandtl-Ishlinskii hysteresis (Brokate & Sprekels, *Hysteresis and
Phase Transitions*, Springer 1996, Ch 2; Krasnosel'skii & Pokrovskii 1989): the one home
of that law, offline over a record and live tick by tick.

A stop of width r [m] is an elastic-perfectly-plastic element driven by the elongation x:
its play state p follows x with a clearance of r,

    p(t) = min(x(t) + r, max(x(t) - r, p(t - dt))),      s_r(t) = (x(t) - p(t)) / r  in [-1, 1],

so s_r moves with x (elastic) until |x - p| = r and then stays at +-1 (sliding) until the
motion reverses. A weighted sum of stops of several widths is a Prandtl-Ishlinskii
hysteresis: a chain of Jenkins (spring-slider) elements is one exactly, and other
rate-independent loops (a wire or fibre rope's strand friction, a Bouc-Wen loop) are
approximated by one (Brokate & Sprekels, Ch 2). The state starts at p = x on the first
tick (s = 0: a relaxed element). A non-finite x leaves the state as it is and gives a
non-finite s there, offline and live alike.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["stop_columns", "stop_step"]


@numba.njit(cache=True)
def _stops(x, widths, out):                       # pragma: no cover - compiled
    n = x.shape[0]
    for j in range(widths.shape[0]):
        r = widths[j]
        p = x[0]
        for i in range(n):
            xi = x[i]
            if np.isfinite(xi):
                if not np.isfinite(p):
                    p = xi
                if p < xi - r:
                    p = xi - r
                elif p > xi + r:
                    p = xi + r
            out[j, i] = (xi - p) / r


def stop_columns(x: np.ndarray, widths: np.ndarray, out: np.ndarray) -> np.ndarray:
    """The stops s_r (k, N) [-] of widths ``widths`` (k,) [m] over the elongation record
    ``x`` (N,) [m], into ``out`` (k, N), each from a relaxed state at the first finite tick."""
    _stops(np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(widths, dtype=np.float64), out)
    return out


def stop_step(p: np.ndarray, x: np.ndarray, widths: np.ndarray, out: np.ndarray, started: np.ndarray,
              lo: np.ndarray, hi: np.ndarray) -> None:
    """One live tick of the stops: ``p`` (k, lanes, m) [m] the play states (updated in place),
    ``x`` (lanes, m) [m] this tick's elongation, ``widths`` (k, 1, 1) [m]; ``out`` (k, lanes,
    m) [-] gets s_r; ``lo``, ``hi`` (k, lanes, m) scratch. ``started`` (lanes, m) bool marks
    the states that have seen a finite elongation (updated in place): a state starts
    relaxed at its first finite x, as offline. Fixed numpy calls, no allocation."""
    ok = np.isfinite(x)
    np.copyto(p, x, where=ok & ~started)              # (k, lanes, m) <- (lanes, m)
    np.logical_or(started, ok, out=started)
    np.subtract(x, widths, out=lo)
    np.maximum(lo, p, out=lo)
    np.add(x, widths, out=hi)
    np.minimum(hi, lo, out=hi)                        # min(x + r, max(x - r, p))
    np.copyto(p, hi, where=ok)                        # a non-finite x leaves the state
    np.subtract(x, p, out=out)
    np.divide(out, widths, out=out)
