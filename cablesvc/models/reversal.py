"""Direction of motion with a dead-band: when has the elongation really turned back?

The polynomial (002 eqs 4-7) and amplitude-dependent (002 eq 8) models switch branch on
sgn(x'), and the amplitude model also takes A and the frequency from the last reversal
points. Taking sgn(x') from the sign of each tick's increment makes every sensor or bus
quantisation step a "reversal": a 10 nm length quantum on a CAN bus flips the branch, and
the amplitude estimate collapses to the size of the noise.

Here a reversal is declared only when the elongation has moved back by more than a
dead-band ``delta`` [m] from the running extremum of the current half-cycle, and the
reversal point is that extremum (not the sample where the turn was noticed), so the
amplitude estimate is exact up to the noise on the extremum itself. This is the same
rule :func:`reversal_points` applies offline (below). Choose
``delta`` above the peak-to-peak noise of the elongation and well below the smallest
amplitude of interest; the default, 1 um, is 1 % of the 0.1 mm amplitudes of 002 Sec 4
and ten times the quantisation of the shipped DBC.

The rule, in full: no direction until x has moved by ``delta`` from its first extremes
(the later of the two extremes sets it); then a running extremum, which becomes a reversal
point once x is ``delta`` back from it; the amplitude A is half the distance between the
last two reversal points (0 before two). It is written here once in each of the two forms
the callers need:

* numpy over any shape of lanes, in fixed time (:func:`track_reversals` and :func:`flip`,
  six ufunc calls whatever the data, all buffers the caller's): the running part of the
  rule, for the kernel's polynomial and amplitude models (they start from an assumed
  direction) and for :class:`LiveReversalAmplitude` (which adds the start: the amplitude
  the live physics terms see);
* numba, one sample of one series at a time (``_reversal_step``), run over a whole record
  (:func:`reversal_points`, :func:`reversal_amplitude`) or piece by piece with its state
  carried (:func:`amplitude_stream`, discovery's streamed path); both loops call the same
  step, so a record cut into pieces gives exactly the whole record's amplitude.
"""

from __future__ import annotations

from typing import Optional

import numba
import numpy as np

__all__ = ["REVERSAL_DEADBAND", "track_reversals", "flip", "LiveReversalAmplitude", "reversal_points",
           "reversal_amplitude", "amplitude_stream", "STREAM_STATE_SIZE"]

#: the reversal dead-band [m]: the default of the kernel's models (``reversal_deadband`` of
#: the polynomial and amplitude models) and of the amplitude signal the physics terms see,
#: offline (:func:`reversal_amplitude`, discovery) and live (the terms' stack). One value:
#: on twin recordings (hold-sine and trajectory, ipanema3) the elongation's noise is at most
#: 0.26 um peak to peak, and dead-bands of 0.5, 1, 2 and 4 um find the same reversals; the
#: amplitude signal once used 2 um without a measured reason.
REVERSAL_DEADBAND = 1e-6


def track_reversals(x: np.ndarray, direction: np.ndarray, extremum: np.ndarray, deadband: np.ndarray,
                    back: np.ndarray, rev: np.ndarray) -> None:
    """Advance the reversal detector by one sample, in place.

    x: elongation [m]; direction: +1 rising / -1 falling (read); extremum: the running
    extremum of the current half-cycle [m] (updated to include x); deadband [m]. Writes
    ``back`` = how far x lies back from the extremum [m] (0 exactly when x is a new
    extremum) and ``rev`` = back > deadband. All arrays have the same shape. The caller
    reads the extremum (the reversal point) where ``rev`` is set, then calls
    :func:`flip` to turn the direction and restart the extremum at x.
    """
    np.multiply(direction, x, back)            # s x
    np.multiply(direction, extremum, extremum)  # s e
    np.maximum(extremum, back, out=extremum)   # s e <- max(s e, s x)
    np.subtract(extremum, back, back)          # s e - s x >= 0: distance moved back
    np.multiply(extremum, direction, extremum)  # back to metres (s * s = 1)
    np.greater(back, deadband, rev)


def flip(x: np.ndarray, direction: np.ndarray, extremum: np.ndarray, rev: np.ndarray, scratch: np.ndarray) -> None:
    """Where ``rev``: turn the direction and restart the running extremum at x (in place)."""
    np.negative(direction, scratch)
    np.copyto(direction, scratch, where=rev)
    np.copyto(extremum, x, where=rev)


class LiveReversalAmplitude:
    """Live elongation amplitude A per (lane, cable), tick by tick: the rule of the module
    over (lanes, m), equal sample for sample to :func:`reversal_amplitude` of the same
    elongations (dead-band ``eps``).

    A lane whose direction is set runs the kernel's step (:func:`track_reversals`, then
    :func:`flip` where a reversal is confirmed); a lane still without a direction (0) keeps
    its first extremes ``hi`` and ``lo`` until they are ``eps`` apart. The two phases touch
    disjoint lanes within one tick and are run in this order:

    1. the running phase over every lane: on a lane without a direction ``track_reversals``
       multiplies by 0, so it writes back = 0 and no reversal (whatever ``eps`` >= 0), and
       its ``ext`` becomes 0 (a value never read: the lane's start below sets it);
    2. the start phase on the lanes whose direction is still 0. ``flip`` turns only lanes
       that had a direction, to -1 or +1, so these are exactly the lanes without a direction
       at the tick's start. A lane that starts here gets its direction and ``ext`` and is
       first run at the next tick, as in the whole-record loop.

    Assumes finite x, as the kernel's models do (the sources reject non-finite values
    before the kernel).
    """

    _STATE = ("dir", "hi", "lo", "hi_later", "ext", "last", "prev", "count", "A", "started")

    def __init__(self, lanes: int, m: int, eps: float):
        shp = (lanes, m)
        self.eps = eps
        self.dir = np.zeros(shp)        # 0 before the first move, +1 rising, -1 falling
        self.hi = np.zeros(shp)
        self.lo = np.zeros(shp)
        self.hi_later = np.zeros(shp, bool)
        self.ext = np.zeros(shp)
        self.last = np.zeros(shp)
        self.prev = np.zeros(shp)
        self.count = np.zeros(shp)
        self.A = np.zeros(shp)
        self.started = False
        self._back = np.zeros(shp)
        self._rev = np.zeros(shp, bool)

    def step(self, x: np.ndarray) -> np.ndarray:
        """A (lanes, m) [m] after the elongation x (lanes, m) [m] (a buffer the next tick
        overwrites)."""
        if not self.started:
            np.copyto(self.hi, x)
            np.copyto(self.lo, x)
            self.started = True
            return self.A
        # 1. the lanes with a direction: the kernel's rule
        rev = self._rev
        track_reversals(x, self.dir, self.ext, self.eps, self._back, rev)
        np.copyto(self.prev, self.last, where=rev)
        np.copyto(self.last, self.ext, where=rev)
        self.count += rev
        np.copyto(self.A, 0.5 * np.abs(self.last - self.prev), where=rev & (self.count >= 2))
        flip(x, self.dir, self.ext, rev, self._back)
        # 2. the lanes without one: their first extremes, until x has moved by eps
        init = self.dir == 0
        up_hi = init & (x > self.hi)
        up_lo = init & (x < self.lo)
        np.copyto(self.hi, x, where=up_hi)
        np.copyto(self.lo, x, where=up_lo)
        self.hi_later[up_hi] = True
        self.hi_later[up_lo] = False
        start = init & ((self.hi - self.lo) > self.eps)
        np.copyto(self.dir, np.where(self.hi_later, 1.0, -1.0), where=start)
        np.copyto(self.ext, np.where(self.hi_later, self.hi, self.lo), where=start)
        return self.A

    def state_dict(self, prefix: str) -> dict[str, np.ndarray]:
        return {prefix + k: np.array(getattr(self, k)) for k in self._STATE}

    def load_state_dict(self, d: dict[str, np.ndarray], prefix: str) -> None:
        for k in self._STATE[:-1]:
            if prefix + k in d:
                np.copyto(getattr(self, k), d[prefix + k])
        if prefix + "started" in d:
            self.started = bool(d[prefix + "started"])


# --------------------------------------------------------------------------------------
# the same rule sample by sample (numba): over a whole record, or in pieces
# --------------------------------------------------------------------------------------

# the state of one series, a float vector: samples seen, direction (0 before the first
# move), running extremum and its index, the first extremes hi and lo and their indices,
# the last reversal point, reversals seen, amplitude
#: length of one series' state in :func:`amplitude_stream`
STREAM_STATE_SIZE = 11
_N, _DIR, _EXT, _EXT_AT, _HI, _HI_AT, _LO, _LO_AT, _LAST, _SEEN, _AMP = range(STREAM_STATE_SIZE)


@numba.njit(cache=True)
def _reversal_step(st, xi, eps):
    """One sample ``xi`` of one series through the rule, its state ``st`` updated in place
    (the amplitude is ``st[_AMP]`` after it). Returns the index of the reversal point this
    sample confirms, -1 when it confirms none. Indices count the samples the state has seen."""
    i = st[_N]
    st[_N] = i + 1.0
    if i == 0.0:                       # the first sample: the first extremes
        st[_HI] = xi
        st[_LO] = xi
        return -1.0
    d = st[_DIR]
    if d == 0.0:                       # not yet moved by eps: no direction, no turn
        if xi > st[_HI]:
            st[_HI] = xi
            st[_HI_AT] = i
        if xi < st[_LO]:
            st[_LO] = xi
            st[_LO_AT] = i
        if st[_HI] - st[_LO] > eps:
            if st[_HI_AT] > st[_LO_AT]:
                st[_DIR], st[_EXT], st[_EXT_AT] = 1.0, st[_HI], st[_HI_AT]
            else:
                st[_DIR], st[_EXT], st[_EXT_AT] = -1.0, st[_LO], st[_LO_AT]
        return -1.0
    rev = False
    if d == 1.0:
        if xi >= st[_EXT]:
            st[_EXT], st[_EXT_AT] = xi, i
        elif st[_EXT] - xi > eps:
            rev = True
    else:
        if xi <= st[_EXT]:
            st[_EXT], st[_EXT_AT] = xi, i
        elif xi - st[_EXT] > eps:
            rev = True
    if not rev:
        return -1.0
    ext, at = st[_EXT], st[_EXT_AT]
    if st[_SEEN] >= 1.0:
        st[_AMP] = 0.5 * abs(ext - st[_LAST])
    st[_LAST] = ext
    st[_SEEN] += 1.0
    st[_DIR], st[_EXT], st[_EXT_AT] = -d, xi, i
    return at


@numba.njit(cache=True)
def _turns(x, eps):
    """(extremum indices, confirmation indices) of the turning points of x: see
    :func:`reversal_points`."""
    n = x.size
    ext_at = np.empty(n, np.int64)
    seen_at = np.empty(n, np.int64)
    st = np.zeros(STREAM_STATE_SIZE)
    k = 0
    for i in range(n):
        at = _reversal_step(st, x[i], eps)
        if at >= 0.0:
            ext_at[k] = np.int64(at)
            seen_at[k] = i
            k += 1
    return ext_at[:k].copy(), seen_at[:k].copy()


@numba.njit(cache=True)
def _amplitudes(x, eps, st, out):
    """The amplitude after each sample of x (one series) into ``out``, from the state ``st``."""
    for i in range(x.shape[0]):
        _reversal_step(st, x[i], eps)
        out[i] = st[_AMP]


def reversal_points(x: np.ndarray, eps: float, *, confirmed: bool = False):
    """Indices of the turning points of ``x`` (N,): a running extreme is confirmed as a
    reversal once x has moved back from it by more than ``eps`` [m] (hysteresis against
    noise and quantisation). On a flat top the last sample of the flat is the reversal.
    Until x has first moved by ``eps`` there is no direction, and the start of the record
    is not a reversal. This is the rule of the kernel
    (:func:`cablesvc.models.reversal.track_reversals`, ``reversal_deadband`` in place of
    ``eps``), run over a whole record.

    ``confirmed``: also return the index of the sample at which each reversal was
    confirmed (the first sample ``eps`` back from it: when a causal estimator knows of it).
    """
    ext_at, seen_at = _turns(np.ascontiguousarray(x, dtype=np.float64), float(eps))
    return (ext_at, seen_at) if confirmed else ext_at


def amplitude_stream(x: np.ndarray, state: Optional[np.ndarray] = None, tol: float = REVERSAL_DEADBAND
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Reversal amplitude (N, m) of ``x`` (N, m) continuing from ``state`` ((m,
    :data:`STREAM_STATE_SIZE`), None at the start): the pieces of a record give exactly
    :func:`reversal_amplitude` of the whole record. Returns (amplitude, state)."""
    x = np.asarray(x, float)
    m = x.shape[1]
    st = np.zeros((m, STREAM_STATE_SIZE)) if state is None else state
    out = np.empty_like(x)
    for c in range(m):
        col = np.empty(x.shape[0])
        _amplitudes(np.ascontiguousarray(x[:, c]), float(tol), st[c], col)
        out[:, c] = col
    return out, st


def reversal_amplitude(x: np.ndarray, tol: float = REVERSAL_DEADBAND) -> np.ndarray:
    """Elongation amplitude A [m] per sample, causal, from the reversal points of x (N,)
    or (N, m): half the distance between the last two reversals (002 Sec 3: the amplitude
    the model's tables are indexed by, estimated as the amplitude model does online), from
    the sample where the later one is confirmed on and held until the next; 0 before two
    reversals. ``tol`` [m]: the reversal dead-band of :func:`reversal_points`."""
    xa = np.asarray(x, dtype=np.float64)
    cols = xa.reshape(xa.shape[0], int(np.prod(xa.shape[1:])))     # (N, cables), also for N = 0
    out, _ = amplitude_stream(cols, None, tol)
    return out.reshape(xa.shape)
