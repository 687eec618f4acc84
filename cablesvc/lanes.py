"""Lane dispatch: whether a numba kernel over independent lanes (parameter sets, load paths)
runs its ``prange`` form in numba's threads or its plain loop.

Each kernel compiles the two loops itself (``parallel=True`` is a property of the compiled
function); the choice between them is made here, once, for the benchmark oscillator
(:mod:`cablesvc.simulate.oscillator`) and the beam (:mod:`cablesvc.beam.solver`).
"""

from __future__ import annotations

import numba

__all__ = ["run_lanes"]


def run_lanes(parallel, serial, lanes: int, *args, threads: bool = True, min_per_thread: int = 0) -> None:
    """Call ``parallel(*args)`` when ``threads`` is on, numba has more than one thread and
    there are at least 2 lanes and ``min_per_thread`` lanes per thread; ``serial(*args)``
    otherwise. Waking the thread pool costs milliseconds on a loaded machine, so a kernel
    whose lanes are short asks for a few lanes per thread (the oscillator: 2); the results
    do not depend on the choice (the lanes are independent)."""
    n = numba.get_num_threads()
    if threads and n > 1 and lanes >= max(2, min_per_thread * n):
        parallel(*args)
    else:
        serial(*args)
