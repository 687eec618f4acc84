"""The daemon's latency percentiles (cablesvc.service.latency) equal hdrh's own, read in
one pass instead of a Python loop per percentile."""

from __future__ import annotations

import numpy as np
import pytest
from hdrh.histogram import HdrHistogram

from cablesvc.service.latency import value_at_percentiles

PERCENTILES = (0, 1, 50, 90, 99, 99.9, 99.99, 100)


@pytest.mark.parametrize("seed", range(6))
def test_equal_to_hdrh_on_heavy_tailed_latencies(seed):
    rng = np.random.default_rng(seed)
    h = HdrHistogram(1, 60_000_000, 3)                 # the daemon's histogram
    n = int(rng.integers(1, 5000))
    lat = np.exp(rng.normal(5.8, 1.2 + seed * 0.3, n))            # ~330 us median, a long tail
    for v in np.clip(lat, 1, 60_000_000).astype(int):
        h.record_value(int(v))
    got = value_at_percentiles(h, PERCENTILES)
    want = [h.get_value_at_percentile(p) for p in PERCENTILES]
    assert got == want


def test_single_value_and_empty_histogram():
    h = HdrHistogram(1, 60_000_000, 3)
    assert value_at_percentiles(h, (50, 99.9)) == [h.get_value_at_percentile(50), h.get_value_at_percentile(99.9)]
    assert value_at_percentiles(h, (50,)) == [0]
    h.record_value(123_456)
    assert value_at_percentiles(h, PERCENTILES) == [h.get_value_at_percentile(p) for p in PERCENTILES]
    assert value_at_percentiles(h, (50,))[0] == pytest.approx(123_456, rel=1e-3)
