"""One place for the live service's alarms: drift, spread, state alarms and the input watch.

The daemon calls :meth:`AlarmManager.on_tick` once per processed tick and
:meth:`AlarmManager.on_idle` whenever its loop waits; both return the events to publish
(usually none). The manager keeps the set of active alarms (what the status query shows),
counts raises per code, and snapshots its state for restarts.

Configuration is an :class:`AlarmConfig`, in TOML a table with four sub-tables::

    [alarms.drift]          # DriftConfig: N, s
    warmup_s = 60.0
    cusum_h_ns = 2.0
    [alarms.spread]         # SpreadConfig: N, s
    raise_ratio = 1.5
    [alarms.state]          # StateAlarmConfig
    wrench_raise_fraction = 0.25
    [alarms.input]          # InputConfig: wall-clock s
    stale_s = 0.05
    lost_s = 1.0
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from cablesvc.alarms import AlarmEvent
from cablesvc.alarms.drift import DriftConfig, DriftDetector
from cablesvc.alarms.spread import SpreadConfig, SpreadDetector
from cablesvc.alarms.state import InputConfig, InputWatch, StateAlarmConfig, StateAlarms
from cablesvc.config.params import ModelParams
from cablesvc.config.robot import RobotGeometry

__all__ = ["AlarmConfig", "AlarmManager", "load_alarm_config"]

_STATE_CODES = ("slack", "over_limit", "amplitude_range", "wrench_residual")


class AlarmConfig(BaseModel):
    """All alarm settings: ``drift``, ``spread``, ``state`` and ``input`` sections."""

    model_config = ConfigDict(extra="forbid")

    drift: DriftConfig = Field(default_factory=DriftConfig)
    spread: SpreadConfig = Field(default_factory=SpreadConfig)
    state: StateAlarmConfig = Field(default_factory=StateAlarmConfig)
    input: InputConfig = Field(default_factory=InputConfig)

    @classmethod
    def from_toml(cls, text: str, table: str | None = "alarms") -> "AlarmConfig":
        """Parse TOML text; ``table`` is the (dotted) table holding the sections, None for the
        top level. A missing table gives the defaults."""
        data: Any = tomllib.loads(text)
        for part in (table.split(".") if table else ()):
            data = data.get(part, {}) if isinstance(data, dict) else {}
        return cls.model_validate(data)


def load_alarm_config(path: str | Path, table: str | None = "alarms") -> AlarmConfig:
    """Read an :class:`AlarmConfig` from the ``[alarms]`` table (or ``table``) of a TOML file.
    Raises ValueError naming the file on a syntax or validation error."""
    p = Path(path)
    try:
        return AlarmConfig.from_toml(p.read_text(), table)
    except (tomllib.TOMLDecodeError, ValueError) as e:
        raise ValueError(f"{p}: invalid alarm configuration: {e}") from None


class AlarmManager:
    """Holds a :class:`DriftDetector`, a :class:`SpreadDetector`, :class:`StateAlarms` and an
    :class:`InputWatch`.

    ``geom`` the robot, ``params`` the cable model's parameters (for the identified
    amplitude range), ``config`` an :class:`AlarmConfig`.
    """

    def __init__(self, geom: RobotGeometry, params: ModelParams | None, config: AlarmConfig | None = None):
        self.config = cfg = config if config is not None else AlarmConfig()
        self.geom = geom
        self.drift = DriftDetector(geom.n_cables, cfg.drift, geom.cable_names)
        self.state = StateAlarms(geom, params, cfg.state)
        self.watch = InputWatch(cfg.input.stale_s, cfg.input.lost_s, enabled=cfg.input.enabled)
        self._drift_on = bool(cfg.drift.enabled)
        self.spread = SpreadDetector(geom.n_cables, cfg.spread, geom.cable_names)
        self._spread_on = bool(cfg.spread.enabled)
        self._active: dict[tuple[str, int | None], AlarmEvent] = {}
        self.counters: dict[str, int] = {}          # raises per code since start (or snapshot)
        self.events_total = 0

    def on_tick(self, t: float, seq: int | None, out) -> list[AlarmEvent]:
        """One processed tick (``out`` the kernel's :class:`~cablesvc.kernel.TickOutput`).
        Drift and spread run on the cables whose ``out.residual`` is finite (measured forces
        present)."""
        ev = self.watch.tick(t, seq)
        ev2 = self.state.update(t, seq, out)
        ev3 = self.drift.update(t, seq, out.residual) if self._drift_on else ev2[:0]
        ev4 = self.spread.update(t, seq, out.residual) if self._spread_on else ev2[:0]
        if ev or ev2 or ev3 or ev4:
            events = ev + ev2 + ev3 + ev4
            self._account(events)
            return events
        return ev

    def on_idle(self, wall_monotonic: float) -> list[AlarmEvent]:
        """The daemon loop is waiting: check the input watch at wall time [s] (monotonic)."""
        events = self.watch.poll(wall_monotonic)
        if events:
            self._account(events)
        return events

    def _account(self, events: list[AlarmEvent]) -> None:
        for e in events:
            self.events_total += 1
            if e.action == "raise":
                self._active[e.key] = e
                self.counters[e.code] = self.counters.get(e.code, 0) + 1
            else:
                self._active.pop(e.key, None)

    def active(self) -> list[AlarmEvent]:
        """The raise events of the alarms active now, oldest condition first."""
        return sorted(self._active.values(), key=lambda e: (e.since if e.since == e.since else e.t, e.code,
                                                            -1 if e.cable is None else e.cable))

    def reset_drift(self, cables=None) -> list[AlarmEvent]:
        """Restart the residual detectors, drift's baseline and spread's statistics (after
        re-identification or new parameters: the residual is another model's, and a spread
        window still full of the old model's residual would raise again at once); returns
        clear events for the drift and spread alarms that were active on those cables. Both
        warm up again."""
        idx = range(self.geom.n_cables) if cables is None else cables
        out = []
        for i in idx:
            for code in ("drift", "spread"):
                e = self._active.get((code, int(i)))
                if e is not None:
                    out.append(AlarmEvent("clear", code, int(i), e.severity, e.t, e.since, e.seq,
                                          f"cable {int(i)}: {code} restarted with the new model"))
        self.drift.reset(cables)
        self.spread.reset(cables)
        self._account(out)
        return out

    def set_params(self, params: ModelParams | None, t: float, seq: int | None) -> list[AlarmEvent]:
        """New cable-model parameters (the daemon's reload at a tick boundary): the state
        alarms use their identified amplitude range from the next tick on. Returns clear
        events for active ``amplitude_range`` alarms when the new parameters have no range
        (that alarm is then off and could never clear by itself). Drift is not touched here:
        the caller restarts its baseline (:meth:`reset_drift`) when the model changed."""
        rng = params.amplitude_range() if params is not None else None
        self.state.set_amplitude_range(rng)
        out = []
        if not self.state.enabled("amplitude_range"):
            for key, e in list(self._active.items()):
                if e.code == "amplitude_range":
                    out.append(AlarmEvent("clear", e.code, e.cable, e.severity, t, e.since, seq,
                                          f"cable {e.cable}: the new model parameters have no identified "
                                          "amplitude range; amplitude alarm off"))
        self._account(out)
        return out

    # -- snapshots ---------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        """Nested dict of numpy arrays and strings (no objects): drift and state-alarm state,
        active alarms and counters. The input watch restarts with the process."""
        return {
            "drift": self.drift.state_dict(),
            "spread": self.spread.state_dict(),
            "state": self.state.state_dict(),
            "active": np.array(json.dumps([e.payload() for e in self._active.values()])),
            "counters": np.array(json.dumps(self.counters)),
        }

    def rebase_time(self, delta: float) -> None:
        """Move every restored time (alarm ``since`` and ``t``, hold and warm-up timers, the
        detectors' last-sample times) by ``delta`` [s] into this session's time base: after a
        restore, ``delta`` = the first tick's t - the snapshot's last t, so that an alarm keeps
        its age (the downtime is not counted) whatever the controller clock did meanwhile
        (also when it restarted from 0). NaN (no timer) stays NaN."""
        if not math.isfinite(delta) or delta == 0.0:
            return
        self.drift.rebase_time(delta)
        self.spread.rebase_time(delta)
        self.state.rebase_time(delta)
        for key, e in list(self._active.items()):
            self._active[key] = dataclasses.replace(
                e, t=e.t + delta if e.t is not None else None,
                since=e.since + delta if e.since is not None else None)

    def _enabled(self, code: str | None) -> bool:
        """Whether the detector of alarm ``code`` runs with this manager's config."""
        if code == "drift":
            return self._drift_on
        if code == "spread":
            return self._spread_on
        if code in _STATE_CODES:
            return self.state.enabled(code)
        return True

    def load_state_dict(self, d: dict[str, Any]) -> None:
        """Continue from :meth:`state_dict` (also after a save/load through ``np.savez``,
        where strings come back as 0-d arrays or numpy strings). Missing parts are skipped.

        Alarms whose detector is disabled in this config (e.g. ``[alarms.state] slack =
        false`` or ``[alarms.drift] enabled = false``) are dropped: they could never clear
        and would be written into every later snapshot. Their per-channel state restarts
        inactive. No clear event is published for them: nothing was raised in this run, so
        a subscriber of this run has nothing to clear (the status query no longer lists
        them). The same holds for the wall-clock input alarms, which never survive a restart.
        """
        if "drift" in d and "state" in d["drift"]:
            self.drift.load_state_dict(d["drift"])
            if not self._drift_on:
                self.drift.deactivate()
        if "spread" in d and "state" in d["spread"]:      # snapshots from before the spread alarm lack it
            self.spread.load_state_dict(d["spread"])
            if not self._spread_on:
                self.spread.deactivate()
        if "state" in d and "state" in d["state"]:
            self.state.load_state_dict(d["state"])       # zeroes the disabled channels itself
        if "active" in d:
            active = json.loads(str(np.asarray(d["active"])[()]))
            self._active = {}
            for p in active:
                if p.get("code") in ("input_stale", "input_lost"):
                    continue              # wall-clock alarms do not survive a restart
                if not self._enabled(p.get("code")):
                    continue              # detector disabled now: it would never clear
                e = AlarmEvent.from_payload(p)
                self._active[e.key] = e
        if "counters" in d:
            self.counters = {str(k): int(v) for k, v in json.loads(str(np.asarray(d["counters"])[()])).items()}
