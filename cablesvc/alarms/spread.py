"""Spread detector: per-cable spread of the residual (measured - predicted) vs its noise floor.

``drift`` watches the residual's mean. A model that misses a term whose contribution
averages to zero over the motion (a dead time, a viscous force c v, a pulley friction
F sign(v)) leaves the mean where it was and only widens the residual: this detector
raises ``spread`` on a cable when its residual varies by more than its sensor noise can
explain, and suggests ``cablesvc discover`` to find the missing term.

Per cable i and per sample with a finite residual r [N] (NaN = no measurement: skipped,
the cable's state does not change):

1. **Sample weight** dt: time since the cable's previous valid sample, at most
   ``max_dt_s`` (:func:`~cablesvc.alarms.residual.sample_dt`, the same as drift's). Every
   statistic below is an EWMA with a time constant in seconds and gain
   dt / (tau + dt) (:func:`~cablesvc.alarms.residual.ewma_gain`), so the tuning does not
   depend on the tick rate.
2. **Mean** mu: EWMA of r with ``mean_tau_s``; z = r - mu (mu before this sample).
   Changes slower than ``mean_tau_s`` are the mean's (``drift``'s business), faster ones
   are spread. While the statistics are younger than ``mean_tau_s`` (a start, a reset after
   new parameters) the gain is the running average's when larger, dt / age: a first sample
   far off (the tick of a parameter switch) is then one sample among many instead of the
   mean's value for ``mean_tau_s`` seconds, which widened the spread until after the
   warm-up and raised a false alarm.
3. **Spread** s^2: EWMA of z^2 with ``tau_s``.
4. **Noise floor** q: EWMA of (r - r_prev)^2 / 2 with ``tau_s``, over consecutive
   samples at most ``max_dt_s`` apart: the live form of the offline floor
   std(diff r) / sqrt 2 of ``cablesvc discover`` (:func:`cablesvc.discover.locate.noise_floor`).
   White noise of std sigma gives s^2 = q = sigma^2 at any tick rate; a term that varies
   smoothly over many ticks adds its variance to s^2 but almost nothing to q. Behind a
   load-cell amplifier's low-pass filter consecutive samples are correlated and q reads only
   the noise above the filter. Over the warm-up the detector therefore also averages
   q_L = d^2 / 6, d = r - 2 r_1 + r_2 over samples about ``noise_lag_s`` apart (r_1, r_2:
   the last two samples taken as such anchors, each the first at least ``noise_lag_s``
   after the previous one; a gap over ``max_dt_s`` restarts them), which is sigma^2 once
   the filter's correlation has died out within the lag. Where q_L exceeds
   :data:`~cablesvc.noise.NOISE_RATIO`^2 q at the end of the warm-up, as offline
   (:mod:`cablesvc.noise`), the floor is q times the factor kappa = q_L / q from then on.
   The factor is a property of the amplifier and is kept like drift's baseline (a reset, new
   parameters, learns it again); it is not tracked further because a friction F sign(v)
   puts steps of 2 F into the second differences at every reversal (a 3 sigma friction
   reversing every 2 s makes q_L about 1.6 sigma^2), which would lift the floor under the very
   effect the alarm is for, while q hardly sees them. On white
   noise the two agree and q stands alone. The floor used is max(sqrt(kappa q), ``floor_min_n``) (a
   residual without noise, e.g. a simulation replayed through its own model, has no
   meaningful ratio).
5. **Ratio** rho = s / floor. After ``warmup_s`` seconds of valid samples (the EWMAs
   settle), **raise** when rho > ``raise_ratio`` continuously for ``raise_hold_s``;
   **clear** when rho < ``clear_ratio`` (hysteresis) for ``clear_hold_s``. The hold timers
   are the state alarms' (:func:`cablesvc.alarms.state.hold`): a timer that started after
   the current t (clock restarted, older snapshot restored) restarts at t.

The event's ``value`` is the spread s [N] and ``limit`` the threshold ``raise_ratio`` x
floor [N] (for a clear, ``clear_ratio`` x floor); ``since`` the time rho went above
``raise_ratio``.

Limits of the method (``docs/messages.md`` has the measured numbers): a model that
already leaves a structured residual above ``raise_ratio`` x the noise keeps the alarm
raised until the term is found (``cablesvc discover``) or ``raise_ratio`` is raised; a
step of the mean by several times the noise raises ``spread`` for about ``mean_tau_s``
beside ``drift``; a zero-mean effect already there during the warm-up can be taken for a
correlated noise (a 3 sigma friction reversing every 2 s, from the first tick: kappa
1.0-1.8 and rho 2.3-3.1 instead of 3.2 on 8 cables at 100 Hz and 1 kHz, still raised on
all); a noise correlated over more than ``noise_lag_s`` (a filter below about
2 Hz) is still read below its level: measure rho on a good run (:attr:`SpreadDetector.ratio`)
and set ``raise_ratio`` above it.

Like the drift detector, the per-sample work is one numba kernel shared by :meth:`update`
(one call per tick for all cables, no allocation unless an event happens) and
:meth:`update_batch` (a block of ticks in one call, bit-identical).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from cablesvc.alarms import SPREAD_SUGGESTED_ACTION, AlarmEvent, jit_inline, jit_kernel
from cablesvc.alarms.residual import (RUN_SIGNATURE, STEP_SIGNATURE, ResidualDetector, ewma_gain, sample_dt,
                                      block_samples, tick_samples)
from cablesvc.alarms.state import ACTIVE, CLEAR_SINCE, RAISE_SINCE, SINCE, hold
from cablesvc.noise import NOISE_LAG_S, NOISE_RATIO

__all__ = ["SpreadConfig", "SpreadDetector"]


class SpreadConfig(BaseModel):
    """Tuning of the spread detector (``[alarms.spread]`` in a TOML file). SI units: N, s."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="run the detector when measured forces are present")
    warmup_s: float = Field(30.0, ge=0.0, description="seconds of valid samples before the first decision [s]")
    mean_tau_s: float = Field(10.0, gt=0.0, description="EWMA time constant of the mean removed from the residual [s]")
    tau_s: float = Field(5.0, gt=0.0, description="EWMA time constant of the spread and of the noise floor [s]")
    raise_ratio: float = Field(1.5, gt=1.0, description="spread / noise floor above this raises")
    clear_ratio: float = Field(1.2, gt=0.0, description="spread / noise floor below this clears (hysteresis)")
    raise_hold_s: float = Field(2.0, ge=0.0, description="ratio must stay above raise_ratio this long to raise [s]")
    clear_hold_s: float = Field(10.0, ge=0.0, description="ratio must stay below clear_ratio this long to clear [s]")
    floor_min_n: float = Field(1e-3, gt=0.0, description="smallest noise floor used [N]")
    max_dt_s: float = Field(0.1, gt=0.0, description="largest weight of one sample; larger gaps skip the floor [s]")
    noise_lag_s: float = Field(NOISE_LAG_S, ge=0.0,
                               description="lag of the second differences that measure a filtered sensor's noise "
                                           "at its level [s] (0: consecutive samples only)")

    @model_validator(mode="after")
    def _check(self) -> "SpreadConfig":
        if self.clear_ratio >= self.raise_ratio:
            raise ValueError(f"clear_ratio ({self.clear_ratio}) must be below raise_ratio ({self.raise_ratio}) "
                             "(hysteresis)")
        return self

    def as_array(self) -> np.ndarray:
        """Parameter vector of the kernel (order: the _P_* indices)."""
        return np.array([self.warmup_s, self.mean_tau_s, self.tau_s, self.raise_ratio, self.clear_ratio,
                         self.raise_hold_s, self.clear_hold_s, self.floor_min_n, self.max_dt_s, self.noise_lag_s],
                        dtype=np.float64)


# ---- kernel layout -----------------------------------------------------------------------
# state rows (NS, m): the hold-timer rows of cablesvc.alarms.state first, then ours
_R0 = max(ACTIVE, RAISE_SINCE, CLEAR_SINCE, SINCE) + 1
(_READY, _W_T0, _T_LAST, _R_PREV, _MEAN, _VAR, _FLOOR) = range(_R0, _R0 + 7)
# the lagged floor's rows come last, so that a snapshot from before them is this layout's head
(_LAG_T, _LAG_R1, _LAG_R2, _FLOOR_LAG, _KAPPA) = range(_R0 + 7, _R0 + 12)
_NS = _R0 + 12
_NS_BEFORE_LAG = _R0 + 7
_STATE_NAMES = {ACTIVE: "active", RAISE_SINCE: "raise_since", CLEAR_SINCE: "clear_since", SINCE: "since",
                _READY: "ready", _W_T0: "warmup_t0", _T_LAST: "t_last", _R_PREV: "r_prev", _MEAN: "mean",
                _VAR: "spread_sq", _FLOOR: "floor_sq", _LAG_T: "lag_t", _LAG_R1: "lag_r1", _LAG_R2: "lag_r2",
                _FLOOR_LAG: "floor_lag_sq", _KAPPA: "noise_factor"}
# parameters
(_P_WARMUP, _P_MEAN_TAU, _P_TAU, _P_RAISE, _P_CLEAR, _P_RAISE_HOLD, _P_CLEAR_HOLD, _P_FLOOR_MIN,
 _P_MAX_DT, _P_LAG) = range(10)
#: the warm-up's lagged floor scales the consecutive one above this ratio of the two (variances)
_LAG_VAR_RATIO = NOISE_RATIO * NOISE_RATIO
#: an anchor is taken once (1 - this) x the lag has passed (timestamps k / rate round)
_LAG_TOL = 1e-6
# event record columns (row and cable first, as ResidualDetector reads them): row, cable,
# action (+1 raise, -1 clear), since, spread [N], floor [N]
(_E_ROW, _E_CABLE, _E_ACTION, _E_SINCE, _E_SPREAD, _E_FLOOR) = range(6)
_NE = 6


@jit_inline
def _spread_sample(S, P, t, r, i, E, ne, row):
    """One sample r [N] of cable i at time t [s]; appends raise/clear records to E[ne:].
    Returns the new number of records."""
    if not math.isfinite(r):                     # NaN: no measurement, skipped (and so is +-inf)
        return ne
    t_last = S[_T_LAST, i]
    if t_last != t_last:                         # first sample: start the statistics at it
        S[_T_LAST, i] = t
        S[_R_PREV, i] = r
        S[_MEAN, i] = r
        S[_W_T0, i] = t
        S[_LAG_T, i] = t
        S[_LAG_R1, i] = r
        S[_LAG_R2, i] = math.nan
        return ne
    gap = t - t_last
    dt = sample_dt(t, t_last, P[_P_MAX_DT])
    z = r - S[_MEAN, i]
    # the mean's gain: the EWMA's, or while the statistics are younger than its time
    # constant the running average's (so one odd first sample weighs 1/n, not 1 - n dt/tau)
    gm = ewma_gain(dt, P[_P_MEAN_TAU])
    age = t - S[_W_T0, i] + dt
    if age > 0.0 and dt / age > gm:
        gm = dt / age
    S[_MEAN, i] += gm * z
    g = ewma_gain(dt, P[_P_TAU])
    S[_VAR, i] += g * (z * z - S[_VAR, i])
    if gap <= P[_P_MAX_DT]:                      # consecutive samples: their difference is noise
        d = r - S[_R_PREV, i]
        S[_FLOOR, i] += g * (0.5 * d * d - S[_FLOOR, i])
    lag = P[_P_LAG]
    if lag > 0.0 and S[_READY, i] == 0.0:       # the warm-up measures the noise's correlation
        since_anchor = t - S[_LAG_T, i]
        if gap > P[_P_MAX_DT] or not since_anchor >= 0.0:   # a gap, the clock went back, no anchor yet
            S[_LAG_T, i] = t
            S[_LAG_R1, i] = r
            S[_LAG_R2, i] = math.nan
        elif since_anchor >= lag * (1.0 - _LAG_TOL):
            r2 = S[_LAG_R2, i]
            if r2 == r2:                             # three anchors about a lag apart: a second difference
                d2 = r - 2.0 * S[_LAG_R1, i] + r2
                # the running average over the warm-up (span: about the samples so far x lag)
                span = t - S[_W_T0, i] - lag
                gl = min(since_anchor / span, 1.0) if span > 0.0 else 1.0
                S[_FLOOR_LAG, i] += gl * (d2 * d2 / 6.0 - S[_FLOOR_LAG, i])
            S[_LAG_R2, i] = S[_LAG_R1, i]
            S[_LAG_R1, i] = r
            S[_LAG_T, i] = t
    S[_T_LAST, i] = t
    S[_R_PREV, i] = r
    if S[_READY, i] == 0.0:
        if t < S[_W_T0, i]:                      # the clock went back: restart the warm-up
            S[_W_T0, i] = t
        if t - S[_W_T0, i] < P[_P_WARMUP]:
            return ne
        S[_READY, i] = 1.0
        # the noise's ticks are correlated (a filter): the factor from the consecutive floor to
        # its level, learned over the warm-up and kept (a property of the sensor's amplifier)
        k = S[_FLOOR_LAG, i] / S[_FLOOR, i] if S[_FLOOR, i] > 0.0 else 1.0
        S[_KAPPA, i] = k if k > _LAG_VAR_RATIO else 1.0
    q = S[_FLOOR, i]
    if S[_KAPPA, i] > 1.0:
        q *= S[_KAPPA, i]
    fl = math.sqrt(q)
    if fl < P[_P_FLOOR_MIN]:
        fl = P[_P_FLOOR_MIN]
    s = math.sqrt(S[_VAR, i])
    a = hold(S, i, t, s > P[_P_RAISE] * fl, s < P[_P_CLEAR] * fl, P[_P_RAISE_HOLD], P[_P_CLEAR_HOLD])
    if a != 0:
        E[ne, _E_ROW] = row
        E[ne, _E_CABLE] = i
        E[ne, _E_ACTION] = a
        E[ne, _E_SINCE] = S[SINCE, i]
        E[ne, _E_SPREAD] = s
        E[ne, _E_FLOOR] = fl
        ne += 1
    return ne


@jit_kernel(STEP_SIGNATURE)
def _spread_step(S, P, t, r, E):
    """One tick of every cable (:func:`_spread_sample` each). Returns the number of event records."""
    return tick_samples(_spread_sample, S, P, t, r, E)


@jit_kernel(RUN_SIGNATURE)
def _spread_run(S, P, T, R, E, row0):
    """A block of ticks from row0 on (:func:`~cablesvc.alarms.residual.block_samples`)."""
    return block_samples(_spread_sample, S, P, T, R, E, row0)

class SpreadDetector(ResidualDetector):
    """Per-cable spread of the residual measured - predicted [N] against its noise floor;
    see the module docstring.

    ``n_cables`` m; ``config`` a :class:`SpreadConfig`; ``cable_names`` for the messages.
    :meth:`update` takes one tick (m residuals, NaN = no measurement) and returns the alarm
    events of that tick (usually none); :meth:`update_batch` takes a block of ticks and
    returns exactly what the same ticks given one by one to :meth:`update` would.
    """

    code = "spread"
    config_class = SpreadConfig
    n_state = _NS
    n_record = _NE
    _step = staticmethod(_spread_step)
    _run = staticmethod(_spread_run)
    # the state rows that ResidualDetector's reset, deactivate, rebase_time, ready, active and
    # describe_state read
    state_names = tuple(name for _, name in sorted(_STATE_NAMES.items()))
    rest_nan_rows = (RAISE_SINCE, CLEAR_SINCE, SINCE, _W_T0, _T_LAST, _R_PREV, _MEAN, _LAG_T, _LAG_R1, _LAG_R2)
    time_rows = (_W_T0, _T_LAST, RAISE_SINCE, CLEAR_SINCE, SINCE, _LAG_T)
    # a snapshot from before the lagged floor: its rows are the head of ours, the lagged
    # floor starts afresh (at rest) from the next sample
    older_n_states = (_NS_BEFORE_LAG,)
    alarm_zero_rows = (ACTIVE,)
    alarm_nan_rows = (RAISE_SINCE, CLEAR_SINCE, SINCE)
    ready_row = _READY
    active_row = ACTIVE

    # -- read-outs (ready, active: ResidualDetector's) ----------------------------------------
    @property
    def spread(self) -> np.ndarray:
        """Current spread s per cable [N] (NaN before the first sample)."""
        return np.where(np.isnan(self._S[_T_LAST]), np.nan, np.sqrt(self._S[_VAR]))

    @property
    def floor(self) -> np.ndarray:
        """Current noise floor per cable [N], at least ``floor_min_n`` (NaN before the first
        sample): from consecutive samples, or from the lagged second differences where the
        noise is correlated (:attr:`noise_correlated`)."""
        q = self._S[_FLOOR] * np.maximum(self._S[_KAPPA], 1.0)
        fl = np.maximum(np.sqrt(q), self.config.floor_min_n)
        return np.where(np.isnan(self._S[_T_LAST]), np.nan, fl)

    @property
    def noise_correlated(self) -> np.ndarray:
        """(m,) bool: the warm-up found consecutive samples of the noise correlated (e.g. by the
        force amplifier's low-pass filter), and the floor is scaled by :attr:`noise_factor`."""
        return self._S[_KAPPA] > 1.0

    @property
    def noise_factor(self) -> np.ndarray:
        """(m,) factor on the consecutive-sample floor's q learned over the warm-up (1: white noise)."""
        return np.maximum(self._S[_KAPPA], 1.0)

    @property
    def ratio(self) -> np.ndarray:
        """Spread / noise floor per cable (1 for white noise; NaN before the first sample)."""
        return self.spread / self.floor

    def _event(self, rec: np.ndarray, t: float, seq: int | None) -> AlarmEvent:
        i = int(rec[_E_CABLE])
        who = f"cable {i} ({self.cable_names[i]})"
        since = float(rec[_E_SINCE])
        s = float(rec[_E_SPREAD])
        fl = float(rec[_E_FLOOR])
        cfg = self.config
        if rec[_E_ACTION] > 0:
            msg = (f"{who}: measured - predicted force spreads {s:.3f} N, {s / fl:.1f} x its noise floor of "
                   f"{fl:.3f} N, since t = {since:.1f} s; the cable model misses a term that averages out "
                   f"(dead time, viscous or pulley friction, ...)")
            return AlarmEvent("raise", "spread", i, self._severity, t, since, seq, msg,
                              suggested_action=SPREAD_SUGGESTED_ACTION, value=s, limit=cfg.raise_ratio * fl)
        msg = (f"{who}: measured - predicted force spreads {s:.3f} N, back below {cfg.clear_ratio:g} x its "
               f"noise floor of {fl:.3f} N")
        return AlarmEvent("clear", "spread", i, self._severity, t, since, seq, msg, value=s,
                          limit=cfg.clear_ratio * fl)
