"""The stop operator of Prandtl-Ishlinskii hysteresis (cablesvc/models/play.py): its law,
and the live step against the offline record, NaNs included."""

from __future__ import annotations

import numpy as np

from cablesvc.models.play import LiveStops, initial_state_columns, stop_columns


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


def test_the_initial_state_column_is_the_gap_between_the_extreme_starts_and_closes_after_2r():
    r = 1e-3
    # rest, then 1.5 mm down (less than 2 r: the start is still remembered), then 3 mm up
    x = np.r_[np.zeros(10), np.linspace(0.0, -1.5e-3, 16), np.linspace(-1.4e-3, 1.6e-3, 31)]
    d = initial_state_columns(x, np.array([r]), np.empty((1, x.size)))[0]
    hi = stop_columns(x, np.array([r]), np.empty((1, x.size)), starts=[1.0])[0]
    lo = stop_columns(x, np.array([r]), np.empty((1, x.size)), starts=[-1.0])[0]
    mid = stop_columns(x, np.array([r]), np.empty((1, x.size)))[0]
    assert hi[0] == 1.0 and lo[0] == -1.0 and mid[0] == 0.0
    np.testing.assert_array_equal(d, 0.5 * (hi - lo))
    assert np.all(d[:10] == 1.0)                                     # at rest nothing is forgotten
    assert np.all(np.diff(d) <= 1e-15) and np.all((d >= 0.0) & (d <= 1.0))
    # 1.5 mm down: the stop started at -1 slides after 0 mm, the one at +1 only after 2 mm
    assert abs(d[25] - (1.0 - 1.5e-3 / (2 * r))) < 1e-12
    # every start lies between the extremes: the relaxed one too
    assert np.all((mid <= hi + 1e-15) & (mid >= lo - 1e-15))
    # after the 3 mm rise (more than 2 r past the turn) every start gives the same state
    assert d[-1] == 0.0 and hi[-1] == lo[-1] == mid[-1] == 1.0


def test_live_stops_from_any_start_equal_the_offline_record():
    rng = np.random.default_rng(5)
    N, lanes, m = 300, 2, 2
    x = np.cumsum(rng.normal(0, 2e-4, (N, lanes, m)), axis=0)
    x[0, 0, 1] = np.nan
    widths = np.array([3e-4, 1e-3, 3e-4, 1e-3])
    starts = np.array([1.0, 1.0, -1.0, -0.5])
    stops = LiveStops(widths, lanes, m, starts=starts)
    out = np.zeros((widths.size, lanes, m))
    live = np.empty((N, widths.size, lanes, m))
    for n in range(N):
        stops.step(x[n], out)
        live[n] = out
    for ln in range(lanes):
        for c in range(m):
            off = stop_columns(x[:, ln, c], widths, np.empty((widths.size, N)), starts=starts)
            np.testing.assert_array_equal(off.T, live[:, :, ln, c])
    np.testing.assert_allclose(live[1, :, 0, 1], starts, atol=1e-12)  # its first finite tick
