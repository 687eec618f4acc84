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

Fixed time: six ufunc calls whatever the data; all buffers are the caller's.
"""

from __future__ import annotations

import numba
import numpy as np

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


# --------------------------------------------------------------------------------------
# the same rule over a whole record (offline)
# --------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _turns(x, eps):
    """(extremum indices, confirmation indices) of the turning points of x: see
    :func:`reversal_points`."""
    n = x.size
    ext_at = np.empty(n, np.int64)
    seen_at = np.empty(n, np.int64)
    k = 0
    direction = 0
    hi = lo = ext = 0
    for i in range(1, n):
        xi = x[i]
        if direction == 0:             # not yet moved by eps: no direction, no turn
            if xi > x[hi]:
                hi = i
            if xi < x[lo]:
                lo = i
            if x[hi] - x[lo] > eps:
                direction = 1 if hi > lo else -1
                ext = hi if direction == 1 else lo
        elif direction == 1:
            if xi >= x[ext]:
                ext = i
            elif x[ext] - xi > eps:
                ext_at[k] = ext
                seen_at[k] = i
                k += 1
                direction, ext = -1, i
        else:
            if xi <= x[ext]:
                ext = i
            elif xi - x[ext] > eps:
                ext_at[k] = ext
                seen_at[k] = i
                k += 1
                direction, ext = 1, i
    return ext_at[:k].copy(), seen_at[:k].copy()


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


def reversal_amplitude(x: np.ndarray, tol: float = REVERSAL_DEADBAND) -> np.ndarray:
    """Elongation amplitude A [m] per sample, causal, from the reversal points of x (N,)
    or (N, m): half the distance between the last two reversals (002 Sec 3: the amplitude
    the model's tables are indexed by, estimated as the amplitude model does online), from
    the sample where the later one is confirmed on and held until the next; 0 before two
    reversals. ``tol`` [m]: the reversal dead-band of :func:`reversal_points`."""
    xa = np.asarray(x, dtype=np.float64)
    cols = xa.reshape(xa.shape[0], int(np.prod(xa.shape[1:])))     # (N, cables), also for N = 0
    out = np.zeros(cols.shape)
    samples = np.arange(cols.shape[0])
    for c in range(cols.shape[1]):
        xc = np.ascontiguousarray(cols[:, c])
        ext_at, seen_at = reversal_points(xc, tol, confirmed=True)
        if ext_at.size < 2:
            continue
        amp = 0.5 * np.abs(np.diff(xc[ext_at]))
        j = np.searchsorted(seen_at[1:], samples, side="right") - 1   # last amplitude known at each sample
        out[:, c] = np.where(j >= 0, amp[np.maximum(j, 0)], 0.0)
    return out.reshape(xa.shape)
