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

__all__ = ["LiveStops", "stop_columns"]


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


class LiveStops:
    """The stops live, tick by tick: play states ``p`` (k, lanes, m) [m] for the widths
    ``widths`` (k,) [m], ``started`` (lanes, m) marking the states that have seen a finite
    elongation (a state starts relaxed at its first finite x, as offline), and scratch
    buffers, so that :meth:`step` is a fixed sequence of numpy calls that allocates
    nothing."""

    def __init__(self, widths: np.ndarray, lanes: int, m: int):
        k = len(widths)
        self.widths = np.asarray(widths, float).reshape(k, 1, 1)
        self.p = np.zeros((k, lanes, m))
        self.started = np.zeros((lanes, m), bool)
        self._lo, self._hi = np.zeros((k, lanes, m)), np.zeros((k, lanes, m))
        self._ok, self._fresh = np.zeros((lanes, m), bool), np.zeros((lanes, m), bool)

    def step(self, x: np.ndarray, out: np.ndarray) -> None:
        """Advance the states with this tick's elongation ``x`` (lanes, m) [m] and write
        s_r (k, lanes, m) [-] into ``out``; a non-finite x leaves its state as it is."""
        p, ok, fresh, lo, hi = self.p, self._ok, self._fresh, self._lo, self._hi
        np.isfinite(x, out=ok)
        np.logical_not(self.started, out=fresh)
        np.logical_and(fresh, ok, out=fresh)
        np.copyto(p, x, where=fresh)                      # (k, lanes, m) <- (lanes, m)
        np.logical_or(self.started, ok, out=self.started)
        np.subtract(x, self.widths, out=lo)
        np.maximum(lo, p, out=lo)
        np.add(x, self.widths, out=hi)
        np.minimum(hi, lo, out=hi)                        # min(x + r, max(x - r, p))
        np.copyto(p, hi, where=ok)
        np.subtract(x, p, out=out)
        np.divide(out, self.widths, out=out)
