"""Resource limits of the commands and of the daemon's embedded controller, checked before
anything is allocated.

A rate, step count or duration is turned into the memory the command would take, with
the per-item costs below, and refused (one line naming the flag, non-zero exit) when that
is more than :data:`MEMORY_SHARE` of the memory available now. The live daemon's tick rate
also has a ceiling from its tick budget (:data:`MAX_LIVE_RATE_HZ`).

The per-item costs are measured, and the command that measures each is named with it.
"""

from __future__ import annotations

import os

__all__ = ["MAX_LIVE_RATE_HZ", "MEMORY_SHARE", "TWIN_BYTES_PER_TICK_CABLE", "available_memory_bytes",
           "beam_bytes", "memory_problem", "twin_bytes"]

#: a command may plan to take at most this share of the memory available when it starts
#: (the rest is the machine's: the live daemon, other users, the page cache)
MEMORY_SHARE = 0.5

#: the digital twin (``cablesvc simulate``, the simulated controller of ``cablesvc run``)
#: holds every tick of its run in memory: peak 4.7 kB per tick and cable (tracemalloc
#: peak / (ticks x cables) of ``simulate_recording``, trajectory scenario, ipanema3 4.4 kB,
#: planar4 4.7 kB; the hold scenarios 2.5-2.6 kB)
TWIN_BYTES_PER_TICK_CABLE = 4700

#: the scenarios' own durations when ``--duration`` is not given are at most the
#: trajectory's 60 s (the hold scenarios: one pass of their levels, 38 s)
TWIN_DEFAULT_DURATION_MAX_S = 60.0

#: seconds of twin motion the embedded controller of ``cablesvc run`` precomputes
#: (cablesvc.sources.sim_controller.sim_controller)
SIM_CONTROLLER_SECONDS = 10.0

#: The daemon's kernel needs about 80 numpy calls a tick (docs/performance.md: IK 20,
#: amplitude model 45, outputs 15), at its fastest measured median 53 us a tick on the
#: reference machine; with half of each tick for the kernel (the bus, alarms and Zenoh need
#: the rest) it cannot follow a controller faster than 0.5 / 53 us = 9.4 kHz.
KERNEL_TICK_FASTEST_S = 53e-6
KERNEL_TICK_SHARE = 0.5
MAX_LIVE_RATE_HZ = int(KERNEL_TICK_SHARE / KERNEL_TICK_FASTEST_S)


def available_memory_bytes() -> int | None:
    """Memory available to a new allocation now [bytes] (Linux ``MemAvailable``; else the
    free physical pages), or None when the system does not say."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _size(n: float) -> str:
    for unit, div in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n >= div:
            return f"{n / div:.3g} {unit}"
    return f"{n / 1e3:.3g} kB"


def memory_problem(what: str, nbytes: float, available: int | None = None) -> str | None:
    """Why ``what`` (the flags in words) cannot run: it needs ``nbytes`` [bytes], more than
    :data:`MEMORY_SHARE` of the available memory. None when it fits (or the system does not
    say how much is available)."""
    avail = available_memory_bytes() if available is None else available
    if avail is None or nbytes <= MEMORY_SHARE * avail:
        return None
    return (f"{what} would need about {_size(nbytes)} of memory, more than {MEMORY_SHARE:.0%} of the "
            f"{_size(avail)} available; use a lower rate, fewer steps or a shorter duration")


def twin_bytes(ticks: float, cables: int) -> float:
    """Peak memory [bytes] of a digital-twin run of ``ticks`` ticks on ``cables`` cables."""
    return float(ticks) * cables * TWIN_BYTES_PER_TICK_CABLE


def beam_bytes(lanes: int, steps_per_cycle: int, cycles: int, elements: int) -> float:
    """Memory [bytes] the beam solver allocates (cablesvc.beam.solver.solve_path and
    loop_path): the load path and its times, ``lanes x steps x cycles`` floats each, and the
    recorded last period, ``lanes x (steps + 1)`` rows of the tip (4 floats) and of every
    element's Gauss point (5 floats)."""
    steps = float(steps_per_cycle) * max(1, int(cycles))
    return 8.0 * lanes * (2.0 * steps + (float(steps_per_cycle) + 1.0) * (4.0 + 5.0 * elements))
