"""Alarms from the prediction alone (no measured forces needed), and input health.

:class:`StateAlarms` checks every tick's :class:`~cablesvc.kernel.TickOutput`:

============== ============================================ ==========================================
code           raises when (for its raise hold time)         clears when (for its clear hold time)
============== ============================================ ==========================================
slack          the kernel flags the cable slack (predicted   not slack and tension >= force_min +
               tension below its slack threshold, by         ``slack_clear_margin_n``
               default the robot file's force_min)
over_limit     tension > force_max (robot file)              tension <= force_max - ``over_limit_clear_margin_n``
wrench_residual |force part of A^T f + w| > ``wrench_raise_fraction`` x platform weight (m g); rows fx, fy
               (and fz unless planar)                        ... < ``wrench_clear_fraction`` x weight
amplitude_range amplitude A > hi (1 + tol) or A < lo (1 - tol), lo <= A <= hi
               [lo, hi] = ``params.amplitude_range()``
============== ============================================ ==========================================

Slack, over_limit and amplitude_range are per cable, wrench_residual is one alarm for
the platform (cable None). A NaN amplitude (models without one) never raises. With
dynamics, A^T f + w equals the platform's inertial force m a: the default raise level
(25 % of the weight) corresponds to about 2.5 m/s^2, more than a cable robot commands
near its operating point; a larger residual means the predicted forces are inconsistent.

:class:`InputWatch` raises ``input_stale`` when no input tick has arrived for
``stale_s`` seconds of wall time and ``input_lost`` after ``lost_s``; both clear at the next
tick. Before the first tick only ``input_lost`` can be raised.

Units: N, m, s.
"""

from __future__ import annotations

import math
import time
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from cablesvc.alarms import ALARM_CODES, AlarmEvent, jit_inline, jit_kernel
from cablesvc.config.params import ModelParams
from cablesvc.config.robot import RobotGeometry

__all__ = ["InputConfig", "InputWatch", "StateAlarmConfig", "StateAlarms"]


class StateAlarmConfig(BaseModel):
    """Tuning of the state alarms (``[alarms.state]``). SI units: N, m, s; fractions are of
    the platform weight m g [N]."""

    model_config = ConfigDict(extra="forbid")

    slack: bool = Field(True, description="raise 'slack' alarms")
    slack_raise_hold_s: float = Field(0.05, ge=0.0, description="slack must last this long to raise [s]")
    slack_clear_hold_s: float = Field(0.5, ge=0.0, description="tension must be back this long to clear [s]")
    slack_clear_margin_n: float = Field(1.0, ge=0.0, description="clear needs tension >= force_min + this [N]")

    over_limit: bool = Field(True, description="raise 'over_limit' alarms")
    over_limit_raise_hold_s: float = Field(0.0, ge=0.0, description="over force_max this long to raise [s] (0: at once)")
    over_limit_clear_hold_s: float = Field(0.5, ge=0.0, description="back under the limit this long to clear [s]")
    over_limit_clear_margin_n: float = Field(1.0, ge=0.0, description="clear needs tension <= force_max - this [N]")

    wrench_residual: bool = Field(True, description="raise 'wrench_residual' alarms")
    wrench_raise_fraction: float = Field(0.25, gt=0.0, description="raise above this fraction of m g")
    wrench_clear_fraction: float = Field(0.15, gt=0.0, description="clear below this fraction of m g")
    wrench_raise_hold_s: float = Field(0.2, ge=0.0, description="[s]")
    wrench_clear_hold_s: float = Field(1.0, ge=0.0, description="[s]")

    amplitude_range: bool = Field(True, description="raise 'amplitude_range' alarms (needs a known range)")
    amplitude_tolerance: float = Field(0.1, ge=0.0, description="relative margin outside [lo, hi] before raising")
    amplitude_raise_hold_s: float = Field(1.0, ge=0.0, description="[s]")
    amplitude_clear_hold_s: float = Field(1.0, ge=0.0, description="[s]")

    @model_validator(mode="after")
    def _check(self) -> "StateAlarmConfig":
        if self.wrench_clear_fraction > self.wrench_raise_fraction:
            raise ValueError("wrench_clear_fraction must not exceed wrench_raise_fraction (hysteresis)")
        return self


class InputConfig(BaseModel):
    """Input watch (``[alarms.input]``), wall-clock seconds."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = True
    stale_s: float = Field(0.05, gt=0.0, description="no tick for this long: input_stale [s]")
    lost_s: float = Field(1.0, gt=0.0, description="no tick for this long: input_lost [s]")

    @model_validator(mode="after")
    def _check(self) -> "InputConfig":
        if self.lost_s < self.stale_s:
            raise ValueError("lost_s must be >= stale_s")
        return self


# ---- kernel --------------------------------------------------------------------------------
# channel state rows (4, C), C = 3 m + 1 channels: slack[m], over_limit[m], amplitude[m], wrench
ACTIVE, RAISE_SINCE, CLEAR_SINCE, SINCE = range(4)
_KINDS = ("slack", "over_limit", "amplitude_range", "wrench_residual")
# parameters
(_P_SLACK, _P_SLACK_RH, _P_SLACK_CH, _P_SLACK_MARGIN,
 _P_OVER, _P_OVER_RH, _P_OVER_CH, _P_OVER_MARGIN,
 _P_AMP, _P_AMP_LO, _P_AMP_HI, _P_AMP_TOL, _P_AMP_RH, _P_AMP_CH,
 _P_WR, _P_WR_RAISE, _P_WR_CLEAR, _P_WR_RH, _P_WR_CH, _P_PLANAR) = range(20)
_NP = 20
_KIND_FLAG = {"slack": _P_SLACK, "over_limit": _P_OVER, "amplitude_range": _P_AMP, "wrench_residual": _P_WR}
# event records (C, 5): channel, action (+1 raise, -1 clear), since, value, limit
_E_CH, _E_ACTION, _E_SINCE, _E_VALUE, _E_LIMIT = range(5)


@jit_inline
def hold_rows(ST, c, t, raise_cond, clear_cond, raise_hold, clear_hold, active, raise_since, clear_since, since):
    """Hold-time state machine of channel c at time t, on the state rows ``active`` (1 while
    raised), ``raise_since`` / ``clear_since`` (start of a pending raise / clear, NaN when
    none) and ``since`` (start of the raised alarm): +1 raised, -1 cleared, 0 nothing.

    A raise needs ``raise_cond`` for ``raise_hold`` [s], a clear ``clear_cond`` for
    ``clear_hold`` [s]; the condition failing once drops the pending timer. A pending
    raise/clear whose start lies after t (the controller clock restarted, or a snapshot of
    an older run was restored) restarts its hold timer at t; otherwise a timer from the old
    time base would hold the alarm back for the old uptime."""
    if ST[active, c] == 0.0:
        if raise_cond:
            # not pending (NaN), or the clock went back: (re)start the timer
            if ST[raise_since, c] != ST[raise_since, c] or t < ST[raise_since, c]:
                ST[raise_since, c] = t
            if t - ST[raise_since, c] >= raise_hold:
                ST[active, c] = 1.0
                ST[since, c] = ST[raise_since, c]
                ST[raise_since, c] = math.nan
                ST[clear_since, c] = math.nan
                return 1
        else:
            ST[raise_since, c] = math.nan
    else:
        if clear_cond:
            # not pending (NaN), or the clock went back: (re)start the timer
            if ST[clear_since, c] != ST[clear_since, c] or t < ST[clear_since, c]:
                ST[clear_since, c] = t
            if t - ST[clear_since, c] >= clear_hold:
                ST[active, c] = 0.0
                ST[clear_since, c] = math.nan
                return -1
        else:
            ST[clear_since, c] = math.nan
    return 0


@jit_inline
def hold(ST, c, t, raise_cond, clear_cond, raise_hold, clear_hold):
    """:func:`hold_rows` on the state alarms' rows (ACTIVE, RAISE_SINCE, CLEAR_SINCE, SINCE),
    which the spread detector's state starts with as well."""
    return hold_rows(ST, c, t, raise_cond, clear_cond, raise_hold, clear_hold, ACTIVE, RAISE_SINCE, CLEAR_SINCE,
                     SINCE)


@jit_inline
def _record(E, ne, c, action, since, value, limit):
    E[ne, _E_CH] = c
    E[ne, _E_ACTION] = action
    E[ne, _E_SINCE] = since
    E[ne, _E_VALUE] = value
    E[ne, _E_LIMIT] = limit
    return ne + 1


@jit_kernel("int64(float64[:, ::1], float64[::1], float64[:, ::1], float64, float64[::1], boolean[::1], "
      "float64[::1], float64[::1], float64[:, ::1])")
def _state_step(ST, P, L, t, force, slack, wres, amp, E):
    """One tick of every state alarm. L (2, m): force_min, force_max [N]. Returns records."""
    m = force.shape[0]
    ne = 0
    if P[_P_SLACK] != 0.0:
        margin = P[_P_SLACK_MARGIN]
        for i in range(m):
            f = force[i]
            a = hold(ST, i, t, slack[i], (not slack[i]) and f >= L[0, i] + margin,
                      P[_P_SLACK_RH], P[_P_SLACK_CH])
            if a > 0:
                ne = _record(E, ne, i, 1.0, ST[SINCE, i], f, L[0, i])
            elif a < 0:
                ne = _record(E, ne, i, -1.0, ST[SINCE, i], f, L[0, i] + margin)
    if P[_P_OVER] != 0.0:
        margin = P[_P_OVER_MARGIN]
        for i in range(m):
            f = force[i]
            c = m + i
            a = hold(ST, c, t, f > L[1, i], f <= L[1, i] - margin, P[_P_OVER_RH], P[_P_OVER_CH])
            if a > 0:
                ne = _record(E, ne, c, 1.0, ST[SINCE, c], f, L[1, i])
            elif a < 0:
                ne = _record(E, ne, c, -1.0, ST[SINCE, c], f, L[1, i] - margin)
    if P[_P_AMP] != 0.0:
        lo = P[_P_AMP_LO]
        hi = P[_P_AMP_HI]
        tol = P[_P_AMP_TOL]
        for i in range(m):
            A = amp[i]
            c = 2 * m + i
            above = A > hi * (1.0 + tol)
            below = A < lo * (1.0 - tol)
            a = hold(ST, c, t, above or below, A >= lo and A <= hi, P[_P_AMP_RH], P[_P_AMP_CH])
            if a > 0:
                ne = _record(E, ne, c, 1.0, ST[SINCE, c], A, hi if above else lo)
            elif a < 0:
                ne = _record(E, ne, c, -1.0, ST[SINCE, c], A, hi if A > 0.5 * (lo + hi) else lo)
    if P[_P_WR] != 0.0:
        s = wres[0] * wres[0] + wres[1] * wres[1]
        if P[_P_PLANAR] == 0.0:
            s += wres[2] * wres[2]
        norm = math.sqrt(s)
        c = 3 * m
        a = hold(ST, c, t, norm > P[_P_WR_RAISE], norm < P[_P_WR_CLEAR], P[_P_WR_RH], P[_P_WR_CH])
        if a > 0:
            ne = _record(E, ne, c, 1.0, ST[SINCE, c], norm, P[_P_WR_RAISE])
        elif a < 0:
            ne = _record(E, ne, c, -1.0, ST[SINCE, c], norm, P[_P_WR_CLEAR])
    return ne


class StateAlarms:
    """slack / over_limit / wrench_residual / amplitude_range from the prediction alone.

    ``geom`` gives force_min, force_max, the platform weight and the cable names; ``params``
    the identified amplitude range (``params.amplitude_range()``; None switches the
    amplitude alarm off). One numba call per tick for all alarms; no allocation unless an
    event happens.
    """

    def __init__(self, geom: RobotGeometry, params: ModelParams | None, config: StateAlarmConfig | None = None):
        self.config = cfg = config if config is not None else StateAlarmConfig()
        self.geom = geom
        m = self.n_cables = geom.n_cables
        self.cable_names = tuple(geom.cable_names)
        self.weight_n = float(geom.mass * np.linalg.norm(geom.gravity))
        rng = params.amplitude_range() if params is not None else None
        self.amplitude_range = rng
        P = np.zeros(_NP)
        P[_P_SLACK] = float(cfg.slack)
        P[_P_SLACK_RH] = cfg.slack_raise_hold_s
        P[_P_SLACK_CH] = cfg.slack_clear_hold_s
        P[_P_SLACK_MARGIN] = cfg.slack_clear_margin_n
        P[_P_OVER] = float(cfg.over_limit)
        P[_P_OVER_RH] = cfg.over_limit_raise_hold_s
        P[_P_OVER_CH] = cfg.over_limit_clear_hold_s
        P[_P_OVER_MARGIN] = cfg.over_limit_clear_margin_n
        P[_P_AMP] = float(cfg.amplitude_range and rng is not None)
        P[_P_AMP_LO], P[_P_AMP_HI] = rng if rng is not None else (math.nan, math.nan)
        P[_P_AMP_TOL] = cfg.amplitude_tolerance
        P[_P_AMP_RH] = cfg.amplitude_raise_hold_s
        P[_P_AMP_CH] = cfg.amplitude_clear_hold_s
        P[_P_WR] = float(cfg.wrench_residual)
        P[_P_WR_RAISE] = cfg.wrench_raise_fraction * self.weight_n
        P[_P_WR_CLEAR] = cfg.wrench_clear_fraction * self.weight_n
        P[_P_WR_RH] = cfg.wrench_raise_hold_s
        P[_P_WR_CH] = cfg.wrench_clear_hold_s
        P[_P_PLANAR] = float(bool(geom.planar))
        self._P = P
        self._L = np.ascontiguousarray(np.stack([np.broadcast_to(geom.force_min, (m,)),
                                                 np.broadcast_to(geom.force_max, (m,))]), dtype=np.float64)
        self._C = 3 * m + 1
        self._ST = np.zeros((4, self._C))
        self._ST[1:] = np.nan
        self._E = np.zeros((self._C, 5))
        self._nan_m = np.full(m, np.nan)
        self._slack_buf = np.zeros(m, dtype=bool)
        self._sev = {k: ALARM_CODES[k][0] for k in _KINDS}

    def update(self, t: float, seq: int | None, out) -> list[AlarmEvent]:
        """One tick's :class:`~cablesvc.kernel.TickOutput` (only force, slack, wrench_residual
        and amplitude are read). Returns the events of this tick (usually none)."""
        try:
            n = _state_step(self._ST, self._P, self._L, t, out.force, out.slack, out.wrench_residual,
                            out.amplitude, self._E)
        except TypeError:                # other dtypes / layouts than the kernel's buffers
            n = self._update_coerced(float(t), out)
        if n == 0:
            return []
        return [self._event(self._E[j], float(t), seq) for j in range(n)]

    def _update_coerced(self, t: float, out) -> int:
        m = self.n_cables

        def vec(a, size):
            v = np.array(a, dtype=np.float64, order="C", copy=True).reshape(-1)
            if v.shape != (size,):
                raise ValueError(f"expected {size} values, got shape {np.shape(a)}")
            return v
        amp = self._nan_m if out.amplitude is None else vec(out.amplitude, m)
        slack = np.array(out.slack, dtype=bool, order="C", copy=True).reshape(-1)
        if slack.shape != (m,):
            raise ValueError(f"expected {m} slack flags, got shape {np.shape(out.slack)}")
        return _state_step(self._ST, self._P, self._L, t, vec(out.force, m), slack,
                           vec(out.wrench_residual, 6), amp, self._E)

    def _event(self, rec: np.ndarray, t: float, seq: int | None) -> AlarmEvent:
        m = self.n_cables
        c = int(rec[_E_CH])
        raised = rec[_E_ACTION] > 0
        action = "raise" if raised else "clear"
        since = float(rec[_E_SINCE])
        v = float(rec[_E_VALUE])
        lim = float(rec[_E_LIMIT])
        if c < 3 * m:
            kind = _KINDS[c // m]
            i = c % m
            who = f"cable {i} ({self.cable_names[i]})"
        else:
            kind = "wrench_residual"
            i = None
        if kind == "slack":
            msg = (f"{who}: predicted tension {v:.1f} N is below force_min {lim:.1f} N, the cable is slack"
                   if raised else f"{who}: predicted tension {v:.1f} N is back above {lim:.1f} N")
        elif kind == "over_limit":
            msg = (f"{who}: predicted tension {v:.1f} N exceeds force_max {lim:.1f} N"
                   if raised else f"{who}: predicted tension {v:.1f} N is back below {lim:.1f} N")
        elif kind == "amplitude_range":
            lo, hi = self.amplitude_range
            msg = (f"{who}: elongation amplitude {v * 1e3:.3f} mm is outside the identified range "
                   f"{lo * 1e3:.3f}-{hi * 1e3:.3f} mm; the cable model extrapolates" if raised else
                   f"{who}: elongation amplitude {v * 1e3:.3f} mm is back inside the identified range "
                   f"{lo * 1e3:.3f}-{hi * 1e3:.3f} mm")
        else:
            msg = (f"the predicted forces leave {v:.1f} N of force unbalanced on the platform (|A^T f + w|), "
                   f"more than {lim:.1f} N = {self.config.wrench_raise_fraction:g} x its weight" if raised else
                   f"the force residual |A^T f + w| is {v:.1f} N, back below {lim:.1f} N")
        return AlarmEvent(action, kind, i, self._sev[kind], t, since, seq, msg, value=v, limit=lim)

    def set_amplitude_range(self, rng: tuple[float, float] | None) -> None:
        """New parameters were loaded (the daemon's reload): use their identified amplitude
        range [m] from the next tick on (None switches the amplitude alarm off). The
        channels' states (active alarms, hold timers) are kept."""
        self.amplitude_range = rng
        P = self._P
        P[_P_AMP] = float(self.config.amplitude_range and rng is not None)
        P[_P_AMP_LO], P[_P_AMP_HI] = rng if rng is not None else (math.nan, math.nan)

    def state_dict(self) -> dict[str, np.ndarray]:
        """Alarm states (active, pending since, ...) per channel, numeric only."""
        return {"state": self._ST.copy()}

    def rebase_time(self, delta: float) -> None:
        """Move the restored timers (pending raise / clear, active since) by ``delta`` [s]
        into the current session's time base (see AlarmManager.rebase_time)."""
        self._ST[RAISE_SINCE:] += delta

    def enabled(self, kind: str) -> bool:
        """Whether alarm ``kind`` (one of slack, over_limit, amplitude_range,
        wrench_residual) runs with this config (amplitude_range also needs a known range)."""
        return self._P[_KIND_FLAG[kind]] != 0.0

    def load_state_dict(self, d: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state_dict`. The channels of alarms disabled in this config
        restart inactive with no pending timer: they would never run again to clear."""
        ST = np.asarray(d["state"], dtype=np.float64)
        if ST.shape != self._ST.shape:
            raise ValueError(f"state-alarm state of shape {ST.shape} does not fit {self.n_cables} cables")
        self._ST[...] = ST
        m = self.n_cables
        for k, kind in enumerate(_KINDS):            # channels k m .. k m + m (wrench: one)
            if not self.enabled(kind):
                ch = slice(k * m, k * m + (1 if kind == "wrench_residual" else m))
                self._ST[ACTIVE, ch] = 0.0
                self._ST[RAISE_SINCE:, ch] = np.nan


class InputWatch:
    """Input health from the wall clock (``time.monotonic()`` seconds).

    :meth:`tick` is called for every input tick (``t`` controller time [s], ``seq``) and
    returns the clear events when ticks resume; :meth:`poll` is called by the daemon loop
    whenever it is idle and returns ``input_stale`` (no tick for > ``stale_s``) and
    ``input_lost`` (> ``lost_s``) raise events. The reference before the first tick is the
    first :meth:`poll` (or :meth:`start`). Event times are controller time extrapolated from
    the last tick with the wall clock.
    """

    def __init__(self, stale_s: float = 0.05, lost_s: float = 1.0, *, enabled: bool = True):
        if not (0 < stale_s <= lost_s):
            raise ValueError("need 0 < stale_s <= lost_s")
        self.stale_s = float(stale_s)
        self.lost_s = float(lost_s)
        self.enabled = bool(enabled)
        self._wall: float | None = None          # wall time of the last tick (or of start)
        self._t = math.nan                       # controller time of the last tick
        self._seq: int | None = None
        self._ticked = False
        self._stale: AlarmEvent | None = None    # active raise events
        self._lost: AlarmEvent | None = None

    def start(self, wall_monotonic: float | None = None) -> None:
        """Start the clock before the first tick (otherwise the first poll starts it)."""
        if self._wall is None:
            self._wall = time.monotonic() if wall_monotonic is None else float(wall_monotonic)

    def tick(self, t: float, seq: int | None, wall_monotonic: float | None = None) -> list[AlarmEvent]:
        """An input tick arrived (now, or at ``wall_monotonic``). Returns clear events."""
        wall = time.monotonic() if wall_monotonic is None else wall_monotonic
        prev = self._wall
        self._wall = wall
        self._t = t
        self._seq = seq
        self._ticked = True
        if self._stale is None and self._lost is None:
            return []
        gap = wall - prev if prev is not None else math.nan
        out = []
        for ev in (self._stale, self._lost):
            if ev is not None:
                out.append(AlarmEvent("clear", ev.code, None, ev.severity, float(t), ev.since, seq,
                                      f"input ticks arrive again (gap {gap:.3f} s)", value=gap,
                                      limit=ev.limit))
        self._stale = self._lost = None
        return out

    def poll(self, wall_monotonic: float) -> list[AlarmEvent]:
        """Check the time since the last tick at wall time ``wall_monotonic`` [s]."""
        if not self.enabled:
            return []
        if self._wall is None:
            self._wall = wall_monotonic
            return []
        gap = wall_monotonic - self._wall
        if gap <= self.stale_s or (self._lost is not None):
            return []
        out = []
        t_est = self._t + gap if self._ticked else math.nan
        if self._ticked and self._stale is None:
            self._stale = AlarmEvent("raise", "input_stale", None, ALARM_CODES["input_stale"][0], t_est, self._t,
                                     self._seq, f"no input tick for {gap:.3f} s (more than {self.stale_s:g} s)",
                                     value=gap, limit=self.stale_s)
            out.append(self._stale)
        if gap > self.lost_s:
            what = f"no input tick for {gap:.3f} s" if self._ticked else f"no input tick in the first {gap:.3f} s"
            self._lost = AlarmEvent("raise", "input_lost", None, ALARM_CODES["input_lost"][0], t_est, self._t,
                                    self._seq, f"{what} (more than {self.lost_s:g} s): the input is lost",
                                    value=gap, limit=self.lost_s)
            out.append(self._lost)
        return out

    def active(self) -> list[AlarmEvent]:
        return [e for e in (self._stale, self._lost) if e is not None]
