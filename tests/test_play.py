"""The stop operator of Prandtl-Ishlinskii hysteresis (cablesvc/models/play.py): its law,
and the live step against the offline record, NaNs included."""

from __future__ import annotations

import numpy as np

from cablesvc.models.play import LiveStops, stop_columns


def test_stop_is_elastic_then_slides_and_remembers_its_reversal():
    r = 1e-3
    x = np.r_[np.linspace(0.0, 0.5e-3, 6), np.linspace(0.6e-3, 5e-3, 45), np.linspace(4.9e-3, 3.5e-3, 15),
              np.linspace(3.6e-3, 6e-3, 25)]
    s = stop_columns(x, np.array([r]), np.empty((1, x.size)))[0]
    # elastic from the relaxed start: s = x / r while |x| < r
    np.testing.assert_allclose(s[:6], x[:6] / r, atol=1e-12)
    # sliding on loading: at +1 once x has gone r past the start
    assert np.all(s[(x > 1.01e-3) & (np.arange(x.size) < 51)] == 1.0)
    # on unloading by 1.5 mm (less than 2r) it moves elastically, from +1 by -1.5 mm / r
    k = 65
    assert abs(s[k] - (1.0 - (5e-3 - x[k]) / r)) < 1e-12
    assert np.all(np.abs(s) <= 1.0 + 1e-12)
    # reloading: back at +1 once x passes the old play state again (x - r after the turn)
    assert s[-1] == 1.0


def test_live_step_equals_the_offline_record_with_gaps():
    rng = np.random.default_rng(4)
    N, lanes, m = 400, 2, 3
    x = np.cumsum(rng.normal(0, 3e-4, (N, lanes, m)), axis=0)
    x[0, 1, 2] = np.nan                     # a state that starts late
    x[50:53, 0, 1] = np.nan                 # a gap mid-record
    widths = np.array([3e-4, 1e-3, 3e-3])
    k = widths.size
    stops = LiveStops(widths, lanes, m)
    out = np.zeros((k, lanes, m))
    live = np.empty((N, k, lanes, m))
    for n in range(N):
        stops.step(x[n], out)
        live[n] = out
    for ln in range(lanes):
        for c in range(m):
            off = stop_columns(x[:, ln, c], widths, np.empty((k, N)))
            np.testing.assert_array_equal(off.T, live[:, :, ln, c])
    assert np.isnan(live[51, 0, 0, 1]) and np.isfinite(live[53, 0, 0, 1])
    assert np.all(np.abs(live[np.isfinite(live)]) <= 1.0 + 1e-12)
