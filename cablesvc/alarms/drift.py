"""Model-drift detector: per-cable residual (measured - predicted) vs a learned baseline.

Paper 002 (Fig 6) found the measured cable force 0.4 N off the identified model after a
few days of operation (temperature, cable settlement, high-tension states). This detector
raises a ``drift`` alarm per cable when that happens, and suggests re-identifying the model.

Per cable i and per sample with a finite residual r [N] (NaN = no measurement: skipped,
the cable's state does not change):

1. **Baseline** (warm-up). A good model still leaves a nonzero mean residual per cable
   (002 reports 0.4 N average model error). The first ``warmup_s`` seconds of valid
   samples of each cable are averaged into its baseline b_i [N], which then stays frozen
   (a baseline that kept adapting would follow the drift and hide it). Drift is measured
   relative to it: z = r - b_i. ``baseline_n`` in the config skips the warm-up;
   :meth:`DriftDetector.reset` restarts it (after re-identifying the model).
2. **Sample weight**: dt = time since the cable's previous valid sample [s], at most
   ``max_dt_s`` (a gap in the measurements does not count as evidence). All sums below are
   integrals over time, so the tuning does not depend on the tick rate.
3. **EWMA** of z with time constant tau = ``ewma_tau_s``: e += dt / (tau + dt) * (z - e)
   (the exact implicit discretisation; no transcendental function, so the tick-by-tick
   and batch paths round identically). e is the current offset estimate [N].
4. **Two-sided CUSUM** on z clipped to +-``clip_n`` (a short burst, e.g. a collision,
   cannot raise drift on its own):
   S+ = max(0, S+ + (zc - k) dt), S- = max(0, S- + (-zc - k) dt)   [N s],
   k = ``cusum_k_n`` (half the smallest offset worth detecting). The last time a side was
   zero estimates when the change started; the mean of z since then estimates its size.
5. **Raise** when S+ or S- exceeds h = ``cusum_h_ns`` continuously for ``raise_hold_s``
   (the hold timers are the state alarms' :func:`~cablesvc.alarms.state.hold_rows`; a hold
   or warm-up timer that started after the current t, i.e. the controller clock restarted
   or an older snapshot was restored, restarts at t).
   The event carries ``since`` (change start), ``offset_n`` (the larger in magnitude of the
   mean of z since the change start and the EWMA: right for a step and for a ramp).
6. **Clear** when |e| < ``clear_n`` (< k: hysteresis) continuously for ``clear_hold_s``;
   both CUSUM sides restart from zero.

Delays with the defaults (k = 0.2 N, h = 2 N s, 1 s hold; derivation in
``docs/messages.md``, measured by ``cablesvc bench alarms``): a 0.4 N step raises after
about h / (0.4 - k) + 1 s = 11 s; a 0.4 N/h ramp raises about 33 min after it starts,
when the offset is about 0.22 N.

The work per sample is a numba kernel (:func:`_drift_sample`) shared by :meth:`update`
(one call per tick for all cables) and :meth:`update_batch` (a whole block of ticks in one
call, for offline checks such as an hour of 1 kHz data): both run the same compiled code,
so they give bit-identical states and events.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from cablesvc.alarms import DRIFT_SUGGESTED_ACTION, AlarmEvent, jit_inline, jit_kernel
from cablesvc.alarms.residual import (RUN_SIGNATURE, STEP_SIGNATURE, ResidualDetector, ewma_gain, sample_dt,
                                      block_samples, tick_samples)
from cablesvc.alarms.state import hold_rows

__all__ = ["DriftConfig", "DriftDetector"]


class DriftConfig(BaseModel):
    """Tuning of the drift detector (``[alarms.drift]`` in a TOML file). SI units: N, s."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = Field(True, description="run the detector when measured forces are present")
    warmup_s: float = Field(60.0, ge=0.0, description="seconds of valid samples averaged into each cable's baseline [s]")
    baseline_n: Optional[float | list[float]] = Field(
        None, description="fixed baseline per cable (or one for all) [N]; skips the warm-up")
    ewma_tau_s: float = Field(10.0, gt=0.0, description="EWMA time constant of the offset estimate [s]")
    cusum_k_n: float = Field(0.2, ge=0.0, description="CUSUM reference: offsets above it accumulate [N]")
    cusum_h_ns: float = Field(2.0, gt=0.0, description="CUSUM decision threshold [N s]")
    clip_n: float = Field(1.0, gt=0.0, description="residual deviations are clipped to +-clip_n in the CUSUM [N]")
    raise_hold_s: float = Field(1.0, ge=0.0, description="CUSUM must stay above h this long to raise [s]")
    clear_n: float = Field(0.1, gt=0.0, description="|EWMA| below this (hysteresis, < k) clears [N]")
    clear_hold_s: float = Field(10.0, ge=0.0, description="|EWMA| must stay below clear_n this long to clear [s]")
    max_dt_s: float = Field(0.1, gt=0.0, description="largest weight of one sample (after a gap) [s]")

    @model_validator(mode="after")
    def _check(self) -> "DriftConfig":
        if self.clip_n <= self.cusum_k_n:
            raise ValueError(f"clip_n ({self.clip_n} N) must be larger than cusum_k_n ({self.cusum_k_n} N), "
                             "otherwise no offset can accumulate")
        return self

    def as_array(self) -> np.ndarray:
        """Parameter vector of the kernel (order: the _P_* indices)."""
        return np.array([self.warmup_s, self.ewma_tau_s, self.cusum_k_n, self.cusum_h_ns, self.clip_n,
                         self.raise_hold_s, self.clear_n, self.clear_hold_s, self.max_dt_s], dtype=np.float64)


# ---- kernel layout -----------------------------------------------------------------------
# state rows (NS, m)
(_BASE, _READY, _W_T0, _W_SUM, _W_N, _T_LAST, _EWMA, _CU, _CL, _CU_T0, _CL_T0, _CU_SZ, _CU_ST,
 _CL_SZ, _CL_ST, _ACTIVE, _SIDE, RAISE_SINCE, _CLEAR_SINCE, _SINCE, _OFFSET) = range(21)
_NS = 21
_STATE_NAMES = ("baseline", "ready", "warmup_t0", "warmup_sum", "warmup_n", "t_last", "ewma", "cusum_up",
                "cusum_down", "cusum_up_t0", "cusum_down_t0", "cusum_up_sum_z", "cusum_up_sum_t",
                "cusum_down_sum_z", "cusum_down_sum_t", "active", "side", "raise_since", "clear_since",
                "since", "offset")
# parameters
(_P_WARMUP, _P_TAU, _P_K, _P_H, _P_CLIP, _P_RAISE_HOLD, _P_CLEAR, _P_CLEAR_HOLD, _P_MAX_DT) = range(9)
# event record columns (row and cable first, as ResidualDetector reads them)
(_E_ROW, _E_CABLE, _E_ACTION, _E_SIDE, _E_SINCE, _E_OFFSET, _E_EWMA, _E_BASE) = range(8)
_NE = 8

_NAN = math.nan


@jit_inline
def _restart_cusum(S, i, t):
    """Both CUSUM sides of cable i back to zero, their runs starting at time t."""
    S[_CU, i] = 0.0
    S[_CL, i] = 0.0
    S[_CU_T0, i] = t
    S[_CL_T0, i] = t
    S[_CU_SZ, i] = 0.0
    S[_CU_ST, i] = 0.0
    S[_CL_SZ, i] = 0.0
    S[_CL_ST, i] = 0.0


@jit_inline
def _start(S, i, t, base):
    """Cable i leaves the warm-up (or is given a baseline) at time t."""
    S[_BASE, i] = base
    S[_READY, i] = 1.0
    S[_T_LAST, i] = t
    S[_EWMA, i] = 0.0
    _restart_cusum(S, i, t)
    S[RAISE_SINCE, i] = _NAN
    S[_CLEAR_SINCE, i] = _NAN


@jit_inline
def _cusum_side(S, i, t, inc, z, dt, c, c_t0, c_sz, c_st):
    """One side of the two-sided CUSUM of cable i: S[c] += inc, floored at 0 (then the
    run restarts at t); while it runs, the residual integral S[c_sz] and duration S[c_st]
    give the run's mean offset."""
    v = S[c, i] + inc
    if v <= 0.0:
        S[c, i] = 0.0
        S[c_t0, i] = t
        S[c_sz, i] = 0.0
        S[c_st, i] = 0.0
    else:
        S[c, i] = v
        S[c_sz, i] += z * dt
        S[c_st, i] += dt


@jit_inline
def _drift_sample(S, P, t, r, i, E, ne, row):
    """One sample r [N] of cable i at time t [s]; appends raise/clear records to E[ne:].
    Returns the new number of records."""
    if r != r:                                   # NaN: no measurement, skipped
        return ne
    if S[_READY, i] == 0.0:                      # warm-up: learn the baseline
        # first sample, or the clock went back: (re)start the timer
        if S[_W_T0, i] != S[_W_T0, i] or t < S[_W_T0, i]:
            S[_W_T0, i] = t
        S[_W_SUM, i] += r
        S[_W_N, i] += 1.0
        if t - S[_W_T0, i] >= P[_P_WARMUP]:
            _start(S, i, t, S[_W_SUM, i] / S[_W_N, i])
        return ne
    dt = sample_dt(t, S[_T_LAST, i], P[_P_MAX_DT])   # 0: first sample after a preset baseline
    S[_T_LAST, i] = t
    z = r - S[_BASE, i]
    S[_EWMA, i] += ewma_gain(dt, P[_P_TAU]) * (z - S[_EWMA, i])
    clip = P[_P_CLIP]
    zc = z
    if zc > clip:
        zc = clip
    elif zc < -clip:
        zc = -clip
    k = P[_P_K]
    _cusum_side(S, i, t, (zc - k) * dt, z, dt, _CU, _CU_T0, _CU_SZ, _CU_ST)     # upper: offsets > k
    _cusum_side(S, i, t, (-zc - k) * dt, z, dt, _CL, _CL_T0, _CL_SZ, _CL_ST)    # lower: offsets < -k
    h = P[_P_H]
    a = hold_rows(S, i, t, S[_CU, i] > h or S[_CL, i] > h, abs(S[_EWMA, i]) < P[_P_CLEAR],
                  P[_P_RAISE_HOLD], P[_P_CLEAR_HOLD], _ACTIVE, RAISE_SINCE, _CLEAR_SINCE, _SINCE)
    if a > 0:
        if S[_CU, i] >= S[_CL, i]:
            side = 1.0
            since = S[_CU_T0, i]
            mean = S[_CU_SZ, i] / S[_CU_ST, i] if S[_CU_ST, i] > 0.0 else z
        else:
            side = -1.0
            since = S[_CL_T0, i]
            mean = S[_CL_SZ, i] / S[_CL_ST, i] if S[_CL_ST, i] > 0.0 else z
        e = S[_EWMA, i]
        offset = mean
        if abs(e) > abs(mean) and e * side > 0.0:
            offset = e
        S[_SIDE, i] = side
        S[_SINCE, i] = since                     # the change start (its CUSUM run), not the hold's
        S[_OFFSET, i] = offset
        E[ne, _E_ROW] = row
        E[ne, _E_CABLE] = i
        E[ne, _E_ACTION] = 1.0
        E[ne, _E_SIDE] = side
        E[ne, _E_SINCE] = since
        E[ne, _E_OFFSET] = offset
        E[ne, _E_EWMA] = e
        E[ne, _E_BASE] = S[_BASE, i]
        ne += 1
    elif a < 0:
        E[ne, _E_ROW] = row
        E[ne, _E_CABLE] = i
        E[ne, _E_ACTION] = -1.0
        E[ne, _E_SIDE] = S[_SIDE, i]
        E[ne, _E_SINCE] = S[_SINCE, i]
        E[ne, _E_OFFSET] = S[_EWMA, i]
        E[ne, _E_EWMA] = S[_EWMA, i]
        E[ne, _E_BASE] = S[_BASE, i]
        ne += 1
        S[_SIDE, i] = 0.0
        _restart_cusum(S, i, t)
    return ne


@jit_kernel(STEP_SIGNATURE)
def _drift_step(S, P, t, r, E):
    """One tick of every cable (:func:`_drift_sample` each). Returns the number of event records."""
    return tick_samples(_drift_sample, S, P, t, r, E)


@jit_kernel(RUN_SIGNATURE)
def _drift_run(S, P, T, R, E, row0):
    """A block of ticks from row0 on (:func:`~cablesvc.alarms.residual.block_samples`)."""
    return block_samples(_drift_sample, S, P, T, R, E, row0)

class DriftDetector(ResidualDetector):
    """Per-cable drift of the residual measured - predicted [N]; see the module docstring.

    ``n_cables`` m; ``config`` a :class:`DriftConfig`; ``cable_names`` for the messages.
    :meth:`update` takes one tick (m residuals, NaN = no measurement) and returns the alarm
    events of that tick (usually none); :meth:`update_batch` takes a block of ticks and
    returns exactly what the same ticks given one by one to :meth:`update` would.
    """

    code = "drift"
    config_class = DriftConfig
    n_state = _NS
    n_record = _NE
    _step = staticmethod(_drift_step)
    _run = staticmethod(_drift_run)
    # the state rows that ResidualDetector's reset, deactivate, rebase_time, ready, active and
    # describe_state read
    state_names = _STATE_NAMES
    rest_nan_rows = (_BASE, _W_T0, _T_LAST, _CU_T0, _CL_T0, RAISE_SINCE, _CLEAR_SINCE, _SINCE, _OFFSET)
    time_rows = (_W_T0, _T_LAST, _CU_T0, _CL_T0, RAISE_SINCE, _CLEAR_SINCE, _SINCE)
    alarm_zero_rows = (_ACTIVE, _SIDE)
    alarm_nan_rows = (RAISE_SINCE, _CLEAR_SINCE, _SINCE, _OFFSET)
    ready_row = _READY
    active_row = _ACTIVE

    def __init__(self, n_cables: int, config: DriftConfig | None = None,
                 cable_names: Sequence[str] | None = None):
        super().__init__(n_cables, config, cable_names)
        if self.config.baseline_n is not None:
            self.set_baseline(self.config.baseline_n)

    # -- baseline (reset, ready: ResidualDetector's) ----------------------------------------
    def set_baseline(self, baseline_n) -> None:
        """Use this baseline [N] (a number or one per cable) instead of learning it; the
        detector's other state of every cable restarts."""
        b = np.broadcast_to(np.asarray(baseline_n, dtype=np.float64), self._shape)
        if not np.all(np.isfinite(b)):
            raise ValueError("baseline_n must be finite")
        self.reset()
        S = self._S
        S[_BASE] = b
        S[_READY] = 1.0
        S[_EWMA] = 0.0

    @property
    def baseline(self) -> np.ndarray:
        """Baseline residual per cable [N]; NaN while the cable is still warming up."""
        return np.where(self._S[_READY] > 0, self._S[_BASE], np.nan)

    @property
    def offset(self) -> np.ndarray:
        """Current EWMA offset estimate per cable [N] (NaN during the warm-up)."""
        return np.where(self._S[_READY] > 0, self._S[_EWMA], np.nan)

    @property
    def cusum(self) -> np.ndarray:
        """(2, m) current CUSUM statistics [N s]: upper (positive offsets), lower."""
        return self._S[[_CU, _CL]].copy()

    def _event(self, rec: np.ndarray, t: float, seq: int | None) -> AlarmEvent:
        i = int(rec[_E_CABLE])
        name = self.cable_names[i]
        base = float(rec[_E_BASE])
        since = float(rec[_E_SINCE])
        cfg = self.config
        if rec[_E_ACTION] > 0:
            off = float(rec[_E_OFFSET])
            msg = (f"cable {i} ({name}): measured - predicted force is {off:+.2f} N away from its baseline "
                   f"of {base:+.2f} N since t = {since:.1f} s; the cable model no longer fits this cable")
            return AlarmEvent("raise", "drift", i, self._severity, t, since, seq, msg, offset_n=off,
                              suggested_action=DRIFT_SUGGESTED_ACTION, value=off, limit=cfg.cusum_k_n)
        off = float(rec[_E_EWMA])
        msg = (f"cable {i} ({name}): measured - predicted force back within {cfg.clear_n:g} N of its "
               f"baseline of {base:+.2f} N (now {off:+.3f} N)")
        return AlarmEvent("clear", "drift", i, self._severity, t, since, seq, msg, offset_n=off,
                          value=off, limit=cfg.clear_n)
