"""The one lag-one correlation estimate (cablesvc/serial.py) that identification and
discovery share."""

from __future__ import annotations

import numpy as np

from cablesvc.serial import lag_one_correlation, variance_inflation


def _ar1(rho, n, seed):
    rng = np.random.default_rng(seed)
    e = np.zeros(n)
    w = rng.standard_normal(n)
    for i in range(1, n):
        e[i] = rho * e[i - 1] + w[i]
    return e


def test_lag_one_correlation_of_ar1_and_white_noise():
    assert abs(lag_one_correlation([_ar1(0.8, 20000, 1)]) - 0.8) < 0.02
    assert abs(lag_one_correlation([np.random.default_rng(2).standard_normal(20000)])) < 0.03
    assert lag_one_correlation([np.zeros(10)]) == 0.0


def test_pairs_never_span_two_pieces():
    # two constant pieces of opposite sign: within each piece the correlation is 1; a
    # pair across the joint would pull it down
    a, b = np.full(50, 1.0), np.full(50, -1.0)
    whole = lag_one_correlation([np.concatenate([a, b])], floor=-1.0, cap=1.0)
    split = lag_one_correlation([a, b], floor=-1.0, cap=1.0)
    assert split > whole
    assert abs(split - 49 / 50) < 1e-12


def test_floor_cap_and_inflation():
    alt = np.tile([1.0, -1.0], 100)                      # anti-correlated
    assert lag_one_correlation([alt]) == 0.0            # floored: white residuals keep the plain test
    assert lag_one_correlation([alt], floor=-1.0) < -0.99
    assert lag_one_correlation([np.ones(1000)]) == 0.99  # capped
    assert variance_inflation(0.0) == 1.0
    assert abs(variance_inflation(0.9) - 19.0) < 1e-12
