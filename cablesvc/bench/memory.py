"""A process's own peak resident memory, for the benchmarks that time a child process.

On Linux ``ru_maxrss`` (``getrusage``, or ``os.wait4`` on a child) keeps the peak RSS of the
process a child was forked from across the exec, so a child started from a large process
reports that process's memory. ``VmHWM`` of ``/proc/self/status`` is the process's own
peak; ``ru_maxrss`` is the fallback where there is no /proc.
"""

from __future__ import annotations

import resource

__all__ = ["own_peak_kb"]


def own_peak_kb() -> int:
    """This process's own peak RSS [kB]."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
