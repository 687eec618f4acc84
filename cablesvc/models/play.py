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
approximated by one (Brokate & Sprekels, Ch 2). By default the state starts at p = x on
the first finite tick (s = 0: a relaxed element); ``starts`` gives another initial s_0 in
[-1, 1] (p = x - s_0 r). A non-finite x leaves the state as it is and gives a non-finite s
there, offline and live alike.

A recording starts in a state of the loop nobody knows. Stops started in the two extreme
states, s_0 = +1 and -1, give the bounds every other start lies between; they coincide once
the elongation has moved 2 r one way (the loop's memory of its start is wiped out, the
wiping-out property of Preisach and Prandtl-Ishlinskii operators: Mayergoyz, *Mathematical
Models of Hysteresis*, Springer 1991, Ch 1). Half their difference,
d_r = (s_r^+ - s_r^-) / 2 in [0, 1] (:func:`initial_state_columns`), is 1 on the first tick
and 0 once the start is forgotten: a column whose coefficient is the part of the loop's
force its unknown initial state leaves.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["LiveStops", "initial_state_columns", "stop_columns"]


@numba.njit(cache=True)
def _stops(x, widths, starts, out):               # pragma: no cover - compiled
    n = x.shape[0]
    for j in range(widths.shape[0]):
        r = widths[j]
        p = np.nan
        for i in range(n):
            xi = x[i]
            if np.isfinite(xi):
                if not np.isfinite(p):
                    p = xi - starts[j] * r
                if p < xi - r:
                    p = xi - r
                elif p > xi + r:
                    p = xi + r
            out[j, i] = (xi - p) / r


def stop_columns(x: np.ndarray, widths: np.ndarray, out: np.ndarray, starts=None) -> np.ndarray:
    """The stops s_r (k, N) [-] of widths ``widths`` (k,) [m] over the elongation record
    ``x`` (N,) [m], into ``out`` (k, N), each from the state s_0 ``starts`` (k,) [-] in
    [-1, 1] at the first finite tick (default 0: relaxed)."""
    w = np.ascontiguousarray(widths, dtype=np.float64)
    s0 = np.zeros(w.size) if starts is None else np.ascontiguousarray(np.broadcast_to(starts, w.shape), dtype=np.float64)
    _stops(np.ascontiguousarray(x, dtype=np.float64), w, s0, out)
    return out


def initial_state_columns(x: np.ndarray, widths: np.ndarray, out: np.ndarray) -> np.ndarray:
    """d_r = (s_r^+ - s_r^-) / 2 (k, N) [-] into ``out``: half the difference between the
    stops of widths ``widths`` (k,) [m] started at s_0 = +1 and at s_0 = -1 over the
    elongation record ``x`` (N,) [m]; 1 at the first finite tick, 0 once x has moved 2 r one
    way (the start forgotten). See the module."""
    k = len(widths)
    lo = np.empty((k, np.shape(x)[0]))
    stop_columns(x, widths, out, starts=np.ones(k))
    stop_columns(x, widths, lo, starts=-np.ones(k))
    np.subtract(out, lo, out=out)
    np.multiply(out, 0.5, out=out)
    return out


class LiveStops:
    """The stops live, tick by tick: play states ``p`` (k, lanes, m) [m] for the widths
    ``widths`` (k,) [m], ``started`` (lanes, m) marking the states that have seen a finite
    elongation (a state starts at its first finite x in the state ``starts`` (k,) [-],
    default 0: relaxed, as offline), and scratch buffers, so that :meth:`step` is a fixed
    sequence of numpy calls that allocates nothing."""

    def __init__(self, widths: np.ndarray, lanes: int, m: int, starts=None):
        k = len(widths)
        self.widths = np.asarray(widths, float).reshape(k, 1, 1)
        s0 = np.zeros(k) if starts is None else np.broadcast_to(np.asarray(starts, float), (k,))
        #: x - p at the start [m]: s_0 r
        self.offset = (s0.reshape(k, 1, 1) * self.widths).copy()
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
        np.subtract(x, self.offset, out=lo)               # the start p = x - s_0 r
        np.copyto(p, lo, where=fresh)
        np.logical_or(self.started, ok, out=self.started)
        np.subtract(x, self.widths, out=lo)
        np.maximum(lo, p, out=lo)
        np.add(x, self.widths, out=hi)
        np.minimum(hi, lo, out=hi)                        # min(x + r, max(x - r, p))
        np.copyto(p, hi, where=ok)
        np.subtract(x, p, out=out)
        np.divide(out, self.widths, out=out)
