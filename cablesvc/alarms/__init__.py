"""Alarms of the live service: model drift and spread, predicted cable state, input health.

Four detectors feed one :class:`~cablesvc.alarms.manager.AlarmManager`:

- :class:`~cablesvc.alarms.drift.DriftDetector`: with measured forces, the per-cable
  residual (measured - predicted, N) is compared with a baseline learned in a warm-up
  period and tracked with an EWMA and a two-sided CUSUM. It raises ``drift`` when the
  cable model no longer fits (paper 002, Fig 6: a 0.4 N offset after a few days).
- :class:`~cablesvc.alarms.spread.SpreadDetector`: with measured forces, the per-cable
  spread of the residual against its sensor-noise floor. It raises ``spread`` when the
  model misses a term whose error averages out (dead time, viscous or pulley friction),
  which ``drift`` cannot see.
- :class:`~cablesvc.alarms.state.StateAlarms`: without measured forces, from the
  prediction alone: ``slack``, ``over_limit``, ``wrench_residual``, ``amplitude_range``.
- :class:`~cablesvc.alarms.state.InputWatch`: ``input_stale`` / ``input_lost`` when the
  controller's ticks stop arriving (wall clock).

Every detector returns :class:`AlarmEvent` objects: one ``raise`` when a condition has
held for its hold time, one ``clear`` when the opposite condition (with hysteresis) has
held for its own hold time. Codes and severities are stable (``docs/messages.md``).

The per-tick work of the drift, spread and state detectors runs in small numba kernels (one call
per tick for all cables; no Python loop per cable). The same compiled per-sample code is
used tick by tick and by the offline ``update_batch``, so both give identical results.
:func:`jit_kernel` and :func:`jit_inline` are how the detector modules compile them (an
implementation detail of this package, not in ``__all__``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

#: alarm code -> (severity, one-line meaning). The codes are stable API.
ALARM_CODES: dict[str, tuple[str, str]] = {
    "drift": ("warning", "measured - predicted force of a cable drifted away from its baseline"),
    "spread": ("warning", "measured - predicted force of a cable spreads more than its sensor noise explains"),
    "slack": ("warning", "predicted cable tension below the robot file's force_min"),
    "over_limit": ("error", "predicted cable tension above the robot file's force_max"),
    "wrench_residual": ("warning", "predicted forces do not balance the platform (|A^T f + w| vs its weight)"),
    "input_stale": ("warning", "no input tick for longer than input.stale_s"),
    "input_lost": ("error", "no input tick for longer than input.lost_s"),
    "amplitude_range": ("info", "elongation amplitude outside the range the cable model was identified on"),
    "input_fault": ("warning", "the source rejected input (bad frame or value, missing frames, time or seq "
                               "going backwards, ...); cleared after input_fault_clear_s without rejections"),
    "params_refused": ("warning", "new cable-model parameters (SIGHUP or a put on cablesvc/<robot>/params) were "
                                  "refused; the previous ones stay active; cleared by the next accepted reload"),
}
SEVERITIES = ("info", "warning", "error")
ACTIONS = ("raise", "clear")

#: what a drift alarm suggests doing
DRIFT_SUGGESTED_ACTION = "re-identify the cable model (cablesvc identify ...)"
#: what a spread alarm suggests doing
SPREAD_SUGGESTED_ACTION = "find the missing physics term (cablesvc discover ... --out augmented.toml)"


def _num(v: float | None) -> float | None:
    """A float for JSON: None for None and for non-finite values."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


@dataclass
class AlarmEvent:
    """One alarm transition.

    ``action`` "raise" or "clear"; ``code`` one of :data:`ALARM_CODES`; ``cable`` the
    0-based cable or None; ``severity`` "info" | "warning" | "error"; ``t`` controller time
    of the event [s]; ``since`` controller time the condition started [s] (for a clear: the
    time the alarm was raised); ``seq`` the input tick or None; ``message`` plain words.
    ``offset_n`` (drift) the estimated offset of the residual from its baseline [N];
    ``suggested_action`` (drift, spread) what to do; ``value`` the measured quantity at the event
    (N for forces and the wrench residual, m for amplitudes) and ``limit`` the threshold it
    was compared with, in the same unit.
    """

    action: str
    code: str
    cable: int | None
    severity: str
    t: float
    since: float
    seq: int | None
    message: str
    offset_n: float | None = None
    suggested_action: str | None = None
    value: float | None = None
    limit: float | None = None

    @property
    def key(self) -> tuple[str, int | None]:
        """(code, cable): what identifies one alarm among the active ones."""
        return (self.code, self.cable)

    def payload(self, robot: str | None = None) -> dict[str, Any]:
        """JSON-able dict matching ``cablesvc.service.messages.ALARM_SCHEMA`` (a superset of
        the MCAP alarm schema of ``cablesvc.recording.schemas``). Non-finite numbers become
        null. ``robot`` is added when given."""
        t = _num(self.t)
        p: dict[str, Any] = {
            "action": self.action,
            "code": self.code,
            "cable": None if self.cable is None else int(self.cable),
            "severity": self.severity,
            "t": 0.0 if t is None else t,
            "since": _num(self.since),
            "seq": None if self.seq is None else int(self.seq),
            "message": self.message,
            "offset_n": _num(self.offset_n),
            "suggested_action": self.suggested_action,
            "value": _num(self.value),
            "limit": _num(self.limit),
        }
        if robot is not None:
            p["robot"] = robot
        return p

    @classmethod
    def from_payload(cls, p: dict[str, Any]) -> "AlarmEvent":
        """Inverse of :meth:`payload` (nulls stay None; ``robot`` is ignored)."""
        return cls(action=p["action"], code=p["code"], cable=p.get("cable"), severity=p["severity"],
                   t=float(p["t"]), since=float("nan") if p.get("since") is None else float(p["since"]),
                   seq=p.get("seq"), message=p["message"], offset_n=p.get("offset_n"),
                   suggested_action=p.get("suggested_action"), value=p.get("value"), limit=p.get("limit"))


def jit_kernel(signature: str):
    """numba.njit with an explicit signature (compiled once, at import, never again in the
    loop) and an on-disk cache; without a writable cache location, compile without cache."""
    import numba

    def deco(fn):
        try:
            return numba.njit(signature, cache=True, nogil=True)(fn)
        except RuntimeError:            # "cannot cache function ...: no locator available"
            return numba.njit(signature, cache=False, nogil=True)(fn)
    return deco


def jit_inline(fn):
    """numba.njit for helpers called only from other kernels (compiled into them)."""
    import numba
    return numba.njit(inline="always")(fn)


_LAZY = {
    "DriftConfig": "cablesvc.alarms.drift", "DriftDetector": "cablesvc.alarms.drift",
    "SpreadConfig": "cablesvc.alarms.spread", "SpreadDetector": "cablesvc.alarms.spread",
    "InputConfig": "cablesvc.alarms.state", "InputWatch": "cablesvc.alarms.state",
    "StateAlarmConfig": "cablesvc.alarms.state", "StateAlarms": "cablesvc.alarms.state",
    "AlarmConfig": "cablesvc.alarms.manager", "AlarmManager": "cablesvc.alarms.manager",
    "load_alarm_config": "cablesvc.alarms.manager",
}


def __getattr__(name: str):
    """The detectors load numba kernels (about a second): imported on first use, so that
    ``ALARM_CODES`` and :class:`AlarmEvent` stay cheap to import (e.g. for ``cablesvc listen``)."""
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'cablesvc.alarms' has no attribute {name!r}")
    import importlib
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value


__all__ = [
    "ACTIONS",
    "ALARM_CODES",
    "AlarmConfig",
    "AlarmEvent",
    "AlarmManager",
    "DRIFT_SUGGESTED_ACTION",
    "DriftConfig",
    "DriftDetector",
    "InputConfig",
    "InputWatch",
    "SEVERITIES",
    "SPREAD_SUGGESTED_ACTION",
    "SpreadConfig",
    "SpreadDetector",
    "StateAlarmConfig",
    "StateAlarms",
    "load_alarm_config",
]
