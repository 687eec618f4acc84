"""The terms of a parameter file, live (:class:`TermStack`): the signals the kernel gives them
every tick over (lanes, cables), the amplitude tracker, the creep clock, the dead-time
delay line and each term's live form, with all their state.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from cablesvc.models.reversal import REVERSAL_DEADBAND, LiveReversalAmplitude
from cablesvc.models.terms.base import Term
from cablesvc.models.terms.catalogue import term_class
from cablesvc.models.terms.recalibration import Recalibration
from cablesvc.models.terms.signals import CableView

__all__ = ["TermStack", "DELAY_WINDOW_S"]


#: seconds of history the live dead-time line keeps (the largest dead time discovery fits)
DELAY_WINDOW_S = 0.5


class _DelayLine:
    """The last ``n`` ticks of k (lanes, m) signals with their times, in a doubled ring so
    that the window is always one contiguous, time-ordered slice; :meth:`at` interpolates
    linearly at t - tau per cable exactly as ``np.interp`` does offline (held at the oldest
    value before it, at the newest after it): both taps of every signal and cable come from
    one ``np.take`` at indices (2, k, lanes, m) into the window, written into buffers made
    once."""

    def __init__(self, n: int, k: int, lanes: int, m: int):
        self.n = int(max(n, 2))
        self.t = np.zeros(2 * self.n)
        self.v = np.zeros((2 * self.n, k, lanes, m))
        self.head = 0          # index of the newest sample in [0, n)
        self.started = False
        self._fill = False     # the first tick's row fills the whole window (commit)
        size = k * lanes * m
        #: (k, lanes, m): the flat offset of each signal and cable within one tick's row
        self.offs = (np.arange(size).reshape(k, lanes, m)).astype(np.intp)
        self.size = size
        self.taps = np.zeros((2, m), np.intp)       # the taps' ticks in the window, per cable
        self.tap_off = np.array([[-1], [0]], np.intp)
        self.flat = np.zeros((2, k, lanes, m), np.intp)
        self.tt = np.zeros((2, m))                  # the taps' times
        self.vv = np.zeros((2, k, lanes, m))        # the taps' values
        self.dtab = np.zeros(m)
        self.w = np.zeros(m)
        self.inside = np.zeros(m, bool)

    def slot(self, t: float) -> np.ndarray:
        """Advance by one tick at time ``t`` and return the row (k, lanes, m) to write this
        tick's values into; :meth:`commit` then copies it into the ring's second half."""
        if not self.started:
            self.t.fill(t)
            self.started = True
            self.head = self.n - 1
            self._fill = True
            return self.v[self.head]
        h = (self.head + 1) % self.n
        self.t[h] = self.t[h + self.n] = t
        self.head = h
        self._fill = False
        return self.v[h]

    def commit(self) -> None:
        h = self.head
        if self._fill:                              # the first tick: the whole window holds it
            self.v[...] = self.v[h].copy()
        else:
            np.copyto(self.v[h + self.n], self.v[h])

    def at(self, q: np.ndarray, out: np.ndarray) -> None:
        """Values (k, lanes, m) at times q (m,), into ``out``."""
        lo = self.head + 1
        tw = self.t[lo: lo + self.n]
        j = np.searchsorted(tw, q, side="right")    # tw[j - 1] <= q < tw[j]
        taps = self.taps
        np.add(j, self.tap_off, out=taps)           # j - 1, j
        np.maximum(taps, 0, out=taps)               # (np.clip with int bounds keeps a small cache growing)
        np.minimum(taps, self.n - 1, out=taps)
        np.take(tw, taps, out=self.tt, mode="clip")      # (in range; mode='raise' buffers out)
        np.multiply(taps, self.size, out=taps)
        np.add(taps[:, None, None, :], self.offs, out=self.flat)
        np.take(self.v[lo: lo + self.n], self.flat, out=self.vv, mode="clip")
        ta, tb = self.tt
        np.subtract(tb, ta, out=self.dtab)
        np.greater(self.dtab, 0.0, out=self.inside)
        self.w.fill(0.0)                            # held (both taps one tick): x - xp[j] = 0
        np.subtract(q, ta, out=self.w, where=self.inside)
        va, vb = self.vv
        np.subtract(vb, va, out=out)
        np.divide(out, self.dtab, out=out, where=self.inside)
        np.multiply(out, self.w, out=out)
        np.add(out, va, out=out)                    # np.interp: slope (x - xp[j]) + fp[j]

    def state_dict(self, prefix: str) -> dict[str, np.ndarray]:
        return {prefix + "t": self.t.copy(), prefix + "v": self.v.copy(),
                prefix + "head": np.array([self.head, int(self.started)])}

    def load_state_dict(self, d: dict[str, np.ndarray], prefix: str) -> None:
        if prefix + "t" not in d or d[prefix + "t"].shape != self.t.shape:
            return
        np.copyto(self.t, d[prefix + "t"])
        np.copyto(self.v, d[prefix + "v"])
        self.head, started = (int(v) for v in d[prefix + "head"])
        self.started = bool(started)


class TermStack:
    """The terms of a parameter file, live: every tick, from the kernel's baseline force f0,
    elongation x, motor length, wrap angle, free length and temperature (lanes, m), the
    sum of the terms' forces (lanes, m) [N].

    It keeps the state the terms need: the previous x and motor length (dx/dt and the
    sliding speed over the pulley by backward differences, 0 on the first tick), the
    amplitude tracker, the creep clock (time since the recording's start that the parameter
    file gives as ``terms_clock_origin``, else since the first tick), the dead-time delay line
    (f0, x, dx/dt and A of the last :data:`DELAY_WINDOW_S` s at up to ``max_rate_hz``; the
    other terms of a cable with a dead time see them delayed by its tau, as offline) and
    each term's own state (Bouc-Wen z). All of it is in :meth:`state_dict`."""

    def __init__(self, terms: list[Term], tables: dict[str, dict[str, Any]], m: int, lanes: int = 1,
                 max_rate_hz: float = 2000.0, clock_origin: Optional[float] = None):
        self.m, self.lanes = m, lanes
        self.max_rate_hz = float(max_rate_hz)
        self.delay = next((t for t in terms if t.delays_input), None)
        self.live = [t.live(tables.get(t.name, {}), lanes, m) for t in terms if not t.delays_input]
        shp = (lanes, m)
        # every term's rows (and the dead time's f0(t - tau) - f0(t), coefficient 1) in one
        # buffer: the force is one multiply and one sum over the rows per tick
        n_dead = 0 if self.delay is None else 1
        rows = n_dead + sum(lt.rows for lt in self.live)
        self.cols = np.zeros((rows, lanes, m))
        self.coef = np.ones((rows, 1, m))
        self.prod = np.zeros_like(self.cols)
        r = n_dead
        for lt in self.live:
            lt.bind(self.cols[r: r + lt.rows], self.coef[r: r + lt.rows])
            r += lt.rows
        self.acc = np.zeros(shp)
        self.v = np.zeros(shp)
        self.v_slide = np.zeros(shp)
        self.x_prev = np.zeros(shp)
        self.ml_prev = np.zeros(shp)
        self.temp = np.full(shp, np.nan)            # (lanes, m) as the other signals: ufuncs'
        self.clock = np.zeros(shp)                  # fast path (no broadcasting) at lanes = 1
        #: the creep clock's zero [s, in the ticks' time base]: the recording's start when the
        #: parameter file gives it (``terms_clock_origin``), else the first tick
        self.origin = None if clock_origin is None else float(clock_origin)
        self.t0: Optional[float] = None
        self.t_prev = 0.0
        self.rev = LiveReversalAmplitude(lanes, m, REVERSAL_DEADBAND)
        #: what the terms see: f0, x, dx/dt and A of this tick, or with a dead time, the delay
        #: line's (f0, x, dx/dt, A)(t - tau), which :meth:`_DelayLine.at` writes in place
        seen = np.zeros((4,) + shp)
        if self.delay is not None:
            tau = np.asarray(tables.get(self.delay.name, {}).get("tau", np.zeros(m)), float).reshape(-1)
            self.tau = np.clip(tau, 0.0, DELAY_WINDOW_S)
            self.line = _DelayLine(int(math.ceil(DELAY_WINDOW_S * max_rate_hz)) + 2, 4, lanes, m)
            self.delayed = seen
            self.q = np.zeros(m)
        self.g = CableView(t=self.clock, f0=seen[0], x=seen[1], v=seen[2] if self.delay is not None else self.v,
                           v_slide=self.v_slide, wrap=np.zeros(shp), free_length=np.zeros(shp),
                           temperature=self.temp, amplitude=seen[3])

    @classmethod
    def from_params(cls, identification: dict[str, Any], m: int, lanes: int = 1,
                    max_rate_hz: float = 2000.0) -> Optional["TermStack"]:
        """The stack of a parameter file's ``[identification]`` section: the baseline's
        recalibration (``term_baseline``) and the ``discovered_terms``; None when it has
        neither."""
        names = [n for n in [Recalibration.name] if f"term_{n}" in identification]
        names += [n for n in identification.get("discovered_terms", []) if n not in names]
        if not names:
            return None
        terms = [term_class(n) for n in names]
        tables = {n: dict(identification.get(f"term_{n}", {})) for n in names}
        origin = identification.get("terms_clock_origin")
        return cls(terms, tables, m, lanes, max_rate_hz, None if origin is None else float(origin))

    def prime(self, t: float, x: np.ndarray, motor_length: np.ndarray) -> None:
        """Start a stack that has seen no tick from the previous tick's time, elongation and
        motor length (a reload mid-run: the kernel before it ran without these terms), so
        that the first tick's dx/dt and sliding speed are the real ones, not 0. No effect on
        a stack that has run."""
        if self.t0 is not None:
            return
        self.t0 = float(t) if self.origin is None else self.origin
        self.t_prev = float(t)
        self.x_prev[...] = x
        self.ml_prev[...] = motor_length

    def step(self, t: float, f0: np.ndarray, x: np.ndarray, motor_length: np.ndarray, wrap: np.ndarray,
             free_length: np.ndarray, temperature: Optional[float]) -> np.ndarray:
        """The terms' force (lanes, m) [N] at this tick (a buffer the next tick overwrites)."""
        first = self.t0 is None
        if first:
            self.t0 = t if self.origin is None else self.origin
            self.t_prev = t
            np.copyto(self.x_prev, x)
            np.copyto(self.ml_prev, motor_length)
        dt = t - self.t_prev
        inv = 1.0 / dt if dt > 0 else 0.0
        np.subtract(x, self.x_prev, out=self.v)
        np.multiply(self.v, inv, out=self.v)
        np.subtract(self.ml_prev, motor_length, out=self.v_slide)
        np.multiply(self.v_slide, inv, out=self.v_slide)
        np.copyto(self.x_prev, x)
        np.copyto(self.ml_prev, motor_length)
        self.t_prev = t
        self.clock.fill(t - self.t0)
        self.temp.fill(np.nan if temperature is None else temperature)
        A = self.rev.step(x)
        g = self.g
        np.copyto(g.wrap, wrap)
        np.copyto(g.free_length, free_length)
        if self.delay is not None:
            rel = t - self.t0                          # relative times, as offline (s.t - t[0])
            row = self.line.slot(rel)
            np.copyto(row[0], f0)
            np.copyto(row[1], x)
            np.copyto(row[2], self.v)
            np.copyto(row[3], A)
            self.line.commit()
            np.subtract(rel, self.tau, out=self.q)
            self.line.at(self.q, self.delayed)
            np.subtract(g.f0, f0, out=self.cols[0])    # f0(t - tau) - f0(t)
        else:
            np.copyto(g.f0, f0)
            np.copyto(g.x, x)
            np.copyto(g.amplitude, A)
        for lt in self.live:
            lt.write(g)
        # np.add.reduce is what np.sum calls, without its Python wrapper (same bits)
        np.multiply(self.cols, self.coef, out=self.prod)
        np.add.reduce(self.prod, axis=0, out=self.acc)
        return self.acc

    def state_dict(self) -> dict[str, np.ndarray]:
        if self.t0 is None:
            return {}
        d = {"t0": np.array([self.t0, self.t_prev]), "x_prev": self.x_prev.copy(), "ml_prev": self.ml_prev.copy()}
        d.update(self.rev.state_dict("rev."))
        if self.delay is not None:
            d.update(self.line.state_dict("delay."))
        for lt in self.live:
            d.update({f"{lt.term.name}.{k}": v for k, v in lt.state_dict().items()})
        return d

    def load_state_dict(self, d: dict[str, np.ndarray]) -> None:
        if "t0" not in d:
            return
        self.t0, self.t_prev = (float(v) for v in d["t0"])
        np.copyto(self.x_prev, d["x_prev"])
        np.copyto(self.ml_prev, d["ml_prev"])
        self.rev.load_state_dict(d, "rev.")
        if self.delay is not None:
            self.line.load_state_dict(d, "delay.")
        for lt in self.live:
            pre = f"{lt.term.name}."
            lt.load_state_dict({k[len(pre):]: v for k, v in d.items() if k.startswith(pre)})
