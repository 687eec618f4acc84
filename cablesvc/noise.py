"""How the force sensors' noise level is measured, offline and live.

Smooth model errors cancel in a difference of the residual, sensor noise does not. Both
``cablesvc discover`` (:func:`cablesvc.discover.locate.noise_floor`, over a whole recording)
and the live ``spread`` alarm (:class:`cablesvc.alarms.spread.SpreadDetector`, an EWMA per
cable) take the noise std sigma [N] from consecutive ticks, std(diff r) / sqrt 2, which is
sigma for noise that is white at the tick rate. Behind a load-cell amplifier's low-pass
filter consecutive ticks are correlated and that reads only the part of the noise above the
filter (a first-order 5 Hz filter at 100 Hz: about half of sigma). Both therefore also
measure sigma from second differences NOISE_LAG_S apart, r(t) - 2 r(t - L) + r(t - 2 L),
whose variance is 6 sigma^2 once the filter's correlation has died out within L, and take
that estimate where it exceeds the consecutive-tick one by more than NOISE_RATIO (in std;
NOISE_RATIO^2 in variance). On white noise the two agree, so nothing changes there.
"""

from __future__ import annotations

__all__ = ["NOISE_LAG_S", "NOISE_RATIO"]

#: s: the lag of the second differences that measure a noise whose ticks are correlated
#: (a force channel behind a low-pass filter): long against a load-cell amplifier's filter
#: (a 10 Hz first-order filter's correlation has fallen to 2 % after it, a 5 Hz one's to
#: 4 %), short against the trajectory's moves, whose smooth part a second difference cancels
NOISE_LAG_S = 0.1
#: how much larger (in std) than the consecutive-tick estimate the lagged one must be to be
#: taken: on white noise the two agree (on 64 cable residuals of the realistic discovery
#: bench, both truth laws, the lagged one was 0.96-1.07 x the other); a filter of 10 Hz at
#: 100 Hz makes it 1.5 x, one of 5 Hz 1.9 x
NOISE_RATIO = 1.2
