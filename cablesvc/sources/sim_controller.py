"""The embedded simulated controller of ``cablesvc run`` (``[source] kind = "sim"``, the
default): a digital twin of the robot (:class:`cablesvc.sources.simulated.CanController`)
sending on a virtual CAN bus that the daemon reads through the CAN source. Its
configuration is :class:`cablesvc.config.daemon.SimSource`; the daemon's planner
(:mod:`cablesvc.service.plan`) checks its rate and builds it here."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["sim_controller", "sim_rate_problem", "sim_source_id"]


def sim_controller(robot, src: dict[str, Any], *, scenario: str | None, rate: float | None, seed: int | None,
                   channel: str):
    """The embedded default: a simulated controller (not started) on a virtual CAN bus, and
    the CAN source config that reads that bus: (controller, source dict)."""
    from cablesvc.sources.simulated import CanController

    bus = {"interface": src.get("interface") or "virtual", "channel": channel}
    # 10 s of twin motion, played forwards and backwards without end
    fd = src.get("fd", True) is not False          # 1 kHz needs the FD layout (docs/sources.md)
    src = {**src, "fd": fd}
    controller = CanController(robot, bus, dbc=src.get("dbc"), scenario=scenario or "trajectory",
                               rate=1000.0 if rate is None else rate, seed=seed or 0, duration=10.0, fd=fd)
    # the controller thread shares the interpreter: allow it to be held off by the GIL mid-tick
    return controller, {"kind": "can", "interface": bus["interface"], "channel": channel, "deadline_s": 0.05,
                        **{k: v for k, v in src.items() if k in ("dbc", "deadline_s", "fd")}}


def sim_rate_problem(rate: Any, n_cables: int) -> str | None:
    """Why the embedded controller cannot tick at ``rate`` [Hz] (None: the default), or None:
    above the rate the daemon's kernel can follow (cablesvc.limits.MAX_LIVE_RATE_HZ), or
    more memory than there is for the motion it precomputes. Checked before it is built."""
    from cablesvc.limits import MAX_LIVE_RATE_HZ, SIM_CONTROLLER_SECONDS, memory_problem, twin_bytes

    if rate is None:
        return None
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (math.isfinite(rate) and rate > 0):
        return f"rate: expected a tick rate in Hz > 0 (a finite number), got {rate!r}"
    if rate > MAX_LIVE_RATE_HZ:
        return (f"rate {rate:g} Hz: the daemon's kernel cannot follow a controller faster than {MAX_LIVE_RATE_HZ} Hz "
                "(half a tick at its fastest measured 53 us per tick; cablesvc/limits.py)")
    return memory_problem(f"rate {rate:g} Hz x the {SIM_CONTROLLER_SECONDS:g} s the simulated controller precomputes",
                          twin_bytes(rate * SIM_CONTROLLER_SECONDS, n_cables))


def sim_source_id(robot_name: str) -> str:
    """The snapshot identity of an embedded simulated controller: a new one at every start
    (it starts from rest), so no later start restores its state."""
    import uuid

    return f"sim:{robot_name}:{uuid.uuid4().hex}"
