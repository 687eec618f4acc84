"""``cablesvc run`` in the foreground, for one robot or a fleet: the signals (SIGINT / SIGTERM
during start-up end it with status 130, SIGHUP re-reads the parameter files), the wait for
the end (``--seconds``, a signal, the loops ending) and the live terminal view."""

from __future__ import annotations

import logging
import signal
import threading
import time
from typing import Callable

__all__ = ["StartupInterrupted", "interrupt_startup", "hup_during_startup", "reload_on_sighup", "wait_until_stopped",
           "view", "print_last_frame"]


class StartupInterrupted(Exception):
    """SIGINT or SIGTERM while the daemon was starting: nothing runs yet (exit status 130)."""


def interrupt_startup(signum, frame):
    raise StartupInterrupted(signal.Signals(signum).name)


#: SIGHUP received while starting (before a daemon could take it): reload once it runs
_HUP_EARLY: list[int] = []


def hup_during_startup(signum, frame):
    _HUP_EARLY.append(signum)


def reload_on_sighup(daemons) -> None:
    """From here on SIGHUP makes every daemon re-read its parameter file (the handler only
    queues the request; each daemon's reload thread reads and checks the file, its loop
    switches between two ticks). A SIGHUP that came during start-up is served now."""
    def on_hup(signum, frame):
        for d in daemons:
            d.request_reload(origin="SIGHUP")

    signal.signal(signal.SIGHUP, on_hup)
    if _HUP_EARLY:
        _HUP_EARLY.clear()
        on_hup(signal.SIGHUP, None)


def wait_until_stopped(alive: Callable[[], bool], stop: threading.Event, deadline: float | None) -> None:
    """Without a view: wait while ``alive()`` and ``stop`` is not set; at ``deadline``
    (time.monotonic(), None: never) set ``stop``."""
    while alive() and not stop.is_set():
        stop.wait(0.1)
        if deadline is not None and time.monotonic() >= deadline:
            stop.set()


def _since(v) -> str:
    """An alarm's ``since`` [s] for the view: null (raised before the first tick) is "-"."""
    return "-" if v is None else f"{v:.2f}"


def view(robots, stop: threading.Event, alive: Callable[[], bool], deadline,
         last_frame: list | None = None) -> None:
    """Live terminal view of forces and alarms (main thread), refreshed eight times a second:
    one forces table per robot (``robots``: (daemon, robot, geometry) tuples) and the
    active alarms of all of them. Runs while ``alive()`` and ``stop`` is not set.

    The live display is cleared when it ends: the caller prints the last frame with
    :func:`print_last_frame` (``last_frame`` receives the renderer) once the loops have ended
    and the daemons drained their sources. Drawn at the exit of the display instead, while the
    source still queued ticks, it held the interpreter ~30-150 ms, and the ticks drained after
    it took that long (the README's main command: p99.9 of the tick latency 40-125 ms, 62 of the
    64 ticks over 10 ms in a 10 s run the last ones; 2.3-2.8 ms without the view)."""
    import numpy as np
    from rich.console import Group
    from rich.live import Live
    from rich.table import Table
    from rich.text import Text

    several = len(robots) > 1

    def render():
        parts = []
        al = Table(title="active alarms", expand=False)
        for col in (("robot",) if several else ()) + ("code", "cable", "severity", "since s", "message"):
            al.add_column(col)
        for daemon, robot, geom in robots:
            st = daemon.status()
            v = daemon.view()
            lat = st["latency_us"]
            head = (f"cablesvc · {robot.name} · {st['input']['source']} · {st['tick_rate_hz']:.0f} Hz · "
                    f"{st['ticks']} ticks · latency p50/p99 {lat.get('p50_us', 0)}/{lat.get('p99_us', 0)} us · "
                    f"rejected {sum(st['input'].get('rejected', {}).values())}")
            tb = Table(title=head, expand=False)
            for col in ("cable", "predicted N", "measured N", "residual N", "elongation mm", "wrap deg", "slack"):
                tb.add_column(col, justify="right")
            if v is not None:
                for i in range(geom.n_cables):
                    tb.add_row(geom.cable_names[i], f"{v['force'][i]:8.2f}", f"{v['measured'][i]:8.2f}",
                               f"{v['residual'][i]:+7.2f}", f"{v['elongation'][i] * 1e3:7.3f}",
                               f"{np.degrees(v['wrap_angle'][i]):6.1f}", "yes" if v["slack"][i] else "")
            parts.append(tb)
            for a in st["alarms_active"]:
                al.add_row(*((robot.name,) if several else ()), a["code"],
                           "" if a.get("cable") is None else geom.cable_names[a["cable"]], a["severity"],
                           _since(a.get("since")), a["message"])
        return Group(*parts, al)

    failed = [False]

    def safe_render():
        # the view is a window on the daemon, never a reason for it to stop: a view that
        # cannot draw says why (once in the log) and the loop goes on
        try:
            return render()
        except Exception as e:  # noqa: BLE001
            if not failed[0]:
                logging.getLogger("cablesvc.run").exception("the terminal view failed; the daemon keeps running")
                failed[0] = True
            return Text(f"terminal view failed ({e!r}); the daemon keeps running, see the log")

    if last_frame is not None:
        last_frame.append(safe_render)
    with Live(safe_render(), refresh_per_second=8, transient=True) as live:
        while alive() and not stop.is_set():
            stop.wait(0.125)
            live.update(safe_render())
            if deadline is not None and time.monotonic() >= deadline:
                stop.set()


def print_last_frame(last_frame: list) -> None:
    """Print the view's last frame (see :func:`view`), after the daemons have stopped."""
    if last_frame:
        from rich.console import Console

        Console().print(last_frame[0]())
