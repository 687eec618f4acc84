"""Robust scale: the standard deviation a Gaussian sample would have, read from its median
absolute deviation (1.4826 x MAD; Hampel 1974), so that a few outliers (a reversal's kink
in a second difference, a glitch) do not count. Used for the noise of a measured signal from
its second differences (identification's reversal threshold, discovery's noise floor) and
for discovery's glitch threshold."""

from __future__ import annotations

import numpy as np

__all__ = ["MAD_TO_STD", "robust_std"]

#: a Gaussian's standard deviation over its median absolute deviation, 1 / Phi^-1(3/4)
MAD_TO_STD = 1.4826


def robust_std(a: np.ndarray, axis: int = 0) -> np.ndarray:
    """MAD_TO_STD x the median absolute deviation of ``a`` from its median along ``axis``."""
    a = np.asarray(a, dtype=np.float64)
    med = np.median(a, axis=axis, keepdims=True)
    return MAD_TO_STD * np.median(np.abs(a - med), axis=axis)
