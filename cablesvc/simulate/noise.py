"""Correlated noise for the benchmarks: a stationary first-order autoregression.

y_n = phi y_(n-1) + sqrt(1 - phi^2) e_n on unit Gaussian draws e keeps a unit std while
correlating the ticks by phi per tick. With phi = exp(-2 pi f_c dt) it is white noise
through a first-order low-pass filter of cut-off f_c [Hz] sampled every dt [s] (a load-cell
amplifier's, ``cablesvc bench discover --noise-filter-hz``, ``cablesvc bench alarms
--noise-filter-hz``); with phi = exp(-dt / tau) an Ornstein-Uhlenbeck process of
correlation time tau [s] (``cablesvc bench alarms --model-error``). Started from a y_(-1)
drawn as a unit Gaussian it is stationary from its first tick.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ar1", "lowpass_phi"]


def lowpass_phi(cutoff_hz: float, dt: float) -> float:
    """phi of a first-order low-pass filter of cut-off ``cutoff_hz`` [Hz] sampled every ``dt`` [s]."""
    return math.exp(-2.0 * math.pi * float(cutoff_hz) * float(dt))


def ar1(e: np.ndarray, phi: float, y_prev: np.ndarray) -> np.ndarray:
    """y (n, ...) from unit draws ``e`` (n, ...) and the previous value ``y_prev`` (...);
    y[-1] is the next chunk's ``y_prev``."""
    from scipy.signal import lfilter

    e = np.asarray(e, dtype=np.float64)
    zi = phi * np.asarray(y_prev, dtype=np.float64)[None]
    y, _ = lfilter([math.sqrt(1.0 - phi * phi)], [1.0, -phi], e, axis=0, zi=zi)
    return y
