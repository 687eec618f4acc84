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
rule :func:`cablesvc.identify.amplitude_fit.reversal_points` applies offline. Choose
``delta`` above the peak-to-peak noise of the elongation and well below the smallest
amplitude of interest; the default, 1 um, is 1 % of the 0.1 mm amplitudes of 002 Sec 4
and ten times the quantisation of the shipped DBC.

Fixed time: six ufunc calls whatever the data; all buffers are the caller's.
"""

from __future__ import annotations

import numpy as np

#: default reversal dead-band [m]
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
